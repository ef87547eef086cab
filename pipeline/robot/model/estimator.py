"""Robot error models: one generic nonlinear least-squares fit over a sum of effects.

:class:`RobotErrorModel` is the estimator. Given effects (``pipeline.robot.arm.effects``) it
predicts the SMR position as the forward kinematics of the error model (``pipeline.robot``)
at ``Q0 + sum_p x_p basis_p`` and fits ``x`` to tracker positions (and a 6-DoF probe's orientations).
A fit reads as problem -> directions -> weighting -> solve -> judge:

* the problem: :class:`~pipeline.robot.model.design.Design` (the effect Jacobian) and the effects'
  penalty rows at nominal (:meth:`RobotErrorModel.identification`);
* the directions: :mod:`pipeline.robot.model.identify` (which parameters the poses determine; what they
  cannot see held nearest the nominal robot; ``x = B z``);
* the weighting: :mod:`pipeline.robot.model.weighting` (variance components, 6-DoF campaigns);
* the solve: ``solver="gauss-newton"`` (:mod:`pipeline.robot.model.gauss_newton`, Eq. 6 of the paper
  iterated), ``"lm"`` (the paper's improved Levenberg-Marquardt, :mod:`pipeline.robot.model.lm`) or
  ``"scipy"`` (``scipy.optimize.least_squares``, a cross-check);
* the judgement: :mod:`pipeline.robot.model.plausibility`.

The MDH calibration stage (:func:`calibrate_mdh`) is this estimator with the ``geometry``
effect on the ``sample`` poses. docs/fitting-core.md gives the invariants.
"""

from __future__ import annotations

import copy
import time

import numpy as np

from ...core.se3 import angle_arcsec, orientation_errors
from . import gauss_newton, identify, lm, normal, plausibility, weighting
# lm's solvers are looked up at call time as lm.improved_lm (tests wrap them)
from ..arm.effects import REFERENCE_TEMPERATURE_C, Base, Geometry, RobotData, RobotEffect
from ..arm.kinematics import Robot
from .design import Design


