"""jointcal correct (robot programs) and jointcal simulate measure: the whole loop on a virtual cell."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker

SPEC = (ROOT / "specs" / "robot_cell.toml").read_text() + """[[effect]]
name = "joint_harmonic"
joints = [2]
orders = [7]
"""


def _q(frame, n=6):
    return frame[[f"q{j}" for j in range(1, n + 1)]].to_numpy(float)


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """A cell with a hidden joint harmonic, measured without gratings, a model of it, and a fresh program."""
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses

    tmp = tmp_path_factory.mktemp("loop")
    run = cli_invoker()
    cell = tmp / "cell"
    cell.mkdir()
    shutil.copy(ROOT / "raw/robot/kr210/robot.toml", cell / "robot.toml")
    r = run("simulate", "robot", "--campaign", cell, "--truth", tmp / "truth.json", "--seed", "3",
            "--hidden", "joint_harmonic:2")
    assert r.exit_code == 0, r.output
    poses = pd.read_csv(cell / "poses.csv")
    prog = poses[poses["set"] != "repeat"][["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg"]]
    prog.to_csv(tmp / "measure.csv", index=False)
    robot_toml = ROOT / "raw/robot/kr210/robot.toml"
    r = run("simulate", "measure", "--truth", tmp / "truth.json", "--poses", tmp / "measure.csv",
            "--campaign", tmp / "meas")      # the truth names its robot
    assert r.exit_code == 0, r.output
    (tmp / "spec.toml").write_text(SPEC)
    r = run("fit", "--campaign", tmp / "meas", "--spec", tmp / "spec.toml", "--out", tmp / "fit.json")
    assert r.exit_code == 0, r.output
    fit = json.loads((tmp / "fit.json").read_text())
    robot = load_robot(robot_toml)
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    Q = draw_poses(robot, 600, np.random.default_rng(11), ROBOT_FIXTURE["box_mm"], 10.0)
    Q = Q[np.all((Q >= lo) & (Q <= hi), axis=1)][:120]
    fresh = pd.DataFrame({"point_id": [f"P{k:03d}" for k in range(len(Q))]})
    for j in range(6):
        fresh[f"q{j + 1}"] = Q[:, j]
    fresh["payload_kg"] = 60.0
    fresh.to_csv(tmp / "fresh.csv", index=False)
    return {"tmp": tmp, "run": run, "fit": fit, "robot_toml": robot_toml, "fresh": fresh}


def test_measure_is_the_simulators_cell(loop):
    """The same poses, measured by `simulate measure`, agree with `simulate robot`'s campaign to its noise."""
    tmp = loop["tmp"]
    a = pd.read_csv(tmp / "cell" / "tracker.csv").set_index("point_id")
    b = pd.read_csv(tmp / "meas" / "tracker.csv").set_index("point_id")
    pa = pd.read_csv(tmp / "cell" / "poses.csv").set_index("point_id").loc[b.index]
    pb = pd.read_csv(tmp / "meas" / "poses.csv").set_index("point_id")
    cols = [f"dir{j}" for j in range(1, 7)]
    same = (pa[cols].to_numpy() == pb[cols].to_numpy()).all(axis=1)
    assert same.mean() > 0.9 and set(pb["set"]) == {"sample", "target"}
    d = np.linalg.norm(a.loc[b.index[same], ["x_mm", "y_mm", "z_mm"]].to_numpy()
                       - b.loc[same, ["x_mm", "y_mm", "z_mm"]].to_numpy(), axis=1)
    assert np.sqrt(np.mean(d ** 2)) < 0.06        # two tracker readings (15 um per axis each) and jitter
    from pipeline.robot.arm.kinematics import build_model, load_robot, positions

    nominal = positions(build_model(load_robot(loop["robot_toml"])), np.deg2rad(_q(pb)))
    assert np.sqrt(np.mean(np.sum((b[["x_mm", "y_mm", "z_mm"]].to_numpy() - nominal) ** 2, axis=1))) > 0.2


