"""Robot programs through the model (contract section 11): conventions, IK branches, byte-for-byte
rewriting, bad programs, and the filtered programs measured on virtual cells."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from conftest import ROOT, cli_invoker
from pipeline.programs import conventions as cv
from pipeline.programs import ik
from pipeline.robot.arm.kinematics import build_model, load_robot, placements

DATA = ROOT / "tests/data/programs"
KR210 = ROOT / "raw/robot/kr210/robot.toml"
UR10 = ROOT / "raw/real/ur10-ipa/robot.toml"
SPEC = """[model]
kind = "robot"
[[effect]]
name = "geometry"
[[effect]]
name = "base"
[[effect]]
name = "tool"
[[effect]]
name = "compliance"
joints = [2, 3]
[[effect]]
name = "backlash"
[[effect]]
name = "joint_harmonic"
joints = [1, 2, 3, 4, 5, 6]
orders = [1, 2, 3]
"""
FANUC_TOOL = "-60 -40 120 10 -20 -150"  # the samples' UTOOL[1] on the KR210 in FANUC's faceplate frame (sample.ls)
KUKA_TOOL = "120 40 -60 53.947611268 54.468652237 69.357657952"   # sample.src's $TOOL, in KUKA's $FLANGE


# ------------------------------------------------------------------------------ conventions
def test_rotations_match_an_independent_formula():
    rng = np.random.default_rng(0)
    for a, b, c in rng.uniform(-180, 180, (20, 3)) * [1, 0.49, 1]:
        R = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()       # intrinsic Z-Y'-X''
        assert np.allclose(cv.kuka_matrix(a, b, c), R, atol=1e-12)
        assert np.allclose(cv.kuka_abc(R), (a, b, c), atol=1e-9)
        Rf = Rotation.from_euler("xyz", [a, b, c], degrees=True).as_matrix()      # fixed axes x, y, z
        assert np.allclose(cv.fanuc_matrix(a, b, c), Rf, atol=1e-12)
        assert np.allclose(cv.fanuc_wpr(Rf), (a, b, c), atol=1e-9)
    for q in rng.normal(size=(20, 4)):
        q /= np.linalg.norm(q)
        R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()              # scalar last in scipy
        assert np.allclose(cv.abb_matrix(*q), R, atol=1e-12)
        assert np.allclose(cv.abb_quaternion(R, q), q, atol=1e-12)
        v = Rotation.from_matrix(R).as_rotvec()
        assert np.allclose(cv.ur_matrix(*v), R, atol=1e-12)
        assert np.allclose(cv.ur_rotvec(R), v, atol=1e-9)
    # the other Euler solution, the quaternion's other hemisphere, a rotation vector past pi: kept
    assert np.allclose(cv.kuka_abc(cv.kuka_matrix(10, 20, 30), (190, 160, 210)), (190, 160, 210))
    assert np.allclose(cv.abb_quaternion(cv.abb_matrix(0.5, 0.5, 0.5, 0.5), (-0.5, -0.5, -0.5, -0.5)), [-0.5] * 4)
    v = np.array([0.0, 0.0, 3.5])
    assert np.allclose(cv.ur_rotvec(cv.ur_matrix(*v), v), v)


def test_configuration_data():
    assert cv.kuka_status(False, False, False) == 2 and cv.kuka_status(True, True, True) == 5
    assert cv.kuka_status(False, False, True) == 6                       # the S 6 of public .dat files
    assert cv.kuka_status_flags(2 + 8) == (False, False, False)           # bits 3 and up ignored
    assert cv.kuka_turn([-1, 2, -3, 4, 5, -6]) == 0b100101
    assert cv.abb_quadrants([-10, 0, 0, 95, 0, -180]) == (-1, 1, -2)
    assert cv.abb_cfx(True, False, True) == 5 and cv.abb_cfx_flags(6) == (True, True, False)
    assert cv.fanuc_letters(False, False, True) == "N U T" and cv.fanuc_letter_flags("F D B") == (True, True, False)
    assert [cv.fanuc_turn(v) for v in (-180, -179, 180, 181, 540, 541)] == [-1, 0, 0, 1, 1, 2]
    with pytest.raises(ValueError):
        cv.fanuc_letter_flags("N U")


# ------------------------------------------------------------------------------ kinematics
@pytest.mark.parametrize("path", [KR210, UR10])
def test_forward_kinematics_is_pinocchios(path):
    robot = load_robot(path)
    Q = np.random.default_rng(1).uniform(-np.pi, np.pi, (6, 6))
    F = ik.flange(ik.chain_of(robot), Q)
    R, P = placements(build_model(robot), Q, "flange")
    assert np.abs(F[:, :3, 3] - P).max() < 1e-9 and np.abs(F[:, :3, :3] - R).max() < 1e-12


@pytest.mark.parametrize("path", [KR210, UR10])
def test_every_branch_is_found(path):
    """Poses of random joint values: the numerical IK finds the 8 solutions, each on the pose, the joint
    values the pose came from among them; on the KR210 one per branch flags (the UR10's offset wrist
    shares flags between solutions: its moves take the one nearest the point before)."""
    robot = load_robot(path)
    chain = ik.chain_of(robot)
    Q = np.random.default_rng(3).uniform(-np.pi, np.pi, (12, 6))
    sols = ik.solve_all(chain, ik.flange(chain, Q), extra=48)
    eight = 0
    for q, s in zip(Q, sols):
        assert np.min(np.abs(ik.wrap(s - q)).max(axis=1)) < 1e-6
        F = ik.flange(chain, s)
        assert np.abs(F - ik.flange(chain, q[None])).max() < 1e-6
        flags = {tuple(f) for f in ik.flags_from_frames(ik.frames(chain, s))}
        if path == KR210:                              # a spherical wrist: one solution per branch flags
            assert len(flags) == len(s)
        eight += len(s) == 8
    assert eight >= 6


# ------------------------------------------------------------------------------ the loop
@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    """KR210 and UR10 cells (hidden joint harmonic), measured open loop, and a model of each."""
    tmp = tmp_path_factory.mktemp("programs")
    run = cli_invoker()
    (tmp / "spec.toml").write_text(SPEC)
    out = {"tmp": tmp, "run": run}
    for name, robot, extra in (("kr210", KR210, []), ("ur10", UR10, ["--robot", UR10])):
        cell = tmp / name
        cell.mkdir()
        shutil.copy(robot, cell / "robot.toml")
        r = run("simulate", "robot", "--campaign", cell, "--truth", tmp / f"{name}.json", "--seed", "3",
                "--hidden", "joint_harmonic:2", *extra)
        assert r.exit_code == 0, r.output
        poses = pd.read_csv(cell / "poses.csv")
        poses[poses["set"] != "repeat"][["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg"]].to_csv(
            tmp / f"{name}_poses.csv", index=False)
        r = run("simulate", "measure", "--truth", tmp / f"{name}.json", "--poses", tmp / f"{name}_poses.csv",
                "--campaign", tmp / f"{name}_meas")
        assert r.exit_code == 0, r.output
        r = run("fit", "--campaign", tmp / f"{name}_meas", "--spec", tmp / "spec.toml", "--out", tmp / f"{name}_fit.json")
        assert r.exit_code == 0, r.output
        fit = json.loads((tmp / f"{name}_fit.json").read_text())
        ident = dict(fit, parameters=[dict(p, value=0.0) for p in fit["parameters"]])
        (tmp / f"{name}_identity.json").write_text(json.dumps(ident))
        out[name] = {"fit": fit, "payload": float(poses["payload_kg"].iloc[0])}
    return out


def _skeleton(text):
    return re.sub(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", "#", text)


SAMPLES = [("sample.src", "kr210", []), ("sample.mod", "kr210", []), ("sample.ls", "kr210", ["--tool", FANUC_TOOL]),
           ("sample.script", "ur10", [])]


@pytest.mark.parametrize("name,cell,extra", SAMPLES)
def test_identity_model_changes_no_byte(cells, tmp_path, name, cell, extra):
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    r = cells["run"]("correct", "--model", cells["tmp"] / f"{cell}_identity.json", "--program", src / name,
                     "--out", tmp_path / "out", *extra)
    assert r.exit_code == 0, r.output
    for f in (tmp_path / "out").iterdir():
        assert f.read_bytes() == (src / f.name).read_bytes(), f.name


@pytest.mark.parametrize("name,cell,extra", SAMPLES)
def test_only_target_numbers_change(cells, tmp_path, name, cell, extra):
    """A fitted model: numbers change, each with its decimals; every other byte stays; run-time targets are named."""
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    r = cells["run"]("correct", "--model", cells["tmp"] / f"{cell}_fit.json", "--program", src / name, "--out",
                     tmp_path / "out", "--payload", cells[cell]["payload"], "--max-correction-deg", "2",
                     "--json", tmp_path / "r.json", *extra)
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["counts"]["ok"] >= 6 and "run_time" in rep["counts"]
    assert "left as given" in r.output
    changed = 0
    for f in (tmp_path / "out").iterdir():
        a, b = (src / f.name).read_bytes().decode("latin-1"), f.read_bytes().decode("latin-1")
        assert _skeleton(a).replace(" ", "") == _skeleton(b).replace(" ", "")
        if f.suffix != ".ls":
            assert _skeleton(a) == _skeleton(b)
        na = re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", a)
        nb = re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", b)
        for x, y in zip(na, nb):
            if x != y:
                changed += 1
                assert len(x.split(".")[-1]) == len(y.split(".")[-1]) and x.startswith(".") == y.startswith(".")
    assert changed > 20
    if name == "sample.src":
        assert b"\r\n" in (tmp_path / "out/sample.src").read_bytes() and b"Schwei\xdf" in (
            tmp_path / "out/sample.src").read_bytes()


def _intended(robot_path, program, extra):
    from pipeline.programs.filtering import play
    from pipeline.programs.io import read_program

    robot = load_robot(robot_path)
    tool = [float(v) for v in extra[1].split()] if extra else None
    pl = play(read_program(program), robot, tool)
    q = pl.q_deg[[k for k, r in enumerate(pl.reason) if not r]]
    F = ik.flange(ik.chain_of(robot), np.deg2rad(q))
    return (F @ np.append(robot.tool_xyz_mm, 1.0))[:, :3]


@pytest.mark.parametrize("fmt", ["krl", "rapid", "fanuc", "ur"])
def test_filtered_program_lands_on_the_model(cells, tmp_path, fmt):
    """32 targets (joint and Cartesian, PTP and linear) of a fresh program per format: as given, the
    robot lands at its uncorrected error; filtered, within 1.25 x the model's held-out RMS + 5 um."""
    import program_samples as ps
    from pipeline.robot.cell.simulate import cell_config, draw_poses

    cell = "ur10" if fmt == "ur" else "kr210"
    robot_path = UR10 if fmt == "ur" else KR210
    robot = load_robot(robot_path)
    fit = cells[cell]["fit"]
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    cfg = cell_config(robot, paper=fmt != "ur")
    Q = draw_poses(robot, 1500, np.random.default_rng(5), cfg["box_mm"], cfg["orientation_deg"])
    Q = Q[np.all((Q >= lo + 0.5) & (Q <= hi - 0.5), axis=1)]
    Q = ps.smooth_path(robot, Q, 32) if fmt == "ur" else Q[:32]
    extra = []
    if fmt == "krl":
        s, d = ps.krl(robot, Q, "prog")
        (tmp_path / "prog.src").write_bytes(s.encode()), (tmp_path / "prog.dat").write_bytes(d.encode())
        prog = tmp_path / "prog.src"
    else:
        prog = tmp_path / {"rapid": "prog.mod", "fanuc": "prog.ls", "ur": "prog.script"}[fmt]
        prog.write_text({"rapid": ps.rapid, "fanuc": ps.fanuc, "ur": ps.urscript}[fmt](robot, Q, "prog"))
        extra = ["--tool", "60 40 120 10 -20 30"] if fmt == "fanuc" else []    # program_samples.fanuc's UTOOL[1]
    run = cells["run"]
    payload = ["--payload", cells[cell]["payload"]]
    # one UR10 target needs 0.56 deg of joint 5 (the default limit 0.5 deg would leave it as given, at its
    # uncorrected error); before the orientation was held only where determined (issue 22) it needed 2.3 deg
    r = run("correct", "--model", cells["tmp"] / f"{cell}_fit.json", "--program", prog, "--out", tmp_path / "out",
            "--max-correction-deg", "1", *payload, *extra)
    assert r.exit_code == 0, r.output
    intended = _intended(robot_path, prog, extra)
    assert len(intended) == 32
    rms = {}
    for label, p in (("given", prog), ("filtered", tmp_path / "out" / prog.name)):
        r = run("simulate", "measure", "--truth", cells["tmp"] / f"{cell}.json", "--program", p, "--campaign",
                tmp_path / label, *payload, *extra)
        assert r.exit_code == 0, r.output
        xyz = pd.read_csv(tmp_path / label / "tracker.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy()
        rms[label] = float(np.sqrt(np.mean(np.sum((xyz - intended) ** 2, axis=1))))
    heldout = fit["heldout"]["rms_after_mm"]
    before = fit["heldout"]["rms_before_mm"]
    assert rms["filtered"] <= 1.25 * heldout + 0.005, (rms, heldout)
    assert 0.5 * before < rms["given"] < 2.0 * before, (rms, before)


# ------------------------------------------------------------------------------ bad programs
BAD = [
    ("sample.src", "PTP XP1\r\n", "SPLINE\r\nPTP XP1\r\n", "SPLINE without ENDSPLINE"),
    ("sample.src", "$BASE = {X 100.0,Y -50.0,Z 20.0,A 5.0,B 0.0,C 0.0}", "BAS(#BASE, 3)", "give it with --base"),
    ("sample.dat", "DECL E6POS XP1={X", "DECL E6POS XP1={{X", "unbalanced"),
    ("sample.dat", "ENDDAT", ";ENDDAT", "DEFDAT without ENDDAT"),
    ("sample.mod", "tSMR \\WObj:=wCell;  ! to p2", "tSMR \\WObj:=wCell  ! to p2", "statement without its ';'"),
    ("sample.mod", "tSMR \\WObj:=wCell;  ! to p1", "tOther \\WObj:=wCell;  ! to p1", "tool tOther"),
    ("sample.ls", "/END", "/ENX", "no /END"),
    ("sample.ls", "   3:  !hand-written sample ;", "   3:  !hand-written sample", "not an /MN instruction"),
    ("sample.script", "  set_tcp(", "  if True:\n  set_tcp(", "block without its 'end'"),
    ("sample.script", "a=1.4, v=1.05)\n", "a=1.4, v=1.05\n", "unbalanced"),
]


@pytest.mark.parametrize("file,old,new,message", BAD)
def test_bad_program_is_refused_with_its_line(cells, tmp_path, file, old, new, message):
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    text = (src / file).read_bytes().decode("latin-1")
    assert old in text
    (src / file).write_bytes(text.replace(old, new, 1).encode("latin-1"))
    prog = src / (file.replace(".dat", ".src"))
    cell = "ur10" if file.endswith(".script") else "kr210"
    extra = ["--tool", FANUC_TOOL] if file.endswith(".ls") else []
    r = cells["run"]("correct", "--model", cells["tmp"] / f"{cell}_fit.json", "--program", prog, "--out",
                     tmp_path / "out", *extra)
    assert r.exit_code == 2, r.output
    line = [s for s in r.output.splitlines() if s.startswith("jointcal: error:")]
    assert len(line) == 1 and message in line[0] and re.search(r":\d+:", line[0]), r.output
    assert "Traceback" not in r.output
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_unreachable_target_is_named_and_left_as_given(cells, tmp_path):
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    text = (src / "sample.dat").read_bytes().decode("latin-1")
    m = re.search(r"DECL E6POS (XP\d+)=\{X ([-\d.]+)", text)
    text = text.replace(f"{{X {m.group(2)}", "{X 9000.0", 1)
    (src / "sample.dat").write_bytes(text.encode("latin-1"))
    r = cells["run"]("correct", "--model", cells["tmp"] / "kr210_fit.json", "--program", src / "sample.src", "--out",
                     tmp_path / "out", "--json", tmp_path / "r.json")
    assert r.exit_code == 0, r.output
    rows = [t for t in json.loads((tmp_path / "r.json").read_text())["targets"] if t["name"] == m.group(1)]
    assert rows[0]["status"] == "no_ik_solution" and f"{m.group(1)} (cartesian) left as given" in r.output
    assert "X 9000.0," in (tmp_path / "out/sample.dat").read_text(encoding="latin-1")


def test_decisions_on_unconfirmed_conventions():
    """KR210 (q5 = 0 is its wrist singularity): the middle of its ranges is front, elbow up, no flip;
    q5 < 0 is flip (KUKA S bit 2, ABB cfx bit 0, FANUC N); FANUC turns are those of joints 1, 4, 6."""
    chain = ik.chain_of(load_robot(KR210))
    mid = np.array([0.0, -90.0, 95.0, 0.0, 85.0, -10.0])
    assert ik.arm_flags(chain, mid[None]).tolist() == [[False, False, False]]
    assert ik.arm_flags(chain, (mid * [1, 1, 1, 1, -1, 1])[None]).tolist() == [[False, False, True]]
    assert cv.fanuc_turns([190, 0, 0, -190, 0, 370]) == (1, -1, 1) and cv.fanuc_turns([0, 400, 400, 0, 0, 0]) == (0, 0, 0)


def test_ptp_goes_to_the_branch_its_configuration_names(tmp_path):
    """A KR210 with full joint ranges: the same pose at S 2 and S 6 (flip) gives the two wrist
    solutions; T picks the turn; a LIN after it keeps the branch of the point before."""
    from pipeline.programs.filtering import play
    from pipeline.programs.flanges import vendor_flange
    from pipeline.programs.io import read_program

    robot = load_robot(KR210)
    for i in range(6):
        robot = robot.replace_joint(i, lower_deg=-350.0, upper_deg=350.0)
    chain = ik.chain_of(robot)
    q = np.array([10.0, -95.0, 100.0, 20.0, 70.0, 30.0])
    qf = q + [0, 0, 0, 180, 0, 180]
    qf[4] = -q[4]
    T = ik.flange(chain, np.deg2rad(q[None]))[0]
    assert np.allclose(ik.flange(chain, np.deg2rad(qf[None]))[0], T, atol=1e-9)
    T = T @ vendor_flange(robot, "krl").pose          # KUKA's $FLANGE (the null tool's TCP)
    a, b, c = cv.kuka_abc(T[:3, :3])
    pos = f"X {T[0, 3]:.6f},Y {T[1, 3]:.6f},Z {T[2, 3]:.6f},A {a:.7f},B {b:.7f},C {c:.7f}"
    t_flip = cv.kuka_turn(qf)
    (tmp_path / "p.src").write_text("DEF p( )\n$TOOL = {X 0,Y 0,Z 0,A 0,B 0,C 0}\nBAS(#BASE, 0)\n"
                                    f"PTP {{{pos},S 2,T {cv.kuka_turn(q)}}}\nPTP {{{pos},S 6,T {t_flip}}}\n"
                                    f"LIN {{{pos},S 2,T 0}}\nPTP {{{pos},S 6,T {t_flip ^ 8}}}\nEND\n")
    pl = play(read_program(tmp_path / "p.src"), robot)
    assert np.allclose(pl.q_deg[0], q, atol=1e-6)
    assert np.allclose(pl.q_deg[1], qf, atol=1e-6)
    assert np.allclose(pl.q_deg[2], qf, atol=1e-6)         # LIN: the branch of the point before, S ignored
    assert np.allclose(pl.q_deg[3], qf - [0, 0, 0, 360, 0, 0], atol=1e-6)   # T bit 3: joint 4 negative


def test_kss8_inline_form_fanuc_continuation_and_names_from_elsewhere(cells, tmp_path):
    """KSS 8 ``SPTP ... WITH $TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO)`` takes FP1's tool and base
    numbers (here TOOL_DATA[1], BASE_DATA[1]: --tool, --base); ``PTP XHOME`` of $config.dat is named and
    left as given; a FANUC instruction continued on a ':' line is read whole (its Offset option seen)."""
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    s = (src / "sample.src").read_bytes().decode("latin-1")
    s = s.replace("PTP XP1\r\n", "SPTP XP1 WITH $TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO), $APO = "
                  "SAPO_PTP(PPDAT1)\r\nPTP XHOME\r\n", 1)
    s = s.replace("$TOOL = {X 120.0,Y 40.0,Z -60.0,A 53.947611268,B 54.468652237,C 69.357657952}", "BAS(#TOOL, 1)")
    s = s.replace("$BASE = {X 100.0,Y -50.0,Z 20.0,A 5.0,B 0.0,C 0.0}", "BAS(#BASE, 1)")
    (src / "sample.src").write_bytes(s.encode("latin-1"))
    d = (src / "sample.dat").read_bytes().decode("latin-1")
    d = d.replace("ENDDAT", "DECL FDAT FP1={TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE,POINT2[] \" \",TQ_STATE FALSE}\r\n"
                  "ENDDAT")
    (src / "sample.dat").write_bytes(d.encode("latin-1"))
    run = cells["run"]
    model = cells["tmp"] / "kr210_identity.json"
    r = run("correct", "--model", model, "--program", src / "sample.src", "--out", tmp_path / "o1")
    assert r.exit_code == 2 and "give it with --tool" in r.output
    r = run("correct", "--model", model, "--program", src / "sample.src", "--out", tmp_path / "o2", "--tool",
            KUKA_TOOL, "--base", "100 -50 20 5 0 0", "--json", tmp_path / "r.json")
    assert r.exit_code == 0, r.output
    rows = {t["name"]: t for t in json.loads((tmp_path / "r.json").read_text())["targets"]}
    assert rows["XP1"]["status"] == "ok" and rows["XHOME"]["status"] == "run_time"
    assert "declared outside the program" in rows["XHOME"]["reason"]
    for f in ("sample.src", "sample.dat"):
        assert (tmp_path / "o2" / f).read_bytes() == (src / f).read_bytes()
    ls = (src / "sample.ls").read_text()
    first = re.search(r"(?m)^(\s*\d+:J P\[1\] 100% CNT50)(\s*;)$", ls)
    (src / "sample.ls").write_text(ls.replace(first.group(0), first.group(1) + "\n    :  Offset,PR[3]" + first.group(2)))
    r = run("correct", "--model", model, "--program", src / "sample.ls", "--out", tmp_path / "o3", "--tool", FANUC_TOOL,
            "--json", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "f.json").read_text())["targets"]
    assert rows[0]["name"] == "P[1]" and rows[0]["status"] == "run_time" and "Offset" in rows[0]["reason"]


