"""Any serial arm (issue 17): robots of 4 and 7 joints from robot.toml or URDF, through import,
fit, predict and diagnose on a simulated cell; joint-count mismatches refused."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest

from conftest import ROOT
from pipeline.robot.arm.kinematics import build_model, load_robot, positions
from pipeline.robot.cell.simulate import cell_config, format_poses_csv, format_tracker_csv, simulate_robot
from pipeline.robot.campaign.urdf import robot_from_urdf

ARMS = ROOT / "raw" / "arms"
PANDA, ARM4, PANDA_URDF = ARMS / "panda.toml", ARMS / "arm4.toml", ARMS / "panda.urdf"
ONE_LINE = re.compile(r"^jointcal: error: (?P<file>[^:]+):(?P<line>\d+|-):(?P<col>[^:]+): \S.*$")
KINEMATIC = ROOT / "specs" / "robot_kinematic.toml"

# Franka's documentation: Craig's modified DH, one row per joint (a_{i-1} m, d_i m, alpha_{i-1} rad), then the flange
CRAIG = [(0.0, 0.333, 0.0), (0.0, 0.0, -np.pi / 2), (0.0, 0.316, np.pi / 2), (0.0825, 0.0, np.pi / 2),
         (-0.0825, 0.384, -np.pi / 2), (0.0, 0.0, np.pi / 2), (0.088, 0.0, np.pi / 2)]
FLANGE_D = 0.107


def _craig_smr(q_rad, tool_m):
    """SMR position (m) by Craig's formula T = prod Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(q_i) Tz(d_i) . Tz(flange) . tool."""
    def rx(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])

    def rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    def tr(x, y, z):
        T = np.eye(4)
        T[:3, 3] = x, y, z
        return T

    T = np.eye(4)
    for (a, d, alpha), q in zip(CRAIG, q_rad):
        T = T @ rx(alpha) @ tr(a, 0, 0) @ rz(q) @ tr(0, 0, d)
    T = T @ tr(0, 0, FLANGE_D)
    return (T @ np.r_[tool_m, 1.0])[:3]


def test_panda_toml_is_crafts_table():
    """The shipped Panda (contract convention) puts the SMR where Craig's formula with Franka's table does."""
    robot = load_robot(PANDA)
    assert robot.n_joints == 7
    rng = np.random.default_rng(3)
    Q = rng.uniform(np.deg2rad(robot.lower_deg), np.deg2rad(robot.upper_deg), (40, 7))
    mine = positions(build_model(robot), Q)
    craig = np.array([_craig_smr(q, np.asarray(robot.tool_xyz_mm) / 1000.0) for q in Q]) * 1000.0
    assert np.abs(mine - craig).max() < 1e-9


def test_seven_joint_urdf_matches_pinocchio():
    """A URDF with 7 revolute joints (and fixed ones folded in) read as the contract's robot: its SMR
    agrees with pinocchio's own model of the URDF, and with the Panda's robot.toml."""
    robot, info = robot_from_urdf(PANDA_URDF, "smr")
    assert robot.n_joints == 7 and len(info["chain"]) == 7
    urdf = pin.buildModelFromUrdf(str(PANDA_URDF))
    data = urdf.createData()
    fid = urdf.getFrameId("smr")
    rng = np.random.default_rng(5)
    Q = rng.uniform(urdf.lowerPositionLimit, urdf.upperPositionLimit, (40, urdf.nq))
    theirs = []
    for q in Q:
        pin.framesForwardKinematics(urdf, data, q)
        theirs.append(data.oMf[fid].translation.copy() * 1000.0)
    mine = positions(build_model(robot), Q)
    assert np.abs(mine - np.array(theirs)).max() < 1e-6
    toml = load_robot(PANDA)
    # the toml's tool is 60 mm past the flange; the URDF's tip link is that SMR
    assert np.abs(positions(build_model(toml), Q) - mine).max() < 1e-6


def test_prismatic_joint_refused_naming_it(tmp_path):
    text = PANDA_URDF.read_text().replace('name="panda_joint4" type="revolute"', 'name="panda_joint4" type="prismatic"')
    bad = tmp_path / "bad.urdf"
    bad.write_text(text)
    from pipeline.core.errors import InputError

    with pytest.raises(InputError) as exc:
        robot_from_urdf(bad, "smr")
    assert "panda_joint4" in str(exc.value) and "prismatic" in str(exc.value)
    assert exc.value.line == text[:text.index('name="panda_joint4"')].count("\n") + 1


