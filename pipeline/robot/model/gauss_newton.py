"""The fit's step: one damped Gauss-Newton loop over two evaluators.

:func:`damped_gauss_newton` is Eq. 6 of the paper iterated, ``Delta X = (J^T J)^-1 J^T Delta P``, on the
column-scaled Jacobian (minimum-norm steps), with Levenberg damping only when a full step does not lower
the cost: the damping grows tenfold until a step does (from 1e-3 of the largest curvature) and falls
tenfold after each success, to 0 (a plain Gauss-Newton step again). Converged when a full step would
change the residuals by ``||dF||^2 <= GN_PHI`` (or a ``GAIN_REL_CONVERGED`` fraction of ``||F||^2``): the
improved L-M's test (:mod:`pipeline.robot.model.lm`). Step halving alone stopped at its iteration limit
on a real UR10, worse than the start.

The loop sees the problem through an evaluator:

* :class:`DenseSteps`: the dense Jacobian of the fitted directions and its SVD (a few dozen directions);
* :class:`NormalSteps`: the normal equations built from the sparse Jacobian
  (:data:`pipeline.robot.model.normal.GRAM_MIN_K`): ``Jf^T Jf = V diag(sv^2) V^T`` gives the SVD's sv and
  V, and ``U^T F = diag(1/sv) V^T Jf^T F``; solved by the Cholesky factor where well-conditioned.

:func:`steps_without` is the same step taken on a subset of the poses from a fit's solution (the
wild-point search's and the folds' refits). Every solver returns an :class:`~pipeline.robot.model.lm.LMResult`.
"""

from __future__ import annotations

import time

import numpy as np

from . import normal
from .lm import GAIN_REL_CONVERGED, LMResult

#: Gauss-Newton has converged when a full step would change the residuals by ||dF||^2 <= GN_PHI (mm^2),
#: the improved L-M's phi (pipeline.robot.model.lm)
GN_PHI = 1e-5
#: Failed damped trials of one iteration before the loop stops (the damping then 1e16 x its start)
MAX_DAMPED_TRIALS = 16


class DenseSteps:
    """Steps on the dense Jacobian of the fitted directions.

    Parameters
    ----------
    fun_and_jac : callable z -> (F (m,), Jf (m, k))
        The residual (data rows, then ``n_penalty`` penalty rows) and its Jacobian.
    F, Jf : ndarray, shape (m,) and (m, k)
        Their values at the start.
    n_penalty : int
        Penalty rows at the end of F (left out of the hat matrix's trace, :attr:`dof`).
    """

    def __init__(self, fun_and_jac, F, Jf, n_penalty: int):
        self.fun_and_jac, self.F, self.Jf, self.n_penalty = fun_and_jac, F, Jf, n_penalty
        self.scale = np.zeros(Jf.shape[1])
        self.dof = float("nan")

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.F)) and np.all(np.isfinite(self.Jf)))

    def linearise(self):
        """The Gauss-Newton gain ``||U^T F||^2`` (mm^2) and the largest curvature, at the current point."""
        self.scale = np.maximum(self.scale, np.linalg.norm(self.Jf, axis=0))
        self.sc = sc = np.where(self.scale > 0, self.scale, 1.0)
        U, sv, Vt = np.linalg.svd(self.Jf / sc, full_matrices=False)
        r = int(np.sum(sv > normal.SINGULAR_RTOL * sv[0])) if sv.size else 0
        U, self.sv, self.Vt = U[:, :r], sv[:r], Vt[:r]
        self.c = U.T @ self.F
        nd = self.F.size - self.n_penalty
        self.dof = float(np.sum(U[:nd] ** 2))
        return float(self.c @ self.c), (float(self.sv[0] ** 2) if self.sv.size else 0.0)

    def step(self, lam: float) -> np.ndarray:
        sv = self.sv
        return -(self.Vt.T @ (sv / (sv**2 + lam) * self.c)) / self.sc

    def largest_curvature(self) -> float:          # never needed: linearise gives it
        raise AssertionError("the dense evaluator's largest curvature comes with its SVD")

    def move(self, z) -> np.ndarray:
        self.F, self.Jf = self.fun_and_jac(z)
        return self.F


