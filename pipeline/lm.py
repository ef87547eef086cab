"""The improved Levenberg-Marquardt method of the second paper (Eqs. 14-21).

The paper's steps, implemented as written:

1. k = 1, convergence accuracy phi = 1e-5, factor v_1, parameters m, P0 < P1 < P2 with
   0 < P0 < P1 < P2 < 1 and v_1 > m > 0.
2. Jacobian J(x_k) and error F(x_k) (Eq. 13).
3. mu_k = v_k ||F(x_k)||^2, d_k1 = -(J^T J + mu_k I)^-1 J^T F(x_k)            (Eq. 14)
4. y_k = x_k + d_k1, d_k2 = -(J^T J + mu_k I)^-1 J^T F(y_k)                  (Eq. 15)
   z_k = y_k + d_k2, d_k3 = -(J^T J + mu_k I)^-1 J^T F(z_k)                  (Eq. 16)
   (one matrix, factorised once, for the three steps: J is not re-evaluated)
5. s_k = d_k1 + d_k2 + d_k3                                                   (Eq. 17)
6. r_k = Ared_k / Pred_k                                                      (Eqs. 18-19)
7. x_{k+1} = x_k + s_k if r_k > P0, else x_k                                  (Eq. 20)
   v_{k+1} = 4 v_k if r_k < P1; v_k if P1 <= r_k <= P2; max(v_k / 2, m) if r_k > P2   (Eq. 21)
8. stop when ||F(x_{k+1}) - F(x_k)||^2 <= phi or k = 100.

Reconstructions (the printed paper lacks Eqs. 18-19 and has a typo in Eq. 21):

* Eqs. 18-19 follow the multi-step L-M family of the paper's reference [22] (Fan's
  modified L-M with an approximate Jacobian reused for extra steps)::

      Ared_k = ||F(x_k)||^2 - ||F(x_k + s_k)||^2
      Pred_k = ||F(x_k)||^2 - ||F(x_k) + J d_k1||^2
             + ||F(y_k)||^2 - ||F(y_k) + J d_k2||^2
             + ||F(z_k)||^2 - ||F(z_k) + J d_k3||^2

* Eq. 21 prints ``r_k > P2`` for both the first and the third case; the first case must be
  ``r_k < P1`` (a poor step increases the damping). We use 4 v_k there (the family's usual
  choice; the paper prints 2 v_k) - the factor is an option.
* Step 8's test is only meaningful after an accepted step (a rejected step leaves F
  unchanged and would "converge" at once); we test it after accepted steps only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg


@dataclass
class LMResult:
    x: np.ndarray
    cost: float                 # 0.5 ||F||^2 at x
    n_iter: int
    n_fev: int
    n_jev: int
    converged: bool
    seconds: float
    history: list = field(default_factory=list)   # per iteration: cost, r_k, v_k, accepted


def improved_lm(fun, jac, x0, *, v1=1.0, m=1e-6, p0=1e-4, p1=0.25, p2=0.75, phi=1e-5, max_iter=100,
                increase=4.0, fun_and_jac=None) -> LMResult:
    """Minimise ||F(x)||^2 with the paper's improved L-M (see module docstring).

    Parameters
    ----------
    fun : callable x -> F, shape (N,)
    jac : callable x -> J, shape (N, p)
    x0 : ndarray, shape (p,)
    v1, m, p0, p1, p2, phi, max_iter : the paper's constants (0 < p0 < p1 < p2 < 1, v1 > m > 0)
    increase : float
        Factor on v when r_k < P1 (4; the paper prints 2).
    fun_and_jac : callable x -> (F, J), optional
        Both at once (cheaper when F comes with J).
    """
    if not (0 < p0 < p1 < p2 < 1) or not (v1 > m > 0):
        raise ValueError("the improved L-M needs 0 < P0 < P1 < P2 < 1 and v1 > m > 0")
    t0 = time.perf_counter()
    x = np.array(x0, float)
    v = float(v1)
    nfev = njev = 0
    F = None
    history = []
    converged = False
    k = 0
    for k in range(1, max_iter + 1):
        if fun_and_jac is not None:
            F, J = fun_and_jac(x)
            nfev += 1
        else:
            if F is None:
                F = fun(x)
                nfev += 1
            J = jac(x)
        njev += 1
        FF = F @ F
        mu = v * FF
        A = J.T @ J
        A[np.diag_indices_from(A)] += mu
        cho = scipy.linalg.cho_factor(A, check_finite=False)
        d1 = -scipy.linalg.cho_solve(cho, J.T @ F, check_finite=False)
        y = x + d1
        Fy = fun(y)
        d2 = -scipy.linalg.cho_solve(cho, J.T @ Fy, check_finite=False)
        z = y + d2
        Fz = fun(z)
        d3 = -scipy.linalg.cho_solve(cho, J.T @ Fz, check_finite=False)
        s = d1 + d2 + d3
        Fs = fun(x + s)
        nfev += 3

        def lin(Fa, d):
            r = Fa + J @ d
            return Fa @ Fa - r @ r

        ared = FF - Fs @ Fs
        pred = lin(F, d1) + lin(Fy, d2) + lin(Fz, d3)
        r = ared / pred if pred > 0 else -np.inf
        accepted = r > p0
        if r < p1:
            v = increase * v
        elif r > p2:
            v = max(v / 2.0, m)
        history.append({"iteration": k, "cost": 0.5 * float(Fs @ Fs if accepted else FF), "r": float(r),
                        "v": v, "mu": float(mu), "accepted": bool(accepted)})
        if accepted:
            change = (Fs - F) @ (Fs - F)
            x, F = x + s, Fs
            if change <= phi:
                converged = True
                break
    F = F if F is not None else fun(x)
    return LMResult(x, 0.5 * float(F @ F), k, nfev, njev, converged, time.perf_counter() - t0, history)


def scipy_least_squares(fun, jac, x0, **kw) -> LMResult:
    """Cross-check with ``scipy.optimize.least_squares`` (trust-region reflective, exact solves)."""
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    opts = dict(method="trf", tr_solver="exact", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200)
    opts.update(kw)
    res = least_squares(fun, np.asarray(x0, float), jac=jac, **opts)
    return LMResult(res.x, float(res.cost), int(res.nfev), int(res.nfev), int(res.njev or 0), bool(res.success),
                    time.perf_counter() - t0, [])


def limit_blas_threads(n: int = 1) -> bool:
    """Ask the OpenBLAS libraries bundled with numpy and scipy to use ``n`` threads.

    The problems here are small (a few hundred parameters at most); on a busy machine
    OpenBLAS's spinning worker threads make a 144 x 144 Cholesky 100 times slower than
    one thread does. Called at the edges (CLI, benchmark, tests); best effort, returns
    whether a library was found.
    """
    import ctypes
    import glob
    import os

    found = False
    for pkg in ("numpy", "scipy"):
        try:
            mod = __import__(pkg)
        except ImportError:  # pragma: no cover
            continue
        libdir = os.path.join(os.path.dirname(os.path.dirname(mod.__file__)), f"{pkg}.libs")
        for path in glob.glob(os.path.join(libdir, "libscipy_openblas*.so*")):
            try:
                lib = ctypes.CDLL(path)
            except OSError:  # pragma: no cover
                continue
            for sym in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads"):
                fn = getattr(lib, sym, None)
                if fn is not None:
                    fn(ctypes.c_int(n))
                    found = True
                    break
    return found
