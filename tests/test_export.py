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
    text, _ = rewrite_urdf(original, "tool0", folded_chain(robot, model), ["a comment"], base="base_link",
                           nominal=folded_chain(robot, model, keep=()))
    q = np.random.default_rng(4).uniform(-170, 170, (30, 6))
    # pinocchio's model of the whole file: base_link's pose in the root frame maps the model's base frame
    import pinocchio as pin

    pm = pin.buildModelFromXML(text)
    pd_ = pm.createData()
    pin.forwardKinematics(pm, pd_, pin.neutral(pm))
    pin.updateFramePlacements(pm, pd_)
    oMb = pd_.oMf[pm.getFrameId("base_link")]
    got = (urdf_positions(text, "smr", q) / 1000.0 - oMb.translation) @ oMb.rotation * 1000.0
    assert np.abs(got - _chain_reference(robot, model, q)).max() < 1e-3
    strip = lambda t: re.sub(r"<origin\b[^>]*/>", "<origin/>", re.sub(r"<!--.*?-->\n?", "", t, flags=re.S))  # noqa: E731
    added = re.compile(r'[ \t]*<link name="smr"/>\r?\n[ \t]*<joint name="tool0-smr".*?</joint>\r?\n', re.S)
    assert len(added.findall(text)) == 1
    assert strip(added.sub("", text)) == strip(original)
    assert text != original


def test_ur_round_trip_with_nearly_parallel_axes(ur10, tmp_path):
    import yaml

    from pipeline.export.chain import folded_chain
    from pipeline.export.ur import dh_positions, standard_dh, yaml_positions
    from pipeline.robot.campaign.ur import parse_calibration_conf

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
    conf = parse_calibration_conf((tmp_path / "ur10.conf").read_text())
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


def test_ur_paths_of_out():
    from pathlib import Path

    from pipeline.export.run import ur_paths

    assert ur_paths("a/b.yaml") == (Path("a/b.conf"), Path("a/b.yaml"))
    assert ur_paths("a/b.yml") == (Path("a/b.conf"), Path("a/b.yml"))
    assert ur_paths("a/b.conf") == (Path("a/b.conf"), Path("a/b.yaml"))
    assert ur_paths("a/cell") == (Path("a/cell/calibration.conf"), Path("a/cell/kinematics.yaml"))


def _loaded(robot, spec_text, seed, lo, hi):
    from pipeline.robot.model.predict import load_model_document

    _, params = synthetic_model(robot, spec_text, seed)
    doc = _fit_doc(robot, params, spec_text, lo, hi)
    return doc, load_model_document(doc, "fit.json")


def test_export_robot_texts_carry_the_chain(ur10):
    """export_robot, the library of `jointcal export`: each format's texts, the URDF's and the UR
    deltas' chain the model's, the note saying what is left out."""
    from pipeline.export.run import export_robot
    from pipeline.export.urdf import urdf_positions
    from pipeline.robot.campaign.ur import parse_calibration_conf

    lo, hi = np.full(6, -170.0), np.full(6, 170.0)
    doc, loaded = _loaded(ur10, CHAIN_SPEC, 3, lo, hi)
    model = loaded[2]
    q = np.random.default_rng(4).uniform(lo, hi, (30, 6))
    urdf = export_robot("m.json", doc, loaded, "urdf")
    assert [k for k, _ in urdf.texts] == ["urdf"]
    assert np.abs(urdf_positions(urdf.texts[0][1], "smr", q) - _chain_reference(ur10, model, q)).max() < 1e-3
    assert urdf.note.endswith("the model has nothing else: it is carried whole")
    assert "jointcal export, format urdf, of m.json" in urdf.texts[0][1]
    ur = export_robot("m.json", doc, loaded, "ur")
    assert [k for k, _ in ur.texts] == ["conf", "yaml"]
    deltas = parse_calibration_conf(ur.texts[0][1])
    assert np.abs(deltas["delta_theta"]).max() > 1e-6             # a fitted chain, not the nominal one
    table = export_robot("m.json", doc, loaded, "table")
    assert "# the model has no effect of a joint's own angle: the table is empty" in table.texts[0][1]
    # a model with a joint map: the chain cannot carry it, and the note says at what cost
    lo2 = np.array([-170.0, -150.0, -170.0, -170.0, -120.0, -170.0])
    hi2 = np.array([170.0, -30.0, 170.0, 170.0, 60.0, 170.0])
    doc2, loaded2 = _loaded(ur10, TABLE_SPEC, 7, lo2, hi2)
    full = export_robot("m.json", doc2, loaded2, "urdf")
    cost = re.search(r"moves by ([0-9.]+) mm RMS", full.note)
    assert cost and float(cost.group(1)) > 0.0 and "compliance" in full.note
    assert full.plain_model is not full.tables_model