class NormalSteps:
    """Steps on the normal equations of the fitted directions.

    Parameters
    ----------
    normal_equations : callable z -> (F (m,), Gf (k, k), gF (k,))
        The residual and the normal equations ``Jf^T Jf``, ``Jf^T F`` of the fitted directions.
    F, Gf, gF : their values at the start.
    """

    def __init__(self, normal_equations, F, Gf, gF):
        self.normal_equations, self.F, self.Gf, self.gF = normal_equations, F, Gf, gF
        self.scale = np.zeros(Gf.shape[0])
        self.hat = None

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.F)) and np.all(np.isfinite(self.Gf)))

    def linearise(self):
        """The gain and the largest curvature (None where the Cholesky factor solved the step: found only
        when a step needs damping)."""
        self.scale = np.maximum(self.scale, np.sqrt(np.maximum(np.diag(self.Gf), 0.0)))
        self.sc = sc = np.where(self.scale > 0, self.scale, 1.0)
        self.As, self.gs = As, gs = self.Gf / np.outer(sc, sc), self.gF / sc
        self.factor = normal.well_conditioned_cholesky(As)
        top = None
        if self.factor is not None:
            # every direction kept (as the eigen-solution would keep them): solved by the factor
            self.y = normal.cholesky_solve(self.factor, gs)
            gain = float(gs @ self.y)
            self.hat = (self.Gf, sc, self.factor, None, None)
        else:
            self.sv, self.Vt = normal.singular_directions(As, normal.SINGULAR_RTOL)
            self.c = (self.Vt @ gs) / self.sv
            gain = float(self.c @ self.c)
            top = float(self.sv[0] ** 2) if self.sv.size else 0.0
            self.hat = (self.Gf, sc, None, self.Vt, self.sv)
        return gain, top

    def step(self, lam: float) -> np.ndarray:
        if self.factor is None:
            sv = self.sv
            return -(self.Vt.T @ (sv / (sv**2 + lam) * self.c)) / self.sc
        if lam == 0.0:
            return -self.y / self.sc
        return -normal.cholesky_solve(normal.damped_cholesky(self.As, lam), self.gs) / self.sc

    def largest_curvature(self) -> float:
        return normal.largest_eigenvalue(self.As)

    def move(self, z) -> np.ndarray:
        self.F, self.Gf, self.gF = self.normal_equations(z)
        return self.F

    def hat_trace(self, PtP) -> float:
        """The hat matrix's trace of the last linearisation: the data rows' share of each direction
        (the penalty rows' ``PtP`` (k, k) excluded); nan before any."""
        if self.hat is None:
            return float("nan")
        Gh, sch, fh, Vth, svh = self.hat
        Gd = (Gh - PtP) / np.outer(sch, sch)
        return (float(np.trace(normal.cholesky_solve(fh, Gd))) if fh is not None
                else float(np.sum(np.sum((Vth @ Gd) * Vth, axis=1) / svh ** 2)))


