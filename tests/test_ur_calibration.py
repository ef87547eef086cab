"""A Universal Robots calibration.conf as the nominal robot (contract sections 6, 8, 11): read exactly
(delta_d of hundreds of metres), checked against an independent classic-DH forward kinematics,
imported, fitted, exported back as the robot's new calibration.conf, and used by correct --program."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from conftest import ROOT, cli_invoker
from pipeline.robot.campaign.ur import KEYS, UR_DH, parse_calibration_conf, published_dh, robot_from_calibration

CHAIN_SPEC = """[model]
kind = "robot"
[[effect]]
name = "geometry"
[[effect]]
name = "base"
[[effect]]
name = "tool"
"""
SMR_MM = (10.0, -20.0, 95.0)
#: UR's published DH, typed here again from universal-robots.com for the check (a [m], d [m])
TYPED = {"ur10": ([0, -0.612, -0.5723, 0, 0, 0], [0.1273, 0, 0, 0.163941, 0.1157, 0.0922]),
         "ur5e": ([0, -0.425, -0.3922, 0, 0, 0], [0.1625, 0, 0, 0.1333, 0.0997, 0.0996]),
         "ur20": ([0, -0.862, -0.7287, 0, 0, 0], [0.2363, 0, 0, 0.201, 0.1593, 0.1543])}


def _zero_model(robot):
    from pipeline.core.spec import parse_spec
    from pipeline.robot.model.estimator import RobotErrorModel, empty_data

    effects = list(parse_spec(CHAIN_SPEC, "spec").effects)
    names = RobotErrorModel(robot, effects).design(empty_data(robot)).names
    return RobotErrorModel.from_parameters(robot, effects, [{"name": n, "value": 0.0} for n in names])


def _physical(model, seed, tilt_deg=2e-5):
    """A physical arm of the model: its joint axes a little off UR's drawing (axes 2 and 3 tilted by a
    few microradians, lengths by tenths of a mm, angles by hundredths of a degree)."""
    rng = np.random.default_rng(seed)
    robot = robot_from_calibration({k: np.zeros(6) for k in KEYS}, model, SMR_MM)
    for i in range(6):
        j = robot.joints[i]
        robot = robot.replace_joint(i, beta_deg=j.beta_deg + (tilt_deg * (1 + i) if i in (1, 2) else 0.0),
                                    d_mm=j.d_mm + rng.normal(0, 0.3), a_mm=j.a_mm + rng.normal(0, 0.3),
                                    alpha_deg=j.alpha_deg + rng.normal(0, 0.01),
                                    theta_offset_deg=j.theta_offset_deg + rng.normal(0, 0.01))
    return robot


def _conf_text(model, seed):
    """A calibration.conf of real size: the physical arm's classic DH minus the published one, as UR's
    factory calibration writes it (delta_d of hundreds of metres on the nearly parallel joints)."""
    from pipeline.export.chain import folded_chain
    from pipeline.export.ur import standard_dh

    pub = robot_from_calibration({k: np.zeros(6) for k in KEYS}, model)
    ref = standard_dh(folded_chain(pub, _zero_model(pub)))
    phys = _physical(model, seed)
    dh = standard_dh(folded_chain(phys, _zero_model(phys)), reference=ref)
    nom = published_dh(model)
    lines = ["# a calibration.conf written for the tests (tests/test_ur_calibration.py)", "[mounting]"]
    for k in ("theta", "a", "d", "alpha"):
        v = np.angle(np.exp(1j * (dh[k] - nom[k]))) if k == "theta" else dh[k] - nom[k]
        lines.append(f"delta_{k} = [ " + ", ".join(repr(float(x)) for x in v) + " ]")
    lines += ["joint_checksum = [ -1, -1, -1, -1, -1, -1 ]", "", "[calibration_status]", "status = 2"]
    return "\n".join(lines) + "\n", phys


def _dh_T(theta, d, a, alpha, q):
    """Classic DH, written out here: prod Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i); (n, 4, 4), m."""
    out = []
    for qq in q:
        M = np.eye(4)
        for t, dd, aa, al in zip(theta + qq, d, a, alpha):
            ct, st, ca, sa = np.cos(t), np.sin(t), np.cos(al), np.sin(al)
            M = M @ np.array([[ct, -st * ca, st * sa, aa * ct], [st, ct * ca, -ct * sa, aa * st],
                              [0, sa, ca, dd], [0, 0, 0, 1.0]])
        out.append(M)
    return np.array(out)


def _dh_fk(theta, d, a, alpha, q):
    return _dh_T(theta, d, a, alpha, q)[:, :3, 3]


def test_published_tables_are_ur_s():
    for model, (a, d) in TYPED.items():
        nom = published_dh(model)
        assert np.array_equal(nom["a"], a) and np.array_equal(nom["d"], d)
    assert sorted(UR_DH) == sorted(["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"])


@pytest.mark.parametrize("model", sorted(UR_DH))
def test_calibration_conf_is_read_exactly(model):
    """Every model: the robot.toml of a calibration.conf with real-sized deltas puts the flange where an
    independent classic-DH forward kinematics of the file's numbers does, to < 1 um."""
    from pipeline.robot.arm.kinematics import build_model, parse_robot, placements

    text, _ = _conf_text(model, 3)
    deltas = parse_calibration_conf(text)
    assert np.abs(deltas["delta_d"]).max() > 100.0           # metres: as real files have them
    robot = parse_robot(robot_from_calibration(deltas, model, SMR_MM).to_toml())
    assert robot.ur_model == model
    assert max(max(abs(j.d_mm), abs(j.a_mm)) for j in robot.joints) < 1000.0   # every link frame on the arm
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (40, 6))
    _, P = placements(build_model(robot), q, "flange")
    nom = published_dh(model)
    ref = _dh_fk(nom["theta"] + deltas["delta_theta"], nom["d"] + deltas["delta_d"], nom["a"] + deltas["delta_a"],
                 nom["alpha"] + deltas["delta_alpha"], q) * 1000.0
    assert np.abs(P - ref).max() < 1e-3
    # and it is not the published robot: the deltas matter
    plain = _dh_fk(nom["theta"], nom["d"], nom["a"], nom["alpha"], q) * 1000.0
    assert np.abs(plain - ref).max() > 0.1


