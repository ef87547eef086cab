"""What an export carries of a fitted robot model, and what leaving the rest out costs.

A URDF or a controller's kinematic parameters hold a rigid chain: the fitted model's ``geometry``,
``base`` and ``tool`` effects, folded into joint origins (:func:`folded_chain`). A drive's
compensation table holds what is a function of its own joint's angle (``joint_map``,
``joint_harmonic``; ``backlash`` with a direction column). The rest (compliance with the payload,
thermal expansion, the Chebyshev error transfer matrices) no such format carries.
:func:`leftover_cost` measures the cost: the model's prediction with and without the effects the
format cannot carry, over the joint ranges the model was fitted on.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..core.units import REFERENCE_TEMPERATURE_C
from ..robot.calibrate import Design
from ..robot.effects import RobotData
from ..robot.kinematics import build_error_model, build_model, gravity_torques

#: the effects a rigid chain (URDF, UR's DH, the ROS driver's YAML) carries
CHAIN_EFFECTS = ("geometry", "base", "tool")
#: the effects a per-joint compensation table carries (functions of the joint's own angle)
TABLE_EFFECTS = ("joint_map", "joint_harmonic", "backlash")
#: poses over the sampled joint box on which the cost of what is left out is measured
COST_POSES = 2000


def effect_slices(robot, model) -> list[tuple[object, slice]]:
    """Each fitted effect and the slice of ``model.coef_`` that is its parameters."""
    out, k = [], 0
    for e in getattr(model, "effects_", model.effects):
        n = len(e.parameter_names(robot))
        out.append((e, slice(k, k + n)))
        k += n
    return out


def masked_coef(robot, model, keep) -> np.ndarray:
    """``model.coef_`` with the parameters of every effect not named in ``keep`` set to 0."""
    coef = np.array(model.coef_, float)
    for e, sl in effect_slices(robot, model):
        if e.name not in keep:
            coef[sl] = 0.0
    return coef


def left_out(robot, model, keep) -> list[str]:
    """Names of the fitted effects (with any parameter not zero) that ``keep`` does not carry."""
    out = []
    for e, sl in effect_slices(robot, model):
        if e.name not in keep and np.any(np.asarray(model.coef_)[sl] != 0) and e.name not in out:
            out.append(e.name)
    return out


def model_data(robot, q_deg, dirs, payload_kg, temperature_c) -> RobotData:
    """Commanded poses as the model sees them (gravity torques of the pose and payload, N m)."""
    q = np.asarray(q_deg, float)
    tau = gravity_torques(robot, q, payload_kg)
    return RobotData(q, np.asarray(dirs, int), np.asarray(payload_kg, float), np.asarray(temperature_c, float), tau,
                     robot.lower_deg, robot.upper_deg)


def predict_with(robot, model, data: RobotData, keep=None) -> np.ndarray:
    """Model SMR positions (n, 3) mm with only the effects in ``keep`` (None: all)."""
    d = Design(robot, list(getattr(model, "effects_", model.effects)), data)
    coef = np.asarray(model.coef_, float) if keep is None else masked_coef(robot, model, keep)
    return d.predict(coef)


def leftover_cost(robot, model, sampled: dict, keep, n: int = COST_POSES, seed: int = 0) -> dict:
    """How far the model's prediction moves when only ``keep`` is carried (mm), over the sampled box.

    Poses uniform in the joint ranges the model was fitted on, both approach directions at random,
    no payload (the arm's own weight bends it under compliance), temperature uniform in
    15-25 degC when it has thermal (else 20). Seeded: same model, same numbers.

    Returns
    -------
    dict ``{"left_out": [...], "rms_mm", "max_mm", "n"}``
    """
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    nj = len(lo)
    q = rng.uniform(lo, hi, (n, nj))
    dirs = rng.choice([-1, 1], (n, nj))
    names = {e.name for e, _ in effect_slices(robot, model)}
    payload = np.zeros(n)   # the fit does not record its payloads: the arm's own weight only
    temp = (REFERENCE_TEMPERATURE_C + rng.uniform(-5.0, 5.0, n)) if "thermal" in names else \
        np.full(n, REFERENCE_TEMPERATURE_C)
    data = model_data(robot, q, dirs, payload, temp)
    full = predict_with(robot, model, data)
    part = predict_with(robot, model, data, keep)
    e = np.linalg.norm(full - part, axis=1)
    return {"left_out": left_out(robot, model, keep), "rms_mm": float(np.sqrt(np.mean(e ** 2))),
            "max_mm": float(e.max()), "n": int(n),
            "conditions": ("joint angles uniform in the sampled ranges, both approach directions, no payload"
                           + (", 15-25 degC" if "thermal" in names else ""))}


def folded_chain(robot, model) -> dict:
    """The model's rigid chain (geometry, base and tool) as joint origins (metres, radians).

    Returns
    -------
    dict with
      ``origins``: list of N pin.SE3, joint i's origin in the frame of joint i-1 after its rotation
      (joint 1: in the base frame) at zero command, its axis z, the fitted zero offset folded in;
      ``flange``: pin.SE3 of the flange in the last joint's frame; ``smr``: pin.SE3 of the SMR in
      the flange frame; ``lower_rad``, ``upper_rad``: joint limits of robot.toml.
    """
    emodel, idx = build_error_model(robot)
    nj = len(robot.joints)
    data = model_data(robot, np.zeros((1, nj)), np.ones((1, nj), int), np.zeros(1),
                      np.full(1, REFERENCE_TEMPERATURE_C))
    d = Design(robot, list(getattr(model, "effects_", model.effects)), data, (emodel, idx))
    Q = d.configurations(masked_coef(robot, model, CHAIN_EFFECTS))[0]
    ed = emodel.createData()
    pin.forwardKinematics(emodel, ed, Q)
    pin.updateFramePlacements(emodel, ed)
    frames = [pin.SE3.Identity()] + [ed.oMi[int(j) + 1].copy() for j in idx.joints]
    origins = [frames[i].actInv(frames[i + 1]) for i in range(nj)]
    flange = ed.oMf[emodel.getFrameId("flange")].copy()
    smr = ed.oMf[emodel.getFrameId("smr")].copy()
    return {"origins": origins, "flange": frames[-1].actInv(flange), "smr": flange.actInv(smr),
            "lower_rad": np.deg2rad(robot.lower_deg), "upper_rad": np.deg2rad(robot.upper_deg)}


def chain_positions(chain: dict, q_deg) -> np.ndarray:
    """SMR positions (n, 3) mm of a folded chain (for checks): ``prod origin_i Rz(q_i) . flange . smr``."""
    out = []
    for q in np.deg2rad(np.atleast_2d(q_deg)):
        M = pin.SE3.Identity()
        for o, qi in zip(chain["origins"], q):
            M = M * o * pin.SE3(pin.utils.rotate("z", qi), np.zeros(3))
        out.append((M * chain["flange"] * chain["smr"]).translation * 1000.0)
    return np.array(out)


def nominal_model(robot):
    """The plain pinocchio arm of the nominal robot."""
    return build_model(robot)


def heldout_by_carrier(robot, model, data) -> dict:
    """Held-out RMS (mm) on measured poses of the full model and of what each export carries.

    Parameters
    ----------
    data : RobotData
        Poses the model was not fitted on, with ``measured_mm`` (n, 3) in the model's base frame.

    Returns
    -------
    dict ``{"n", "full_rms_mm", "chain_rms_mm" (URDF / UR), "chain_tables_rms_mm" (+ joint tables),
    "nominal_rms_mm", "chain_left_out", "chain_tables_left_out"}``
    """
    meas = np.asarray(data.measured_mm, float)

    def rms(keep):
        e = np.linalg.norm(meas - predict_with(robot, model, data, keep), axis=1)
        return float(np.sqrt(np.mean(e ** 2)))

    return {"n": int(data.n), "full_rms_mm": rms(None), "chain_rms_mm": rms(CHAIN_EFFECTS),
            "chain_tables_rms_mm": rms(CHAIN_EFFECTS + TABLE_EFFECTS), "nominal_rms_mm": rms(()),
            "chain_left_out": left_out(robot, model, CHAIN_EFFECTS),
            "chain_tables_left_out": left_out(robot, model, CHAIN_EFFECTS + TABLE_EFFECTS)}