def damped_gauss_newton(steps, fun, z0, max_iter: int, moved: bool = False) -> LMResult:
    """Iterate damped Gauss-Newton steps from ``z0`` (k,).

    Parameters
    ----------
    steps : DenseSteps or NormalSteps
        The evaluator, at ``z0`` already.
    fun : callable z -> F (m,)
        The residual (mm), for the trial steps.
    max_iter : int
    moved : bool
        Whether ``z0`` counts as having left nominal (a start from a nested model's solution).

    Returns
    -------
    LMResult (``n_fev``: residual evaluations, ``n_jev``: evaluator moves).
    """
    t0 = time.perf_counter()
    xf, F = z0.copy(), steps.F
    cost = 0.5 * float(F @ F)
    lam, converged, it, nfev, njev = 0.0, False, 0, 0, 0
    reason = f"iteration limit ({max_iter}) reached"
    for it in range(1, max_iter + 1):
        if not steps.finite():
            reason = "non-finite residual or Jacobian"
            break
        gain, top = steps.linearise()
        stationary = gain <= max(GN_PHI, GAIN_REL_CONVERGED * 2.0 * cost)
        if gain <= 1e-12 * 2.0 * cost:  # the linear model predicts no decrease beyond rounding
            converged = moved or cost == 0.0
            reason = (f"a Gauss-Newton step would change F by ||dF||^2 = {gain:.2g} mm^2 (rounding)"
                      if converged else "the start is already stationary (never left it)")
            break
        for _ in range(MAX_DAMPED_TRIALS):
            step = steps.step(lam)
            F_try = fun(xf + step)
            nfev += 1
            cost_try = 0.5 * float(F_try @ F_try)
            if np.isfinite(cost_try) and cost_try < cost:
                break
            top = top if top is not None else steps.largest_curvature()
            lam = max(10.0 * lam, 1e-3 * top)
        else:
            converged = moved and stationary
            reason = (f"no damped step lowers the cost; a Gauss-Newton step would change F by ||dF||^2 = "
                      f"{gain:.2g} mm^2" + (f" <= {GN_PHI:g}" if stationary else " (not stationary)"))
            break
        if lam > 0.0:
            top = top if top is not None else steps.largest_curvature()
        lam = lam / 10.0 if lam > 0.0 and lam > 1e-9 * top else 0.0
        xf = xf + step
        moved = True
        F = steps.move(xf)
        njev += 1
        cost = 0.5 * float(F @ F)
    return LMResult(xf, cost, it, nfev, njev, bool(converged), time.perf_counter() - t0, [], reason)


def steps_without(design, B, Pen, x, rows, sparse: bool, measured_mm, max_steps: int = 10):
    """Gauss-Newton steps from the parameters ``x`` (p,) in the directions ``B`` (p, k) with the penalty rows
    ``Pen`` (m, p), the residual rows weighed by ``rows`` (0: a pose left out, 1: kept): the parameters
    reached (p,) and the number of directions the last step's normal equations determined.

    The steps end when one would change the residuals by ``||dF||^2 <= GN_PHI`` (that step taken) or by
    rounding. ``sparse``: on the sparse Jacobian's normal equations (a fit of many parameters), else on the
    dense Jacobian; ``measured_mm`` (n, 3) the positions the design's residual is taken from."""
    import scipy.sparse

    d = design
    PB = Pen @ B
    PtP = PB.T @ PB
    rank = None
    for _ in range(max_steps):
        if not sparse:
            F, J = d.residual_and_jacobian(x)
            J = J * rows[:, None]
            H, g = J.T @ J, J.T @ (F * rows)
        else:
            if d.oriented:
                _, F, J = d.residual_and_sparse_jacobian(x)
            else:
                P, J = d.predict_and_sparse_jacobian(x)
                F = (P - np.asarray(measured_mm, float)).ravel()
            # the poses left out weigh 0 (their rows zeroed: no row slicing of the CSC matrix)
            J = scipy.sparse.csc_matrix((J.data * rows[J.indices], J.indices, J.indptr), shape=J.shape)
            H, g = normal.gram(J, F * rows)
        dz, gain, rank = normal.scaled_min_norm_step(B.T @ H @ B + PtP, B.T @ g + PB.T @ (Pen @ x), with_rank=True)
        cost2 = float((F * rows) @ F) + float((Pen @ x) @ (Pen @ x))
        if not np.isfinite(gain) or gain <= 1e-12 * cost2:
            break
        x = x + B @ dz
        if gain <= GN_PHI:
            break
    return x, rank
