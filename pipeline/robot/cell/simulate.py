"""Stage ``simulate robot``: the virtual KR210 cell (synthetic, seeded, documented physics), and
the same cell for any serial arm of 4 to 7 joints (:func:`cell_config`).

The true robot is the nominal robot.toml plus

* MDH parameter errors (dtheta, dd, da, dalpha, dbeta of every joint), built into a
  perturbed pinocchio model (exact, not linearised);
* joint transmission error: a smooth periodic error of every joint in its own angle,
  ``sum_k A_jk sin(k q_j + phi_jk)`` for orders k = 1, 2, 3 per joint turn;
* gravity compliance: each joint gives way by ``c_j * tau_j`` where ``tau_j`` is the
  pinocchio gravity torque of the arm and the payload at the flange;
* backlash on every joint: the joint stops ``b_j / 2`` short of its command in the
  direction it last moved (it lags);
* repeatability jitter of every joint per move, tracker noise (15 um per axis),
  gratings on joints 1-3 reading the true joint angle with 50 nm on a 300 mm radius.

Every random draw comes from ``numpy.random.default_rng([seed, stream])`` with a stream per
purpose, so the cell (its truth) can be rebuilt from the seed alone: the evaluate stage
executes commands on this cell without reading the truth file.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
import pinocchio as pin

from ...core.files import to_resolution
from ...core.se3 import kabsch_rotation
from ..paper.closedloop import JointPlant, run_loop
from ..arm.effects import effect_class, effect_classes
from ..arm.kinematics import Robot, build_model, directions_from_sequence, gravity_torques, inverse_kinematics, placements, positions

# streams of the generator
TRUTH, POSES, MEASURE, EXECUTE = 1, 2, 3, 4
# decimals of every drawn or derived number in a truth file (deg, arcsec, mm, rotation elements): 1e-8 deg
# is 36 micro-arcseconds, 1e-8 mm ten picometres; rounding noise (1e-16 to 1e-12) stays below it on any machine
TRUTH_DECIMALS = 8

ROBOT_FIXTURE = {
    "seed": 15,                              # chosen among seeds 0-59: closest to Table 2 (raw/README.md)
    "n_sample": 100,
    "n_target": 104,
    "box_mm": [600.0, 1000.0, 600.0],       # x, y, z sizes of the test region (paper Fig. 5)
    "orientation_deg": 10.0,                 # end orientation A, B, C within +-10 deg (paper 3.2)
    "repeat_cycles": 30,                     # ISO 9283, paper 3.1
    "approach_mm": 100.0,
    "diagonal_fractions": [0.2, 0.5, 0.8],   # P1..P3 on the box diagonal
    "payload_kg": 60.0,                      # end effector carried at the flange
    "geometry_sigma": {"dtheta_arcsec": 160.0, "dd_mm": 0.63, "da_mm": 0.63, "dalpha_arcsec": 63.0,
                       "dbeta_arcsec": 63.0},
    "transmission_arcsec": [12.0, 12.0, 12.0, 25.0, 25.0, 25.0],   # amplitude scale per joint
    "compliance_arcsec_per_knm": [2.0, 2.0, 3.0, 25.0, 25.0, 40.0],
    "backlash_arcsec": [45.0, 25.0, 25.0, 62.0, 62.0, 62.0],     # full play
    "jitter_arcsec": 0.5,
    "tracker_sigma_mm": 0.015,
    "grating_resolution_deg": float(np.rad2deg(50e-9 / 0.3)),
    "start_time": "2020-06-01T08:00:00Z",
}


#: the cell of any other robot (:func:`cell_config`): the KR210 cell's physics, scaled to the arm
GENERIC_CELL = {
    "seed": 1,
    "n_sample": 100,
    "n_target": 104,
    "box_fraction": 0.45,                    # test region: this fraction of the arm's reach on each side
    "orientation_deg": 30.0,                 # end orientation within +-30 deg of the mid-range pose
    "repeat_cycles": 0,                      # no ISO 9283 rows (the paper-2 chain's, KR210 only)
    "iso_poses": False,
    "approach_mm": 100.0,
    "diagonal_fractions": [0.2, 0.5, 0.8],
    "payload_fraction": 0.1,                 # payload: this fraction of the arm's mass
    "geometry_sigma": {"dtheta_arcsec": 160.0, "dd_mm": 0.3, "da_mm": 0.3, "dalpha_arcsec": 63.0,
                       "dbeta_arcsec": 63.0},
    "transmission_arcsec": {"arm": 12.0, "wrist": 25.0},
    "backlash_arcsec": {"arm": 25.0, "wrist": 62.0},
    "compliance_deflection_arcsec": 10.0,    # deflection of each joint at its largest gravity torque
    "jitter_arcsec": 0.5,
    "tracker_sigma_mm": 0.015,
    "grating_resolution_deg": float(np.rad2deg(50e-9 / 0.3)),
    "gratings": False,                       # a user's cell: joints read by their own encoders only
    "start_time": "2020-06-01T08:00:00Z",
}


def cell_config(robot: Robot, seed: int | None = None, paper: bool = True) -> dict:
    """The virtual cell's configuration for ``robot``.

    The paper's six-joint cell (:data:`ROBOT_FIXTURE`, the KR210 fixture, byte for byte) when
    ``paper`` and the robot has six joints; otherwise the same physics (raw/README.md) scaled
    to the arm (:data:`GENERIC_CELL`): the last three joints are the wrist (transmission and
    backlash of the KR210's wrist), the others the arm; the test box is ``box_fraction`` of
    the reach (sum of the link lengths and the tool) on each side of the mid-range pose; the
    payload ``payload_fraction`` of the arm's mass; each joint's compliance bends it by
    ``compliance_deflection_arcsec`` at the largest gravity torque it carries over 200 poses
    drawn in its ranges (stream TRUTH, 2); gratings off.
    """
    if paper and robot.n_joints == 6:
        config = dict(ROBOT_FIXTURE)
    else:
        g = dict(GENERIC_CELL)
        n = robot.n_joints
        wrist = np.arange(n) >= n - 3
        reach = sum(abs(j.a_mm) + abs(j.d_mm) for j in robot.joints) + float(np.linalg.norm(robot.tool_xyz_mm))
        mass = sum(j.mass_kg for j in robot.joints)
        payload = round(g.pop("payload_fraction") * mass, 1)
        rng = rng_for(g["seed"] if seed is None else seed, TRUTH, 2)
        Q = rng.uniform(robot.lower_deg, robot.upper_deg, (200, n))
        tau = np.abs(gravity_torques(robot, Q, np.full(len(Q), payload))).max(axis=0)
        side = round(2 * g.pop("box_fraction") * reach, 1)
        config = {**g, "box_mm": [side, side, side], "payload_kg": payload,
                  "transmission_arcsec": np.where(wrist, g["transmission_arcsec"]["wrist"],
                                                  g["transmission_arcsec"]["arm"]).tolist(),
                  "backlash_arcsec": np.where(wrist, g["backlash_arcsec"]["wrist"], g["backlash_arcsec"]["arm"]).tolist(),
                  "compliance_arcsec_per_knm": np.round(g["compliance_deflection_arcsec"] * 1000.0
                                                        / np.maximum(tau, 1.0), 3).tolist()}
    if seed is not None:
        config["seed"] = seed
    return config


def rng_for(seed, stream, *more):
    return np.random.default_rng([int(seed), int(stream), *map(int, more)])


@dataclass
class VirtualCell:
    """The simulated robot in its cell (see the module docstring)."""

    robot: Robot
    true_robot: Robot
    config: dict
    trans_amp_deg: np.ndarray      # (N, 3)
    trans_phase: np.ndarray        # (N, 3) rad
    compliance_deg_per_nm: np.ndarray  # (N,)
    backlash_deg: np.ndarray       # (N,) full play
    hidden: dict
    frame_R: np.ndarray = None     # tracker base frame registration (rotation)
    frame_t: np.ndarray = None     # and translation, mm

    def __post_init__(self):
        self.model_true = build_model(self.true_robot)
        self.model_nominal = build_model(self.robot)
        if self.frame_R is None:
            self.frame_R, self.frame_t = self._register()

    def _register(self):
        """The tracker's base frame: best fit (rigid, Kabsch) of the true robot onto the nominal one
        over registration poses in the test region, as a cell set-up does before a campaign."""
        rng = rng_for(self.config["seed"], TRUTH, 1)
        Q = draw_poses(self.robot, 60, rng, self.config["box_mm"], self.config["orientation_deg"], self.model_nominal)
        payload = np.full(len(Q), float(self.config["payload_kg"]))
        true = positions(self.model_true, np.deg2rad(Q + self.repeatable_offset_deg(Q, payload)))
        nom = positions(self.model_nominal, np.deg2rad(Q))
        a, b = true - true.mean(0), nom - nom.mean(0)
        R, _ = kabsch_rotation(a.T @ b)
        return R, nom.mean(0) - true.mean(0) @ R.T

    # -------------------------------------------------------------------------- physics
    def transmission_deg(self, q_deg):
        q = np.deg2rad(np.atleast_2d(q_deg))[:, :, None]
        k = np.arange(1, self.trans_amp_deg.shape[1] + 1)
        out = (self.trans_amp_deg * np.sin(k * q + self.trans_phase)).sum(axis=2)
        if self.hidden_class is not None:
            self.hidden_class.inject_joint_error(self.hidden, q[:, :, 0], out)
        return out

    @property
    def hidden_class(self):
        """The class of the hidden effect (its ``inject_*`` hooks), or None."""
        return effect_class(self.hidden["effect"]) if self.hidden else None

    def repeatable_offset_deg(self, q_cmd_deg, payload_kg):
        """Transmission error + gravity deflection, (n, N) deg."""
        tau = gravity_torques(self.true_robot, q_cmd_deg, payload_kg, self.model_true)
        return self.transmission_deg(q_cmd_deg) - self.compliance_deg_per_nm * tau

    def open_loop(self, q_cmd_deg, dirs, payload_kg, rng):
        """True joint angles (n, N) deg reached by commands approached in directions ``dirs``."""
        q_cmd_deg = np.atleast_2d(q_cmd_deg)
        jitter = rng.normal(0.0, self.config["jitter_arcsec"] / 3600.0, q_cmd_deg.shape)
        return (q_cmd_deg + self.repeatable_offset_deg(q_cmd_deg, payload_kg)
                - np.asarray(dirs) * self.backlash_deg / 2 + jitter)

    def measure(self, q_true_deg, rng, temperature_c=None):
        """Tracker reading of the SMR (n, 3) mm in the base frame."""
        P = positions(self.model_true, np.deg2rad(q_true_deg)) @ self.frame_R.T + self.frame_t
        if self.hidden_class is not None:
            P = self.hidden_class.inject_measurement(self.hidden, P, temperature_c)
        return P + rng.normal(0.0, self.config["tracker_sigma_mm"], P.shape)

    @property
    def six_dof(self) -> bool:
        """Whether the cell's tracker measures the probe frame's orientation too (``--probe 6dof``)."""
        return self.config.get("probe") == "6dof"

    def measure_pose(self, q_true_deg, rng, temperature_c=None):
        """Tracker reading of the probe: positions (n, 3) mm as :meth:`measure` (the same draws) and, on a
        6-DoF cell, the probe frames (n, 3, 3) in the base frame with the probe's noise (a rotation of
        ``probe_sigma_arcsec`` per axis, drawn after the positions'); None on a cell of positions only."""
        P = self.measure(q_true_deg, rng, temperature_c)
        if not self.six_dof:
            return P, None
        from scipy.spatial.transform import Rotation

        R, _ = placements(self.model_true, np.deg2rad(np.atleast_2d(q_true_deg)), "smr")
        R = np.einsum("ij,njk->nik", self.frame_R, R)
        if self.hidden_class is not None and hasattr(self.hidden_class, "inject_orientation"):
            R = self.hidden_class.inject_orientation(self.hidden, R)
        noise = rng.normal(0.0, np.deg2rad(self.config["probe_sigma_arcsec"] / 3600.0), (len(R), 3))
        return P, Rotation.from_rotvec(noise).as_matrix() @ R

    def gratings(self, q_true_deg):
        res = self.config["grating_resolution_deg"]
        return np.round(np.atleast_2d(q_true_deg)[:, :3] / res) * res

    #: joints (0-based) with an absolute grating on the paper's cell
    GRATING_JOINTS = (0, 1, 2)

    def grating_joints(self) -> tuple:
        """0-based joints read by a grating: joints 1-3 on the paper's cell, none on a user's cell."""
        return self.GRATING_JOINTS if self.config.get("gratings", True) else ()

    def closed_loop(self, q_cmd_deg, dirs, target123_deg, payload_kg, rng, trace=False, joints=None):
        """Command ``q_cmd``, then run the grating loop on joints 1-3 to ``target123``.

        ``joints``: the 0-based grating joints to run closed loop (default 1-3, in which case
        ``target123_deg`` holds their targets, shape (n, len(joints))); the others stay open loop.
        Returns true joint angles (n, N) deg and the loop's result (cycles, final errors).
        """
        J = slice(0, 3) if joints is None else np.asarray(joints, int)
        q_cmd_deg = np.atleast_2d(q_cmd_deg)
        n = len(q_cmd_deg)
        k = 3 if joints is None else len(J)
        q_true = self.open_loop(q_cmd_deg, dirs, payload_kg, rng)
        offset = self.repeatable_offset_deg(q_cmd_deg, payload_kg)[:, J]
        jitter = q_true[:, J] - (q_cmd_deg[:, J] + offset - np.asarray(dirs)[:, J] * self.backlash_deg[J] / 2)
        play = np.broadcast_to(self.backlash_deg[J], (n, k))
        plant = JointPlant(q_cmd_deg[:, J].ravel().copy(), play.ravel().copy(),
                           (q_cmd_deg[:, J] - np.asarray(dirs)[:, J] * play / 2).ravel(),
                           (offset + jitter).ravel(), self.config["grating_resolution_deg"])
        res = run_loop(plant, np.asarray(target123_deg, float).ravel(), trace=trace)
        q_true = q_true.copy()
        q_true[:, J] = plant.output_deg.reshape(n, k)
        return q_true, res


def make_cell(robot: Robot, config: dict | None = None, hidden: dict | None = None) -> VirtualCell:
    """Draw the cell's truth from ``config['seed']`` (stream TRUTH); pure and deterministic."""
    config = dict(ROBOT_FIXTURE if config is None else config)
    rng = rng_for(config["seed"], TRUTH)
    g = config["geometry_sigma"]
    true = robot
    geo = []
    for i, j in enumerate(robot.joints):
        d = {"dtheta_arcsec": rng.normal(0, g["dtheta_arcsec"]), "dd_mm": rng.normal(0, g["dd_mm"]),
             "da_mm": rng.normal(0, g["da_mm"]), "dalpha_arcsec": rng.normal(0, g["dalpha_arcsec"]),
             "dbeta_arcsec": rng.normal(0, g["dbeta_arcsec"])}
        geo.append(d)
        true = true.replace_joint(i, theta_offset_deg=j.theta_offset_deg + d["dtheta_arcsec"] / 3600,
                                  d_mm=j.d_mm + d["dd_mm"], a_mm=j.a_mm + d["da_mm"],
                                  alpha_deg=j.alpha_deg + d["dalpha_arcsec"] / 3600,
                                  beta_deg=j.beta_deg + d["dbeta_arcsec"] / 3600)
    n_joints = robot.n_joints
    amp = np.asarray(config["transmission_arcsec"], float)[:, None] * rng.uniform(0.5, 1.0, (n_joints, 3)) / 3600
    amp[:, 2] *= 0.5
    phase = rng.uniform(0, 2 * np.pi, (n_joints, 3))
    compliance = (np.asarray(config["compliance_arcsec_per_knm"], float) * rng.uniform(0.8, 1.2, n_joints)
                  / 3600 / 1000)
    backlash = np.asarray(config["backlash_arcsec"], float) * rng.uniform(0.8, 1.2, n_joints) / 3600
    hidden = dict(hidden or {})
    if hidden:
        true = effect_class(hidden["effect"]).inject_truth(hidden, true, compliance, backlash)
    if config.get("probe") == "6dof":
        # the probe's mounting on the flange is off its nominal too (its own stream: the rest of the cell
        # is the cell of positions only, draw for draw)
        turn = rng_for(config["seed"], TRUTH, 3).normal(0.0, config["probe_mount_sigma_arcsec"], 3) / 3600.0
        true = replace(true, tool_rpy_deg=tuple(np.add(robot.tool_rpy_deg, turn)))
    return VirtualCell(robot, true, config, amp, phase, compliance, backlash, hidden)


def cell_truth(cell: VirtualCell) -> dict:
    """Every drawn parameter, in the contract's units (for raw/truth; never read by the pipeline)."""
    geo = []
    for i, (j0, j1) in enumerate(zip(cell.robot.joints, cell.true_robot.joints)):
        geo.append({"joint": i + 1, "dtheta_arcsec": (j1.theta_offset_deg - j0.theta_offset_deg) * 3600,
                    "dd_mm": j1.d_mm - j0.d_mm, "da_mm": j1.a_mm - j0.a_mm,
                    "dalpha_arcsec": (j1.alpha_deg - j0.alpha_deg) * 3600,
                    "dbeta_arcsec": (j1.beta_deg - j0.beta_deg) * 3600})
    # "generator": this module's name when the shipped truth (raw/truth) was written (pipeline.robot_simulate,
    # now pipeline.robot.cell.simulate); kept so that `make fixtures-robot` rewrites it byte for byte
    # drawn and derived numbers at a fixed resolution (TRUTH_DECIMALS): the tracker frame comes from an
    # SVD whose last bits differ between CPUs and BLAS builds (issue 15); the configuration is written as given
    return {"generator": "pipeline.robot_simulate", "synthetic": True, "config": cell.config, "hidden": cell.hidden,
            **to_resolution({"mdh_errors": geo,
            "transmission": [{"joint": i + 1, "orders": [1, 2, 3],
                              "amplitude_arcsec": (cell.trans_amp_deg[i] * 3600).tolist(),
                              "phase_deg": np.rad2deg(cell.trans_phase[i]).tolist()}
                             for i in range(cell.robot.n_joints)],
            "compliance_arcsec_per_knm": (cell.compliance_deg_per_nm * 3600 * 1000).tolist(),
            "backlash_arcsec": (cell.backlash_deg * 3600).tolist(),
            "tool_xyz_mm": list(cell.true_robot.tool_xyz_mm),
            **({"tool_rpy_deg": list(cell.true_robot.tool_rpy_deg)} if cell.six_dof else {}),
            "tracker_frame": {"rotation": cell.frame_R.tolist(), "translation_mm": cell.frame_t.tolist()}},
                            TRUTH_DECIMALS)}


# ------------------------------------------------------------------------------ poses
def reference_pose(robot: Robot, model=None):
    """SMR pose at the middle of the joint ranges: centre of the test box and reference orientation."""
    model = model or build_model(robot)
    mid = (robot.lower_deg + robot.upper_deg) / 2
    R, p = placements(model, np.deg2rad(mid)[None], "smr")
    return mid, R[0], p[0]


def draw_poses(robot: Robot, n: int, rng, box_mm, orientation_deg, model=None, batch=4000):
    """Joint angles (n, N) deg uniform in the ranges, SMR inside the box, orientation within +-limit."""
    model = model or build_model(robot)
    _, R0, c = reference_pose(robot, model)
    half = np.asarray(box_mm, float) / 2
    out = []
    while sum(len(o) for o in out) < n:
        Q = rng.uniform(robot.lower_deg, robot.upper_deg, (batch, robot.n_joints))
        R, P = placements(model, np.deg2rad(Q), "smr")
        rel = np.einsum("ji,njk->nik", R0, R)
        abc = np.rad2deg(np.array([pin.rpy.matrixToRpy(r) for r in rel]))
        ok = (np.abs(P - c) <= half).all(axis=1) & (np.abs(abc) <= orientation_deg).all(axis=1)
        out.append(Q[ok])
    return np.concatenate(out)[:n]


def repeat_poses(robot: Robot, config: dict, model=None):
    """ISO 9283 poses P1..P3 on the box diagonal and the start points of the three approaches.

    Returns dict label -> {"q": (N,), "starts": {approach: (N,)}} (deg). Approach ``+x`` ends
    with a 100 mm move in +x (it starts 100 mm in -x of the pose).
    """
    model = model or build_model(robot)
    mid, R0, c = reference_pose(robot, model)
    half = np.asarray(config["box_mm"], float) / 2
    out = {}
    q0 = np.deg2rad(mid)
    for k, f in enumerate(config["diagonal_fractions"]):
        p = c - half + 2 * half * f
        q = inverse_kinematics(model, R0, p, q0)
        starts = {}
        for a, u in zip(("+x", "+y", "+z"), np.eye(3)):
            starts[a] = np.rad2deg(inverse_kinematics(model, R0, p - config["approach_mm"] * u, q))
        out[f"P{k + 1}"] = {"q": np.rad2deg(q), "starts": starts, "xyz_mm": p}
    return out


# ---------------------------------------------------------------------------- campaign
def simulate_robot(robot: Robot, config: dict | None = None, hidden: dict | None = None):
    """Simulate the campaign: poses.csv and tracker.csv frames and the truth dict."""
    config = dict(ROBOT_FIXTURE if config is None else config)
    cell = make_cell(robot, config, hidden)
    model = cell.model_nominal
    rng = rng_for(config["seed"], POSES)
    n_s, n_t = config["n_sample"], config["n_target"]
    Q = draw_poses(robot, n_s + n_t, rng, config["box_mm"], config["orientation_deg"], model)
    ids = [f"S{k + 1:03d}" for k in range(n_s)] + [f"T{k + 1:03d}" for k in range(n_t)]
    sets = ["sample"] * n_s + ["target"] * n_t
    order = rng.permutation(n_s + n_t)
    rows = [{"point_id": ids[k], "set": sets[k], "q": Q[k], "pose": "", "approach": "", "cycle": None}
            for k in order]
    visits = [r["q"] for r in rows]
    rep = repeat_poses(robot, config, model) if config.get("iso_poses", True) else {}
    for c in range(1, config["repeat_cycles"] + 1):
        for label, P in rep.items():
            for a, qs in P["starts"].items():
                visits.append(qs)
                rows.append({"point_id": None, "q": qs})       # approach start: visited, not measured
                visits.append(P["q"])
                rows.append({"point_id": f"R{c:02d}_{label}_{a}", "set": "repeat", "q": P["q"], "pose": label,
                             "approach": a, "cycle": c})
    mid = (robot.lower_deg + robot.upper_deg) / 2
    dirs_all = directions_from_sequence(np.array(visits), start_deg=mid)
    keep = [k for k, r in enumerate(rows) if r["point_id"] is not None]
    rows = [rows[k] for k in keep]
    dirs = dirs_all[keep]
    q_cmd = np.array([r["q"] for r in rows])
    n = len(rows)
    payload = np.full(n, float(config["payload_kg"]))
    t = np.arange(n) * 20.0
    temperature = 20.3 + 0.4 * t / t[-1]
    if cell.hidden_class is not None:
        payload, temperature = cell.hidden_class.inject_conditions(
            cell.hidden, payload, temperature, t, lambda k: rng_for(config["seed"], POSES, k))
    temperature = np.round(temperature, 2)
    mrng = rng_for(config["seed"], MEASURE)
    q_true = cell.open_loop(q_cmd, dirs, payload, mrng)
    xyz, R_meas = cell.measure_pose(q_true, mrng, temperature)
    g = cell.gratings(q_true)
    start = dt.datetime.fromisoformat(config["start_time"].replace("Z", "+00:00"))
    poses = pd.DataFrame({"point_id": [r["point_id"] for r in rows], "set": [r["set"] for r in rows]})
    for j in range(robot.n_joints):
        poses[f"q{j + 1}"] = q_cmd[:, j]
    for j in range(robot.n_joints):
        poses[f"dir{j + 1}"] = dirs[:, j]
    poses["payload_kg"] = payload
    poses["temperature_c"] = temperature
    poses["timestamp"] = [(start + dt.timedelta(seconds=float(s))).strftime("%Y-%m-%dT%H:%M:%SZ") for s in t]
    poses["pose"] = [r["pose"] for r in rows]
    poses["approach"] = [r["approach"] for r in rows]
    poses["cycle"] = [r["cycle"] for r in rows]
    for j in range(3 if config.get("gratings", True) else 0):
        poses[f"grating{j + 1}_deg"] = g[:, j]
    tracker = pd.DataFrame({"point_id": poses["point_id"], "x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
                            "sigma_mm": config["tracker_sigma_mm"]})
    if R_meas is not None:
        tracker = add_orientations(tracker, R_meas, config["probe_sigma_arcsec"])
    truth = cell_truth(cell)
    # the ISO poses come from a Newton solve: a joint that stays at 0 comes out as +-1e-14 deg (issue 15)
    truth["repeat_poses"] = to_resolution({k: {"q_deg": v["q"], "xyz_mm": v["xyz_mm"]} for k, v in rep.items()},
                                          TRUTH_DECIMALS)
    return poses, tracker, truth


def simulated_campaign(robot: Robot, config: dict, hidden: dict | None = None) -> tuple[dict, dict, int]:
    """:func:`simulate_robot` as the files ``jointcal simulate robot`` writes.

    Returns
    -------
    (files, truth, n): the campaign's ``poses.csv`` and ``tracker.csv`` texts by name, the truth
    (with the cell's nominal ``robot_toml``: ``jointcal simulate measure`` rebuilds the cell from it)
    and the number of measured poses.
    """
    poses, tracker, truth = simulate_robot(robot, config, hidden)
    truth["robot_toml"] = robot.to_toml()
    return {"poses.csv": format_poses_csv(poses), "tracker.csv": format_tracker_csv(tracker)}, truth, len(poses)


def format_poses_csv(poses: pd.DataFrame) -> str:
    out = poses.copy()
    j = 1
    while f"q{j}" in out:
        out[f"q{j}"] = out[f"q{j}"].map(lambda v: f"{v:.6f}")
        j += 1
    for j in range(1, 4):
        if f"grating{j}_deg" in out:
            out[f"grating{j}_deg"] = out[f"grating{j}_deg"].map(lambda v: f"{v:.7f}")
    out["payload_kg"] = out["payload_kg"].map(lambda v: f"{v:.1f}")
    out["temperature_c"] = out["temperature_c"].map(lambda v: f"{v:.2f}")
    out["cycle"] = out["cycle"].map(lambda v: "" if v is None or pd.isna(v) else str(int(v)))
    return out.to_csv(index=False, lineterminator="\n")


def format_tracker_csv(tracker: pd.DataFrame) -> str:
    out = tracker.copy()
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = out[c].map(lambda v: f"{v:.4f}")
    out["sigma_mm"] = out["sigma_mm"].map(lambda v: f"{v:g}")
    for c in ("qw", "qx", "qy", "qz"):
        if c in out:
            out[c] = out[c].map(lambda v: f"{v:.12f}")
    if "sigma_arcsec" in out:
        out["sigma_arcsec"] = out["sigma_arcsec"].map(lambda v: f"{v:g}")
    return out.to_csv(index=False, lineterminator="\n")


#: a 6-DoF probe's orientation noise (arcsec, 1 sigma per axis: a T-Mac repeats to about 0.006 deg) and
#: how far its true mounting is off the nominal one (arcsec per axis), for ``simulate robot --probe 6dof``
PROBE_6DOF = {"probe": "6dof", "probe_sigma_arcsec": 20.0, "probe_mount_sigma_arcsec": 120.0}


def add_orientations(tracker: pd.DataFrame, R, sigma_arcsec: float) -> pd.DataFrame:
    """The tracker table with a 6-DoF probe's frames (n, 3, 3) as ``qw, qx, qy, qz`` (scalar first, w >= 0)
    and ``sigma_arcsec``."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R, float)).as_quat()[:, [3, 0, 1, 2]]
    q[q[:, 0] < 0] *= -1.0
    out = tracker.copy()
    for k, c in enumerate(("qw", "qx", "qy", "qz")):
        out[c] = q[:, k]
    out["sigma_arcsec"] = float(sigma_arcsec)
    return out


def hidden_robot_effect(text: str, seed: int, n_joints: int = 6) -> dict:
    """Parse ``EFFECT[:TARGET]`` and draw a realistic size (seeded) for a hidden effect.

    Sizes are drawn by the effect's class (:meth:`~pipeline.robot.arm.effects.RobotEffect.hidden`):
    thermal: 8-14 ppm/K with an 8 K temperature rise over the campaign; tool: 0.3-0.8 mm SMR
    offset; base: 0.3-0.8 mm and 20-60 arcsec; joint_harmonic:J: order 4-8 per turn, 15-40
    arcsec on joint J; backlash:J: 40-120 arcsec more play on joint J; compliance:J:
    +20-60 arcsec/kNm on joint J with a payload that varies 0-150 kg.
    """
    rng = np.random.default_rng([seed, 99])
    name, _, target = text.partition(":")
    joint = int(target) if target else int(rng.integers(1, n_joints + 1))  # drawn first, whatever the effect
    if not 1 <= joint <= n_joints:
        raise ValueError(f"joint {joint} of --hidden {text}: the robot has joints 1..{n_joints}")
    try:
        cls = effect_class(name)
    except KeyError:
        cls = None
    if cls is None or not cls.hidden_syntax:
        raise ValueError(f"unknown hidden robot effect {name!r}; use {hidden_effects_help()}")
    return cls.hidden(rng, target, joint)


def hidden_effects_help() -> str:
    """The ``--hidden`` choices, from the robot effects that can be simulated."""
    names = [cls.hidden_syntax for cls in effect_classes() if cls.hidden_syntax]
    return ", ".join(names[:-1]) + " or " + names[-1]
