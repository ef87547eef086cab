"""Robot campaign ingest (contract section 2): validate and join poses.csv + tracker.csv.

Checks (each a located InputError): required columns (misspellings named), NaN and
non-numbers, duplicate point_id, tracker points without a pose and poses without a
tracker point, unknown ``set`` values, joint angles outside the joint range of robot.toml
(with a hint when the value would fit in radians), tracker coordinates that look like
metres, ``repeat`` rows without pose/approach/cycle, and ``campaign.toml`` (optional: only
``frame = "tracker"`` or ``"base"``).

Then, on a campaign that passes those checks, the nominal-consistency check of contract
section 2 (:func:`pipeline.robot.campaign.frame.consistency`): after the best rigid fit of the nominal
SMR positions onto the measured ones (over the sample poses) the residual must be what a real
robot's errors can be (:data:`pipeline.robot.campaign.frame.MAX_RMS_MM`); otherwise the campaign is
refused with the likely cause (joint angles in radians, positions in metres, a joint's sign
flipped, two joints swapped, a wrong tool, a few wild points, or, with ``frame = "base"``,
points that are in the tracker's frame).

With ``frame = "tracker"`` the rigid tracker-to-base transform is that fit's inverse (the best
rigid fit of the measured points onto the nominal positions over the sample poses); every
tracker point is moved into the base frame with it. The raw points stay in
``x_tracker_mm/y_tracker_mm/z_tracker_mm`` and the transform travels with the table as
``frame.attrs["jointcal_frame"] = {"frame": ..., "tracker_to_base": 4x4 list (mm)}``.

The output (``interim/robot/poses.parquet``) has one row per pose in visiting order with
q1..qN (deg), dir1..dirN (N = the robot's joint count, 4 to 7; derived from the visiting order when absent: sign of
q_j(this) - q_j(previous pose), carrying the previous sign when unchanged, +1 for the first
pose), payload_kg, temperature_c, x_mm/y_mm/z_mm (base frame), the nominal SMR position
xn/yn/zn (mm), the gravity torques tau1..tauN (N m), the optional grating readings, and with
``frame = "tracker"`` the raw tracker-frame points x_tracker_mm/y_tracker_mm/z_tracker_mm.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from ...core.errors import InputError, parse_toml
from ...core.files import read_text_input
from ...core.tables import (FLOAT, INT, SIGN, STR, TIME, Problems, check_unique_ids, csv_header, find_joint_columns,
                            read_table)
from . import frame as rf
from ..arm.effects import REFERENCE_TEMPERATURE_C, RobotData
from ..arm.kinematics import Robot, build_model, directions_from_sequence, gravity_torques, load_robot, positions

def poses_required(n: int = 6) -> dict:
    """Required poses.csv columns of an ``n``-joint robot: point_id, set, q1..qn."""
    return {"point_id": STR, "set": STR, **{f"q{j}": FLOAT for j in range(1, n + 1)}}


def poses_optional(n: int = 6) -> dict:
    """Optional poses.csv columns of an ``n``-joint robot (dir1..dirn, payload, temperature, ...)."""
    return {**{f"dir{j}": SIGN for j in range(1, n + 1)}, "payload_kg": FLOAT, "temperature_c": FLOAT,
            "timestamp": TIME, "pose": STR, "approach": STR, "cycle": INT,
            **{f"grating{j}_deg": FLOAT for j in range(1, 4)}}


POSES_REQUIRED = poses_required(6)
POSES_OPTIONAL = poses_optional(6)
TRACKER_REQUIRED = {"point_id": STR, "x_mm": FLOAT, "y_mm": FLOAT, "z_mm": FLOAT}
TRACKER_OPTIONAL = {"sigma_mm": FLOAT, "qw": FLOAT, "qx": FLOAT, "qy": FLOAT, "qz": FLOAT, "sigma_arcsec": FLOAT}
#: a 6-DoF probe's orientation in tracker.csv: a unit quaternion, scalar first (contract section 13)
QUATERNION = ("qw", "qx", "qy", "qz")
#: the raw (tracker-frame) quaternion of a ``frame = "tracker"`` campaign
RAW_QUATERNION = ("qw_tracker", "qx_tracker", "qy_tracker", "qz_tracker")
SETS = ("sample", "target", "repeat")
FRAMES = ("base", "tracker")
#: key of ``DataFrame.attrs`` holding ``{"frame": "base" | "tracker", "tracker_to_base": 4x4 list (mm)}``
FRAME_ATTR = "jointcal_frame"
RAW_COLUMNS = ("x_tracker_mm", "y_tracker_mm", "z_tracker_mm")


def _dup(path, frame, problems):
    check_unique_ids(path, frame, "duplicate point_id '{id}'; each point appears once", problems=problems)


def _member(series, values) -> pd.Series:
    """``series.isin(values)`` for text columns by a Python set (pandas' isin on its Arrow strings is slow
    at a user's scale: docs/speed.md "Measurements behind the code"); NaN is no member."""
    pool = set(v for v in values if isinstance(v, str))
    return pd.Series([isinstance(v, str) and v in pool for v in series.tolist()], index=series.index, dtype=bool)


def load_robot_campaign(folder, problems: Problems | None = None):
    """Read and check a robot campaign folder (every check of the module docstring).

    Parameters
    ----------
    folder : path-like
        Campaign folder: robot.toml, poses.csv, tracker.csv, optional campaign.toml.
    problems : Problems, optional
        Collector (``jointcal validate``); when None the first problem is raised.

    Returns
    -------
    robot : Robot
    poses : DataFrame (typed, with ``_line``)
    tracker : DataFrame (typed, with ``_line``). When the campaign passed every check,
        x_mm/y_mm/z_mm are in the robot base frame, ``tracker.attrs[FRAME_ATTR]`` holds
        ``{"frame", "tracker_to_base"}`` and ``tracker.attrs[FIT_ATTR]`` the nominal fit's
        summary; with ``frame = "tracker"`` the raw points are in x_tracker_mm/y_tracker_mm/z_tracker_mm.
    """
    own = problems is None
    problems = Problems() if own else problems
    start = len(problems)
    folder = Path(folder)
    robot = None
    try:
        robot = load_robot(folder / "robot.toml")
    except InputError as exc:
        problems.append(exc)
    frame_kind = read_campaign_frame(folder, problems)
    pp, tp = folder / "poses.csv", folder / "tracker.csv"
    poses = tracker = None
    for p in (pp, tp):
        if not p.exists():
            problems.add(p, "file not found; a robot campaign needs robot.toml, poses.csv and tracker.csv")
    n = robot.n_joints if robot is not None else None
    if pp.exists() and (n is None or check_joint_columns(pp, n, "robot.toml", problems)):
        n = n or _header_joint_count(pp) or 6
        poses = read_table(pp, poses_required(n), poses_optional(n), problems)
    if tp.exists():
        tracker = read_table(tp, TRACKER_REQUIRED, TRACKER_OPTIONAL, problems)
    if poses is not None and robot is not None and robot.coupling:
        # coupled joints: the kinematics take the combination robot.toml's [coupling] states of the recorded
        # angles (a FANUC's J2/J3 interaction); every check and model below sees those angles
        cols = [f"q{j}" for j in range(1, robot.n_joints + 1)]
        if all(c in poses for c in cols):
            poses[cols] = robot.kinematic_angles(poses[cols].to_numpy(float))
    if poses is not None:
        _dup(pp, poses, problems)
        bad = ~_member(poses["set"], SETS)
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            problems.add(pp, f"set '{poses['set'].iloc[i]}' is not one of {', '.join(SETS)}", int(poses["_line"].iloc[i]), "set")
        if robot is not None:
            _check_limits(pp, poses, robot, problems)
        rep = poses["set"] == "repeat"
        for col in ("pose", "approach", "cycle"):
            if rep.any() and (col not in poses or poses.loc[rep, col].isna().any() or (poses.loc[rep, col] == "").any()):
                i = int(np.argmax(rep.to_numpy())) if col not in poses else int(
                    np.argmax((rep & (poses[col].isna() | (poses[col] == ""))).to_numpy()))
                problems.add(pp, f"'repeat' rows need {col} (ISO 9283 pose label, approach and cycle)",
                             int(poses["_line"].iloc[i]), col)
        if "payload_kg" in poses and (poses["payload_kg"] < 0).any():
            i = int(np.argmax((poses["payload_kg"] < 0).to_numpy()))
            problems.add(pp, "payload_kg must not be negative", int(poses["_line"].iloc[i]), "payload_kg")
    if tracker is not None:
        _dup(tp, tracker, problems)
        xyz = tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        if np.isfinite(xyz).all() and len(xyz) > 3 and np.abs(xyz).max() < 5.0:
            problems.add(tp, "every coordinate is below 5: x_mm/y_mm/z_mm look like metres; the contract says mm",
                         2, "x_mm")
        if "sigma_mm" in tracker and (tracker["sigma_mm"] <= 0).any():
            i = int(np.argmax((tracker["sigma_mm"] <= 0).to_numpy()))
            problems.add(tp, "sigma_mm must be positive", int(tracker["_line"].iloc[i]), "sigma_mm")
        _check_quaternions(tp, tracker, problems)
    if poses is not None and tracker is not None:
        no_pose = ~_member(tracker["point_id"], poses["point_id"])
        if no_pose.any():
            i = int(np.argmax(no_pose.to_numpy()))
            problems.add(tp, f"point_id '{tracker['point_id'].iloc[i]}' has no row in poses.csv",
                         int(tracker["_line"].iloc[i]), "point_id")
        no_meas = ~_member(poses["point_id"], tracker["point_id"])
        if no_meas.any():
            i = int(np.argmax(no_meas.to_numpy()))
            problems.add(pp, f"point_id '{poses['point_id'].iloc[i]}' has no tracker point in tracker.csv",
                         int(poses["_line"].iloc[i]), "point_id")
    if robot is not None and poses is not None and tracker is not None and len(problems) == start:
        check_nominal(folder, robot, poses, tracker, frame_kind, problems)
    if own:
        problems.raise_first()
    return robot, poses, tracker


def _check_quaternions(path, tracker, problems) -> None:
    """A 6-DoF probe's orientation: all of qw, qx, qy, qz or none, each row a unit quaternion."""
    have = [c for c in QUATERNION if c in tracker]
    if not have:
        if "sigma_arcsec" in tracker:
            problems.add(path, "sigma_arcsec without an orientation: a 6-DoF probe's orientation needs the columns "
                         "qw, qx, qy, qz", 1, "sigma_arcsec")
        return
    missing = [c for c in QUATERNION if c not in tracker]
    if missing:
        problems.add(path, f"column '{missing[0]}' is missing: a 6-DoF probe's orientation needs all of qw, qx, qy, qz "
                     f"(a unit quaternion, scalar first); found {', '.join(have)}", 1, have[0])
        return
    q = tracker[list(QUATERNION)].to_numpy(float)
    norm = np.linalg.norm(q, axis=1)
    bad = ~(np.abs(norm - 1.0) <= 1e-3)
    if bad.any():
        i = int(np.argmax(bad))
        problems.add(path, f"the quaternion (qw, qx, qy, qz) of point {tracker['point_id'].iloc[i]} has norm "
                     f"{norm[i]:.6g}, not 1: qw..qz must be a unit quaternion, scalar first (w, x, y, z); angles or a "
                     "rotation vector go through jointcal import's [orientation]", int(tracker["_line"].iloc[i]), "qw")
    if "sigma_arcsec" in tracker and (tracker["sigma_arcsec"] <= 0).any():
        i = int(np.argmax((tracker["sigma_arcsec"] <= 0).to_numpy()))
        problems.add(path, "sigma_arcsec must be positive", int(tracker["_line"].iloc[i]), "sigma_arcsec")


def _header_joint_count(path) -> int:
    """Highest k of the q<k> columns in a CSV header (0 when none)."""
    return max(find_joint_columns(csv_header(path), 0).q, default=0)


def check_joint_columns(path, n: int, robot_name: str, problems: Problems | None = None) -> bool:
    """Refuse a table whose joint columns (q<k>, dir<k>) do not match the robot's ``n`` joints.

    One located problem naming both counts (header line, the first column in excess, or the
    first missing q<k>); True when the header is fine (or unreadable: the table reader says why).
    The finding is :func:`pipeline.core.tables.find_joint_columns`'s.
    """
    header = csv_header(path)
    if not header:
        return True
    joints = find_joint_columns(header, n)
    qs, extra = joints.q, joints.extra
    found = max(qs, default=0)
    if extra or (qs and found < n):
        column = extra[0] if extra else f"q{found + 1}"
        if found == n and len(set(qs)) == n:
            what = f"column {column} names joint {column.lstrip('qdir')} of a robot with {n} joints ({robot_name})"
        else:
            what = (f"{len(set(qs))} joint angle columns (q1..q{found}) for a robot with {n} joints ({robot_name}); "
                    f"poses need q1..q{n}, one per joint")
        err = InputError(path, what, 1, column)
        if problems is None:
            raise err
        problems.append(err)
        return False
    return True


# ---------------------------------------------------------------------- campaign.toml
def _toml_key(text: str, key: str):
    """(line, column of the value) of ``key = ...`` or of a ``[key]`` table header; (1, 1) if not found."""
    for k, line in enumerate(text.splitlines()):
        m = re.match(r"^\s*(?:\"" + re.escape(key) + r"\"|'" + re.escape(key) + r"'|" + re.escape(key) + r")\s*=\s*", line)
        if m:
            return k + 1, m.end() + 1
        m = re.match(r"^\s*\[+\s*" + re.escape(key) + r"\b", line)
        if m:
            return k + 1, 1
    return 1, 1


def read_campaign_frame(folder, problems: Problems | None = None) -> str:
    """The ``frame`` of a robot campaign's optional ``campaign.toml``: ``"base"`` (default) or ``"tracker"``.

    Any other key, or another value, is a located problem (collected, or raised when
    ``problems`` is None); the frame is then taken as ``"base"``.
    """
    own = problems is None
    problems = Problems() if own else problems
    path = Path(folder) / "campaign.toml"
    if not path.exists():
        return "base"
    try:
        text = read_text_input(path, "campaign.toml")
        doc = parse_toml(text, path)
    except InputError as exc:
        problems.append(exc)
        if own:
            problems.raise_first()
        return "base"
    frame = "base"
    for key, value in doc.items():
        if key != "frame":
            problems.add(path, f"unknown key '{key}'; a robot campaign.toml knows only frame = \"tracker\" or "
                         "\"base\"", *_toml_key(text, key))
        elif value not in FRAMES:
            problems.add(path, f"frame = {value!r} is not one of \"base\" (points in the robot base frame, the "
                         "default) or \"tracker\" (points in the tracker's frame)", *_toml_key(text, key))
        else:
            frame = value
    if own:
        problems.raise_first()
    return frame


# ---------------------------------------------------------------- nominal consistency
def _joined(poses, tracker):
    """Joint angles (n, N) deg, measured points (n, 3) mm in poses order and each pose's tracker line."""
    t = tracker.set_index("point_id").loc[poses["point_id"]]
    q = poses[joint_columns(poses)].to_numpy(float)
    return q, t[["x_mm", "y_mm", "z_mm"]].to_numpy(float), t["_line"].to_numpy(int)


def _robot_line(robot: Robot, key="xyz_mm"):
    try:
        text = Path(robot.path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return 1, key
    return _toml_key(text, key)


NO_CAUSE = ("none of the usual causes explains it (tried: joint angles in radians, positions in metres, each "
            "joint's sign flipped, each pair of joints swapped, a joint coupled to the one before it, a wrong "
            "tool): check poses.csv against the joint "
            "order, signs and zero offsets (theta_offset_deg) of robot.toml, that each point_id joins its own "
            "tracker point, and the frame (frame = \"tracker\" in campaign.toml when the points are in the "
            "tracker's frame)")


def consistency_error(folder, c: "rf.Consistency", point_ids, poses_lines, tracker_lines, robot: Robot) -> InputError:
    """The one located line that refuses a campaign failing :func:`pipeline.robot.campaign.frame.consistency`.

    The error also carries ``hypothesis`` (the cause found: ``radians``, ``metres``, ``sign<j>``,
    ``swap<j><k>``, ``tool``, ``frame``, ``outlier``, or ``""`` when none explains the data) and
    ``kind`` (``residual``, ``outlier``, ``frame``) and ``tool_mm`` (the SMR in the flange frame that fits,
    when the cause is the tool), for callers that point at their own inputs
    (``jointcal import``) instead of parsing the message.

    Parameters
    ----------
    folder : path-like
        Campaign folder (the error names poses.csv, tracker.csv or robot.toml in it).
    c : Consistency
        A failed check.
    point_ids, poses_lines, tracker_lines : sequences, one per pose (poses order)
        point_id and the 1-based lines of each pose in poses.csv and tracker.csv.
    robot : Robot
        For the line of ``[tool] xyz_mm`` when the cause is the tool.
    """
    err = _consistency_error(Path(folder), c, point_ids, poses_lines, tracker_lines, robot)
    err.hypothesis, err.kind = c.hypothesis, c.kind
    err.tool_mm = c.tool_mm
    return err


def _consistency_error(folder: Path, c, point_ids, poses_lines, tracker_lines, robot: Robot) -> InputError:
    i = c.worst
    pid = point_ids[i]
    if c.kind == "frame":
        return InputError(folder / "tracker.csv", c.cause, int(tracker_lines[0]) if len(tracker_lines) else 2, "x_mm")
    if c.kind == "outlier":
        more = f" ({c.n_outliers} such poses)" if c.n_outliers > 1 else ""
        return InputError(folder / "tracker.csv",
                          f"point {pid} is {c.max_mm:.0f} mm from where the nominal kinematics of robot.toml put it "
                          f"after the best rigid fit, while the other poses fit within RMS {c.rest_rms_mm:.1f} mm"
                          f"{more}: a wrong measurement, or a point_id that belongs to another pose (a real robot's "
                          f"errors stay within {rf.MAX_POINT_MM:g} mm)", int(tracker_lines[i]), "x_mm")
    head = (f"the points do not fit the nominal kinematics of robot.toml: RMS {c.rms_mm:.1f} mm after the best rigid "
            f"fit, where a real robot's errors stay below {rf.MAX_RMS_MM:g} mm (worst pose {pid}: {c.max_mm:.1f} mm); ")
    if not c.cause:
        return InputError(folder / "tracker.csv", head + NO_CAUSE, int(tracker_lines[i]), "x_mm")
    text = head + "likely cause: " + c.cause
    if c.file == "robot":
        line, col = _robot_line(robot)
        return InputError(robot.path, text, line, col)
    if c.file == "poses":
        return InputError(folder / "poses.csv", text, int(poses_lines[i]), c.column)
    return InputError(folder / "tracker.csv", text, int(tracker_lines[i]), c.column)


#: key of ``DataFrame.attrs`` with the nominal fit's summary (rms_mm, max_mm over every pose, mm)
FIT_ATTR = "jointcal_nominal_fit"


def check_nominal(folder, robot: Robot, poses: pd.DataFrame, tracker: pd.DataFrame, frame_kind: str = "base",
                  problems: Problems | None = None, model=None):
    """Nominal-consistency check and, with ``frame = "tracker"``, the move into the base frame.

    ``poses`` and ``tracker`` must have passed every other check (typed, unique ids that join).
    On success ``tracker`` is changed in place: x_mm/y_mm/z_mm in the base frame, the raw
    points in :data:`RAW_COLUMNS` (tracker frame only), ``attrs[FRAME_ATTR]`` and
    ``attrs[FIT_ATTR]``. A failure is added to ``problems`` (raised when None).

    Returns
    -------
    Consistency or None (when the check could not run: fewer than 3 poses, collinear points).
    """
    folder = Path(folder)
    own = problems is None
    problems = Problems() if own else problems
    q, meas, tlines = _joined(poses, tracker)
    sample = (poses["set"] == "sample").to_numpy()
    if not sample.any() and (poses["set"] == "target").all() and len(sample) >= 3:
        # a validation set (every pose target): the check runs on every pose; predict takes the points
        # through the fit campaign's transform (the tracker stayed put) or, --register, refuses
        sample = np.ones(len(sample), bool)
    if frame_kind == "tracker" and sample.sum() < 3:
        line = int(poses["_line"].iloc[int(np.argmax(sample))]) if sample.any() else 2
        problems.add(folder / "poses.csv", f"frame = \"tracker\" (campaign.toml) needs at least 3 sample poses to "
                     f"estimate the tracker-to-base transform on; found {int(sample.sum())}", line, "set")
        if own:
            problems.raise_first()
        return None
    try:
        c = rf.consistency(robot, q, meas, sample, frame=frame_kind, model=model)
    except ValueError as exc:
        if frame_kind == "tracker":
            problems.add(folder / "tracker.csv", f"cannot estimate the tracker-to-base transform: {exc}", 2, "x_mm")
        elif own:
            return None
        if own:
            problems.raise_first()
        return None
    if not c.ok:
        problems.append(consistency_error(folder, c, poses["point_id"].to_numpy(object), poses["_line"].to_numpy(int),
                                          tlines, robot))
        if own:
            problems.raise_first()
        return c
    R, t = (c.tracker_to_base() if frame_kind == "tracker" else (np.eye(3), np.zeros(3)))
    if frame_kind == "tracker":
        raw = tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        for k, col in enumerate(RAW_COLUMNS):
            tracker[col] = raw[:, k]
        moved = rf.apply(R, t, raw)
        tracker["x_mm"], tracker["y_mm"], tracker["z_mm"] = moved.T
    if all(col in tracker for col in QUATERNION):
        if not _check_orientations(folder, robot, poses, tracker, R, frame_kind, sample, problems, model):
            if own:
                problems.raise_first()
            return c
    tracker.attrs[FRAME_ATTR] = {"frame": frame_kind, "tracker_to_base": rf.to_matrix(R, t).tolist()}
    tracker.attrs[FIT_ATTR] = {"rms_mm": c.rms_mm, "max_mm": c.max_mm, "limit_rms_mm": rf.MAX_RMS_MM}
    return c


#: key of ``DataFrame.attrs`` with the orientation check's summary (the probe's mounting estimated from the data)
ORIENTATION_ATTR = "jointcal_orientation"


def _check_orientations(folder, robot, poses, tracker, R_tb, frame_kind, sample, problems, model=None) -> bool:
    """A 6-DoF campaign's orientations: moved into the base frame (``frame = "tracker"``), checked against
    the nominal flange frames after the best probe mounting, and that mounting against robot.toml's
    ``[tool] rpy_deg``. False (a problem added) when they do not fit a robot."""
    from . import orientation as ro
    from ..arm.kinematics import placements

    t = tracker.set_index("point_id").loc[poses["point_id"]]
    q_tr = t[list(QUATERNION)].to_numpy(float)
    lines = t["_line"].to_numpy(int)
    R_meas = ro.quaternions_to_matrices(q_tr / np.linalg.norm(q_tr, axis=1, keepdims=True))
    R_base = np.einsum("ij,njk->nik", R_tb, R_meas)
    model = model or build_model(robot)
    Rf, _ = placements(model, np.deg2rad(poses[joint_columns(poses)].to_numpy(float)), "flange")
    M, err = ro.mounting(Rf, R_base, sample)
    stated = robot.tool_rotation
    apart = float(ro.angles_deg(M, stated))
    summary = {"mounting_rpy_deg": ro.rpy_deg(M).tolist(), "robot_rpy_deg": list(robot.tool_rpy_deg),
               "mounting_apart_deg": apart, "rms_deg": ro.rms(err), "max_deg": float(err.max())}
    if ro.rms(err) > ro.MAX_ORIENTATION_RMS_DEG:
        k = int(np.argmax(err))
        problems.add(folder / "tracker.csv", f"the orientations do not fit the nominal flange frames of robot.toml: "
                     f"RMS {ro.rms(err):.2f} deg after the best probe mounting, where a real robot's orientation "
                     f"errors stay below {ro.MAX_ORIENTATION_RMS_DEG:g} deg (worst point {poses['point_id'].iloc[k]}: "
                     f"{err[k]:.2f} deg); likely cause: qw, qx, qy, qz not a scalar-first quaternion of the probe frame "
                     "in the positions' frame (jointcal import's [orientation] reads other conventions)",
                     int(lines[k]), "qw")
        return False
    if apart > ro.MOUNTING_TOL_DEG:
        line, col = _robot_line(robot, "rpy_deg") if "rpy_deg" in _robot_text(robot) else _robot_line(robot, "xyz_mm")
        rpy = ", ".join(f"{v:.2f}" for v in ro.rpy_deg(M))
        problems.add(robot.path, f"the probe frame sits {apart:.1f} deg from robot.toml's [tool] rpy_deg "
                     f"{list(robot.tool_rpy_deg)} on the flange (estimated from the orientations: rpy_deg = [{rpy}]): "
                     "set [tool] rpy_deg to the probe's mounting", line, col)
        return False
    q_base = ro.matrices_to_quaternions(R_base)
    order = tracker.set_index("point_id").index.get_indexer(poses["point_id"])
    moved = np.empty_like(q_base)
    moved[order] = q_base
    if frame_kind == "tracker":
        raw = tracker[list(QUATERNION)].to_numpy(float)
        for k, col in enumerate(RAW_QUATERNION):
            tracker[col] = raw[:, k]
    for k, col in enumerate(QUATERNION):
        tracker[col] = moved[:, k]
    tracker.attrs[ORIENTATION_ATTR] = summary
    return True


def _robot_text(robot: Robot) -> str:
    try:
        return Path(robot.path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return ""


def _check_limits(path, poses, robot: Robot, problems):
    tol = 1e-6
    for j in range(robot.n_joints):
        col = f"q{j + 1}"
        q = poses[col].to_numpy(float)
        lo, hi = robot.lower_deg[j], robot.upper_deg[j]
        out = np.isfinite(q) & ((q < lo - tol) | (q > hi + tol))
        if out.any():
            i = int(np.argmax(out))
            v = q[i]
            hint = _limit_hint(poses, robot, j, tol)
            if any(k == j for k, _ in robot.coupling):
                hint += f" (joint {j + 1}'s angle as robot.toml's [coupling] combines the recorded ones)"
            if lo - tol <= np.rad2deg(v) <= hi + tol:
                hint = "; the column looks like radians, the contract says degrees"
            problems.add(path, f"{col} = {v:g} deg is outside joint {j + 1}'s range [{lo:g}, {hi:g}] of robot.toml{hint}",
                         int(poses["_line"].iloc[i]), col)
            return


def _limit_hint(poses, robot: Robot, j: int, tol: float) -> str:
    """Why column q<j+1> may be outside its joint's range: another joint's column, or its sign flipped."""
    lo, hi = robot.lower_deg, robot.upper_deg

    def inside(values, k):
        v = values[np.isfinite(values)]
        return len(v) > 0 and bool(np.all((v >= lo[k] - tol) & (v <= hi[k] + tol)))

    q = {k: poses[f"q{k + 1}"].to_numpy(float) for k in range(len(lo))}
    for k in range(len(lo)):
        if k != j and inside(q[j], k) and inside(q[k], j):
            a, b = sorted((j + 1, k + 1))
            return f"; q{a} and q{b} look swapped (each column fits the other joint's range): check the joint order"
    if inside(-q[j], j):
        return f"; -q{j + 1} fits the range: joint {j + 1}'s sign looks flipped"
    return ""


def derive_robot(robot: Robot, poses: pd.DataFrame, tracker: pd.DataFrame) -> pd.DataFrame:
    """Join poses and tracker points, derive directions, nominal positions and torques (pure)."""
    n = len(poses)
    N = robot.n_joints
    q = poses[[f"q{j}" for j in range(1, N + 1)]].to_numpy(float)
    out = pd.DataFrame({"point_id": poses["point_id"].astype(str).to_numpy(), "set": poses["set"].astype(str).to_numpy(),
                        "visit": np.arange(n, dtype=np.int64)})
    for j in range(N):
        out[f"q{j + 1}"] = q[:, j]
    derived = directions_from_sequence(q)
    for j in range(N):
        col = f"dir{j + 1}"
        given = poses[col].to_numpy(float) if col in poses else np.full(n, np.nan)
        out[col] = np.where(np.isfinite(given), given, derived[:, j]).astype(np.int64)
    out["payload_kg"] = poses["payload_kg"].fillna(0.0).to_numpy(float) if "payload_kg" in poses else 0.0
    out["temperature_c"] = poses["temperature_c"].fillna(REFERENCE_TEMPERATURE_C).to_numpy(float) if "temperature_c" in poses \
        else REFERENCE_TEMPERATURE_C
    out["pose"] = poses["pose"].astype(str).to_numpy() if "pose" in poses else ""
    out["approach"] = poses["approach"].astype(str).to_numpy() if "approach" in poses else ""
    out["cycle"] = poses["cycle"].fillna(0).astype(np.int64).to_numpy() if "cycle" in poses else 0
    for j in range(1, 4):
        col = f"grating{j}_deg"
        out[col] = poses[col].to_numpy(float) if col in poses else np.nan
    t = tracker.set_index("point_id")
    xyz = t.loc[out["point_id"], ["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    out["x_mm"], out["y_mm"], out["z_mm"] = xyz.T
    out["sigma_mm"] = t.loc[out["point_id"], "sigma_mm"].to_numpy(float) if "sigma_mm" in t else np.nan
    if all(c in t for c in QUATERNION):
        for c in QUATERNION + tuple(c for c in RAW_QUATERNION if c in t):
            out[c] = t.loc[out["point_id"], c].to_numpy(float)
        out["sigma_arcsec"] = t.loc[out["point_id"], "sigma_arcsec"].to_numpy(float) if "sigma_arcsec" in t else np.nan
    if all(c in t for c in RAW_COLUMNS):
        raw = t.loc[out["point_id"], list(RAW_COLUMNS)].to_numpy(float)
        for k, c in enumerate(RAW_COLUMNS):
            out[c] = raw[:, k]
    model = build_model(robot)
    nom = positions(model, np.deg2rad(q))
    out["xn_mm"], out["yn_mm"], out["zn_mm"] = nom.T
    tau = gravity_torques(robot, q, out["payload_kg"].to_numpy(float), model)
    for j in range(N):
        out[f"tau{j + 1}_nm"] = tau[:, j]
    out.attrs[FRAME_ATTR] = frame_info(tracker)
    if FIT_ATTR in tracker.attrs:
        out.attrs[FIT_ATTR] = dict(tracker.attrs[FIT_ATTR])
    if ORIENTATION_ATTR in tracker.attrs:
        out.attrs[ORIENTATION_ATTR] = dict(tracker.attrs[ORIENTATION_ATTR])
    return out


def joint_columns(table: pd.DataFrame) -> list[str]:
    """``q1 .. qN`` of a poses table (N = the consecutive q<k> columns present)."""
    cols = []
    while f"q{len(cols) + 1}" in table:
        cols.append(f"q{len(cols) + 1}")
    return cols


def frame_info(table: pd.DataFrame) -> dict:
    """``{"frame": "base" | "tracker", "tracker_to_base": 4x4 list (mm)}`` of a checked tracker or ingested table.

    Identity and ``"base"`` when the table carries none (e.g. one made by hand).
    """
    info = dict(getattr(table, "attrs", {}).get(FRAME_ATTR, {}))
    info.setdefault("frame", "base")
    info.setdefault("tracker_to_base", np.eye(4).tolist())
    return {"frame": info["frame"], "tracker_to_base": [list(map(float, r)) for r in info["tracker_to_base"]]}


def ingest_robot(folder) -> tuple[Robot, pd.DataFrame]:
    """Validate a robot campaign folder and return the robot and the joined table.

    The table's x_mm/y_mm/z_mm are in the robot base frame (moved there when campaign.toml says
    ``frame = "tracker"``); ``table.attrs[FRAME_ATTR]`` is :func:`frame_info`.
    """
    robot, poses, tracker = load_robot_campaign(folder)
    return robot, derive_robot(robot, poses, tracker)


def ingest_robot_with_frame(folder) -> tuple[Robot, pd.DataFrame, dict]:
    """:func:`ingest_robot` and the campaign's frame: ``{"frame", "tracker_to_base" (4x4 list, mm),
    "translation_mm" (3,), "rotation_deg", "nominal_rms_mm", "nominal_max_mm"}``."""
    robot, table = ingest_robot(folder)
    info = frame_info(table)
    R, t = rf.from_matrix(info["tracker_to_base"])
    fit = table.attrs.get(FIT_ATTR, {})
    info.update({"translation_mm": t.tolist(), "rotation_deg": rf.rotation_angle_deg(R),
                 "nominal_rms_mm": fit.get("rms_mm"), "nominal_max_mm": fit.get("max_mm")})
    return robot, table, info


def campaign_files(folder) -> list[Path]:
    """The files of a robot campaign folder that its results depend on (their hashes are the
    results' provenance): robot.toml, poses.csv, tracker.csv and campaign.toml when there is one."""
    files = [Path(folder) / n for n in ("robot.toml", "poses.csv", "tracker.csv")]
    return files + [f for f in [Path(folder) / "campaign.toml"] if f.exists()]


def ingested_metadata(campaign, info: dict, provenance: dict) -> dict:
    """The Parquet metadata ``jointcal ingest`` writes beside the table: the campaign, the
    provenance of its files, its frame and tracker-to-base transform (4x4, mm) and the nominal fit
    (mm); ``info`` as :func:`ingest_robot_with_frame` returns it."""
    return {"campaign": str(campaign), **provenance, "frame": info["frame"], "tracker_to_base": info["tracker_to_base"],
            "nominal_fit": {"rms_mm": info["nominal_rms_mm"], "max_mm": info["nominal_max_mm"]}}


def check_ingested(table: pd.DataFrame, path, metadata: dict | None = None) -> None:
    """The nominal-consistency check on an already ingested table (``interim/robot/poses.parquet``).

    Cheap: one rigid fit of the stored nominal positions (xn/yn/zn_mm) onto the base-frame
    points (x/y/z_mm) over the sample poses; the fit must leave what a robot can (see
    :func:`pipeline.robot.campaign.frame.consistency`) and be near identity (the table is in the base
    frame). On failure the source campaign named in the metadata is checked again, so that
    the error names its file, line and likely cause; when that campaign is gone or now
    passes, the table itself is named (stale: ingest again). Also sets ``table.attrs[FRAME_ATTR]``
    from the metadata. Tables without those columns are left alone.
    """
    metadata = metadata or {}
    if "tracker_to_base" in metadata:
        table.attrs[FRAME_ATTR] = {"frame": metadata.get("frame", "base"), "tracker_to_base": metadata["tracker_to_base"]}
    cols = ["x_mm", "y_mm", "z_mm", "xn_mm", "yn_mm", "zn_mm"]
    if not all(c in table for c in cols) or len(table) < 3:
        return
    meas = table[cols[:3]].to_numpy(float)
    nominal = table[cols[3:]].to_numpy(float)
    if not (np.isfinite(meas).all() and np.isfinite(nominal).all()):
        raise InputError(path, "non-finite positions in the ingested table: run jointcal ingest again", None, "x_mm")
    rows = (table["set"] == "sample").to_numpy() if "set" in table else np.ones(len(table), bool)
    if rows.sum() < 3:
        rows = np.ones(len(table), bool)
    try:
        R, t, err = rf.fit_residuals(nominal, meas, rows)
    except ValueError:
        return
    fine = (rf.rms(err) <= rf.MAX_RMS_MM and err.max() <= rf.MAX_POINT_MM
            and np.linalg.norm(t) <= rf.MAX_BASE_TRANSLATION_MM and rf.rotation_angle_deg(R) <= rf.MAX_BASE_ROTATION_DEG)
    if fine:
        return
    campaign = metadata.get("campaign")
    if campaign and all((Path(campaign) / n).exists() for n in ("robot.toml", "poses.csv", "tracker.csv")):
        load_robot_campaign(campaign)  # raises the located error with its likely cause
    k = int(np.argmax(err))
    raise InputError(path, f"the ingested table does not fit the nominal kinematics it was ingested with (RMS "
                     f"{rf.rms(err):.1f} mm, row {k + 1} {err[k]:.1f} mm off after the best rigid fit; "
                     f"{rf.describe(R, t)}): it is stale or was not written by jointcal ingest; run jointcal ingest "
                     "again", k + 1, "x_mm")


def robot_data(robot: Robot, frame: pd.DataFrame, use_gratings: bool = False) -> RobotData:
    """The model's view of an ingested table (see :class:`pipeline.robot.arm.effects.RobotData`).

    With ``use_gratings`` the grating readings replace the commanded angles of joints 1-3
    where they exist (the joint's true angle, read by the absolute grating).
    """
    cols = range(1, robot.n_joints + 1)
    q = frame[[f"q{j}" for j in cols]].to_numpy(float).copy()
    if use_gratings:
        for j in range(3):
            col = f"grating{j + 1}_deg"
            if col in frame:
                g = frame[col].to_numpy(float)
                q[:, j] = np.where(np.isfinite(g), g, q[:, j])
    meas = frame[["x_mm", "y_mm", "z_mm"]].to_numpy(float) if "x_mm" in frame else None
    R = sig_p = sig_o = None
    if all(c in frame for c in QUATERNION):
        from .orientation import quaternions_to_matrices

        R = quaternions_to_matrices(frame[list(QUATERNION)].to_numpy(float))
        sig_o = frame["sigma_arcsec"].to_numpy(float) if "sigma_arcsec" in frame else None
        sig_p = frame["sigma_mm"].to_numpy(float) if "sigma_mm" in frame else None
    return RobotData(q, frame[[f"dir{j}" for j in cols]].to_numpy(int), frame["payload_kg"].to_numpy(float),
                     frame["temperature_c"].to_numpy(float), frame[[f"tau{j}_nm" for j in cols]].to_numpy(float),
                     robot.lower_deg, robot.upper_deg, meas, frame["point_id"].to_numpy(object), R, sig_p, sig_o)


def has_gratings(frame: pd.DataFrame) -> bool:
    return all(f"grating{j}_deg" in frame and frame[f"grating{j}_deg"].notna().all() for j in range(1, 4))


def robot_data_from_campaign(folder, sets=("sample",)):
    """(robot, RobotData) of a raw robot campaign's poses in ``sets``.

    Joints 1-3 use the grating readings where the campaign has them (the paper's cell reads
    the true angle of those joints), else the commanded angles.
    """
    robot, (data,) = robot_data_sets(folder, sets)
    return robot, data


def robot_data_sets(folder, *groups, with_frame=False, with_table=False):
    """(robot, [RobotData of each group of sets]) from one ingest of a raw robot campaign,
    e.g. ``robot_data_sets(folder, ("sample",), ("target",))``; see :func:`robot_data_from_campaign`.

    With ``with_frame`` the campaign's frame (``{"frame", "tracker_to_base"}``, the transform the
    ingest estimated) follows; with ``with_table`` the ingested table of the first group too.
    """
    robot, frame = ingest_robot(folder)
    out, tables = [], []
    for sets in groups:
        part = frame[_member(frame["set"], sets)].reset_index(drop=True)
        data = robot_data(robot, part, use_gratings=has_gratings(part))
        data.grating_joints = (1, 2, 3) if has_gratings(part) else ()
        out.append(data)
        tables.append(part)
    result = [robot, out]
    if with_frame:
        result.append(frame_info(frame))
    if with_table:
        result.append(tables[0])
    return tuple(result)
