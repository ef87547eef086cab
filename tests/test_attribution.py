"""effect_swaps (pipeline.diagnosis.attribution): which effect makes two fits differ on a campaign's poses.

Simulated KR210 poses (SYNTHETIC): two models that share every parameter but joint 2's map; the measurements are
the second model's predictions in a tracker frame turned and shifted from the base."""

import numpy as np
import pytest

from pipeline.diagnosis.attribution import effect_key, effect_swaps
from pipeline.robot.arm.effects import Base, Compliance, Geometry, JointMap, RobotData
from pipeline.robot.arm.kinematics import gravity_torques, load_robot
from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses
from pipeline.robot.model.design import Design

ROBOT = load_robot("raw/robot/kr210/robot.toml")


def _data(Q):
    n = len(Q)
    return RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(ROBOT, Q),
                     ROBOT.lower_deg, ROBOT.upper_deg)


def test_the_effect_that_differs_is_the_one_whose_swap_closes_the_gap():
    Q = draw_poses(ROBOT, 120, np.random.default_rng(3), ROBOT_FIXTURE["box_mm"], 10.0)
    data = _data(Q)
    effects = [e.prepared(ROBOT, data) for e in (Geometry(), Base(), JointMap(joints=[2]), Compliance(joints=[2]))]
    d = Design(ROBOT, effects, data)
    rng = np.random.default_rng(4)
    a = 0.05 * rng.normal(size=d.p)                               # mm / mrad: a fitted model
    b = a.copy()
    is_map = np.array([n.startswith("map2_") for n in d.names])
    b[is_map] += 0.3 * np.sin(np.arange(is_map.sum()) / 3.0)      # another map of joint 2 (about 60 arcsec)
    turn = np.array([[np.cos(0.2), -np.sin(0.2), 0], [np.sin(0.2), np.cos(0.2), 0], [0, 0, 1.0]])
    measured = d.predict(b) @ turn.T + [1500.0, -200.0, 30.0]     # the tracker's frame
    sample = np.arange(data.n) % 3 != 0
    out = effect_swaps(ROBOT, (effects, a), (effects, b), data, measured, sample, ~sample)
    assert out["b_mm"] < 1e-6 < 0.05 < out["a_mm"]
    by = {(e["effect"], tuple(e["joints"])): e for e in out["effects"]}
    assert by[("joint_map", (2,))]["b_into_a_mm"] < 1e-6                  # swapping the map closes the gap
    assert by[("joint_map", (2,))]["a_into_b_mm"] == pytest.approx(out["a_mm"], rel=1e-6)
    for k in (("geometry", ()), ("base", ()), ("compliance", (2,))):
        assert by[k]["b_into_a_mm"] == pytest.approx(out["a_mm"], rel=1e-6)  # the others change nothing
    assert by[("joint_map", (2,))]["joint_rms_arcsec"][1] > 10.0
    assert max(by[("joint_map", (2,))]["joint_rms_arcsec"][j] for j in (0, 2, 3, 4, 5)) == 0.0
    # joint 2's whole angle error swapped closes it too; any other joint's changes nothing
    angles = {e["joint"]: e for e in out["joint_angles"]}
    assert angles[2]["b_into_a_mm"] < 1e-6 and angles[2]["rms_arcsec"] > 10.0
    assert all(angles[j]["b_into_a_mm"] == pytest.approx(out["a_mm"], rel=1e-6) for j in (1, 3, 4, 5, 6))


def test_an_effect_is_known_by_name_joints_and_orders_not_by_its_grid():
    assert effect_key(JointMap(joints=[2], range_deg={"2": [-10.0, 10.0]})) == effect_key(JointMap(joints=[2]))
    assert effect_key(JointMap(joints=[2])) != effect_key(JointMap(joints=[3]))
