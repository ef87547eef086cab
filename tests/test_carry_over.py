"""Issue 52, honest away from the data: which of a model's effects carry over beyond the joint ranges its poses
sampled and which are local (the effect registry says it, predict and fit print it), every target outside the
calibrated region named with its u95 (``correct --targets``, ``correct --program``), and a model that never saw
the probe's orientation not judged on it. The campaigns are synthetic: the shipped KR210 fixture
(raw/robot/kr210) and a simulated 6-DoF cell."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker, six_dof_cell

KINEMATIC = ROOT / "specs" / "robot_kinematic.toml"
FIXTURE = ROOT / "raw" / "robot" / "kr210"
PROGRAMS = ROOT / "tests" / "data" / "programs"
MAPPED = KINEMATIC.read_text() + """
[[effect]]
name = "joint_map"
joints = [2]
step_deg = 10.0
"""
CARRY_LINE = "beyond the joint ranges the fit's poses sampled"


@pytest.fixture(scope="module")
def fixture_fit(tmp_path_factory):
    """The KR210 fixture campaign fitted with the kinematic spec plus a joint map on joint 2 (CLI; joints 1-3 on
    their gratings' angles, as the fixture reads them)."""
    tmp = tmp_path_factory.mktemp("carry")
    shutil.copytree(FIXTURE, tmp / "kr210")
    (tmp / "spec.toml").write_text(MAPPED)
    run = cli_invoker()
    r = run("fit", "--campaign", tmp / "kr210", "--spec", tmp / "spec.toml", "--out", tmp / "fit.json")
    assert r.exit_code == 0, r.output
    return {"tmp": tmp, "run": run, "fit": json.loads((tmp / "fit.json").read_text()), "fit_stderr": r.stderr}


def _narrowed(doc: dict, joint: int, upper_deg: float) -> dict:
    """The fit document with joint ``joint``'s sampled range ending at ``upper_deg`` (as if the poses had stopped
    there): the targets beyond it are outside the calibrated region."""
    out = json.loads(json.dumps(doc))
    out["sampled_range"]["upper_deg"][joint - 1] = float(upper_deg)
    return out


# ---------------------------------------------------------------------------------------------- the registry
def test_every_robot_effect_says_whether_it_carries_over_and_why():
    import pipeline.robot  # noqa: F401  (registers the robot effects)
    from pipeline.core.effect import CARRIES, LOCAL
    from pipeline.robot.arm.effects import effect_classes

    classes = {cls.name: cls for cls in effect_classes()}
    for cls in classes.values():
        assert cls.extrapolates in (CARRIES, LOCAL), cls.name
        assert len(cls.extrapolation.split()) >= 6, cls.name      # a sentence, not a word
    # physics that holds at every angle: the arm's constants, its frames, gravity through the masses, a
    # periodicity over the joint's whole turn; learned curves over the sampled range only: maps, polynomials
    for name in ("geometry", "base", "tool", "compliance", "joint_harmonic", "campaign_frame"):
        assert classes[name].extrapolates == CARRIES, name
    for name in ("joint_map", "chebyshev"):
        assert classes[name].extrapolates == LOCAL, name


def test_the_carry_over_line_groups_a_models_effects_with_their_joints():
    import pipeline.robot  # noqa: F401
    from pipeline.core.effect import REGISTRY, carry_over_line

    effects = [REGISTRY.make("robot", "geometry"), REGISTRY.make("robot", "joint_map", joints=[3]),
               REGISTRY.make("robot", "compliance", joints=[2, 3]), REGISTRY.make("robot", "joint_map", joints=[1])]
    line = carry_over_line(effects)
    carries, local = line.split("these are local:")
    assert "geometry" in carries and "compliance (joints 2 3)" in carries and "joint_map" not in carries
    assert local.strip().startswith("joint_map (joints 1 3) (")
    assert REGISTRY.make("robot", "joint_map").extrapolation in local
    assert carry_over_line([]) == ""


def test_fit_says_once_what_carries_over(fixture_fit):
    lines = [ln for ln in fixture_fit["fit_stderr"].splitlines() if CARRY_LINE in ln]
    assert len(lines) == 1, fixture_fit["fit_stderr"]
    carries, local = lines[0].split("these are local:")
    assert "geometry" in carries and "base" in carries and "tool" in carries
    assert "joint_map (joint 2)" in local and "joint_map" not in carries


def test_predict_says_what_carries_over_where_points_lie_beyond(fixture_fit, tmp_path):
    tmp, run, fit = fixture_fit["tmp"], fixture_fit["run"], fixture_fit["fit"]
    r = run("predict", "--campaign", tmp / "kr210", "--model", tmp / "fit.json", "--json", tmp_path / "own.json")
    assert r.exit_code == 0, r.output
    inside = json.loads((tmp_path / "own.json").read_text())
    if inside["outside_sampled_range"] == 0:
        assert CARRY_LINE not in r.stderr           # nothing extrapolates: nothing to say
    lo, hi = fit["sampled_range"]["lower_deg"][0], fit["sampled_range"]["upper_deg"][0]
    (tmp_path / "narrow.json").write_text(json.dumps(_narrowed(fit, 1, (lo + hi) / 2)))
    r = run("predict", "--campaign", tmp / "kr210", "--model", tmp_path / "narrow.json", "--json", tmp_path / "n.json")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "n.json").read_text())["outside_sampled_range"] > 0
    lines = [ln for ln in r.stderr.splitlines() if CARRY_LINE in ln]
    assert len(lines) == 1 and "joint_map (joint 2)" in lines[0].split("these are local:")[1], r.stderr


