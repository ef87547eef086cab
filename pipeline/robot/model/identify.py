"""Identifiability: which parameters and directions a fit steps in, and what it holds where.

* :func:`identifiability`: the numerical rank of the column-scaled Jacobian and the parameters the poses
  determine well enough to fit (:data:`RANK_TOL`, :data:`WEAK_TOL`, :data:`SHORT_LEVER`);
* :func:`physical_subspace`: what the measurements cannot see held nearest the nominal robot, every
  parameter counted in units of its typical size (``x = B z``; contract section 8);
* :func:`unseen_groups`: those unseen combinations, group by group, in words (the fit JSON);
* :func:`fit_directions`: the directions ``B`` a fit steps in and the unseen ones ``U``, from the verdict;
* :func:`penalty_rows` and :func:`priority`: the effects' penalty rows and the order parameters are kept in.
"""

from __future__ import annotations

import re

import numpy as np
import scipy.linalg

from . import normal

#: Relative singular value of the column-scaled Jacobian below which a direction is not identifiable
#: (numerical rank)
RANK_TOL = 1e-7
#: A parameter is identified only when the poses determine it well enough for the model to hold on
#: poses the fit did not see. Its determination is the distance of its (unit) Jacobian column from
#: the span of the other identified parameters' columns, relative to the largest singular value: the
#: inverse of its standard error in these units, i.e. how well it is told apart from all the others
#: together. Parameters below WEAK_TOL are left at nominal one at a time, the least determined first,
#: until every one left is above (condition number of the identified set ~1 / WEAK_TOL or better; the
#: series it was set on: docs/fitting-core.md).
WEAK_TOL = 5e-4
#: Relative singular value below which a fixed parameter is called redundant (an exact combination
#: of the kept ones) rather than weakly determined.
EXACT_TOL = 1e-9
#: A rotation parameter whose Jacobian column is shorter than this times the median rotation's (it
#: moves the measured point a hundred times less than a typical rotation: an axis the SMR sits on or
#: near) is not identified (1e-3 let such rotations reach 1e5 arcsec: docs/fitting-core.md).
SHORT_LEVER = 1e-2

_SHORT = ("moves the measured point less than 1/100 as much as a typical parameter "
          "(an axis the SMR sits on or near): not identifiable")
#: the same for a value of a penalised table (a joint map's knot): few or no sample poses near its angle
_SHORT_KNOT = ("moves the measured point less than 1/100 as much as a typical parameter: few or no sample "
               "poses lie near this angle of the joint (a range's end, a stretch the poses barely reached), or "
               "the joint barely moves the measured point (an axis the SMR sits on); it stays at 0")