def test_bad_calibration_conf_names_its_line(tmp_path):
    text, _ = _conf_text("ur10", 3)
    bad = text.replace("delta_a = [ ", "delta_a = [ x, ", 1)
    (tmp_path / "calibration.conf").write_text(bad)
    (tmp_path / "src.csv").write_text("q1,q2,q3,q4,q5,q6,x,y,z\n0,0,0,0,0,0,0,0,0\n")
    (tmp_path / "map.toml").write_text(MAP)
    r = cli_invoker()("import", "--source", tmp_path / "src.csv", "--map", tmp_path / "map.toml", "--robot",
                      tmp_path / "calibration.conf", "--ur-model", "ur10", "--out", tmp_path / "camp")
    assert r.exit_code == 2 and "calibration.conf:4:" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "camp").exists()
    (tmp_path / "calibration.conf").write_text(text)
    r = cli_invoker()("import", "--source", tmp_path / "src.csv", "--map", tmp_path / "map.toml", "--robot",
                      tmp_path / "calibration.conf", "--out", tmp_path / "camp")
    assert r.exit_code == 2 and "--ur-model" in r.output, r.output


MAP = """[joints]
columns = ["q1", "q2", "q3", "q4", "q5", "q6"]
unit = "rad"
[position]
columns = ["x", "y", "z"]
unit = "m"
frame = "base"
[split]
sample_fraction = 0.6
seed = 1
"""


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """A UR10 measured (its physical arm, as a tracker sees the SMR) and imported on its own
    calibration.conf; then fitted (geometry, base, tool) and exported back as a calibration.conf."""
    from pipeline.robot.arm.kinematics import build_model, positions

    tmp = tmp_path_factory.mktemp("urcal")
    text, phys = _conf_text("ur10", 5)
    (tmp / "calibration.conf").write_text(text)
    rng = np.random.default_rng(8)
    q = rng.uniform([-3, -2.8, -2.5, -3, -3, -3], [3, -0.4, 2.5, 3, 3, 3], (120, 6))
    xyz = positions(build_model(phys), q, "smr") / 1000.0 + rng.normal(0, 5e-6, (len(q), 3))
    rows = ["q1,q2,q3,q4,q5,q6,x,y,z"] + [",".join(repr(float(v)) for v in (*a, *b)) for a, b in zip(q, xyz)]
    (tmp / "src.csv").write_text("\n".join(rows) + "\n")
    (tmp / "map.toml").write_text(MAP)
    (tmp / "spec.toml").write_text(CHAIN_SPEC)
    run = cli_invoker()
    r = run("import", "--source", tmp / "src.csv", "--map", tmp / "map.toml", "--robot", tmp / "calibration.conf",
            "--ur-model", "ur10", "--tool-mm", *SMR_MM, "--out", tmp / "camp")
    assert r.exit_code == 0, r.output
    r = run("fit", "--campaign", tmp / "camp", "--spec", tmp / "spec.toml", "--out", tmp / "fit.json")
    assert r.exit_code == 0, r.output
    r = run("export", "--model", tmp / "fit.json", "--format", "ur", "--out", tmp / "new.conf")
    assert r.exit_code == 0, r.output
    return {"tmp": tmp, "run": run, "conf": text, "phys": phys, "fit": json.loads((tmp / "fit.json").read_text())}