# ------------------------------------------------------------------------------ programs as users have them
def _numbers_of(path):
    return re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", path.read_bytes().decode("latin-1"))


def _correct(cells, tmp_path, model, program, out, *extra, json_name=None):
    args = ["correct", "--model", cells["tmp"] / model, "--program", program, "--out", tmp_path / out, *extra]
    if json_name:
        args += ["--json", tmp_path / json_name]
    r = cells["run"](*args)
    rows = json.loads((tmp_path / json_name).read_text())["targets"] if json_name and r.exit_code == 0 else []
    return r, {(t["name"], t["line"]): t for t in rows}


@pytest.mark.parametrize("cell", ["kr210_identity.json", "kr210_fit.json"])
def test_byte_order_marks_and_utf16_are_read_and_kept(cells, tmp_path, cell):
    """A KRL .src with a UTF-8 byte-order mark (refused before: 'END without DEF') and a RAPID module in
    UTF-16 with its mark: read, filtered like the same program without them, the mark and codec kept."""
    src = tmp_path / "in"
    shutil.copytree(DATA, src)
    (src / "bom").mkdir()
    for f in ("sample.src", "sample.dat"):
        (src / "bom" / f).write_bytes(b"\xef\xbb\xbf" + (src / f).read_bytes())
    (src / "u16").mkdir()
    (src / "u16/sample.mod").write_bytes((src / "sample.mod").read_bytes().decode("latin-1").encode("utf-16"))
    pay = ["--payload", cells["kr210"]["payload"]]
    for prog, plain in ((src / "bom/sample.src", src / "sample.src"), (src / "u16/sample.mod", src / "sample.mod")):
        r, rows = _correct(cells, tmp_path, cell, prog, "o_" + prog.parent.name, *pay, json_name="r.json")
        assert r.exit_code == 0, r.output
        assert sum(t["status"] == "ok" for t in rows.values()) >= 6
        r0, _ = _correct(cells, tmp_path, cell, plain, "o_plain_" + prog.parent.name, *pay)
        assert r0.exit_code == 0, r0.output
        for f in (tmp_path / ("o_plain_" + prog.parent.name)).iterdir():
            got = (tmp_path / ("o_" + prog.parent.name) / f.name).read_bytes()
            if prog.suffix == ".mod":
                assert got.startswith(b"\xff\xfe") and got.decode("utf-16").encode("latin-1") == f.read_bytes()
            else:
                assert got == b"\xef\xbb\xbf" + f.read_bytes()
            if cell == "kr210_identity.json":
                assert got == (prog.parent / f.name).read_bytes()


