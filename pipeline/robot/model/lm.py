"""The improved Levenberg-Marquardt method of the second paper (Eqs. 14-21).

The paper's steps:

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

Deviations from the printed algorithm, so that it works on real data and says when it does
not (issue #10: on a real UR10 with 5 mm initial error the run "converged" by the step-8 test
at the start's cost, 120 x scipy's, after v_k had climbed to 1e17. Two causes: the problem
handed to it was broken - the rank reduction scaled Jacobian columns that are zero up to
rounding (rotations about the axis the probe sits on) to unit norm, so every step moved those
coefficients by 1e9 rad and no linear model held; see tests/test_solvers.py - and the method
had no defence: an unscaled ``mu_k = v_k ||F||^2`` of 54,000 mm^2 against a J^T J diagonal of
40 ... 1e-5, and a stopping test that a crawl passes. With the reduction repaired the paper's
method reaches scipy's cost on that series in 75 iterations; as below, in 4):

* **Scaling (Marquardt / scipy's ``x_scale='jac'``).** The steps are solved for the scaled
  parameters D x, D = diag of the Jacobian's column norms (running maximum over the iterations,
  as MINPACK does; a zero column keeps scale 1), so every parameter enters J^T J with unit
  diagonal whatever its unit (mm, mrad, Chebyshev coefficient) and lever arm. In D-scaled
  variables the paper's ``(J^T J + mu I)`` is Marquardt's ``(J^T J + mu diag(J^T J))``.
* **Dimensionless damping.** mu_k = v_k * (||F(x_k)||^2 / ||F(x_0)||^2) * max diag(Js^T Js)
  (Js the D-scaled Jacobian): the paper's ``||F||^2`` factor (damping that falls as the
  residual falls, Fan's choice) measured relative to the start, so that mu has the units of
  J^T J and v is a pure number. With v_1 = 1 the first step is damped by the largest curvature
  (between a gradient and a Gauss-Newton step, a cautious start far from the solution); v then
  halves on every very successful step (4 x on a poor one) down to m = 1e-6. In the Chebyshev
  stage's reduced problem (truncated SVD) the scaled J^T J is the identity at the start, so every
  kept direction sees the same damping and the runs take 3-4 iterations on the fixture and on
  the real UR10, where the paper's unscaled mu_k took 16 to 75 (or never arrived).
* **Convergence is earned, not declared.** Step 8's test is applied after accepted steps only
  (a rejected step leaves F unchanged and would "converge" at once), and it ends the run as
  *converged* only when the point is also stationary: step 8's test must also hold for the
  undamped (Gauss-Newton) step the linear model predicts, ``||P_J F||^2 <= phi`` (P_J: projection
  on the range of J; or <= :data:`GAIN_REL_CONVERGED` ||F||^2 when the cost is huge). A damped
  crawl passes step 8 with the tiny step it took but not this test, and continues.
  A run that ends at ``max_iter``, whose damping runs away (v_k > :data:`V_MAX`: no step can
  lower the cost), or that never accepted a step (never left its start) is *not converged*; the
  result says why (``reason``).
* A rejected step keeps J and its factor's inputs (x did not move): no new Jacobian.
* A trial point with a non-finite residual is a rejected step (r_k = -inf).
"""

from __future__ import annotations

import ctypes
import glob
import os
import time
from dataclasses import dataclass, field

import numpy as np
import scipy

from . import normal


#: A run counts as converged only where a full Gauss-Newton step would change the residual by
#: ||dF||^2 <= phi (the paper's own test, applied to the undamped step the linear model predicts:
#: a damped crawl passes the paper's test with the step it took, not this one) or by at most this
#: fraction of ||F||^2 (for problems whose cost is so large that phi is below rounding).
GAIN_REL_CONVERGED = 1e-6
#: Damping factor beyond which no step can lower the cost (mu is then 1e12 x the largest
#: curvature): the run stops, not converged unless the point is stationary.
V_MAX = 1e12


