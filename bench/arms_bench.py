"""Any serial arm: fit and diagnosis against the joint count N (4, 6, 7): ``run() -> dict``.

One virtual cell per robot (``jointcal simulate robot --robot``: the KR210 cell's physics scaled
to the arm, seed 1, 100 sample + 104 target poses): the 4R arm of raw/arms/arm4.toml, the KR210
of raw/robot/kr210 and the Franka Panda of raw/arms/panda.toml. For each: the kinematic spec
(geometry + base + tool) fitted on the sample poses (wall time of the fit alone, best of 3;
parameters, those left at nominal, held-out RMS before/after on the targets), and the diagnosis
of the campaign with that spec (wall time of ``diagnose()``, one process; candidates tried).

Expected: the error model has 7 N + 9 coordinates and the spec 5 N + 9 parameters; the fit's
cost is the Jacobian (poses x parameters x coordinates, about N^2) plus its identifiability
checks (about N^3, small at these sizes); the diagnosis tries a fixed number of candidates per
joint (about N of them), each refitted in 5 folds at a cost that grows with N too: about
N^1.5-2 in all. Measured here (2 shared cores): fit 0.035 / 0.074 / 0.126 s (N = 4 / 6 / 7,
exponent 2.2), diagnosis 1.4 / 2.0 / 3.7 s for 78 / 103 / 135 candidates (exponent 1.6;
candidates 0.9).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = {4: ROOT / "raw" / "arms" / "arm4.toml", 6: ROOT / "raw" / "robot" / "kr210" / "robot.toml",
          7: ROOT / "raw" / "arms" / "panda.toml"}


def _campaign(folder: Path, robot_path: Path):
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import cell_config, format_poses_csv, format_tracker_csv, simulate_robot

    robot = load_robot(robot_path)
    poses, tracker, _ = simulate_robot(robot, cell_config(robot, 1, paper=False))
    folder.mkdir()
    (folder / "robot.toml").write_text(robot.to_toml())
    (folder / "poses.csv").write_text(format_poses_csv(poses))
    (folder / "tracker.csv").write_text(format_tracker_csv(tracker))
    robot, (sample, target) = robot_data_sets(folder, ("sample",), ("target",))
    return robot, sample, target


def one(n_joints: int, robot_path: Path) -> dict:
    from pipeline.core.spec import load_spec
    from pipeline.diagnosis.engine import diagnose
    from pipeline.diagnosis.robot import RobotAdapter
    from pipeline.robot.model.estimate import fit_effects, heldout_fit

    spec = load_spec(ROOT / "specs" / "robot_kinematic.toml")
    with tempfile.TemporaryDirectory() as tmp:
        robot, sample, target = _campaign(Path(tmp) / "cell", robot_path)
    effects = list(spec.effects)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        model = fit_effects(robot, effects, sample)
        times.append(time.perf_counter() - t)
    held = heldout_fit(robot, effects, sample, target, model=model)
    t = time.perf_counter()
    result = diagnose(RobotAdapter(robot), spec, sample)
    diag_s = time.perf_counter() - t
    n_cand = len(result["candidates"])
    top = result["candidates"][0] if n_cand else {}
    return {"robot": robot.name, "joints": n_joints, "sample_poses": int(sample.n), "target_poses": int(target.n),
            "parameters": len(model.names_), "left_at_nominal": len(model.fixed_),
            "fit_seconds": min(times), "heldout_rms_before_mm": held["rms_before_mm"],
            "heldout_rms_after_mm": held["rms_after_mm"], "diagnose_seconds": diag_s, "candidates": n_cand,
            "diagnose_seconds_per_candidate": diag_s / max(n_cand, 1),
            "diagnose_top": f"{top.get('effect')} {top.get('target')}" if top else None}


def run() -> dict:
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    rows = [one(n, p) for n, p in ROBOTS.items()]
    ns = np.array([r["joints"] for r in rows], float)

    def slope(key):
        return float(np.polyfit(np.log(ns), np.log([r[key] for r in rows]), 1)[0])

    return {"robots": rows, "fit_time_exponent_in_N": slope("fit_seconds"),
            "diagnose_time_exponent_in_N": slope("diagnose_seconds"),
            "candidates_exponent_in_N": slope("candidates")}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=1, default=float))