def identifiability(J: np.ndarray, names: list[str], tol: float = RANK_TOL, priority=None,
                    weak_tol: float | None = None, units=None, penalised=None) -> dict:
    """Rank, condition number and identifiable parameters of a Jacobian.

    Parameters
    ----------
    J : ndarray, shape (N, p)
        Jacobian of the residuals (mm per internal unit), dense or scipy.sparse.
    names : list of str, length p
    priority : sequence of int, optional
        Order in which parameters are preferred when some must be fixed (greedy: a
        parameter is kept when it raises the rank of those kept before it). Default:
        QR with column pivoting.
    weak_tol : float, optional
        Parameters determined below it are left at nominal (:data:`WEAK_TOL`).
    units : list of (unit, factor), optional
    penalised : ndarray of bool, shape (p,), optional
        Parameters kept smooth and unique by their effect's penalty rows: not ranked.

    Returns
    -------
    dict with ``rank``, ``n_params``, ``condition_number`` (of the scaled Jacobian restricted
    to the identifiable parameters), ``condition_number_all``, ``singular_values`` (scaled),
    ``keep`` (bool mask) and ``not_identifiable`` (names fixed at 0).
    """
    if penalised is not None and np.any(penalised):
        return _identifiability_penalised(J, names, tol, priority, weak_tol, units, penalised)
    if hasattr(J, "tocsc"):          # a scipy.sparse Jacobian (Design.predict_and_sparse_jacobian)
        J = J.toarray()
    norms = np.linalg.norm(J, axis=0)
    zero = norms <= 1e-12 * max(norms.max(initial=0.0), 1e-300)
    # a parameter that moves the measured point a hundred times less than a typical one (a rotation
    # about an axis the SMR sits on, 0.4 mm off it) is not identified: scaled to unit norm, its column
    # would turn rounding and noise into coefficients of 1e6 arcsec (SHORT_LEVER)
    angle = np.array([u[0] == "arcsec" for u in units], bool) if units is not None else np.zeros(len(names), bool)
    short = np.zeros_like(zero)
    if (angle & ~zero).any():   # rotations: compared with the other rotations (mm of motion per mrad)
        short = angle & ~zero & (norms < SHORT_LEVER * np.median(norms[angle & ~zero]))
    zero = zero | short
    Js = J / np.where(zero, 1.0, norms)
    Js[:, zero] = 0.0
    if Js.shape[0] > Js.shape[1]:
        # J = Q R with orthonormal Q: every column subset of R has the singular values of the
        # same subset of J, so the rank tests below cost O(p^3) whatever the number of poses
        Js = np.linalg.qr(Js, mode="r")
    s = np.linalg.svd(Js, compute_uv=False)
    rank = int(np.sum(s > tol * s[0])) if s.size else 0
    keep = _kept_by_rank(Js, s, rank, zero, tol, priority)
    reasons = {}
    for c in np.flatnonzero(~keep):
        reasons[names[c]] = {"relative_determination": 0.0,
                             "reason": (_SHORT if short[c] else
                                        "does not move the measured point at these poses" if zero[c] else
                                        "redundant: a combination of the identified parameters (numerical rank)")}
    s0 = float(s[0]) if s.size else 0.0
    if weak_tol is not None and s0 > 0:
        _leave_out_weak(Js, s0, keep, reasons, names, weak_tol, priority)
    sk = np.linalg.svd(Js[:, keep], compute_uv=False) if keep.any() else np.array([1.0])
    return {"rank": rank, "n_params": int(J.shape[1]),
            "condition_number": float(sk[0] / sk[-1]),
            # rank-deficient: the smallest singular value is rounding noise, and so would be the ratio
            # (1e17 on one CPU, 3e18 on another): infinite, written as null
            "condition_number_all": float(s[0] / s[-1]) if s.size and s[-1] > tol * s[0] else float("inf"),
            "singular_values": s.tolist(), "keep": keep, "rank_tol": tol, "weak_tol": weak_tol,
            "not_identifiable": [n for n, k in zip(names, keep) if not k],
            "fixed_reasons": reasons, "zero": zero}


def _identifiability_penalised(J, names, tol, priority, weak_tol, units, penalised) -> dict:
    """:func:`identifiability` with penalised parameters: those are not ranked (their effect's penalty keeps
    them smooth and unique, a joint map's hundreds of grid values); only the rotations the SMR barely feels
    are left out."""
    sparse = hasattr(J, "tocsc")
    pen = np.asarray(penalised, bool)
    Jr = J.tocsc()[:, np.flatnonzero(~pen)].toarray() if sparse else J[:, ~pen]
    rest = identifiability(Jr, [n for n, q in zip(names, pen) if not q], tol,
                           None if priority is None else [int(np.sum(~pen[:c])) for c in priority if not pen[c]],
                           weak_tol, None if units is None else [u for u, q in zip(units, pen) if not q])
    norms = (np.sqrt(np.asarray(J.multiply(J).sum(axis=0)).ravel()) if sparse else np.linalg.norm(J, axis=0))
    angle = np.array([u[0] == "arcsec" for u in units], bool) if units is not None else np.zeros(len(names), bool)
    ref = norms[angle & ~pen & (norms > 0)]
    short = pen & (norms < SHORT_LEVER * (np.median(ref) if ref.size else norms.max(initial=0.0)))
    keep = np.zeros(J.shape[1], bool)
    keep[~pen] = rest["keep"]
    keep[pen] = ~short[pen]
    zero = np.zeros(J.shape[1], bool)
    zero[~pen] = rest["zero"]
    zero |= short
    reasons = dict(rest["fixed_reasons"])
    for c in np.flatnonzero(short):
        reasons[names[c]] = {"relative_determination": 0.0, "reason": _SHORT_KNOT}
    return {**rest, "n_params": int(J.shape[1]), "keep": keep, "zero": zero, "fixed_reasons": reasons,
            "not_identifiable": [n for n, k in zip(names, keep) if not k], "penalised": int(pen.sum())}


