"""Issue 53: a URDF whose joint 1 turns about -z of the base link (ROS-Industrial's KUKA descriptions,
``joint_a1`` axis ``0 0 -1``) is imported as the same arm with joint 1's angle counted the other way
(robot.toml ``[coupling] q1 = { q1 = -1.0 }``), then fitted, corrected and exported in the URDF's angles.

The fixture tests/data/urdf/kuka_like_a1_minus_z.urdf is SYNTHETIC (kuka_like.urdf with joint 1 about -z
and unequal joint 1 limits); the cell's true robot is hidden (tests/acceptance_cells.py) and read back by
the test alone to judge the result.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pinocchio as pin
import pytest

import acceptance_cells as ac
from pipeline.export.urdf import UrdfProblem, rewrite_urdf
from pipeline.robot.arm.kinematics import build_model, load_robot, positions
from pipeline.robot.campaign.ingest import ingest_robot_with_frame
from pipeline.robot.campaign.urdf import robot_from_urdf

MINUS_Z = ac.URDF_DIR / "kuka_like_a1_minus_z.urdf"
PLUS_Z = ac.URDF_DIR / "kuka_like.urdf"
SMR_MM = (150.0, 40.0, 90.0)
CELL = {"urdf": MINUS_Z.name, "tip": "link_6", "smr_mm": SMR_MM, "flange": "flange", "format": "krl", "coupling": None}


def urdf_smr(text: str, q_deg, tool_mm=SMR_MM) -> np.ndarray:
    """pinocchio's SMR (n, 3) mm in the URDF's root frame at the URDF's own angles (n, 6) deg."""
    T = ac.Truth(text).poses("link_6", q_deg)
    return (T @ np.append(np.asarray(tool_mm, float), 1.0))[:, :3]


def test_a_minus_z_joint_1_is_imported_with_its_angle_taken_as_minus_q1():
    robot, info = robot_from_urdf(MINUS_Z, "link_6", tool_mm=SMR_MM)
    plus, _ = robot_from_urdf(PLUS_Z, "link_6", tool_mm=SMR_MM)
    assert info["joint1_reversed"] and info["fk_max_error_mm"] < 1e-6
    assert robot.coupling == ((0, (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0)),)
    assert "[coupling]" in robot.to_toml() and "q1 = { q1 = -1 }" in robot.to_toml().replace("-1.0", "-1")
    # z up: the arm is the +z one's, joint for joint; joint 1's limits are those of -q1 (URDF -170 .. +150 deg)
    geometry = ("a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg")
    for j, k in zip(robot.joints, plus.joints):
        assert all(getattr(j, f) == getattr(k, f) for f in geometry)
    assert robot.joints[1:] == plus.joints[1:]
    assert (robot.joints[0].lower_deg, robot.joints[0].upper_deg) == pytest.approx((-150.0, 170.0), abs=1e-3)
    # the robot with the recorded (URDF) angles against pinocchio's URDF model, 64 random configurations
    rng = np.random.default_rng(7)
    urdf_lo, urdf_hi = np.array([-170.0, -140, -120, -350, -125, -350]), np.array([150.0, -5, 168, 350, 125, 350])
    Q = rng.uniform(urdf_lo, urdf_hi, (64, 6))
    mine = positions(build_model(robot), np.deg2rad(robot.kinematic_angles(Q)), "smr")
    assert np.abs(mine - urdf_smr(MINUS_Z.read_text(), Q)).max() < 1e-6
    # without the coupling the robot would be another arm for every joint 1 but 0 and 180
    assert np.abs(positions(build_model(plus), np.deg2rad(Q), "smr") - urdf_smr(MINUS_Z.read_text(), Q)).max() > 100.0


def test_a_joint_1_about_another_axis_is_still_refused(tmp_path):
    bad = tmp_path / "tilted.urdf"
    bad.write_text(MINUS_Z.read_text().replace('<axis xyz="0 0 -1"/>', '<axis xyz="0 -1 0"/>', 1))
    from pipeline.core.errors import InputError
    with pytest.raises(InputError, match="joint 1 'joint_1' turns about"):
        robot_from_urdf(bad, "link_6", tool_mm=SMR_MM)


