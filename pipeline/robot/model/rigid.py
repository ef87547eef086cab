"""The rigid chain that best reproduces a fitted robot model, and the conditions a model was made for
(contract section 8: what travels with the model to the robot).

A URDF or a controller's kinematic parameters hold a rigid chain only (geometry, base, tool). The
chain to write is not the model's own ``geometry`` / ``base`` / ``tool`` parameters: those were
fitted *together with* the model's other effects (joint maps, compliance, ...) and are only right
with them. On the real UR10 series B the model's own geometry alone is 0.80 mm held out, a plain
kinematic fit 0.45 mm. :func:`fit_rigid_chain` fits geometry + base + tool to the **model's own
predictions** (every effect, nominal temperature) at the poses the model was fitted on (their
joint angles, approach directions and payloads): where the model is known. Over the whole sampled
joint box instead, a joint map is only interpolated between measured angles in most of the box,
and the chain fitted there was 0.55 mm held out on series B (measured). For a model that is only
geometry, base and tool the chain is that model, exactly.

``jointcal fit`` records the chain in the fit JSON (``rigid_chain``: its parameters and how far it
is from the model on those poses), beside which angle each joint's model takes
(:func:`joint_angle_sources`) and the payloads it was fitted at (:func:`fitted_payloads`).
"""

from __future__ import annotations

import numpy as np

from ...core.se3 import angle_arcsec, orientation_errors
from .design import Design
from .estimator import RobotErrorModel, empty_data
from .weighting import START_WEIGHT_MM_PER_MRAD
from ..arm.effects import REFERENCE_TEMPERATURE_C, RobotData, effect_class

#: the effects a rigid chain (URDF, UR's DH, the ROS driver's YAML) carries
CHAIN_EFFECTS = ("geometry", "base", "tool")
#: the effects a per-joint compensation table carries (functions of the joint's own angle)
TABLE_EFFECTS = ("joint_map", "joint_harmonic", "backlash")
#: the word for a joint whose model takes the commanded angle
COMMANDED = "commanded"


def joint_angle_sources(n_joints: int, grating_joints=()) -> list[str]:
    """Which angle each joint's model takes: ``"commanded"``, or the column of the secondary encoder
    (a grating, ``grating1_deg``) whose readings it was fitted on."""
    g = {int(j) for j in grating_joints}
    return [f"grating{j}_deg" if j in g else COMMANDED for j in range(1, n_joints + 1)]


def secondary_joints(sources) -> list[int]:
    """1-based joints whose model takes a secondary encoder's angle (see :func:`joint_angle_sources`)."""
    return [j + 1 for j, s in enumerate(sources or []) if s != COMMANDED]


def fitted_payloads(payload_kg) -> list[float]:
    """The distinct payloads (kg) of the poses a model was fitted on, ascending."""
    return sorted({round(float(p), 3) + 0.0 for p in np.asarray(payload_kg, float)})


def model_payload(payloads) -> float | None:
    """The one payload a model was fitted at, or None (several, or not recorded)."""
    return float(payloads[0]) if payloads is not None and len(payloads) == 1 else None


def chain_effects(effects) -> list:
    """geometry, base and tool: the model's own ``[[effect]]`` tables where it has them, else the defaults."""
    own = {e.name: e for e in effects if e.name in CHAIN_EFFECTS}
    return [own.get(n) or effect_class(n)() for n in CHAIN_EFFECTS]


def carries_only(robot, model, keep=CHAIN_EFFECTS) -> bool:
    """Whether every effect of the model with a parameter not zero is one of ``keep``."""
    k = 0
    coef = np.asarray(model.coef_, float)
    for e in getattr(model, "effects_", model.effects):
        n = len(e.parameter_names(robot))
        if e.name not in keep and np.any(coef[k:k + n] != 0):
            return False
        k += n
    return True