def test_corrected_program_lands_at_the_models_heldout_error(loop):
    from pipeline.robot.arm.kinematics import build_model, load_robot, positions

    tmp, run = loop["tmp"], loop["run"]
    r = run("correct", "--model", tmp / "fit.json", "--targets", tmp / "fresh.csv", "--out", tmp / "corr.csv")
    assert r.exit_code == 0, r.output
    corr = pd.read_csv(tmp / "corr.csv")
    assert (corr["status"] == "ok").mean() > 0.95
    assert corr.loc[corr["status"] == "ok", "model_residual_um"].max() <= 1.0
    for name, prog in (("corrected", tmp / "corr.csv"), ("given", tmp / "fresh.csv")):
        r = run("simulate", "measure", "--truth", tmp / "truth.json", "--poses", prog, "--campaign", tmp / name,
                "--robot", loop["robot_toml"])
        assert r.exit_code == 0, r.output
    robot = load_robot(loop["robot_toml"])
    target = positions(build_model(robot), np.deg2rad(_q(loop["fresh"])))
    rms = {}
    for name in ("corrected", "given"):
        meas = pd.read_csv(tmp / name / "tracker.csv").set_index("point_id").loc[loop["fresh"]["point_id"]]
        e = np.linalg.norm(meas[["x_mm", "y_mm", "z_mm"]].to_numpy() - target, axis=1)
        rms[name] = float(np.sqrt(np.mean(e ** 2)))
    heldout = loop["fit"]["heldout"]["rms_after_mm"]
    assert abs(rms["corrected"] - heldout) <= 0.2 * heldout, (rms, heldout)
    assert rms["given"] > 5 * rms["corrected"]


def test_correct_reaches_the_model_point_and_keeps_orientation(loop):
    from pipeline.correct.robot import ModelKinematics, correct_commands
    from pipeline.robot.model.predict import load_model_document

    robot, effects, model, sampled, _ = load_model_document(loop["fit"], "fit.json")
    kin = ModelKinematics(robot, model)
    q = _q(loop["fresh"])[:40]
    rng = np.random.default_rng(5)
    target = kin.nominal(q)[1] + rng.normal(0, 0.3, (len(q), 3))     # points beside the nominal ones
    payload = rng.uniform(0, 150, len(q))
    res = correct_commands(kin, q, target, payload_kg=payload, sampled=sampled)
    ok = res.status == "ok"
    assert ok.all()
    pred = kin.predict(res.q_deg, res.dirs, payload, np.full(len(q), 20.0))
    assert np.linalg.norm(pred - target, axis=1).max() * 1000 <= 1.0
    assert np.nanmax(res.orientation_arcsec) < 1e-2      # six joints: the orientation is kept exactly
    # the payload matters: corrected for no payload, the model misses the point by the sag
    res0 = correct_commands(kin, q, target, sampled=sampled)
    miss = np.linalg.norm(kin.predict(res0.q_deg, res0.dirs, payload, np.full(len(q), 20.0)) - target, axis=1)
    assert miss.max() > 0.01


def test_rows_left_as_given_say_why(loop):
    from pipeline.correct.robot import ModelKinematics, correct_commands
    from pipeline.robot.model.predict import load_model_document

    robot, effects, model, sampled, _ = load_model_document(loop["fit"], "fit.json")
    kin = ModelKinematics(robot, model)
    q = _q(loop["fresh"])[:3].copy()
    q[1, 2] = sampled["upper_deg"][2] + 5.0
    target = kin.nominal(q)[1]
    target[2] += [20.0, 0.0, 0.0]
    res = correct_commands(kin, q, target, sampled=sampled, max_correction_deg=0.5)
    assert list(res.status) == ["ok", "outside_sampled_range", "correction_too_large"]
    assert np.all(res.q_deg[1:] == q[1:]) and "joint 3" in res.reason[1]


@pytest.mark.parametrize("edit, column", [
    (lambda t: t.replace("q3", "q_3", 1), None),                          # missing required column
    (lambda t: t.replace("\nP001,", "\nP000,", 1), "point_id"),           # duplicate id
    (lambda t: t.replace(",60.0\n", ",sixty\n", 1), "payload_kg"),        # not a number
])
def test_bad_targets_refused(loop, tmp_path, edit, column):
    text = (loop["tmp"] / "fresh.csv").read_text()
    bad = tmp_path / "bad.csv"
    bad.write_text(edit(text))
    out = tmp_path / "out.csv"
    r = loop["run"]("correct", "--model", loop["tmp"] / "fit.json", "--targets", bad, "--out", out)
    assert r.exit_code == 2
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"jointcal: error: {bad}:") and "Traceback" not in r.output
    if column:
        assert f":{column}:" in lines[0]
    assert not out.exists()