def test_a_ur_comes_back_as_its_own_calibration(imported):
    """Imported on its calibration.conf, fitted and exported: the new calibration.conf's classic DH (the
    published table plus its deltas, FK written out here) puts the flange where the fitted chain does
    to < 1 um, and - the arm being the one its file describes - where the old file does, to the
    tracker's noise; its deltas are UR's kind (hundreds of metres on joints 2-3), not a delta against
    the imported robot (which would be near zero)."""
    from pipeline.export.chain import chain_positions, folded_chain
    from pipeline.export.ur import standard_dh
    from pipeline.robot.model.predict import load_model_document

    tmp, fit = imported["tmp"], imported["fit"]
    new = parse_calibration_conf((tmp / "new.conf").read_text())
    old = parse_calibration_conf(imported["conf"])
    assert "published DH of the UR10" in (tmp / "new.conf").read_text()
    assert np.abs(new["delta_d"][1:3]).max() > 100.0
    robot, effects, model, sampled, _ = load_model_document(fit, tmp / "fit.json")
    chain = folded_chain(robot, model)
    fitted = standard_dh(chain)
    nom = published_dh("ur10")
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, (40, 6))
    B, tool = fitted["base"].homogeneous, (fitted["tool"] * chain["smr"]).homogeneous

    def smr(d):                                     # mm: base . DH(q) . tool, the DH of a calibration.conf
        T = _dh_T(*(nom[k] + d[f"delta_{k}"] for k in ("theta", "d", "a", "alpha")), q)
        return np.einsum("ij,njk,kl->nil", B, T, tool)[:, :3, 3] * 1000.0

    ref = chain_positions(chain, np.rad2deg(q))
    print(f"new calibration.conf vs the fitted chain {np.abs(smr(new) - ref).max() * 1000:.2e} um, old file vs "
          f"new {np.abs(smr(old) - ref).max() * 1000:.2f} um, held-out {fit['heldout']['rms_after_mm'] * 1000:.2f} um, "
          f"delta_d {new['delta_d'][1]:.1f} / {new['delta_d'][2]:.1f} m (old {old['delta_d'][1]:.1f} / "
          f"{old['delta_d'][2]:.1f} m)")
    assert np.abs(smr(new) - ref).max() < 1e-3
    assert np.abs(smr(old) - ref).max() < 0.05
    assert fit["heldout"]["rms_after_mm"] < 0.02