@dataclass
class LMResult:
    x: np.ndarray
    cost: float                 # 0.5 ||F||^2 at x
    n_iter: int
    n_fev: int
    n_jev: int
    converged: bool
    seconds: float
    history: list = field(default_factory=list)   # per iteration: cost, r_k, v_k, mu_k, accepted
    reason: str = ""            # why the run stopped (and why it is or is not converged)


def gauss_newton_gain(F, J) -> float:
    """||F(x) - F_lin(x + d_GN)||^2 = ||P_J F||^2: how much a full Gauss-Newton step would change the
    residual by the linear model (P_J: projection on the range of J; 0 at a least-squares optimum,
    whatever the units or scaling of the parameters). Units of ||F||^2."""
    F = np.asarray(F, float)
    if F.size == 0 or J.size == 0:
        return 0.0
    nc = np.linalg.norm(J, axis=0)
    Js = J[:, nc > 0] / nc[nc > 0]
    if Js.shape[1] == 0:
        return 0.0
    U, sv, _ = np.linalg.svd(Js, full_matrices=False)
    U = U[:, sv > 1e-12 * sv[0]]
    c = U.T @ F
    return float(c @ c)


def is_stationary(F, J, phi) -> tuple[bool, float]:
    """(converged?, Gauss-Newton gain): the gain <= phi or <= GAIN_REL_CONVERGED ||F||^2."""
    gain = gauss_newton_gain(F, J)
    return gain <= max(phi, GAIN_REL_CONVERGED * float(np.asarray(F) @ np.asarray(F))), gain


def improved_lm(fun, jac, x0, *, v1=1.0, m=1e-6, p0=1e-4, p1=0.25, p2=0.75, phi=1e-5, max_iter=100,
                increase=4.0, fun_and_jac=None, scale=True) -> LMResult:
    """Minimise ||F(x)||^2 with the paper's improved L-M (see module docstring).

    Parameters
    ----------
    fun : callable x -> F, shape (N,)
    jac : callable x -> J, shape (N, p)
    x0 : ndarray, shape (p,)
    v1, m, p0, p1, p2, phi, max_iter : the paper's constants (0 < p0 < p1 < p2 < 1, v1 > m > 0);
        v is dimensionless here: mu_k = v_k (||F_k||^2 / ||F_0||^2) max diag(Js^T Js).
    increase : float
        Factor on v when r_k < P1 (4; the paper prints 2).
    fun_and_jac : callable x -> (F, J), optional
        Both at once (cheaper when F comes with J).
    scale : bool
        Solve for the column-scaled parameters (default; False: the paper's plain identity).

    Returns
    -------
    LMResult; ``converged`` is False when the run hit ``max_iter``, stalled (v_k > V_MAX) or
    never accepted a step; ``reason`` says which.
    """
    _check_constants(v1, m, p0, p1, p2, max_iter)
    t0 = time.perf_counter()
    x, v = np.array(x0, float), float(v1)
    nfev = njev = 0

    def evaluate(at):
        nonlocal nfev, njev
        Fa, Ja = fun_and_jac(at) if fun_and_jac is not None else (fun(at), jac(at))
        nfev, njev = nfev + 1, njev + 1
        return np.asarray(Fa, float), np.asarray(Ja, float)

    def done(converged, reason, k):
        return LMResult(x, 0.5 * float(F @ F), k, nfev, njev, bool(converged), time.perf_counter() - t0, history,
                        reason)

    history = []
    F, J = evaluate(x)
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(J))):
        return done(False, "non-finite residual or Jacobian at the start", 0)
    FF0 = float(F @ F)
    if FF0 == 0.0:
        return done(True, "zero residual at the start", 0)
    D = np.zeros(x.size)
    moved, converged, k, new_point = False, False, 0, True
    reason = f"iteration limit ({int(max_iter)}) reached"
    for k in range(1, int(max_iter) + 1):
        if new_point:
            FF = float(F @ F)
            D, Ds, Js, A0, curvature = _scaled(J, D, scale)
            new_point = False
        mu = v * (FF / FF0) * curvature if scale else v * FF
        s, Fs, pred = _three_steps(fun, x, F, J, Js, Ds, A0, mu)
        nfev += 3
        r, v = _ratio_and_damping(FF - Fs @ Fs, pred, v, p1, p2, increase, m)
        accepted = bool(r > p0)
        history.append({"iteration": k, "cost": 0.5 * float(Fs @ Fs if accepted else FF), "r": float(r),
                        "v": v, "mu": float(mu), "accepted": accepted})
        if accepted:
            change = float((Fs - F) @ (Fs - F))
            x = x + s
            F, J = evaluate(x)
            new_point = moved = True
            if not (np.all(np.isfinite(F)) and np.all(np.isfinite(J))):
                reason = "non-finite residual or Jacobian"
                break
            if change <= phi:
                ok, gain = is_stationary(F, J, phi)
                if ok:
                    converged = True
                    reason = f"||dF||^2 = {change:.2g} <= phi and a Gauss-Newton step would change F by {gain:.2g}"
                    break
        if v > V_MAX:
            converged, reason = _stalled(F, J, phi, moved)
            break
    if not moved:
        converged, reason = False, f"never left the start (no step accepted in {k} iteration(s)): {reason}"
    return done(converged, reason, k)