def _kept_by_rank(Js, s, rank, zero, tol, priority) -> np.ndarray:
    """The parameters (p,) bool kept by the numerical rank of the scaled ``Js``: QR with column pivoting, or
    greedily in ``priority`` order (a parameter kept when it raises the rank of those kept before it)."""
    keep = np.zeros(Js.shape[1], bool)
    if priority is None:
        _, _, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
        keep[piv[:rank]] = True
    else:
        kept = []
        for c in priority:
            if zero[c]:
                continue
            trial = Js[:, kept + [c]]
            sv = np.linalg.svd(trial, compute_uv=False)
            if sv[-1] > tol * s[0]:
                kept.append(c)
            if len(kept) == rank:
                break
        keep[kept] = True
    keep &= ~zero
    return keep


def _leave_out_weak(Js, s0, keep, reasons, names, weak_tol, priority) -> None:
    """Leave the weakly determined parameters at nominal one at a time, the least determined first, until
    every one left is determined above ``weak_tol`` (``keep`` and ``reasons`` updated in place)."""
    rank_of = {c: k for k, c in enumerate(priority)} if priority is not None else {}
    while keep.sum() > 1:
        idx = np.flatnonzero(keep)
        A = Js[:, idx]
        try:
            det = 1.0 / np.sqrt(np.diag(np.linalg.inv(A.T @ A))) / s0   # distance from the others' span
        except np.linalg.LinAlgError:
            break
        low = np.flatnonzero(det < weak_tol)
        if not low.size:
            break
        # the least determined first; among (nearly) equal ones, the one of lowest priority
        k = max(low, key=lambda m: (-round(float(np.log10(max(det[m], 1e-300))), 1), rank_of.get(idx[m], idx[m])))
        c = int(idx[k])
        keep[c] = False
        reasons[names[c]] = {"relative_determination": float(det[k]),
                             "reason": (f"weakly determined: {det[k]:.1e} of the best-determined direction (limit "
                                        f"{weak_tol:g}); fitted, it would trade with the identified parameters and "
                                        "not hold on poses away from these")}