RAPID_DATA = """%%%
  VERSION:1
  LANGUAGE:ENGLISH
%%%
MODULE CellData(SYSMODULE)
  ! the cell's data, in a system module of its own
"""
RAPID_MAIN = """MODULE Main
  PROC main()
    ConfJ \\On;
    moveToStart;
    MoveAbsJ j0,v1000,z50,tSMR;
    MoveJ p1, v500, fine, tSMR \\WObj:=wCell;  ! to p1
    IF diReady = 1 THEN
      TriggL p2, v500, gunOn, fine, tSMR \\WObj:=wCell;
    ENDIF
    IF diFast = 1 MoveL p3, v500, fine, tSMR \\WObj:=wCell;
    SearchL \\Stop, diTouch, pHit, p6, v100, tSMR \\WObj:=wCell;
    goThrough p7,
      v500;
    MoveL pNowhere, v500, fine, tSMR \\WObj:=wCell;
  ENDPROC

  PROC goThrough(
      PERS robtarget pVia,
      speeddata sp)
    MoveL pVia, sp, fine, tSMR \\WObj:=wCell;
  ENDPROC

  PROC moveToStart()
    MoveAbsJ j4,v1000,z50,tSMR;
  ENDPROC
ENDMODULE
"""


def _rapid_modules(folder):
    """sample.mod split as a controller holds it: its data in a .sys (each robtarget over three lines, a
    comment between them), the motions in a .prg with procedure headers over several lines, calls,
    TriggL, a compact IF, SearchL and a target declared nowhere."""
    text = (DATA / "sample.mod").read_text(encoding="latin-1")
    decls = re.findall(r"(?m)^  ((?:CONST|PERS|TASK PERS) \w+ \w+:=.*;)$", text)
    split = [re.sub(r"\],\[", "],  ! next group\n      [", d, count=2) if " robtarget " in d else d for d in decls]
    folder.mkdir()
    (folder / "CellData.sys").write_text(RAPID_DATA + "".join(f"  {d}\n" for d in split) + "ENDMODULE\n")
    (folder / "Main.prg").write_text(RAPID_MAIN)
    return folder


