"""Plausibility (pipeline.robot.model.plausibility): the bounds, the frames' deviations, the judgement."""

import numpy as np

from pipeline.robot.arm.kinematics import build_error_model, load_robot
from pipeline.robot.model import plausibility


def test_parameters_beyond_their_bound_are_named_worst_first():
    bad = plausibility.implausible_parameters([
        {"name": "a", "value": 0.5, "unit": "mm"},
        {"name": "b", "value": 300.0, "unit": "mm"},
        {"name": "c", "value": -40000.0, "unit": "arcsec"},
        {"name": "d", "value": float("nan"), "unit": "mm"},
        {"name": "e", "value": 1e9, "unit": "no bound"}])
    assert [q["name"] for q in bad] == ["d", "b", "c"]
    assert bad[1]["bound"] == plausibility.MAX_LENGTH_ERROR_MM and bad[0]["bound"] is None
    assert plausibility.describe_implausible(bad, limit=1).endswith("and 2 more")


def test_the_nominal_robots_frames_do_not_move_and_a_base_shift_is_seen_at_every_frame():
    robot = load_robot("raw/robot/kr210/robot.toml")
    model, idx = build_error_model(robot)
    rng = np.random.default_rng(0)
    Q0 = np.zeros((5, idx.nq))
    Q0[:, idx.joints] = np.deg2rad(rng.uniform(-30, 30, size=(5, idx.joints.size)))
    nominal = plausibility.frame_deviations(model, idx, Q0, Q0)
    assert max(abs(d["value"]) for d in nominal) < 0.05     # arcsec: arccos near 1 resolves ~1e-8 rad
    Q = Q0.copy()
    Q[:, idx.base[0]] = 0.002          # the first base error channel: 2 mm (or 2 mrad)
    moved = {d["name"]: d["value"] for d in plausibility.frame_deviations(model, idx, Q, Q0)}
    base = [v for k, v in moved.items() if k.startswith("the base frame")]
    assert max(base) > 1.0 and moved["the SMR: distance from its nominal position (largest over the sampled poses)"] > 1.0
