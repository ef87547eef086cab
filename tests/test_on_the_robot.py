"""What travels with a fitted model to the robot (contract section 8): the rigid chain nearest the whole
model, the joint angles and the payload it was made for; `simulate measure` closed loop on gratings."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker

KR210 = ROOT / "raw/robot/kr210"
TRUTH = ROOT / "raw/truth/robot/kr210.json"
KINEMATIC = ROOT / "specs/robot_kinematic.toml"
FULL_SPEC = (ROOT / "specs" / "robot_cell.toml").read_text()
Q = [f"q{j}" for j in range(1, 7)]


def _land_rms(campaign, fresh, robot_toml=KR210 / "robot.toml"):
    """RMS (mm) of where a measured program landed from the nominal kinematics of its given joints."""
    from pipeline.robot.arm.kinematics import build_model, load_robot, positions

    target = positions(build_model(load_robot(robot_toml)), np.deg2rad(fresh[Q].to_numpy(float)))
    meas = pd.read_csv(campaign / "tracker.csv").set_index("point_id").loc[fresh["point_id"]]
    e = np.linalg.norm(meas[["x_mm", "y_mm", "z_mm"]].to_numpy() - target, axis=1)
    return float(np.sqrt(np.mean(e ** 2)))


def _fresh(fit, n=60, seed=21):
    """A program of poses in the model's sampled joint ranges (the cell's test box), no payload_kg."""
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses

    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    q = draw_poses(load_robot(KR210 / "robot.toml"), 10 * n, np.random.default_rng(seed), ROBOT_FIXTURE["box_mm"], 10.0)
    q = q[np.all((q >= lo) & (q <= hi), axis=1)][:n]
    fresh = pd.DataFrame({"point_id": [f"P{k:03d}" for k in range(len(q))]})
    for j in range(6):
        fresh[Q[j]] = q[:, j]
    return fresh


@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    """The KR210 fixture fitted as shipped (gratings on joints 1-3, 60 kg), and its poses measured again
    open loop without gratings (commanded angles) and fitted with compliance, backlash and harmonics."""
    tmp = tmp_path_factory.mktemp("robot")
    run = cli_invoker()
    r = run("fit", "--campaign", KR210, "--spec", KINEMATIC, "--out", tmp / "grating_fit.json")
    assert r.exit_code == 0, r.output
    poses = pd.read_csv(KR210 / "poses.csv")
    poses[poses["set"] != "repeat"][["point_id", "set"] + Q + ["payload_kg"]].to_csv(tmp / "poses.csv", index=False)
    r = run("simulate", "measure", "--truth", TRUTH, "--poses", tmp / "poses.csv", "--campaign", tmp / "open")
    assert r.exit_code == 0, r.output
    (tmp / "full.toml").write_text(FULL_SPEC)
    for name, spec in (("full", tmp / "full.toml"), ("kinematic", KINEMATIC)):
        r = run("fit", "--campaign", tmp / "open", "--spec", spec, "--out", tmp / f"{name}_fit.json")
        assert r.exit_code == 0, r.output
    fits = {k: json.loads((tmp / f"{k}_fit.json").read_text()) for k in ("grating", "full", "kinematic")}
    return {"tmp": tmp, "run": run, "fits": fits}


def test_fit_records_joint_angles_and_payloads(cells):
    g, f = cells["fits"]["grating"], cells["fits"]["full"]
    assert g["joint_angles"] == ["grating1_deg", "grating2_deg", "grating3_deg"] + ["commanded"] * 3
    assert f["joint_angles"] == ["commanded"] * 6
    assert g["payloads_kg"] == [60.0] and f["payloads_kg"] == [60.0]
    assert cells["fits"]["kinematic"]["rigid_chain"]["exact"] and not f["rigid_chain"]["exact"]


def test_export_chain_is_nearest_the_whole_model(cells):
    """The URDF's chain is fitted to the whole model: held out it beats the model's own geometry (fitted
    together with compliance, backlash and harmonics) and is as good as a kinematic fit; pinocchio's
    forward kinematics of the file is that chain."""
    from pipeline.export.urdf import urdf_positions
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.arm.kinematics import load_robot

    tmp, run = cells["tmp"], cells["run"]
    r = run("export", "--model", tmp / "full_fit.json", "--format", "urdf", "--out", tmp / "full.urdf",
            "--heldout", tmp / "open", "--json", tmp / "export.json")
    assert r.exit_code == 0, r.output
    h = json.loads((tmp / "export.json").read_text())
    kin = cells["fits"]["kinematic"]["heldout"]["rms_after_mm"]
    assert h["chain_rms_mm"] <= kin * 1.01 + 1e-3, (h, kin)
    assert h["chain_rms_mm"] < h["model_geometry_rms_mm"] - 0.005, h
    assert h["full_rms_mm"] < h["chain_rms_mm"]
    # the chain for drives that apply the joint tables, with them, beats the model's own geometry with them
    assert h["full_rms_mm"] <= h["chain_tables_rms_mm"] < h["model_geometry_tables_rms_mm"], h
    assert "payload 60 kg" in r.output              # says what it assumes
    from pipeline.robot.model.rigid import load_chain

    robot = load_robot(KR210 / "robot.toml")
    chain = load_chain(robot, cells["fits"]["full"]["rigid_chain"])
    _, (target,) = robot_data_sets(tmp / "open", ("target",))
    urdf = urdf_positions((tmp / "full.urdf").read_text(), "smr", target.q_deg)
    assert np.abs(urdf - chain.predict(target)).max() < 1e-3        # mm
    # --with-tables: that URDF at the angles the joint tables turn the joints to is the model's chain for them
    from pipeline.robot.model.predict import load_model_document
    from pipeline.robot.model.rigid import table_angles_deg, with_angles

    r = run("export", "--model", tmp / "full_fit.json", "--format", "urdf", "--with-tables", "--out", tmp / "t.urdf")
    assert r.exit_code == 0, r.output
    _, _, model, _, _ = load_model_document(cells["fits"]["full"], "fit.json")
    tabled = load_chain(robot, cells["fits"]["full"]["rigid_chain_with_tables"])
    q = table_angles_deg(robot, model, target)
    urdf = urdf_positions((tmp / "t.urdf").read_text(), "smr", q)
    assert np.abs(urdf - tabled.predict(with_angles(target, q))).max() < 1e-3            # mm
    assert np.abs(urdf - chain.predict(target)).max() > 0.01        # another chain


def test_row_without_payload_is_corrected_at_the_models_payload(cells, tmp_path):
    tmp, run = cells["tmp"], cells["run"]
    fresh = _fresh(cells["fits"]["full"], n=12)
    fresh.to_csv(tmp_path / "none.csv", index=False)
    for kg in (0.0, 60.0):
        fresh.assign(payload_kg=kg).to_csv(tmp_path / f"{kg:g}.csv", index=False)
    out, said = {}, {}
    for name in ("none", "0", "60"):
        r = run("correct", "--model", tmp / "full_fit.json", "--targets", tmp_path / f"{name}.csv",
                "--out", tmp_path / f"c_{name}.csv")
        assert r.exit_code == 0, r.output
        out[name], said[name] = pd.read_csv(tmp_path / f"c_{name}.csv"), r.output
    assert np.abs(out["60"][Q].to_numpy() - out["0"][Q].to_numpy()).max() * 3600 > 1.0     # arcsec: it matters
    assert np.array_equal(out["none"][Q].to_numpy(), out["60"][Q].to_numpy())
    assert (out["none"]["payload_kg"] == 60).all()
    assert f"{len(fresh)} row(s) without payload_kg corrected at 60 kg" in said["none"]


def test_grating_model_refused_for_an_open_loop_program(cells, tmp_path):
    tmp, run = cells["tmp"], cells["run"]
    _fresh(cells["fits"]["grating"], n=5).to_csv(tmp_path / "p.csv", index=False)
    model = tmp / "grating_fit.json"
    r = run("correct", "--model", model, "--targets", tmp_path / "p.csv", "--out", tmp_path / "c.csv")
    assert r.exit_code == 2
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"jointcal: error: {model}:") and ":joint_angles:" in lines[0]
    assert "--closed-loop-joints 1 2 3" in lines[0] and not (tmp_path / "c.csv").exists()
    # a commanded-angle model for joints said to run closed loop: refused too
    r = run("correct", "--model", tmp / "full_fit.json", "--targets", tmp_path / "p.csv", "--out", tmp_path / "c.csv",
            "--closed-loop-joints", "1")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1 and not (tmp_path / "c.csv").exists()
    r = run("correct", "--model", model, "--targets", tmp_path / "p.csv", "--out", tmp_path / "c.csv",
            "--closed-loop-joints", "1,2,3")
    assert r.exit_code == 0, r.output
    assert "closed loop on their encoders: joints 1 2 3" in r.output


def test_simulate_measure_closed_loop_on_gratings(cells, tmp_path):
    """Closed loop, the gratings of joints 1-3 read the command and those joints' errors are gone."""
    run = cells["run"]
    poses = pd.read_csv(cells["tmp"] / "poses.csv").head(15)
    poses.to_csv(tmp_path / "p.csv", index=False)
    r = run("simulate", "measure", "--truth", TRUTH, "--poses", tmp_path / "p.csv", "--campaign", tmp_path / "closed",
            "--closed-loop-joints", "1 2 3")
    assert r.exit_code == 0, r.output
    r = run("simulate", "measure", "--truth", TRUTH, "--poses", tmp_path / "p.csv", "--campaign", tmp_path / "open")
    assert r.exit_code == 0, r.output
    closed = pd.read_csv(tmp_path / "closed" / "poses.csv")
    assert "grating1_deg" not in pd.read_csv(tmp_path / "open" / "poses.csv")
    g = closed[["grating1_deg", "grating2_deg", "grating3_deg"]].to_numpy()
    assert np.abs(g - closed[Q[:3]].to_numpy()).max() < 5e-5                 # deg: the loop's tolerance
    a = pd.read_csv(tmp_path / "closed" / "tracker.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy()
    b = pd.read_csv(tmp_path / "open" / "tracker.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy()
    assert np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))) > 0.05                # mm
    r = run("simulate", "measure", "--truth", TRUTH, "--poses", tmp_path / "p.csv", "--campaign", tmp_path / "x",
            "--closed-loop-joints", "4")
    assert r.exit_code == 2 and "no grating" in r.output