def _check_constants(v1, m, p0, p1, p2, max_iter) -> None:
    if not (0 < p0 < p1 < p2 < 1) or not (v1 > m > 0):
        raise ValueError("the improved L-M needs 0 < P0 < P1 < P2 < 1 and v1 > m > 0")
    if int(max_iter) < 1:
        raise ValueError("the improved L-M needs max_iter >= 1")


def _scaled(J, D, scale: bool):
    """At a new point: the column scale D (p,) (the largest column norms so far) and its divisor Ds, the
    scaled Jacobian Js (N, p), ``Js^T Js`` (p, p) and its largest diagonal (the damping's yardstick)."""
    if scale:
        D = np.maximum(D, np.linalg.norm(J, axis=0))
        Ds = np.where(D > 0, D, 1.0)
    else:
        Ds = np.ones(J.shape[1])
    Js = J / Ds
    A0 = Js.T @ Js
    return D, Ds, Js, A0, float(np.max(np.diag(A0), initial=0.0)) or 1.0


def _three_steps(fun, x, F, J, Js, Ds, A0, mu):
    """Eqs. 14-17 and the prediction of Eq. 19: the three steps of one factorised matrix ``A0 + mu I`` from
    x (F its residual, J its Jacobian), their sum s (p,), F(x + s) (N,) and the decrease the linear model
    predicts."""
    cho = normal.levenberg_cholesky(A0, mu)

    def solve(Fa):
        return -normal.cholesky_solve(cho, Js.T @ Fa) / Ds

    d1 = solve(F)
    y = x + d1
    Fy = np.asarray(fun(y), float)
    d2 = solve(Fy) if np.all(np.isfinite(Fy)) else np.full_like(d1, np.nan)
    z = y + d2
    Fz = np.asarray(fun(z), float) if np.all(np.isfinite(z)) else np.full_like(F, np.nan)
    d3 = solve(Fz) if np.all(np.isfinite(Fz)) else np.full_like(d1, np.nan)
    s = d1 + d2 + d3
    Fs = np.asarray(fun(x + s), float) if np.all(np.isfinite(s)) else np.full_like(F, np.nan)

    def lin(Fa, d):
        r = Fa + J @ d
        return Fa @ Fa - r @ r

    return s, Fs, lin(F, d1) + lin(Fy, d2) + lin(Fz, d3)


def _ratio_and_damping(ared, pred, v, p1, p2, increase, m):
    """Eqs. 18-21: the ratio r_k of the actual to the predicted decrease (-inf where it is not a number
    or nothing was predicted), and the next damping factor v."""
    r = ared / pred if (np.isfinite(ared) and np.isfinite(pred) and pred > 0) else -np.inf
    if r < p1:
        v = increase * v
    elif r > p2:
        v = max(v / 2.0, m)
    return r, v