def test_target_far_from_its_pose_refused(loop, tmp_path):
    from pipeline.robot.arm.kinematics import build_model, load_robot, positions

    fresh = loop["fresh"].head(5).copy()
    xyz = positions(build_model(load_robot(loop["robot_toml"])), np.deg2rad(_q(fresh))) / 1000.0   # metres
    fresh["x_mm"], fresh["y_mm"], fresh["z_mm"] = xyz.T
    fresh.to_csv(tmp_path / "m.csv", index=False)
    r = loop["run"]("correct", "--model", loop["tmp"] / "fit.json", "--targets", tmp_path / "m.csv",
                    "--out", tmp_path / "o.csv")
    assert r.exit_code == 2 and ":2:x_mm:" in r.output and not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("n_joints", [4, 5, 6, 7])
def test_step_reaches_the_point_for_any_joint_count(n_joints):
    """The prioritised step on a random N-joint pinocchio arm: the position is reached exactly; with 7
    joints the step is the smallest that keeps the orientation too (no joint count is assumed)."""
    import pinocchio as pin

    from pipeline.correct.robot import _prioritised_step

    rng = np.random.default_rng(n_joints)
    model = pin.Model()
    parent = 0
    for i in range(n_joints):
        M = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-1.5, 1.5, 3)), rng.uniform(-0.3, 0.3, 3))
        parent = model.addJoint(parent, pin.JointModelRZ(), M, f"j{i}")
    fid = model.addFrame(pin.Frame("tip", parent, 0, pin.SE3(np.eye(3), np.array([0.1, 0.0, 0.2])),
                                   pin.FrameType.OP_FRAME))
    data = model.createData()

    def pose(q):
        pin.computeJointJacobians(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED).copy()
        J[:3] *= 1000.0
        return M.rotation.copy(), M.translation * 1000.0, J

    q0 = rng.uniform(-1, 1, n_joints)
    R0, p0, _ = pose(q0)
    target = p0 + rng.normal(0, 0.5, 3)
    q = q0.copy()
    from scipy.spatial.transform import Rotation

    for _ in range(10):
        R, p, J = pose(q)
        e_rot = Rotation.from_matrix(R0 @ R.T).as_rotvec()
        q = q + _prioritised_step(J[None], (target - p)[None], e_rot[None], (q - q0)[None])[0]
    R, p, J = pose(q)
    assert np.linalg.norm(p - target) < 1e-6                       # mm
    if n_joints >= 6:
        assert np.linalg.norm(Rotation.from_matrix(R0 @ R.T).as_rotvec()) < 1e-6    # rad (0.2 arcsec)
    if n_joints == 7:
        # smallest: no motion of the self-motion direction (null space of the full 6-row Jacobian) is in it
        null = np.linalg.svd(J)[2][-1]
        assert abs(null @ (q - q0)) < 1e-6 * np.linalg.norm(q - q0) + 1e-9


def test_correct_targets_uses_the_models_payload_where_a_row_gives_none(loop, tmp_path):
    """correct_targets, the library of `jointcal correct --targets`: rows without payload_kg are corrected
    at the one payload the model was fitted at (0 kg when it was fitted at several), said in the CSV."""
    import io

    from pipeline.correct.run import correct_targets
    from pipeline.robot.model.predict import load_model_document

    fit = loop["fit"]
    loaded = load_model_document(fit, "fit.json")
    fresh = loop["fresh"].head(6).copy()
    fresh["payload_kg"] = [12.5, None, 12.5, None, None, 3.0]
    fresh.to_csv(tmp_path / "t.csv", index=False)
    run = correct_targets(tmp_path / "t.csv", fit, loaded, 0.5)
    pays = fit.get("payloads_kg") or []
    model_kg = float(pays[0]) if len(pays) == 1 else None
    assert run.payload_kg == model_kg
    expect = np.array([12.5, model_kg or 0.0, 12.5, model_kg or 0.0, model_kg or 0.0, 3.0])
    assert np.array_equal(run.targets.payload_kg, expect)
    assert list(run.targets.payload_given) == [True, False, True, False, False, True]
    out = pd.read_csv(io.StringIO(run.csv))
    assert list(out["point_id"]) == list(fresh["point_id"]) and np.allclose(out["payload_kg"], expect)
    assert (run.result.status == "ok").all() and "joint" in run.assumed


