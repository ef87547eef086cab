"""Planned poses against random ones (issue #19): ``run() -> dict``.

* ``real``: the shipped real UR10 series (raw/real/ur10-ipa, imported as ``jointcal import`` does):
  the sample poses are the pool, the target poses are held out. For K = 12, 20, 30, 60 poses, the
  planned set (``jointcal plan``'s default model-robust D-optimal choice, and the plain D-optimal
  one, ``--criterion D``; seeing joint values only) and RANDOM_DRAWS
  random sets of K sample poses are each fitted with geometry + base + tool (the estimator ``jointcal
  fit`` uses) and judged on every target pose (RMS of the 3-D error, mm): the planned error, the
  random draws' median, quartiles, extremes, and how many random fits did not converge. The tracker
  frame is registered once on all the series' sample poses (as the import does); the fitted base
  (6 dof) takes up any rigid difference, so the registration does not favour either choice.
* ``virtual``: the virtual KR210 cell (pipeline.robot.cell.simulate; ``jointcal simulate measure`` stands
  in for it once it lands) with no backlash but a hidden one on joint 4 (90 arcsec): from a pool of
  300 reachable poses (drawn per trial), K poses chosen at random (visited in the short-path order,
  directions from the motion) or planned with ``--reveal 'name = "backlash", joints = [4]'``
  (directions as the plan writes them), measured, and diagnosed (``jointcal diagnose``, spec
  geometry + base + tool): how often diagnosis names backlash of joint 4 first and meaningful (a
  recommendation: ``named_first``), and how often it is merely first in the list (``listed_first``).
* ``speed``: ``plan_poses`` on a pool of 10,000 UR10 poses, K = 30 (wall time, goal under 30 s).
"""

from __future__ import annotations

import io
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "raw" / "real" / "ur10-ipa"
SPEC = ROOT / "specs" / "robot_kinematic.toml"
KS = (12, 20, 30, 60)
RANDOM_DRAWS = 30
VIRTUAL_K = (20, 30)
VIRTUAL_TRIALS = 10


def _import(series: str, tmp: Path) -> Path:
    from pipeline.robot.campaign.importer import import_campaign

    src = {"B": REAL / "Series_B" / "measurements_joint_configurations.csv",
           "C": REAL / "Series_C" / "measurements_random_poses.csv"}[series]
    out = tmp / series
    import_campaign(src, REAL / "map.toml", REAL / "robot.toml", out)
    return out


def _stats(values) -> dict:
    v = np.asarray(values, float)
    return {"median_mm": float(np.median(v)), "q25_mm": float(np.percentile(v, 25)),
            "q75_mm": float(np.percentile(v, 75)), "min_mm": float(v.min()), "max_mm": float(v.max())}


def real_series(folder: Path) -> dict:
    from pipeline.core.spec import load_spec
    from pipeline.plan.design import plan_poses, pool_data
    from pipeline.robot.model.estimate import fit_effects
    from pipeline.robot.campaign.ingest import robot_data_sets

    robot, (sample, target) = robot_data_sets(folder, ("sample",), ("target",))
    effects = load_spec(SPEC).effects
    pool = pool_data(robot, sample.q_deg)

    def heldout(idx):
        m = fit_effects(robot, effects, sample.subset(np.sort(idx)))
        e = np.linalg.norm(m.predict(target) - target.measured_mm, axis=1)
        return float(np.sqrt(np.mean(e ** 2))), bool(m.converged_ and m.plausible_)

    rows = []
    rng = np.random.default_rng(19)
    for K in KS:
        t = time.perf_counter()
        plan = plan_poses(robot, effects, pool, K)
        t_plan = time.perf_counter() - t
        planned, ok = heldout(plan.chosen)
        plain, plain_ok = heldout(plan_poses(robot, effects, pool, K, criterion="D").chosen)
        draws = [heldout(rng.choice(sample.n, K, replace=False)) for _ in range(RANDOM_DRAWS)]
        rms = [d[0] for d in draws]
        rows.append({"k": K, "planned_mm": planned, "planned_converged": ok, "plan_seconds": t_plan,
                     "planned_plain_D_mm": plain, "planned_plain_D_converged": plain_ok,
                     "predicted_rms_mm_at_0.05mm_noise": plan.predicted_rms_mm,
                     "random": {**_stats(rms), "draws": RANDOM_DRAWS, "not_converged": sum(not d[1] for d in draws),
                                "worse_than_planned": int(sum(r > planned for r in rms))}})
        print(f"  {folder.name} K={K}: planned {planned:.3f} mm (plain D {plain:.3f}), random median "
              f"{np.median(rms):.3f} mm", flush=True)
    for r in rows:   # the fewest random poses whose median reaches the planned error
        r["random_k_whose_median_reaches_it"] = next((q["k"] for q in rows if q["random"]["median_mm"] <= r["planned_mm"]),
                                                     None)
    return {"pool": int(sample.n), "held_out": int(target.n), "rows": rows}


