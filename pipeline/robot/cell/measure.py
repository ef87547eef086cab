"""Stage ``simulate measure`` (contract section 10): the virtual cell as a robot.

Given commanded poses, the cell whose truth ``jointcal simulate robot`` wrote moves to them and its
tracker measures the SMR - with the simulator's own physics (:class:`pipeline.robot.cell.simulate.VirtualCell`:
true geometry and tool, transmission error, gravity compliance under the row's payload, backlash by
the row's approach direction, repeatability jitter, the hidden effect, tracker noise). The result is a
campaign folder of section 2 (``robot.toml``, ``poses.csv``, ``tracker.csv``; every pose ``target``
unless the poses say otherwise), so that planning, fitting and correcting can be checked end to end.

A simulator, not the pipeline: it reads the truth. The cell is rebuilt from the truth's drawn values
(not from the seed), so it is the cell that wrote the truth whatever the generator does now.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ...core.errors import InputError
from ...core.files import read_json_input
from ...core.tables import FLOAT, SIGN, STR, check_unique_ids, read_table
from ...core.units import REFERENCE_TEMPERATURE_C
from ..arm.kinematics import Robot, directions_from_sequence, load_robot, parse_robot
from .simulate import VirtualCell, add_orientations, rng_for

#: the generator's stream for measuring given programs (simulate.py uses 1-4)
PROGRAM = 5


def cell_from_truth(robot: Robot, truth: dict) -> VirtualCell:
    """The virtual cell a truth dict describes (:func:`pipeline.robot.cell.simulate.cell_truth`).

    Parameters
    ----------
    robot : Robot
        The cell's nominal robot (N joints).
    truth : dict
        ``mdh_errors``, ``transmission``, ``compliance_arcsec_per_knm``, ``backlash_arcsec``,
        ``tool_xyz_mm``, ``tracker_frame``, ``config``, ``hidden`` (KeyError/ValueError when missing).
    """
    n = len(robot.joints)
    true = robot
    geo = {int(g["joint"]): g for g in truth["mdh_errors"]}
    for i, j in enumerate(robot.joints):
        g = geo.get(i + 1, {})
        true = true.replace_joint(i, theta_offset_deg=j.theta_offset_deg + g.get("dtheta_arcsec", 0.0) / 3600,
                                  d_mm=j.d_mm + g.get("dd_mm", 0.0), a_mm=j.a_mm + g.get("da_mm", 0.0),
                                  alpha_deg=j.alpha_deg + g.get("dalpha_arcsec", 0.0) / 3600,
                                  beta_deg=j.beta_deg + g.get("dbeta_arcsec", 0.0) / 3600)
    true = replace(true, tool_xyz_mm=tuple(float(v) for v in truth["tool_xyz_mm"]))
    if "tool_rpy_deg" in truth:
        true = replace(true, tool_rpy_deg=tuple(float(v) for v in truth["tool_rpy_deg"]))
    trans = {int(t["joint"]): t for t in truth["transmission"]}
    K = max((max(t["orders"]) for t in trans.values()), default=1)
    amp, phase = np.zeros((n, K)), np.zeros((n, K))
    for j, t in trans.items():
        for k, a, p in zip(t["orders"], t["amplitude_arcsec"], t["phase_deg"]):
            amp[j - 1, int(k) - 1] = a / 3600
            phase[j - 1, int(k) - 1] = np.deg2rad(p)
    compliance = np.asarray(truth["compliance_arcsec_per_knm"], float) / 3600 / 1000
    backlash = np.asarray(truth["backlash_arcsec"], float) / 3600
    if compliance.shape != (n,) or backlash.shape != (n,):
        raise ValueError(f"the truth describes {compliance.size} joints, the robot has {n}")
    fr = truth["tracker_frame"]
    return VirtualCell(robot, true, dict(truth["config"]), amp, phase, compliance, backlash, dict(truth.get("hidden") or {}),
                       np.asarray(fr["rotation"], float), np.asarray(fr["translation_mm"], float))


def measure_poses(cell: VirtualCell, q_cmd_deg, dirs=None, payload_kg=None, temperature_c=None, seed=None,
                  closed_loop_joints=(), orientation: bool = False):
    """Move the cell to commanded poses (in visiting order) and measure the SMR.

    Parameters
    ----------
    q_cmd_deg : ndarray, shape (n, N), deg
    dirs : ndarray, shape (n, N), +1/-1, optional
        Sign of each joint's last motion; None: from the visiting order, starting from the middle
        of the joint ranges (as ``simulate robot``).
    payload_kg : ndarray, shape (n,), kg, optional (default 0)
    temperature_c : ndarray, shape (n,), degC, optional (default 20)
    seed : int, optional
        Seed of the jitter and tracker noise (default the cell's).
    closed_loop_joints : sequence of int (1-based)
        Joints that run closed loop on their gratings (the second paper's loop, Eq. 26, until the
        grating reads the command); the others run open loop (the command, with the joint's
        transmission error, compliance, backlash and jitter). Each must have a grating
        (:meth:`VirtualCell.grating_joints`; ValueError otherwise).

    Returns
    -------
    dirs : ndarray, shape (n, N), int
    xyz_mm : ndarray, shape (n, 3), mm, robot base frame
    gratings : ndarray, shape (n, G), deg, or None
        With ``closed_loop_joints``: the readings of the cell's G gratings at the measured poses.
    R : ndarray, shape (n, 3, 3), or None (only with ``orientation``)
        A 6-DoF cell's measured probe frames (:meth:`VirtualCell.measure_pose`).
    """
    q = np.atleast_2d(np.asarray(q_cmd_deg, float))
    n = len(q)
    if dirs is None:
        dirs = directions_from_sequence(q, start_deg=(cell.robot.lower_deg + cell.robot.upper_deg) / 2)
    payload = np.zeros(n) if payload_kg is None else np.asarray(payload_kg, float)
    temp = np.full(n, REFERENCE_TEMPERATURE_C) if temperature_c is None else np.asarray(temperature_c, float)
    rng = rng_for(cell.config["seed"] if seed is None else seed, PROGRAM)
    closed = sorted({int(j) for j in closed_loop_joints})
    have = cell.grating_joints()
    missing = [j for j in closed if j - 1 not in have]
    if missing:
        raise ValueError(f"joint {missing[0]} has no grating on this cell (gratings on joints "
                         f"{', '.join(str(j + 1) for j in have) or 'none'}): it cannot run closed loop")
    if closed:
        J = [j - 1 for j in closed]
        q_true, _ = cell.closed_loop(q, dirs, q[:, J], payload, rng, joints=J)
        g = cell.gratings(q_true)[:, :len(have)]
    else:
        q_true, g = cell.open_loop(q, dirs, payload, rng), None
    P, R = cell.measure_pose(q_true, rng, temp)
    if orientation:
        return np.asarray(dirs, int), P, g, R
    return np.asarray(dirs, int), P, g


def campaign_tables(point_id, sets, q_cmd_deg, dirs, payload_kg, temperature_c, xyz_mm, sigma_mm, gratings=None,
                    R=None, sigma_arcsec=None):
    """``poses.csv`` and ``tracker.csv`` text of a measured program (contract section 2); with
    ``gratings`` (n, G) deg also the grating readings ``grating1_deg …`` (a closed-loop campaign); with
    ``R`` (n, 3, 3) a 6-DoF probe's frames as ``qw, qx, qy, qz`` and ``sigma_arcsec`` (section 13)."""
    q = np.asarray(q_cmd_deg, float)
    poses = pd.DataFrame({"point_id": np.asarray(point_id, str), "set": np.asarray(sets, str)})
    for j in range(q.shape[1]):
        poses[f"q{j + 1}"] = [f"{v:.9f}" for v in q[:, j]]
    for j in range(q.shape[1]):
        poses[f"dir{j + 1}"] = np.asarray(dirs, int)[:, j]
    poses["payload_kg"] = [f"{v:g}" for v in payload_kg]
    poses["temperature_c"] = [f"{v:g}" for v in temperature_c]
    if gratings is not None:
        for j in range(np.asarray(gratings).shape[1]):
            poses[f"grating{j + 1}_deg"] = [f"{v:.7f}" for v in np.asarray(gratings)[:, j]]
    tracker = pd.DataFrame({"point_id": poses["point_id"]})
    for k, c in enumerate(("x_mm", "y_mm", "z_mm")):
        tracker[c] = [f"{v:.6f}" for v in np.asarray(xyz_mm)[:, k]]
    tracker["sigma_mm"] = f"{sigma_mm:g}"
    if R is not None:
        tracker = add_orientations(tracker, R, sigma_arcsec or 0.0)
        for c in ("qw", "qx", "qy", "qz"):
            tracker[c] = [f"{v:.12f}" for v in tracker[c]]
        tracker["sigma_arcsec"] = f"{sigma_arcsec:g}"
    return poses.to_csv(index=False, lineterminator="\n"), tracker.to_csv(index=False, lineterminator="\n")


def measured_campaign(robot: Robot, cell: VirtualCell, point_id, sets, q_cmd_deg, dirs, payload_kg, temperature_c,
                      seed=None, closed_loop_joints=()) -> dict:
    """A campaign folder's files (contract section 2): the cell moved to commanded poses and measured.

    Parameters
    ----------
    robot : Robot
        The cell's nominal robot (``robot.toml``).
    cell : VirtualCell
    point_id, sets : ndarray of str, shape (n,)
    q_cmd_deg : ndarray, shape (n, N), deg
        Commanded poses, in visiting order.
    dirs : ndarray, shape (n, N), int (+1/-1), or None
        Approach directions (None: from the visiting order).
    payload_kg : ndarray, shape (n,), kg
    temperature_c : ndarray, shape (n,), degC
    seed : int, optional
        Seed of the jitter and tracker noise (None: the cell's).
    closed_loop_joints : sequence of int
        Joints (1-based) run closed loop on their gratings.

    Returns
    -------
    dict
        File name (``robot.toml``, ``poses.csv``, ``tracker.csv``) -> text, in writing order.

    Raises
    ------
    ValueError
        A closed-loop joint the cell has no grating on (:func:`measure_poses`).
    """
    dirs, xyz, gratings, R = measure_poses(cell, q_cmd_deg, dirs, payload_kg, temperature_c, seed, closed_loop_joints,
                                           orientation=True)
    poses_csv, tracker_csv = campaign_tables(point_id, sets, q_cmd_deg, dirs, payload_kg, temperature_c, xyz,
                                             float(cell.config.get("tracker_sigma_mm", 0.0)), gratings, R,
                                             cell.config.get("probe_sigma_arcsec"))
    return {"robot.toml": robot.to_toml(), "poses.csv": poses_csv, "tracker.csv": tracker_csv}


# ------------------------------------------------------------------------ the command's inputs
_HINT = "run the stage that makes it first, or `make all`"


def measure_robot(truth_path, campaign, robot_path=None, truth=None) -> Robot:
    """The cell's nominal robot: ``robot_path``, else the truth's own (``robot_toml``), else the
    campaign folder's robot.toml, else the fixture layout (raw/truth/robot/X.json -> raw/robot/X/robot.toml).
    ``truth``: the truth file's contents when already read."""
    if robot_path:
        return load_robot(robot_path)
    truth = read_json_input(truth_path, _HINT) if truth is None else truth
    if isinstance(truth, dict) and isinstance(truth.get("robot_toml"), str):
        return parse_robot(truth["robot_toml"], f"{truth_path} (robot_toml)")
    for cand in (Path(campaign) / "robot.toml",
                 Path(truth_path).parent.parent.parent / "robot" / Path(truth_path).stem / "robot.toml"):
        if cand.is_file():
            return load_robot(cand)
    raise InputError(truth_path, "the truth does not name its robot: give the cell's robot.toml with --robot", 1, 1)


def measure_cell(truth_path, campaign, robot_path=None) -> tuple[Robot, VirtualCell]:
    """The nominal robot (:func:`measure_robot`) and the virtual cell its truth file describes; a file
    that is not such a truth is bad input."""
    truth = None if robot_path else read_json_input(truth_path, _HINT)   # read once (after --robot's robot.toml)
    robot = measure_robot(truth_path, campaign, robot_path, truth)
    truth = read_json_input(truth_path, _HINT) if truth is None else truth
    try:
        return robot, cell_from_truth(robot, truth)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(truth_path, f"not the truth of a virtual robot cell (`jointcal simulate robot` writes one): "
                         f"{exc}", 1, 1) from None


def read_commanded_poses(path, robot: Robot) -> dict:
    """The commanded poses of ``jointcal simulate measure --poses``, read and checked (one located line
    for the first problem: a point_id twice, an unknown set, a joint beyond the robot's range).

    Returns
    -------
    dict: ``point_id`` (n,) str, ``set`` (n,) str (``target`` where empty), ``q_deg`` (n, N) deg,
    ``dirs`` (n, N) +1/-1 or None (from the visiting order), ``payload_kg`` (n,) kg (0 where empty),
    ``temperature_c`` (n,) degC (20 where empty).
    """
    nj = len(robot.joints)
    qcols = [f"q{j}" for j in range(1, nj + 1)]
    frame = read_table(path, {"point_id": STR, **{c: FLOAT for c in qcols}},
                       {"payload_kg": FLOAT, "temperature_c": FLOAT, "set": STR,
                        **{f"dir{j}": SIGN for j in range(1, nj + 1)}})
    lines = frame["_line"].to_numpy(int)
    check_unique_ids(path, frame, "point_id '{id}' appears twice")
    sets = frame["set"].replace("", "target").to_numpy(str) if "set" in frame else np.full(len(frame), "target")
    bad = ~np.isin(sets, ("sample", "target", "repeat"))
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(path, f"set '{sets[k]}' must be sample, target or repeat", lines[k], "set")
    q = frame[qcols].to_numpy(float)
    out = np.any((q < robot.lower_deg) | (q > robot.upper_deg), axis=1)
    if out.any():
        k = int(np.argmax(out))
        j = int(np.argmax((q[k] < robot.lower_deg) | (q[k] > robot.upper_deg)))
        raise InputError(path, f"q{j + 1} = {q[k, j]:g} deg is beyond the robot's joint range "
                         f"({robot.lower_deg[j]:g} to {robot.upper_deg[j]:g} deg): the cell cannot go there",
                         lines[k], f"q{j + 1}")
    dcols = [f"dir{j}" for j in range(1, nj + 1)]
    dirs = None
    if all(c in frame for c in dcols) and not frame[dcols].isna().any().any():
        dirs = frame[dcols].to_numpy(int)
    payload = frame["payload_kg"].fillna(0.0).to_numpy(float) if "payload_kg" in frame else np.zeros(len(q))
    temp = frame["temperature_c"].fillna(20.0).to_numpy(float) if "temperature_c" in frame else np.full(len(q), 20.0)
    return {"point_id": frame["point_id"].to_numpy(str), "set": sets, "q_deg": q, "dirs": dirs, "payload_kg": payload,
            "temperature_c": temp}
