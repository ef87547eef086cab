"""A spec's effects fitted to a data set: the estimator, nested models, held-out fits, k-fold cross-validation."""

from __future__ import annotations

import numpy as np

from ...core import crossval
from ...core.crossval import CVResult
from ...core.parallel import can_fork, fork_map, fork_map_async
from ...core.se3 import angle_arcsec, orientation_errors
from .design import Design
from .estimator import RobotErrorModel
from .chebyshev import chebyshev_estimator


def error_stats(err_mm) -> dict:
    """Absolute positioning error statistics (Eq. 27) of error vectors (n, 3) mm."""
    n = np.linalg.norm(np.asarray(err_mm, float), axis=1)
    return {"min_mm": float(n.min()), "max_mm": float(n.max()), "mean_mm": float(n.mean()),
            "std_mm": float(n.std(ddof=1)) if n.size > 1 else 0.0, "n": int(n.size)}


def effects_estimator(robot, effects, start=None, checks: bool = True, orientation: bool = True,
                      orientation_weight: float | None = None, weight_start: float | None = None) -> RobotErrorModel:
    """The estimator (not fitted) :func:`fit_effects` fits: ``jointcal plan`` asks it which
    parameters a set of poses identifies. ``start``: parameter name -> value (internal units) to
    start the solver from (a nested model's solution). ``checks``: judge the fitted model's plausibility
    (:class:`~pipeline.robot.model.estimator.RobotErrorModel`); off for a fit used only to predict.
    ``orientation``: fit a 6-DoF campaign's orientations too (False: its positions alone);
    ``orientation_weight`` (mm per mrad): their weight, None to estimate it (variance components), starting
    from ``weight_start`` when given (the weight a fit of the same model on nearly the same poses ended with)."""
    if any(e.name == "chebyshev" for e in effects):
        est = chebyshev_estimator(robot, effects, "gauss-newton")
        est.start, est.checks = start, checks
        est.orientation, est.orientation_weight, est.weight_start = orientation, orientation_weight, weight_start
        return est
    return RobotErrorModel(robot, effects, solver="gauss-newton", start=start, checks=checks, orientation=orientation,
                           orientation_weight=orientation_weight, weight_start=weight_start)


def orientation_stats(err_mrad) -> dict:
    """Orientation error statistics (arcsec) of orientation errors (n, 3) mrad: the angle between
    measured and predicted probe frames."""
    a = angle_arcsec(err_mrad)
    return {"min_arcsec": float(a.min()), "max_arcsec": float(a.max()), "mean_arcsec": float(a.mean()),
            "std_arcsec": float(a.std(ddof=1)) if a.size > 1 else 0.0, "rms_arcsec": float(np.sqrt(np.mean(a ** 2))),
            "n": int(a.size)}


def point_errors(R_pred, P_pred, R_meas, P_meas, point_mm) -> np.ndarray:
    """Error vectors (n, 3) mm of a point rigidly fixed to the probe (``point_mm`` (3,), probe frame):
    measured - predicted, as positions are."""
    p = np.asarray(point_mm, float)
    return (P_meas + np.einsum("nij,j->ni", R_meas, p)) - (P_pred + np.einsum("nij,j->ni", R_pred, p))


#: A fit may leave its sample poses' RMS at most this much (relative) above a model nested in it:
#: the solvers' own agreement (:data:`pipeline.robot.model.chebyshev.CROSS_CHECK_RTOL`); the conflicts it
#: is there for are gross (issue 16: 0.06 mm for the nested model, 0.79 mm with one effect more).
NESTED_RTOL = 0.01


def overlapping_pairs(effects, robot=None) -> list[str]:
    """The pairs of effects of a model that overlap (:meth:`RobotEffect.overlaps`), in words."""
    out = []
    for i, a in enumerate(effects):
        for b in effects[i + 1:]:
            joints = a.overlaps(b, robot) if hasattr(a, "overlaps") else []
            if joints:
                js = ", ".join(map(str, joints))
                out.append(f"{a.name} joint {js} and {b.name} joint {js}")
    return out