def _virtual_trial(robot, cell, spec_path, K, seed, tmp: Path) -> dict:
    from pipeline.core.spec import load_spec
    from pipeline.diagnosis.campaign import run_diagnosis
    from pipeline.plan.api import plan_from_pool
    from pipeline.plan.design import visiting_order
    from pipeline.plan.pool import Pool
    from pipeline.plan.reveal import parse_reveal
    from pipeline.robot.arm.kinematics import directions_from_sequence
    from pipeline.robot.cell.simulate import draw_poses

    rng = np.random.default_rng([19, seed])
    Q = draw_poses(robot, 300, rng, [1200.0, 1600.0, 1200.0], 30.0, cell.model_nominal)
    mid = (robot.lower_deg + robot.upper_deg) / 2
    pay = 60.0
    out = {}
    # random: K poses, visited in the short-path order a user would also use
    q = Q[rng.choice(len(Q), K, replace=False)]
    q = q[visiting_order(q, mid)]
    out["random"] = (q, directions_from_sequence(q, start_deg=mid))
    pool = Pool(np.array([f"P{k:03d}" for k in range(len(Q))], dtype=object), Q, np.zeros(len(Q)), False)
    text, _ = plan_from_pool(robot, load_spec(spec_path).effects, pool, K,
                             reveal=parse_reveal('name = "backlash", joints = [4]'))
    plan = pd.read_csv(io.StringIO(text))
    out["planned"] = (plan[[f"q{j}" for j in range(1, 7)]].to_numpy(float),
                      plan[[f"dir{j}" for j in range(1, 7)]].to_numpy(int))
    named = {}
    for how, (q, d) in out.items():
        r = np.random.default_rng([19, seed, 1 if how == "random" else 2])
        payload = np.full(len(q), pay)
        P = cell.measure(cell.open_loop(q, d, payload, r), r)
        camp = tmp / f"{how}_{K}_{seed}"
        camp.mkdir(parents=True)
        (camp / "robot.toml").write_text((ROOT / "raw" / "robot" / "kr210" / "robot.toml").read_text())
        ids = [f"S{k:03d}" for k in range(len(q))]
        poses = pd.DataFrame({"point_id": ids, "set": "sample"})
        for j in range(6):
            poses[f"q{j + 1}"] = q[:, j]
        for j in range(6):
            poses[f"dir{j + 1}"] = d[:, j]
        poses["payload_kg"] = payload
        poses.to_csv(camp / "poses.csv", index=False)
        pd.DataFrame({"point_id": ids, "x_mm": P[:, 0], "y_mm": P[:, 1], "z_mm": P[:, 2]}).to_csv(
            camp / "tracker.csv", index=False)
        result, _ = run_diagnosis(camp, spec_path)
        first = result["candidates"][0] if result["candidates"] else None
        top = first is not None and first["effect"] == "backlash" and first["target"] == 4 and bool(first.get("meaningful", True))
        named[how] = {"first": None if first is None else f"{first['effect']} {first['target']}",
                      "listed_first": bool(first is not None and first["effect"] == "backlash" and first["target"] == 4),
                      "named_first": bool(top), "gain": None if first is None else float(first["gain"])}
    return named


def virtual() -> dict:
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import ROBOT_FIXTURE, make_cell

    robot = load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml")
    config = {**ROBOT_FIXTURE, "backlash_arcsec": [0.0] * 6}
    cell = make_cell(robot, config, {"effect": "backlash", "joint": 4, "arcsec": 90.0})
    tmp = Path(tempfile.mkdtemp(prefix="jointcal-plan-bench-"))
    rows = []
    try:
        for K in VIRTUAL_K:
            trials = [_virtual_trial(robot, cell, SPEC, K, s, tmp) for s in range(VIRTUAL_TRIALS)]
            row = {"k": K, "trials": VIRTUAL_TRIALS}
            for how in ("planned", "random"):
                row[how] = {"named_first": int(sum(t[how]["named_first"] for t in trials)),
                            "listed_first": int(sum(t[how]["listed_first"] for t in trials)),
                            "median_gain_of_first": float(np.median([t[how]["gain"] or 0.0 for t in trials])),
                            "first_listed": [t[how]["first"] for t in trials]}
            print(f"  virtual K={K}: backlash 4 named first, planned {row['planned']['named_first']}/{VIRTUAL_TRIALS}, "
                  f"random {row['random']['named_first']}/{VIRTUAL_TRIALS}", flush=True)
            rows.append(row)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"hidden": "backlash of joint 4, 90 arcsec (the cell has no other backlash)", "pool": 300, "rows": rows}


def speed() -> dict:
    from pipeline.core.spec import load_spec
    from pipeline.plan.design import plan_poses, pool_data
    from pipeline.robot.arm.kinematics import load_robot

    robot = load_robot(REAL / "robot.toml")
    rng = np.random.default_rng(0)
    q = rng.uniform(np.maximum(robot.lower_deg, -180), np.minimum(robot.upper_deg, 180), (10000, len(robot.joints)))
    t = time.perf_counter()
    pool = pool_data(robot, q)
    plan = plan_poses(robot, load_spec(SPEC).effects, pool, 30)
    return {"pool": 10000, "k": 30, "seconds": time.perf_counter() - t, "goal_seconds": 30.0,
            "parameters_identifiable": int(np.sum(plan.identification["keep"]))}


def run() -> dict:
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    tmp = Path(tempfile.mkdtemp(prefix="jointcal-plan-real-"))
    try:
        real = {f"series_{s}": real_series(_import(s, tmp)) for s in ("C", "B")}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"real": real, "virtual": virtual(), "speed": speed()}


if __name__ == "__main__":
    import json
    import sys

    part = sys.argv[1] if len(sys.argv) > 1 else "all"
    fn = {"virtual": virtual, "speed": speed, "all": run}[part]
    print(json.dumps(fn(), indent=1, default=float))