def test_rapid_program_of_several_modules(cells, tmp_path):
    """A RAPID program whose targets, tool and work object are declared in another module: read as a
    folder, every declared target reached by a motion is filtered - to the numbers the single-module
    sample gets - and the rest is named: SearchL, a name declared nowhere, a call passed through."""
    prog = _rapid_modules(tmp_path / "cell")
    r, rows = _correct(cells, tmp_path, "kr210_fit.json", prog, "out", "--max-correction-deg", "2", json_name="r.json")
    assert r.exit_code == 0, r.output
    status = {name: t["status"] for (name, _), t in rows.items()}
    for name in ("j0", "p1", "p2", "p3", "j4"):
        assert status[name] == "ok", (name, rows)
    for name in ("SearchL@11", "pNowhere", "pVia", "p6", "p7"):      # p6, p7: declared, reached by no motion read
        assert status[name] == "run_time", (name, rows)
    reason = {name: t["reason"] for (name, _), t in rows.items()}
    assert "declared in none" in reason["pNowhere"] and "declared in none" in reason["pVia"]
    assert "no motion the filter reads" in reason["p7"]
    assert all(t["payload_kg"] == 60 and "tooldata tSMR" in t["payload_source"] for t in rows.values()
               if t["status"] == "ok")
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == ["CellData.sys", "Main.prg"]
    assert (tmp_path / "out/Main.prg").read_bytes() == (prog / "Main.prg").read_bytes()
    # the same targets in the one-module sample: the same new numbers
    r1, _ = _correct(cells, tmp_path, "kr210_fit.json", DATA / "sample.mod", "one", "--max-correction-deg", "2")
    assert r1.exit_code == 0, r1.output
    one = (tmp_path / "one/sample.mod").read_text(encoding="latin-1")
    got = (tmp_path / "out/CellData.sys").read_text(encoding="latin-1")
    for name in ("j0", "p1", "p2", "p3", "j4"):
        a = re.search(rf"{name}:=(\[.*?\]);", one, re.DOTALL).group(1)
        b = re.search(rf"{name}:=(\[.*?\]);", got, re.DOTALL).group(1)
        assert re.sub(r"!.*|\s", "", b) == a.replace(" ", ""), name
    # one module alone: the targets of the other are named, never a refusal
    r2, rows2 = _correct(cells, tmp_path, "kr210_fit.json", prog / "Main.prg", "alone", "--tool", "0 0 0 1 0 0 0",
                         "--base", "0 0 0 1 0 0 0", json_name="r2.json")
    assert r2.exit_code == 0, r2.output
    assert all(t["status"] == "run_time" for t in rows2.values())
    assert (tmp_path / "alone/Main.prg").read_bytes() == (prog / "Main.prg").read_bytes()


def test_a_folder_is_written_all_or_none(cells, tmp_path):
    prog = _rapid_modules(tmp_path / "cell")
    (prog / "Broken.mod").write_text("MODULE Broken\n  PROC x()\n    MoveL p1, v500, fine, tSMR\n  ENDPROC\nENDMODULE\n")
    r, _ = _correct(cells, tmp_path, "kr210_fit.json", prog, "out")
    assert r.exit_code == 2 and "Broken.mod:3:" in r.output and "without its ';'" in r.output, r.output
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
    (prog / "Broken.mod").unlink()
    r, _ = _correct(cells, tmp_path, "kr210_fit.json", prog, "cell/filtered")
    assert r.exit_code == 2 and "inside the program's own folder" in r.output
    (tmp_path / "out/Main.prg").mkdir(parents=True)              # the second file cannot be written: not the first
    r, _ = _correct(cells, tmp_path, "kr210_fit.json", prog, "out")
    assert r.exit_code == 2 and "Main.prg" in r.output and "Traceback" not in r.output, r.output
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == ["Main.prg"]


def test_krl_with_the_controllers_config_dat(cells, tmp_path):
    """BAS(#TOOL, 1) / BAS(#BASE, 1) with TOOL_DATA[1], BASE_DATA[1] and LOAD_DATA[1] (60 kg) of $config.dat:
    no --tool, --base or --payload; the same numbers as the sample with the frames inline at 60 kg;
    XHOME of $config.dat named and left; $config.dat read, never written."""
    prog = tmp_path / "krc"
    prog.mkdir()
    s = (DATA / "sample.src").read_bytes().decode("latin-1")
    s = s.replace("$TOOL = {X 120.0,Y 40.0,Z -60.0,A 53.947611268,B 54.468652237,C 69.357657952}", "BAS(#TOOL, 1)")
    s = s.replace("$BASE = {X 100.0,Y -50.0,Z 20.0,A 5.0,B 0.0,C 0.0}", "BAS(#BASE, 1)")
    s = s.replace("PTP XP1\r\n", "PTP XHOME\r\nPTP XP1\r\n", 1)
    (prog / "sample.src").write_bytes(s.encode("latin-1"))
    shutil.copy(DATA / "sample.dat", prog / "sample.dat")
    (prog / "$config.dat").write_bytes(
        b"DEFDAT $CONFIG\r\nDECL FRAME TOOL_DATA[16]\r\nTOOL_DATA[1]={X 120.0,Y 40.0,Z -60.0,A 53.947611268,B 54.468652237,C 69.357657952}\r\n"
        b"DECL FRAME BASE_DATA[32]\r\nBASE_DATA[1]={X 100.0,Y -50.0,Z 20.0,A 5.0,B 0.0,C 0.0}\r\n"
        b"DECL LOAD LOAD_DATA[16]\r\nLOAD_DATA[1]={M 60.0,CM {X 0.0,Y 0.0,Z 100.0,A 0.0,B 0.0,C 0.0},J {X 0.0,Y 0.0,Z 0.0}}\r\n"
        b"DECL E6AXIS XHOME={A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 60.0,A6 0.0,E1 0.0,E2 0.0}\r\nENDDAT\r\n")
    model = dict(cells["kr210"]["fit"], payloads_kg=[0.0, 60.0])          # several payloads: none is assumed
    (tmp_path / "multi.json").write_text(json.dumps(model))
    run = cells["run"]
    r = run("correct", "--model", tmp_path / "multi.json", "--program", prog, "--out", tmp_path / "out",
            "--max-correction-deg", "2", "--json", tmp_path / "r.json")
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "r.json").read_text())["targets"]
    home = [t for t in rows if t["name"] == "XHOME"][0]
    assert home["status"] == "run_time" and "$config.dat" in home["reason"]
    assert all(t["payload_kg"] == 60 and "LOAD_DATA[1]" in t["payload_source"] for t in rows if t["status"] == "ok")
    assert sum(t["status"] == "ok" for t in rows) >= 6
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == ["sample.dat", "sample.src"]
    r = run("correct", "--model", tmp_path / "multi.json", "--program", DATA / "sample.src", "--out", tmp_path / "ref",
            "--max-correction-deg", "2", "--payload", "60")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out/sample.dat").read_bytes() == (tmp_path / "ref/sample.dat").read_bytes()
    # the sample states no load: on a model fitted at several payloads it is refused, naming --payload
    r = run("correct", "--model", tmp_path / "multi.json", "--program", DATA / "sample.src", "--out", tmp_path / "no")
    line = [x for x in r.output.splitlines() if x.startswith("jointcal: error:")]
    assert r.exit_code == 2 and len(line) == 1 and "--payload" in line[0] and re.search(r"sample.src:\d+:", line[0])
    assert not (tmp_path / "no").exists()


