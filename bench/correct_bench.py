"""``jointcal correct`` at 10,000 poses (issue #18): ``run() -> dict``.

A model with every kind of effect the correction must invert (geometry, base, tool, compliance,
backlash, joint harmonics) fitted on a virtual cell's campaign, then a 10,000-point program
(drawn in the model's sampled joint box, payload 60 kg) corrected by a fresh ``jointcal correct``
process as a user runs it. Goal: under 10 s (best of 3). Also the library call alone.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
JC = str(ROOT / ".venv" / "bin" / "jointcal")
SPEC = (ROOT / "specs" / "robot_cell.toml").read_text()


def fitted_cell(tmp: Path) -> dict:
    """The fixture's KR210 virtual cell measured open loop (`simulate measure`, no gratings) and fitted with
    every effect of its physics (specs/robot_cell.toml); returns the fit JSON, written to tmp/fit.json."""
    cell = tmp / "cell"
    cell.mkdir()
    shutil.copy(ROOT / "raw/robot/kr210/robot.toml", cell / "robot.toml")
    subprocess.run([JC, "simulate", "robot", "--campaign", cell, "--truth", tmp / "truth.json"], check=True,
                   capture_output=True)
    poses = pd.read_csv(cell / "poses.csv")
    poses[poses["set"] != "repeat"].drop(columns=[c for c in poses if c.startswith("grating")]).to_csv(
        tmp / "prog.csv", index=False)
    subprocess.run([JC, "simulate", "measure", "--truth", tmp / "truth.json", "--poses", tmp / "prog.csv",
                    "--campaign", tmp / "meas", "--robot", cell / "robot.toml"], check=True, capture_output=True)
    (tmp / "spec.toml").write_text(SPEC)
    subprocess.run([JC, "fit", "--campaign", tmp / "meas", "--spec", tmp / "spec.toml", "--out", tmp / "fit.json"],
                   check=True, capture_output=True)
    return json.loads((tmp / "fit.json").read_text())


def run(n: int = 10_000, repeat: int = 3) -> dict:
    from pipeline.correct.robot import ModelKinematics, correct_commands
    from pipeline.robot.model.predict import load_model_document

    tmp = Path(tempfile.mkdtemp(prefix="jointcal-correct-bench-"))
    try:
        fit = fitted_cell(tmp)
        lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
        rng = np.random.default_rng(1)
        Q = rng.uniform(lo, hi, (n, len(lo)))
        prog = pd.DataFrame({"point_id": [f"P{k:05d}" for k in range(n)]})
        for j in range(Q.shape[1]):
            prog[f"q{j + 1}"] = Q[:, j]
        prog["payload_kg"] = 60.0
        prog.to_csv(tmp / "program.csv", index=False)
        best = None
        for _ in range(repeat):
            t = time.perf_counter()
            subprocess.run([JC, "correct", "--model", tmp / "fit.json", "--targets", tmp / "program.csv",
                            "--out", tmp / "out.csv", "--max-correction-deg", "2"], check=True, capture_output=True)
            dt = time.perf_counter() - t
            best = dt if best is None else min(best, dt)
        out = pd.read_csv(tmp / "out.csv")
        robot, effects, model, sampled, _ = load_model_document(fit, "fit.json")
        kin = ModelKinematics(robot, model)
        t = time.perf_counter()
        res = correct_commands(kin, Q, None, payload_kg=np.full(n, 60.0), sampled=sampled, max_correction_deg=2.0)
        lib = time.perf_counter() - t
        ok = out["status"] == "ok"
        return {"n_poses": n, "command_seconds": best, "library_seconds": lib, "goal_seconds": 10.0,
                "within_goal": bool(best < 10.0), "ok_rows": int(ok.sum()),
                "max_residual_um": float(out.loc[ok, "model_residual_um"].max()),
                "mean_iterations": float(res.iterations[res.status == "ok"].mean())}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