def physical_subspace(A: np.ndarray | None, B0: np.ndarray, free, sizes, tol: float = RANK_TOL, gram=None):
    """What the measurements determine, represented nearest the nominal robot (contract section 8).

    The fit moves the parameters ``x`` in the span of ``B0`` (the parameters kept, or the leading
    singular directions): that span decides the predictions. Among the parameters ``free`` to move,
    the directions ``n`` with ``A n = 0`` (relative singular value of the column-scaled ``A`` below
    ``tol``) change no prediction: the measurements cannot see them (with one SMR, the last joint's
    frame against the tool offset; a 7-joint arm's redundant axes). Every parameter is counted in
    units of its typical size (``u = x / sizes``); the span of ``B0`` is replaced by its projection
    orthogonal (in ``u``) to those directions. ``A B`` spans what ``A B0`` spans (the same
    predictions, to first order), and the least-squares solution in it is the one nearest the
    nominal robot: the smallest ``||x / sizes||`` of all the solutions that predict alike.

    Parameters
    ----------
    A : ndarray, shape (m, p)
        Jacobian of the residuals (with any penalty rows) at the nominal parameters.
    B0 : ndarray, shape (p, k)
        The fitted directions (columns), zero outside ``free``.
    free : ndarray of bool, shape (p,)
        Parameters that may move (not fixed at nominal).
    sizes : ndarray, shape (p,)
        Typical size of each parameter (internal units).
    gram : ndarray, shape (p, p), optional
        ``A^T A`` in place of ``A`` (``A`` may then be None): the singular values and right singular
        vectors are those of its eigen-decomposition (a relative singular value resolves down to
        about 1e-8, below ``tol``'s 1e-7; what the measurements cannot see at all comes out near 1e-8
        or below), for fits of hundreds of parameters on thousands of poses
        (:data:`pipeline.robot.model.normal.GRAM_MIN_K`).

    Returns
    -------
    B : ndarray, shape (p, k)
        The directions to fit in (``x = B z``): each column of ``B0`` without its part along the unseen
        directions (in ``u``).
    U : ndarray, shape (p, r)
        The directions the measurements cannot see (``u`` coordinates, orthonormal; 0 outside ``free``).
    """
    p = B0.shape[0]
    cols = np.flatnonzero(free)
    U = np.zeros((p, 0))
    if cols.size and gram is not None:
        G = gram[np.ix_(cols, cols)] * np.outer(sizes[cols], sizes[cols])
        nrm = np.sqrt(np.maximum(np.diag(G), 0.0))
        nrm = np.where(nrm > 0, nrm, 1.0)
        sv, Vt = normal.singular_directions(G / np.outer(nrm, nrm), rtol=None)
    elif cols.size:
        Af = A[:, cols] * sizes[cols]
        nrm = np.linalg.norm(Af, axis=0)
        nrm = np.where(nrm > 0, nrm, 1.0)
        R = np.linalg.qr(Af / nrm, mode="r") if Af.shape[0] > Af.shape[1] else Af / nrm
        _, sv, Vt = np.linalg.svd(R, full_matrices=True)
        sv = np.concatenate([sv, np.zeros(cols.size - sv.size)])
    if cols.size:
        null = Vt[sv <= tol * max(sv[0], 1e-300)].T / nrm[:, None]      # u coordinates, not orthonormal
        if null.shape[1]:
            Q, r, _ = scipy.linalg.qr(null, mode="economic", pivoting=True)
            Q = Q[:, np.abs(np.diag(r)) > 1e-12 * np.abs(r[0, 0])]
            U = np.zeros((p, Q.shape[1]))
            U[cols] = Q
    # each fitted direction without its unseen part: A B = A B0 column by column, so the solver sees the
    # Jacobian it saw before (same steps, same convergence), and x = B z is the representative nearest
    # the nominal robot
    Bu = B0 / sizes[:, None]
    Bu = Bu - U @ (U.T @ Bu)
    Bu[~np.asarray(free, bool)] = 0.0          # a parameter fixed at nominal stays there
    return sizes[:, None] * Bu, U


