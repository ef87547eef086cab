"""Stage ``harmonic``: per-run Fourier coefficients of the angle error (paper 1, Eqs. 1-2).

Convention: error(theta) = A_0 + sum_i A_i cos(i theta) + B_i sin(i theta)
                         = C_0 + sum_i C_i sin(i theta + phi_i),
with C_i = hypot(A_i, B_i), phi_i = atan2(A_i, B_i) (degrees), C_0 = A_0 (signed).

Two estimators: least squares (any angles) and FFT (angles on an even grid). On even
data they agree to rounding. Aliasing (Eqs. 3-4) is in :mod:`pipeline.encoder.aliasing`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .aliasing import check_orders


def harmonic_columns(theta_deg, orders) -> tuple[list[str], np.ndarray]:
    """cos/sin regressors of ``orders`` (order 0 excluded: it is the run constant).

    Parameters
    ----------
    theta_deg : ndarray, shape (n,), deg
    orders : sequence of int

    Returns
    -------
    labels : list of str, ``A<i>``, ``B<i>`` for each order i >= 1
    X : ndarray, shape (n, 2 * k)
        Columns cos(i theta), sin(i theta), so that A_i cos + B_i sin = C_i sin(i theta + phi_i).
    """
    th = np.deg2rad(np.asarray(theta_deg, dtype=float))
    labels, cols = [], []
    for i in orders:
        if i == 0:
            continue
        labels += [f"A{i}", f"B{i}"]
        cols += [np.cos(i * th), np.sin(i * th)]
    X = np.column_stack(cols) if cols else np.empty((th.size, 0))
    return labels, X


def lsq_coefficients(theta_deg, y, orders) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares A_i, B_i for the given orders (always with a constant).

    Parameters
    ----------
    theta_deg : ndarray, shape (n,), deg
        Angles of the readings; need not be even.
    y : ndarray, shape (n,) or (n, m), arcsec
        Errors (m signals share the angles).
    orders : sequence of int
        Orders to fit; order 0 is the constant and is always fitted.

    Returns
    -------
    A, B : ndarray, shape (len(orders),) or (len(orders), m), arcsec
        ``B`` of order 0 is 0.
    """
    orders = list(orders)
    pos = [i for i in orders if i != 0]
    _, H = harmonic_columns(theta_deg, pos)
    X = np.column_stack([np.ones(H.shape[0]), H])
    coef, *_ = np.linalg.lstsq(X, np.asarray(y, float), rcond=None)
    shape = (len(orders),) + coef.shape[1:]
    A, B = np.zeros(shape), np.zeros(shape)
    for j, i in enumerate(orders):
        if i == 0:
            A[j] = coef[0]
        else:
            k = 1 + 2 * pos.index(i)
            A[j], B[j] = coef[k], coef[k + 1]
    return A, B


