"""The `joint_map` effect: an angle-dependent joint error on a grid over the sampled range, smooth,
fading to zero beyond it; its spec lines carry the grid so a fitted model can be applied elsewhere."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ROOT
from pipeline.robot.arm.kinematics import load_robot
from pipeline.robot.arm.effects import JOINT_MAP_FADE_DEG, JointMap, joint_map_basis
from pipeline.core.spec import parse_spec


def test_basis_interpolates_inside_and_fades_to_zero_beyond():
    knots = np.linspace(-100.0, -20.0, 41)
    q = np.array([-100.0, -61.0, -20.0, -20.0 + JOINT_MAP_FADE_DEG / 2, -20.0 + 2 * JOINT_MAP_FADE_DEG, -130.0])
    B = joint_map_basis(q, knots)
    np.testing.assert_allclose(B[:3].sum(axis=1), 1.0)
    assert B[1, 19] == pytest.approx(0.5) and B[1, 20] == pytest.approx(0.5)   # -61 is halfway between knots
    assert B[3].sum() == pytest.approx(0.5) and B[3, -1] == pytest.approx(0.5)  # half way through the fade
    assert np.all(B[4:] == 0.0)                                                  # beyond it: nothing


def test_prepared_effect_writes_its_grid_into_its_spec_lines():
    robot = load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml")

    class D:
        q_deg = np.column_stack([np.linspace(-30, 40, 50)] * 6)

    e = JointMap(joints=[2, 3], step_deg=5.0).prepared(robot, D)
    assert e.params["range_deg"] == {"2": [-30.0, 40.0], "3": [-30.0, 40.0]}
    again = parse_spec('[model]\nkind = "robot"\n\n' + e.spec_lines() + "\n").effects[0]
    assert again.parameter_names(robot) == e.parameter_names(robot)
    assert len(e.knots(2)) == 15                                        # 70 deg in 5 deg steps
    pen = e.penalty(robot, 100)
    assert pen.shape[1] == len(e.parameter_names(robot))
    # the penalty is blind to a straight line of zero mean (no curvature, no level) only in the ridge
    line = np.concatenate([np.linspace(-1, 1, 15), np.zeros(15)])
    assert np.linalg.norm(pen @ line) < 0.05 * np.linalg.norm(pen @ np.concatenate([np.ones(15), np.zeros(15)]))


def test_bad_parameters_are_refused_with_the_spec_line():
    from pipeline.core.errors import InputError

    with pytest.raises(InputError, match="step_deg"):
        parse_spec('[model]\nkind = "robot"\n\n[[effect]]\nname = "joint_map"\nstep_deg = 0\n', "s.toml")