def _source(tmp, q_urdf, recorded, text: str, coupling_toml: str, seed: int = 3):
    """A positions-only export in the base frame of the (nominal) URDF, 10 um noise, and its map."""
    rng = np.random.default_rng(seed)
    P = urdf_smr(text, q_urdf) + rng.normal(0.0, 0.01, (len(q_urdf), 3))
    rows = [",".join([f"P{i}"] + [f"{v:.6f}" for v in recorded[i]] + [f"{v:.4f}" for v in P[i]])
            for i in range(len(q_urdf))]
    src, mp = tmp / "export.csv", tmp / "map.toml"
    src.write_text("\n".join(["id,j1,j2,j3,j4,j5,j6,x,y,z"] + rows) + "\n")
    mp.write_text('[joints]\ncolumns = ["j1", "j2", "j3", "j4", "j5", "j6"]\nunit = "deg"\n' + coupling_toml
                  + '[position]\ncolumns = ["x", "y", "z"]\nunit = "mm"\nframe = "base"\n'
                  '[columns]\npoint_id = "id"\n[split]\nsample_fraction = 0.7\nseed = 1\n')
    return src, mp


@pytest.mark.parametrize("coupling_toml, C_map", [
    ("", np.eye(6)),
    # a FANUC-style J2/J3 interaction on top of the URDF's -z joint 1
    ("coupling = { q3 = { q2 = 1.0, q3 = 1.0 } }\n", np.eye(6) + np.eye(6, k=-1) * (np.arange(6) == 2)[:, None]),
    # a coupling of joint 1 itself: C = C_sign @ C_map and C_map @ C_sign differ here
    ("coupling = { q1 = { q1 = 1.0, q2 = 0.5 } }\n", np.eye(6) + 0.5 * np.eye(6, k=1) * (np.arange(6) == 0)[:, None]),
    # a controller counting joint 1 about +z: the map's -q1 and the URDF's undo each other (no [coupling])
    ("coupling = { q1 = { q1 = -1.0 } }\n", np.diag([-1.0, 1, 1, 1, 1, 1])),
])
def test_import_combines_the_sign_with_the_maps_coupling(invoke, tmp_path, coupling_toml, C_map):
    text = MINUS_Z.read_text()
    q_urdf = ac.arm_angles(text, 60, np.random.default_rng(11))
    recorded = np.linalg.solve(C_map, q_urdf.T).T          # the map: the URDF's angles = C_map @ recorded
    src, mp = _source(tmp_path, q_urdf, recorded, text, coupling_toml)
    camp = tmp_path / "camp"
    r = invoke("import", "--source", src, "--map", mp, "--robot", MINUS_Z, "--tip", "link_6",
               "--tool-mm", *map(str, SMR_MM), "--out", camp)
    assert r.exit_code == 0, r.output
    assert "joint 1 turns about -z in the URDF: its angle is taken as -q1 (a [coupling] row)" in r.output
    rms = float(re.search(r"miss them by ([0-9.]+) mm RMS", r.output).group(1))
    assert rms < 0.05, r.output                               # the noise: the kinematics take the right angles
    robot = load_robot(camp / "robot.toml")
    C_sign = np.diag([-1.0, 1, 1, 1, 1, 1])
    assert np.allclose(robot.coupling_matrix, C_sign @ C_map)
    text = (camp / "robot.toml").read_text()
    assert ("[coupling]" in text) == bool(robot.coupling) and "\n\n\n" not in text
    assert robot.kinematic_angles(recorded) == pytest.approx(q_urdf * [-1, 1, 1, 1, 1, 1], abs=1e-9)


def test_a_plus_z_urdf_gets_no_coupling_and_no_note(invoke, tmp_path):
    text = PLUS_Z.read_text()
    q = ac.arm_angles(text, 40, np.random.default_rng(12))
    src, mp = _source(tmp_path, q, q, text, "")
    r = invoke("import", "--source", src, "--map", mp, "--robot", PLUS_Z, "--tip", "link_6",
               "--tool-mm", *map(str, SMR_MM), "--out", tmp_path / "camp")
    assert r.exit_code == 0, r.output
    assert "-z" not in r.output and not load_robot(tmp_path / "camp" / "robot.toml").coupling


