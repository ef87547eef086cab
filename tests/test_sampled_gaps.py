"""A joint's sampled range can hold stretches no pose reached (a grid campaign, a range sampled in lobes):
the model extrapolates there as beyond the range's ends (issue 52: Series A never measured joint 1 between
-113 and -64 deg, and B's targets there looked 'inside A's ranges')."""

import numpy as np

from pipeline.correct.run import outside_region, outside_where
from pipeline.robot.model.predict import beyond_range, gap_message, sampled_range
from pipeline.robot.model.uncertainty import beyond_deg


def _lobes(seed=3):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-30, 30, size=(400, 3))
    # joint 1 sampled in two lobes, [-100, -60] and [0, 40]: a 60 deg stretch between them no pose reached
    q[:, 0] = np.where(rng.random(400) < 0.5, rng.uniform(-100, -60, 400), rng.uniform(0, 40, 400))
    return q


def test_a_stretch_no_pose_reached_is_recorded_and_counts_as_beyond():
    q = _lobes()
    rng = sampled_range(q)
    (a, b), = rng["gaps_deg"]["1"]
    assert -61 < a <= -60 and 0 <= b < 1
    assert "2" not in rng["gaps_deg"] and "3" not in rng["gaps_deg"]
    probe = np.array([[-30.0, 0.0, 0.0], [-59.0 + 0.5 * (a + 60), 0.0, 0.0], [20.0, 0.0, 0.0], [55.0, 0.0, 0.0]])
    d = beyond_deg(probe, rng)
    assert abs(d[0, 0] - min(-30 - a, b + 30)) < 1e-9        # the middle of the gap: ~30 deg from the poses
    assert d[2, 0] == 0.0                                     # where the poses were
    assert abs(d[3, 0] - (55 - max(q[:, 0]))) < 1e-9          # beyond the range's end, as before
    assert np.all(d[:, 1:] == 0.0)
    where = beyond_range(probe, rng)
    assert where[0]["gap_deg"] == [a, b] and where[2] is None and "gap_deg" not in where[3]
    assert "joint 1: 1 in [" in gap_message([{"extrapolates": where[0]}])


def test_a_small_stretch_is_inside_and_old_models_are_unchanged():
    q = _lobes()
    q[:, 0] = np.linspace(-100, 40, 400)                      # no stretch wider than the map's bridge
    rng = sampled_range(q)
    assert "gaps_deg" not in rng
    old = {"lower_deg": [-100, -30, -30], "upper_deg": [40, 30, 30]}   # a fit JSON written before gaps
    assert np.all(beyond_deg(np.array([[-30.0, 0, 0]]), old) == 0.0)


def test_correct_names_a_target_in_a_gap_in_words():
    rng = sampled_range(_lobes())
    where = outside_region(np.array([[-30.0, 0.0, 0.0], [20.0, 0.0, 0.0]]), rng, np.array([0.5, 0.1]))
    assert where[1] is None and where[0]["gap_deg"] == rng["gaps_deg"]["1"][0]
    text = outside_where(where[0])
    assert "no sample pose reached" in text and "u95_mm 0.500" in text