def _stalled(F, J, phi, moved: bool) -> tuple[bool, str]:
    """Whether a run whose damping went beyond V_MAX ended converged, and why it ended."""
    ok, gain = is_stationary(F, J, phi)
    return moved and ok, (f"no step lowers the cost (v_k > {V_MAX:g}); a Gauss-Newton step would change F by "
                          f"||dF||^2 = {gain:.2g}" + ("" if ok else " > phi (not stationary)"))


LM_OPTIONS = ("v1", "m", "p0", "p1", "p2", "phi", "max_iter", "increase", "scale")


def lm_options_problem(options: dict) -> tuple[str, str] | None:
    """``(key, what is wrong)`` with a set of improved L-M constants (a spec's ``[model.lm]``), or None."""
    for key in options:
        if key not in LM_OPTIONS:
            return key, f"unknown improved L-M constant {key!r} (known: {', '.join(LM_OPTIONS)})"
    number = {k: v for k, v in options.items() if k != "scale"}
    for key, value in number.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            return key, f"{key} must be a finite number, found {value!r}"
    o = {"v1": 1.0, "m": 1e-6, "p0": 1e-4, "p1": 0.25, "p2": 0.75, "phi": 1e-5, "max_iter": 100, "increase": 4.0,
         **number}
    if not (0 < o["p0"] < o["p1"] < o["p2"] < 1):
        return "p0", "the improved L-M needs 0 < p0 < p1 < p2 < 1"
    if not (o["v1"] > o["m"] > 0):
        return "v1", "the improved L-M needs v1 > m > 0"
    if o["max_iter"] != int(o["max_iter"]) or o["max_iter"] < 1:
        return "max_iter", f"max_iter must be a whole number >= 1, found {o['max_iter']!r}"
    if not o["phi"] > 0:
        return "phi", "phi must be > 0 (mm^2)"
    if not o["increase"] > 1:
        return "increase", "increase must be > 1"
    return None


def scipy_least_squares(fun, jac, x0, phi=1e-5, **kw) -> LMResult:
    """Cross-check with ``scipy.optimize.least_squares`` (trust-region reflective, exact solves).

    ``converged`` is scipy's ``success`` (False when it stopped at ``max_nfev``), and the point
    must be stationary as :func:`improved_lm` requires (:func:`is_stationary`, phi = 1e-5) and
    away from the start.
    """
    # imported here, not at the top: scipy.optimize takes 0.35 s to import (measured with
    # `python -X importtime`), which every robot stage importing this module would pay, and
    # only the Chebyshev stage's cross-check uses it
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    opts = dict(method="trf", tr_solver="exact", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200)
    opts.update(kw)
    x0 = np.asarray(x0, float)
    res = least_squares(fun, x0, jac=jac, **opts)
    ok, gain = is_stationary(res.fun, np.asarray(res.jac, float), phi)
    converged = bool(res.success) and ok and (res.cost == 0.0 or not np.array_equal(res.x, x0))
    reason = f"{res.message} (a Gauss-Newton step would change F by ||dF||^2 = {gain:.2g})"
    return LMResult(res.x, float(res.cost), int(res.nfev), int(res.nfev), int(res.njev or 0), converged,
                    time.perf_counter() - t0, [], reason)


def limit_blas_threads(n: int = 1) -> bool:
    """Ask the OpenBLAS libraries bundled with numpy and scipy to use ``n`` threads.

    The problems here are small (a few hundred parameters at most); on a busy machine
    OpenBLAS's spinning worker threads make a 144 x 144 Cholesky 100 times slower than
    one thread does. Called at the edges (CLI, benchmark, tests); best effort, returns
    whether a library was found.
    """
    found = False
    for pkg, mod in (("numpy", np), ("scipy", scipy)):
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