class RobotErrorModel:
    """Estimator of a robot error model made of effects (scikit-learn style).

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
    solver : {"gauss-newton", "lm", "scipy"}
    identifiability : bool
        Fix parameters beyond the numerical rank at 0 (and report them).
    lm_options : dict, optional
        Constants of the improved L-M (see :func:`pipeline.robot.model.lm.improved_lm`).
    max_iter : int
        Gauss-Newton iterations at most.
    weak_tol : float or None
        Parameters whose determination (distance of their scaled Jacobian column from the span
        of the other kept ones, relative to the largest singular value) is below it stay at
        nominal, the least determined first (see :data:`~pipeline.robot.model.identify.WEAK_TOL`);
        None keeps every parameter of the numerical rank. Only with ``reduction="fix"``.
    rank_tol : float
        Relative singular value (column-scaled Jacobian) below which a direction counts as
        not identifiable.
    start : dict, optional
        Parameter name -> value (internal units) to start the solver from (the solution of a model
        nested in this one, :func:`pipeline.robot.model.estimate.fit_effects`); default: nominal (0).
    orientation : bool
        On a campaign with a 6-DoF probe's orientations (``RobotData.measured_R``), fit them too
        (contract section 13); False fits the positions alone.
    orientation_weight : float or None
        Weight of the orientation rows, mm per mrad; None: estimated by variance components
        (:data:`~pipeline.robot.model.weighting.VCE_RTOL`), stated in ``weighting_``.
    weight_start : float or None
        Where the variance components start (mm per mrad) when ``orientation_weight`` is None: the
        weight a fit of the same model on nearly the same poses ended with; default: the stated
        uncertainties, else :data:`~pipeline.robot.model.weighting.START_WEIGHT_MM_PER_MRAD`
        (:func:`~pipeline.robot.model.weighting.start_weight`).
    reduction : {"fix", "svd"}
        What to do with the directions that are not identifiable: ``"fix"`` fixes the
        parameters beyond the rank at 0 (named, QR with pivoting / priority); ``"svd"``
        solves in the span of the leading right singular vectors of the column-scaled
        Jacobian (truncated SVD: the minimum-norm solution; no parameter is singled out).
    keep_designs : bool
        Keep the fit's design (its sparse layouts, its last evaluation) for a caller that goes on with
        the same poses (the wild search's and the folds' refit steps and predictions); released by
        :meth:`release_designs`.
    checks : bool
        Check the fitted model against what a real robot can be (``plausible_``, ``implausible_``: the
        parameters' bounds, its frames' deviations, the error budget). A fit used only for its
        predictions (a cross-validation fold, the wild-point detector's flexible model) skips them
        (``plausible_`` is then None).

    Attributes (after fit)
    ----------------------
    coef_ : ndarray, shape (p,), internal units (mm, mrad, ...)
    names_, units_ : parameter names, (unit, factor internal -> reported)
    identifiability_ : dict (see :func:`~pipeline.robot.model.identify.identifiability`)
    basis_ : ndarray, shape (p, k), the fitted directions (``x = B z``); penalty_ : ndarray, shape (m, p),
        the effects' penalty rows: the fit's covariance (:mod:`pipeline.robot.model.uncertainty`) lives there
    unseen_ : ndarray, shape (p, r), the directions (internal units) no measurement of the fit can see
    weight_ : float or None, the orientation rows' weight (mm per mrad) of a 6-DoF fit, None otherwise
    cost_ : float, 0.5 ||F||^2 at the solution, mm^2
    rms_mm_ : float, RMS of the 3-D position residual norms of the fitted poses
    orientation_rms_arcsec_ : float or None, RMS of the orientation errors (angles) of the fitted poses
    weighting_ : dict or None, how positions and orientations were weighed (6-DoF fits)
    dof_ : float, the effective number of parameters (trace of the hat matrix of the last Gauss-Newton
        linearisation, penalties included; Gauss-Newton only): a fit with ``dof_`` near its number of
        residuals (3 a pose) interpolates them
    n_iter_, seconds_ : iterations and wall time of the solver
    solver_result_ : LMResult (every solver's)
    implausible_, plausible_ : the judgement (:func:`pipeline.robot.model.plausibility.judge`)
    """

    def __init__(self, robot: Robot, effects, solver: str = "gauss-newton", identifiability: bool = True,
                 lm_options: dict | None = None, max_iter: int = 100, rank_tol: float = identify.RANK_TOL,
                 reduction: str = "fix", weak_tol: float | None = identify.WEAK_TOL, start: dict | None = None,
                 checks: bool = True, orientation: bool = True, orientation_weight: float | None = None,
                 weight_start: float | None = None, keep_designs: bool = False):
        self.robot = robot
        self.checks = checks
        self.start = start
        self.orientation = orientation
        self.orientation_weight = orientation_weight
        self.weight_start = weight_start
        self.effects = effects
        self.solver = solver
        self.identifiability = identifiability
        self.lm_options = lm_options
        self.max_iter = max_iter
        self.rank_tol = rank_tol
        self.reduction = reduction
        self.weak_tol = weak_tol
        self.keep_designs = keep_designs

    def design(self, data: RobotData) -> Design:
        """The :class:`Design` of this model's effects on ``data`` (the one kept, within a fit or with
        ``keep_designs``), at the fit's orientation weight."""
        memo = getattr(self, "_designs", None)
        if memo is not None and id(data) in memo and memo[id(data)][0] is data:
            # within one variance-components fit: the same poses, the same effects, another weight
            d = memo[id(data)][1]
        else:
            d = Design(self.robot, list(getattr(self, "effects_", self.effects)), data,
                       getattr(self, "_model_and_index", None))
            if memo is not None:
                memo[id(data)] = (data, d)
                d.keep_last = True
        if self.orientation and getattr(data, "measured_R", None) is not None:
            d.weight = getattr(self, "weight_", None) or self.orientation_weight or weighting.start_weight(data)[0]
        return d

    def release_designs(self) -> None:
        """Let go of the designs kept (``keep_designs``) once the caller is done with the fit's poses."""
        self._designs = None

    def identification(self, data: RobotData, sparse: bool = False):
        """The identification problem of ``data`` at the nominal parameters, as :meth:`fit` sees it.

        Prepares the effects on ``data`` (``effects_``), and returns ``(design, P, J, Pen, penalised,
        ident)``: the :class:`Design`, nominal SMR positions P (n, 3) mm, the identification Jacobian
        J (3 n, p) mm per internal unit (rows x, y, z of each pose), the effects' penalty rows Pen
        (m, p), which parameters are penalised (p,) bool, and
        :func:`~pipeline.robot.model.identify.identifiability`'s verdict (rank, condition number, the
        parameters kept and why the others are fixed) with this estimator's rank and weak-determination
        tolerances. It needs joint values only (no measurement): ``jointcal plan`` chooses poses on the
        same problem. With ``sparse`` J is a scipy.sparse matrix (CSC), for fits of many parameters
        (:data:`~pipeline.robot.model.normal.GRAM_MIN_K`).
        """
        self.effects_ = [e.prepared(self.robot, data) for e in self.effects]
        d = self.design(data)
        self._model_and_index = (d.model, d.idx)
        x = np.zeros(d.p)
        if sparse and d.oriented:
            P, _, J2 = d.residual_and_sparse_jacobian(x)
        elif sparse:
            P, J2 = d.predict_and_sparse_jacobian(x)
        else:
            P, J2 = d.jacobian_rows(x)
        Pen, penalised = identify.penalty_rows(self.robot, self.effects_, data.n, d.p)
        ident = identify.identifiability(
            J2, d.names, tol=self.rank_tol, priority=identify.priority(d.names), units=d.units,
            weak_tol=self.weak_tol if self.identifiability and self.reduction == "fix" else None, penalised=penalised)
        ident["rank_exact"] = int(np.sum(np.asarray(ident["singular_values"]) > 1e-10 * ident["singular_values"][0]))
        return d, P, J2, Pen, penalised, ident

    def solves_on_normal_equations(self, data: RobotData) -> bool:
        """Whether a fit on ``data`` is solved on normal equations: with the default reduction (parameters
        kept or fixed by name), more parameters than :data:`~pipeline.robot.model.normal.GRAM_MIN_K` and some
        of them penalised (a joint map's grid values); in the leading singular directions (``reduction="svd"``,
        a Chebyshev model's), a Jacobian of more entries than :data:`~pipeline.robot.model.normal.DENSE_SVD_MAX`."""
        if not (self.identifiability and self.solver == "gauss-newton"):
            return False
        effects = [e.prepared(self.robot, data) for e in self.effects]
        p = sum(len(e.parameter_names(self.robot)) for e in effects)
        if self.reduction == "fix":
            return p > normal.GRAM_MIN_K and any(e.penalty(self.robot, 1) is not None for e in effects)
        return self.reduction == "svd" and (6 if data.has_orientation else 3) * data.n * p > normal.DENSE_SVD_MAX

    def fit(self, data: RobotData) -> "RobotErrorModel":
        """Fit on ``data``'s measured positions (and orientations, a 6-DoF campaign); returns self.

        A 6-DoF fit without a stated ``orientation_weight`` weighs the two by variance components
        (:func:`pipeline.robot.model.weighting.variance_components`), a weight whose orientation rows cost the
        positions held out lowered (:func:`pipeline.robot.model.weighting.position_guard`); one on its positions
        alone then registers the probe's mounting from the orientations."""
        t0 = time.perf_counter()
        self.weight_ = None
        self.weighting_ = None
        if getattr(data, "measured_R", None) is None:
            if self.keep_designs:
                self._designs = {}
            self._fit_at(data)
        elif not self.orientation:
            # positions alone; a 6-DoF probe's mounting on the flange then comes from the orientations
            # with every other parameter as the positions put it (the rotation nearest all of them)
            self._fit_at(data)
            weighting.register_mounting(self, data)
            self.weighting_ = dict(weighting.POSITIONS_ONLY)
        else:
            # every weight's fit is on the same poses with the same effects: one design serves them all
            # (its sparse layouts are built once; the weight is applied where the residual is evaluated)
            self._designs = {}
            try:
                self.weighting_ = weighting.variance_components(self, data, lambda w: self._fit_at(data, w))
            finally:
                if not self.keep_designs:
                    self._designs = None
        self.seconds_ = time.perf_counter() - t0
        return self

    def _fit_at(self, data: RobotData, weight: float | None = None) -> None:
        """One fit on ``data`` at the orientation weight ``weight``: problem -> directions -> solve -> judge."""
        self.weight_ = weight
        large = self.solves_on_normal_equations(data)
        d, P, J2, Pen, _, ident = self.identification(data, sparse=large)
        meas = np.asarray(data.measured_mm, float)
        F0 = d.residual(np.zeros(d.p)) if d.oriented else (P - meas).ravel()
        H0, g0 = normal.gram(J2, F0) if large else (None, None)
        B, U = identify.fit_directions(J2, Pen, ident, d, self.reduction, self.identifiability, self.rank_tol, H0)
        self.unseen_ = d.sizes[:, None] * U
        self.basis_, self.penalty_ = B, Pen
        result = self._solve(d, B, Pen, meas, large, (P, J2, F0, H0, g0))
        self.coef_ = B @ result.x
        self.names_, self.units_ = d.names, d.units
        self.identifiability_, self.fixed_ = ident, ident["not_identifiable"]
        self.cost_, self.solver_result_ = result.cost, result
        self.n_iter_, self.converged_, self.convergence_ = result.n_iter, bool(result.converged), result.reason
        if d.oriented:
            R_, P_ = d.predict_pose(self.coef_)
            resid = P_ - meas
            self.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(orientation_errors(R_, data.measured_R))
                                                                 ** 2)))
        else:
            resid = (d.predict(self.coef_) - meas)
            self.orientation_rms_arcsec_ = None
        self.rms_mm_ = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
        self._judge(d, data)

    def _solve(self, d: Design, B, Pen, meas, large: bool, nominal) -> lm.LMResult:
        """Solve for z (``x = B z``) with this estimator's solver, from :meth:`_start` (``nominal``: the nominal
        positions, identification Jacobian, residual and, ``large``, its normal equations)."""
        P, J2, F0, H0, g0 = nominal
        PB = Pen @ B

        def fun(z):
            return np.concatenate([d.residual(B @ z), PB @ z])

        def fun_and_jac(z):
            F_, J_ = d.residual_and_jacobian(B @ z)
            return np.concatenate([F_, PB @ z]), np.vstack([J_ @ B, PB])

        z0 = self._start(d, B)
        if self.solver == "lm":
            return lm.improved_lm(fun, None, z0, fun_and_jac=fun_and_jac, **(self.lm_options or {}))
        if self.solver == "scipy":
            return lm.scipy_least_squares(fun, lambda xf: fun_and_jac(xf)[1], z0)
        if self.solver != "gauss-newton":
            raise ValueError(f"unknown solver {self.solver!r}")
        if large:
            ne = _normal_equations(d, B, PB, meas)
            steps = gauss_newton.NormalSteps(ne, *(ne(z0) if self.start else ne(z0, F0, H0, g0)))
        elif self.start:
            steps = gauss_newton.DenseSteps(fun_and_jac, *fun_and_jac(z0), PB.shape[0])
        else:
            Fd = F0 if d.oriented else (P - meas).ravel()
            steps = gauss_newton.DenseSteps(fun_and_jac, np.concatenate([Fd, np.zeros(PB.shape[0])]),
                                            np.vstack([J2 @ B, PB]), PB.shape[0])
        # a start from a nested model's solution counts as having left nominal
        result = gauss_newton.damped_gauss_newton(steps, fun, z0, self.max_iter, moved=bool(self.start))
        self.dof_ = steps.hat_trace(PB.T @ PB) if large else steps.dof
        return result

    def _start(self, d: Design, B) -> np.ndarray:
        """Where the solver starts, z (k,): nominal (0), or the part of ``start`` in the fitted directions
        (counted in typical sizes)."""
        z0 = np.zeros(B.shape[1])
        if self.start:
            x0 = np.array([float(self.start.get(nm, 0.0)) for nm in d.names])
            z0 = np.linalg.lstsq(B / d.sizes[:, None], x0 / d.sizes, rcond=None)[0] if B.shape[1] else z0
        return z0

    def _judge(self, d: Design, data: RobotData) -> None:
        """``implausible_`` and ``plausible_`` (:func:`pipeline.robot.model.plausibility.judge`; None without
        ``checks``), on the design ``d`` of the poses ``data`` it was fitted on."""
        if not self.checks:
            self.implausible_, self.plausible_ = [], None
        else:
            self.implausible_, self.plausible_ = plausibility.judge(self, d, data)

    def predict(self, data: RobotData) -> np.ndarray:
        """Model SMR positions, shape (n, 3), mm."""
        return self.design(data).predict(self.coef_)

    def predict_pose(self, data: RobotData):
        """Model probe frames: rotations (n, 3, 3) and positions (n, 3) mm."""
        return self.design(data).predict_pose(self.coef_)

    def refit_without(self, data: RobotData, keep, kept: RobotData | None = None, determined: bool = True,
                      max_steps: int = 10) -> "RobotErrorModel | None":
        """This model refitted on the poses ``keep`` of ``data`` (the poses it was fitted on) by Gauss-Newton
        steps from its solution, in its fitted directions (``basis_``) with the effects' penalty rows, at the
        fit's orientation weight (:func:`pipeline.robot.model.gauss_newton.steps_without`): a new model
        (this one is not changed). Leaving out a few poses of thousands moves the solution by little: two
        steps, each one Jacobian, instead of a new design, identification and iteration. The identification
        stays the fit's (it needs joint values only): the directions it could not see on all poses are not
        fitted on fewer.

        Parameters
        ----------
        data : RobotData
            The poses the model was fitted on, n of them.
        keep : ndarray of bool, shape (n,)
            The poses the steps are fitted on.
        kept : RobotData, optional
            The same poses as ``data.subset(keep)``: the new model is then judged as a fit on them is (its
            RMS residuals, its variance components and its plausibility), and is None where the weight the
            kept poses give differs from the fit's by :data:`~pipeline.robot.model.weighting.VCE_RTOL` or more.
        determined : bool
            None where the steps cannot stand for a fit on the kept poses: the model has no fitted directions
            to step in, or the kept poses do not determine every one of them (always, with ``kept``).
            False: the steps, whatever they determined.
        """
        keep = np.asarray(keep, bool)
        if kept is not None and keep.all():
            return self
        B = getattr(self, "basis_", None)
        if (determined or kept is not None) and B is None:
            return None
        out = copy.copy(self)
        if B is not None and B.shape[1] > 0 and not keep.all():
            rows = np.repeat(keep, 3).astype(float)
            d = self.design(data)
            if d.oriented:
                rows = np.concatenate([rows, rows])
            # a fit of many parameters steps on its sparse Jacobian (its layout already built), a small one on
            # the dense Jacobian it was fitted with
            out.coef_, rank = gauss_newton.steps_without(d, B, self.penalty_, np.asarray(self.coef_, float), rows,
                                                         self.solves_on_normal_equations(data), data.measured_mm,
                                                         max_steps)
            if (determined or kept is not None) and rank is not None and rank < B.shape[1]:
                return None
        if kept is None:
            return out
        return out._judged_on(kept)

    def _judged_on(self, kept: RobotData) -> "RobotErrorModel | None":
        """This stepped model's residuals, weighting and judgement on the poses ``kept`` (None: the weight
        they give is not the fit's, :func:`pipeline.robot.model.weighting.holds_on`)."""
        d = self.design(kept)
        meas = np.asarray(kept.measured_mm, float)
        if d.oriented:
            R, P = d.predict_pose(self.coef_)
            ori = orientation_errors(R, kept.measured_R)
            self.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(ori) ** 2)))
            if self.weighting_ and self.weighting_.get("method") == "variance components":
                self.weighting_ = weighting.holds_on(self, P, ori, meas)
                if self.weighting_ is None:
                    return None
        else:
            P = d.predict(self.coef_)
        self.rms_mm_ = float(np.sqrt(np.mean(np.sum((P - meas) ** 2, axis=1))))
        self._judge(d, kept)
        return self

    def predict_error(self, data: RobotData) -> np.ndarray:
        """Predicted position error (model - nominal), shape (n, 3), mm (the paper's Delta P_e)."""
        d = self.design(data)
        return d.predict(self.coef_) - d.predict(np.zeros(d.p))

    def parameters(self) -> list[dict]:
        """Fitted parameters in reported units."""
        fixed = set(self.fixed_)
        return [{"name": n, "value": float(v * f), "unit": u, "fixed": n in fixed}
                for n, v, (u, f) in zip(self.names_, self.coef_, self.units_)]

    @classmethod
    def from_parameters(cls, robot, effects, parameters: list[dict]) -> "RobotErrorModel":
        """Rebuild a fitted model from :meth:`parameters` (e.g. read from JSON)."""
        m = cls(robot, effects)
        m.effects_ = list(effects)       # as fitted (their spec lines carry any fit-time state)
        d = m.design(empty_data(robot))
        by = {p["name"]: p for p in parameters}
        m.names_, m.units_ = d.names, d.units
        m.coef_ = np.array([by[n]["value"] / f for n, (u, f) in zip(d.names, d.units)])
        m.fixed_ = [p["name"] for p in parameters if p.get("fixed")]
        m.unseen_ = np.zeros((len(d.names), 0))
        return m

    def undetermined(self) -> np.ndarray:
        """Directions of the parameters (internal units, shape (p, m)) the measurements of the fit did
        not determine: the combinations no measurement could see (:attr:`unseen_`) and every parameter
        left at nominal (:attr:`fixed_`). ``jointcal correct`` holds the flange orientation only where
        none of them turns it."""
        U = getattr(self, "unseen_", None)
        U = np.zeros((len(self.names_), 0)) if U is None else np.asarray(U, float)
        if "orientation_weight_mm_per_mrad" in (getattr(self, "weighting_", None) or {}):
            # fitted on a 6-DoF probe's orientations: the probe frame's orientation is a measurement, and
            # what no measurement could see leaves it as it is; a parameter left at nominal as weakly
            # determined moves it only as the identified ones already do over the sampled poses. The
            # whole orientation is determined (contract section 13: orientation_held = all).
            return np.zeros((len(self.names_), 0))
        fixed = [k for k, n in enumerate(self.names_) if n in set(self.fixed_)]
        E = np.zeros((len(self.names_), len(fixed)))
        E[fixed, np.arange(len(fixed))] = 1.0
        return np.hstack([U, E])


