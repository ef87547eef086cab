"""Conversion of a jointcal robot campaign into FIGAROH's inputs (issue #6 benchmark).

FIGAROH 1.0.2 takes a URDF, a unified YAML config and a CSV of measurements in metres and
radians. jointcal describes the robot by ``robot.toml`` (contract section 2, modified DH in
mm/deg)::

    T_i = Rz(q_i + theta_offset_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i) . Ry(beta_i)

and the SMR is at ``T_1 ... T_6 . [tool.xyz_mm, 1]``. With ``L_i = Tz(d_i) Tx(a_i) Rx(alpha_i)
Ry(beta_i)`` the URDF below has

* revolute joint ``q{i}`` (axis z) with origin ``L_{i-1} . Rz(theta_offset_i)`` (``L_0 = I``),
  child link ``link{i}`` = the joint frame after the rotation, limits = robot.toml's range;
* the mass of link i (``mass_kg`` at ``com_mm`` in MDH link frame {i}) as ``link{i}``'s
  inertial, at ``L_i . com`` in the joint frame (rotational inertia ``0.01 m`` I, as
  ``pipeline.robot.arm.kinematics`` uses; it plays no part in gravity);
* a fixed joint to ``flange`` at ``L_6`` and a fixed joint to ``smr`` at the tool offset;
* optionally a fixed ``payload`` link carrying the payload mass at the SMR point - the
  same point where ``pipeline.robot.arm.kinematics.gravity_torques`` lumps the payload. FIGAROH has no
  per-pose payload: its elasticity model uses the URDF's gravity torques only, so the
  payload must be a constant of the model (exact when every pose carries the same payload).

URDF origins are ``xyz`` + ``rpy`` (R = Rz(yaw) Ry(pitch) Rx(roll)), written with 17
significant digits; :func:`verify_urdf` checks the URDF's forward kinematics and gravity
torques in pinocchio against ``pipeline.robot.arm.kinematics``.

Runs in jointcal's venv (imports ``pipeline``); the FIGAROH side reads only the files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from pipeline.robot.arm.kinematics import Robot, build_model, gravity_torques, link_placement, positions

JOINT_NAMES = tuple(f"q{i}" for i in range(1, 7))


def _f(v) -> str:
    return repr(float(v))


def _origin(M: pin.SE3) -> str:
    xyz = " ".join(_f(v) for v in M.translation)
    rpy = " ".join(_f(v) for v in pin.rpy.matrixToRpy(M.rotation))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _rz(deg) -> pin.SE3:
    return pin.SE3(pin.utils.rotate("z", np.deg2rad(deg)), np.zeros(3))


def _inertial(mass, com_m) -> str:
    if mass <= 0.0:
        return ""
    i = 0.01 * mass
    return (f'    <inertial><origin xyz="{" ".join(_f(v) for v in com_m)}" rpy="0 0 0"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(i)}" ixy="0" ixz="0" iyy="{_f(i)}" iyz="0" izz="{_f(i)}"/></inertial>\n')


def robot_to_urdf(robot: Robot, payload_kg: float = 0.0) -> str:
    """URDF text of ``robot`` (metres, radians); see the module docstring for the mapping."""
    out = [f'<?xml version="1.0"?>\n<robot name="{robot.name}">\n  <link name="base_link"/>\n']
    parent, prev_L = "base_link", pin.SE3.Identity()
    for i, j in enumerate(robot.joints, start=1):
        placement = prev_L * _rz(j.theta_offset_deg)
        L = link_placement(j)
        com = L.act(np.asarray(j.com_mm, float) / 1000.0)
        out.append(f'  <joint name="q{i}" type="revolute">\n    <parent link="{parent}"/><child link="link{i}"/>\n'
                   f'    {_origin(placement)}\n    <axis xyz="0 0 1"/>\n'
                   f'    <limit lower="{_f(np.deg2rad(j.lower_deg))}" upper="{_f(np.deg2rad(j.upper_deg))}" '
                   f'effort="10000" velocity="100"/>\n  </joint>\n')
        out.append(f'  <link name="link{i}">\n{_inertial(j.mass_kg, com)}  </link>\n')
        parent, prev_L = f"link{i}", L
    out.append(f'  <joint name="flange_joint" type="fixed">\n    <parent link="{parent}"/><child link="flange"/>\n'
               f'    {_origin(prev_L)}\n  </joint>\n  <link name="flange"/>\n')
    tool = pin.SE3(np.eye(3), np.asarray(robot.tool_xyz_mm, float) / 1000.0)
    out.append(f'  <joint name="smr_joint" type="fixed">\n    <parent link="flange"/><child link="smr"/>\n'
               f'    {_origin(tool)}\n  </joint>\n  <link name="smr"/>\n')
    if payload_kg > 0.0:
        out.append('  <joint name="payload_joint" type="fixed">\n    <parent link="smr"/><child link="payload"/>\n'
                   '    <origin xyz="0 0 0" rpy="0 0 0"/>\n  </joint>\n'
                   f'  <link name="payload">\n{_inertial(payload_kg, np.zeros(3))}  </link>\n')
    out.append("</robot>\n")
    return "".join(out)


def verify_urdf(robot: Robot, urdf_path, payload_kg: float = 0.0, n: int = 20, seed: int = 0) -> dict:
    """Compare the URDF model (pinocchio) with ``pipeline.robot.arm.kinematics`` at ``n`` random poses.

    Returns the largest SMR position difference (m) and the largest gravity torque
    difference (N m, payload included).
    """
    model = pin.buildModelFromUrdf(str(urdf_path))
    data = model.createData()
    fid = model.getFrameId("smr")
    names = [model.names[k] for k in range(1, model.njoints)]
    assert names == list(JOINT_NAMES), names
    rng = np.random.default_rng(seed)
    Q = rng.uniform(robot.lower_deg, robot.upper_deg, (n, 6))
    Q[0] = 0.0
    ref_model = build_model(robot)
    ref = positions(ref_model, np.deg2rad(Q)) / 1000.0
    tau_ref = gravity_torques(robot, Q, np.full(n, payload_kg), ref_model)
    dp, dt = 0.0, 0.0
    for k, q in enumerate(np.deg2rad(Q)):
        pin.framesForwardKinematics(model, data, q)
        dp = max(dp, float(np.abs(data.oMf[fid].translation - ref[k]).max()))
        dt = max(dt, float(np.abs(pin.computeGeneralizedGravity(model, data, q) - tau_ref[k]).max()))
    return {"poses": n, "max_position_diff_m": dp, "max_gravity_torque_diff_nm": dt,
            "ok": dp < 1e-9 and dt < 1e-6 * max(1.0, float(np.abs(tau_ref).max()))}


def measurement_csv(q_deg: np.ndarray, xyz_mm: np.ndarray | None = None) -> str:
    """FIGAROH's calibration CSV: ``x1, y1, z1`` (m, marker 1 position) and one column per joint (rad)."""
    cols, rows = [], []
    if xyz_mm is not None:
        cols += ["x1", "y1", "z1"]
    cols += list(JOINT_NAMES)
    for k in range(len(q_deg)):
        vals = [] if xyz_mm is None else list(np.asarray(xyz_mm[k], float) / 1000.0)
        vals += list(np.deg2rad(np.asarray(q_deg[k], float)))
        rows.append(",".join(_f(v) for v in vals))
    return ",".join(cols) + "\n" + "\n".join(rows) + "\n"