# ----------------------------------------------------------------------- simulated campaigns
def _clean_campaign(folder, robot_path, hidden, seed=2):
    """The virtual cell of any arm with MDH errors, the hidden effect and tracker noise only."""
    robot = load_robot(robot_path)
    n = robot.n_joints
    config = dict(cell_config(robot, seed, paper=False), n_target=60, transmission_arcsec=[0.0] * n,
                  compliance_arcsec_per_knm=[0.0] * n, backlash_arcsec=[0.0] * n, jitter_arcsec=0.0)
    poses, tracker, _ = simulate_robot(robot, config, hidden)
    folder.mkdir(parents=True)
    (folder / "robot.toml").write_text(robot.to_toml())
    (folder / "poses.csv").write_text(format_poses_csv(poses))
    (folder / "tracker.csv").write_text(format_tracker_csv(tracker))
    return robot, poses, tracker, config["tracker_sigma_mm"] * np.sqrt(3)


def _export(tmp_path, robot, poses, tracker):
    """The campaign as a measurement export (radians, metres, one row per pose) and its map."""
    n = robot.n_joints
    names = [f"joint_{k}_rad" for k in range(1, n + 1)]
    src = pd.DataFrame({"Id": poses["point_id"], "use": poses["set"]})
    for k, c in enumerate(names):
        src[c] = np.deg2rad(poses[f"q{k + 1}"].to_numpy(float))
    for c in ("x", "y", "z"):
        src[f"m_{c}"] = tracker[f"{c}_mm"].to_numpy(float) / 1000.0
    for k in range(n):
        src[f"d{k + 1}"] = poses[f"dir{k + 1}"].to_numpy(int)
    src["load"] = poses["payload_kg"].to_numpy(float)
    source = tmp_path / "export.csv"
    src.to_csv(source, index=False, float_format="%.12g")
    dirs = "\n".join(f'dir{k + 1} = "d{k + 1}"' for k in range(n))
    mp = tmp_path / "map.toml"
    mp.write_text(f'[joints]\ncolumns = {json.dumps(names)}\nunit = "rad"\n\n[position]\n'
                  'columns = ["m_x", "m_y", "m_z"]\nunit = "m"\nframe = "base"\n\n'
                  f'[columns]\npoint_id = "Id"\npayload_kg = "load"\n{dirs}\n\n[split]\ncolumn = "use"\n')
    return source, mp


ARMS_CASES = [  # robot, hidden effect, (name, target) expected first
    (PANDA, {"effect": "backlash", "joint": 2, "arcsec": 100.0}, ("backlash", 2)),
    (ARM4, {"effect": "joint_harmonic", "joint": 3, "order": 6, "arcsec": 40.0, "phase_deg": 30.0},
     ("joint_harmonic", 3)),
]


@pytest.mark.parametrize("robot_path,hidden,first", ARMS_CASES, ids=["panda-7", "arm4-4"])
def test_any_arm_import_fit_predict_diagnose(tmp_path, invoke, robot_path, hidden, first):
    robot, poses, tracker, floor = _clean_campaign(tmp_path / "sim", robot_path, hidden)
    source, mp = _export(tmp_path, robot, poses, tracker)
    camp = tmp_path / "campaign"
    r = invoke("import", "--source", source, "--map", mp, "--robot", robot_path, "--out", camp)
    assert r.exit_code == 0, r.output
    got = pd.read_csv(camp / "poses.csv")
    assert [c for c in got.columns if re.fullmatch(r"q\d+", c)] == [f"q{k}" for k in range(1, robot.n_joints + 1)]

    r = invoke("diagnose", "--campaign", camp, "--spec", KINEMATIC, "--json", tmp_path / "diag.json")
    assert r.exit_code == 0, r.output
    diag = json.loads((tmp_path / "diag.json").read_text())
    top = diag["candidates"][0]
    summary = [(c["effect"], c["target"], round(c["gain"], 3)) for c in diag["candidates"][:4]]
    assert (top["effect"], top["target"]) == first, summary
    assert top["cv_rms_with"] <= 1.5 * floor, (top["cv_rms_with"], floor)
    # every joint of the arm has its per-joint candidates
    assert {c["target"] for c in diag["candidates"] if c["effect"] in ("backlash", "joint_harmonic")} == \
        set(range(1, robot.n_joints + 1))

    spec = tmp_path / "spec.toml"
    spec.write_text(KINEMATIC.read_text() + "\n" + top["spec_line"] + "\n")
    r = invoke("fit", "--campaign", camp, "--spec", spec, "--out", tmp_path / "fit.json")
    assert r.exit_code == 0, r.output
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert fit["heldout"]["rms_after_mm"] <= 1.5 * floor < fit["heldout"]["rms_before_mm"]
    r = invoke("predict", "--campaign", camp, "--model", tmp_path / "fit.json", "--json", tmp_path / "pred.json")
    assert r.exit_code == 0, r.output
    pred = json.loads((tmp_path / "pred.json").read_text())
    assert pred["n"] == 60 and pred["rms_mm"] <= 1.5 * floor


