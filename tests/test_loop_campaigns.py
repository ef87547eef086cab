"""Several campaigns of one robot in ``jointcal diagnose`` and ``jointcal robot diagnose-loop`` (contract
section 15, issue 52): one robot, each campaign its own tracker frame, each campaign's folds by pose and by
region, held-out and cross-validated results per campaign beside the totals. The campaigns are simulated
(synthetic): one virtual KR210 cell measured twice, the second time with joint 1 turned the other way and
from another tracker station (the fixture of tests/test_campaigns.py). The tests compare with what they
arranged themselves (which poses belong to which campaign), never with the generator's truth.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import ROOT
from test_campaigns import cells  # noqa: F401 (the fixture: campaigns a and b of one simulated cell)

SPEC = ROOT / "specs" / "robot_kinematic.toml"


def _stacked(cells):
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.campaigns import stacked

    parts = [robot_data_sets(cells[k], ("sample",))[1][0] for k in ("a", "b")]
    return stacked(parts)


def test_each_fold_holds_out_some_of_every_campaign(cells):  # noqa: F811
    """The folds by region are each campaign's own regions of joint space: every region fold holds out poses of
    both campaigns and leaves most of both to fit on (so each campaign's own frame is fitted in every fold, even
    where the campaigns lie in disjoint joint ranges and regions of the stacked poses would hold out a whole
    campaign, its frame then undetermined). The folds by pose likewise hold out a share of each campaign."""
    from pipeline.diagnosis.robot import campaign_region_folds, pose_folds

    data = _stacked(cells)
    for folds in (campaign_region_folds(data), pose_folds(data)):
        for f in np.unique(folds):
            for k in (1, 2):
                mine = data.campaign == k
                assert np.any(mine & (folds == f)), (f, k)      # held out
                assert np.sum(mine & (folds != f)) > 0.5 * mine.sum(), (f, k)   # most of it left to fit on


def test_one_campaign_keeps_its_folds(cells):  # noqa: F811
    """One campaign: the folds are those of before (same bytes out)."""
    from pipeline.diagnosis.linear import region_folds
    from pipeline.diagnosis.robot import campaign_region_folds, pose_folds
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimate import fold_ids

    _, (data,) = robot_data_sets(cells["a"], ("sample",))
    assert np.array_equal(campaign_region_folds(data), region_folds(data.q_deg))
    assert np.array_equal(pose_folds(data), fold_ids(data.n))


def test_diagnose_two_campaigns_each_its_own_frame(cells):  # noqa: F811
    """``jointcal diagnose --campaign a --campaign b``: the second campaign's tracker frame is an effect of the
    baseline, and the baseline's cross-validated RMS is given per campaign (JSON and console) beside the totals,
    the totals being the campaigns' pooled."""
    out = cells["root"] / "diag_ab.json"
    r = cells["run"]("diagnose", "--campaign", cells["a"], "--campaign", cells["b"], "--spec", SPEC, "--json", out)
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert "campaign_frame" in doc["baseline"]["effects"]
    per = doc["campaigns"]
    assert [c["campaign"] for c in per] == [str(cells["a"]), str(cells["b"])]
    for key, total in (("cv_rms", doc["baseline"]["cv_rms"]), ("cv_rms_region", doc["baseline"]["cv_rms_region"])):
        n = sum(c["n_sample"] for c in per)
        assert total == pytest.approx(np.sqrt(sum(c["n_sample"] * c[key] ** 2 for c in per) / n), rel=1e-5)
    # the kinematic spec leaves the cell's compliance and transmission errors: well above the tracker's noise,
    # but each campaign is fitted in its own frame (a second station not taken up would leave metres)
    assert all(0.01 < c["cv_rms"] < 1.0 for c in per), per
    assert "per campaign" in r.output and str(cells["b"]) in r.output


def test_the_loop_on_two_campaigns_reports_each(cells):  # noqa: F811
    """``jointcal robot diagnose-loop --campaign a --campaign b``: every round's model has b's own frame, every
    round reports each campaign's held-out targets and cross-validated RMS; the spec it ends with is the robot's
    (without the campaigns' frames, which ``jointcal fit`` adds), and fits both campaigns together."""
    out, spec_out = cells["root"] / "loop_ab.json", cells["root"] / "loop_ab.toml"
    r = cells["run"]("robot", "diagnose-loop", "--campaign", cells["a"], "--campaign", cells["b"], "--spec", SPEC,
                     "--json", out, "--spec-out", spec_out, "--rounds", "2")
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert doc["campaigns"] == [str(cells["a"]), str(cells["b"])]
    for row in doc["rounds"]:
        assert any("campaign_frame" in e for e in row["effects"])
        per = row["campaigns"]
        assert [c["campaign"] for c in per] == [str(cells["a"]), str(cells["b"])]
        own = [c["own"] for c in per]
        n = sum(o["n"] for o in own)
        assert n == row["own"]["n"]
        assert row["own"]["rms_mm"] == pytest.approx(np.sqrt(sum(o["n"] * o["rms_mm"] ** 2 for o in own) / n), rel=1e-5)
    assert "campaign_frame" not in spec_out.read_text()
    # the console shows each campaign's errors under each round
    assert r.output.count(f"{cells['b']}: held-out RMS") == len(doc["rounds"])
    fit = cells["root"] / "loop_ab_fit.json"
    r = cells["run"]("fit", "--campaign", cells["a"], "--campaign", cells["b"], "--spec", spec_out, "--out", fit)
    assert r.exit_code == 0, r.output
