"""Whether a real robot can have a fitted model: parameter bounds, frame deviations, the error budget.

:func:`judge` is the verdict every fit gives on itself (``plausible_``, ``implausible_``): its parameters
within :data:`PLAUSIBLE_BOUNDS`, its frames' shifts and turns from the nominal robot's
(:func:`frame_deviations`, contract section 8) within them too, and each joint's fitted angle error
within the robot's error budget (:mod:`pipeline.robot.model.budget`).
"""

from __future__ import annotations

import numpy as np

from ...core.se3 import ARCSEC_PER_RAD, rotation_angle
from ..arm.kinematics import batch_frames, positions_and_jacobians
from .budget import model_over_budget
from .design import Design

#: Bounds on fitted robot error parameters (reported units) beyond which no real robot goes: a
#: parameter beyond them means the fit went wrong (a direction the data do not determine, a
#: solver that diverged), not that the robot is that far off. Robot errors are arcseconds to a
#: few hundredths of a degree and tenths of a mm to a few mm (a wrong tool length: tens of mm).
MAX_ANGLE_ERROR_DEG = 5.0                   # deg: joint offsets, link twists, base / link rotations
MAX_LENGTH_ERROR_MM = 100.0                 # mm: link lengths and offsets, base, tool, link translations
MAX_COMPLIANCE_ARCSEC_PER_KNM = 36000.0     # arcsec per kN m (10 deg per kN m: 1.7e-4 rad/N m)
MAX_THERMAL_PPM_PER_K = 1000.0              # ppm/K (steel 12, aluminium 23)
PLAUSIBLE_BOUNDS = {"arcsec": MAX_ANGLE_ERROR_DEG * 3600.0, "mm": MAX_LENGTH_ERROR_MM,
                    "arcsec/kNm": MAX_COMPLIANCE_ARCSEC_PER_KNM, "ppm/K": MAX_THERMAL_PPM_PER_K}


def implausible_parameters(parameters) -> list[dict]:
    """The fitted parameters a real robot cannot have (non-finite, or beyond PLAUSIBLE_BOUNDS).

    Parameters
    ----------
    parameters : list of dict with ``name``, ``value``, ``unit`` (``RobotErrorModel.parameters()``)

    Returns
    -------
    list of ``{name, value, unit, bound}`` (bound None for a non-finite value), worst first.
    """
    out = []
    for p in parameters:
        value, unit = float(p["value"]), p.get("unit", "")
        bound = PLAUSIBLE_BOUNDS.get(unit)
        if not np.isfinite(value):
            out.append({"name": p["name"], "value": value, "unit": unit, "bound": None, "excess": np.inf})
        elif bound is not None and abs(value) > bound:
            out.append({"name": p["name"], "value": value, "unit": unit, "bound": bound, "excess": abs(value) / bound})
    out.sort(key=lambda q: -q["excess"])
    return [{k: v for k, v in q.items() if k != "excess"} for q in out]


def describe_implausible(bad: list[dict], limit: int = 2) -> str:
    """One-line description of :func:`implausible_parameters`' result."""
    parts = [f"{q['name']} = {q['value']:.3g} {q['unit']}" + (f" (bound {q['bound']:g})" if q["bound"] else "")
             for q in bad[:limit]]
    return ", ".join(parts) + (f" and {len(bad) - limit} more" if len(bad) > limit else "")