def test_correct_program_on_a_ur_uses_its_calibration(imported, tmp_path):
    """correct --program with a model of the UR imported on its calibration.conf: the program is played
    on the robot's own kinematics (hundreds-of-metres DH included); an identity model changes no byte."""
    from pipeline.programs.filtering import play
    from pipeline.programs.io import read_program
    from pipeline.robot.arm.kinematics import parse_robot

    fit = imported["fit"]
    ident = dict(fit, parameters=[dict(p, value=0.0) for p in fit["parameters"]],
                 sampled_range={"lower_deg": [-360.0] * 6, "upper_deg": [360.0] * 6})
    (tmp_path / "ident.json").write_text(json.dumps(ident))
    shutil.copy(ROOT / "tests/data/programs/sample.script", tmp_path / "p.script")
    r = imported["run"]("correct", "--model", tmp_path / "ident.json", "--program", tmp_path / "p.script", "--out",
                        tmp_path / "out", "--json", tmp_path / "r.json")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out/p.script").read_bytes() == (tmp_path / "p.script").read_bytes()
    assert json.loads((tmp_path / "r.json").read_text())["counts"]["ok"] >= 8
    robot = parse_robot(fit["robot_toml"])
    assert robot.ur_model == "ur10" and max(max(abs(j.d_mm), abs(j.a_mm)) for j in robot.joints) < 1000.0
    played = play(read_program(tmp_path / "p.script"), robot)
    plain = play(read_program(tmp_path / "p.script"), robot_from_calibration({k: np.zeros(6) for k in KEYS}, "ur10",
                                                                            robot.tool_xyz_mm))
    ok = [k for k, why in enumerate(played.reason) if not why and not plain.reason[k]]
    assert len(ok) >= 8
    assert np.abs(played.q_deg[ok] - plain.q_deg[ok]).max() > 1e-3      # its own kinematics, not the table's


@pytest.mark.skipif(not (ROOT / "results/real/C_kinematic.json").is_file(), reason="make all writes the real fits")
def test_series_c_on_its_own_kinematic_calibration(tmp_path):
    """The real UR10's Series C kinematic fit exported as a calibration.conf, the series imported on it
    (as a UR carrying that calibration would be): base and tool alone reach the kinematic fit's
    held-out error; on UR's published table they do not."""
    run = cli_invoker()
    raw = ROOT / "raw/real/ur10-ipa"
    kin = json.loads((ROOT / "results/real/C_kinematic.json").read_text())
    r = run("export", "--model", ROOT / "results/real/C_kinematic.json", "--format", "ur", "--out", tmp_path / "c.conf")
    assert r.exit_code == 0, r.output
    assert np.abs(parse_calibration_conf((tmp_path / "c.conf").read_text())["delta_d"]).max() > 100.0
    (tmp_path / "bt.toml").write_text('[model]\nkind = "robot"\n[[effect]]\nname = "base"\n[[effect]]\nname = "tool"\n')
    tool = [str(v) for v in kin["robot_toml"].split("xyz_mm = [")[1].split("]")[0].split(",")]
    held = {}
    for label, robot in (("own", ["--robot", tmp_path / "c.conf", "--ur-model", "ur10", "--tool-mm", *tool]),
                         ("table", ["--robot", raw / "robot.toml"])):
        r = run("import", "--source", raw / "Series_C/measurements_random_poses.csv", "--map", raw / "map.toml",
                *robot, "--out", tmp_path / label)
        assert r.exit_code == 0, r.output
        r = run("fit", "--campaign", tmp_path / label, "--spec", tmp_path / "bt.toml", "--out", tmp_path / f"{label}.json")
        assert r.exit_code == 0, r.output
        held[label] = json.loads((tmp_path / f"{label}.json").read_text())["heldout"]["rms_after_mm"]
    print(f"Series C, base + tool: on its own calibration {held['own']:.4f} mm, on the published table "
          f"{held['table']:.4f} mm; the kinematic fit {kin['heldout']['rms_after_mm']:.4f} mm")
    assert held["own"] <= kin["heldout"]["rms_after_mm"] * 1.01
    assert held["table"] > 1.5 * kin["heldout"]["rms_after_mm"]