def nested_models(effects, robot=None) -> list[list]:
    """Models nested in ``effects`` that a fit of it must do at least as well as on its sample poses:
    the kinematic core (the effects on the whole robot: geometry, base, tool, thermal) and, when
    the model has overlapping effects, the model without the later effect of each overlapping pair."""
    effects = list(effects)
    core = [e for e in effects if not getattr(e, "per_joint", True)]
    out = [core] if 0 < len(core) < len(effects) else []
    later = {id(b) for i, a in enumerate(effects) for b in effects[i + 1:] if hasattr(a, "overlaps") and a.overlaps(b, robot)}
    if later:
        out.append([e for e in effects if id(e) not in later])
    return out


def fit_effects(robot, effects, data, check_nested: bool = False, checks: bool = True, start=None,
                orientation: bool = True, orientation_weight: float | None = None, weight_start: float | None = None):
    """Fit a robot error model (a list of effects) on ``data``: the estimator diagnosis uses.

    Gauss-Newton with step halving; a model with Chebyshev terms is solved in the span of the
    leading singular directions, as the Chebyshev stage does (:func:`pipeline.robot.model.chebyshev.chebyshev_estimator`).

    With ``check_nested`` the fit is checked against the models nested in it (:func:`nested_models`):
    when it fits the sample poses worse than one of them (by more than :data:`NESTED_RTOL`), it is
    refitted from that model's solution; when still worse, ``conflict_`` says which effects conflict
    (else it is ''). ``nested_`` lists each nested model's sample RMS (mm). Without ``checks`` the fit
    is not judged for plausibility (a fit used only for its predictions). ``start``: parameter name ->
    value (internal units) to start the solver from (a fit of the same model on nearly the same poses);
    ``weight_start``: the orientation weight (mm per mrad) such a fit ended with, where a 6-DoF fit's
    variance components start.
    """
    model = effects_estimator(robot, effects, start=start, checks=checks, orientation=orientation,
                              orientation_weight=orientation_weight, weight_start=weight_start).fit(data)
    if not check_nested:
        return model
    model.conflict_, model.nested_ = "", []
    for nested in nested_models(effects, robot):
        m0 = effects_estimator(robot, nested, orientation=orientation, orientation_weight=orientation_weight).fit(data)
        entry = {"effects": [e.name for e in nested], "rms_mm": m0.rms_mm_}
        model.nested_.append(entry)
        if model.rms_mm_ <= m0.rms_mm_ * (1.0 + NESTED_RTOL):
            continue
        warm = effects_estimator(robot, effects, start=dict(zip(m0.names_, m0.coef_)), orientation=orientation,
                                 orientation_weight=orientation_weight).fit(data)
        entry["started_from_it"] = True
        if warm.rms_mm_ < model.rms_mm_:
            warm.conflict_, warm.nested_ = "", model.nested_
            model = warm
        if model.rms_mm_ > m0.rms_mm_ * (1.0 + NESTED_RTOL):
            pairs = overlapping_pairs(effects, robot)
            names = {id(e) for e in nested}
            added = [e.name for e in effects if id(e) not in names]
            who = ("; ".join(pairs) + " overlap (they model the same angle error)" if pairs else
                   f"{', '.join(dict.fromkeys(added))} conflict with {' + '.join(entry['effects'])}")
            model.conflict_ = (f"the model fits its sample poses worse ({model.rms_mm_:.4g} mm RMS) than "
                               f"{' + '.join(entry['effects'])} nested in it ({m0.rms_mm_:.4g} mm), even started from "
                               f"that model's solution: {who}")
            break
    return model