def test_correct_targets_refuses_a_repeated_point_id(loop, tmp_path):
    from pipeline.core.errors import InputError
    from pipeline.correct.run import correct_targets
    from pipeline.robot.model.predict import load_model_document

    fresh = loop["fresh"].head(4).copy()
    fresh.loc[3, "point_id"] = fresh.loc[1, "point_id"]
    fresh.to_csv(tmp_path / "t.csv", index=False)
    with pytest.raises(InputError) as err:
        correct_targets(tmp_path / "t.csv", loop["fit"], load_model_document(loop["fit"], "fit.json"), 0.5)
    assert (err.value.line, err.value.column) == (5, "point_id")
    assert err.value.message == f"point_id '{fresh.loc[1, 'point_id']}' appears twice; ids must be unique"


def test_measured_campaign_is_seeded_and_refuses_a_loop_without_gratings(loop):
    """measured_campaign, the library of `jointcal simulate measure`: the campaign's three files, the
    same bytes for the same seed, other noise for another; a closed loop on a joint the cell has no
    grating on is a ValueError (the command's --closed-loop-joints)."""
    import io

    from pipeline.robot.cell.measure import measure_cell, measured_campaign

    tmp = loop["tmp"]
    robot, cell = measure_cell(tmp / "truth.json", tmp / "meas")
    fresh = loop["fresh"].head(5)
    q, n = _q(fresh), len(fresh)
    args = (robot, cell, fresh["point_id"].to_numpy(), np.full(n, "target"), q, None, np.zeros(n), np.full(n, 20.0))
    a = measured_campaign(*args, seed=1)
    assert list(a) == ["robot.toml", "poses.csv", "tracker.csv"]
    assert a == measured_campaign(*args, seed=1)
    b = measured_campaign(*args, seed=2)
    assert a["poses.csv"] == b["poses.csv"] and a["tracker.csv"] != b["tracker.csv"]
    t = pd.read_csv(io.StringIO(a["tracker.csv"]))
    assert list(t["point_id"]) == list(fresh["point_id"])
    with pytest.raises(ValueError, match="joint 6 has no grating"):       # the KR210 cell's are on joints 1-3
        measured_campaign(*args, seed=1, closed_loop_joints=[6])
    closed = measured_campaign(*args, seed=1, closed_loop_joints=[1, 2, 3])
    assert "grating1_deg" in closed["poses.csv"] and "grating1_deg" not in a["poses.csv"]


def test_correct_targets_report_names_the_first_row_left_as_given(loop, tmp_path):
    from pipeline.correct.run import correct_targets
    from pipeline.robot.model.predict import load_model_document

    fit = loop["fit"]
    fresh = loop["fresh"].head(5).copy()
    fresh.loc[3, "q3"] = fit["sampled_range"]["upper_deg"][2] + 5.0      # beyond what the model saw
    fresh.to_csv(tmp_path / "t.csv", index=False)
    run = correct_targets(tmp_path / "t.csv", fit, load_model_document(fit, "fit.json"), 0.5)
    lines = run.report("out.csv", 1.25, 0.5, closed=[1, 2])
    assert lines[0].startswith("out.csv: 5 rows in 1.2 s: 4 corrected, largest correction ")
    assert "left as given: 1 outside the sampled joint range, 0 beyond --max-correction-deg 0.5, 0 without" in lines[0]
    assert lines[1].startswith(f"  first left as given: {fresh.loc[3, 'point_id']} (line 5): ")
    assert lines[-1].endswith("; closed loop on their encoders: joints 1 2")


