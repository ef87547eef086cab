"""Several campaigns of one robot in ``jointcal diagnose`` and ``jointcal robot diagnose-loop`` (contract
section 15, issue 52): one robot, each campaign its own tracker frame, each campaign's folds by pose and by
region, held-out and cross-validated results per campaign beside the totals. The campaigns are simulated
(synthetic): one virtual KR210 cell measured twice, the second time with joint 1 turned the other way and
from another tracker station (the fixture of tests/test_campaigns.py). The tests compare with what they
arranged themselves (which poses belong to which campaign), never with the generator's truth.
"""

from __future__ import annotations

import dataclasses
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


@pytest.mark.parametrize("command", [("diagnose", "--json"), ("robot", "diagnose-loop", "--json")])
def test_a_campaign_given_twice_is_refused(cells, command):  # noqa: F811
    """Bad input: one line naming the campaign's poses.csv, exit status 2, nothing written."""
    out = cells["root"] / f"twice_{command[-2]}.json"
    r = cells["run"](*command[:-1], "--campaign", cells["a"], "--campaign", cells["a"], "--spec", SPEC, command[-1], out)
    assert r.exit_code == 2, r.output
    assert "given twice" in r.output and "poses.csv" in r.output and "Traceback" not in r.output
    assert not out.exists()


# ---------------------------------------------------------------- full poses are never worse (issue 52)
# The control logic, with diagnosis and the fits replaced by stand-ins whose numbers the test chooses (as
# tests/test_diagnose_loop_rollback.py): on a 6-DoF campaign the orientation rows made the loop take one effect
# (a compliance) where the positions alone take another (a joint map), and the first then blocks the second.

START = '[model]\nkind = "robot"\n\n[[effect]]\nname = "geometry"\n'
COMPLIANCE = '[[effect]]\nname = "compliance"\njoints = [2]'
MAP = '[[effect]]\nname = "joint_map"\njoints = [2]'


@dataclasses.dataclass
class _Poses:
    """Stand-in poses: ``n`` of them, with or without orientations."""
    n: int = 0
    measured_R: object = None
    sigma_arcsec: object = None

    @property
    def has_orientation(self):
        return self.measured_R is not None


def _run_loop(monkeypatch, position_cv, region_cv=None):
    """The loop on a stand-in 6-DoF campaign; ``position_cv``: the refitted (position mm, orientation arcsec) by
    pose of each final spec, keyed by its extra effects' names joined by '+' (in spec order); ``region_cv``: the
    same by region (None: the stand-in has no folds by region)."""
    from pipeline.diagnosis import loop as loop_mod

    def extra(effects):
        names = [e.name for e in effects if e.name != "geometry"]
        return "+".join(names) if names else None

    def fake_diagnose(adapter, spec, data, progress=None):
        have = extra(spec.effects)
        line = COMPLIANCE if data.has_orientation else MAP
        cands = [] if have else [{"effect": "x", "target": 2, "meaningful": True, "gain": 0.3, "spec_line": line}]
        cv = (1.0, 1.0) if not have else (0.5, 0.5)
        return {"baseline": {"cv_rms": cv[0], "cv_rms_region": cv[1], "unit": "mm"}, "candidates": cands}

    class Adapter:
        def __init__(self, *args, **kwargs):
            pass

        def weight(self, data):
            return 1.0

        def refit_cv(self, effects, data):
            assert data.has_orientation        # both specs judged with the orientations, fold by fold
            return extra(effects), (None if region_cv is None else ("region", extra(effects)))

        def components(self, cv, data):
            got = region_cv[cv[1]] if isinstance(cv, tuple) else position_cv[cv]
            return {"position_rms_mm": got[0], "orientation_rms_arcsec": got[1]}

    class Model:
        converged_ = plausible_ = True

    monkeypatch.setattr(loop_mod, "diagnose", fake_diagnose)
    monkeypatch.setattr(loop_mod, "RobotAdapter", Adapter)
    monkeypatch.setattr(loop_mod, "fit_effects", lambda robot, effects, data: Model())
    monkeypatch.setattr(loop_mod, "model_cv", lambda robot, effects, data: (1.0, 1.0))
    monkeypatch.setattr(loop_mod, "try_swap", lambda *args, **kwargs: None)
    six = _Poses(n=4, measured_R=np.zeros((4, 3, 3)))
    return loop_mod.diagnosis_loop(None, START, six, _Poses())