def test_export_robot_refuses_an_unreadable_urdf(ur10, tmp_path):
    from pipeline.core.errors import InputError
    from pipeline.export.run import export_robot

    doc, loaded = _loaded(ur10, CHAIN_SPEC, 3, np.full(6, -170.0), np.full(6, 170.0))
    (tmp_path / "bad.urdf").write_text("<robot name='x'><link name='a'>")
    with pytest.raises(InputError) as err:
        export_robot("m.json", doc, loaded, "urdf", urdf=(tmp_path / "bad.urdf", "smr", None, None))
    assert err.value.path == str(tmp_path / "bad.urdf") and "not valid XML" in err.value.message
    assert err.value.line == 1


def test_export_encoder_table_and_refusal(tmp_path):
    from pipeline.core.errors import InputError
    from pipeline.export.run import ENCODER_NOTE, export_encoder

    doc = {"terms": [{"order": 1, "C_arcsec": 10.0, "phi_deg": 30.0}]}
    text, n = export_encoder(doc, 2.0, "enc.json")
    assert n == 180 and text.startswith(f"# {ENCODER_NOTE}\n")
    rows = [line.split(",") for line in text.splitlines()[2:]]
    err = np.array([float(r[2]) for r in rows])
    theta = np.array([float(r[1]) for r in rows])
    assert np.allclose(err, 10.0 * np.sin(np.deg2rad(theta + 30.0)), atol=1e-5)    # C sin(theta + phi)
    assert np.allclose([float(r[3]) for r in rows], -err)
    with pytest.raises(InputError) as e:
        export_encoder({"something": 1}, 1.0, "enc.json")
    assert (e.value.line, e.value.column) == (1, 1) and "neither a fitted robot model" in e.value.message


FANUC_LIKE_URDF = ROOT / "tests/data/urdf/fanuc_like.urdf"     # synthetic, ROS-Industrial style (see its header)
FANUC_TOOL_MM = (204.5, 46.6, 195.2)                             # the SMR in link_6's frame, as given to import


def _body_frames(text: str, q_rad) -> dict:
    """pinocchio's placement (root frame) of every link of a URDF text at joint angles ``q_rad`` (rad)."""
    import pinocchio as pin

    m = pin.buildModelFromXML(text)
    d = m.createData()
    pin.framesForwardKinematics(m, d, np.asarray(q_rad, float))
    return {f.name: d.oMf[k].copy() for k, f in enumerate(m.frames) if f.type == pin.FrameType.BODY}


def _apart(A, B) -> tuple[float, float]:
    """Distance (mm) and angle (arcsec) between two SE3 placements."""
    import pinocchio as pin

    d = A.actInv(B)
    return float(np.linalg.norm(d.translation)) * 1000.0, float(np.rad2deg(np.linalg.norm(pin.log3(d.rotation)))) * 3600


#: the user's own SMR link on link_6 (case "own SMR link": --tip my_smr, no --tool-mm)
MY_SMR = """  <link name="my_smr"/>
  <joint name="link_6-my_smr" type="fixed">
    <origin xyz="0.2045 0.0466 0.1952" rpy="0 0 0"/>
    <parent link="link_6"/>
    <child link="my_smr"/>
  </joint>
</robot>"""


