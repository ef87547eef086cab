"""Diagnosis speed and memory: a 200-pose robot campaign (every candidate, 5 folds, 2 forked
processes) with two specs, and an 8-run encoder campaign: ``run() -> dict``.

Each case runs in a fresh Python process (``python -m bench.diagnose_bench CASE``) so that
its memory can be read: the diagnosis forks worker processes, whose allocations tracemalloc
in the parent cannot see. Reported: wall time of ``diagnose()`` alone (data set-up and imports
excluded; scipy's sub-packages imported before), the process's resident set before the call
and its peak during the call (``VmHWM`` reset before it), and the peak resident set of the
largest worker (``RUSAGE_CHILDREN``; a fork shares the parent's pages, which count in both).
"""

from __future__ import annotations

import importlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CASES = ("robot_200_poses_robot_paper", "robot_200_poses_robot_geometry", "encoder_8_runs")


def _robot_case(name):
    from pipeline.core.spec import load_spec, parse_spec
    from pipeline.diagnosis.robot import RobotAdapter
    from pipeline.robot.campaign.ingest import robot_data_from_campaign
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import ROBOT_FIXTURE, format_poses_csv, format_tracker_csv, simulate_robot

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
    if name.endswith("robot_paper"):
        spec = load_spec(ROOT / "specs" / "robot_paper.toml")
    else:
        spec = parse_spec('[model]\nkind = "robot"\n\n[[effect]]\nname = "geometry"\n\n[[effect]]\nname = "base"\n')
    return RobotAdapter(robot_), spec, data, {"poses": data.n, "processes": 2, "goal_seconds": 60.0}


def _encoder_case():
    from pipeline.core.spec import load_spec
    from pipeline.diagnosis.encoder import EncoderAdapter
    from pipeline.encoder.effects import EncoderData
    from pipeline.encoder.ingest import derive_encoder
    from pipeline.encoder.simulate import ENCODER_FIXTURE, simulate_encoder

    frame, _ = simulate_encoder("a", dict(ENCODER_FIXTURE["a"], seed=5), runs=8, two_way=True)
    frame["_file"], frame["_line"] = "sim.csv", 0
    frame["timestamp"] = pd.to_datetime(frame["timestamp"])
    enc = EncoderData.from_frame(derive_encoder(frame, {"faces": 36}))
    spec = load_spec(ROOT / "specs" / "encoder_paper.toml")
    return EncoderAdapter(), spec, enc, {"readings": int(enc.theta_deg.size), "processes": 1, "goal_seconds": 5.0}


def case(name) -> dict:
    """One diagnosis, measured in this process (meant to be a fresh one)."""
    from pipeline.diagnosis.engine import diagnose
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    adapter, spec, data, info = _encoder_case() if name == "encoder_8_runs" else _robot_case(name)
    for module in ("scipy.interpolate", "scipy.ndimage", "scipy.optimize", "scipy.stats"):
        importlib.import_module(module)   # imported lazily by the diagnosis (0.5 s): not timed
    before = _status_mb("VmRSS")
    reset = _reset_peak()
    t = time.perf_counter()
    result = diagnose(adapter, spec, data)
    seconds = time.perf_counter() - t
    peak = _status_mb("VmHWM")
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"seconds": seconds, **info, "candidates": len(result["candidates"]),
            "not_revealable": len(result["not_revealable"]),
            "top": [c["effect"] + ("" if c["target"] is None else f" {c['target']}") for c in result["candidates"][:2]],
            "rss_before_mb": before, "peak_rss_mb": peak if reset else None,
            "worker_peak_rss_mb": workers if workers > 0 else None}


def _status_mb(field):
    """A field of /proc/self/status (kB) in MB. ``ru_maxrss`` is no use here: Linux carries
    it over from the process that forked and exec'd us (the benchmark, 1 GB after harmonic)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return None


def _reset_peak() -> bool:
    """Reset VmHWM to the current resident set (Linux >= 4.0), so that it is the call's peak."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def run() -> dict:
    out = {}
    for name in CASES:
        proc = subprocess.run([sys.executable, "-m", "bench.diagnose_bench", name], cwd=ROOT, check=True,
                              capture_output=True, text=True)
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


if __name__ == "__main__":
    if len(sys.argv) > 1:
        print(json.dumps(case(sys.argv[1]), default=float))
    else:
        print(json.dumps(run(), indent=2, default=float))