def test_grating_model_lands_at_its_heldout_error_closed_loop(cells, tmp_path):
    """KR210 cell: the grating model's corrected program, run with joints 1-3 closed loop on their
    gratings, lands within 1.25x the model's held-out RMS + 5 um; run open loop it does not."""
    tmp, run = cells["tmp"], cells["run"]
    fit = cells["fits"]["grating"]
    fresh = _fresh(fit)
    fresh.to_csv(tmp_path / "p.csv", index=False)
    r = run("correct", "--model", tmp / "grating_fit.json", "--targets", tmp_path / "p.csv", "--out", tmp_path / "c.csv",
            "--closed-loop-joints", "1 2 3")
    assert r.exit_code == 0, r.output
    assert (pd.read_csv(tmp_path / "c.csv")["status"] == "ok").mean() >= 0.95
    land = {}
    for mode, extra in (("closed", ("--closed-loop-joints", "1,2,3")), ("open", ())):
        r = run("simulate", "measure", "--truth", TRUTH, "--poses", tmp_path / "c.csv", "--campaign", tmp_path / mode,
                *extra)
        assert r.exit_code == 0, r.output
        land[mode] = _land_rms(tmp_path / mode, fresh)
    heldout = fit["heldout"]["rms_after_mm"]
    assert land["closed"] <= 1.25 * heldout + 0.005, (land, heldout)
    assert land["open"] > 2 * heldout, (land, heldout)