def has_tables(robot, model) -> bool:
    """Whether the model has a table effect (:data:`TABLE_EFFECTS`) with a parameter not zero."""
    k = 0
    coef = np.asarray(model.coef_, float)
    for e in getattr(model, "effects_", model.effects):
        n = len(e.parameter_names(robot))
        if e.name in TABLE_EFFECTS and np.any(coef[k:k + n] != 0):
            return True
        k += n
    return False


def table_angles_deg(robot, model, data: RobotData) -> np.ndarray:
    """Joint angles (n, N) deg that the drives' compensation tables (``jointcal export --format
    table``: the model's joint_map, joint_harmonic and backlash) turn each joint to at the poses of
    ``data``: the commanded angle plus those effects' angle error."""
    effects = list(getattr(model, "effects_", model.effects))
    d = Design(robot, effects, data)
    coef = np.array(model.coef_, float)
    k = 0
    for e in effects:
        n = len(e.parameter_names(robot))
        if e.name not in TABLE_EFFECTS:
            coef[k:k + n] = 0.0
        k += n
    dq = d.configurations(coef)[:, d.idx.joints] - d.Q0[:, d.idx.joints]
    return np.asarray(data.q_deg, float) + np.rad2deg(dq)


def with_angles(data: RobotData, q_deg) -> RobotData:
    """``data`` at other joint angles (everything else as it is)."""
    return RobotData(np.asarray(q_deg, float), data.dir, data.payload_kg, data.temperature_c, data.torque_nm,
                     data.lower_deg, data.upper_deg, data.measured_mm, data.point_id, data.measured_R, data.sigma_mm,
                     data.sigma_arcsec)


def own_chain(robot, model) -> RobotErrorModel:
    """The model's own geometry, base and tool as a model of its own (defaults where it has none)."""
    effects = chain_effects(getattr(model, "effects_", model.effects))
    by = {p["name"]: p for p in model.parameters()}
    d = Design(robot, effects, empty_data(robot))
    params = [by.get(n, {"name": n, "value": 0.0, "unit": u, "fixed": True}) for n, (u, _) in zip(d.names, d.units)]
    return RobotErrorModel.from_parameters(robot, effects, params)


def fit_rigid_chain(robot, model, data: RobotData, with_tables: bool = False) -> tuple[RobotErrorModel, dict]:
    """The rigid chain nearest the whole model at the poses of ``data`` (module docstring).

    Parameters
    ----------
    robot : Robot
    model : RobotErrorModel
        Fitted.
    data : RobotData
        Poses in the model's own joint angles, with their approach directions and payloads (the
        poses the model was fitted on); temperatures are taken at the nominal 20 degC.
    with_tables : bool
        The chain for a robot whose drives also apply the model's per-joint compensation tables
        (:data:`TABLE_EFFECTS`): fitted at the joint angles the tables turn each joint to
        (:func:`table_angles_deg`), so that chain + tables reproduce the model; else the chain alone.

    Returns
    -------
    chain : RobotErrorModel (geometry, base, tool)
    info : dict ``{"n_poses", "rms_to_model_mm", "max_to_model_mm", "exact"}``: how far the chain
        (with the tables) is from the model on those poses.
    """
    n = data.n
    at = RobotData(np.asarray(data.q_deg, float), np.asarray(data.dir, int), np.asarray(data.payload_kg, float),
                   np.full(n, REFERENCE_TEMPERATURE_C), np.asarray(data.torque_nm, float), data.lower_deg,
                   data.upper_deg)
    # a model fitted on a 6-DoF probe's orientations: the chain reproduces its predicted frames too
    oriented = "tool_ex" in getattr(model, "names_", [])
    R_full, full = model.predict_pose(at) if oriented else (None, model.predict(at))
    if with_tables:
        at = with_angles(at, table_angles_deg(robot, model, at))
    if carries_only(robot, model, CHAIN_EFFECTS + (TABLE_EFFECTS if with_tables else ())):
        chain, exact = own_chain(robot, model), True
    else:
        at.measured_mm = full
        at.measured_R = R_full
        w = (getattr(model, "weight_", None) or START_WEIGHT_MM_PER_MRAD) if oriented else None
        chain, exact = RobotErrorModel(robot, chain_effects(getattr(model, "effects_", model.effects)),
                                       solver="gauss-newton", orientation_weight=w).fit(at), False
    if oriented:
        R_c, P_c = chain.predict_pose(at)
        e = np.linalg.norm(P_c - full, axis=1)
        a = angle_arcsec(orientation_errors(R_c, R_full))
    else:
        e = np.linalg.norm(chain.predict(at) - full, axis=1)
    info = {"n_poses": int(n), "rms_to_model_mm": float(np.sqrt(np.mean(e ** 2))) if n else 0.0,
            "max_to_model_mm": float(e.max()) if n else 0.0, "exact": bool(exact)}
    if oriented and n:
        info.update(orientation_rms_to_model_arcsec=float(np.sqrt(np.mean(a ** 2))),
                    orientation_max_to_model_arcsec=float(a.max()))
    return chain, info