def heldout_fit(robot, effects, sample, target, model=None) -> dict:
    """Fit the spec's model on the sample poses; its error on the held-out target poses.

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
        The whole model (every stage's effects together).
    sample, target : RobotData
        Sample poses (fit) and target poses (held out), with tracker positions ``measured_mm``
        of shape (n, 3), mm.

    Returns
    -------
    dict: ``before`` (nominal model) and ``after`` (fitted model) error statistics of the targets
    (mm, Eq. 27), ``rms_before_mm`` / ``rms_after_mm`` (RMS of the 3-D error), ``max_reduction_pct``,
    ``rms_reduction_pct``, the fitted ``parameters`` and the fit's identifiability.
    ``model``: the model already fitted on ``sample`` (else it is fitted here).
    """
    model = model if model is not None else fit_effects(robot, effects, sample)
    nominal = Design(robot, [], target).predict(np.zeros(0))
    before = target.measured_mm - nominal
    after = target.measured_mm - model.predict(target)

    def rms(e):
        return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))

    out = {"n_sample": int(sample.n), "n_target": int(target.n), "before": error_stats(before),
           "after": error_stats(after), "rms_before_mm": rms(before), "rms_after_mm": rms(after)}
    out["max_reduction_pct"] = 100.0 * (1.0 - out["after"]["max_mm"] / out["before"]["max_mm"])
    out["rms_reduction_pct"] = 100.0 * (1.0 - out["rms_after_mm"] / out["rms_before_mm"])
    if target.has_orientation:
        # a 6-DoF campaign: the orientation error beside the position error (contract section 13)
        R0, _ = Design(robot, [], target).predict_pose(np.zeros(0))
        Rm, _ = model.predict_pose(target)
        ob, oa = orientation_errors(R0, target.measured_R), orientation_errors(Rm, target.measured_R)
        out["orientation_before"], out["orientation_after"] = orientation_stats(ob), orientation_stats(oa)
        out["orientation_rms_before_arcsec"] = out["orientation_before"]["rms_arcsec"]
        out["orientation_rms_after_arcsec"] = out["orientation_after"]["rms_arcsec"]
    ident = getattr(model, "identifiability_", None) or {}
    out["identifiability"] = {k: ident[k] for k in ("rank", "n_params", "condition_number", "not_identifiable")
                              if k in ident}
    out["parameters"] = model.parameters()
    return out


# ------------------------------------------------------------------ cross-validation by pose
#: folds of the cross-validated RMS (``jointcal fit``) and of diagnosis
N_FOLDS = 5


def fold_ids(n: int, k: int = N_FOLDS, seed: int = 0) -> np.ndarray:
    """Fold of each pose: a seeded permutation cut into k nearly equal parts (:func:`pipeline.core.crossval.fold_ids`)."""
    return crossval.fold_ids(n, k, seed)


def fold_description(data, n_folds: int = N_FOLDS) -> str:
    return f"{n_folds}-fold by pose over {data.n} sample poses"


#: sample poses from which ``jointcal fit`` cross-validates its folds in forked processes (fewer: one process;
#: a fork costs about 0.1 s, a fold's fit of 1,000 6-DoF poses about as much)
PARALLEL_CV_MIN_POSES = 2000


