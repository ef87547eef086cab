"""`jointcal import` (contract section 6): real UR10 exports, URDF robots, bad inputs."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.robot.arm.kinematics import Joint, Robot, build_model, load_robot, parse_robot, positions

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "raw" / "real" / "ur10-ipa"
SERIES_C = FIX / "Series_C" / "measurements_random_poses.csv"
SERIES_B = FIX / "Series_B" / "measurements_joint_configurations.csv"
MAP = FIX / "map.toml"
ROBOT = FIX / "robot.toml"
URDF = Path("/work/shared/real/urdf/ur10e.urdf")
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
FILES = ("robot.toml", "poses.csv", "tracker.csv", "campaign.toml")
ONE_LINE = re.compile(r"^jointcal: error: (?P<file>[^:]+):(?P<line>\d+|-):(?P<col>[^:]+): \S.*$")
# UR's published UR10e DH (/work/shared/real/urdf/README.md): a, alpha, d per joint
UR10E_DH = [(0.0, 90.0, 180.7), (-612.7, 0.0, 0.0), (-571.55, 0.0, 0.0), (0.0, 90.0, 174.15), (0.0, -90.0, 119.85),
            (0.0, 0.0, 116.55)]


def _source(path=SERIES_C) -> pd.DataFrame:
    return pd.read_csv(path, sep=";", decimal=",")


def _digest(folder) -> dict:
    return {f: hashlib.sha256((Path(folder) / f).read_bytes()).hexdigest() for f in FILES}


def _read(folder):
    poses = pd.read_csv(Path(folder) / "poses.csv", dtype={"point_id": str})
    tracker = pd.read_csv(Path(folder) / "tracker.csv", dtype={"point_id": str})
    return poses, tracker


def _fails(result, out, name=None):
    """Exit 2, exactly one line file:line:column: message, nothing written."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    m = ONE_LINE.match(lines[0])
    assert m, lines[0]
    assert not Path(out).exists()
    assert not list(Path(out).parent.glob(f".{Path(out).name}.import-*")), "temporary folder left behind"
    if name is not None:
        assert Path(m["file"]).name == name, lines[0]
    return m


# ------------------------------------------------------------------------- the real data
def test_series_c_import(invoke, tmp_path):
    out = tmp_path / "ur10c"
    result = invoke("import", "--source", SERIES_C, "--map", MAP, "--robot", ROBOT, "--out", out)
    assert result.exit_code == 0, result.output     # its speed: `make bench` (bench/real_bench.py, import_seconds)
    assert sorted(p.name for p in out.iterdir()) == sorted(FILES)
    poses, tracker = _read(out)
    src = _source()
    assert len(poses) == len(tracker) == 2773
    q_rad = src[JOINTS].to_numpy(float)
    np.testing.assert_allclose(poses[[f"q{j}" for j in range(1, 7)]].to_numpy(), q_rad * 180.0 / np.pi, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                               src[["measurement_x", "measurement_y", "measurement_z"]].to_numpy(float), rtol=0, atol=1e-9)
    np.testing.assert_allclose(poses["temperature_c"], src["measurement_temperature"], rtol=0, atol=1e-9)
    assert list(poses["point_id"]) == list(tracker["point_id"]) == [f"{i:04d}" for i in range(1, 2774)]
    assert "timestamp" not in poses
    # the T-Mac's spreads ([uncertainty]): per pose the RMS of the three axes' 1-sigma (issue 30)
    std = src[["measurement_std_x", "measurement_std_y", "measurement_std_z"]].to_numpy(float)
    np.testing.assert_allclose(tracker["sigma_mm"], np.sqrt(np.mean(std ** 2, axis=1)), rtol=0, atol=1e-9)
    assert {"qw", "qx", "qy", "qz", "sigma_arcsec"} <= set(tracker.columns)
    camp = (out / "campaign.toml").read_text()
    assert re.search(r'^frame = "tracker"$', camp, re.M)
    assert "measurements_random_poses.csv" in camp and "map.toml" in camp and str(tmp_path) not in camp
    copied, given = load_robot(out / "robot.toml"), load_robot(ROBOT)
    assert (copied.name, copied.joints, copied.tool_xyz_mm) == (given.name, given.joints, given.tool_xyz_mm)
    # ~60/40 seeded split over the whole series
    n_sample = int((poses["set"] == "sample").sum())
    assert n_sample == round(0.6 * 2773) and set(poses["set"]) == {"sample", "target"}
    first, last = (poses["set"].iloc[:1386] == "sample").mean(), (poses["set"].iloc[1386:] == "sample").mean()
    assert abs(first - 0.6) < 0.05 and abs(last - 0.6) < 0.05  # random, not a block


