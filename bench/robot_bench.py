"""Speed and scale of the robot identification (issue #3): ``run() -> dict``.

Third-order Chebyshev identification (144 coefficients, improved L-M with the analytic
pinocchio Jacobian) on 100 and on 10,000 poses; targets: under 2 s and under 30 s, memory
linear in the number of poses (peak traced by tracemalloc).
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np


def _problem(n, seed=0):
    from pipeline.calibrate import Design
    from pipeline.robot import gravity_torques, load_robot
    from pipeline.robot_effects import Chebyshev, RobotData

    robot = load_robot("raw/robot/kr210/robot.toml")
    rng = np.random.default_rng(seed)
    Q = rng.uniform(robot.lower_deg, robot.upper_deg, (n, 6))
    data = RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(robot, Q),
                     robot.lower_deg, robot.upper_deg)
    d = Design(robot, [Chebyshev(order=3)], data)
    truth = rng.normal(0, 0.02, d.p)
    data.measured_mm = d.predict(truth) + rng.normal(0, 0.015, (n, 3))
    return robot, data


def identify_once(n, seed=0) -> dict:
    from pipeline.calibrate import RobotErrorModel
    from pipeline.chebyshev import CHEB_RANK_TOL, LM_DEFAULTS
    from pipeline.robot_effects import Chebyshev

    robot, data = _problem(n, seed)
    tracemalloc.start()
    t0 = time.perf_counter()
    m = RobotErrorModel(robot, [Chebyshev(order=3)], solver="lm", lm_options=LM_DEFAULTS,
                        rank_tol=CHEB_RANK_TOL, reduction="svd").fit(data)
    seconds = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"poses": n, "seconds": seconds, "iterations": m.n_iter_, "cost_mm2": m.cost_,
            "peak_memory_mb": peak / 2**20, "rank": m.identifiability_["rank"]}


def run() -> dict:
    """Benchmark the third-order Chebyshev identification on 100 and 10,000 poses."""
    from pipeline.lm import limit_blas_threads

    limit_blas_threads(1)
    small = identify_once(100)
    mid = identify_once(1000)
    large = identify_once(10000)
    return {"chebyshev_order3_100_poses": small, "chebyshev_order3_1000_poses": mid,
            "chebyshev_order3_10000_poses": large,
            "targets": {"100_poses_s": 2.0, "10000_poses_s": 30.0},
            "ok": small["seconds"] < 2.0 and large["seconds"] < 30.0,
            "memory_per_pose_kb": {"1000": mid["peak_memory_mb"] * 1024 / 1000,
                                   "10000": large["peak_memory_mb"] * 1024 / 10000}}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