def cpu_count() -> int:
    """The CPUs this process may run on (at least 1)."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def cross_validate(robot, effects, data, n_folds: int = N_FOLDS, orientation: bool = True,
                   orientation_weight: float | None = None, jobs: int = 1, folds=None) -> CVResult:
    """Held-out residuals (mm, shape (n, 3)) of ``effects`` fitted by :func:`fit_effects`, k-fold by pose.

    Each fold of poses (:func:`fold_ids`) is predicted by the model fitted on the others; without
    effects, by the nominal kinematics. Poses are the independent blocks. On a 6-DoF campaign
    ``extra["orientation"]`` holds the held-out orientation errors (n, 3) mrad (predicted - measured);
    ``orientation_weight`` (the whole sample's, from its own fit) weighs every fold's fit alike.
    ``jobs`` > 1 fits the folds in up to that many forked processes (Linux, not from inside a worker
    process): each fold's fit is the same computation as in one process, so the result is the same.
    ``folds`` (n,) int: each pose's fold, when not :func:`fold_ids`' (diagnosis's folds by region).
    """
    if folds is None:
        folds, labels = fold_ids(data.n, n_folds), list(range(n_folds))
    else:
        folds = np.asarray(folds)
        labels = list(np.unique(folds))
    args = (robot, effects, data, folds, orientation, orientation_weight)
    jobs = min(int(jobs), n_folds)
    if jobs > 1 and effects and can_fork():
        parts = fork_map(_cv_shared_fold, (args, labels), len(labels), jobs)
    else:
        parts = [_cv_fold(*args, f) for f in labels]
    return held_out(folds, labels, parts, data.has_orientation)


def held_out(folds, labels, parts, has_orientation: bool) -> CVResult:
    """The held-out residuals of every pose from its fold's: ``folds`` (n,) each pose's fold, ``parts`` the
    (residuals (n_f, 3) mm, orientation errors (n_f, 3) mrad or None) of the fold ``labels[i]``; a
    :class:`CVResult` with ``extra["orientation"]`` (n, 3) mrad where ``has_orientation``."""
    n = len(folds)
    res = np.empty((n, 3))
    ori = np.empty((n, 3)) if has_orientation else None
    for f, (r, o) in zip(labels, parts):
        test = folds == f
        res[test] = r
        if ori is not None:
            ori[test] = o
    out = CVResult(res, np.arange(n))
    if ori is not None:
        out.extra["orientation"] = ori
    return out


def _cv_fold(robot, effects, data, folds, orientation, orientation_weight, f):
    """Fold ``f`` of :func:`cross_validate`: its poses' held-out residuals (n_f, 3) mm and orientation
    errors (n_f, 3) mrad (None without orientations)."""
    test = folds == f
    train, held = data.subset(~test), data.subset(test)
    m = Design(robot, [], held) if not effects else fit_effects(robot, effects, train, checks=False,
                                                                orientation=orientation,
                                                                orientation_weight=orientation_weight)
    o = None
    if data.has_orientation:
        R, pred = m.predict_pose(np.zeros(0)) if not effects else m.predict_pose(held)
        o = orientation_errors(R, held.measured_R)
    else:
        pred = m.predict(np.zeros(0)) if not effects else m.predict(held)
    return data.measured_mm[test] - pred, o


def _cv_shared_fold(shared, k):
    args, labels = shared
    return _cv_fold(*args, labels[k])


class FoldsBeforeWild:
    """The k-fold cross-validation by pose of a model fitted before its campaign's wild poses are known
    (:func:`pipeline.robot.model.fit.fitted_before_wild`): the folds are drawn over every sample pose
    (:func:`fold_ids`), each fold's model is fitted on the other folds' poses (:meth:`fit`, while the wild search
    runs; stepped there from ``first``, given) and then taken to their kept poses by Gauss-Newton steps
    (:meth:`cross_validate`). A wild pose is in no fold's fit and has no residual. Each fold's model is the one
    fitted on the other folds' kept poses, to the steps' 1e-5 mm^2 (where the kept poses leave a direction
    undetermined: fitted on them).

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
    data : RobotData
        Every sample pose, n of them.
    orientation : bool
    orientation_weight : float or None
        mm per mrad, every fold's (the whole sample's weight).
    first : RobotErrorModel or None
        The model fitted on every pose of ``data`` (its design kept), or None. Given, each fold's model is it
        taken to the other folds' poses by Gauss-Newton steps (:meth:`~pipeline.robot.model.estimator.\
RobotErrorModel.refit_without`, at its orientation weight, in its fitted directions): the fit on them
        to the steps' 1e-5 mm^2, from the fit on all the poses (four fifths of them the fold's), instead of a
        design, an identification and an iteration from nominal; fitted where the other folds' poses leave a fitted
        direction undetermined.
    """

    def __init__(self, robot, effects, data, orientation: bool = True, orientation_weight: float | None = None,
                 n_folds: int = N_FOLDS, first=None):
        self.robot, self.effects, self.data = robot, effects, data
        self.orientation, self.orientation_weight, self.n_folds = orientation, orientation_weight, n_folds
        self.first = first

    def _fit_fold(self, f: int):
        """Fold ``f``'s model and the poses it holds a design of: (None, model) for ``first`` stepped (its
        design of every pose, fitted on the other folds'), (train, model) for a model fitted on ``train``."""
        folds = fold_ids(self.data.n, self.n_folds)
        if self.first is not None:
            m = self.first.refit_without(self.data, folds != f)
            if m is not None:
                return None, m
        train = self.data.subset(folds != f)
        est = effects_estimator(self.robot, self.effects, checks=False, orientation=self.orientation,
                                orientation_weight=self.orientation_weight)
        est.keep_designs = True       # the steps to the kept poses reuse its design
        return train, est.fit(train)

    def fit(self) -> "FoldsBeforeWild":
        """Fit every fold's model on the other folds' poses, wild or not (``models_``)."""
        self.models_ = [self._fit_fold(f) for f in range(self.n_folds)]
        return self

    def _fold(self, f: int, keep, fitted=None):
        """Fold ``f``'s kept poses' held-out residuals (n_f, 3) mm and orientation errors (n_f, 3) mrad (None
        without orientations), by its model taken to the other folds' kept poses."""
        folds = fold_ids(self.data.n, self.n_folds)
        train, m = fitted if fitted is not None else self._fit_fold(f)
        if not keep[folds != f].all():
            # stepped from the whole sample's model: on its design of every pose, the other folds' kept ones
            step = (m.refit_without(self.data, (folds != f) & keep) if train is None
                    else m.refit_without(train, keep[folds != f]))
            if step is None:
                step = fit_effects(self.robot, self.effects, self.data.subset((folds != f) & keep), checks=False,
                                   orientation=self.orientation, orientation_weight=self.orientation_weight)
            m = step
        m.release_designs()
        held = self.data.subset((folds == f) & keep)
        o = None
        if self.data.has_orientation:
            R, pred = m.predict_pose(held)
            o = orientation_errors(R, held.measured_R)
        else:
            pred = m.predict(held)
        return held.measured_mm - pred, o

    def start(self, keep, jobs: int = 1):
        """Begin :meth:`cross_validate` of the poses ``keep`` (n,) bool in up to ``jobs`` forked processes
        (Linux, not from inside a worker process; else here, when asked): returns a function that gives its
        :class:`CVResult`. Folds fitted by :meth:`fit` are stepped there; the others fitted and stepped. The
        caller goes on meanwhile (the model's own steps, its held-out errors)."""
        keep = np.asarray(keep, bool)
        jobs = min(int(jobs), self.n_folds)
        if not (jobs > 1 and can_fork()):
            return lambda: self.cross_validate(keep)
        # the workers fork here, with the folds' models
        pending = fork_map_async(_shared_fold, (self, keep), self.n_folds, jobs)

        def result() -> CVResult:
            parts = pending()
            self.models_ = None
            return self._assemble(keep, parts)

        return result

    def cross_validate(self, keep) -> CVResult:
        """Held-out residuals (mm, shape (n_kept, 3)) of the poses ``keep`` (n,) bool, in their order, as
        :func:`cross_validate` gives them (``extra["orientation"]`` on a 6-DoF campaign), in this process. Folds
        fitted by :meth:`fit` are stepped; otherwise each fold is fitted and stepped (:meth:`start`: the same
        computation in forked processes, the same result)."""
        keep = np.asarray(keep, bool)
        fitted = getattr(self, "models_", None)
        parts = [self._fold(f, keep, fitted[f] if fitted else None) for f in range(self.n_folds)]
        self.models_ = None
        return self._assemble(keep, parts)

    def _assemble(self, keep, parts) -> CVResult:
        return held_out(fold_ids(self.data.n, self.n_folds)[keep], range(self.n_folds), parts,
                        self.data.has_orientation)


def _shared_fold(shared, f):
    folds, keep = shared
    fitted = getattr(folds, "models_", None)
    return folds._fold(f, keep, fitted[f] if fitted else None)
