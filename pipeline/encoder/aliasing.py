"""Aliasing of harmonic orders (paper 1, Eqs. 3-4).

With N distinct, evenly spaced angles per turn, orders above N/2 cannot be separated:
order j shows up at order |j mod N| folded into 0..N/2,

    a_i = A_i + sum_k (A_{kN-i} + A_{kN+i}),   b_i = B_i + sum_k (B_{kN+i} - B_{kN-i}).

The closing reading of a one-way run revisits the first face; it is a closure check, not
a new angle, so N counts distinct angles (36 for a 36-face polygon, not 37).
"""

from __future__ import annotations


class OrderTooHighError(ValueError):
    """A harmonic order the data cannot resolve was asked for."""


def max_order(n_distinct: int) -> int:
    """Highest order resolvable from N distinct angles: N // 2 (cosine only at N/2 when N is even)."""
    return int(n_distinct) // 2


def max_full_order(n_distinct: int) -> int:
    """Highest order with both cosine and sine resolvable: (N - 1) // 2."""
    return (int(n_distinct) - 1) // 2


def check_orders(orders, n_distinct: int) -> None:
    """Refuse orders above N/2 with a message that says why and what folds where."""
    top = max_order(n_distinct)
    bad = sorted(int(o) for o in orders if int(o) > top)
    if bad:
        folds = ", ".join(f"{o} -> {fold(o, n_distinct)[0]}" for o in bad[:4])
        raise OrderTooHighError(
            f"harmonic order {bad[0]} cannot be resolved from {n_distinct} distinct angles per run: the highest "
            f"order is N/2 = {top} (Shannon); higher orders alias onto lower ones ({folds})")
    neg = [o for o in orders if int(o) < 0]
    if neg:
        raise OrderTooHighError(f"harmonic order {neg[0]} is negative; orders are 0, 1, 2, ...")


def fold(order: int, n_distinct: int) -> tuple[int, int]:
    """Order that ``order`` lands on with N distinct angles, and the sign of its sine term.

    Returns
    -------
    (i, s) : the fitted order i in 0..N/2 and s = +1 if B_order adds to b_i, -1 if it subtracts.
    """
    N = int(n_distinct)
    r = int(order) % N
    if r == 0 or 2 * r == N:
        return r, 0  # the sine of these orders vanishes at every sample
    if r < N - r:
        return r, +1
    return N - r, -1


def alias_table(n_distinct: int, n_fit: int, highest: int = 100) -> list[dict]:
    """For each fitted order 0..n_fit, the higher orders (up to ``highest``) that fold into it.

    Returns
    -------
    list of dict: ``order``, ``cos_from`` (orders adding to a_i), ``sin_plus`` (adding to b_i),
    ``sin_minus`` (subtracted from b_i), and ``equation``: a_i and b_i written as Eq. 4 writes them.
    """
    rows = []
    for i in range(n_fit + 1):
        plus, minus, cos = [], [], []
        for j in range(n_fit + 1, highest + 1):
            k, s = fold(j, n_distinct)
            if k == i:
                cos.append(j)
                if s > 0:
                    plus.append(j)
                elif s < 0:
                    minus.append(j)  # s == 0: the sine of j vanishes at every sample (order 0, N/2)
        cos_from = sorted(cos)
        a = " + ".join([f"A{i}"] + [f"A{j}" for j in cos_from[:4]]) + (" + ..." if len(cos_from) > 4 else "")
        b = f"B{i}" + "".join(f" + B{j}" for j in plus[:2]) + "".join(f" - B{j}" for j in minus[:2])
        nyquist = 2 * i == int(n_distinct)
        eq = f"a{i} = {a}" if i == 0 or nyquist else f"a{i} = {a};  b{i} = {b} ..."
        if nyquist:
            eq += f";  b{i} not estimable (sin({i} theta) = 0 at every sample)"
        rows.append({"order": i, "cos_from": cos_from, "sin_plus": plus, "sin_minus": minus, "equation": eq})
    return rows


def alias_frame(n_distinct: int, highest: int = 100):
    """``jointcal aliasing``'s table: :func:`alias_table` for every order N distinct angles resolve, one row an
    order, the folding orders as space-separated text.

    Returns
    -------
    pandas.DataFrame
        ``N_distinct``, ``order``, ``folds_from``, ``sin_added``, ``sin_subtracted``, ``equation``.
    """
    import pandas as pd

    rows = alias_table(n_distinct, max_order(n_distinct), highest)
    table = pd.DataFrame([{"order": r["order"], "folds_from": " ".join(map(str, r["cos_from"])),
                           "sin_added": " ".join(map(str, r["sin_plus"])),
                           "sin_subtracted": " ".join(map(str, r["sin_minus"])), "equation": r["equation"]}
                          for r in rows])
    table.insert(0, "N_distinct", n_distinct)
    return table
