"""Diagnosis speed: a 200-pose robot campaign (every candidate, 5 folds) and an 8-run encoder campaign."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]


def run() -> dict:
    from pipeline.diagnose import diagnose
    from pipeline.diagnose_encoder import EncoderAdapter
    from pipeline.effects import EncoderData
    from pipeline.ingest import derive_encoder
    from pipeline.robot import load_robot
    from pipeline.robot_diagnose import RobotAdapter, robot_data_from_campaign
    from pipeline.robot_simulate import ROBOT_FIXTURE, format_poses_csv, format_tracker_csv, simulate_robot
    from pipeline.simulate import ENCODER_FIXTURE, simulate_encoder
    from pipeline.spec import load_spec

    out = {}
    robot = load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml")
    config = dict(ROBOT_FIXTURE, seed=101, n_sample=200, n_target=0, repeat_cycles=0)
    poses, tracker, _ = simulate_robot(robot, config, {"effect": "backlash", "joint": 5, "arcsec": 60.0})
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "cell"
        folder.mkdir()
        (folder / "robot.toml").write_text(robot.to_toml())
        (folder / "poses.csv").write_text(format_poses_csv(poses))
        (folder / "tracker.csv").write_text(format_tracker_csv(tracker))
        robot_, data = robot_data_from_campaign(folder)
    for name in ("robot_paper", "robot_geometry"):
        spec = load_spec(ROOT / "specs" / "robot_paper.toml") if name == "robot_paper" else None
        if spec is None:
            from pipeline.spec import parse_spec

            spec = parse_spec('[model]\nkind = "robot"\n\n[[effect]]\nname = "geometry"\n\n[[effect]]\nname = "base"\n')
        t = time.perf_counter()
        result = diagnose(RobotAdapter(robot_), spec, data)
        out[f"robot_200_poses_{name}"] = {
            "seconds": time.perf_counter() - t, "poses": data.n, "candidates": len(result["candidates"]),
            "not_revealable": len(result["not_revealable"]), "processes": 2, "goal_seconds": 60.0,
            "top": [c["effect"] + ("" if c["target"] is None else f" {c['target']}") for c in result["candidates"][:2]]}
    frame, _ = simulate_encoder("a", dict(ENCODER_FIXTURE["a"], seed=5), runs=8, two_way=True)
    frame["_file"], frame["_line"] = "sim.csv", 0
    frame["timestamp"] = pd.to_datetime(frame["timestamp"])
    enc = EncoderData.from_frame(derive_encoder(frame, {"faces": 36}))
    spec = load_spec(ROOT / "specs" / "encoder_paper.toml")
    t = time.perf_counter()
    result = diagnose(EncoderAdapter(), spec, enc)
    out["encoder_8_runs"] = {"seconds": time.perf_counter() - t, "readings": int(enc.theta_deg.size),
                             "candidates": len(result["candidates"]), "goal_seconds": 5.0}
    return out