def test_a_row_at_the_wrist_singularity_says_so():
    """At joint 5 = 0 the correction a 6-DoF hold would need is large; the row's reason names the wrist
    singularity (joints 4 and 6 about one axis), not only "joint 4 would need ... deg". Away from it, no
    singularity is named."""
    from test_export import synthetic_model

    from pipeline.correct.robot import ModelKinematics, correct_commands, singularity
    from pipeline.robot.arm.kinematics import load_robot

    robot = load_robot(ROOT / "raw/robot/kr210/robot.toml")
    spec = '[model]\nkind = "robot"\n[[effect]]\nname = "geometry"\n[[effect]]\nname = "base"\n'
    model, _ = synthetic_model(robot, spec, 5)
    q = np.array([[10.0, -80.0, 90.0, 30.0, 0.0, 20.0], [10.0, -80.0, 90.0, 30.0, 40.0, 20.0]])
    res = correct_commands(ModelKinematics(robot, model), q, max_correction_deg=0.5)
    assert "would need" in res.reason[0] and "the wrist singularity: at joint 5 = +0.000 deg joints 4 and 6" \
        in res.reason[0], res.reason[0]
    assert "singularity" not in res.reason[1] and singularity(robot, q[1]) == ""


def test_a_coupled_robots_ls_joint_targets_are_read_and_written_as_the_pendant_has_them(tmp_path):
    """A FANUC .ls joint target holds the pendant's angles (J3 counting J2): on a robot whose robot.toml says
    [coupling] q3 = { q2 = 1, q3 = 1 }, correct --program corrects the arm's angles and writes the pendant's,
    so that the model, at the arm's angles of what is written, lands where the nominal robot put the given
    target. (Before: J3 was read as the arm's own angle, silently.)"""
    import re

    from test_export import CHAIN_SPEC, _fit_doc, synthetic_model

    from pipeline.correct.robot import ModelKinematics
    from pipeline.robot.arm.kinematics import parse_robot
    from pipeline.robot.campaign.urdf import robot_from_urdf

    base, _ = robot_from_urdf(ROOT / "tests/data/urdf/fanuc_like.urdf", "link_6", tool_mm=(204.5, 46.6, 195.2))
    robot = parse_robot(base.to_toml() + "\n[coupling]\nq3 = { q2 = 1.0, q3 = 1.0 }\n", "robot.toml")
    model, params = synthetic_model(robot, CHAIN_SPEC, 21)
    lo, hi = np.maximum(robot.lower_deg, -170.0), np.minimum(robot.upper_deg, 170.0)
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(robot, params, CHAIN_SPEC, lo, hi)))
    given = np.array([[10.0, -10.0, 30.0, 20.0, -40.0, 15.0], [-35.0, 20.0, -5.0, -60.0, 50.0, -90.0]])
    pos = []
    for k, q in enumerate(given, 1):
        pos += [f"P[{k}]{{", "   GP1:", "\tUF : 0, UT : 1,\t",
                f"\tJ1= {q[0]:9.3f} deg,\tJ2= {q[1]:9.3f} deg,\tJ3= {q[2]:9.3f} deg,",
                f"\tJ4= {q[3]:9.3f} deg,\tJ5= {q[4]:9.3f} deg,\tJ6= {q[5]:9.3f} deg", "};"]
    lines = ["/PROG  CPL", "/ATTR", "/APPL", "/MN", "   1:J P[1] 100% FINE    ;", "   2:J P[2] 100% FINE    ;",
             "/POS"] + pos + ["/END"]
    (tmp_path / "cpl.ls").write_text("\n".join(lines) + "\n")
    r = cli_invoker()("correct", "--model", tmp_path / "fit.json", "--program", tmp_path / "cpl.ls",
                      "--out", tmp_path / "out")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "out" / "cpl.ls").read_text()
    written = np.array([[float(v) for v in re.findall(r"J\d=\s*(-?[\d.]+) deg", block)]
                        for block in re.findall(r"P\[\d\]\{.*?\};", text, flags=re.S)])
    assert written.shape == (2, 6) and np.abs(written - given).max() > 0.001     # corrected
    kin = ModelKinematics(robot, model)
    meant = kin.nominal(robot.kinematic_angles(given))[1]
    lands = kin.predict(robot.kinematic_angles(written), np.ones((2, 6), int), np.zeros(2), np.full(2, 20.0))
    assert np.abs(lands - meant).max() < 0.02          # mm: the .ls keeps 3 decimals of a degree (~0.01 mm here)