def test_export_keeps_a_minus_z_joint_1_only_for_a_robot_that_takes_minus_q1():
    """rewrite_urdf of the -z URDF with the +z robot's chain (no sign coupling) is refused at joint_1."""
    from pipeline.export.chain import folded_chain
    from pipeline.robot.model.estimator import RobotErrorModel

    plus, _ = robot_from_urdf(PLUS_Z, "link_6", tool_mm=SMR_MM)
    model = RobotErrorModel.from_parameters(plus, [], [])
    chain = folded_chain(plus, model, keep=())
    with pytest.raises(UrdfProblem, match="joint 'joint_1'"):
        rewrite_urdf(MINUS_Z.read_text(), "link_6", chain, [], nominal=chain, tool_mm=SMR_MM)
    out, info = rewrite_urdf(MINUS_Z.read_text(), "link_6", chain, [], nominal=chain, tool_mm=SMR_MM,
                             joint1_reversed=True)
    assert '<axis xyz="0 0 -1"/>' in out and info["moved_mm"] < 1e-9 and info["turned_arcsec"] < 1e-6


def test_a_minus_z_cell_is_fitted_corrected_and_exported_in_the_urdfs_angles(invoke, tmp_path, monkeypatch):
    """The whole job on a simulated cell of the -z URDF (a 3-SMR nest, the tracker's frame): the recorded
    angles are the URDF's throughout, the exported URDF keeps joint 1 about -z, and every link frame of it
    is where the truth's is."""
    monkeypatch.setitem(ac.CELLS, "kuka_a1_minus_z", CELL)
    seed = 21
    nominal_text = MINUS_Z.read_text()
    truth, _, camp, fit_path, cal = ac.simulate_and_fit(invoke, "kuka_a1_minus_z", tmp_path, 100, seed)
    robot = load_robot(camp / "robot.toml")
    assert robot.coupling_matrix[0, 0] == -1.0
    fit = json.loads(fit_path.read_text())
    assert fit["heldout"]["rms_after_mm"] < 0.05 < 1.0 < fit["heldout"]["rms_before_mm"], fit["heldout"]
    _, _, info = ingest_robot_with_frame(camp)
    t2b = np.array(info["tracker_to_base"])
    # export: joint 1's axis as the user wrote it; every link frame where the truth's is (the flange within
    # 0.1 mm / 0.01 deg), and where the nominal's is but for the calibration's amounts, at the URDF's angles
    cal_text = cal.read_text()
    j1 = re.search(r'<joint name="joint_1".*?</joint>', cal_text, re.S).group(0)
    assert '<axis xyz="0 0 -1"/>' in j1
    Qc = ac.arm_angles(nominal_text, 200, np.random.default_rng(seed + 3))
    exported, nom = ac.Truth(cal_text), ac.Truth(nominal_text)
    mm, deg = ac.apart(ac.in_tracker(truth.poses("flange", Qc)), np.linalg.inv(t2b) @ exported.poses("flange", Qc))
    mm0, _ = ac.apart(ac.in_tracker(truth.poses("flange", Qc)), np.linalg.inv(t2b) @ nom.poses("flange", Qc))
    assert mm0.max() > 1.0 and mm.max() < 0.1 and deg.max() < 0.01, (mm0.max(), mm.max(), deg.max())
    links = [f.name for f in nom.model.frames if f.type == pin.FrameType.BODY]
    for name in links:
        d_mm, d_deg = ac.apart(exported.poses(name, Qc[:20]), nom.poses(name, Qc[:20]))
        assert d_mm.max() < 5.0 and d_deg.max() < 0.2, (name, d_mm.max(), d_deg.max())
    # correct: targets in the controller's (the URDF's) angles, inside the fitted range; the corrected commands
    # come back in the same angles and land the true robot's SMR where the nominal robot meant it
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    inside = np.all((robot.kinematic_angles(Qc) >= lo + 2.0) & (robot.kinematic_angles(Qc) <= hi - 2.0), axis=1)
    Qt = Qc[inside][:20]
    assert len(Qt) >= 10
    targets = tmp_path / "targets.csv"
    targets.write_text("point_id,q1,q2,q3,q4,q5,q6\n" + "".join(
        f"T{k}," + ",".join(f"{v:.6f}" for v in q) + "\n" for k, q in enumerate(Qt)))
    out = tmp_path / "corrected.csv"
    r = invoke("correct", "--model", fit_path, "--targets", targets, "--out", out, "--max-correction-deg", "1")
    assert r.exit_code == 0, r.output
    import pandas as pd
    res = pd.read_csv(out, comment="#")
    ok = (res["status"] == "ok").to_numpy()
    assert ok.sum() >= 0.9 * len(Qt), res[["status"]].value_counts()
    Qcor = res[[f"q{j}" for j in range(1, 7)]].to_numpy(float)
    assert np.abs(Qcor - Qt)[:, 0].max() < 0.5              # joint 1 corrected by tenths of a degree, not turned round
    s1 = np.append(np.array(SMR_MM), 1.0)
    meant = urdf_smr(nominal_text, Qt)                       # the nominal URDF's base frame is the campaign's

    def landed(q):
        return (t2b @ ac.in_tracker(truth.poses("link_6", q)) @ s1)[:, :3]

    given = np.linalg.norm(landed(Qt) - meant, axis=1)[ok]
    corrected = np.linalg.norm(landed(Qcor) - meant, axis=1)[ok]
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))   # noqa: E731

    assert rms(given) > 0.5, rms(given)
    assert rms(corrected) <= 1.25 * fit["heldout"]["rms_after_mm"] + 0.005, (rms(given), rms(corrected))


