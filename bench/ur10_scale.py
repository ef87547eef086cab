"""A simulated UR10 campaign of any size with the kind of errors the real series show (issue 32).

The truth is the model :data:`TRUTH_SPEC` fitted on the real UR10's Series C (raw/real/ur10-ipa,
imported as ``jointcal import`` does): geometry, base, tool and the joint maps and compliance the
diagnosis loop finds on the real series. Poses are Series C's sample poses, each moved by a seeded
Gaussian step of :data:`JITTER_DEG` per joint (kept inside the range Series C sampled); each pose's
tracker point is the truth's prediction plus Gaussian noise of the truth fit's own residual size
per axis, and :data:`N_WILD` points are moved 2 to 6 mm (an SMR reseated). The points are written in
Series C's tracker frame (``frame = "tracker"``), 75 % sample and 25 % target poses, so that
``jointcal fit / predict / diagnose / robot diagnose-loop`` see what a user's import would give.

``python -m bench.ur10_scale OUT N [SEED]`` writes one; :func:`write_campaign` is the function.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "raw" / "real" / "ur10-ipa"
#: the truth: what the diagnosis loop adds on the real series (joint maps, compliance) on top of geometry
TRUTH_SPEC = """[model]
kind = "robot"

[[effect]]
name = "geometry"

[[effect]]
name = "base"

[[effect]]
name = "tool"

[[effect]]
name = "joint_map"
joints = [2, 3]

[[effect]]
name = "compliance"
joints = [2, 3]
"""
JITTER_DEG = 4.0
SAMPLE_FRACTION = 0.75
N_WILD = 6


def import_series(series: str, out: Path) -> Path:
    """A real series imported as ``jointcal import`` does (into ``out``)."""
    from pipeline.robot.campaign.importer import import_campaign

    src = {"B": REAL / "Series_B" / "measurements_joint_configurations.csv",
           "C": REAL / "Series_C" / "measurements_random_poses.csv"}[series]
    import_campaign(src, REAL / "map.toml", REAL / "robot.toml", out)
    return out


def write_campaign(out, n: int, seed: int = 32, real_c=None) -> dict:
    """Write a simulated UR10 campaign of ``n`` poses into the folder ``out``.

    Parameters
    ----------
    out : path
        The campaign folder (robot.toml, campaign.toml, poses.csv, tracker.csv are written).
    n : int
        Poses (75 % sample, 25 % target).
    seed : int
    real_c : path, optional
        Series C already imported (else imported into ``out``/_C and removed).

    Returns
    -------
    dict: ``n``, ``noise_mm`` (per axis), ``wild`` (point ids moved, mm).
    """
    import shutil

    from pipeline.core.spec import parse_spec
    from pipeline.robot.arm.effects import RobotData
    from pipeline.robot.campaign.frame import apply, from_matrix
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimate import fit_effects

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    own = real_c is None
    camp = import_series("C", out / "_C") if own else Path(real_c)
    robot, (sample,), info = robot_data_sets(camp, ("sample",), with_frame=True)
    truth = fit_effects(robot, list(parse_spec(TRUTH_SPEC, "<truth>").effects), sample)
    noise = float(truth.rms_mm_ / np.sqrt(3.0))
    rng = np.random.default_rng(seed)
    lo, hi = sample.q_deg.min(axis=0), sample.q_deg.max(axis=0)
    pick = rng.integers(0, sample.n, n)
    q = np.clip(sample.q_deg[pick] + rng.normal(0.0, JITTER_DEG, (n, robot.n_joints)), lo, hi)
    temp = sample.temperature_c[pick]
    data = RobotData(q, np.ones_like(q, dtype=int), np.zeros(n), temp, np.zeros_like(q), sample.lower_deg,
                     sample.upper_deg, None, np.array([f"P{k + 1:05d}" for k in range(n)], dtype=object))
    # the torques the effects read: those of the ingest (gravity of the arm, no payload)
    from pipeline.robot.arm.kinematics import gravity_torques
    data.torque_nm = gravity_torques(robot, q, np.zeros(n))
    xyz = truth.predict(data) + rng.normal(0.0, noise, (n, 3))
    wild = rng.choice(n, N_WILD, replace=False)
    step = rng.normal(size=(N_WILD, 3))
    size = rng.uniform(2.0, 6.0, N_WILD)
    xyz[wild] += step / np.linalg.norm(step, axis=1)[:, None] * size[:, None]
    R, t = from_matrix(info["tracker_to_base"])
    raw = apply(R.T, -R.T @ t, xyz)               # back into the tracker's frame
    sets = np.where(rng.random(n) < SAMPLE_FRACTION, "sample", "target")
    poses = pd.DataFrame({"point_id": data.point_id, "set": sets})
    for j in range(robot.n_joints):
        poses[f"q{j + 1}"] = [f"{v:.10f}" for v in q[:, j]]
    poses["temperature_c"] = [f"{v:.8f}" for v in temp]
    tracker = pd.DataFrame({"point_id": data.point_id, **{c: [f"{v:.5f}" for v in raw[:, k]]
                                                          for k, c in enumerate(("x_mm", "y_mm", "z_mm"))}})
    shutil.copy(camp / "robot.toml", out / "robot.toml")
    (out / "campaign.toml").write_text(f"# simulated UR10 campaign (bench/ur10_scale.py), {n} poses, seed {seed}\n"
                                       'frame = "tracker"\n')
    poses.to_csv(out / "poses.csv", index=False, lineterminator="\n")
    tracker.to_csv(out / "tracker.csv", index=False, lineterminator="\n")
    if own:
        shutil.rmtree(out / "_C", ignore_errors=True)
    return {"n": n, "noise_mm": noise, "truth_rms_mm": float(truth.rms_mm_),
            "wild": {str(data.point_id[k]): float(s) for k, s in zip(wild, size)}}


if __name__ == "__main__":
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    print(write_campaign(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else 32))
