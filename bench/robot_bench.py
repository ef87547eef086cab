"""Speed and scale of the robot identification (issues #3, #6): ``run() -> dict``.

Both stages of ``specs/robot_paper.toml``, run by the code the CLI runs, on synthetic
campaigns of 10^2, 10^3 and 10^4 poses of the KR210 (joint angles uniform in the robot's
range, tracker noise 0.015 mm per axis):

* ``mdh``: the kinematic stage, ``pipeline.robot.model.estimator.calibrate_mdh`` with the spec's
  ``kinematic_effects`` (geometry + base: 36 parameters, Gauss-Newton, identifiability),
  as ``jointcal robot calibrate`` runs it;
* ``chebyshev``: the feedback stage's identification, ``pipeline.robot.model.chebyshev.chebyshev_estimator``
  with the spec's ``feedback_effects`` (order 3 on joints 1-6: 144 coefficients) and the
  spec's improved L-M constants (``jointcal robot chebyshev`` also runs scipy beside it as a
  cross-check; that is measured by ``bench.solver_bench``).

For each size: best wall time of the whole call (without tracing), peak traced memory (a
separate traced call), iterations; for the Chebyshev fit also the solver's own time (the
rest is set-up: design, identifiability analysis, truncated SVD). For each series the fitted
exponents of time and memory against the number of poses (least-squares slope of the logs
over all sizes, and over the top decade). Targets (issue #3): Chebyshev under 2 s at 100 poses, under 30 s at 10^4.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZES = (100, 1000, 10000)
NOISE_MM = 0.015


def _spec_and_robot():
    from pipeline.core.spec import load_spec
    from pipeline.robot.arm.kinematics import load_robot

    return load_spec(ROOT / "specs" / "robot_paper.toml"), load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml")


def stage_effects(spec, stage):
    from pipeline.robot.model.fit import stage_effects as effects_of

    return effects_of(spec, stage)


def synthetic_campaign(robot, effects, n, seed=0, size=0.02):
    """``n`` poses uniform in the joint range; tracker positions of the model ``effects`` with
    parameters drawn N(0, size) (internal units: mm, mrad) plus N(0, 0.015 mm) noise."""
    from pipeline.robot.model.design import Design
    from pipeline.robot.arm.effects import RobotData
    from pipeline.robot.arm.kinematics import gravity_torques

    rng = np.random.default_rng(seed)
    Q = rng.uniform(robot.lower_deg, robot.upper_deg, (n, 6))
    data = RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(robot, Q),
                     robot.lower_deg, robot.upper_deg)
    d = Design(robot, list(effects), data)
    truth = rng.normal(0, size, d.p)
    data.measured_mm = d.predict(truth) + rng.normal(0, NOISE_MM, (n, 3))
    return data


def _series(what, sizes, fit_once):
    from bench.run import exponents, measure

    rows = []
    for n in sizes:
        calls = []
        seconds, peak = measure(lambda: calls.append(fit_once(n)), repeat=3 if n <= 1000 else 1)
        info = dict(calls[-1])
        if "solver_seconds" in info:      # best of the untraced calls, like ``seconds``
            info["solver_seconds"] = min(c["solver_seconds"] for c in calls[:-1])
            info["setup_seconds"] = seconds - info["solver_seconds"]
            info["solver_seconds_per_iteration"] = info["solver_seconds"] / max(info["iterations"], 1)
        rows.append({"poses": n, "seconds": seconds, "peak_mb": peak, "kb_per_pose": peak * 1024 / n, **info})
    out = {"what": what, "rows": rows,
           **exponents([r["poses"] for r in rows], [r["seconds"] for r in rows], [r["peak_mb"] for r in rows])}
    if "solver_seconds" in rows[0]:
        out["solver_only"] = exponents([r["poses"] for r in rows], [r["solver_seconds"] for r in rows])
        out["solver_per_iteration"] = exponents([r["poses"] for r in rows],
                                                [r["solver_seconds_per_iteration"] for r in rows])
    return out


def mdh_series(sizes=SIZES) -> dict:
    """The kinematic stage (``calibrate_mdh``, Gauss-Newton on geometry + base)."""
    from pipeline.robot.model.estimator import calibrate_mdh

    spec, robot = _spec_and_robot()
    effects = stage_effects(spec, "kinematic")
    campaigns = {n: synthetic_campaign(robot, effects, n, seed=1, size=0.1) for n in sizes}

    def fit_once(n):
        _, report = calibrate_mdh(robot, campaigns[n], effects)
        return {"iterations": report["iterations"], "rank": report["rank"], "n_params": report["n_params"],
                "rms_before_mm": report["rms_before_mm"], "rms_after_mm": report["rms_after_mm"]}

    return _series(f"MDH calibration (calibrate_mdh: {' + '.join(e.name for e in effects)}, Gauss-Newton, "
                   "identifiability analysis included)", sizes, fit_once)


def chebyshev_series(sizes=SIZES) -> dict:
    """The feedback stage's identification (improved L-M, truncated-SVD reduction)."""
    from pipeline.robot.model.chebyshev import LM_DEFAULTS, chebyshev_estimator

    spec, robot = _spec_and_robot()
    effects = stage_effects(spec, "feedback")
    opts = {**LM_DEFAULTS, **spec.model.get("lm", {})}
    campaigns = {n: synthetic_campaign(robot, effects, n, seed=0, size=0.02) for n in sizes}

    def fit_once(n):
        m = chebyshev_estimator(robot, effects, "lm", opts).fit(campaigns[n])
        return {"iterations": m.n_iter_, "solver_seconds": m.solver_result_.seconds, "cost_mm2": m.cost_,
                "rms_mm": m.rms_mm_,
                "converged": m.solver_result_.converged, "rank": m.identifiability_["rank"],
                "n_params": m.identifiability_["n_params"]}

    return _series("Chebyshev identification (chebyshev_estimator: order 3 on joints 1-6, improved L-M, "
                   "spec constants, truncated-SVD reduction included)", sizes, fit_once)


def run() -> dict:
    """Benchmark both robot identification stages at 10^2, 10^3 and 10^4 poses."""
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    mdh = mdh_series()
    cheb = chebyshev_series()
    by = {r["poses"]: r for r in cheb["rows"]}
    return {"mdh": mdh, "chebyshev": cheb,
            "targets": {"chebyshev_100_poses_s": 2.0, "chebyshev_10000_poses_s": 30.0},
            "ok": by[100]["seconds"] < 2.0 and by[10000]["seconds"] < 30.0,
            "synthetic_campaign": f"poses uniform in the KR210's joint range, parameters N(0, 0.1) (MDH) / "
                                  f"N(0, 0.02) (Chebyshev) in mm and mrad, tracker noise {NOISE_MM} mm per axis"}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2, default=float))