def test_urscript_streams_and_states_its_payload(cells, tmp_path):
    """A .urscript: servoj / speedl streamed at run time are named and left (refused before), a movel
    over two lines is read, set_payload gives the payload of the motions after it."""
    s = (DATA / "sample.script").read_text()
    s = s.replace("  movej([-0.523598776", "  set_payload(2.5, [0, 0, 0.05])\n  movej([-0.523598776", 1)
    s = s.replace("  movel(p[-0.692034282, 0.084000230,", "  servoj(get_actual_joint_positions(), t=0.008)\n"
                  "  speedl([0, 0, 0.01, 0, 0, 0], 0.5, 0.1)\n  movel(p[-0.692034282,\n        0.084000230,", 1)
    (tmp_path / "cell.urscript").write_text(s)
    r, rows = _correct(cells, tmp_path, "ur10_fit.json", tmp_path / "cell.urscript", "out", "--max-correction-deg", "1",
                       json_name="r.json")
    assert r.exit_code == 0, r.output
    named = {t["name"]: t for t in rows.values()}
    assert named["servoj@7"]["status"] == "run_time" and named["speedl@8"]["status"] == "run_time"
    moved = [t for t in rows.values() if t["status"] == "ok"]
    assert len(moved) >= 7 and any(t["line"] == 9 for t in moved)
    assert all(t["payload_kg"] == 2.5 and "set_payload" in t["payload_source"] for t in moved)
    r, _ = _correct(cells, tmp_path, "ur10_identity.json", tmp_path / "cell.urscript", "same")
    assert r.exit_code == 0 and (tmp_path / "same/cell.urscript").read_bytes() == (tmp_path / "cell.urscript").read_bytes()


def test_fanuc_positioner_group_and_other_lines(cells, tmp_path):
    """A motion of group 2 only (a positioner) is named and left as given; '------ ;' and unnumbered
    ':' lines are kept; the robot's motions are filtered as before."""
    s = (DATA / "sample.ls").read_text()
    s = s.replace("   3:  !hand-written sample ;", "   3:  !hand-written sample ;\n       ------ ;\n  : Arc Start[1] ;\n"
                  "   4:J P[9] 100% FINE    ;")
    s = s.replace("/END", "P[9]{\n   GP2:\n\tUF : 0, UT : 1,\t\n\tJ1=    90.000 deg\n};\n/END")
    (tmp_path / "p.ls").write_text(s)
    r, rows = _correct(cells, tmp_path, "kr210_fit.json", tmp_path / "p.ls", "out", "--tool", FANUC_TOOL, "--payload",
                       cells["kr210"]["payload"], json_name="r.json")
    assert r.exit_code == 0, r.output
    named = {t["name"]: t for t in rows.values()}
    assert named["P[9]"]["status"] == "run_time" and "group 2" in named["P[9]"]["reason"]
    assert sum(t["status"] == "ok" for t in rows.values()) >= 6
    assert "J1=    90.000 deg" in (tmp_path / "out/p.ls").read_text()


@pytest.fixture(scope="module")
def two_payloads(cells):
    """The KR210 cell measured carrying 0 kg and 60 kg (every other pose), and a model fitted on both."""
    tmp, run = cells["tmp"], cells["run"]
    poses = pd.read_csv(tmp / "kr210_poses.csv")
    poses["payload_kg"] = np.where(np.arange(len(poses)) % 2 == 0, 0.0, 60.0)
    poses.to_csv(tmp / "kr210_two_poses.csv", index=False)
    r = run("simulate", "measure", "--truth", tmp / "kr210.json", "--poses", tmp / "kr210_two_poses.csv",
            "--campaign", tmp / "kr210_two")
    assert r.exit_code == 0, r.output
    r = run("fit", "--campaign", tmp / "kr210_two", "--spec", tmp / "spec.toml", "--out", tmp / "kr210_two_fit.json")
    assert r.exit_code == 0, r.output
    fit = json.loads((tmp / "kr210_two_fit.json").read_text())
    assert sorted(fit["payloads_kg"]) == [0.0, 60.0]
    return fit