@pytest.mark.parametrize("case", ["tip link_6 --tool-mm", "own SMR link"])
def test_user_urdf_keeps_its_link_frames(tmp_path, case):
    """export --urdf on a user's ROS-Industrial-style URDF: every link frame (link_1..link_6, flange,
    tool0, a camera, the fixed base) stays on its body, moved only by the calibration's amounts at random
    joint angles; the SMR is a fixed child of --tip where the model predicts it; the file is the user's
    but for the revolute joints' origins and the SMR link. (Before: link_6, flange and tool0 moved
    215 mm to the wrist centre, links 2, 3 and 5 turned by 90 deg; --tip link_6 was refused.)"""
    import pinocchio as pin

    from pipeline.robot.arm.kinematics import build_error_model, placements
    from pipeline.robot.campaign.urdf import robot_from_urdf

    original = FANUC_LIKE_URDF.read_text(encoding="utf-8")
    if case == "own SMR link":
        original = original.replace("</robot>", MY_SMR)
        tip, tool = "my_smr", ()
    else:
        tip, tool = "link_6", ("--tool-mm", *map(str, FANUC_TOOL_MM))
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(original, encoding="utf-8")
    robot, _ = robot_from_urdf(urdf, tip, tool_mm=FANUC_TOOL_MM if tool else None)
    model, params = synthetic_model(robot, CHAIN_SPEC, 11)
    lo, hi = np.maximum(robot.lower_deg, -170.0), np.minimum(robot.upper_deg, 170.0)
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(robot, params, CHAIN_SPEC, lo, hi)))
    r = cli_invoker()("export", "--model", tmp_path / "fit.json", "--format", "urdf", "--urdf", urdf,
                      "--tip", tip, *tool, "--out", tmp_path / "cal.urdf")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "cal.urdf").read_text(encoding="utf-8")
    q = np.random.default_rng(12).uniform(lo, hi, (60, 6))
    # the calibration's size: how far the model moves its own frames (every link's, the flange, the SMR)
    from pipeline.export.chain import model_data
    from pipeline.robot.model.design import Design

    emodel, idx = build_error_model(robot)
    d = Design(robot, list(model.effects), model_data(robot, q, np.ones(q.shape, int), np.zeros(len(q)),
                                                      np.full(len(q), 20.0)), (emodel, idx))
    size_mm, size_arcsec = 0.0, 0.0
    for frame in [f"link{i + 1}" for i in range(6)] + ["flange", "smr"]:
        Rc, pc = placements(emodel, d.configurations(model.coef_), frame)
        Rn, pn = placements(emodel, d.configurations(np.zeros_like(model.coef_)), frame)
        size_mm = max(size_mm, float(np.linalg.norm(pc - pn, axis=1).max()))
        ang = [np.linalg.norm(pin.log3(a.T @ b)) for a, b in zip(Rn, Rc)]
        size_arcsec = max(size_arcsec, float(np.rad2deg(max(ang))) * 3600)
    assert 0.3 < size_mm < 10.0 and size_arcsec > 30.0        # a calibration of realistic size, not zero
    worst_mm, worst_arcsec = 0.0, 0.0
    for qk in np.deg2rad(q):
        before, after = _body_frames(original, qk), _body_frames(text, qk)
        assert set(before) <= set(after)
        for name in before:
            mm, arcsec = _apart(before[name], after[name])
            worst_mm, worst_arcsec = max(worst_mm, mm), max(worst_arcsec, arcsec)
    assert worst_mm < 1.5 * size_mm, worst_mm
    assert worst_arcsec < size_arcsec + 1e-3, worst_arcsec
    # tool0 hangs from the flange exactly as in the user's file, at every pose
    for qk in np.deg2rad(q[:5]):
        after, before = _body_frames(text, qk), _body_frames(original, qk)
        rel_after = after["link_6"].actInv(after["tool0"])
        rel_before = before["link_6"].actInv(before["tool0"])
        assert _apart(rel_after, rel_before)[0] < 1e-9
    # the SMR: a fixed child of the tip, where the model predicts it
    from pipeline.export.urdf import urdf_positions

    assert re.search(f'<joint name="{tip}-smr" type="fixed">\\s*<parent link="{tip}"/>', text)
    assert np.abs(urdf_positions(text, "smr", q) - _chain_reference(robot, model, q)).max() < 1e-3
    # every byte of the user's file is kept but the six revolute joints' origins, the SMR link and the comments
    revolute = lambda t: re.sub(r'(<joint name="joint_\d" type="revolute">\s*)<origin\b[^>]*/>', r"\1<origin/>", t)  # noqa: E731
    no_smr = re.sub(f'  <link name="smr"/>\n  <joint name="{tip}-smr".*?</joint>\n', "", text, flags=re.S)
    assert revolute(re.sub(r"<!--.*?-->\n?", "", no_smr, flags=re.S)) == revolute(re.sub(r"<!--.*?-->\n?", "",
                                                                                            original, flags=re.S))