def test_a_full_pose_loop_ends_no_worse_in_position_than_positions_alone(monkeypatch):
    """The full-pose loop ends on the compliance; the loop on the positions alone on the map, which holds out by
    pose far better in position (every fold refitted with the orientations) and no worse in orientation: the
    map's spec is the result, and the JSON says why."""
    out = _run_loop(monkeypatch, {"compliance": (0.25, 80.0), "joint_map": (0.15, 78.0),
                                  "compliance+joint_map": (0.25, 80.0)})
    check = out["positions_only"]
    assert check["used"] and check["full"]["position_rms_mm"] == 0.25 and check["positions"]["position_rms_mm"] == 0.15
    names = [e.name for e in __import__("pipeline.core.spec", fromlist=["x"]).parse_spec(out["final_spec"]).effects]
    assert names == ["geometry", "joint_map"], out["final_spec"]
    assert "positions-only" in out["done"]


@pytest.mark.parametrize("cv", [{"compliance": (0.25, 80.0), "joint_map": (0.245, 78.0)},   # within 1.05x
                                {"compliance": (0.25, 80.0), "joint_map": (0.15, 120.0)}])   # orientation worse
def test_the_full_pose_spec_stays_when_positions_alone_do_not_do_better(monkeypatch, cv):
    out = _run_loop(monkeypatch, {**cv, "compliance+joint_map": cv["compliance"]})
    assert not out["positions_only"]["used"] and out["positions_only"]["taken"] == "full"
    assert "compliance" in out["final_spec"] and "joint_map" not in out["final_spec"]


def test_both_loops_effects_together_are_the_result_where_they_hold_out_best(monkeypatch):
    """What each loop found may hold together (Series D: the full-pose loop's compliance and the positions-only
    loop's map): the union of the two specs, judged by the same rule, is the result when it does best in position
    by pose, no worse in orientation, and no worse by region than the full-pose loop's spec."""
    by_pose = {"compliance": (0.25, 80.0), "joint_map": (0.16, 78.0), "compliance+joint_map": (0.12, 62.0)}
    by_region = {"compliance": (0.39, 140.0), "joint_map": (0.55, 180.0), "compliance+joint_map": (0.32, 122.0)}
    out = _run_loop(monkeypatch, by_pose, by_region)
    check = out["positions_only"]
    assert check["used"] and check["taken"] == "union", check["why"]
    names = [e.name for e in __import__("pipeline.core.spec", fromlist=["x"]).parse_spec(out["final_spec"]).effects]
    assert names == ["geometry", "compliance", "joint_map"], out["final_spec"]
    assert check["union"]["position_rms_region_mm"] == 0.32 and "both loops' effects" in out["done"]


def test_an_alternative_worse_by_region_is_not_taken(monkeypatch):
    """The positions-only loop's spec holds out better by pose but worse by region than the full-pose loop's (the
    loop keeps a round only when both fall): the full-pose loop's spec stays (the union is no better by pose)."""
    by_pose = {"compliance": (0.25, 80.0), "joint_map": (0.16, 78.0), "compliance+joint_map": (0.25, 80.0)}
    by_region = {"compliance": (0.39, 140.0), "joint_map": (0.55, 180.0), "compliance+joint_map": (0.39, 140.0)}
    out = _run_loop(monkeypatch, by_pose, by_region)
    assert not out["positions_only"]["used"], out["positions_only"]["why"]
    assert "joint_map" not in out["final_spec"]
