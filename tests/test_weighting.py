"""Variance components (pipeline.robot.model.weighting): where the weight starts, how it steps, when a
stepped fit's weight still holds. Synthetic numbers."""

import numpy as np
import pytest

from pipeline.robot.model import weighting


class _Data:
    def __init__(self, sigma_mm=None, sigma_arcsec=None):
        self.sigma_mm, self.sigma_arcsec = sigma_mm, sigma_arcsec


def test_the_start_is_the_ratio_of_the_stated_uncertainties_else_one_mm_per_mrad():
    w, why = weighting.start_weight(_Data(np.array([0.02, 0.02, np.nan]), np.array([2.0, 2.0, 4.0])))
    assert w == pytest.approx(0.02 / (2.0 / 206.264806)) and "stated" in why
    assert weighting.start_weight(_Data())[0] == weighting.START_WEIGHT_MM_PER_MRAD
    assert weighting.start_weight(_Data(np.array([0.0]), np.array([1.0])))[0] == weighting.START_WEIGHT_MM_PER_MRAD


def test_the_first_step_is_the_plain_one_and_a_good_secant_is_taken():
    assert weighting.vce_next(0.0, 0.5, None) == pytest.approx(np.exp(0.5))
    # h falls linearly with log w (root at log w = 1): the secant through two points lands on it
    h = lambda lw: 0.8 * (1.0 - lw)
    lw0, lw1 = 0.0, 0.8
    assert np.log(weighting.vce_next(lw1, h(lw1), (lw0, h(lw0)))) == pytest.approx(1.0)
    # a secant that points back (the wrong side of the plain step) is not taken
    assert weighting.vce_next(0.0, 0.1, (1.0, 0.05)) == pytest.approx(np.exp(0.1))


def test_a_stepped_fit_keeps_its_weight_only_where_the_poses_left_give_the_same_one():
    class M:
        weight_ = 2.0
        weighting_ = {"method": "variance components", "orientation_weight_mm_per_mrad": 2.0}
    rng = np.random.default_rng(0)
    meas = rng.normal(size=(50, 3))
    P = meas + 0.02 * rng.choice([-1.0, 1.0], size=(50, 3))            # 0.02 mm per axis exactly
    ori = 0.01 * rng.choice([-1.0, 1.0], size=(50, 3))                 # 0.01 mrad per axis exactly
    held = weighting.holds_on(M(), P, ori, meas)
    assert held["position_sigma_mm"] == pytest.approx(0.02) and held["method"] == "variance components"
    assert held["orientation_sigma_arcsec"] == pytest.approx(0.01 * 206.264806)
    assert weighting.holds_on(M(), P, 1.5 * ori, meas) is None         # 2 -> 1.33 mm per mrad: not the fit's
