"""Identifiability (pipeline.robot.model.identify): which parameters a fit keeps, what it cannot see and how
that is held nearest the nominal robot. Synthetic Jacobians."""

import numpy as np
import pytest

from pipeline.robot.model import identify

MM, ARCSEC = ("mm", 1.0), ("arcsec", 206.264806)


def _J(seed=0, m=60, k=5):
    return np.random.default_rng(seed).normal(size=(m, k))


def test_a_column_that_is_a_combination_of_others_is_redundant_and_a_zero_one_does_not_move():
    J = _J()
    J[:, 3] = J[:, 0] - 2.0 * J[:, 1]
    J[:, 4] = 0.0
    names = ["a", "b", "c", "d", "e"]
    v = identify.identifiability(J, names, priority=[0, 1, 2, 3, 4])
    assert v["rank"] == 3 and v["not_identifiable"] == ["d", "e"]
    assert v["fixed_reasons"]["d"]["reason"].startswith("redundant")
    assert "does not move" in v["fixed_reasons"]["e"]["reason"]
    assert v["condition_number_all"] == float("inf")


def test_a_weakly_determined_parameter_is_left_at_nominal_below_weak_tol_only():
    J = _J(1)
    J[:, 4] = J[:, 2] + 1e-4 * _J(2)[:, 0]        # nearly the same as c: determined at ~1e-4
    names = ["a", "b", "c", "d", "e"]
    assert identify.identifiability(J, names, priority=list(range(5)))["not_identifiable"] == []
    v = identify.identifiability(J, names, priority=list(range(5)), weak_tol=identify.WEAK_TOL)
    assert v["not_identifiable"] == ["e"]                  # the lower priority of the two
    assert v["fixed_reasons"]["e"]["relative_determination"] < identify.WEAK_TOL


def test_a_rotation_with_a_short_lever_is_not_identified():
    J = _J(3, k=4)
    J[:, 3] *= 0.5 * identify.SHORT_LEVER * np.median(np.linalg.norm(J[:, :3], axis=0)) / np.linalg.norm(J[:, 3])
    v = identify.identifiability(J, ["r1", "r2", "r3", "r4"], units=[ARCSEC] * 4)
    assert v["not_identifiable"] == ["r4"] and "1/100" in v["fixed_reasons"]["r4"]["reason"]


def test_what_no_measurement_sees_is_held_nearest_nominal_in_units_of_typical_size():
    """Two parameters that move the point alike (a tool length and a last-link length): the fit direction
    keeps no part along the unseen combination, counted in typical sizes (1 mm and 2 mm)."""
    J = _J(4, k=3)
    J[:, 2] = J[:, 1]
    sizes = np.array([1.0, 1.0, 2.0])
    B, U = identify.physical_subspace(J, np.eye(3), np.ones(3, bool), sizes)
    u = np.array([0.0, 2.0, -1.0]) / np.sqrt(5.0)             # x = (0, 1, -1) mm: u = x / sizes = (0, 1, -0.5)
    np.testing.assert_allclose(np.abs(U[:, 0]), np.abs(u), atol=1e-12)
    np.testing.assert_allclose(U.T @ (B / sizes[:, None]), 0.0, atol=1e-12)
    np.testing.assert_allclose(J @ B, J, atol=1e-12)           # the same predictions
    # the same from the normal equations (a large fit's path)
    Bg, Ug = identify.physical_subspace(None, np.eye(3), np.ones(3, bool), sizes, gram=J.T @ J)
    np.testing.assert_allclose(Bg, B, atol=1e-9)
    groups = identify.unseen_groups(U, ["x", "tool", "link"], [MM] * 3, sizes)
    assert len(groups) == 1 and groups[0]["parameters"] == ["tool", "link"]
    assert groups[0]["seen"] == 1 and groups[0]["unseen"] == 1
    assert groups[0]["unseen_directions"] == [{"tool": 1.0, "link": -1.0}]


def test_mdh_parameters_come_first_in_priority_offsets_before_lengths():
    names = ["tool_x", "dd2", "dtheta3", "da1", "dtheta1"]
    assert [names[k] for k in identify.priority(names)] == ["dtheta1", "dtheta3", "da1", "dd2", "tool_x"]


def test_fit_directions_in_the_leading_singular_directions_leave_the_redundant_one_out():
    J = _J(5, k=4)
    J[:, 3] = J[:, 0] + J[:, 1]

    class D:
        names, units, sizes, p = ["a", "b", "c", "d"], [MM] * 4, np.ones(4), 4
    v = identify.identifiability(J, D.names)
    B, U = identify.fit_directions(J, np.zeros((0, 4)), v, D(), "svd", True, identify.RANK_TOL)
    assert B.shape == (4, 3) and U.shape[1] == 1 and v["directions_left_out"] == 1
    np.testing.assert_allclose(J @ U[:, 0], 0.0, atol=1e-10)
    B, U = identify.fit_directions(J, np.zeros((0, 4)), identify.identifiability(J, D.names), D(), "fix", True,
                                   identify.RANK_TOL)
    assert B.shape == (4, 3) and U.shape[1] == 1
    assert np.linalg.matrix_rank(J @ B) == 3


def test_a_table_value_no_pose_reaches_says_so():
    """A joint map's knot that the sample poses barely reach was said to sit on 'an axis the SMR sits on'
    (Series A: knots of joint 1 across a stretch no pose sampled): its reason names the poses."""
    rng = np.random.default_rng(1)
    J = rng.normal(size=(60, 4))
    J[:, 3] *= 1e-4                      # the table value the poses barely reach
    units = [("arcsec", 1.0)] * 4
    v = identify.identifiability(J, ["r1", "r2", "m1", "m2"], units=units, penalised=np.array([False, False, True, True]))
    assert v["not_identifiable"] == ["m2"]
    assert "few or no sample poses lie near this angle" in v["fixed_reasons"]["m2"]["reason"]