def test_seven_joint_fit_says_why_it_keeps_parameters_at_nominal(tmp_path, invoke):
    """The Panda's SMR sits on joint 7's axis: joint 7's rotation does not move it, and more is redundant."""
    _clean_campaign(tmp_path / "sim", PANDA, None)
    r = invoke("fit", "--campaign", tmp_path / "sim", "--spec", KINEMATIC, "--out", tmp_path / "fit.json")
    assert r.exit_code == 0, r.output
    fixed = json.loads((tmp_path / "fit.json").read_text())["not_identified"]
    assert "dtheta7" in fixed and "does not move the measured point" in fixed["dtheta7"]
    assert all(reason for reason in fixed.values())


# ---------------------------------------------------------------------------- mismatches
def _one_line(result):
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, lines
    m = ONE_LINE.match(lines[0])
    assert m, lines[0]
    return m, lines[0]


@pytest.mark.parametrize("robot_path,n_robot", [(ROOT / "raw" / "robot" / "kr210" / "robot.toml", 6), (ARM4, 4)])
def test_joint_count_mismatch_refused(tmp_path, invoke, robot_path, n_robot):
    robot, poses, tracker, _ = _clean_campaign(tmp_path / "sim", PANDA, None)
    (tmp_path / "sim" / "robot.toml").write_text(robot_path.read_text())
    m, line = _one_line(invoke("ingest", "--campaign", tmp_path / "sim", "--out", tmp_path / "x.parquet"))
    assert m["file"].endswith("poses.csv") and m["line"] == "1" and m["col"] == f"q{n_robot + 1}"
    assert f"q1..q7" in line and f"{n_robot} joints" in line
    assert not (tmp_path / "x.parquet").exists()


@pytest.mark.parametrize("header, n, extra, missing", [
    (["point_id", "q1", "q2", "q4"], 3, ["q4"], ["q3"]),
    (["point_id", "set", "q1", "q2", "q3", "q4", "q5", "q6", "q7"], 6, ["q7"], []),
    (["q1", "q2", "q3", "q4", "dir1", "dir5", "q0", "q1_corrected", "x_mm"], 4, ["dir5", "q0"], []),
    (["point_id", "q1", "q2", "q3", "q4", "q5", "q6", "dir1", "dir6"], 6, [], []),
])
def test_find_joint_columns_names_the_missing_and_the_extra(header, n, extra, missing):
    """The one finding behind the poses', the pool's and the targets' joint-count checks."""
    from pipeline.core.tables import find_joint_columns

    found = find_joint_columns(header, n)
    assert (found.extra, found.missing) == (extra, missing)
    assert found.q == [int(c[1:]) for c in header if re.fullmatch(r"q\d+", c)]


def test_import_map_with_other_joint_count_refused(tmp_path, invoke):
    robot, poses, tracker, _ = _clean_campaign(tmp_path / "sim", PANDA, None)
    source, mp = _export(tmp_path, robot, poses, tracker)
    m, line = _one_line(invoke("import", "--source", source, "--map", mp, "--robot", ARM4, "--out", tmp_path / "c"))
    assert m["file"].endswith("map.toml") and "7 joint columns" in line and "4 joints" in line
    assert not (tmp_path / "c").exists()


def test_robot_toml_joint_count_bounds(tmp_path):
    from pipeline.core.errors import InputError
    from pipeline.robot.arm.kinematics import parse_robot

    text = ARM4.read_text()
    three = text[:text.rindex("[[joint]]")]
    with pytest.raises(InputError, match="found 3 \\[\\[joint\\]\\] tables; expected 4 to 7"):
        parse_robot(three)
    assert parse_robot(text).n_joints == 4