def figaroh_config(name: str, data_file: str, non_geom: bool) -> str:
    """FIGAROH 1.0.2 unified YAML config of the geometric (and elastic) calibration.

    ``full_params`` (6 placement errors per joint, reduced to the structural base
    parameters by FIGAROH's QR), the SMR position measured (one marker, x y z), chain from
    ``universe`` to the ``smr`` frame, no outlier removal (threshold 1 km), elastic joint
    gains when ``non_geom``. ``known_baseframe``/``known_tipframe`` are not config keys in
    1.0.2: the runner sets them in ``calib_config`` (both unknown).
    """
    return f"""# FIGAROH 1.0.2 unified config, written by bench/figaroh_convert.py (jointcal issue #6)
meta:
  schema_version: "2.0"
robot:
  name: {name}
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    kinematics:
      base_frame: universe
      tool_frame: smr
      free_flying_base: false
    measurements:
      markers:
        - reference_joint: q6
          measurable_dof: [true, true, true, false, false, false]
      poses:
        base_pose: null
        tool_pose: null
    parameters:
      calibration_level: full_params
      include_non_geometric: {str(bool(non_geom)).lower()}
      outlier_threshold: 1000.0
    data:
      source_file: {data_file}
"""


def write_inputs(robot: Robot, sample_q_deg, sample_xyz_mm, target_q_deg, folder, payload_kg: float,
                 tag: str) -> dict:
    """Write URDF, sample/target CSVs and the two YAML configs (geometric; geometric + elastic).

    Returns the paths and the URDF verification.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    urdf = folder / f"{tag}.urdf"
    urdf.write_text(robot_to_urdf(robot, payload_kg))
    sample = folder / f"{tag}_sample.csv"
    sample.write_text(measurement_csv(sample_q_deg, sample_xyz_mm))
    target = folder / f"{tag}_target_q.csv"
    target.write_text(measurement_csv(target_q_deg))
    configs = {}
    for kind, non_geom in (("geometry", False), ("compliance", True)):
        path = folder / f"{tag}_{kind}.yaml"
        path.write_text(figaroh_config(robot.name, str(sample), non_geom))
        configs[kind] = str(path)
    return {"urdf": str(urdf), "sample_csv": str(sample), "target_csv": str(target), "configs": configs,
            "urdf_check": verify_urdf(robot, urdf, payload_kg)}
