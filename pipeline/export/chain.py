"""What an export carries of a fitted robot model, and what leaving the rest out costs.

A URDF or a controller's kinematic parameters hold a rigid chain, folded into joint origins
(:func:`folded_chain`): the chain nearest the *whole* model (:func:`export_chain`; the fit JSON's
``rigid_chain``, :mod:`pipeline.robot.model.rigid`), not the model's own ``geometry``, ``base`` and
``tool`` parameters, which were fitted together with its other effects. A drive's
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
from ..robot.model.design import Design
from ..robot.arm.effects import RobotData
from ..robot.arm.kinematics import build_error_model, build_model, gravity_torques
from ..robot.model.rigid import CHAIN_EFFECTS, TABLE_EFFECTS, chain_predict, fit_rigid_chain, has_tables, load_chain

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


def box_poses(robot, model, sampled: dict, payloads=None, n: int = COST_POSES, seed: int = 0) -> RobotData:
    """Poses uniform in the joint ranges the model was fitted on (seeded): both approach directions at
    random, the payloads it was fitted at (each pose one of them at random; none recorded: 0 kg),
    temperature uniform in 15-25 degC when the model has thermal (else 20)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    nj = len(lo)
    q = rng.uniform(lo, hi, (n, nj))
    dirs = rng.choice([-1, 1], (n, nj))
    names = {e.name for e, _ in effect_slices(robot, model)}
    pay = np.asarray(payloads if payloads else [0.0], float)
    payload = pay[rng.integers(0, len(pay), n)] if len(pay) > 1 else np.full(n, pay[0])
    temp = (REFERENCE_TEMPERATURE_C + rng.uniform(-5.0, 5.0, n)) if "thermal" in names else \
        np.full(n, REFERENCE_TEMPERATURE_C)
    return model_data(robot, q, dirs, payload, temp)


def leftover_cost(robot, model, sampled: dict, keep, n: int = COST_POSES, seed: int = 0, chain=None,
                  payloads=None) -> dict:
    """How far the model's prediction moves when only ``keep`` is carried (mm), over the sampled box.

    Poses from :func:`box_poses`. ``chain``: the rigid chain the export writes (a model of geometry,
    base and tool, :func:`export_chain`) is what is carried of ``CHAIN_EFFECTS``: with ``keep`` just
    the chain effects, its prediction; with the table effects too, its prediction at the angles the
    tables turn the joints to; without ``chain`` the model's own parameters of the effects in ``keep``.
    Seeded: same model, same numbers.

    Returns
    -------
    dict ``{"left_out": [...], "rms_mm", "max_mm", "n", "conditions"}``
    """
    data = box_poses(robot, model, sampled, payloads, n, seed)
    names = {e.name for e, _ in effect_slices(robot, model)}
    full = predict_with(robot, model, data)
    if chain is not None and set(keep) in (set(CHAIN_EFFECTS), set(CHAIN_EFFECTS + TABLE_EFFECTS)):
        part = chain_predict(robot, model, chain, data, with_tables=set(keep) != set(CHAIN_EFFECTS))
    else:
        part = predict_with(robot, model, data, keep)
    e = np.linalg.norm(full - part, axis=1)
    pay = ", ".join(f"{p:g}" for p in payloads) if payloads else "0"
    return {"left_out": left_out(robot, model, keep), "rms_mm": float(np.sqrt(np.mean(e ** 2))),
            "max_mm": float(e.max()), "n": int(n),
            "conditions": (f"joint angles uniform in the sampled ranges, both approach directions, payload {pay} kg"
                           + (", 15-25 degC" if "thermal" in names else ""))}