def test_user_urdf_export_refuses_another_tool_or_urdf(tmp_path):
    """--tool-mm other than the import's, or a URDF that is not the robot's, is refused in one line."""
    from pipeline.robot.campaign.urdf import robot_from_urdf

    robot, _ = robot_from_urdf(FANUC_LIKE_URDF, "link_6", tool_mm=FANUC_TOOL_MM)
    model, params = synthetic_model(robot, CHAIN_SPEC, 13)
    lo, hi = np.full(6, -120.0), np.full(6, 120.0)
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(robot, params, CHAIN_SPEC, lo, hi)))
    base = ("export", "--model", tmp_path / "fit.json", "--format", "urdf", "--tip", "link_6", "--out",
            tmp_path / "cal.urdf")
    r = cli_invoker()(*base, "--urdf", FANUC_LIKE_URDF)
    assert r.exit_code == 2
    assert "[204.5000, 46.6000, 195.2000] mm in link 'link_6''s frame" in r.output, r.output
    other = tmp_path / "other.urdf"
    other.write_text(FANUC_LIKE_URDF.read_text().replace('<origin xyz="0 0 1.075" rpy="0 0 0"/>',
                                                         '<origin xyz="0 0 1.085" rpy="0 0 0"/>'))
    r = cli_invoker()(*base, "--urdf", other, "--tool-mm", *map(str, FANUC_TOOL_MM))
    assert r.exit_code == 2
    assert "joint 'joint_3' of the URDF lies" in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert f"{other}:53:3:" in r.output            # the file, line and column of joint_3
    assert not (tmp_path / "cal.urdf").exists()


def test_a_coupled_joints_table_is_in_its_drives_angle(ur10, tmp_path):
    """Issue 53: with coupled joints (robot.toml [coupling] q3 = { q2 = 1, q3 = 1 }: the model's joint 3 turns by
    the recorded J2 + J3, a FANUC's J2/J3), the drive table is in the drive's own (recorded) angle: the
    controller commanding recorded angles r minus the table's error lands the chain alone where the whole
    model puts r. The table was in the model's joint angle (a drive reading it would be off by J2)."""
    import pandas as pd

    from pipeline.export.chain import CHAIN_EFFECTS, TABLE_EFFECTS, model_data, predict_with
    from pipeline.robot.arm.kinematics import parse_robot

    robot = parse_robot(ur10.to_toml() + "\n[coupling]\nq3 = { q2 = 1.0, q3 = 1.0 }\n", "robot.toml")
    spec = CHAIN_SPEC + '[[effect]]\nname = "joint_map"\njoints = [3]\nstep_deg = 5.0\nrange_deg = {"3" = [-150.0, 150.0]}\n'
    model, params = synthetic_model(robot, spec, 5)
    lo = np.array([-170.0, -150.0, -150.0, -170.0, -120.0, -170.0])
    hi = np.array([170.0, -30.0, 150.0, 170.0, 60.0, 170.0])
    (tmp_path / "fit.json").write_text(json.dumps(_fit_doc(robot, params, spec, lo, hi)))
    r = cli_invoker()("export", "--model", tmp_path / "fit.json", "--format", "table", "--out", tmp_path / "t.csv",
                      "--step-deg", "2")
    assert r.exit_code == 0, r.output
    text = (tmp_path / "t.csv").read_text()
    assert "drive's own angle" in text and "drive(s) 2" in text
    t = pd.read_csv(tmp_path / "t.csv", comment="#")
    assert sorted(t["joint"].unique()) == [3]        # only joint 3's error: drive 3 alone corrects it
    mid_r = robot.recorded_angles(((lo + hi) / 2)[None])[0]         # drive 2 at -90: drive 3 spans q3's range + 90
    assert t.angle_deg.min() == pytest.approx(lo[2] - mid_r[1]) and t.angle_deg.max() == pytest.approx(hi[2] - mid_r[1])
    dirs = np.ones((1, 6), int)
    for _, row in t.sample(15, random_state=3).iterrows():
        rec = mid_r.copy()
        rec[2] = row.angle_deg
        true = rec.copy()
        true[2] -= row.error_arcsec / 3600.0
        q, q_true = robot.kinematic_angles(rec[None]), robot.kinematic_angles(true[None])
        whole = predict_with(robot, model, model_data(robot, q, dirs, np.zeros(1), np.full(1, 20.0)),
                             CHAIN_EFFECTS + TABLE_EFFECTS)
        chain = predict_with(robot, model, model_data(robot, q_true, dirs, np.zeros(1), np.full(1, 20.0)), CHAIN_EFFECTS)
        assert np.abs(whole - chain).max() < 1e-6      # mm
    assert t.error_arcsec.abs().max() > 1.0
