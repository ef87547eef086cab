"""jointcal export: URDF, UR and table round trips (pinocchio), on synthetic fitted models."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from conftest import ROOT, cli_invoker

UR10 = ROOT / "raw/real/ur10-ipa/robot.toml"
UR10E_URDF = "/work/shared/real/urdf/ur10e.urdf"
CHAIN_SPEC = """[model]
kind = "robot"
[[effect]]
name = "geometry"
[[effect]]
name = "base"
[[effect]]
name = "tool"
"""
TABLE_SPEC = CHAIN_SPEC + """[[effect]]
name = "joint_map"
joints = [2, 5]
step_deg = 5.0
range_deg = {"2" = [-150.0, -30.0], "5" = [-120.0, 60.0]}
[[effect]]
name = "backlash"
joints = [2, 5]
[[effect]]
name = "compliance"
joints = [2]
"""


def synthetic_model(robot, spec_text, seed, angle_arcsec=60.0, length_mm=0.5):
    """A 'fitted' model: every parameter drawn at a realistic size (seeded)."""
    from pipeline.core.spec import parse_spec
    from pipeline.robot.model.estimator import RobotErrorModel

    effects = list(parse_spec(spec_text, "spec").effects)
    from pipeline.export.chain import model_data
    from pipeline.robot.model.design import Design

    nj = len(robot.joints)
    d = Design(robot, effects, model_data(robot, np.zeros((1, nj)), np.ones((1, nj), int), np.zeros(1),
                                          np.full(1, 20.0)))
    rng = np.random.default_rng(seed)
    scale = {"mm": length_mm, "arcsec": angle_arcsec}
    params = [{"name": n, "value": float(rng.normal(0, scale.get(u, 30.0))), "unit": u, "fixed": False}
              for n, (u, _) in zip(d.names, d.units)]
    return RobotErrorModel.from_parameters(robot, effects, params), params


def _fit_doc(robot, params, spec_text, lo, hi):
    from pipeline.core.spec import parse_spec

    return {"kind": "robot", "version": 1, "robot_toml": robot.to_toml(),
            "spec_effects": [e.spec_lines() for e in parse_spec(spec_text, "spec").effects],
            "parameters": params, "sampled_range": {"lower_deg": list(lo), "upper_deg": list(hi)}}


def _chain_reference(robot, model, q):
    from pipeline.export.chain import CHAIN_EFFECTS, model_data, predict_with

    n, nj = q.shape
    return predict_with(robot, model, model_data(robot, q, np.ones((n, nj), int), np.zeros(n), np.full(n, 20.0)),
                        CHAIN_EFFECTS)


@pytest.fixture(scope="module")
def ur10():
    from pipeline.robot.arm.kinematics import load_robot

    return load_robot(UR10)


def test_urdf_round_trip(ur10, tmp_path):
    from pipeline.export.urdf import urdf_positions

    model, params = synthetic_model(ur10, CHAIN_SPEC, 1)
    lo, hi = np.full(6, -170.0), np.full(6, 170.0)
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(ur10, params, CHAIN_SPEC, lo, hi)))
    r = cli_invoker()("export", "--model", tmp_path / "fit.json", "--format", "urdf", "--out", tmp_path / "r.urdf")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "r.urdf").read_text()
    q = np.random.default_rng(2).uniform(lo, hi, (40, 6))
    err = np.abs(urdf_positions(text, "smr", q) - _chain_reference(ur10, model, q)).max()
    assert err < 1e-3        # mm: < 1 um
    # the nominal chain is not the model's: the test can tell them apart
    from pipeline.robot.arm.kinematics import build_model, positions

    assert np.abs(positions(build_model(ur10), np.deg2rad(q)) - _chain_reference(ur10, model, q)).max() > 0.1


def test_urdf_rewrite_changes_only_origins(tmp_path):
    from pipeline.export.chain import folded_chain
    from pipeline.export.urdf import rewrite_urdf, urdf_positions
    from pipeline.robot.campaign.urdf import robot_from_urdf

    robot, _ = robot_from_urdf(UR10E_URDF, "tool0", base="base_link")
    model, _ = synthetic_model(robot, CHAIN_SPEC, 3)
    original = open(UR10E_URDF, encoding="utf-8").read()
    text = rewrite_urdf(original, "tool0", folded_chain(robot, model), ["a comment"], base="base_link")
    q = np.random.default_rng(4).uniform(-170, 170, (30, 6))
    # pinocchio's model of the whole file: base_link's pose in the root frame maps the model's base frame
    import pinocchio as pin

    pm = pin.buildModelFromXML(text)
    pd_ = pm.createData()
    pin.forwardKinematics(pm, pd_, pin.neutral(pm))
    pin.updateFramePlacements(pm, pd_)
    oMb = pd_.oMf[pm.getFrameId("base_link")]
    got = (urdf_positions(text, "tool0", q) / 1000.0 - oMb.translation) @ oMb.rotation * 1000.0
    assert np.abs(got - _chain_reference(robot, model, q)).max() < 1e-3
    strip = lambda t: re.sub(r"<origin\b[^>]*/>", "<origin/>", re.sub(r"<!--.*?-->\n?", "", t, flags=re.S))  # noqa: E731
    assert strip(text) == strip(original)
    assert text != original


def test_ur_round_trip_with_nearly_parallel_axes(ur10, tmp_path):
    import yaml

    from pipeline.export.chain import folded_chain
    from pipeline.export.ur import dh_positions, read_calibration_conf, standard_dh, yaml_positions

    model, params = synthetic_model(ur10, CHAIN_SPEC, 5)
    lo, hi = np.full(6, -170.0), np.full(6, 170.0)
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(ur10, params, CHAIN_SPEC, lo, hi)))
    r = cli_invoker()("export", "--model", tmp_path / "fit.json", "--format", "ur", "--out", tmp_path / "ur10.yaml")
    assert r.exit_code == 0, r.output
    q = np.random.default_rng(6).uniform(lo, hi, (40, 6))
    ref = _chain_reference(ur10, model, q)
    text = (tmp_path / "ur10.yaml").read_text()
    assert np.abs(yaml_positions(text, q) - ref).max() < 1e-3
    doc = yaml.safe_load(text)["kinematics"]
    assert list(doc) == ["shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3"]
    assert max(abs(v[k]) for v in doc.values() for k in ("x", "y", "z")) < 1.0    # sane origins (m)
    # calibration.conf: UR's nominal DH (the UR10's published values) plus the deltas
    conf = read_calibration_conf((tmp_path / "ur10.conf").read_text())
    nominal = {"theta": np.zeros(6), "a": np.array([0, -0.612, -0.5723, 0, 0, 0]),
               "d": np.array([0.1273, 0, 0, 0.163941, 0.1157, 0.0922]),
               "alpha": np.array([np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0])}
    assert np.abs(conf["delta_d"][1:3]).max() > 10.0     # axes 2-4 nearly parallel: d of tens of metres
    chain = folded_chain(ur10, model)
    fitted = standard_dh(chain)
    dh = {k: nominal[k] + conf[f"delta_{k}"] for k in ("theta", "a", "d", "alpha")}
    dh.update(base=fitted["base"], tool=fitted["tool"])
    assert np.abs(dh_positions(dh, chain["smr"], q) - ref).max() < 1e-3


def test_table_carries_the_joint_angle_effects(ur10, tmp_path):
    import pandas as pd

    from pipeline.export.chain import CHAIN_EFFECTS, TABLE_EFFECTS, model_data, predict_with

    model, params = synthetic_model(ur10, TABLE_SPEC, 7)
    lo = np.array([-170.0, -150.0, -170.0, -170.0, -120.0, -170.0])
    hi = np.array([170.0, -30.0, 170.0, 170.0, 60.0, 170.0])
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(ur10, params, TABLE_SPEC, lo, hi)))
    r = cli_invoker()("export", "--model", tmp_path / "fit.json", "--format", "table", "--out", tmp_path / "t.csv",
                      "--step-deg", "2")
    assert r.exit_code == 0, r.output
    assert "compliance" in r.output           # says what it cannot carry
    t = pd.read_csv(tmp_path / "t.csv", comment="#")
    assert list(t.columns) == ["joint", "angle_deg", "direction", "error_arcsec", "correction_arcsec"]
    assert sorted(t["joint"].unique()) == [2, 5]
    assert np.allclose(np.diff(t[(t.joint == 2) & (t.direction == 1)]["angle_deg"]), 2.0)
    # the model with the table's effects at command q equals the chain alone at the true angles
    # q - error (every tabled joint at one of its grid angles)
    rng = np.random.default_rng(1)
    mid = (lo + hi) / 2
    for _ in range(20):
        direction = int(rng.choice([-1, 1]))
        q, q_true = mid.copy(), mid.copy()
        for j in (2, 5):
            row = t[(t.joint == j) & (t.direction == direction)].sample(1, random_state=int(rng.integers(1e6))).iloc[0]
            q[j - 1] = row.angle_deg
            q_true[j - 1] = row.angle_deg - row.error_arcsec / 3600.0
        dirs = np.full((1, 6), direction)
        with_table = predict_with(ur10, model, model_data(ur10, q[None], dirs, np.zeros(1), np.full(1, 20.0)),
                                  CHAIN_EFFECTS + TABLE_EFFECTS)
        chain_only = predict_with(ur10, model, model_data(ur10, q_true[None], dirs, np.zeros(1), np.full(1, 20.0)),
                                  CHAIN_EFFECTS)
        assert np.abs(with_table - chain_only).max() < 1e-6      # mm
        assert abs(q - q_true).max() > 1e-3                     # the table is not empty


def test_encoder_model_exports_the_same_table(tmp_path):
    import pandas as pd

    doc = {"terms": [{"order": 1, "C_arcsec": 10.0, "phi_deg": 30.0}, {"order": 4, "C_arcsec": 2.0, "phi_deg": 0.0}]}
    (tmp_path / "enc.json").write_text(json.dumps(doc))
    r = cli_invoker()("export", "--model", tmp_path / "enc.json", "--format", "table", "--out", tmp_path / "t.csv")
    assert r.exit_code == 0, r.output
    t = pd.read_csv(tmp_path / "t.csv", comment="#")
    assert list(t.columns) == ["joint", "angle_deg", "error_arcsec", "correction_arcsec"] and len(t) == 360
    assert np.allclose(t["correction_arcsec"], -t["error_arcsec"]) and t["error_arcsec"].abs().max() > 10.0
