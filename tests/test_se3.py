"""The one home of frame maths (pipeline.core.se3), checked against pinocchio's SO(3) log and exp."""

import numpy as np
import pinocchio as pin
import pytest

from pipeline.core import se3


def _rotations(n, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    return np.stack([pin.exp3(rng.normal(size=3) * scale) for _ in range(n)])


def test_rotation_vectors_are_pinocchios_log3():
    R = _rotations(20)
    np.testing.assert_allclose(se3.rotation_vectors(R), [pin.log3(r) for r in R], atol=1e-12)
    assert se3.rotation_vectors(R.reshape(4, 5, 3, 3)).shape == (4, 5, 3)


def test_an_orientation_error_is_the_turn_from_measured_to_predicted_in_mrad():
    R_meas = _rotations(5, seed=1)
    turn = np.array([0.001, -0.002, 0.0005])                    # rad, base frame
    R_pred = np.einsum("ij,njk->nik", pin.exp3(turn), R_meas)
    e = se3.orientation_errors(R_pred, R_meas)
    np.testing.assert_allclose(e, np.tile(turn * 1000.0, (5, 1)), atol=1e-9)
    np.testing.assert_allclose(se3.angle_arcsec(e), np.linalg.norm(turn) * 1000.0 * se3.ARCSEC_PER_MRAD)


def test_rotation_angle_is_the_norm_of_the_relative_log():
    Ra, Rb = _rotations(10, seed=2), _rotations(10, seed=3)
    want = [np.linalg.norm(pin.log3(a.T @ b)) for a, b in zip(Ra, Rb)]
    np.testing.assert_allclose(se3.rotation_angle(Ra, Rb), want, atol=1e-7)
    assert se3.rotation_angle(Ra[0], Ra[0]) == pytest.approx(0.0, abs=1e-7)


def test_the_chordal_mean_of_rotations_spread_evenly_about_one_is_that_one():
    R0 = pin.exp3(np.array([0.3, -0.2, 1.1]))
    spread = [pin.exp3(s * v) for v in np.eye(3) for s in (0.05, -0.05)]
    M = se3.chordal_mean(np.stack([R0 @ D for D in spread]))
    np.testing.assert_allclose(M, R0, atol=1e-12)
    assert np.linalg.det(M) == pytest.approx(1.0)


def test_the_two_arcsec_per_mrad_constants_agree_to_their_six_digits():
    assert se3.ARCSEC_PER_MRAD_EXACT == pytest.approx(se3.ARCSEC_PER_MRAD, rel=2e-9)
    assert se3.ARCSEC_PER_RAD == pytest.approx(206264.80624709636)


def test_kabsch_finds_the_turn_between_two_point_sets_and_rigid_fit_the_shift_too():
    R0 = pin.exp3(np.array([0.4, 0.1, -0.7]))
    a = np.random.default_rng(5).normal(size=(20, 3))
    R, S = se3.kabsch_rotation((a - a.mean(0)).T @ ((a @ R0.T) - (a @ R0.T).mean(0)))
    np.testing.assert_allclose(R, R0, atol=1e-12)
    assert S[1] > 1.0
    R2, t2 = se3.rigid_fit(a, a @ R0.T + [1.0, -2.0, 3.0])
    np.testing.assert_allclose(t2, [1.0, -2.0, 3.0], atol=1e-12)
    assert se3.rotation_angle_deg(R2 @ R0.T) == pytest.approx(0.0, abs=1e-5)
    assert se3.rotation_angle_deg(pin.exp3(np.array([0.0, 0.0, np.pi / 2]))) == pytest.approx(90.0)
    with pytest.raises(ValueError, match="collinear"):
        se3.rigid_fit(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [3, 2, 1]))
