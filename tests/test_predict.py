"""`jointcal predict` (contract section 7): a fitted robot model applied to other measurements."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import ROOT, cli_invoker

KR210 = ROOT / "raw" / "robot" / "kr210"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("predict")
    fit = tmp / "fit.json"
    r = cli_invoker()("fit", "--campaign", KR210, "--spec", ROOT / "specs" / "robot_kinematic.toml", "--out", fit)
    assert r.exit_code == 0, r.output
    return fit, json.loads(fit.read_text())


def _moved_copy(dst, angle_deg=25.0, shift=(1500.0, -800.0, 300.0)):
    """The fixture with its tracker points moved by a rigid transform and marked as tracker frame."""
    shutil.copytree(KR210, dst)
    t = pd.read_csv(dst / "tracker.csv", dtype={"point_id": str})
    a = np.radians(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    xyz = t[["x_mm", "y_mm", "z_mm"]].to_numpy(float) @ R.T + np.array(shift)
    t["x_mm"], t["y_mm"], t["z_mm"] = xyz.T
    t.to_csv(dst / "tracker.csv", index=False, float_format="%.6f")
    (dst / "campaign.toml").write_text('frame = "tracker"\n')
    return dst


def test_predict_on_the_fit_campaign_reproduces_the_heldout_error(fitted, tmp_path):
    fit, doc = fitted
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", KR210, "--model", fit, "--json", out)
    assert r.exit_code == 0, r.output
    p = json.loads(out.read_text())
    h = doc["heldout"]
    assert p["n"] == h["n_target"] and p["evaluated_on"] == "target"
    assert p["rms_mm"] == pytest.approx(h["rms_after_mm"], rel=1e-9)
    assert p["max_mm"] == pytest.approx(h["after"]["max_mm"], rel=1e-9)
    assert len(p["points"]) == p["n"] and {"point_id", "error_mm"} <= set(p["points"][0])
    # the fit's own numbers are those of a model that beat the nominal one
    assert p["rms_mm"] < 0.5 * h["rms_before_mm"]


def test_register_recovers_a_moved_tracker(fitted, tmp_path):
    fit, _ = fitted
    run = cli_invoker()
    moved = _moved_copy(tmp_path / "moved")
    ref, got, raw = tmp_path / "ref.json", tmp_path / "got.json", tmp_path / "raw.json"
    assert run("predict", "--campaign", KR210, "--model", fit, "--json", ref, "--register").exit_code == 0
    r = run("predict", "--campaign", moved, "--model", fit, "--json", got, "--register")
    assert r.exit_code == 0, r.output
    a, b = json.loads(ref.read_text()), json.loads(got.read_text())
    assert b["rms_mm"] == pytest.approx(a["rms_mm"], abs=1e-4)
    ea = {p["point_id"]: p["error_mm"] for p in a["points"]}
    assert max(abs(ea[p["point_id"]] - p["error_mm"]) for p in b["points"]) < 1e-3
    # without --register the fit campaign's own tracker transform is used: wrong for a moved tracker
    assert run("predict", "--campaign", moved, "--model", fit, "--json", raw).exit_code == 0
    assert json.loads(raw.read_text())["rms_mm"] > 10 * a["rms_mm"]


def test_outside_sampled_range_counts_poses_beyond_the_fitted_joint_ranges(fitted, tmp_path):
    fit, doc = fitted
    out = tmp_path / "p.json"
    assert cli_invoker()("predict", "--campaign", KR210, "--model", fit, "--json", out).exit_code == 0
    p = json.loads(out.read_text())
    rng = doc["sampled_range"]
    poses = pd.read_csv(KR210 / "poses.csv", dtype={"point_id": str}).set_index("point_id")
    q = poses.loc[[x["point_id"] for x in p["points"]], [f"q{j}" for j in range(1, 7)]].to_numpy(float)
    lo, hi = np.array(rng["lower_deg"]), np.array(rng["upper_deg"])
    expected = int(np.any((q < lo) | (q > hi), axis=1).sum())
    assert expected > 0  # the fixture's targets reach a little beyond its samples
    assert p["outside_sampled_range"] == expected


def _one_line_error(r, name):
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.exit_code == 2, r.output
    assert len(lines) == 1 and lines[0].startswith("jointcal: error: ") and name in lines[0], lines
    assert "Traceback" not in r.output


def test_a_campaign_of_another_robot_is_refused(fitted, tmp_path):
    fit, _ = fitted
    other = tmp_path / "other"
    shutil.copytree(KR210, other)
    text = (other / "robot.toml").read_text().replace("a_mm = 350.0", "a_mm = 360.0", 1)
    assert text != (other / "robot.toml").read_text()
    (other / "robot.toml").write_text(text)
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", other, "--model", fit, "--json", out)
    _one_line_error(r, "robot.toml")
    assert not out.exists()


def test_a_json_that_is_not_a_model_is_refused(tmp_path):
    bad = tmp_path / "fit.json"
    bad.write_text(json.dumps({"kind": "encoder", "orders": [1]}))
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", KR210, "--model", bad, "--json", out)
    _one_line_error(r, "fit.json")
    assert not out.exists()


def test_a_fit_of_a_campaign_without_sample_poses_points_to_predict(tmp_path):
    camp = tmp_path / "all_targets"
    shutil.copytree(KR210, camp)
    p = pd.read_csv(camp / "poses.csv", dtype=str, keep_default_na=False)
    p["set"] = "target"
    p.to_csv(camp / "poses.csv", index=False)
    r = cli_invoker()("fit", "--campaign", camp, "--spec", ROOT / "specs" / "robot_kinematic.toml",
                      "--out", tmp_path / "f.json")
    _one_line_error(r, "poses.csv")
    assert "predict" in r.stderr


GARBAGE = ["", "nan", "abc", "1e999", "-999", "T001"]


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file=st.sampled_from(["poses.csv", "tracker.csv"]), row=st.integers(0, 400),
       col=st.sampled_from(["point_id", "set", "q2", "q6", "x_mm", "z_mm"]), value=st.sampled_from(GARBAGE))
def test_predict_on_mutated_campaigns_fails_cleanly(fitted, tmp_path_factory, file, row, col, value):
    fit, _ = fitted
    folder = tmp_path_factory.mktemp("mut") / "kr210"
    shutil.copytree(KR210, folder)
    frame = pd.read_csv(folder / file, dtype=str, keep_default_na=False)
    if col in frame:
        frame.loc[frame.index[row % len(frame)], col] = value
    frame.to_csv(folder / file, index=False)
    out = folder.parent / "p.json"
    r = cli_invoker()("predict", "--campaign", folder, "--model", fit, "--json", out)
    assert r.exit_code in (0, 2) and "Traceback" not in r.output
    if r.exit_code == 2:
        _one_line_error(r, str(folder))
        assert not out.exists()
    else:
        assert out.exists()


def test_a_hair_beyond_the_sampled_range_is_not_printed_as_zero():
    """Series D of the IPA UR10: one target 0.004 deg past the sample poses' range of joint 6 was warned as
    "up to 0.00 deg beyond"; the warning gives the size it has."""
    from pipeline.robot.model.predict import outside_calibrated_range, outside_message

    sample = np.array([[0.0, -90.0], [10.0, 0.0]])
    target = np.array([[10.0041, -45.0], [5.0, 2.5]])
    text = outside_message(outside_calibrated_range(sample, target, ["T1", "T2"]), worst=True)
    assert "joint 1: 1 target(s), up to 0.0041 deg beyond" in text and "0.00 deg" not in text
    assert "joint 2: 1 target(s), up to 2.5 deg beyond" in text
