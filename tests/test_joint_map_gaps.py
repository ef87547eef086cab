"""A joint map over a sampled range with stretches no pose reached (a grid campaign: a joint held on a lattice
of angles, or its range sampled in lobes). Between lattice angles the map interpolates its measured knots; across
a wide stretch it fades to zero as beyond the range's ends. Before, a knot no pose reached was a free value the fit
left at 0: a comb of spikes and zeros, wrong on every pose of another campaign between the lattice angles.

Simulated KR210 poses (SYNTHETIC): the truth is a periodic angle error of joint 2 (the tests' generator, a
joint_harmonic of 30 deg period), never read by the fit."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.spec import parse_spec
from pipeline.robot.arm.effects import (JOINT_MAP_GAP_DEG, Geometry, JointHarmonic, JointMap, RobotData,
                                        sampled_gaps)
from pipeline.robot.arm.kinematics import gravity_torques, load_robot
from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses
from pipeline.robot.model.design import Design
from pipeline.robot.model.estimator import RobotErrorModel

ROBOT = load_robot("raw/robot/kr210/robot.toml")
LATTICE_DEG = 6.0


def _data(Q, measured=None):
    n = len(Q)
    return RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(ROBOT, Q),
                     ROBOT.lower_deg, ROBOT.upper_deg, measured)


def _measured(Q, truth):
    """The generator: SMR positions (n, 3) mm of the robot with joint 2's periodic error."""
    return Design(ROBOT, truth, _data(Q)).predict(np.array([0.5, -0.3]))      # mrad: about 120 arcsec


@pytest.fixture(scope="module")
def campaigns():
    truth = [JointHarmonic(joints=[2], orders=[12])]                            # a 30 deg period
    grid = draw_poses(ROBOT, 300, np.random.default_rng(11), ROBOT_FIXTURE["box_mm"], 10.0)
    grid[:, 1] = np.round(grid[:, 1] / LATTICE_DEG) * LATTICE_DEG               # joint 2 on a lattice
    other = draw_poses(ROBOT, 200, np.random.default_rng(12), ROBOT_FIXTURE["box_mm"], 10.0)
    lo, hi = grid[:, 1].min(), grid[:, 1].max()
    other = other[(other[:, 1] > lo) & (other[:, 1] < hi)]                      # inside the lattice's range
    return truth, grid, other


def test_a_map_fitted_on_a_lattice_holds_between_its_angles(campaigns):
    truth, grid, other = campaigns
    fit = RobotErrorModel(ROBOT, [Geometry(), JointMap(joints=[2])]).fit(_data(grid, _measured(grid, truth)))
    nominal = Design(ROBOT, truth, _data(other)).predict(np.zeros(2))
    size = np.sqrt(np.mean(np.sum((_measured(other, truth) - nominal) ** 2, axis=1)))
    err = np.sqrt(np.mean(np.sum((fit.predict(_data(other)) - _measured(other, truth)) ** 2, axis=1)))
    # the lattice's own poses are fitted either way; between them the map interpolated (before: 0 there)
    assert err < 0.35 * size, (err, size)


def test_knots_no_pose_reaches_are_left_out_and_written_into_the_spec_lines(campaigns):
    _, grid, _ = campaigns
    e = JointMap(joints=[2]).prepared(ROBOT, _data(grid))
    gaps = e.params["gaps_deg"]["2"]
    assert gaps == sampled_gaps(grid[:, 1], 2.0) and all(b - a == pytest.approx(LATTICE_DEG) for a, b in gaps)
    # every knot has a pose within a grid step of it
    kn = e.knots(2)
    assert np.all(np.min(np.abs(kn[:, None] - grid[None, :, 1]), axis=1) < 2.0)
    again = parse_spec('[model]\nkind = "robot"\n\n' + e.spec_lines() + "\n").effects[0]
    np.testing.assert_array_equal(again.knots(2), kn)
    assert e.penalty(ROBOT, 100).shape[1] == len(e.parameter_names(ROBOT)) == kn.size


def test_a_wide_stretch_fades_to_zero_and_a_narrow_one_interpolates():
    q = np.concatenate([np.linspace(-100, -60, 41), np.linspace(-20, 0, 21), [6.0, 12.0]])
    e = JointMap(joints=[1]).prepared(ROBOT, type("D", (), {"q_deg": np.column_stack([q] * 6)})())
    B = e.map_basis(1, np.array([-40.0, -60.0 + JOINT_MAP_GAP_DEG / 4, 3.0, 9.0]))
    assert B[0].sum() == 0.0                                    # the middle of a 40 deg stretch: not measured
    assert 0.0 < B[1].sum() < 1.0                               # fading out of the measured lobe
    np.testing.assert_allclose(B[2:].sum(axis=1), 1.0)          # 6 deg apart: interpolated
    # an effect prepared again (the region plan, diagnosis) lays its grid and gaps anew
    moved = JointMap(**{k: v for k, v in e.params.items() if k != "range_deg"}).prepared(
        ROBOT, type("D", (), {"q_deg": np.column_stack([np.linspace(-100, 0, 101)] * 6)})())
    assert "gaps_deg" not in moved.params
