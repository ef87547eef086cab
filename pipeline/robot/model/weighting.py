"""Variance components: how a 6-DoF fit weighs its orientation rows against its positions.

The weight (mm per mrad, the fit's public ``weight_``) is the ratio of the fit's RMS position residual
per axis (mm) to its RMS orientation residual per axis (mrad), refitted until it changes by less than
:data:`VCE_RTOL` (:func:`variance_components`). Each next weight is where the iteration ends on the fit
linearised at its solution (:func:`linear_weight`), else the plain or secant step (:func:`vce_next`).
A fit on the positions alone registers the probe's mounting from the orientations (:func:`register_mounting`).

The variance components treat each block's residual as its noise. Where the orientation rows carry an error the
model cannot explain (the probe's own orientation error, an unmodelled wrist effect), that error is systematic:
weighed as noise it pulls the parameters the positions share, and the fit trades position for orientation. So a
variance-components weight is then judged held out (:func:`position_guard`): the fit linearised at its solution,
k-fold by pose, its position error at the weight against the same model's on its positions alone; where the
orientation rows raise it by more than :data:`POSITION_GUARD`, the weight is lowered to the largest one that
does not (the orientations still fit, the positions no longer pay for them).
"""

from __future__ import annotations

import numpy as np

from ...core.se3 import ARCSEC_PER_MRAD, angle_arcsec, chordal_mean, orientation_errors
from ...core.crossval import fold_ids
from . import normal

#: The variance components' iteration stops when the weight changes by less than this (relative)
VCE_RTOL = 0.01
#: and after this many fits at most
VCE_MAX_ITER = 8
#: mm per mrad: where the iteration starts without stated uncertainties (sigma_mm / sigma_arcsec)
START_WEIGHT_MM_PER_MRAD = 1.0

#: A 6-DoF fit on its positions alone: how it is weighed (the fit JSON's ``weighting``)
POSITIONS_ONLY = {"method": "positions only",
                  "rule": "fitted on the positions alone; the probe frame's turn on the flange (tool_ex, "
                          "tool_ey, tool_ez) is then the mean rotation from the predicted to the measured "
                          "probe frames, every other parameter as the positions put it"}


#: The orientation rows of a variance-components fit may raise its position error held out (k-fold by pose, the
#: fit linearised at its solution) by at most this share over the same model fitted on its positions alone
#: (:func:`position_guard`): half of issue 52's 1.05x, the held-out targets being another sample than the folds
POSITION_GUARD = 0.025
#: folds by pose of the guard (as ``jointcal fit``'s cross-validation: :func:`pipeline.core.crossval.fold_ids`)
GUARD_FOLDS = 5
#: the guard's search for the largest weight that holds: halvings of log w at most, and how far down it looks
GUARD_STEPS = 10
GUARD_FLOOR = 1.0 / 64.0


def vce_next(log_w: float, h: float, before) -> float:
    """The next weight of the variance components' iteration (mm per mrad).

    The plain step takes the ratio the fit at ``w`` gave: ``w exp(h)``, with ``h = log(w_new / w)``.
    It converges linearly (each step a fixed fraction of the one before), so from the second step on the
    root of ``h`` is sought by the secant through this iteration and ``before`` (its ``(log w, h)``):
    taken when it lies on the plain step's side and at most four times as far, else the plain step.
    Where it ends is decided by the same test (:data:`VCE_RTOL` on ``h``), not by the step."""
    plain = log_w + h
    if before is not None and h != before[1]:
        step = -h * (log_w - before[0]) / (h - before[1])
        if step * h > 0 and abs(step) <= 4.0 * abs(h):
            return float(np.exp(log_w + step))
    return float(np.exp(plain))


def start_weight(data) -> tuple[float, str]:
    """The first orientation weight (mm per mrad) of a 6-DoF fit and where it came from."""
    sp, so = getattr(data, "sigma_mm", None), getattr(data, "sigma_arcsec", None)
    if sp is not None and so is not None and np.isfinite(sp).any() and np.isfinite(so).any():
        a, b = float(np.nanmedian(sp)), float(np.nanmedian(so)) / ARCSEC_PER_MRAD
        if a > 0 and b > 0:
            return a / b, "the stated uncertainties (median sigma_mm / sigma_arcsec)"
    return START_WEIGHT_MM_PER_MRAD, f"{START_WEIGHT_MM_PER_MRAD:g} mm per mrad"


def first_weight(model, data) -> tuple[float, str]:
    """Where the variance components start (mm per mrad) and why: the stated ``orientation_weight``, the
    ``weight_start`` (a fit of the same model on nearly the same poses), else :func:`start_weight`."""
    if model.orientation_weight:
        return float(model.orientation_weight), "stated (orientation_weight)"
    if getattr(model, "weight_start", None):
        return float(model.weight_start), "the weight of a fit of the same model on nearly the same poses"
    return start_weight(data)