def fft_coefficients(y_even, n_max: int, theta0_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A_i, B_i for orders 0..n_max from N readings evenly spaced over one turn.

    Parameters
    ----------
    y_even : ndarray, shape (N,) or (N, m), arcsec
        Readings at theta0 + k * 360 / N, k = 0..N-1 (no closing reading).
    n_max : int
        Highest order; at most N // 2 (the Nyquist order has no sine term).
    theta0_deg : float or ndarray, shape (m,), deg
        Angle of the first reading (of each signal).

    Returns
    -------
    A, B : ndarray, shape (n_max + 1,) or (n_max + 1, m), arcsec
    """
    y = np.asarray(y_even, float)
    N = y.shape[0]
    check_orders([n_max], N)
    F = np.fft.rfft(y, axis=0)[: n_max + 1] / N
    i = np.arange(n_max + 1).reshape((-1,) + (1,) * (y.ndim - 1))
    # rotate to absolute angle: the grid starts at theta0
    F = F * np.exp(-1j * i * np.deg2rad(theta0_deg))
    A = 2 * F.real
    B = -2 * F.imag
    A[0] = F[0].real
    B[0] = 0.0
    if N % 2 == 0 and n_max == N // 2:
        A[-1] = F[-1].real  # Nyquist order: cos only, not doubled
        B[-1] = 0.0
    return A, B


def amplitude_phase(A, B) -> tuple[np.ndarray, np.ndarray]:
    """C_i = hypot(A_i, B_i) (arcsec), phi_i = atan2(A_i, B_i) in degrees, in [0, 360)."""
    return np.hypot(A, B), np.mod(np.rad2deg(np.arctan2(A, B)), 360.0)


def circular_mean_deg(phi_deg, axis=0):
    """Mean direction of angles in degrees, in [0, 360)."""
    ph = np.deg2rad(np.asarray(phi_deg, float))
    return np.mod(np.rad2deg(np.arctan2(np.sin(ph).mean(axis), np.cos(ph).mean(axis))), 360.0)


def circular_range_deg(phi_deg) -> float:
    """Smallest arc (deg) containing all the angles."""
    ph = np.sort(np.mod(np.asarray(phi_deg, float), 360.0))
    if ph.size < 2:
        return 0.0
    gaps = np.diff(np.concatenate([ph, [ph[0] + 360.0]]))
    return float(360.0 - gaps.max())


def _design(theta_rad, orders):
    """cos/sin columns, shape theta.shape + (1 + 2 * #positive orders,).

    Powers of exp(i theta) give every order with one complex product each (orders need
    not be contiguous), much faster than a sine and a cosine per order.
    """
    pos = [i for i in orders if i]
    X = np.empty(theta_rad.shape + (1 + 2 * len(pos),))
    X[..., 0] = 1.0
    z = np.exp(1j * theta_rad)
    w = np.ones_like(z)
    power = 0
    for j, i in enumerate(sorted(pos)):
        w = w * z ** (i - power) if i - power > 1 else w * z
        power = i
        X[..., 1 + 2 * j] = w.real
        X[..., 2 + 2 * j] = w.imag
    if pos != sorted(pos):
        raise ValueError("orders must be increasing")
    return X


def batch_lsq(theta_deg, y, orders) -> tuple[np.ndarray, np.ndarray]:
    """Least squares for R runs of m readings each, in one batched solve.

    The normal matrix is built from trigonometric power sums S_k = sum_m exp(i k theta),
    k = 0..2n (products of sines and cosines are sums of such terms), so the work is
    O(n R m) and no (R, m, 2n+1) design tensor is ever formed: memory stays linear in
    the readings.

    Parameters
    ----------
    theta_deg : ndarray, shape (R, m), deg
    y : ndarray, shape (R, m), arcsec
    orders : list of int (0 = constant, always fitted)

    Returns
    -------
    A, B : ndarray, shape (R, len(orders)), arcsec
    """
    orders = list(orders)
    basis = [("c", 0)] + [(t, i) for i in orders if i for t in ("c", "s")]
    top = max(orders) if orders else 0
    z = np.exp(1j * np.deg2rad(np.asarray(theta_deg, float)))
    y = np.asarray(y, float)
    R = z.shape[0]
    P = np.empty((R, 2 * top + 1), complex)
    Q = np.empty((R, top + 1), complex)
    chunk = max(1, 4096 // max(1, z.shape[1]) * 16)  # keep the working set in cache
    for lo in range(0, R, chunk):
        zc, yc = z[lo:lo + chunk], y[lo:lo + chunk]
        w = np.ones_like(zc)
        for k in range(2 * top + 1):
            P[lo:lo + chunk, k] = w.sum(axis=1)
            if k <= top:
                Q[lo:lo + chunk, k] = (w * yc).sum(axis=1)
            w *= zc
    K = 2 * top + 1
    T = np.concatenate([P.real, P.imag, -P.imag], axis=1)  # sum cos(k theta), sum sin, -sum sin

    def cos_sum(k):  # column of T holding sum cos(k theta)
        return abs(k)

    def sin_sum(k, sign=1):  # column of T holding sign * sum sin(k theta)
        return K + abs(k) if (k >= 0) == (sign > 0) else 2 * K + abs(k)

    idx = np.zeros((len(basis), len(basis), 2), int)
    for p, (tp, a) in enumerate(basis):
        for q, (tq, b) in enumerate(basis):
            if tp == "c" and tq == "c":  # cos a cos b = (cos(a-b) + cos(a+b)) / 2
                idx[p, q] = cos_sum(a - b), cos_sum(a + b)
            elif tp == "s" and tq == "s":  # sin a sin b = (cos(a-b) - cos(a+b)) / 2
                idx[p, q] = cos_sum(a - b), -1
            elif tp == "c":  # cos a sin b = (sin(a+b) - sin(a-b)) / 2
                idx[p, q] = sin_sum(a + b), sin_sum(a - b, -1)
            else:  # sin a cos b = (sin(a+b) + sin(a-b)) / 2
                idx[p, q] = sin_sum(a + b), sin_sum(a - b)
    npar = len(basis)
    # the one term with a minus sign on a cosine: sin a sin b
    ss = np.array([[tp == "s" and tq == "s" for tq, _ in basis] for tp, _ in basis]).reshape(-1)
    plus = np.array([[cos_sum(a + b) for _, b in basis] for _, a in basis]).reshape(-1)
    i0, i1 = idx[..., 0].reshape(-1), idx[..., 1].reshape(-1)
    i1 = np.where(ss, plus, i1)
    G = np.take(T, i0, axis=1)
    second = np.take(T, i1, axis=1)
    second[:, ss] *= -1.0
    G += second
    del second
    G *= 0.5
    G = G.reshape(R, npar, npar)
    b = np.array([Q[:, i].real if t == "c" else Q[:, i].imag for t, i in basis]).T
    coef = np.linalg.solve(G, b[..., None])[..., 0]
    A, B = np.zeros((R, len(orders))), np.zeros((R, len(orders)))
    k = 1
    for j, i in enumerate(orders):
        if i == 0:
            A[:, j] = coef[:, 0]
        else:
            A[:, j], B[:, j] = coef[:, k], coef[:, k + 1]
            k += 2
    return A, B


def analyse_runs(frame: pd.DataFrame, n_max: int | None = None, grid_tol_deg: float = 0.05) -> pd.DataFrame:
    """Per-run harmonic coefficients by LSQ and, where the angles are even, FFT.

    Parameters
    ----------
    frame : DataFrame
        Ingested encoder readings (``run``, ``step``, ``theta_deg``, ``error_arcsec``,
        optional ``direction``).
    n_max : int, optional
        Highest order. Default: the highest order with both A and B resolvable from the
        run's distinct angles, (N - 1) // 2. Higher than N // 2 is refused (aliasing).
    grid_tol_deg : float, deg
        Largest distance from the even grid for the FFT to apply (the joint's own error
        moves the angles off the grid by its error, tens of arcseconds).

    Returns
    -------
    DataFrame, one row per (run, order): A, B, C, phi_deg (LSQ), A_fft, B_fft (NaN when
    uneven), N distinct angles, closure_arcsec (last minus first reading at the same angle).

    Runs of equal length are solved together in one batched normal-equation solve, so a
    million readings take well under a second.
    """
    f = frame.sort_values(["run", "step"], kind="stable")
    run = f["run"].to_numpy()
    th_all = f["theta_deg"].to_numpy(float)
    y_all = f["error_arcsec"].to_numpy(float)
    one_way_all = f["direction"].to_numpy() > 0 if "direction" in f else np.ones(run.size, bool)
    starts = np.flatnonzero(np.r_[True, run[1:] != run[:-1]])
    lengths = np.diff(np.r_[starts, run.size])
    parts = []
    for m in np.unique(lengths):
        sel = starts[lengths == m]
        idx = sel[:, None] + np.arange(m)[None, :]
        parts.append(_analyse_block(run[sel], th_all[idx], y_all[idx], one_way_all[idx].all(axis=1), n_max, grid_tol_deg))
    out = pd.concat(parts, ignore_index=True)
    return out.sort_values(["run", "order"], kind="stable").reset_index(drop=True)


def _analyse_block(runs, th, y, one_way, n_max, tol):
    """Runs with m readings each: th, y of shape (R, m)."""
    R, m = th.shape
    rel = np.mod(th - th[:, :1] + tol, 360.0) - tol        # angle from each run's start, in [-tol, 360 - tol)
    back = np.abs(rel) < tol
    back[:, 0] = False
    # distinct angles per run, and whether they sit on an even grid of one turn
    srt = np.sort(rel, axis=1)
    N_run = 1 + np.count_nonzero(np.diff(srt, axis=1) > tol, axis=1)
    pitch = 360.0 / N_run[:, None]
    k = np.round(rel / pitch)
    on_grid = np.all(np.abs(rel - k * pitch) <= tol, axis=1)
    kk = np.sort(np.mod(k, N_run[:, None]), axis=1)
    even = on_grid & (1 + np.count_nonzero(np.diff(kk, axis=1) > 0, axis=1) == N_run)
    N = int(N_run.min())
    nm = (N - 1) // 2 if n_max is None else int(n_max)
    check_orders([nm], N)
    orders = list(range(nm + 1))
    A, B = batch_lsq(th, y, orders)
    C, phi = amplitude_phase(A, B)
    C[:, 0] = A[:, 0]
    Af = np.full_like(A, np.nan)
    Bf = np.full_like(B, np.nan)
    fft_ok = even & one_way & (N_run == N) & (m - back.sum(axis=1) == N)
    if fft_ok.any():
        rows = np.flatnonzero(fft_ok)
        keep = ~back[rows]
        yy = y[rows][keep].reshape(rows.size, N)
        rr = rel[rows][keep].reshape(rows.size, N)
        order_idx = np.argsort(rr, axis=1)
        yy = np.take_along_axis(yy, order_idx, axis=1)
        a, b = fft_coefficients(yy.T, nm, th[rows, 0])
        Af[rows], Bf[rows] = a.T, b.T
    closure = np.where(back.any(axis=1), np.where(back, y, np.nan)[np.arange(R), m - 1 - np.argmax(back[:, ::-1], axis=1)] - y[:, 0], np.nan)
    n_ord = len(orders)
    return pd.DataFrame({
        "run": np.repeat(runs.astype(np.int64), n_ord), "order": np.tile(np.arange(n_ord, dtype=np.int64), R),
        "A": A.ravel(), "B": B.ravel(), "C": C.ravel(), "phi_deg": phi.ravel(),
        "A_fft": Af.ravel(), "B_fft": Bf.ravel(), "N": np.repeat(N_run.astype(np.int64), n_ord),
        "readings": np.full(R * n_ord, m, dtype=np.int64), "closure_arcsec": np.repeat(closure, n_ord)})