def test_split_is_seeded_same_bytes(invoke, tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for out in (a, b):
        assert invoke("import", "--source", SERIES_C, "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    assert _digest(a) == _digest(b)
    other = tmp_path / "seed2.toml"
    other.write_text(MAP.read_text().replace("seed = 1", "seed = 2"))
    assert invoke("import", "--source", SERIES_C, "--map", other, "--robot", ROBOT, "--out", c).exit_code == 0
    sa, sc = _read(a)[0]["set"], _read(c)[0]["set"]
    assert (sa == "sample").sum() == (sc == "sample").sum() and (sa != sc).any()
    # importing again over an existing folder replaces its files with the same bytes
    assert invoke("import", "--source", SERIES_C, "--map", MAP, "--robot", ROBOT, "--out", c).exit_code == 0
    assert _digest(c) == _digest(a)
    assert not list(tmp_path.glob(".*import-*"))


def test_one_map_for_both_series(invoke, tmp_path):
    out = tmp_path / "ur10b"
    assert invoke("import", "--source", SERIES_B, "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    poses, tracker = _read(out)
    src = _source(SERIES_B)
    assert len(poses) == 1495
    np.testing.assert_allclose(poses[[f"q{j}" for j in range(1, 7)]].to_numpy(), np.rad2deg(src[JOINTS].to_numpy(float)),
                               rtol=0, atol=1e-9)
    assert (poses["set"] == "sample").sum() == round(0.6 * 1495)


def test_nominal_residual_is_a_robots(tmp_path, invoke):
    """With the fixture's robot.toml the measured points sit a few mm from nominal (rigid fit)."""
    from pipeline.robot.campaign.importer import nominal_rms

    out = tmp_path / "c"
    assert invoke("import", "--source", SERIES_C, "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    poses, tracker = _read(out)
    rms = nominal_rms(load_robot(ROBOT), poses[[f"q{j}" for j in range(1, 7)]].to_numpy(),
                      tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(), "tracker")
    assert 0.3 < rms < 10.0, rms


def test_initial_transform_says_109_mm_where_the_hand_eye_fit_says_93():
    """The planning transform puts the probe 109 mm along flange z; robot.toml takes the hand-eye
    measurement instead (tests/test_real_reference.py refits it), which is about 16 mm shorter."""
    T = np.loadtxt(FIX / "Series_C" / "Trafo_TM_F_init.txt")
    smr = np.linalg.inv(T)[:3, 3]
    assert abs(smr[2] - 109.0) < 1e-3
    tool = np.array(load_robot(ROBOT).tool_xyz_mm)
    assert 14.0 < smr[2] - tool[2] < 18.0 and np.abs(tool[:2]).max() < 1.0


# ---------------------------------------------------------------------------------- URDF
def _urdf_positions(base, tip, Q):
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(URDF))
    data = model.createData()
    fb, ft = model.getFrameId(base), model.getFrameId(tip)
    ids = [model.joints[model.getJointId(n)].idx_q for n in JOINTS]
    out = np.empty((len(Q), 3))
    for k, q6 in enumerate(Q):
        q = pin.neutral(model)
        q[ids] = q6
        pin.framesForwardKinematics(model, data, q)
        out[k] = data.oMf[fb].actInv(data.oMf[ft]).translation * 1000.0
    return out


@pytest.mark.parametrize("base,tip", [("base", "tool0"), (None, "flange"), ("base_link", "tool0"),
                                      ("base", "ur10e_tooltip_link")])
def test_urdf_fk_matches_pinocchio(base, tip):
    from pipeline.robot.campaign.urdf import robot_from_urdf

    robot, info = robot_from_urdf(URDF, tip, base)
    assert info["chain"] == JOINTS and info["fk_max_error_mm"] < 1e-6
    Q = np.random.default_rng(7).uniform(-np.pi, np.pi, size=(60, 6))
    mine = positions(build_model(robot), Q, "smr")
    theirs = _urdf_positions(base or "world", tip, Q)
    assert np.abs(mine - theirs).max() < 1e-6
    # round trip through robot.toml
    again = parse_robot(robot.to_toml(), "x.toml")
    assert again.joints == robot.joints and again.tool_xyz_mm == robot.tool_xyz_mm


def test_urdf_gives_urs_published_dh():
    """In UR's own base frame the derived parameters are UR's published UR10e DH."""
    from pipeline.robot.campaign.urdf import robot_from_urdf

    robot, _ = robot_from_urdf(URDF, "tool0", "base")
    got = np.array([(j.a_mm, j.alpha_deg, j.d_mm) for j in robot.joints])
    np.testing.assert_allclose(got, np.array(UR10E_DH), rtol=0, atol=1e-6)
    assert all(abs(j.theta_offset_deg) < 1e-6 and j.beta_deg == 0.0 for j in robot.joints)
    assert robot.tool_xyz_mm == (0.0, 0.0, 0.0)
    assert [j.mass_kg for j in robot.joints][:5] == [7.778, 12.93, 3.87, 1.96, 1.96]
    assert robot.lower_deg[2] == -180.0 and robot.upper_deg[0] == 360.0
    # the published DH, written out, predicts the URDF's flange positions
    pub = Robot("ur10e", tuple(Joint(a_mm=a, alpha_deg=al, d_mm=d, theta_offset_deg=0.0, beta_deg=0.0,
                                     lower_deg=-360.0, upper_deg=360.0) for a, al, d in UR10E_DH), (0.0, 0.0, 0.0))
    Q = np.random.default_rng(3).uniform(-np.pi, np.pi, size=(50, 6))
    assert np.abs(positions(build_model(pub), Q, "smr") - _urdf_positions("base", "tool0", Q)).max() < 1e-3


def test_import_with_urdf_robot(invoke, tmp_path):
    """A source generated from the URDF imports against the URDF (base frame, metres, degrees)."""
    Q = np.random.default_rng(11).uniform(-150, 150, size=(40, 6))
    P = _urdf_positions("base", "tool0", np.deg2rad(Q)) + np.array([0.0, 0.0, 0.0])
    src = tmp_path / "export.csv"
    lines = ["id,j1,j2,j3,j4,j5,j6,x,y,z,split"] + [
        ",".join([f"P{i}"] + [f"{v:.9f}" for v in Q[i]] + [f"{v / 1000:.12f}" for v in P[i]]
                 + ["sample" if i % 3 else "target"]) for i in range(len(Q))]
    src.write_text("\n".join(lines) + "\n")
    mp = tmp_path / "map.toml"
    mp.write_text('[joints]\ncolumns = ["j1", "j2", "j3", "j4", "j5", "j6"]\nunit = "deg"\n'
                  '[position]\ncolumns = ["x", "y", "z"]\nunit = "m"\nframe = "base"\n'
                  '[columns]\npoint_id = "id"\n[split]\ncolumn = "split"\n')
    out = tmp_path / "camp"
    r = invoke("import", "--source", src, "--map", mp, "--robot", URDF, "--tip", "tool0", "--base", "base", "--out", out)
    assert r.exit_code == 0, r.output
    robot = load_robot(out / "robot.toml")
    assert np.allclose([j.d_mm for j in robot.joints], [d for _, _, d in UR10E_DH])
    poses, tracker = _read(out)
    assert list(poses["point_id"]) == [f"P{i}" for i in range(40)]
    assert list(poses["set"]) == ["sample" if i % 3 else "target" for i in range(40)]
    assert re.search(r'^frame = "base"$', (out / "campaign.toml").read_text(), re.M)
    nominal = positions(build_model(robot), np.deg2rad(poses[[f"q{j}" for j in range(1, 7)]].to_numpy()))
    assert np.abs(nominal - tracker[["x_mm", "y_mm", "z_mm"]].to_numpy()).max() < 1e-5
    # the same with an SMR offset given in the tip's frame
    out2 = tmp_path / "camp2"
    r = invoke("import", "--source", src, "--map", mp, "--robot", URDF, "--tip", "tool0", "--base", "base",
               "--tool-mm", "0", "0", "0", "--out", out2)
    assert r.exit_code == 0 and (out2 / "poses.csv").read_bytes() == (out / "poses.csv").read_bytes()


def test_robot_toml_round_trips(invoke, tmp_path):
    robot = load_robot(ROBOT)
    again = parse_robot(robot.to_toml(), "copy.toml")
    assert again.joints == robot.joints and again.tool_xyz_mm == robot.tool_xyz_mm and again.name == robot.name
    out = tmp_path / "c"
    assert invoke("import", "--source", SERIES_B, "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    copied = load_robot(out / "robot.toml")
    assert copied.joints == robot.joints and copied.tool_xyz_mm == robot.tool_xyz_mm
    # the campaign's robot.toml imports again to the same bytes
    out2 = tmp_path / "c2"
    assert invoke("import", "--source", SERIES_B, "--map", MAP, "--robot", out / "robot.toml", "--out", out2).exit_code == 0
    assert (out2 / "poses.csv").read_bytes() == (out / "poses.csv").read_bytes()


# ---------------------------------------------------------------------------- bad inputs
def _small_source(tmp_path, n=300, edit=None, path=SERIES_C):
    lines = path.read_bytes().decode().split("\r\n")[: n + 1]
    if edit:
        lines = edit(lines)
    out = tmp_path / "src.csv"
    out.write_text("\r\n".join(lines) + "\r\n", newline="")
    return out


def _map(tmp_path, fn):
    out = tmp_path / "bad_map.toml"
    out.write_text(fn(MAP.read_text()))
    return out


def _cell(lines, row, col, value):
    parts = lines[row].split(";")
    parts[col] = value
    lines[row] = ";".join(parts)
    return lines


def _rewrite(lines, columns, fn, fmt):
    """The source's lines with every value of ``columns`` replaced by ``fn(value)`` (decimal commas kept)."""
    head = lines[0].split(";")
    ix = [head.index(c) for c in columns]
    for k in range(1, len(lines)):
        parts = lines[k].split(";")
        for i in ix:
            parts[i] = format(fn(float(parts[i].replace(',', '.'))), fmt).replace(".", ",")
        lines[k] = ";".join(parts)
    return lines


def _metres(lines):
    return _rewrite(lines, ("measurement_x", "measurement_y", "measurement_z"), lambda v: v / 1000, ".9f")


BAD_MAPS = {
    # name: (map edit, expected file name, expected line or None, text in the message)
    "no joints section": (lambda t: re.sub(r"\[joints\].*?unit = \"rad\"\n", "", t, flags=re.S), "bad_map.toml", 1,
                          "[joints] section; it needs columns = [4 to 7 source columns]"),
    "no position columns": (lambda t: t.replace('columns = ["measurement_x", "measurement_y", "measurement_z"]\n', ""),
                            "bad_map.toml", None, "columns"),
    "misspelled column": (lambda t: t.replace('"measurement_y"', '"measurment_y"'), "bad_map.toml", 18,
                          "close: 'measurement_y'"),
    "misspelled joint": (lambda t: t.replace('"elbow_joint"', '"elbow"'), "bad_map.toml", 13, "elbow_joint"),
    "unknown joint unit": (lambda t: t.replace('unit = "rad"', 'unit = "radians"'), "bad_map.toml", 15, "rad"),
    "unknown length unit": (lambda t: t.replace('unit = "mm"', 'unit = "cm"'), "bad_map.toml", 19, "cm"),
    "bad delimiter": (lambda t: t.replace('delimiter = ";"', 'delimiter = ""'), "bad_map.toml", 9, "delimiter"),
    "bad decimal": (lambda t: t.replace('decimal = ","', 'decimal = ";"'), "bad_map.toml", 10, "decimal"),
    "wrong decimal": (lambda t: t.replace('decimal = ","', 'decimal = "."'), "src.csv", 2, "decimal comma"),
    "wrong delimiter": (lambda t: t.replace('delimiter = ";"', 'delimiter = "\\t"'), "bad_map.toml", 13,
                        "contains ';'"),
    "fraction 1": (lambda t: t.replace("sample_fraction = 0.6", "sample_fraction = 1"), "bad_map.toml", 26, "between"),
    "fraction 0": (lambda t: t.replace("sample_fraction = 0.6", "sample_fraction = 0.0"), "bad_map.toml", 26, "between"),
    "no split": (lambda t: re.sub(r"\[split\].*", "", t, flags=re.S), "bad_map.toml", 1, "[split]"),
    "radians labelled deg": (lambda t: t.replace('unit = "rad"', 'unit = "deg"'), "bad_map.toml", 15, 'unit = "rad"'),
    "unknown section": (lambda t: t.replace("[columns]", "[colums]"), "bad_map.toml", 22, "columns"),
    "unknown contract column": (lambda t: t.replace("temperature_c =", "temperature ="), "bad_map.toml", 23,
                                "temperature_c"),
    "split column missing": (lambda t: t.replace("sample_fraction = 0.6\nseed = 1", 'column = "set"'), "bad_map.toml",
                             26, "'set' is not in the header"),
    "not toml": (lambda t: t.replace("[split]", "[split"), "bad_map.toml", None, "TOML"),
}


@pytest.mark.parametrize("case", sorted(BAD_MAPS))
def test_bad_map(invoke, tmp_path, case):
    edit, name, line, text = BAD_MAPS[case]
    src = _small_source(tmp_path)
    mp = _map(tmp_path, edit)
    out = tmp_path / "deep" / "out"
    r = invoke("import", "--source", src, "--map", mp, "--robot", ROBOT, "--out", out)
    m = _fails(r, out, name)
    if line is not None:
        assert m["line"] == str(line), r.stderr
    assert text in r.stderr, r.stderr
    assert not (tmp_path / "deep").exists()


BAD_SOURCES = {
    "word in a joint column": (lambda ls: _cell(ls, 7, 9, "abc"), 8, "elbow_joint", "'abc' is not a number"),
    "nan position": (lambda ls: _cell(ls, 12, 14, "nan"), 13, "measurement_x", "finite"),
    "empty joint": (lambda ls: _cell(ls, 20, 7, ""), 21, "shoulder_pan_joint", "empty"),
    "short row": (lambda ls: ls[:30] + [";".join(ls[30].split(";")[:10])] + ls[31:], 31, "-", "fields"),
    "metres labelled mm": (_metres, None, None, "metres"),
    "out of range": (lambda ls: _cell(ls, 5, 8, "7,5"), 6, "shoulder_lift_joint", "range"),
}


@pytest.mark.parametrize("case", sorted(BAD_SOURCES))
def test_bad_source(invoke, tmp_path, case):
    edit, line, col, text = BAD_SOURCES[case]
    src = _small_source(tmp_path, edit=edit)
    out = tmp_path / "out"
    r = invoke("import", "--source", src, "--map", MAP, "--robot", ROBOT, "--out", out)
    m = _fails(r, out)
    if line is not None:
        assert (m["file"], m["line"], m["col"]) == (str(src), str(line), col), r.stderr
    else:
        assert m["file"] == str(MAP), r.stderr
    assert text in r.stderr, r.stderr


def _degrees(lines):
    return _rewrite(lines, JOINTS, np.rad2deg, ".6f")


def test_degrees_labelled_radians_name_the_unit_line_and_one_wild_value_does_not(invoke, tmp_path):
    # every joint value in degrees while the map says rad: most poses beyond the UR10's +-360 deg,
    # all of them inside in degrees -> the map's unit is named as the fix
    src = _small_source(tmp_path, edit=_degrees)
    out = tmp_path / "out"
    r = invoke("import", "--source", src, "--map", MAP, "--robot", ROBOT, "--out", out)
    m = _fails(r, out)
    assert m["file"] == str(src) and "range" in r.stderr, r.stderr
    assert 'every one is inside them in deg: set [joints] unit = "deg"' in r.stderr, r.stderr
    # one value out of range in radians data: no unit hint (as degrees it would fit, but the others are radians)
    src = _small_source(tmp_path, edit=lambda ls: _cell(ls, 5, 8, "7,5"))
    r = invoke("import", "--source", src, "--map", MAP, "--robot", ROBOT, "--out", out)
    _fails(r, out)
    assert "unit" not in r.stderr, r.stderr


def test_metres_far_from_the_tracker(invoke, tmp_path):
    """Metres labelled mm beyond 5 m still show: the nominal fits them only as metres."""
    def far(lines):
        lines = _metres(lines)
        head = lines[0].split(";")
        i = head.index("measurement_y")
        for k in range(1, len(lines)):
            parts = lines[k].split(";")
            parts[i] = f"{float(parts[i].replace(',', '.')) - 6.0:.9f}".replace(".", ",")
            lines[k] = ";".join(parts)
        return lines

    src = _small_source(tmp_path, edit=far)
    out = tmp_path / "out"
    r = invoke("import", "--source", src, "--map", MAP, "--robot", ROBOT, "--out", out)
    m = _fails(r, out, "map.toml")
    assert m["line"] == "19" and 'unit = "m"' in r.stderr, r.stderr


def test_one_unit_engine_for_import_and_ingest():
    """Positions in metres, labelled mm: the import's unit check and the ingest's nominal-consistency check
    read them through one engine (frame.unit_hypotheses, frame.refit) and agree on the reading and its RMS."""
    from pipeline.core.errors import InputError
    from pipeline.robot.campaign import frame as rf
    from pipeline.robot.campaign import importer as im

    src = _source().iloc[:300]
    q = np.rad2deg(src[JOINTS].to_numpy(float))
    m = src[["measurement_x", "measurement_y", "measurement_z"]].to_numpy(float) / 1000.0 - [0.0, 6.0, 0.0]
    robot = load_robot(ROBOT)
    # the readings, in the order tried; radians only when the caller allows them
    assert rf.other_units(("rad", "mm")) == [("rad", "m"), ("deg", "mm"), ("deg", "m")]
    assert rf.other_units(("deg", "mm"), radians=False) == [("deg", "m")]
    readings = {r: (qq, mm) for r, qq, mm in rf.unit_hypotheses(q, m, ("deg", "mm"))}
    assert list(readings) == [("deg", "m"), ("rad", "mm"), ("rad", "m")]
    assert readings[("deg", "m")][0] is q and np.array_equal(readings[("deg", "m")][1], m * 1000.0)
    np.testing.assert_array_equal(readings[("rad", "mm")][0], np.rad2deg(q))
    # ingest's check: the "metres" hypothesis
    c = rf.consistency(robot, q, m, frame="tracker")
    assert not c.ok and c.hypothesis == "metres" and c.tried["metres"] < 2.0, (c.hypothesis, c.tried)
    # the import (map: rad, mm, tracker): the map's [position] unit line, with the same refit's RMS
    camp = im.Campaign({}, q, m, None, [], {})
    with pytest.raises(InputError) as exc:
        im.check_units(camp, im.parse_map(MAP.read_text(), str(MAP)), robot, None)
    assert exc.value.line == 19 and exc.value.message.endswith('set [position] unit = "m"'), exc.value.message
    assert f"by {c.tried['metres']:.4g} mm with rad and m;" in exc.value.message, exc.value.message


def test_error_found_by_ingest_is_named_in_the_source(invoke, tmp_path):
    """ingest_robot runs on the built folder; what it refuses is named at the source's line and column."""
    src = _small_source(tmp_path, edit=lambda ls: _cell(ls, 9, 13, "-1,5"))
    mp = _map(tmp_path, lambda t: t.replace(
        'temperature_c = "measurement_temperature"',
        'temperature_c = "measurement_temperature"\npayload_kg = "measurement_temperature"'))
    out = tmp_path / "out"
    r = invoke("import", "--source", src, "--map", mp, "--robot", ROBOT, "--out", out)
    m = _fails(r, out, "src.csv")
    assert (m["line"], m["col"]) == ("10", "measurement_temperature") and "payload_kg" in r.stderr


def test_duplicate_point_id(invoke, tmp_path):
    src = _small_source(tmp_path, edit=lambda ls: _cell(_cell(ls, 4, 1, "7"), 9, 1, "7"))
    mp = _map(tmp_path, lambda t: t.replace('temperature_c = "measurement_temperature"', 'point_id = "Goal x"'))
    out = tmp_path / "out"
    m = _fails(invoke("import", "--source", src, "--map", mp, "--robot", ROBOT, "--out", out), out, "src.csv")
    assert (m["line"], m["col"]) == ("10", "Goal x")


def test_existing_folder_unchanged_on_error(invoke, tmp_path):
    out = tmp_path / "camp"
    assert invoke("import", "--source", _small_source(tmp_path), "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    before = _digest(out)
    bad = _small_source(tmp_path, edit=lambda ls: _cell(ls, 7, 9, "abc"))
    r = invoke("import", "--source", bad, "--map", MAP, "--robot", ROBOT, "--out", out)
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1
    assert _digest(out) == before and sorted(p.name for p in out.iterdir()) == sorted(FILES)
    assert not list(tmp_path.glob(".camp.import-*"))


@pytest.mark.parametrize("args,name,text", [
    (["--tip", "tool9"], "ur10e.urdf", "close: tool0"),
    ([], "ur10e.urdf", "--tip"),
    (["--tip", "wrist_3-flange"], "ur10e.urdf", "is a joint"),
    (["--tip", "tool0", "--base", "wall_link"], "ur10e.urdf", "--base LINK"),
    (["--tip", "tool0", "--base", "shoulder_link"], "ur10e.urdf", "fixed base"),
])
def test_bad_urdf_options(invoke, tmp_path, args, name, text):
    out = tmp_path / "out"
    r = invoke("import", "--source", _small_source(tmp_path), "--map", MAP, "--robot", URDF, "--out", out, *args)
    _fails(r, out, name)
    assert text in r.stderr, r.stderr


def test_tip_with_robot_toml_and_missing_files(invoke, tmp_path):
    out = tmp_path / "out"
    src = _small_source(tmp_path)
    _fails(invoke("import", "--source", src, "--map", MAP, "--robot", ROBOT, "--tip", "tool0", "--out", out), out,
           "robot.toml")
    _fails(invoke("import", "--source", tmp_path / "nope.csv", "--map", MAP, "--robot", ROBOT, "--out", out), out,
           "nope.csv")
    _fails(invoke("import", "--source", src, "--map", tmp_path / "nope.toml", "--robot", ROBOT, "--out", out), out,
           "nope.toml")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    _fails(invoke("import", "--source", empty, "--map", MAP, "--robot", ROBOT, "--out", out), out, "empty.csv")


def test_urdf_base_not_on_joint_1_is_refused(tmp_path):
    """A base frame whose z is not joint 1's axis cannot be written as DH: refused, located."""
    from pipeline.core.errors import InputError
    from pipeline.robot.campaign.urdf import robot_from_urdf

    text = URDF.read_text().replace('<origin rpy="0.0 0.0 -1.5707963" xyz="0.0 0.0 0.90"/>',
                                    '<origin rpy="0.3 0.0 -1.5707963" xyz="0.0 0.0 0.90"/>')
    bad = tmp_path / "tilted.urdf"
    bad.write_text(text)
    with pytest.raises(InputError) as exc:
        robot_from_urdf(bad, "tool0")
    assert exc.value.line and "--base LINK" in exc.value.message and "base_link" in exc.value.message
    robot, info = robot_from_urdf(bad, "tool0", "base")   # UR's own base frame still works
    assert info["fk_max_error_mm"] < 1e-6


@pytest.mark.parametrize("what,file,line", [
    ("swapped joints", "bad_map.toml", "13"),
    ("base frame", "bad_map.toml", "20"),
    ("wrong tool", "r.toml", "22"),
])
def test_nominal_check_refusals_point_at_the_fix(invoke, tmp_path, what, file, line):
    """The nominal-consistency check of ingest runs on the imported folder; its refusal names the map or robot line."""
    mp, robot = MAP, ROBOT
    if what == "swapped joints":
        mp = _map(tmp_path, lambda t: t.replace('"shoulder_lift_joint", "elbow_joint"', '"elbow_joint", "shoulder_lift_joint"'))
    elif what == "base frame":
        mp = _map(tmp_path, lambda t: t.replace('frame = "tracker"', 'frame = "base"'))
    else:
        robot = tmp_path / "r.toml"
        text = ROBOT.read_text()
        robot.write_text(text.replace("xyz_mm = [-0.26, 0.3, 93.21]", "xyz_mm = [0.0, 0.0, 600.0]"))
        assert robot.read_text() != text
    out = tmp_path / "out"
    m = _fails(invoke("import", "--source", _small_source(tmp_path, 600), "--map", mp, "--robot", robot, "--out", out),
               out, file)
    assert m["line"] == line


def test_imported_campaign_validates(invoke, tmp_path):
    out = tmp_path / "c"
    assert invoke("import", "--source", SERIES_C, "--map", MAP, "--robot", ROBOT, "--out", out).exit_code == 0
    r = invoke("validate", "--campaign", out)
    assert r.exit_code == 0, r.stderr


def _urdf_of(robot: Robot) -> str:
    """A URDF of a contract robot: joint i at L_{i-1} Rz(theta_offset_i), link i's mass at L_i com_i, SMR link."""
    import pinocchio as pin

    from pipeline.robot.arm.kinematics import link_placement

    def origin(M):
        rpy = pin.rpy.matrixToRpy(M.rotation)
        return (f'<origin xyz="{" ".join(repr(float(v)) for v in M.translation)}" '
                f'rpy="{" ".join(repr(float(v)) for v in rpy)}"/>')

    parts = ['<?xml version="1.0"?>', '<robot name="made">', '<link name="base"/>']
    prev, parent = pin.SE3.Identity(), "base"
    for i, j in enumerate(robot.joints):
        M = prev * pin.SE3(pin.utils.rotate("z", np.deg2rad(j.theta_offset_deg)), np.zeros(3))
        L = link_placement(j)
        com = L.act(np.asarray(j.com_mm) / 1000.0)
        parts += [f'<link name="l{i + 1}"><inertial><origin xyz="{" ".join(repr(float(v)) for v in com)}"/>'
                  f'<mass value="{j.mass_kg!r}"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
                  '</inertial></link>',
                  f'<joint name="j{i + 1}" type="revolute"><parent link="{parent}"/><child link="l{i + 1}"/>'
                  f'{origin(M)}<axis xyz="0 0 1"/><limit lower="{float(np.deg2rad(j.lower_deg))!r}" '
                  f'upper="{float(np.deg2rad(j.upper_deg))!r}" effort="1" velocity="1"/></joint>']
        prev, parent = L, f"l{i + 1}"
    tip = prev * pin.SE3(np.eye(3), np.asarray(robot.tool_xyz_mm) / 1000.0)
    parts += ['<link name="smr"/>', f'<joint name="smr_fix" type="fixed"><parent link="l6"/><child link="smr"/>'
              f'{origin(tip)}</joint>', "</robot>"]
    return "\n".join(parts) + "\n"


def _random_robot(seed) -> Robot:
    rng = np.random.default_rng(seed)
    joints = []
    for i in range(6):
        joints.append(Joint(a_mm=float(rng.choice([0.0, rng.uniform(-800, 800)])),
                            alpha_deg=float(rng.choice([0.0, 90.0, -90.0, rng.uniform(-170, 170)])),
                            d_mm=float(rng.choice([0.0, rng.uniform(-500, 500)])),
                            theta_offset_deg=float(rng.choice([0.0, rng.uniform(-179, 179)])), beta_deg=0.0,
                            lower_deg=-170.0, upper_deg=170.0, mass_kg=float(rng.uniform(0.5, 50)),
                            com_mm=tuple(float(v) for v in rng.uniform(-200, 200, 3))))
    return Robot(f"r{seed}", tuple(joints), tuple(float(v) for v in rng.uniform(-100, 200, 3)))


@pytest.mark.parametrize("which", ["kr210", 1, 2, 3, 4, 5])
def test_urdf_of_a_contract_robot_comes_back(tmp_path, which):
    """robot.toml -> URDF -> derived robot: the same SMR positions and the same gravity torques."""
    from pipeline.robot.arm.kinematics import gravity_torques
    from pipeline.robot.campaign.urdf import robot_from_urdf

    robot = load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml") if which == "kr210" else _random_robot(which)
    path = tmp_path / "made.urdf"
    path.write_text(_urdf_of(robot))
    derived, info = robot_from_urdf(path, "smr")
    assert info["fk_max_error_mm"] < 1e-6
    Q = np.random.default_rng(5).uniform(np.deg2rad(robot.lower_deg), np.deg2rad(robot.upper_deg), size=(50, 6))
    assert np.abs(positions(build_model(derived), Q) - positions(build_model(robot), Q)).max() < 1e-6
    assert np.allclose(derived.lower_deg, robot.lower_deg) and np.allclose(derived.upper_deg, robot.upper_deg)
    tau0 = gravity_torques(robot, np.rad2deg(Q))
    tau1 = gravity_torques(derived, np.rad2deg(Q))
    assert np.abs(tau1 - tau0).max() < 1e-6 * max(1.0, np.abs(tau0).max())


def test_unreadable_urdf_is_one_located_line(invoke, tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text(URDF.read_text().replace('lower="-3.141592653589793" upper="3.141592653589793"',
                                            'lower="abc" upper="3.141592653589793"'))
    out = tmp_path / "out"
    m = _fails(invoke("import", "--source", _small_source(tmp_path), "--map", MAP, "--robot", bad, "--tip", "tool0",
                      "--out", out), out, "bad.urdf")
    assert m["line"] == "434"          # <joint name="elbow_joint" type="revolute">
    broken = tmp_path / "broken.urdf"
    broken.write_text(URDF.read_text().replace('<child link="shoulder_link"/>', '<child link="shoulder_link">'))
    _fails(invoke("import", "--source", _small_source(tmp_path), "--map", MAP, "--robot", broken, "--tip", "tool0",
                  "--out", out), out, "broken.urdf")


def _stamped(lines, bad_row=None):
    """The source's lines with the (spreadsheet-damaged) Timestamp replaced by a logger's compact
    YYYYMMDDhhmmss, one pose every 20 s from 2020-07-14 16:39:04; ``bad_row``'s is 31 July's 25 o'clock."""
    import datetime as dt

    t0 = dt.datetime(2020, 7, 14, 16, 39, 4)
    for k in range(1, len(lines)):
        if lines[k]:
            stamp = (t0 + dt.timedelta(seconds=20 * (k - 1))).strftime("%Y%m%d%H%M%S")
            lines = _cell(lines, k, 0, "20200731250000" if k == bad_row else stamp)
    return lines


def _timestamp_map(tmp_path, fmt):
    extra = f'timestamp_format = "{fmt}"\n' if fmt else ""
    return _map(tmp_path, lambda t: t.replace('decimal = ","\n', 'decimal = ","\n' + extra)
                .replace('temperature_c = "measurement_temperature"',
                         'temperature_c = "measurement_temperature"\ntimestamp = "Timestamp"'))


def test_a_loggers_compact_timestamp_is_read_by_the_maps_format(invoke, tmp_path):
    src = _small_source(tmp_path, n=60, edit=_stamped)
    out = tmp_path / "stamped"
    r = invoke("import", "--source", src, "--map", _timestamp_map(tmp_path, "%Y%m%d%H%M%S"), "--robot", ROBOT,
               "--out", out)
    assert r.exit_code == 0, r.output
    poses = pd.read_csv(out / "poses.csv", dtype={"point_id": str, "timestamp": str})
    expected = pd.Timestamp("2020-07-14T16:39:04") + pd.to_timedelta(20 * np.arange(60), unit="s")
    assert list(pd.to_datetime(poses["timestamp"], format="ISO8601")) == list(expected)
    # the imported campaign is one a fit reads (its timestamps pass the campaign's own ISO-8601 check)
    fit = invoke("fit", "--campaign", out, "--spec", ROOT / "specs" / "robot_kinematic.toml", "--out",
                 tmp_path / "fit.json")
    assert fit.exit_code == 0, fit.output


def test_a_timestamp_that_is_not_iso_or_not_the_maps_format_is_named_in_the_source(invoke, tmp_path):
    src = _small_source(tmp_path, n=40, edit=lambda ls: _stamped(ls, bad_row=7))
    for fmt, line, text in ((None, 2, "timestamp_format"), ("%Y%m%d%H%M%S", 8, "'20200731250000' does not match")):
        out = tmp_path / f"out{line}"
        r = invoke("import", "--source", src, "--map", _timestamp_map(tmp_path, fmt), "--robot", ROBOT, "--out", out)
        m = _fails(r, out)
        assert (m["file"], m["line"], m["col"]) == (str(src), str(line), "Timestamp"), r.stderr
        assert text in r.stderr, r.stderr
    # the shipped series' own timestamps are damaged ("2,02011E+13"): named, not read as some time
    out = tmp_path / "damaged"
    r = invoke("import", "--source", _small_source(tmp_path, n=40), "--map", _timestamp_map(tmp_path, "%Y%m%d%H%M%S"),
               "--robot", ROBOT, "--out", out)
    m = _fails(r, out)
    assert (m["line"], m["col"]) == ("2", "Timestamp"), r.stderr


# --------------------------------------------------- a user's URDF: messages in its own terms
FANUC_LIKE = ROOT / "tests" / "data" / "urdf" / "fanuc_like.urdf"   # synthetic, ROS-Industrial style


def _fanuc_like_export(tmp_path, smr_in_link6_mm, n=60, seed=3):
    """A synthetic tracker export of the FANUC-like URDF's arm (tracker frame, 0.05 mm noise): an SMR
    at ``smr_in_link6_mm`` in link_6's frame; the source and its map."""
    import pinocchio as pin

    m = pin.buildModelFromUrdf(str(FANUC_LIKE))
    d = m.createData()
    fid = m.getFrameId("link_6")
    rng = np.random.default_rng(seed)
    Q = rng.uniform([-150, -50, -60, -180, -110, -180], [150, 60, 80, 180, 110, 180], (n, 6))
    R = pin.exp3(np.array([0.1, -0.2, 0.7]))
    P = []
    for q in np.deg2rad(Q):
        pin.framesForwardKinematics(m, d, q)
        P.append(R @ d.oMf[fid].act(np.asarray(smr_in_link6_mm, float) / 1000.0) * 1000.0 + [2500.0, -300.0, 150.0])
    P = np.array(P) + rng.normal(0.0, 0.05, (n, 3))
    src = tmp_path / "fanuc.csv"
    src.write_text("\n".join(["id,j1,j2,j3,j4,j5,j6,x,y,z"] + [
        ",".join([f"P{i}"] + [f"{v:.6f}" for v in Q[i]] + [f"{v:.4f}" for v in P[i]]) for i in range(n)]) + "\n")
    mp = tmp_path / "fanuc_map.toml"
    mp.write_text('[joints]\ncolumns = ["j1", "j2", "j3", "j4", "j5", "j6"]\nunit = "deg"\n'
                  '[position]\ncolumns = ["x", "y", "z"]\nunit = "mm"\nframe = "tracker"\n'
                  '[columns]\npoint_id = "id"\n[split]\nsample_fraction = 0.6\nseed = 1\n')
    return src, mp


def test_wrong_tool_suggestion_can_be_typed_in_the_tip_links_frame(invoke, tmp_path):
    """With --tip link_6 and no tool, import suggests the SMR in link_6's frame, as --tool-mm takes it, and
    the message names the URDF (not robot.toml); typed back, the suggestion imports. (Before: the SMR in
    the internal DH flange frame, [195.2, 46.6, -204.5], refused again when typed.)"""
    src, mp = _fanuc_like_export(tmp_path, (204.5, 46.6, 195.2))
    out = tmp_path / "camp"
    m = _fails(invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6", "--out", out),
               out, "fanuc_like.urdf")
    line = invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6",
                  "--out", out).stderr
    assert "robot.toml" not in line and "fanuc_like.urdf (--tip link_6)" in line, line
    typed = re.search(r"\(--tool-mm (\S+) (\S+) (\S+)\)", line)
    assert typed, line
    assert np.allclose([float(v) for v in typed.groups()], [204.5, 46.6, 195.2], atol=0.15)
    assert m["line"] == "31"                     # the <link name="link_6"> element
    r = invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6",
               "--tool-mm", *typed.groups(), "--out", out)
    assert r.exit_code == 0, r.output


def test_headerless_space_separated_export(invoke, tmp_path):
    """[source] header = false with columns by number (and delimiter = " ": runs of spaces) imports the same
    campaign as the file with a header; a headerless file read as headed, or a column number beyond its
    fields, is named as a file without a header. (Before: "column '16' is not in the header (line 1)".)"""
    src, mp = _fanuc_like_export(tmp_path, (204.5, 46.6, 195.2), n=30)
    rows = src.read_text().splitlines()[1:]
    bare = tmp_path / "bare.txt"
    bare.write_text("".join("  ".join(r.split(",")) + " \n" for r in rows))
    numbered = tmp_path / "numbered.toml"
    numbered.write_text('[source]\ndelimiter = " "\nheader = false\n'
                        '[joints]\ncolumns = [2, 3, 4, 5, 6, 7]\nunit = "deg"\n'
                        '[position]\ncolumns = [8, 9, 10]\nunit = "mm"\nframe = "tracker"\n'
                        '[columns]\npoint_id = 1\n[split]\nsample_fraction = 0.6\nseed = 1\n')
    robot = ("--robot", FANUC_LIKE, "--tip", "link_6", "--tool-mm", "204.5", "46.6", "195.2")
    a, b = tmp_path / "a", tmp_path / "b"
    assert invoke("import", "--source", src, "--map", mp, *robot, "--out", a).exit_code == 0
    r = invoke("import", "--source", bare, "--map", numbered, *robot, "--out", b)
    assert r.exit_code == 0, r.output
    for f in ("poses.csv", "tracker.csv"):
        assert (a / f).read_bytes() == (b / f).read_bytes()
    # the map of the headed file on the headerless one: named as a file without a header
    headed = tmp_path / "headed.toml"
    headed.write_text(mp.read_text().replace("[joints]", '[source]\ndelimiter = " "\n[joints]'))
    out = tmp_path / "c"
    m = _fails(invoke("import", "--source", bare, "--map", headed, *robot, "--out", out), out, "headed.toml")
    line = invoke("import", "--source", bare, "--map", headed, *robot, "--out", out).stderr
    assert ("line 1 is numbers (9 of its 10 fields), not column names: a file without a header; set [source] "
            "header = false" in line), line
    assert m["line"] == "4"                          # [joints] columns, at "j1"
    # a column number beyond the fields
    beyond = tmp_path / "beyond.toml"
    beyond.write_text(numbered.read_text().replace("[8, 9, 10]", "[8, 9, 16]"))
    m = _fails(invoke("import", "--source", bare, "--map", beyond, *robot, "--out", out), out, "beyond.toml")
    line = invoke("import", "--source", bare, "--map", beyond, *robot, "--out", out).stderr
    assert "column 16 is beyond the 10 fields of line 1 of bare.txt (a file without a header" in line, line
    assert (m["line"], m["col"]) == ("8", "18")      # the 16 in [position] columns
    # a name where the file has none
    named = tmp_path / "named.toml"
    named.write_text(numbered.read_text().replace("[8, 9, 10]", '[8, "y", 10]'))
    _fails(invoke("import", "--source", bare, "--map", named, *robot, "--out", out), out, "named.toml")


def test_a_urdf_without_inertials_is_warned_about(invoke, tmp_path):
    """A URDF without <inertial> on the arm's links imports with every mass 0, and says so: no gravity
    torque, so compliance can be neither fitted nor revealed. With them, no warning."""
    src, mp = _fanuc_like_export(tmp_path, (204.5, 46.6, 195.2), n=30)
    bare = tmp_path / "no_inertia.urdf"
    bare.write_text(re.sub(r"\s*<inertial>.*?</inertial>", "", FANUC_LIKE.read_text(), flags=re.S))
    assert "<inertial>" not in bare.read_text()
    args = ("--tip", "link_6", "--tool-mm", "204.5", "46.6", "195.2")
    r = invoke("import", "--source", src, "--map", mp, "--robot", bare, *args, "--out", tmp_path / "a")
    assert r.exit_code == 0, r.output
    assert "warning: no_inertia.urdf has no <inertial> on the arm's links: every mass is 0" in r.stderr, r.stderr
    assert all(j.mass_kg == 0 for j in load_robot(tmp_path / "a" / "robot.toml").joints)
    r = invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, *args, "--out", tmp_path / "b")
    assert r.exit_code == 0 and "warning" not in r.stderr, r.stderr


def test_fit_headline_says_the_rank_not_only_what_is_left_at_nominal(invoke, tmp_path):
    """On a URDF robot with one SMR, geometry + base + tool has 12 combinations of parameters the SMR never
    sees: fit's headline says the rank (27 of 39) beside "0 parameter(s) left at nominal"."""
    src, mp = _fanuc_like_export(tmp_path, (204.5, 46.6, 195.2), n=60)
    camp = tmp_path / "camp"
    assert invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6", "--tool-mm",
                  "204.5", "46.6", "195.2", "--out", camp).exit_code == 0
    r = invoke("fit", "--campaign", camp, "--spec", ROOT / "specs" / "robot_kinematic.toml", "--out", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    head = next(ln for ln in r.stderr.splitlines() if "left at nominal" in ln)
    assert "rank 27 of 39 parameters: 12 combination(s)" in head, head


def _coupled_export(tmp_path, coupling_line=""):
    """The FANUC-like export with joint 3 as a FANUC pendant records it (J3 = q3 - q2: the arm's joint 3
    turns by J2 + J3), and its map (``coupling_line`` added to [joints])."""
    src, mp = _fanuc_like_export(tmp_path, (204.5, 46.6, 195.2), n=60)
    rows = src.read_text().splitlines()
    out = [rows[0]]
    for r in rows[1:]:
        f = r.split(",")
        f[3] = f"{float(f[3]) - float(f[2]):.6f}"
        out.append(",".join(f))
    src.write_text("\n".join(out) + "\n")
    mp.write_text(mp.read_text().replace('unit = "deg"\n', 'unit = "deg"\n' + coupling_line, 1))
    return src, mp


def test_coupled_joints_are_named_as_a_cause_and_imported_as_stated(invoke, tmp_path):
    """J3 recorded as a FANUC pendant shows it (the J2/J3 interaction): import names the coupling as the likely
    cause, with the line to write; with [joints] coupling the campaign imports, poses.csv keeps the recorded
    angles, robot.toml carries [coupling] and the campaign's nominal check passes on the coupled angles.
    (Before: refused at ~700 mm with no coupling among the causes tried.)"""
    args = ("--robot", FANUC_LIKE, "--tip", "link_6", "--tool-mm", "204.5", "46.6", "195.2")
    src, mp = _coupled_export(tmp_path)
    out = tmp_path / "camp"
    _fails(invoke("import", "--source", src, "--map", mp, *args, "--out", out), out, mp.name)
    line = invoke("import", "--source", src, "--map", mp, *args, "--out", out).stderr
    assert "joint 3's recorded angle looks coupled to joint 2's (q3 + q2 fits" in line, line
    assert "[joints] coupling = { q3 = { q2 = 1, q3 = 1 } }" in line, line
    src, mp = _coupled_export(tmp_path, "coupling = { q3 = { q2 = 1, q3 = 1 } }\n")
    r = invoke("import", "--source", src, "--map", mp, *args, "--out", out)
    assert r.exit_code == 0, r.output
    robot = load_robot(out / "robot.toml")
    assert robot.coupling == ((2, (0.0, 1.0, 1.0, 0.0, 0.0, 0.0)),)
    poses, _ = _read(out)
    given = pd.read_csv(src)
    assert np.allclose(poses["q3"], given["j3"])                 # the recorded angle, as recorded
    from pipeline.robot.campaign.ingest import robot_data_from_campaign

    _, data = robot_data_from_campaign(out, sets=("sample", "target"))
    ids = list(poses["point_id"])
    assert np.allclose(data.q_deg[:, 2], (given["j3"] + given["j2"]).to_numpy()[[ids.index(p) for p in data.point_id]])


def test_coupled_robot_is_corrected_in_the_controllers_angles(invoke, tmp_path):
    """correct --targets on a coupled robot (FANUC J2/J3): targets and corrected commands are the controller's
    angles; the fitted model, at the angles the corrected commands give the arm (J2 + J3 for joint 3), puts
    the SMR where the nominal robot put the given ones."""
    src, mp = _coupled_export(tmp_path, "coupling = { q3 = { q2 = 1, q3 = 1 } }\n")
    camp = tmp_path / "camp"
    assert invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6", "--tool-mm",
                  "204.5", "46.6", "195.2", "--out", camp).exit_code == 0
    fit = tmp_path / "fit.json"
    r = invoke("fit", "--campaign", camp, "--spec", ROOT / "specs" / "robot_kinematic.toml", "--out", fit)
    assert r.exit_code == 0, r.output
    poses, _ = _read(camp)
    given = poses[poses["set"] == "sample"].head(8)[["point_id"] + [f"q{j}" for j in range(1, 7)]]
    given.to_csv(tmp_path / "targets.csv", index=False)
    r = invoke("correct", "--model", fit, "--targets", tmp_path / "targets.csv", "--out", tmp_path / "out.csv")
    assert r.exit_code == 0, r.output
    out = pd.read_csv(tmp_path / "out.csv")
    assert (out["status"] == "ok").all(), out["status"].tolist()
    import json

    from pipeline.correct.robot import ModelKinematics
    from pipeline.robot.model.predict import load_model_document

    robot, _, model, _, _ = load_model_document(json.loads(fit.read_text()), str(fit))
    kin = ModelKinematics(robot, model)
    qg = given[[f"q{j}" for j in range(1, 7)]].to_numpy(float)
    qc = out[[f"q{j}" for j in range(1, 7)]].to_numpy(float)
    n = len(qg)
    meant = kin.nominal(robot.kinematic_angles(qg))[1]
    lands = kin.predict(robot.kinematic_angles(qc), np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0))
    assert np.abs(lands - meant).max() < 1e-3                      # mm
    assert np.allclose(out[[f"dq{j}_arcsec" for j in range(1, 7)]].to_numpy(), (qc - qg) * 3600.0, atol=1e-3)


def _nest_export(tmp_path, n=60, seed=5, wild=None):
    """A synthetic export of the FANUC-like arm measured as three SMRs on a nest on link_6 (tracker frame,
    0.02 mm noise): SMR 1 at (204.5, 46.6, 195.2) mm in link_6's frame, SMR 2 100 mm along its y, SMR 3
    80 mm along its -z. ``wild``: (row, mm) moves SMR 2 of that row along x."""
    import pinocchio as pin

    m = pin.buildModelFromUrdf(str(FANUC_LIKE))
    d = m.createData()
    fid = m.getFrameId("link_6")
    rng = np.random.default_rng(seed)
    Q = rng.uniform([-150, -50, -60, -180, -110, -180], [150, 60, 80, 180, 110, 180], (n, 6))
    s1 = np.array([204.5, 46.6, 195.2])
    smrs = [s1, s1 + [0.0, 100.0, 0.0], s1 + [0.0, 0.0, -80.0]]
    Rt, tt = pin.exp3(np.array([0.1, -0.2, 0.7])), np.array([2500.0, -300.0, 150.0])
    rows = []
    for i, q in enumerate(np.deg2rad(Q)):
        pin.framesForwardKinematics(m, d, q)
        pts = [Rt @ d.oMf[fid].act(s / 1000.0) * 1000.0 + tt + rng.normal(0, 0.02, 3) for s in smrs]
        if wild is not None and i == wild[0]:
            pts[1] = pts[1] + [wild[1], 0.0, 0.0]
        rows.append(",".join([f"P{i}"] + [f"{v:.6f}" for v in Q[i]] + [f"{v:.4f}" for p in pts for v in p]))
    src = tmp_path / "nest.csv"
    src.write_text("\n".join(["id,j1,j2,j3,j4,j5,j6,x1,y1,z1,x2,y2,z2,x3,y3,z3"] + rows) + "\n")
    mp = tmp_path / "nest_map.toml"
    mp.write_text('[joints]\ncolumns = ["j1", "j2", "j3", "j4", "j5", "j6"]\nunit = "deg"\n'
                  '[position]\ncolumns = ["x1", "y1", "z1"]\nunit = "mm"\nframe = "tracker"\n'
                  '[orientation]\nkind = "nest"\ncolumns = ["x2", "y2", "z2", "x3", "y3", "z3"]\n'
                  '[columns]\npoint_id = "id"\n[split]\nsample_fraction = 0.6\nseed = 1\n')
    return src, mp


def test_a_nest_of_three_smrs_is_read_as_position_and_orientation(invoke, tmp_path):
    """[orientation] kind = "nest": SMR 1 is the position, SMRs 2 and 3 give the probe frame's orientation;
    the campaign imports as a 6-DoF campaign whose orientations fit the nominal flange frames (the nest's
    mounting estimated); an SMR off its nest at one pose is refused at that row."""
    src, mp = _nest_export(tmp_path)
    out = tmp_path / "camp"
    r = invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6", "--tool-mm",
               "204.5", "46.6", "195.2", "--out", out)
    assert r.exit_code == 0, r.output
    tracker = pd.read_csv(out / "tracker.csv")
    assert {"qw", "qx", "qy", "qz"} <= set(tracker.columns)
    rms = float(re.search(r"miss the measured probe frames by ([\d.]+) deg", r.stderr).group(1))
    assert rms < 0.05, r.stderr                     # 0.02 mm on a 100 mm nest: hundredths of a degree
    robot = load_robot(out / "robot.toml")
    assert any(v != 0 for v in robot.tool_rpy_deg)  # the nest's mounting, estimated from the data
    src, mp = _nest_export(tmp_path, wild=(7, 3.0))
    m = _fails(invoke("import", "--source", src, "--map", mp, "--robot", FANUC_LIKE, "--tip", "link_6",
                      "--tool-mm", "204.5", "46.6", "195.2", "--out", out.with_name("c2")), out.with_name("c2"),
               "nest.csv")
    assert m["line"] == "9" and m["col"] == "x2"