def variance_components(model, data, fit_at) -> dict:
    """Fit ``model`` on the 6-DoF campaign ``data`` at the weight the variance components settle on; returns
    how it was weighed (the fit JSON's ``weighting``).

    Parameters
    ----------
    model : RobotErrorModel
    data : RobotData
        ``measured_mm`` (n, 3) mm and ``measured_R`` (n, 3, 3).
    fit_at : callable w -> None
        Fits ``model`` on ``data`` at the orientation weight ``w`` (mm per mrad), setting its ``weight_``.
    """
    w, source = first_weight(model, data)
    history = []
    before = None          # (log w, log(w_new / w)) of the iteration before
    for it in range(1, VCE_MAX_ITER + 1):
        fit_at(w)
        d = model.design(data)
        R, P = d.predict_pose(model.coef_)
        sp = float(np.sqrt(np.mean((P - data.measured_mm) ** 2)))
        so = float(np.sqrt(np.mean(orientation_errors(R, data.measured_R) ** 2)))
        history.append(w)
        if model.orientation_weight or so <= 0 or sp <= 0:
            break
        w_new = sp / so
        h = float(np.log(w_new / w))
        if abs(h) < VCE_RTOL:
            break
        # the next weight: where the fit, linearised at this solution, ends the iteration (the
        # position and orientation rows' normal equations apart: a (k, k) solve a trial weight);
        # the plain or secant step where the linear problem cannot say
        guess = linear_weight(model, data, w)
        w = guess if guess is not None else vce_next(np.log(w), h, before)
        before = (float(np.log(history[-1])), h)
    out = {
        "method": "stated" if model.orientation_weight else "variance components",
        "rule": ("the orientation rows (mrad) weigh orientation_weight_mm_per_mrad mm each: the ratio of the "
                 "fit's RMS position residual per axis (mm) to its RMS orientation residual per axis (mrad), "
                 f"refitted until it changes by less than {VCE_RTOL:.0%}"),
        "started_from": source, "iterations": len(history),
        "orientation_weight_mm_per_mrad": float(model.weight_),
        "position_sigma_mm": sp, "orientation_sigma_arcsec": so * ARCSEC_PER_MRAD}
    if model.orientation_weight or so <= 0 or sp <= 0:
        return out
    guard = position_guard(model, data)
    if guard is None:
        return out
    out["position_guard"] = guard
    if guard["factor"] < 1.0:
        fit_at(guard["weight_mm_per_mrad"])
        R, P = model.design(data).predict_pose(model.coef_)
        out["rule"] += (f"; lowered to the largest weight at which the orientation rows raise the position error held "
                        f"out ({GUARD_FOLDS}-fold by pose, linearised) by at most {POSITION_GUARD:.1%} over the "
                        "positions alone (position_guard)")
        out.update(orientation_weight_mm_per_mrad=float(model.weight_),
                   position_sigma_mm=float(np.sqrt(np.mean((P - data.measured_mm) ** 2))),
                   orientation_sigma_arcsec=float(np.sqrt(np.mean(orientation_errors(R, data.measured_R) ** 2)))
                   * ARCSEC_PER_MRAD)
    return out


def _fold_normal_equations(model, data, folds):
    """The fit linearised at its solution, fold by fold: per fold its position and unweighted orientation rows'
    normal equations in the fitted directions (``basis_``), and its position rows (Jacobian in the parameters,
    residual mm); with the penalty's. None where the fit has no directions.

    Parameters
    ----------
    folds : ndarray of int, shape (n,)
        Each pose's fold (:func:`pipeline.core.crossval.fold_ids`).
    """
    B, Pen = model.basis_, model.penalty_
    w = model.weight_
    if B is None or B.shape[1] == 0 or not w or w <= 0:
        return None
    d = model.design(data)
    x = np.asarray(model.coef_, float)
    n3 = 3 * data.n
    if model.solves_on_normal_equations(data):
        _, F, J = d.residual_and_sparse_jacobian(x)
        J = J.tocsr()
    else:
        F, J = d.residual_and_jacobian(x)
    F = np.array(F, float)
    F[n3:] /= w                     # the orientation rows unweighted (mrad)
    parts = []
    for f in np.unique(folds):
        rp = np.flatnonzero(np.repeat(folds == f, 3))
        Jp = J[rp]
        # the fold's rows in the fitted directions (a fold's share of the rows by k: no (p, p) product)
        JBp, JBo = np.asarray(Jp @ B), np.asarray((J[rp + n3] @ B) / w)
        parts.append((JBp.T @ JBp, JBp.T @ F[rp], JBo.T @ JBo, JBo.T @ F[rp + n3], Jp, F[rp]))
        del JBp, JBo
    PB = Pen @ B
    return parts, PB.T @ PB, PB.T @ (Pen @ x), B