@pytest.mark.parametrize("fmt", ["rapid", "ur"])
def test_the_payload_the_program_states(cells, two_payloads, tmp_path, fmt):
    """KR210 cell carrying 60 kg, model fitted at 0 and 60 kg: a RAPID program whose tooldata says 60 kg
    and a URScript with set_payload(60) land within 1.25 x the held-out RMS + 5 um with no --payload;
    the same program stating no payload is refused naming --payload; corrected at 0 kg it lands worse."""
    import program_samples as ps
    from pipeline.robot.cell.simulate import cell_config, draw_poses

    robot = load_robot(KR210)
    fit = two_payloads
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    cfg = cell_config(robot, paper=True)
    Q = draw_poses(robot, 1500, np.random.default_rng(11), cfg["box_mm"], cfg["orientation_deg"])
    Q = Q[np.all((Q >= lo + 0.5) & (Q <= hi - 0.5), axis=1)]
    Q = Q[:32] if fmt == "rapid" else ps.smooth_path(robot, Q, 32)
    if fmt == "rapid":
        text = ps.rapid(robot, Q, "prog")                                # tooldata tSMR: [60,[0,0,100],...]
        prog, bare = tmp_path / "prog.mod", re.sub(r"(?m)^  PERS tooldata tSMR.*\n", "", text)   # tool: --tool
    else:
        text = ps.urscript(robot, Q, "prog").replace("  set_tcp(", "  set_payload(60, [0, 0, 0.1])\n  set_tcp(", 1)
        prog, bare = tmp_path / "prog.script", text.replace("  set_payload(60, [0, 0, 0.1])\n", "")
    assert bare != text
    prog.write_text(text)
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / prog.name).write_text(bare)
    run, model = cells["run"], cells["tmp"] / "kr210_two_fit.json"
    tool = ["--tool", " ".join(map(str, [*robot.tool_xyz_mm, 0.9238795325, 0.0, 0.3826834324, 0.0]))] if fmt == "rapid" \
        else []                                                      # tSMR of program_samples.rapid
    r = run("correct", "--model", model, "--program", tmp_path / "bare" / prog.name, "--out", tmp_path / "no", *tool)
    line = [x for x in r.output.splitlines() if x.startswith("jointcal: error:")]
    assert r.exit_code == 2 and len(line) == 1 and "--payload" in line[0], r.output
    rms = {}
    for label, p, extra in (("stated", prog, []), ("at 0 kg", tmp_path / "bare" / prog.name, ["--payload", "0"] + tool)):
        r = run("correct", "--model", model, "--program", p, "--out", tmp_path / label, "--max-correction-deg", "1",
                "--json", tmp_path / f"{label}.json", *extra)
        assert r.exit_code == 0, r.output
        rep = json.loads((tmp_path / f"{label}.json").read_text())
        assert rep["counts"].get("ok", 0) >= 28, rep["counts"]
        intended = _intended(KR210, p, tool if extra else [])
        r = run("simulate", "measure", "--truth", cells["tmp"] / "kr210.json", "--program", tmp_path / label / p.name,
                "--campaign", tmp_path / f"m_{label}", "--payload", "60", *(tool if extra else []))
        assert r.exit_code == 0, r.output
        xyz = pd.read_csv(tmp_path / f"m_{label}" / "tracker.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy()
        rms[label] = float(np.sqrt(np.mean(np.sum((xyz - intended) ** 2, axis=1))))
    stated = [t for t in json.loads((tmp_path / "stated.json").read_text())["targets"] if t["status"] == "ok"]
    assert all(t["payload_kg"] == 60 and t["payload_source"].startswith("program:") for t in stated)
    heldout = fit["heldout"]["rms_after_mm"]
    print(f"{fmt}: filtered at the stated 60 kg {rms['stated']:.4f} mm, at 0 kg {rms['at 0 kg']:.4f} mm, "
          f"held-out {heldout:.4f} mm")
    assert rms["stated"] <= 1.25 * heldout + 0.005, (rms, heldout)
    assert rms["at 0 kg"] > rms["stated"], rms


def test_a_code_page_whose_bytes_look_like_brackets(cells, tmp_path):
    """Shift-JIS comments and strings (second bytes 0x5B, 0x5D, 0x7B, 0x7D: '[', ']', '{', '}') in a KRL
    program and a FANUC one: read byte for byte, filtered to the same numbers as without them."""
    jis = b"\x83\x5b\x83\x7b\x83\x7d\x83\x5d"                    # katakana whose second bytes are brackets
    src = (DATA / "sample.src").read_bytes().replace(b"$VEL.CP = 0.5 ; m/s", b"$VEL.CP = 0.5 ; " + jis + b"\r\n"
                                                    b"$MSG_T.KEY[] = \"" + jis + b"\"", 1)
    ls = (DATA / "sample.ls").read_bytes().replace(b"!hand-written sample ;", b"!" + jis + b" ;", 1)
    (tmp_path / "jis").mkdir()
    (tmp_path / "jis/sample.src").write_bytes(src)
    shutil.copy(DATA / "sample.dat", tmp_path / "jis/sample.dat")
    (tmp_path / "jis/sample.ls").write_bytes(ls)
    pay = ["--payload", cells["kr210"]["payload"]]
    for name, extra in (("sample.src", []), ("sample.ls", ["--tool", FANUC_TOOL])):
        r, _ = _correct(cells, tmp_path, "kr210_fit.json", tmp_path / "jis" / name, "o_" + name, *pay, *extra)
        assert r.exit_code == 0, r.output
        r0, _ = _correct(cells, tmp_path, "kr210_fit.json", DATA / name, "p_" + name, *pay, *extra)
        assert r0.exit_code == 0, r0.output
        got = (tmp_path / ("o_" + name) / name).read_bytes()
        assert jis in got and _numbers_of(tmp_path / ("o_" + name) / name) == _numbers_of(
            tmp_path / ("p_" + name) / name)


def test_urscript_block_header_over_several_lines(tmp_path):
    """A `while`/`if` whose condition runs over lines opens its block (PolyScope writes such headers;
    the `end` was refused as "without a block to end"); a block left open is still refused."""
    from pipeline.core.errors import InputError
    from pipeline.programs import urscript

    body = ("def demo():\n  n = 0\n  while (n < 3 and\n         n >= 0):\n    n = n + 1\n  end\n"
            "  if (n == 3 or\n      n == 4):\n    movej([0.1, -1.5, 1.4, -1.4, -1.6, 0.0])\n  end\nend\n")
    (tmp_path / "a.script").write_text(body)
    program = urscript.read(tmp_path / "a.script")
    assert len(program.targets) == 1
    (tmp_path / "b.script").write_text(body.replace("    n = n + 1\n  end\n", "    n = n + 1\n", 1))
    with pytest.raises(InputError, match="without its 'end'"):
        urscript.read(tmp_path / "b.script")


def test_krl_fdat_declared_in_the_controller(cells, tmp_path):
    """`FDAT_ACT = FHOME` whose DECL FDAT lives in the controller's $config.dat (not given) no longer
    refuses the file: a joint motion after it is read, a Cartesian one needs --tool/--base or is named."""
    from pipeline.programs import krl

    src = ("DEF home( )\n  BAS (#INITMOV,0 )\n  FDAT_ACT=FHOME\n  BAS (#FRAMES )\n"
           "  PTP {A1 0,A2 -90,A3 90,A4 0,A5 0,A6 0}\nEND\n")
    (tmp_path / "home.src").write_text(src)
    program = krl.read(tmp_path / "home.src")
    assert [t.kind for t in program.targets] == ["joint"]
    r, _ = _correct(cells, tmp_path, "kr210_identity.json", tmp_path / "home.src", "same")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "same/home.src").read_bytes() == src.encode()


def _assert_identity_keeps(cells, tmp_path, model, name, src):
    """``src`` written as ``name``, corrected by an identity ``model``, comes back byte for byte."""
    (tmp_path / name).write_text(src)
    r, _ = _correct(cells, tmp_path, model, tmp_path / name, "same")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "same" / name).read_text() == src


def test_identity_keeps_a_target_at_gimbal_lock(cells, tmp_path):
    """A KRL target at B = +-90 (only A - C or A + C defined) keeps its own A and C under an identity
    model: the filter wrote {A 15.3, B 90, C 15.3}, the same rotation in other bytes. FANUC's W, P, R
    go through the same conversion."""
    src = ("DEF g( )\n  $TOOL = $NULLFRAME\n  $BASE = $NULLFRAME\n  PTP {A1 0,A2 -90,A3 100,A4 0,A5 30,A6 0}\n"
           "  LIN {X 1500.0,Y 100.0,Z 1600.0,A 0.0,B 90.0,C 0.0}\n"
           "  LIN {X 1500.0,Y 100.0,Z 1600.0,A 20.0,B -90.0,C 5.0}\n"
           "  LIN {X 1500.0,Y 100.0,Z 1600.0,A 10.0,B 60.0,C 5.0}\nEND\n")
    _assert_identity_keeps(cells, tmp_path, "kr210_identity.json", "g.src", src)
    for wpr in ((0.0, 90.0, 0.0), (-36.0, 90.0, 12.0), (3.0, -90.0, 40.0)):
        R = cv.fanuc_matrix(*wpr) @ cv.fanuc_matrix(1e-10, 0.0, 0.0)  # a rounding's turn away
        assert np.allclose(cv.fanuc_wpr(R, near=wpr), wpr, atol=1e-6)


def test_a_target_the_program_assigns_is_left_as_given(cells, tmp_path):
    """A KRL or RAPID variable the program sets at run time (g = $POS_ACT; g.X = g.X + 10 / p := CRobT())
    holds the run time's value, not its declaration's: named run_time and not rewritten by a fitted
    model (it rewrote the DECL and reported the motion corrected)."""
    krl_src = ("DEF follow( )\n  $TOOL = $NULLFRAME\n  $BASE = $NULLFRAME\n  goal = $POS_ACT\n  goal.X = goal.X + 10.0\n"
               "  LIN goal\n  LIN fixed\nEND\n")
    krl_dat = ("DEFDAT follow\n  DECL E6POS goal={X 1500.0,Y 100.0,Z 1600.0,A 0.0,B 60.0,C 0.0,S 2,T 35}\n"
               "  DECL E6POS fixed={X 1500.0,Y 100.0,Z 1500.0,A 0.0,B 60.0,C 0.0,S 2,T 35}\nENDDAT\n")
    rapid_src = ("MODULE Park\n  PERS robtarget pNow:=[[1500,100,1600],[0.5,0,0.866025404,0],[0,0,0,0],"
                 "[9E9,9E9,9E9,9E9,9E9,9E9]];\n  PROC main()\n    pNow:=CRobT(\\Tool:=tool0);\n"
                 "    pNow.trans.x:=pNow.trans.x+10;\n    MoveL pNow,v100,fine,tool0;\n  ENDPROC\nENDMODULE\n")
    (tmp_path / "k").mkdir()
    (tmp_path / "k/follow.src").write_text(krl_src)
    (tmp_path / "k/follow.dat").write_text(krl_dat)
    (tmp_path / "Park.mod").write_text(rapid_src)
    for program, json_name in ((tmp_path / "k/follow.src", "k.json"), (tmp_path / "Park.mod", "r.json")):
        r, rows = _correct(cells, tmp_path, "kr210_fit.json", program, "out_" + json_name[0], json_name=json_name)
        assert r.exit_code == 0, r.output
        named = {name: t for (name, _), t in rows.items()}
        moved = "goal" if json_name == "k.json" else "pNow"
        assert named[moved]["status"] == "run_time", named[moved]
        if json_name == "k.json":
            assert named["fixed"]["status"] != "run_time"  # a constant target beside it is still read as one
            out = (tmp_path / "out_k/follow.dat").read_text()
            assert "DECL E6POS goal={X 1500.0,Y 100.0,Z 1600.0,A 0.0,B 60.0,C 0.0,S 2,T 35}" in out
        else:
            assert (tmp_path / "out_r/Park.mod").read_text() == rapid_src