# ------------------------------------------------------------------------------------------ correct --targets
def test_correct_targets_names_every_row_outside_with_its_u95(fixture_fit, tmp_path):
    from pipeline.correct.run import OUTSIDE_NAMED, correct_targets
    from pipeline.robot.model.predict import load_model_document

    fit = fixture_fit["fit"]
    poses = pd.read_csv(FIXTURE / "poses.csv")
    rows = poses[poses["set"] == "target"].head(40).reset_index(drop=True)
    targets = rows[["point_id"] + [f"q{j}" for j in range(1, 7)]].copy()
    hi3 = fit["sampled_range"]["upper_deg"][2]
    far = list(range(5, 5 + OUTSIDE_NAMED + 4))                 # more than the console names one by one
    beyond = {k: 0.5 + 0.25 * i for i, k in enumerate(far)}
    for k, d in beyond.items():
        targets.loc[k, "q3"] = hi3 + d
    targets.to_csv(tmp_path / "t.csv", index=False)
    run = correct_targets(tmp_path / "t.csv", fit, load_model_document(fit, "fit.json"), 0.5)
    res = run.result
    assert set(np.flatnonzero(res.status == "outside_sampled_range")) == set(far)
    lines = run.report("out.csv", 1.0, 0.5)
    summary = [ln for ln in lines if "outside the calibrated region" in ln]
    assert len(summary) == 1 and f"{len(far)} of {len(targets)} targets" in summary[0]
    assert f"joint 3: {len(far)}, up to {max(beyond.values()):.3g} deg beyond" in summary[0]
    u = res.u95_mm[far]
    assert f"their u95_mm {u.min():.3f} to {u.max():.3f} mm" in summary[0]
    named = [ln for ln in lines if re.match(r"^    line \d+: ", ln)]
    assert len(named) == OUTSIDE_NAMED
    for ln, k in zip(named, far):
        # the row's line in the targets file (header on line 1), its id, the joint, how far, its u95
        assert ln.startswith(f"    line {k + 2}: {targets.loc[k, 'point_id']}: joint 3 at "), ln
        assert f"{beyond[k]:.3g} deg beyond [" in ln and ln.endswith(f"; u95_mm {res.u95_mm[k]:.3f}"), ln
    assert any(ln.strip() == f"... and {len(far) - OUTSIDE_NAMED} more (status outside_sampled_range in out.csv)"
               for ln in lines)
    inside = set(targets["point_id"]) - {targets.loc[k, "point_id"] for k in far}
    assert not any(f": {p}: joint" in ln for ln in named for p in inside)