def export_chain(robot, model, doc: dict, sampled: dict, with_tables: bool = False) -> tuple[object, str]:
    """The rigid chain an export writes (a fitted model of geometry, base and tool) and how it was made.

    The fit JSON's ``rigid_chain`` (fitted by ``jointcal fit`` to the whole model at the poses it was
    fitted on, :func:`pipeline.robot.model.rigid.fit_rigid_chain`), or with ``with_tables`` its
    ``rigid_chain_with_tables`` (the chain for drives that apply the model's joint tables); for a fit
    JSON written before they were recorded, the chain fitted to the whole model here, over poses
    uniform in the sampled joint box at the payload the model was fitted at (0 kg when not recorded).
    """
    with_tables = with_tables and has_tables(robot, model)
    rec = doc.get("rigid_chain_with_tables" if with_tables else "rigid_chain") if isinstance(doc, dict) else None
    if isinstance(rec, dict):
        try:
            chain = load_chain(robot, rec)
            how = str(rec.get("fitted_to", "the fit's rigid chain"))
            if not rec.get("exact") and "rms_to_model_mm" in rec:
                how += f", {float(rec['rms_to_model_mm']):.4f} mm RMS from the model there"
            return chain, how
        except (KeyError, TypeError, ValueError):
            pass
    payloads = doc.get("payloads_kg") if isinstance(doc, dict) else None
    data = box_poses(robot, model, sampled, payloads)
    chain, info = fit_rigid_chain(robot, model, data, with_tables)
    how = ("the model's own geometry, base and tool (the model has no other effect)" if info["exact"] else
           f"geometry, base and tool fitted here{' with the joint tables applied' if with_tables else ''} to the whole "
           f"model's predictions at {info['n_poses']} poses uniform in the sampled joint ranges (the fit JSON records "
           f"no rigid chain), {info['rms_to_model_mm']:.4f} mm RMS from the model there")
    return chain, how


def folded_chain(robot, model, keep=CHAIN_EFFECTS) -> dict:
    """The model's rigid chain (geometry, base and tool) as joint origins (metres, radians).

    ``keep=()``: the nominal robot's chain (every parameter at zero).

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
    Q = d.configurations(masked_coef(robot, model, keep))[0]
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


def heldout_by_carrier(robot, model, data, chain=None, chain_tables=None) -> dict:
    """Held-out RMS (mm) on measured poses of the full model and of what each export carries.

    Parameters
    ----------
    data : RobotData
        Poses the model was not fitted on, with ``measured_mm`` (n, 3) in the model's base frame.
    chain, chain_tables : RobotErrorModel, optional
        The rigid chain a URDF / UR's parameters carry alone, and the one for drives that apply the
        joint tables (:func:`export_chain`); default the model's own geometry, base and tool.

    Returns
    -------
    dict ``{"n", "full_rms_mm", "chain_rms_mm" (URDF / UR: the exported chain), "chain_tables_rms_mm"
    (its chain for the tables + the joint tables), "model_geometry_rms_mm", "model_geometry_tables_rms_mm"
    (the model's own geometry, base and tool, alone and with the tables), "nominal_rms_mm",
    "chain_left_out", "chain_tables_left_out"}``
    """
    meas = np.asarray(data.measured_mm, float)

    def rms(pred):
        e = np.linalg.norm(meas - pred, axis=1)
        return float(np.sqrt(np.mean(e ** 2)))

    own = rms(predict_with(robot, model, data, CHAIN_EFFECTS))
    own_tables = rms(predict_with(robot, model, data, CHAIN_EFFECTS + TABLE_EFFECTS))
    return {"n": int(data.n), "full_rms_mm": rms(predict_with(robot, model, data)),
            "chain_rms_mm": own if chain is None else rms(chain.predict(data)),
            "chain_tables_rms_mm": own_tables if chain_tables is None else
            rms(chain_predict(robot, model, chain_tables, data, with_tables=True)),
            "model_geometry_rms_mm": own, "model_geometry_tables_rms_mm": own_tables,
            "nominal_rms_mm": rms(predict_with(robot, model, data, ())),
            "chain_left_out": left_out(robot, model, CHAIN_EFFECTS),
            "chain_tables_left_out": left_out(robot, model, CHAIN_EFFECTS + TABLE_EFFECTS)}