def test_identity_keeps_a_twelve_decimal_pose_near_a_half_turn(cells, tmp_path):
    """An identity model changes no byte of a URScript pose written to 12 decimals with a rotation
    vector near pi under a set_tcp (the pose's respelling moved its last decimals by 6e-11 m)."""
    src = ("def tcp12():\n  set_tcp(p[0.0,0.0,0.22,0.0,0.0,0.0])\n"
           "  movel(p[-.135606889873, -.196202267593, .160257900767, .030794545164, 3.137571550868, -.006587915986])\n"
           "  movel(p[-.435606889873, -.196202267593, .460257900767, .030794545164, 3.137571550868, -.006587915986])\n"
           "end\n")
    _assert_identity_keeps(cells, tmp_path, "ur10_identity.json", "tcp12.script", src)


def test_a_krl_motion_to_a_system_axis_variable_is_a_joint_motion_left_as_given(tmp_path):
    """PTP $AXIS_ACT (an E6AXIS the controller holds) is a joint motion, not a Cartesian one; LIN $POS_ACT
    stays Cartesian; both are read as computed at run time (left as given), an inline joint target is not."""
    from pipeline.programs import krl
    from pipeline.programs.model import CARTESIAN, JOINT
    (tmp_path / "ax.src").write_text("DEF ax( )\n  PTP $AXIS_ACT\n  LIN $POS_ACT\n"
                                     "  PTP {A1 10, A2 -90, A3 90, A4 0, A5 30, A6 0}\nEND\n")
    targets = krl.read(tmp_path / "ax.src").targets
    assert [(t.name, t.kind, bool(t.runtime)) for t in targets[:2]] == [("$AXIS_ACT", JOINT, True),
                                                                      ("$POS_ACT", CARTESIAN, True)]
    assert targets[2].kind == JOINT and not targets[2].runtime


def test_an_encrypted_rapid_module_in_a_folder_is_copied_as_given(cells, tmp_path):
    """A folder's module that is not RAPID text (an encrypted module: binary bytes, or an encoded blob
    without MODULE) is named on stderr and copied byte for byte; the other modules are filtered as
    without it. Given alone, the binary module is still refused with file:line:col. Module attributes
    (SYSMODULE, NOSTEPIN, VIEWONLY) read."""
    prog = _rapid_modules(tmp_path / "cell")
    sys_text = (prog / "CellData.sys").read_text()
    (prog / "CellData.sys").write_text(re.sub(r"(?m)^MODULE (\w+)", r"MODULE \1(SYSMODULE, NOSTEPIN, VIEWONLY)",
                                              sys_text, count=1))
    assert "(SYSMODULE, NOSTEPIN, VIEWONLY)" in (prog / "CellData.sys").read_text()
    binary = bytes(range(256)) * 3 + b"\x00\x01tail"
    blob = b"ENC1:" + b"QUJCREVGR0hJSktMTU5PUFFSU1RVVldYWVo=" * 4 + b"\n"
    (prog / "Secret.mod").write_bytes(binary)
    (prog / "Blob.sys").write_bytes(blob)
    r, rows = _correct(cells, tmp_path, "kr210_fit.json", prog, "out", "--max-correction-deg", "2", json_name="r.json")
    assert r.exit_code == 0, r.output
    for name in ("Secret.mod", "Blob.sys"):
        lines = [ln for ln in r.output.splitlines() if name in ln and "not readable RAPID text" in ln]
        assert len(lines) == 1 and "copied as given" in lines[0], r.output
    assert (tmp_path / "out/Secret.mod").read_bytes() == binary
    assert (tmp_path / "out/Blob.sys").read_bytes() == blob
    status = {name: t["status"] for (name, _), t in rows.items()}
    assert all(status[n] == "ok" for n in ("j0", "p1", "p2", "p3", "j4")), rows
    alone = _correct(cells, tmp_path, "kr210_fit.json", prog / "Secret.mod", "alone")[0]
    assert alone.exit_code == 2 and "Traceback" not in alone.output, alone.output
    assert re.search(r"Secret\.mod:\d+:\d+", alone.output), alone.output


@pytest.mark.parametrize("cell", ["kr210_identity.json", "kr210_fit.json"])
def test_krl_global_points_of_a_public_dat_without_src(cells, tmp_path, cell):
    """A folder: main.src moves to DECL GLOBAL points of shared.dat (DEFDAT shared PUBLIC, no shared.src).
    The points are corrected in shared.dat (the same numbers as the sample with its own .dat), every
    file of the folder is in the output, and an identity model changes no byte of any file."""
    prog = tmp_path / "krc"
    prog.mkdir()
    s = (DATA / "sample.src").read_bytes().decode("latin-1").replace("DEF sample(", "DEF main(")
    (prog / "main.src").write_bytes(s.encode("latin-1"))
    d = (DATA / "sample.dat").read_bytes().decode("latin-1")
    d = d.replace("DEFDAT  SAMPLE", "DEFDAT  SHARED PUBLIC").replace("DECL E6", "DECL GLOBAL E6")
    (prog / "shared.dat").write_bytes(d.encode("latin-1"))
    (prog / "main.dat").write_bytes(b"DEFDAT  MAIN\r\nDECL INT COUNT=0\r\nENDDAT\r\n")
    (prog / "unused.dat").write_bytes(b"DEFDAT  UNUSED PUBLIC\r\nDECL GLOBAL E6POS XQ={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 2,T 10}\r\nENDDAT\r\n")
    r, rows = _correct(cells, tmp_path, cell, prog, "out", "--max-correction-deg", "2", json_name="r.json")
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    assert sorted(f.name for f in out.iterdir()) == ["main.dat", "main.src", "shared.dat", "unused.dat"]
    assert (out / "unused.dat").read_bytes() == (prog / "unused.dat").read_bytes()
    assert (out / "main.dat").read_bytes() == (prog / "main.dat").read_bytes()
    assert sum(t["status"] == "ok" for t in rows.values()) >= 6
    if cell == "kr210_identity.json":
        for f in prog.iterdir():
            assert (out / f.name).read_bytes() == f.read_bytes(), f.name
        return
    r, _ = _correct(cells, tmp_path, cell, DATA / "sample.src", "ref", "--max-correction-deg", "2")
    assert r.exit_code == 0, r.output
    assert _numbers_of(out / "shared.dat") == _numbers_of(tmp_path / "ref/sample.dat")
    assert _numbers_of(out / "shared.dat") != _numbers_of(prog / "shared.dat")


def test_a_declared_target_used_under_two_tools_is_named(cells, tmp_path):
    """One CONST robtarget moved to under two tools (or two payloads): its one set of numbers is filtered
    for the first use; the second is named with both lines in the report and on the console, not
    silently corrected for the wrong frame. Used again under the same tool it is a plain same_target."""
    src = ("MODULE Two\n"
           "  PERS tooldata tA:=[TRUE,[[0,0,200],[1,0,0,0]],[5,[0,0,50],[1,0,0,0],0,0,0]];\n"
           "  PERS tooldata tB:=[TRUE,[[0,80,250],[1,0,0,0]],[5,[0,0,50],[1,0,0,0],0,0,0]];\n"
           "  PERS tooldata tC:=[TRUE,[[0,0,200],[1,0,0,0]],[60,[0,0,50],[1,0,0,0],0,0,0]];\n"
           "  CONST robtarget p1:=[[1500,100,1500],[0.5,0,0.866025404,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
           "  PROC main()\n    MoveJ p1,v100,fine,tA;\n    MoveL p1,v100,fine,tA;\n    MoveL p1,v100,fine,tB;\n"
           "    MoveL p1,v100,fine,tC;\n  ENDPROC\nENDMODULE\n")
    (tmp_path / "Two.mod").write_text(src)
    r, rows = _correct(cells, tmp_path, "kr210_fit.json", tmp_path / "Two.mod", "out", "--payload", "5",
                       json_name="r.json")
    assert r.exit_code == 0, r.output
    by_line = {line: t for (_, line), t in rows.items()}
    assert by_line[7]["status"] != "same_target"                     # filtered or not, at its first use
    assert [by_line[n]["status"] for n in (8, 9, 10)] == ["same_target"] * 3
    assert "under another" not in by_line[8]["reason"]
    assert "tool frame" in by_line[9]["reason"] and "line 7" in by_line[9]["reason"]
    assert "payload" in by_line[10]["reason"] and "tool frame" not in by_line[10]["reason"]
    named = [x for x in r.output.splitlines() if "used again" in x]
    assert len(named) == 2 and all("Two.mod:9:" in x or "Two.mod:10:" in x for x in named), r.output