def chain_document(chain: RobotErrorModel, info: dict, payloads, with_tables: bool = False) -> dict:
    """The ``rigid_chain`` (``rigid_chain_with_tables``) entry of a fit JSON."""
    pay = ", ".join(f"{p:g}" for p in payloads) if payloads else "as measured"
    tables = " with the joint tables applied" if with_tables else ""
    how = (f"the model's own geometry, base and tool (the model has no other effect{' than the tables' if with_tables else ''})"
           if info.get("exact") else
           f"geometry, base and tool fitted{tables} to the whole model's predictions at the {info['n_poses']} poses it "
           f"was fitted on (their joint angles, approach directions and payloads: {pay} kg; 20 degC)")
    return {"spec_effects": [e.spec_lines() for e in getattr(chain, "effects_", chain.effects)],
            "parameters": chain.parameters(), "fitted_to": how, **info}


def load_chain(robot, doc: dict) -> RobotErrorModel:
    """The chain of a fit JSON's ``rigid_chain`` entry (KeyError/ValueError when malformed)."""
    from ...core.spec import parse_spec

    spec = parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(doc["spec_effects"]) + "\n", "rigid_chain")
    effects = list(spec.effects)
    if sorted(e.name for e in effects) != sorted(CHAIN_EFFECTS):
        raise ValueError("rigid_chain must have the effects geometry, base and tool")
    return RobotErrorModel.from_parameters(robot, effects, doc["parameters"])


def chain_predict(robot, model, chain, data: RobotData, with_tables: bool = False) -> np.ndarray:
    """SMR positions (n, 3) mm of a rigid chain at the poses of ``data`` (model angles); ``with_tables``:
    at the angles the model's joint tables turn the joints to."""
    return chain.predict(with_angles(data, table_angles_deg(robot, model, data)) if with_tables else data)


def assumptions(doc: dict, n_joints: int) -> str:
    """What the model assumes of the robot it is applied to, in words (the fit JSON's ``joint_angles``
    and ``payloads_kg``)."""
    sec = secondary_joints(doc.get("joint_angles"))
    if sec:
        angles = (f"joints {', '.join(map(str, sec))} at their secondary encoders' angles "
                  f"({', '.join(doc['joint_angles'][j - 1] for j in sec)}: run them closed loop on those encoders), "
                  "the others at their commanded angles")
    elif doc.get("joint_angles"):
        angles = "every joint at its commanded angle"
    else:
        angles = "every joint at its commanded angle (the model does not record which angles it was fitted on)"
    pays = doc.get("payloads_kg")
    one = model_payload(pays)
    payload = (f"payload {one:g} kg (as fitted)" if one is not None else
               f"fitted at payloads {', '.join(f'{p:g}' for p in pays)} kg" if pays else
               "payload not recorded (0 kg assumed)")
    return f"the model assumes {angles}; {payload}; 20 degC"