# ------------------------------------------------------------------------------------------ correct --program
def test_correct_program_names_every_target_outside_with_its_u95(fixture_fit, tmp_path):
    from pipeline.programs.io import read_program
    from pipeline.programs.run import played_poses
    from pipeline.robot.arm.kinematics import load_robot

    run, fit = fixture_fit["run"], fixture_fit["fit"]
    shutil.copytree(PROGRAMS, tmp_path / "in")
    played = played_poses(read_program(tmp_path / "in" / "sample.src"), load_robot(FIXTURE / "robot.toml"))
    cut = float(np.median(played.q_deg[:, 0]))
    (tmp_path / "narrow.json").write_text(json.dumps(_narrowed(fit, 1, cut)))
    r = run("correct", "--model", tmp_path / "narrow.json", "--program", tmp_path / "in" / "sample.src",
            "--out", tmp_path / "out", "--json", tmp_path / "report.json", "--closed-loop-joints", "1 2 3")
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "report.json").read_text())["targets"]
    out = [row for row in rows if row["status"] == "outside_sampled_range"]
    expected = {pid: q1 - cut for pid, q1 in zip(played.point_id, played.q_deg[:, 0]) if q1 > cut + 1e-9}
    assert out and len(out) <= len(expected)
    summary = [ln for ln in r.stderr.splitlines() if "outside the calibrated region" in ln]
    assert len(summary) == 1 and f"{len(out)} of {len(rows)} targets" in summary[0], r.stderr
    for row in out:
        lines = [ln for ln in r.stderr.splitlines() if ln.startswith(f"  {row['file']}:{row['line']}: {row['name']} ")]
        assert len(lines) == 1, (row, r.stderr)
        m = re.search(r": joint 1 at (-?[\d.]+) deg is outside .*; ([\d.e+-]+) deg beyond; u95_mm ([\d.]+)$", lines[0])
        assert m, lines[0]
        # how far beyond: the joint's angle less the range's end, to the 3 digits printed
        assert abs(float(m[2]) - (float(m[1]) - cut)) <= 6e-3 * float(m[2]) + 1e-3, lines[0]
        assert float(m[3]) > 0.0
    # the motions inside the region say nothing of it
    ok = [row for row in rows if row["status"] == "ok"]
    for row in ok:
        assert not any(ln.startswith(f"  {row['file']}:{row['line']}: ") and "u95_mm" in ln
                       for ln in r.stderr.splitlines())


# ------------------------------------------------------------------------------ orientation of a position fit
@pytest.fixture(scope="module")
def six_dof(tmp_path_factory):
    """A simulated 6-DoF cell, the same campaign without its orientations, and kinematic fits of both."""
    tmp = tmp_path_factory.mktemp("sixdof")
    six = six_dof_cell(tmp / "six", tmp / "truth.json", 3)
    shutil.copytree(six, tmp / "pos")
    t = pd.read_csv(tmp / "pos" / "tracker.csv")
    t.drop(columns=[c for c in ("qw", "qx", "qy", "qz", "sigma_arcsec") if c in t]).to_csv(
        tmp / "pos" / "tracker.csv", index=False)
    run = cli_invoker()
    fits = {}
    for name, campaign, extra in (("pos", "pos", ()), ("full", "six", ()), ("posonly", "six", ("--positions-only",))):
        r = run("fit", "--campaign", tmp / campaign, "--spec", KINEMATIC, "--out", tmp / f"{name}.json", *extra)
        assert r.exit_code == 0, r.output
        fits[name] = json.loads((tmp / f"{name}.json").read_text())
    return {"tmp": tmp, "run": run, "fits": fits}


def test_a_model_fitted_without_orientations_is_not_judged_on_them(six_dof):
    tmp, run = six_dof["tmp"], six_dof["run"]
    assert "orientation_rms_after_arcsec" not in six_dof["fits"]["pos"]["heldout"]
    r = run("predict", "--campaign", tmp / "six", "--model", tmp / "pos.json", "--json", tmp / "pos_on_six.json",
            "--point", "0 0 300")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp / "pos_on_six.json").read_text())
    assert not [k for k in out if k.startswith(("orientation_", "point_")) and k != "orientation_not_judged"], out.keys()
    assert not any("orientation_error_arcsec" in p or "point_error_mm" in p for p in out["points"])
    assert out["orientation_not_judged"]
    assert "orientation not judged" in r.stderr and "arcsec" not in r.stderr.splitlines()[-1]
    # the positions are judged as before
    assert out["n"] > 0 and out["rms_mm"] > 0


@pytest.mark.parametrize("name", ["full", "posonly"])
def test_a_model_that_saw_the_orientations_is_judged_on_them(six_dof, name):
    """A kinematic fit on a 6-DoF campaign fits the orientation; --positions-only registers the probe's mounting
    on it: both keep their orientation errors, equal to the fit's own held-out ones."""
    tmp, run = six_dof["tmp"], six_dof["run"]
    r = run("predict", "--campaign", tmp / "six", "--model", tmp / f"{name}.json", "--json", tmp / f"{name}_p.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp / f"{name}_p.json").read_text())
    assert "orientation_not_judged" not in out and "orientation not judged" not in r.stderr
    held = six_dof["fits"][name]["heldout"]["orientation_rms_after_arcsec"]
    assert abs(out["orientation_rms_arcsec"] - held) < 1e-3 * held
