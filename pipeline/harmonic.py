"""Stage ``harmonic``: per-run Fourier coefficients of the angle error (paper 1, Eqs. 1-2).

Convention: error(theta) = A_0 + sum_i A_i cos(i theta) + B_i sin(i theta)
                         = C_0 + sum_i C_i sin(i theta + phi_i),
with C_i = hypot(A_i, B_i), phi_i = atan2(A_i, B_i) (degrees), C_0 = A_0 (signed).

Two estimators: least squares (any angles) and FFT (angles on an even grid). On even
data they agree to rounding. Aliasing (Eqs. 3-4) is in :mod:`pipeline.aliasing`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .aliasing import check_orders


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
    th = np.deg2rad(np.asarray(theta_deg, float))
    cols = [np.ones_like(th)]
    pos = [i for i in orders if i != 0]
    for i in pos:
        cols += [np.cos(i * th), np.sin(i * th)]
    X = np.column_stack(cols)
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
    theta0_deg : float, deg
        Angle of the first reading.

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


def even_grid(theta_deg, tol_deg: float) -> tuple[bool, float, int]:
    """Whether angles lie on an even grid of one turn (closing repeat ignored).

    Returns (is_even, theta0_deg, N) where N is the number of distinct grid angles.
    """
    th = np.asarray(theta_deg, float)
    base = th[0]
    rel = np.mod(th - base, 360.0)
    rel[rel > 360.0 - tol_deg] -= 360.0
    distinct = np.unique(np.round(rel / max(tol_deg, 1e-9)))
    N = distinct.size
    if N < 3:
        return False, base, N
    pitch = 360.0 / N
    k = np.round(rel / pitch)
    ok = np.all(np.abs(rel - k * pitch) <= tol_deg) and np.unique(np.mod(k, N)).size == N
    return bool(ok), base, N


def analyse_runs(frame: pd.DataFrame, n_max: int | None = None, grid_tol_deg: float = 0.05) -> pd.DataFrame:
    """Per-run harmonic coefficients by LSQ and, where the angles are even, FFT.

    Parameters
    ----------
    frame : DataFrame
        Ingested encoder readings (``run``, ``step``, ``theta_deg``, ``error_arcsec``).
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
    """
    rows = []
    for run, g in frame.groupby("run", sort=True):
        g = g.sort_values("step")
        th = g["theta_deg"].to_numpy()
        y = g["error_arcsec"].to_numpy()
        is_even, theta0, N = even_grid(th, grid_tol_deg)
        nm = (N - 1) // 2 if n_max is None else int(n_max)
        check_orders([nm], N)
        orders = list(range(nm + 1))
        A, B = lsq_coefficients(th, y, orders)
        C, phi = amplitude_phase(A, B)
        # closure: readings that come back to the first angle measure the drift within the run
        back = np.abs(((th - th[0] + 180.0) % 360.0) - 180.0) < grid_tol_deg
        back[0] = False
        closure = float(y[back][-1] - y[0]) if back.any() else np.nan
        Af = Bf = np.full(len(orders), np.nan)
        one_way = "direction" not in g or bool((g["direction"] > 0).all())
        if is_even and one_way:
            first = ~back | (np.arange(th.size) == 0)
            rel = np.mod(th[first] - theta0 + grid_tol_deg, 360.0) - grid_tol_deg
            order_idx = np.argsort(rel)
            if first.sum() == N:
                Af, Bf = fft_coefficients(y[first][order_idx], nm, theta0)
        for j, i in enumerate(orders):
            rows.append({"run": int(run), "order": i, "A": A[j], "B": B[j], "C": C[j] if i else A[j],
                         "phi_deg": phi[j], "A_fft": Af[j], "B_fft": Bf[j], "N": N, "readings": int(th.size),
                         "closure_arcsec": closure})
    return pd.DataFrame(rows)