def test_played_poses_name_revisits_and_say_what_was_not_played(tmp_path):
    """played_poses, the library of `jointcal simulate measure --program`: joint targets as written (rad ->
    deg on a UR), a target visited again named #2, an unreachable one named with its line, the given payload
    where the program states none."""
    from pipeline.programs.io import read_program
    from pipeline.programs.run import played_poses
    from pipeline.robot.arm.kinematics import load_robot

    (tmp_path / "a.script").write_text(
        "def demo():\n  p1 = [0.1, -1.5, 1.4, -1.4, -1.6, 0.0]\n  movej(p1)\n"
        "  movej([0.2, -1.5, 1.4, -1.4, -1.6, 0.0])\n  movej(p1)\n  movel(p[5.0, 5.0, 5.0, 0.0, 0.0, 0.0])\nend\n")
    p = played_poses(read_program(tmp_path / "a.script"), load_robot(UR10), tool=[0.0] * 6, payload_kg=3.0)
    assert list(p.point_id) == ["p1", "<inline>@4", "p1#2"]
    assert np.allclose(p.q_deg[0], np.rad2deg([0.1, -1.5, 1.4, -1.4, -1.6, 0.0]))
    assert np.allclose(p.q_deg[1, 0], np.rad2deg(0.2)) and np.array_equal(p.q_deg[0], p.q_deg[2])
    assert list(p.payload_kg) == [3.0, 3.0, 3.0]
    assert [(t.line, "inverse-kinematics" in why) for t, why in p.not_played] == [(6, True)]


def test_filter_with_model_counts_and_payloads(cells, tmp_path):
    """filter_with_model, the library of `jointcal correct --program`: the identity model changes no text;
    a fitted one changes some, every motion counted once, each motion's payload from where it is stated."""
    from pipeline.programs.io import read_program
    from pipeline.programs.run import filter_with_model
    from pipeline.robot.model.predict import load_model_document

    program = read_program(DATA / "sample.script")
    ident = json.loads((cells["tmp"] / "ur10_identity.json").read_text())
    same = filter_with_model(program, ident, load_model_document(ident, "identity.json"))
    assert same.texts == [s.text for s in program.sources] and same.largest_arcsec < 1e-3
    fit = cells["ur10"]["fit"]
    run = filter_with_model(program, fit, load_model_document(fit, "fit.json"), payload_kg=2.5)
    assert sum(run.counts.values()) == len(run.filtered.rows) == len(program.targets)
    assert run.counts.get("ok", 0) > 0 and run.largest_arcsec > 1.0 and run.moved_mm > 0.0
    assert run.texts != same.texts
    grouped = [r for rows in run.payloads.values() for r in rows]
    assert sorted(map(id, grouped)) == sorted(map(id, run.filtered.rows))
    for (kg, source), rows in run.payloads.items():
        assert all((r["payload_kg"], r["payload_source"]) == (kg, source) for r in rows)
        assert kg == 2.5 if source == "--payload" else source.startswith("program:")
    lines = run.report(["f.script"], 0.0, ["a note"], 2.5)
    left = [r for r in run.filtered.rows if r["status"] not in ("ok", "same_target")]
    assert lines[0].startswith(f"f.script: {len(program.targets)} targets in 0.0 s: {run.counts['ok']} filtered")
    assert len([x for x in lines if " left as given: " in x and x.startswith("  ")]) == len(left)
    assert "  a note" in lines and "; payload: " in lines[-1]


def test_numbers_without_the_decimals_to_carry_the_correction_are_named(cells, tmp_path):
    """A published KRL driver moves to ``PTP {A1 0, A2 -90, A3 90, A4 0, A5 90, A6 0}``: written with no
    decimals, the corrected angles round back to the same integers. It was reported filtered (a
    correction of hundreds of arcsec, a move of 1.6 mm) while no byte changed; it is named
    ``rounded_away`` and left as given. The same joints written with decimals are filtered."""
    fit = cells["kr210"]["fit"]
    mid = np.round((np.array(fit["sampled_range"]["lower_deg"]) + fit["sampled_range"]["upper_deg"]) / 2)
    ints = ", ".join(f"A{j + 1} {v:.0f}" for j, v in enumerate(mid))
    decs = ", ".join(f"A{j + 1} {v:.5f}" for j, v in enumerate(mid))
    src = f"DEF drive( )\n  PTP {{{ints}}}\n  PTP {{{decs}}}\nEND\n"
    (tmp_path / "drive.src").write_text(src)
    r, rows = _correct(cells, tmp_path, "kr210_fit.json", tmp_path / "drive.src", "out", "--payload",
                       cells["kr210"]["payload"], json_name="r.json")
    assert r.exit_code == 0, r.output
    by_line = {t["line"]: t for t in rows.values()}
    assert by_line[2]["status"] == "rounded_away" and "more decimals" in by_line[2]["reason"], by_line[2]
    assert by_line[3]["status"] == "ok" and by_line[3]["move_mm"] > 0.05, by_line[3]
    out = (tmp_path / "out/drive.src").read_text().splitlines()
    assert out[1] == src.splitlines()[1] and out[2] != src.splitlines()[2]


def test_a_declared_target_played_on_two_solutions_is_named(cells, tmp_path):
    """One PolyScope waypoint moved to twice with the qnear of two solutions of its pose: its numbers
    can serve one solution only (the correction depends on the joints). The second use was counted a
    plain 'same_target'; it is named like a use under another tool (the console's "used again")."""
    import program_samples as ps

    robot = load_robot(UR10)
    chain = ik.chain_of(robot)
    q0 = (robot.lower_deg + robot.upper_deg) / 2 + np.array([20.0, -30.0, 40.0, 10.0, 35.0, -15.0])
    T = ik.flange(chain, np.deg2rad(q0[None]))[0]
    sols = np.rad2deg(ik.expand_turns(chain, ik.solve_all(chain, T[None])[0]))
    far = sols[np.argmax(np.abs(sols - q0).max(axis=1))]
    P, _ = ps._poses(robot, q0[None], np.eye(4), np.eye(4), "ur")
    lit = "p[" + ", ".join(f"{v:.12f}" for v in np.r_[P[0][:3, 3] / 1000.0, cv.ur_rotvec(P[0][:3, :3])]) + "]"
    near = lambda q: "[" + ", ".join(f"{v:.6f}" for v in np.deg2rad(q + 2.0)) + "]"   # noqa: E731
    (tmp_path / "twice.script").write_text(
        f"def twice():\n  set_tcp(p[0.0, 0.0, 0.0, 0.0, 0.0, 0.0])\n  global W1_p={lit}\n"
        f"  movej(get_inverse_kin(W1_p, qnear={near(q0)}))\n  movej(get_inverse_kin(W1_p, qnear={near(far)}))\n"
        f"  movej(get_inverse_kin(W1_p, qnear={near(q0)}))\nend\n")
    r, rows = _correct(cells, tmp_path, "ur10_identity.json", tmp_path / "twice.script", "out", "--payload", "0",
                       json_name="r.json")
    assert r.exit_code == 0, r.output
    by_line = {t["line"]: t for t in rows.values()}
    assert by_line[5]["status"] == "same_target" and "arm solution" in by_line[5]["reason"], by_line[5]
    assert by_line[6]["status"] == "same_target" and "arm solution" not in by_line[6]["reason"], by_line[6]