def frame_deviations(model, idx, Q, Q0) -> list[dict]:
    """How far the model's frames move and turn from the nominal robot's over the sampled poses, as
    ``{name, value, unit}`` for the plausibility bounds (:data:`PLAUSIBLE_BOUNDS`).

    Per frame, the largest over the poses of the shift (mm) and the turn (arcsec) of its placement
    relative to the frame before it (the base relative to the world; joint i's link frame relative
    to joint i-1's, joint angle errors included; the SMR relative to the flange), and of the flange
    and the SMR in the base frame (everything before them together). Exact (pinocchio), every effect
    of the model included: what a real robot's frames do, whatever parameters carry it.

    Parameters
    ----------
    model : pin.Model, the error model (:func:`pipeline.robot.arm.kinematics.build_error_model`)
    Q, Q0 : ndarray, shape (n, nq)
        Error-model configurations with the fitted parameters and with none (nominal).
    """
    import pinocchio as pin

    N = idx.joints.size
    names = [f"link{i}" for i in range(1, N + 1)] + ["smr"]
    fids = [model.getFrameId(nm) for nm in names]
    base_joint = int(idx.base[-1]) + 1                      # the last base error joint (pinocchio joint id)
    data = model.createData()

    def frames(Qs):
        """Rotations (n, N + 2, 3, 3) and positions (n, N + 2, 3) m: base, link frames 1..N, SMR."""
        got = batch_frames(model, Qs, names, (base_joint,))
        if got is not None:
            M = [got[base_joint]] + [got[nm] for nm in names]
            return np.stack([m[0] for m in M], axis=1), np.stack([m[1] for m in M], axis=1)
        R = np.empty((len(Qs), N + 2, 3, 3))
        p = np.empty((len(Qs), N + 2, 3))
        for k, q in enumerate(np.asarray(Qs, float)):
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacements(model, data)
            M = [data.oMi[base_joint]] + [data.oMf[f] for f in fids]
            R[k] = [m.rotation for m in M]
            p[k] = [m.translation for m in M]
        return R, p

    def relative(R, p):
        """Each frame relative to the one before it (the base relative to the world)."""
        Rr, pr = R.copy(), p.copy()
        Rr[:, 1:] = np.einsum("nfji,nfjk->nfik", R[:, :-1], R[:, 1:])
        pr[:, 1:] = np.einsum("nfji,nfj->nfi", R[:, :-1], p[:, 1:] - p[:, :-1])
        return Rr, pr

    R1, p1 = frames(Q)
    R0, p0 = frames(Q0)
    Rr1, pr1 = relative(R1, p1)
    Rr0, pr0 = relative(R0, p0)
    # E = rel0^-1 rel: shift rel0.R^T (rel.p - rel0.p), turn angle(rel0.R, rel.R)
    shift = np.linalg.norm(np.einsum("nfji,nfj->nfi", Rr0, pr1 - pr0), axis=2).max(axis=0) * 1000.0
    turn = rotation_angle(Rr0, Rr1).max(axis=0)
    flange_turn = float(rotation_angle(R0[:, N], R1[:, N]).max())
    smr_shift = float(np.linalg.norm(p1[:, -1] - p0[:, -1], axis=1).max()) * 1000.0
    n_frames = N + 2
    arcsec = ARCSEC_PER_RAD
    label = ["the base frame"] + [f"joint {i}'s link frame" for i in range(1, N + 1)] + ["the SMR on the flange"]
    out = []
    for k in range(n_frames):
        out.append({"name": f"{label[k]}: shift from nominal (largest over the sampled poses)",
                    "value": shift[k], "unit": "mm"})
        if k < n_frames - 1:
            out.append({"name": f"{label[k]}: turn from nominal (largest over the sampled poses)",
                        "value": turn[k] * arcsec, "unit": "arcsec"})
    out.append({"name": "the flange: turn from nominal in the base frame (largest over the sampled poses)",
                "value": flange_turn * arcsec, "unit": "arcsec"})
    out.append({"name": "the SMR: distance from its nominal position (largest over the sampled poses)",
                "value": smr_shift, "unit": "mm"})
    return out


def judge(model, d, data) -> tuple[list[dict], bool]:
    """The parameters and frames of the fitted ``model`` a real robot cannot have, and whether there are none:
    ``(implausible, plausible)``, on the design ``d`` of the poses ``data`` it was fitted on.

    Parameters
    ----------
    model : RobotErrorModel
        Fitted (``effects_``, ``coef_``, :meth:`parameters`).
    d : Design
    data : RobotData
    """
    params, checked, k = model.parameters(), [], 0
    for e in model.effects_:
        n = len(e.parameter_names(model.robot))
        checked += e.checked_values(model.robot, params[k:k + n], data.q_deg)
        k += n
    # the frames judged by how far they move and turn (contract section 8: physical deviations, not
    # a parameter that carried a direction the measurements cannot see)
    checked += frame_deviations(d.model, d.idx, d.configurations(model.coef_), d.Q0)
    # and whether a joint's angle error varies beyond the robot's own error budget in the sampled
    # joint box (the yardstick diagnosis uses: pipeline.robot.model.budget)
    implausible = implausible_parameters(checked) + over_budget(model, d, data)
    return implausible, not implausible


def over_budget(model, d, data) -> list[dict]:
    """Joints whose fitted angle error varies beyond the robot's error budget (:mod:`.budget`)."""
    if not any(getattr(e, "on_joint_angle", False) for e in model.effects_) or data.measured_mm is None:
        return []
    nominal, Jext = positions_and_jacobians(d.model, d.Q0)
    return model_over_budget(model.robot, Design, model.effects_, dict(zip(d.names, model.coef_)), data, Jext,
                             d.idx.joints, nominal)