def empty_data(robot) -> RobotData:
    """One pose in the middle of the joint ranges, with no measurement: a design's names and units."""
    z = np.zeros((1, robot.n_joints))
    return RobotData(z + (robot.lower_deg + robot.upper_deg) / 2, np.ones((1, robot.n_joints), int), np.zeros(1),
                     np.full(1, REFERENCE_TEMPERATURE_C),
                     z, robot.lower_deg, robot.upper_deg)


def calibrate_mdh(robot: Robot, data: RobotData, effects=None) -> tuple[RobotErrorModel, dict]:
    """MDH kinematic calibration (Eqs. 3-6) with identifiability analysis.

    Returns the fitted model and a JSON-ready report: parameters (arcsec, mm), rank,
    condition number, parameters not identifiable (fixed at 0), residual RMS before/after.
    """
    effects = effects or [Geometry(), Base()]
    model = RobotErrorModel(robot, effects, solver="gauss-newton", identifiability=True).fit(data)
    nominal = model.design(data).predict(np.zeros(len(model.coef_)))
    before = np.linalg.norm(data.measured_mm - nominal, axis=1)
    after = np.linalg.norm(data.measured_mm - model.predict(data), axis=1)
    ident = model.identifiability_
    report = {"effects": [e.name for e in effects], "n_poses": int(data.n), "solver": "gauss-newton (Eq. 6 iterated)",
              "iterations": model.n_iter_, "seconds": model.seconds_,
              "rank": ident["rank"], "n_params": ident["n_params"],
              "condition_number": ident["condition_number"],
              "condition_number_all": ident["condition_number_all"],
              "not_identifiable": ident["not_identifiable"],
              "redundant": ident.get("redundant_groups", []),
              "rms_before_mm": float(np.sqrt(np.mean(before**2))), "rms_after_mm": float(np.sqrt(np.mean(after**2))),
              "max_before_mm": float(before.max()), "max_after_mm": float(after.max()),
              "parameters": model.parameters()}
    return model, report


def _normal_equations(d: Design, B, PB, meas):
    """The residual and normal equations of the fitted directions ``B`` (p, k) on the sparse Jacobian:
    z -> (F (m,), Jf^T Jf (k, k), Jf^T F (k,)), F's data rows (or, given, ``Fd`` with ``H = J^T J`` and
    ``g = J^T Fd``) followed by the penalty rows ``PB z``."""
    PtP = PB.T @ PB
    rows = np.flatnonzero(np.abs(B).max(axis=1, initial=0.0) > 0)     # the parameters that move
    Br = B[rows]

    def normal_equations(z, Fd=None, H=None, g=None):
        if H is None:
            if d.oriented:
                _, Fd, J_ = d.residual_and_sparse_jacobian(B @ z)
            else:
                P_, J_ = d.predict_and_sparse_jacobian(B @ z)
                Fd = (P_ - meas).ravel()
            H, g = normal.gram(J_, Fd)
        F_ = np.concatenate([Fd, PB @ z])
        return F_, Br.T @ H[np.ix_(rows, rows)] @ Br + PtP, Br.T @ g[rows] + PtP @ z
    return normal_equations
