"""MDH calibration, improved L-M against scipy, the closed loop under the paper's gains."""

import numpy as np

from pipeline.robot.model.design import Design
from pipeline.robot.model.estimator import RobotErrorModel, calibrate_mdh
from pipeline.robot.model.chebyshev import identify
from pipeline.robot.paper.closedloop import KD, KP, JointPlant, pd_poles, run_loop
from pipeline.robot.arm.effects import Base, Chebyshev, Geometry, RobotData
from pipeline.robot.arm.kinematics import build_model, gravity_torques, load_robot, positions
from pipeline.robot.model.lm import improved_lm, limit_blas_threads, scipy_least_squares
from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses

limit_blas_threads(1)
ROBOT = load_robot("raw/robot/kr210/robot.toml")


def _data(robot, Q, measured=None):
    n = len(Q)
    return RobotData(Q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), gravity_torques(robot, Q),
                     robot.lower_deg, robot.upper_deg, measured)


def _poses(n, seed):
    return draw_poses(ROBOT, n, np.random.default_rng(seed), ROBOT_FIXTURE["box_mm"], 10.0)


def test_mdh_calibration_recovers_known_errors_on_noiseless_data():
    Q = _poses(100, 3)
    effects = [Geometry(), Base()]
    probe = RobotErrorModel(ROBOT, effects).fit(_data(ROBOT, Q, positions(build_model(ROBOT), np.deg2rad(Q))))
    keep = ~np.isin(probe.names_, probe.fixed_)
    assert keep.sum() >= 20                        # most parameters are determined on their own, and
    assert probe.unseen_.shape[1] > 0              # some combinations of them cannot be seen at all
    rng = np.random.default_rng(11)
    truth = np.zeros(len(keep))
    truth[keep] = rng.normal(0, 0.3, keep.sum())   # mm and mrad (internal units)
    d = Design(ROBOT, effects, _data(ROBOT, Q))
    meas = d.predict(truth)                        # noiseless "tracker"
    model, report = calibrate_mdh(ROBOT, _data(ROBOT, Q, meas), effects)
    assert report["not_identifiable"] == probe.fixed_
    # the truth's representative nearest the nominal robot (typical sizes): the truth without its part
    # along the combinations no measurement sees (contract section 8)
    U = model.unseen_ / d.sizes[:, None]
    nearest = truth - d.sizes * (U @ np.linalg.lstsq(U, truth / d.sizes, rcond=None)[0])
    # (to first order: the unseen directions are those of the Jacobian at nominal; the truth's 0.3 mrad
    # leave second-order differences of 1e-3 of it)
    assert np.abs(model.coef_ - nearest).max() < 3e-3
    assert report["rms_after_mm"] < 1e-6 < report["rms_before_mm"]


def test_mdh_calibration_of_a_perturbed_mdh_robot_fits_to_second_order():
    Q = _poses(80, 4)
    true = ROBOT
    rng = np.random.default_rng(5)
    for i, j in enumerate(ROBOT.joints):
        true = true.replace_joint(i, a_mm=j.a_mm + rng.normal(0, 0.3), d_mm=j.d_mm + rng.normal(0, 0.3),
                                  alpha_deg=j.alpha_deg + rng.normal(0, 0.01), theta_offset_deg=j.theta_offset_deg + rng.normal(0, 0.02))
    meas = positions(build_model(true), np.deg2rad(Q))
    _, report = calibrate_mdh(ROBOT, _data(ROBOT, Q, meas))
    assert report["rms_before_mm"] > 0.3
    assert report["rms_after_mm"] < 2e-3


def test_improved_lm_and_scipy_agree_on_cost():
    Q = _poses(100, 6)
    rng = np.random.default_rng(8)
    meas = positions(build_model(ROBOT), np.deg2rad(Q)) + rng.normal(0, 0.05, (100, 3))
    d = Design(ROBOT, [Geometry()], _data(ROBOT, Q))
    meas = meas + d.predict(rng.normal(0, 0.3, d.p)) - d.predict(np.zeros(d.p))
    result = identify(ROBOT, _data(ROBOT, Q, meas), [Chebyshev(order=3)])
    assert result["lm"]["converged"]
    assert result["lm"]["iterations"] <= 100
    assert abs(result["lm"]["cost_mm2"] - result["scipy"]["cost_mm2"]) <= 1e-3 * result["scipy"]["cost_mm2"]
    assert result["rank"] < result["n_params"]


def test_improved_lm_solves_rosenbrock_like_problem():
    fun = lambda x: np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])  # noqa: E731
    jac = lambda x: np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])  # noqa: E731
    r = improved_lm(fun, jac, np.array([-1.2, 1.0]), phi=1e-14)
    s = scipy_least_squares(fun, jac, np.array([-1.2, 1.0]))
    assert np.allclose(r.x, [1, 1], atol=1e-5) and np.allclose(s.x, [1, 1], atol=1e-6)


def test_closed_loop_converges_under_the_papers_gains():
    poles = pd_poles(KP, KD)
    assert np.all(np.abs(poles) < 1)
    assert np.max(poles.real) > 0.9                  # slow, non-oscillating dominant pole
    rng = np.random.default_rng(0)
    k = 50
    start = rng.uniform(-0.02, 0.02, k)
    play = rng.uniform(0.002, 0.02, k)
    plant = JointPlant(np.zeros(k), play, -play / 2 * np.sign(rng.normal(size=k)), start, 1e-5)
    target = rng.uniform(-0.03, 0.03, k)
    res = run_loop(plant, target, max_cycles=20000)
    assert np.all(res["cycles"] < 20000)
    assert np.abs(target - plant.output_deg).max() < 3e-5
    # an unstable gain pair is detected by the poles
    assert np.any(np.abs(pd_poles(1.5, 0.9)) > 1)