def unseen_groups(U: np.ndarray, names, units, sizes, tol: float = 1e-9) -> list[dict]:
    """The parameters the measurements cannot tell apart, group by group, in words (the fit JSON).

    Parameters
    ----------
    U : ndarray, shape (p, r)
        Orthonormal directions the measurements cannot see, in units of typical size
        (:func:`physical_subspace`).

    Returns
    -------
    list of dict: per group (parameters linked by an unseen direction; from the projector ``U U^T``,
    so independent of the basis): ``parameters``, ``typical_sizes`` (reported units), ``seen`` and
    ``unseen`` (how many combinations of them the measurements see and do not), ``held`` and ``why``
    (plain words), and ``unseen_directions``: a canonical basis of the unseen combinations (reduced
    row echelon form, reported units: the first parameter of each moves by one typical size).
    """
    if U.shape[1] == 0:
        return []
    P = U @ U.T
    link = np.abs(P) > tol
    p = len(names)
    seen_at, groups = np.full(p, -1), []
    for i in range(p):
        if seen_at[i] >= 0 or P[i, i] <= tol:
            continue
        members, stack = [], [i]
        seen_at[i] = len(groups)
        while stack:
            a = stack.pop()
            members.append(a)
            for b in np.flatnonzero(link[a]):
                if seen_at[b] < 0:
                    seen_at[b] = len(groups)
                    stack.append(b)
        groups.append(sorted(members))
    out = []
    for g in groups:
        g = np.array(g)
        k = int(round(float(np.trace(P[np.ix_(g, g)]))))
        # canonical basis of the unseen combinations: reduced row echelon form of U's rows on the group
        M = U[g].T[np.abs(U[g]).max(axis=0) > tol]                 # (r', n) spanning the group's part
        M = scipy.linalg.orth(M.T).T if M.size else M
        E = _rref(M)[:k]
        dirs = []
        for row in E:
            # at a fixed resolution (1e-6 of the reported unit): the last bits of an SVD differ by machine
            dirs.append({names[c]: round(float(v * sizes[c] * units[c][1]), 6) + 0.0
                         for c, v in zip(g, row) if abs(v) > 1e-9})
        typ = {names[c]: float(sizes[c] * units[c][1]) for c in g}
        out.append({
            "parameters": [names[c] for c in g], "typical_sizes": typ,
            "seen": int(len(g) - k), "unseen": k,
            "held": (f"the {k} combination{'s' if k != 1 else ''} of these {len(g)} parameters that the measurements "
                     f"cannot see {'are' if k != 1 else 'is'} held where the parameters, each counted in units of its "
                     "typical size, are nearest the nominal robot (the smallest sum of squares): what the "
                     "measurements show is carried by the parameters that change least for it"),
            "why": (f"at these poses the {len(g)} parameters move the measured point in only {len(g) - k} independent "
                    f"way{'s' if len(g) - k != 1 else ''}: changed together as in each of the unseen directions, they "
                    "leave every measured position as it is (e.g. with one SMR, the last joint's frame and the tool "
                    "offset), so no measurement can say which of them it is"),
            "unseen_directions": dirs})
    return out