def test_a_krl_program_for_a_minus_z_arm_is_corrected_with_its_turns_in_the_controllers_angles(invoke, tmp_path,
                                                                                                 monkeypatch):
    """KUKA's T names the signs of the controller's angles (A1 = the URDF's q1 here, -1 x the kinematics'):
    a program written for the nominal robot, corrected, lands the true robot's SMR where it meant it."""
    from dataclasses import replace

    from pipeline.programs import ik
    from pipeline.programs.filtering import play
    from pipeline.programs.io import read_program

    monkeypatch.setitem(ac.CELLS, "kuka_a1_minus_z", CELL)
    seed = 31
    nominal_text = MINUS_Z.read_text()
    truth, _, camp, fit_path, _ = ac.simulate_and_fit(invoke, "kuka_a1_minus_z", tmp_path, 100, seed,
                                                      export_urdf=False)
    robot = load_robot(camp / "robot.toml")
    fit = json.loads(fit_path.read_text())
    _, _, info = ingest_robot_with_frame(camp)
    t2b = np.array(info["tracker_to_base"])
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    Qc = ac.arm_angles(nominal_text, 200, np.random.default_rng(seed + 3))
    Qk = robot.kinematic_angles(Qc)
    Qp = Qc[np.all((Qk >= lo + 2.0) & (Qk <= hi - 2.0), axis=1)][:24]
    # the program in the controller's angles (the URDF's): poses of the nominal URDF, T from their signs
    prog = ac.program("kuka_a1_minus_z", ac.Truth(nominal_text), replace(robot, coupling=()), Qp, tmp_path)
    r = invoke("correct", "--model", fit_path, "--program", prog, "--out", tmp_path / "filtered",
               "--max-correction-deg", "1", "--json", tmp_path / "filtered.json")
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "filtered.json").read_text())["targets"]
    ok = np.array([t["status"] == "ok" for t in rows])
    assert ok.sum() >= 0.9 * len(rows), [(t["line"], t["status"], t.get("reason")) for t in rows if t["status"] != "ok"]
    a, b = play(read_program(prog), robot), play(read_program(tmp_path / "filtered" / prog.name), robot)
    keep = [k for k in range(len(a.reason)) if not a.reason[k] and not b.reason[k] and ok[k]]
    assert robot.recorded_angles(a.q_deg[keep]) == pytest.approx(Qp[keep], abs=1e-3)   # played as written
    meant = (ik.flange(ik.chain_of(robot), np.deg2rad(a.q_deg[keep])) @ np.append(robot.tool_xyz_mm, 1.0))[:, :3]
    s1 = np.append(np.array(SMR_MM), 1.0)

    def landed(q_kinematic):
        return (t2b @ ac.in_tracker(truth.poses("link_6", robot.recorded_angles(q_kinematic))) @ s1)[:, :3]

    given = np.linalg.norm(landed(a.q_deg[keep]) - meant, axis=1)
    filtered = np.linalg.norm(landed(b.q_deg[keep]) - meant, axis=1)
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))   # noqa: E731
    assert rms(given) > 0.5, rms(given)
    assert rms(filtered) <= 1.25 * fit["heldout"]["rms_after_mm"] + 0.005, (rms(given), rms(filtered))
