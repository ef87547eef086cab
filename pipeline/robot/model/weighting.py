"""Variance components: how a 6-DoF fit weighs its orientation rows against its positions.

The weight (mm per mrad, the fit's public ``weight_``) is the ratio of the fit's RMS position residual
per axis (mm) to its RMS orientation residual per axis (mrad), refitted until it changes by less than
:data:`VCE_RTOL` (:func:`variance_components`). Each next weight is where the iteration ends on the fit
linearised at its solution (:func:`linear_weight`), else the plain or secant step (:func:`vce_next`).
A fit on the positions alone registers the probe's mounting from the orientations (:func:`register_mounting`).
"""

from __future__ import annotations

import numpy as np

from ...core.se3 import ARCSEC_PER_MRAD, angle_arcsec, chordal_mean, orientation_errors
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
    return {
        "method": "stated" if model.orientation_weight else "variance components",
        "rule": ("the orientation rows (mrad) weigh orientation_weight_mm_per_mrad mm each: the ratio of the "
                 "fit's RMS position residual per axis (mm) to its RMS orientation residual per axis (mrad), "
                 f"refitted until it changes by less than {VCE_RTOL:.0%}"),
        "started_from": source, "iterations": len(history),
        "orientation_weight_mm_per_mrad": float(model.weight_),
        "position_sigma_mm": sp, "orientation_sigma_arcsec": so * ARCSEC_PER_MRAD}


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
    if not (sp > 0 and so > 0) or abs(float(np.log(sp / so / model.weight_))) >= VCE_RTOL:
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