def _rref(M: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Reduced row echelon form of M (rows: a basis of a subspace), pivoting by column order."""
    A = np.array(M, float)
    r = 0
    rows, cols = A.shape
    for c in range(cols):
        if r >= rows:
            break
        piv = r + int(np.argmax(np.abs(A[r:, c])))
        if abs(A[piv, c]) <= tol:
            continue
        A[[r, piv]] = A[[piv, r]]
        A[r] /= A[r, c]
        for i in range(rows):
            if i != r:
                A[i] -= A[i, c] * A[r]
        r += 1
    A[np.abs(A) < 1e-12] = 0.0
    return A[:r]


def priority(names) -> list[int]:
    """Order of the parameters in the rank and weak-determination passes of :func:`identifiability`:
    joint offsets, then link lengths and twists, then d and beta (MDH practice); other effects in
    their order. It decides which parameters are left at nominal when they are weakly determined
    (the predictions), never how what the measurements cannot see is represented: redundant
    parameters stay free and the fit is the one nearest the nominal robot (:func:`physical_subspace`)."""
    order = {"dtheta": 0, "da": 1, "dalpha": 2, "dd": 3, "dbeta": 4}

    def key(k):
        m = re.match(r"^(dtheta|dd|da|dalpha|dbeta)(\d)$", names[k])
        return (order[m.group(1)], int(m.group(2))) if m else (5, k)
    return sorted(range(len(names)), key=key)


def penalty_rows(robot, effects, n_poses: int, p: int):
    """The effects' penalty rows (m, p) (smooth many-parameter effects) and which parameters they
    penalise (p,) bool, for a fit on ``n_poses`` poses."""
    blocks, penalised = [], np.zeros(p, bool)
    k = 0
    for e in effects:
        n_e = len(e.parameter_names(robot))
        pen = e.penalty(robot, n_poses)
        if pen is not None:
            row = np.zeros((pen.shape[0], p))
            row[:, k:k + n_e] = pen
            blocks.append(row)
            penalised[k:k + n_e] = True
        k += n_e
    return (np.vstack(blocks) if blocks else np.zeros((0, p))), penalised


def fit_directions(J2, Pen, ident: dict, design, reduction: str, identified: bool, rank_tol: float,
                   H0=None) -> tuple[np.ndarray, np.ndarray]:
    """The directions a fit steps in, ``x = B z`` (p, k), and the directions no measurement can see, U
    (p, r) in units of typical size (:func:`physical_subspace`); ``ident`` (:func:`identifiability`'s
    verdict) updated in place with what was held and why (``redundant_groups``, ``not_identifiable``).

    Parameters
    ----------
    J2 : ndarray or scipy.sparse matrix, shape (m, p)
        The identification Jacobian at nominal (mm per internal unit).
    Pen : ndarray, shape (m', p)
        The effects' penalty rows.
    design : Design
        Its ``names``, ``units``, ``sizes`` and ``p``.
    reduction : {"fix", "svd"}
        Parameters kept by name, or the leading singular directions of the column-scaled J2.
    identified : bool
        Whether the verdict is applied (False: every parameter free).
    H0 : ndarray, shape (p, p), optional
        ``J2^T J2`` (a fit on normal equations, J2 sparse).
    """
    d = design
    norms = np.sqrt(np.maximum(np.diag(H0), 0.0)) if H0 is not None else np.linalg.norm(J2, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    if identified and reduction == "svd":
        if H0 is not None:
            # the same sv and V as the dense SVD's, without its U
            sv2, Vt = normal.scaled_svd(J2, norms, ident["zero"])
        else:
            Js2 = J2 / norms
            Js2[:, ident["zero"]] = 0.0          # parameters that barely move the point stay at 0
            _, sv2, Vt = np.linalg.svd(Js2, full_matrices=False)
        r = min(ident["rank"], int(np.sum(sv2 > rank_tol * sv2[0])) if sv2.size else 0)
        B = Vt[:r].T / norms[:, None]          # (p, r): x = B z
        ident["not_identifiable"] = [n for n, z in zip(d.names, ident["zero"]) if z]
        # no other parameter is singled out: weak directions are left out
        ident["fixed_reasons"] = {n: v for n, v in ident["fixed_reasons"].items() if n in ident["not_identifiable"]}
        ident["directions_left_out"] = int(d.p - ident["rank"])
    else:
        keep = ident["keep"] if identified else np.ones(d.p, bool)
        B = np.eye(d.p)[:, keep]
    # what the measurements cannot see stays physical (contract section 8): the span of B decides
    # the predictions; within the parameters free to move, the directions that change no prediction
    # are held where the model is nearest the nominal robot, every parameter counted in units of its
    # typical size (physical_subspace). A parameter called redundant (an exact combination of the
    # kept ones) is free: it takes its share of what it cannot be told apart from.
    if identified and reduction == "fix":
        redundant = np.array([ident["fixed_reasons"].get(n, {}).get("reason", "").startswith("redundant")
                              for n in d.names], bool)
        movable = ident["keep"] | redundant
    elif identified:
        movable = ~ident["zero"]
    else:
        movable = np.ones(d.p, bool)
    if H0 is not None:
        B, U = physical_subspace(None, B, movable, d.sizes, gram=H0 + Pen.T @ Pen)
    else:
        B, U = physical_subspace(np.vstack([J2, Pen]), B, movable, d.sizes)
    moves = (np.abs(B).max(axis=1, initial=0.0) > 0) | (np.abs(U).max(axis=1, initial=0.0) > 0)
    groups = unseen_groups(U, d.names, d.units, d.sizes)
    in_group = {n for g in groups for n in g["parameters"]}
    reasons = {n: r for n, r in ident["fixed_reasons"].items()
               if n not in in_group and not (n in d.names and moves[d.names.index(n)])}
    ident["fixed_reasons"] = reasons
    ident["not_identifiable"] = [n for n in d.names if n in reasons]
    ident["redundant_groups"] = groups
    return B, U