def _linear_cv_position(eqs, v: float, n: int) -> float:
    """The held-out position RMS (mm, of the 3-D errors) of the fit linearised at its solution, each fold's
    directions refitted on the other folds' rows with the orientation rows weighing ``v`` mm per mrad."""
    parts, PtP, pz, B = eqs
    Hp = sum(p[0] for p in parts)
    gp = sum(p[1] for p in parts)
    Ho = sum(p[2] for p in parts)
    go = sum(p[3] for p in parts)
    sq = 0.0
    for hp, gpf, ho, gof, Jp, Fp in parts:
        dz, _ = normal.scaled_min_norm_step(Hp - hp + v * v * (Ho - ho) + PtP, gp - gpf + v * v * (go - gof) + pz)
        e = Fp + Jp @ (B @ dz)
        sq += float(e @ e)
    return float(np.sqrt(sq / n))


def position_guard(model, data) -> dict | None:
    """How far the orientation rows of a variance-components fit (``model``, fitted on the 6-DoF ``data`` at its
    weight) raise its position error held out, and the weight (mm per mrad) at which they raise it by at most
    :data:`POSITION_GUARD`: the fit linearised at its solution, :data:`GUARD_FOLDS`-fold by pose
    (:func:`pipeline.core.crossval.fold_ids`), each fold's directions refitted on the other folds' rows (a (k, k) solve a fold and a
    weight, no fit); against the same linear refits on the positions alone (weight 0). The largest weight that
    holds is sought by halving log w down to :data:`GUARD_FLOOR` of the fit's. None where the fit has no
    directions.

    Parameters
    ----------
    model : RobotErrorModel
        Fitted at its variance-components weight ``weight_`` (mm per mrad), with its ``basis_`` and ``penalty_``.
    data : RobotData
        The 6-DoF poses it was fitted on: ``measured_mm`` (n, 3) mm, ``measured_R`` (n, 3, 3).

    Returns
    -------
    dict: ``rule``, ``cv_position_rms_positions_only_mm``, ``cv_position_rms_at_vce_mm`` (at the variance
    components' weight), ``cv_position_rms_mm`` (at the weight kept), ``vce_weight_mm_per_mrad``,
    ``weight_mm_per_mrad`` (kept) and ``factor`` (their ratio, 1 where the variance components' weight holds).
    """
    folds = fold_ids(data.n, GUARD_FOLDS)
    eqs = _fold_normal_equations(model, data, folds)
    if eqs is None:
        return None
    w = float(model.weight_)
    alone = _linear_cv_position(eqs, 0.0, data.n)
    at_w = _linear_cv_position(eqs, w, data.n)
    limit = alone * (1.0 + POSITION_GUARD)
    out = {"rule": (f"the orientation rows may raise the position error held out ({GUARD_FOLDS}-fold by pose, the fit "
                    f"linearised at its solution) by at most {POSITION_GUARD:.1%} over the positions alone"),
           "cv_position_rms_positions_only_mm": alone, "cv_position_rms_at_vce_mm": at_w,
           "vce_weight_mm_per_mrad": w}
    kept, cv = w, at_w
    if at_w > limit:
        lo, hi = np.log(w * GUARD_FLOOR), np.log(w)
        kept, cv = float(np.exp(lo)), _linear_cv_position(eqs, float(np.exp(lo)), data.n)
        if cv <= limit:
            for _ in range(GUARD_STEPS):
                mid = 0.5 * (lo + hi)
                c = _linear_cv_position(eqs, float(np.exp(mid)), data.n)
                if c <= limit:
                    lo, kept, cv = mid, float(np.exp(mid)), c
                else:
                    hi = mid
    out.update(cv_position_rms_mm=cv, weight_mm_per_mrad=kept, factor=kept / w)
    return out


def holds_on(model, P, ori, meas) -> dict | None:
    """The weighting of a variance-components fit stepped to fewer poses, judged there: None where the
    weight those poses give (RMS position residual per axis over RMS orientation residual per axis)
    differs from the fit's by :data:`VCE_RTOL` or more; else the weighting with their sigmas.

    Parameters
    ----------
    P, meas : ndarray, shape (n, 3)
        Predicted and measured positions (mm).
    ori : ndarray, shape (n, 3)
        Orientation errors (mrad).
    """
    sp, so = float(np.sqrt(np.mean((P - meas) ** 2))), float(np.sqrt(np.mean(ori ** 2)))
    # a weight the position guard lowered holds where the same share of the poses' ratio is the fit's
    factor = float((model.weighting_.get("position_guard") or {}).get("factor", 1.0))
    if not (sp > 0 and so > 0) or abs(float(np.log(factor * sp / so / model.weight_))) >= VCE_RTOL:
        return None
    return dict(model.weighting_, position_sigma_mm=sp, orientation_sigma_arcsec=so * ARCSEC_PER_MRAD)


