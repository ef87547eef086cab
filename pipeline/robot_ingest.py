"""Robot campaign ingest (contract section 2): validate and join poses.csv + tracker.csv.

Checks (each a located InputError): required columns (misspellings named), NaN and
non-numbers, duplicate point_id, tracker points without a pose and poses without a
tracker point, unknown ``set`` values, joint angles outside the joint range of robot.toml
(with a hint when the value would fit in radians), tracker coordinates that look like
metres, ``repeat`` rows without pose/approach/cycle.

The output (``interim/robot/poses.parquet``) has one row per pose in visiting order with
q1..q6 (deg), dir1..dir6 (derived from the visiting order when absent: sign of
q_j(this) - q_j(previous pose), carrying the previous sign when unchanged, +1 for the first
pose), payload_kg, temperature_c, x_mm/y_mm/z_mm, the nominal SMR position xn/yn/zn (mm),
the gravity torques tau1..tau6 (N m) and the optional grating readings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError
from .robot import Robot, build_model, gravity_torques, load_robot, positions
from .robot_effects import RobotData
from .robot_simulate import directions_from_sequence
from .tables import FLOAT, INT, SIGN, STR, TIME, Problems, read_table

POSES_REQUIRED = {"point_id": STR, "set": STR, **{f"q{j}": FLOAT for j in range(1, 7)}}
POSES_OPTIONAL = {**{f"dir{j}": SIGN for j in range(1, 7)}, "payload_kg": FLOAT, "temperature_c": FLOAT,
                  "timestamp": TIME, "pose": STR, "approach": STR, "cycle": INT,
                  **{f"grating{j}_deg": FLOAT for j in range(1, 4)}}
TRACKER_REQUIRED = {"point_id": STR, "x_mm": FLOAT, "y_mm": FLOAT, "z_mm": FLOAT}
TRACKER_OPTIONAL = {"sigma_mm": FLOAT}
SETS = ("sample", "target", "repeat")


def _dup(path, frame, problems):
    dup = frame["point_id"].duplicated(keep="first")
    if dup.any():
        i = int(np.argmax(dup.to_numpy()))
        problems.add(path, f"duplicate point_id '{frame['point_id'].iloc[i]}'; each point appears once",
                     int(frame["_line"].iloc[i]), "point_id")


def load_robot_campaign(folder, problems: Problems | None = None):
    """Read and check a robot campaign folder.

    Returns
    -------
    robot : Robot
    poses : DataFrame (typed, with ``_line``)
    tracker : DataFrame (typed, with ``_line``)
    """
    own = problems is None
    problems = Problems() if own else problems
    folder = Path(folder)
    robot = None
    try:
        robot = load_robot(folder / "robot.toml")
    except InputError as exc:
        problems.append(exc)
    pp, tp = folder / "poses.csv", folder / "tracker.csv"
    poses = tracker = None
    for p in (pp, tp):
        if not p.exists():
            problems.add(p, "file not found; a robot campaign needs robot.toml, poses.csv and tracker.csv")
    if pp.exists():
        poses = read_table(pp, POSES_REQUIRED, POSES_OPTIONAL, problems)
    if tp.exists():
        tracker = read_table(tp, TRACKER_REQUIRED, TRACKER_OPTIONAL, problems)
    if poses is not None:
        _dup(pp, poses, problems)
        bad = ~poses["set"].isin(SETS)
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
    if poses is not None and tracker is not None:
        no_pose = ~tracker["point_id"].isin(poses["point_id"])
        if no_pose.any():
            i = int(np.argmax(no_pose.to_numpy()))
            problems.add(tp, f"point_id '{tracker['point_id'].iloc[i]}' has no row in poses.csv",
                         int(tracker["_line"].iloc[i]), "point_id")
        no_meas = ~poses["point_id"].isin(tracker["point_id"])
        if no_meas.any():
            i = int(np.argmax(no_meas.to_numpy()))
            problems.add(pp, f"point_id '{poses['point_id'].iloc[i]}' has no tracker point in tracker.csv",
                         int(poses["_line"].iloc[i]), "point_id")
    if own:
        problems.raise_first()
    return robot, poses, tracker


def _check_limits(path, poses, robot: Robot, problems):
    tol = 1e-6
    for j in range(6):
        col = f"q{j + 1}"
        q = poses[col].to_numpy(float)
        lo, hi = robot.lower_deg[j], robot.upper_deg[j]
        out = np.isfinite(q) & ((q < lo - tol) | (q > hi + tol))
        if out.any():
            i = int(np.argmax(out))
            v = q[i]
            hint = ""
            if lo - tol <= np.rad2deg(v) <= hi + tol:
                hint = "; the column looks like radians, the contract says degrees"
            problems.add(path, f"{col} = {v:g} deg is outside joint {j + 1}'s range [{lo:g}, {hi:g}] of robot.toml{hint}",
                         int(poses["_line"].iloc[i]), col)
            return


def derive_robot(robot: Robot, poses: pd.DataFrame, tracker: pd.DataFrame) -> pd.DataFrame:
    """Join poses and tracker points, derive directions, nominal positions and torques (pure)."""
    n = len(poses)
    q = poses[[f"q{j}" for j in range(1, 7)]].to_numpy(float)
    out = pd.DataFrame({"point_id": poses["point_id"].astype(str).to_numpy(), "set": poses["set"].astype(str).to_numpy(),
                        "visit": np.arange(n, dtype=np.int64)})
    for j in range(6):
        out[f"q{j + 1}"] = q[:, j]
    derived = directions_from_sequence(q)
    for j in range(6):
        col = f"dir{j + 1}"
        given = poses[col].to_numpy(float) if col in poses else np.full(n, np.nan)
        out[col] = np.where(np.isfinite(given), given, derived[:, j]).astype(np.int64)
    out["payload_kg"] = poses["payload_kg"].fillna(0.0).to_numpy(float) if "payload_kg" in poses else 0.0
    out["temperature_c"] = poses["temperature_c"].fillna(20.0).to_numpy(float) if "temperature_c" in poses else 20.0
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
    model = build_model(robot)
    nom = positions(model, np.deg2rad(q))
    out["xn_mm"], out["yn_mm"], out["zn_mm"] = nom.T
    tau = gravity_torques(robot, q, out["payload_kg"].to_numpy(float), model)
    for j in range(6):
        out[f"tau{j + 1}_nm"] = tau[:, j]
    return out


def ingest_robot(folder) -> tuple[Robot, pd.DataFrame]:
    """Validate a robot campaign folder and return the robot and the joined table."""
    robot, poses, tracker = load_robot_campaign(folder)
    return robot, derive_robot(robot, poses, tracker)


def robot_data(robot: Robot, frame: pd.DataFrame, use_gratings: bool = False) -> RobotData:
    """The model's view of an ingested table (see :class:`pipeline.robot_effects.RobotData`).

    With ``use_gratings`` the grating readings replace the commanded angles of joints 1-3
    where they exist (the joint's true angle, read by the absolute grating).
    """
    q = frame[[f"q{j}" for j in range(1, 7)]].to_numpy(float).copy()
    if use_gratings:
        for j in range(3):
            col = f"grating{j + 1}_deg"
            if col in frame:
                g = frame[col].to_numpy(float)
                q[:, j] = np.where(np.isfinite(g), g, q[:, j])
    meas = frame[["x_mm", "y_mm", "z_mm"]].to_numpy(float) if "x_mm" in frame else None
    return RobotData(q, frame[[f"dir{j}" for j in range(1, 7)]].to_numpy(int), frame["payload_kg"].to_numpy(float),
                     frame["temperature_c"].to_numpy(float), frame[[f"tau{j}_nm" for j in range(1, 7)]].to_numpy(float),
                     robot.lower_deg, robot.upper_deg, meas, frame["point_id"].to_numpy(object))


def has_gratings(frame: pd.DataFrame) -> bool:
    return all(f"grating{j}_deg" in frame and frame[f"grating{j}_deg"].notna().all() for j in range(1, 4))
