"""The estimator (pipeline.robot.model.estimator) in the scikit-learn manner: nothing done in the
constructor, fit returns self, fitted attributes end in `_`, one refit_without. Simulated KR210 poses."""

import numpy as np
import pytest

from pipeline.robot.arm.effects import Base, Geometry, RobotData
from pipeline.robot.arm.kinematics import build_model, gravity_torques, load_robot, positions
from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses
from pipeline.robot.model.design import Design
from pipeline.robot.model.estimator import RobotErrorModel

ROBOT = load_robot("raw/robot/kr210/robot.toml")


def _data(Q, measured=None):
    n = len(Q)
    return RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(ROBOT, Q),
                     ROBOT.lower_deg, ROBOT.upper_deg, measured)


@pytest.fixture(scope="module")
def fitted():
    Q = draw_poses(ROBOT, 60, np.random.default_rng(7), ROBOT_FIXTURE["box_mm"], 10.0)
    effects = [Geometry(), Base()]
    d = Design(ROBOT, effects, _data(Q))
    truth = np.zeros(d.p)
    truth[:6] = 0.05                                   # mrad: joint offsets
    meas = d.predict(truth) + 0.01 * np.random.default_rng(1).normal(size=(60, 3))
    data = _data(Q, meas)
    return data, effects, RobotErrorModel(ROBOT, effects).fit(data)


def test_the_constructor_stores_its_arguments_and_nothing_else():
    est = RobotErrorModel(ROBOT, [Geometry()], max_iter=7)
    assert est.max_iter == 7 and est.keep_designs is False
    assert not [a for a in vars(est) if a.endswith("_")]


def test_fit_returns_self_with_its_fitted_attributes(fitted):
    data, _, model = fitted
    for a in ("coef_", "basis_", "penalty_", "unseen_", "identifiability_", "rms_mm_", "dof_", "solver_result_"):
        assert hasattr(model, a), a
    assert model.weight_ is None and model.converged_
    assert model.solver_result_.x.shape == (model.basis_.shape[1],)
    np.testing.assert_allclose(model.basis_ @ model.solver_result_.x, model.coef_)


def test_refit_without_few_poses_is_the_fit_on_the_rest(fitted):
    data, effects, model = fitted
    keep = np.ones(data.n, bool)
    keep[[3, 30, 44]] = False
    kept = data.subset(keep)
    stepped = model.refit_without(data, keep, kept)
    again = RobotErrorModel(ROBOT, effects).fit(kept)
    # the same identification (the fit's), so compare the predictions
    np.testing.assert_allclose(stepped.predict(kept), again.predict(kept), atol=2e-4)
    assert stepped.rms_mm_ == pytest.approx(again.rms_mm_, rel=1e-3)
    assert stepped is not model and not np.array_equal(stepped.coef_, model.coef_)
    assert model.refit_without(data, np.ones(data.n, bool), data) is model


def test_refit_without_needs_fitted_directions_unless_told_otherwise(fitted):
    data, _, model = fitted
    keep = np.arange(data.n) > 2
    bare = RobotErrorModel.from_parameters(ROBOT, model.effects_, model.parameters())
    assert bare.refit_without(data, keep) is None
    assert bare.refit_without(data, keep, determined=False).coef_ is bare.coef_
    # three poses cannot determine every fitted direction
    assert model.refit_without(data, np.arange(data.n) < 3) is None
    assert model.refit_without(data, np.arange(data.n) < 3, determined=False) is not None


def test_held_out_residuals_land_on_their_folds_poses_whatever_the_labels():
    from pipeline.robot.model.estimate import held_out

    folds = np.array([7, 2, 7, 9, 2])                 # region folds: labels need not be 0..k-1
    parts = [(np.full((2, 3), 2.0), np.full((2, 3), -2.0)), (np.full((2, 3), 7.0), np.full((2, 3), -7.0)),
             (np.full((1, 3), 9.0), np.full((1, 3), -9.0))]
    cv = held_out(folds, [2, 7, 9], parts, has_orientation=True)
    np.testing.assert_array_equal(cv.residuals[:, 0], [7.0, 2.0, 7.0, 9.0, 2.0])
    np.testing.assert_array_equal(cv.extra["orientation"][:, 1], [-7.0, -2.0, -7.0, -9.0, -2.0])
    assert "orientation" not in held_out(folds, [2, 7, 9], parts, has_orientation=False).extra