def linear_weight(model, data, w: float) -> float | None:
    """The weight (mm per mrad) where the variance components' iteration ends on the fit linearised at
    its solution (fitted at weight ``w``), to :data:`VCE_RTOL` / 10 on ``h``; None where the linear problem
    cannot say.

    In the fit's directions B (``basis_``) and with its penalty rows, the position and orientation rows
    enter the normal equations apart: at a trial weight v the linear fit is
    ``(Hp + v^2 Ho + Pen^T Pen) dz = -(gp + v^2 go + Pen^T Pen x)`` and its RMS residuals follow from the
    same sums, so each trial costs a (k, k) solve, not a fit. The fit at the weight found decides (the
    iteration's test is on that fit's residuals, as for every weight)."""
    d = model.design(data)
    x = np.asarray(model.coef_, float)
    B, Pen = model.basis_, model.penalty_
    if B is None or B.shape[1] == 0 or w <= 0:
        return None
    n3 = 3 * data.n
    if model.solves_on_normal_equations(data):
        _, F, J = d.residual_and_sparse_jacobian(x)
        J = J.tocsr()
        Hp, gp = normal.gram(J[:n3].tocsc(), F[:n3])
        Ho, go = normal.gram(J[n3:].tocsc(), F[n3:])
    else:
        F, J = d.residual_and_jacobian(x)
        Hp, gp = J[:n3].T @ J[:n3], J[:n3].T @ F[:n3]
        Ho, go = J[n3:].T @ J[n3:], J[n3:].T @ F[n3:]
    # the orientation rows unweighted (mrad)
    Ho, go, Fo, Fp = Ho / w ** 2, go / w ** 2, F[n3:] / w, F[:n3]
    Hp, Ho, gp, go = B.T @ Hp @ B, B.T @ Ho @ B, B.T @ gp, B.T @ go
    PB = Pen @ B
    PtP, pz = PB.T @ PB, PB.T @ (Pen @ x)
    fp2, fo2 = float(Fp @ Fp), float(Fo @ Fo)
    v, before = float(w), None
    for _ in range(4 * VCE_MAX_ITER):
        dz, _ = normal.scaled_min_norm_step(Hp + v * v * Ho + PtP, gp + v * v * go + pz)
        sp2 = (fp2 + 2.0 * float(gp @ dz) + float(dz @ Hp @ dz)) / n3
        so2 = (fo2 + 2.0 * float(go @ dz) + float(dz @ Ho @ dz)) / n3
        if not (np.isfinite(sp2) and np.isfinite(so2) and sp2 > 0 and so2 > 0):
            return None
        h = 0.5 * float(np.log(sp2 / so2)) - float(np.log(v))
        if abs(h) < VCE_RTOL / 10:
            return v
        v, before = vce_next(np.log(v), h, before), (float(np.log(v)), h)
    return None


def register_mounting(model, data) -> None:
    """Set the probe frame's turn on the flange (the tool's orientation parameters) to the chordal
    mean of the rotations from the predicted to the measured probe frames (``model`` fitted on the
    positions of the 6-DoF campaign ``data``)."""
    from scipy.spatial.transform import Rotation

    names = ["tool_ex", "tool_ey", "tool_ez"]
    if not all(n in model.names_ for n in names):
        return
    cols = [model.names_.index(n) for n in names]
    coef = model.coef_.copy()
    coef[cols] = 0.0
    R, _ = model.design(data).predict_pose(coef)
    rel = np.einsum("nji,njk->nik", R, data.measured_R)
    M = chordal_mean(rel)
    coef[cols] = Rotation.from_matrix(M).as_euler("XYZ") * 1000.0    # the joints RX RY RZ, mrad
    model.coef_ = coef
    model.fixed_ = [n for n in model.fixed_ if n not in names]
    reasons = model.identifiability_.get("fixed_reasons", {})
    for n in names:
        reasons.pop(n, None)
    model.identifiability_["not_identifiable"] = [n for n in model.identifiability_.get("not_identifiable", [])
                                                 if n not in names]
    Rp, _ = model.design(data).predict_pose(model.coef_)
    model.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(orientation_errors(Rp, data.measured_R))
                                                         ** 2)))
