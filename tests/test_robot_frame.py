"""Tracker frame (campaign.toml ``frame = "tracker"``) and the nominal-consistency check (contract section 2)."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from conftest import ROOT
from pipeline.core.errors import InputError
from pipeline.robot.campaign import frame as rf

KR210 = ROOT / "raw" / "robot" / "kr210"


# ------------------------------------------------------------------------------ helpers
def _rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return rf._exp_so3(axis * np.deg2rad(deg))


R_TRACKER = _rotation([0.3, -0.2, 1.0], 137.0)        # base -> tracker, a tracker standing somewhere in the cell
T_TRACKER = np.array([2400.0, -3100.0, 850.0])       # mm


def _copy(tmp_path, name="cell"):
    dst = tmp_path / name
    shutil.copytree(KR210, dst)
    return dst


def _csv(path):
    return pd.read_csv(path, dtype=str, keep_default_na=False)


def _write(frame, path):
    frame.to_csv(path, index=False)


def _edit_numbers(path, columns, fn):
    """Apply fn to the (n, k) float array of ``columns``; written back with full precision."""
    f = _csv(path)
    v = fn(f[columns].astype(float).to_numpy())
    for k, c in enumerate(columns):
        f[c] = [repr(float(x)) for x in v[:, k]]
    _write(f, path)


def _move_tracker(folder, R=R_TRACKER, t=T_TRACKER):
    """Express the campaign's points in a tracker frame: p_tracker = R p_base + t."""
    _edit_numbers(folder / "tracker.csv", ["x_mm", "y_mm", "z_mm"], lambda p: rf.apply(R, t, p))


def _frame_toml(folder, frame="tracker"):
    (folder / "campaign.toml").write_text(f'frame = "{frame}"\n')


def _widen_limits(folder):
    """Joint limits of +-360 deg (as a real robot's): only the consistency check can catch a wrong column then."""
    text = (folder / "robot.toml").read_text()
    text = re.sub(r"(?m)^lower_deg = .*$", "lower_deg = -360.0", text)
    text = re.sub(r"(?m)^upper_deg = .*$", "upper_deg = 360.0", text)
    (folder / "robot.toml").write_text(text)


def _ingest(folder, out):
    from pipeline.cli import cli

    return CliRunner().invoke(cli, ["ingest", "--campaign", str(folder), "--out", str(out)])


def _refused(folder, tmp_path):
    """Ingest must exit 2 with one located line and write nothing; the line is returned."""
    out = tmp_path / "poses.parquet"
    r = _ingest(folder, out)
    assert r.exit_code == 2, (r.output, r.exception)
    lines = [s for s in r.stderr.splitlines() if s.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("jointcal: error: ") and "Traceback" not in r.output
    assert not out.exists()
    return lines[0]


def _q(folder):
    return _csv(folder / "poses.csv")


def _line_of(folder, fname, point_id):
    ids = _csv(folder / fname)["point_id"].tolist()
    return ids.index(point_id) + 2


# --------------------------------------------------------------------------- rigid_fit
def test_rigid_fit_recovers_a_known_transform():
    rng = np.random.default_rng(3)
    src = rng.uniform(-1500, 1500, (50, 3))
    R, t = R_TRACKER, T_TRACKER
    dst = rf.apply(R, t, src)
    R2, t2 = rf.rigid_fit(src, dst)
    assert np.allclose(R2, R, atol=1e-12) and np.allclose(t2, t, atol=1e-9)
    assert np.isclose(np.linalg.det(R2), 1.0)
    # inverse direction is the inverse transform; 4x4 round trip
    Ri, ti = rf.rigid_fit(dst, src)
    assert np.allclose(Ri, R.T, atol=1e-12) and np.allclose(ti, -R.T @ t, atol=1e-9)
    assert np.allclose(rf.from_matrix(rf.to_matrix(R, t))[1], t)
    assert np.isclose(rf.rotation_angle_deg(R), 137.0)
    # with noise: close, and the residual is the noise
    noisy = dst + rng.normal(0, 0.05, dst.shape)
    R3, t3, err = rf.fit_residuals(src, noisy)
    assert rf.rotation_angle_deg(R3 @ R.T) < 0.01 and np.linalg.norm(t3 - t) < 0.2
    assert 0.03 < rf.rms(err) < 0.12
    # weights: zero-weighted wild points do not move the fit
    wild = dst.copy()
    wild[:5] += 1000.0
    w = np.r_[np.zeros(5), np.ones(45)]
    R4, t4 = rf.rigid_fit(src, wild, w)
    assert np.allclose(R4, R, atol=1e-12) and np.allclose(t4, t, atol=1e-8)


def test_rigid_fit_never_returns_a_reflection_and_refuses_degenerate_input():
    rng = np.random.default_rng(4)
    src = rng.normal(size=(20, 3)) * 100
    R, _ = rf.rigid_fit(src, src * [1, 1, -1])        # a mirror image: best proper rotation, not the mirror
    assert np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(ValueError, match="collinear"):
        rf.rigid_fit(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [3, 2, 1]))
    with pytest.raises(ValueError, match="at least 3"):
        rf.rigid_fit(src[:2], src[:2])
    with pytest.raises(ValueError, match="shape"):
        rf.rigid_fit(src, src[:, :2])


# ------------------------------------------------------------------------ frame = tracker
def test_tracker_frame_ingests_to_the_same_base_frame_points(tmp_path):
    from pipeline.robot.campaign.ingest import ingest_robot, ingest_robot_with_frame

    a = _copy(tmp_path, "a")
    _frame_toml(a)
    b = _copy(tmp_path, "b")
    _move_tracker(b)
    _frame_toml(b)
    _, ta = ingest_robot(a)
    robot, tb, info = ingest_robot_with_frame(b)
    pa = ta[["x_mm", "y_mm", "z_mm"]].to_numpy()
    pb = tb[["x_mm", "y_mm", "z_mm"]].to_numpy()
    assert np.abs(pa - pb).max() < 1e-6
    # the raw points are kept
    moved = _csv(b / "tracker.csv").set_index("point_id").loc[tb["point_id"], ["x_mm", "y_mm", "z_mm"]].astype(float)
    assert np.abs(tb[["x_tracker_mm", "y_tracker_mm", "z_tracker_mm"]].to_numpy() - moved.to_numpy()).max() < 1e-9
    # the transform found is the inverse of the one applied, up to the cell's own base error (0.1 mm, 0.01 deg)
    assert info["frame"] == "tracker" and tb.attrs["jointcal_frame"]["frame"] == "tracker"
    R, t = rf.from_matrix(info["tracker_to_base"])
    Ri, ti = rf.invert(R_TRACKER, T_TRACKER)
    assert rf.rotation_angle_deg(R @ Ri.T) < 0.05 and np.linalg.norm(t - ti) < 2.0
    # and the base-frame points are the shipped ones to the same precision
    base = _csv(KR210 / "tracker.csv").set_index("point_id").loc[tb["point_id"], ["x_mm", "y_mm", "z_mm"]].astype(float)
    assert np.abs(pb - base.to_numpy()).max() < 0.5
    # a base-frame campaign carries identity
    _, tk = ingest_robot(KR210)
    assert tk.attrs["jointcal_frame"] == {"frame": "base", "tracker_to_base": np.eye(4).tolist()}
    assert "x_tracker_mm" not in tk


def test_ingest_writes_the_transform_and_states_it(tmp_path):
    from pipeline.core.files import parquet_metadata, read_parquet

    b = _copy(tmp_path, "b")
    _move_tracker(b)
    _frame_toml(b)
    out = tmp_path / "b.parquet"
    r = _ingest(b, out)
    assert r.exit_code == 0, r.output
    assert re.search(r"translation \[.*\] mm .*rotation 13[67]\.\d\d deg", r.stderr), r.stderr
    meta = parquet_metadata(out)
    assert meta["frame"] == "tracker"
    T = np.array(meta["tracker_to_base"])
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    assert str(b / "campaign.toml") in meta["inputs"]
    table = read_parquet(out)
    raw = table[["x_tracker_mm", "y_tracker_mm", "z_tracker_mm"]].to_numpy()
    assert np.abs(rf.apply(T[:3, :3], T[:3, 3], raw) - table[["x_mm", "y_mm", "z_mm"]].to_numpy()).max() < 1e-6
    # a robot command reading the table gets the frame back
    from pipeline.cli.robot import _interim

    assert _interim(out).attrs["jointcal_frame"]["frame"] == "tracker"


def test_validate_refuses_tracker_frame_points_without_frame_tracker(tmp_path):
    from pipeline.cli import cli

    b = _copy(tmp_path, "b")
    _move_tracker(b)
    r = CliRunner().invoke(cli, ["validate", "--campaign", str(b)])
    assert r.exit_code == 2
    lines = [s for s in r.stderr.splitlines() if s.strip()]
    assert len(lines) == 1 and f"{b / 'tracker.csv'}:" in lines[0]
    assert "add frame = \"tracker\" to campaign.toml" in lines[0]
    _frame_toml(b, "base")                              # saying base explicitly changes nothing
    assert "tracker's frame" in _refused(b, tmp_path)
    _frame_toml(b)
    r = CliRunner().invoke(cli, ["validate", "--campaign", str(b)])
    assert r.exit_code == 0 and "no problems found" in r.stderr


def test_shipped_campaign_passes_validate():
    from pipeline.cli import cli

    r = CliRunner().invoke(cli, ["validate", "--campaign", str(KR210)])
    assert r.exit_code == 0 and "no problems found" in r.stderr, r.output


@pytest.mark.parametrize("text,where,what", [
    ('frame = "trackr"\n', "campaign.toml:1:9", "not one of"),
    ('frame = "tracker"\nfaces = 36\n', "campaign.toml:2:9", "unknown key 'faces'"),
    ('frame = tracker\n', "campaign.toml:1:", "not valid TOML"),
])
def test_campaign_toml_problems_are_located(tmp_path, text, where, what):
    c = _copy(tmp_path)
    (c / "campaign.toml").write_text(text)
    line = _refused(c, tmp_path)
    assert where in line and what in line, line


def test_tracker_frame_needs_sample_poses(tmp_path):
    c = _copy(tmp_path)
    _frame_toml(c)
    f = _csv(c / "poses.csv")
    f["set"] = f["set"].replace("sample", "target")
    _write(f, c / "poses.csv")
    line = _refused(c, tmp_path)
    assert "poses.csv:" in line and ":set:" in line and "at least 3 sample poses" in line


# ------------------------------------------------------------------- corrupted campaigns
def _radians(c):
    _edit_numbers(c / "poses.csv", [f"q{j}" for j in range(1, 7)], np.deg2rad)


def _metres(c):
    _edit_numbers(c / "tracker.csv", ["x_mm", "y_mm", "z_mm"], lambda p: p / 1000.0)


def _flip(j):
    def edit(c):
        _edit_numbers(c / "poses.csv", [f"q{j}"], lambda q: -q)
    return edit


def _swap(j, k):
    def edit(c):
        f = _csv(c / "poses.csv")
        f[f"q{j}"], f[f"q{k}"] = f[f"q{k}"].copy(), f[f"q{j}"].copy()
        _write(f, c / "poses.csv")
    return edit


def _tool_off(c):
    text = (c / "robot.toml").read_text()
    text = text.replace("xyz_mm = [60.0, 40.0, 120.0]", "xyz_mm = [60.0, 40.0, 320.0]")
    assert "320.0" in text
    (c / "robot.toml").write_text(text)


def _widened(edit):
    def both(c):
        _widen_limits(c)
        edit(c)
    return both


def _far_tracker_in_metres(c):
    # a tracker 8 m away, coordinates exported in metres: the "every value below 5" check cannot see it
    _move_tracker(c, R_TRACKER, np.array([8000.0, -6000.0, 900.0]))
    _metres(c)
    _frame_toml(c)


def _wild_point(c):
    f = _csv(c / "tracker.csv")
    f.loc[17, "x_mm"] = repr(float(f.loc[17, "x_mm"]) + 400.0)
    _write(f, c / "tracker.csv")


def _shuffled_ids(c):
    f = _csv(c / "tracker.csv")
    f["point_id"] = f["point_id"].sample(frac=1.0, random_state=5).to_numpy()
    _write(f, c / "tracker.csv")


def _tracker_frame(c):
    _move_tracker(c)


# the cause as the error carries it for callers (InputError.hypothesis); None: an earlier check refused
HYPOTHESIS = {"radians": "radians", "metres": "metres", "sign_q1": "sign1", "sign_q4": "sign4", "sign_q5": "sign5",
              "swap_q1_q4": "swap14", "swap_q5_q6": "swap56", "tool_200mm_off": "tool",
              "tracker_frame_without_frame": "frame", "one_wild_point": "outlier", "nothing_explains": ""}


def _hypothesis_of(folder):
    from pipeline.robot.campaign.ingest import load_robot_campaign

    with pytest.raises(InputError) as exc:
        load_robot_campaign(folder)
    return getattr(exc.value, "hypothesis", None)


CORRUPTIONS = [
    # (name, edit, file:column the line names, words of the likely cause)
    ("radians_range_check", _radians, ("poses.csv", None), "looks like radians"),
    ("radians", _widened(_radians), ("poses.csv", "q1"), "joint angles look like radians"),
    ("metres_value_check", _metres, ("tracker.csv", "x_mm"), "look like metres"),
    ("metres", _far_tracker_in_metres, ("tracker.csv", "x_mm"), "look like metres (x 1000 fits"),
    ("sign_q1", _flip(1), ("poses.csv", "q1"), "joint 1's sign looks flipped"),
    ("sign_q4", _flip(4), ("poses.csv", "q4"), "joint 4's sign looks flipped"),
    ("sign_q2_range_check", _flip(2), ("poses.csv", "q2"), "joint 2's sign looks flipped"),
    ("sign_q5", _widened(_flip(5)), ("poses.csv", "q5"), "joint 5's sign looks flipped"),
    ("swap_q2_q3_range_check", _swap(2, 3), ("poses.csv", "q2"), "q2 and q3 look swapped"),
    ("swap_q1_q4", _widened(_swap(1, 4)), ("poses.csv", "q1"), "joints 1 and 4 look swapped"),
    ("swap_q5_q6", _widened(_swap(5, 6)), ("poses.csv", "q5"), "joints 5 and 6 look swapped"),
    ("tool_200mm_off", _tool_off, ("robot.toml", None), "a wrong tool"),
    ("tracker_frame_without_frame", _tracker_frame, ("tracker.csv", "x_mm"), "add frame = \"tracker\""),
    ("one_wild_point", _wild_point, ("tracker.csv", "x_mm"), "wrong measurement"),
    ("nothing_explains", _shuffled_ids, ("tracker.csv", "x_mm"), "none of the usual causes"),
]


@pytest.mark.parametrize("name,edit,where,cause", CORRUPTIONS, ids=[c[0] for c in CORRUPTIONS])
def test_corrupted_campaign_is_refused_with_its_likely_cause(tmp_path, name, edit, where, cause):
    c = _copy(tmp_path)
    edit(c)
    line = _refused(c, tmp_path)
    fname, column = where
    m = re.match(r"jointcal: error: (.*?):(\d+):([^:]+): (.*)$", line)
    assert m, line
    path, lineno, col, message = m.group(1), int(m.group(2)), m.group(3), m.group(4)
    assert path == str(c / fname), line
    assert _hypothesis_of(c) == HYPOTHESIS.get(name), (name, line)
    assert cause in message, line
    if column is not None:
        assert col == column, line
    if fname == "robot.toml":
        assert (c / "robot.toml").read_text().splitlines()[lineno - 1].startswith("xyz_mm"), line
    if "worst pose" in message:                            # the line is the worst pose's line in that file
        pid = re.search(r"worst pose (\S+):", message).group(1)
        if fname in ("poses.csv", "tracker.csv"):
            assert lineno == _line_of(c, fname, pid), line
    if name == "one_wild_point":
        assert lineno == 17 + 2 and "is 4" in message
    if name == "tool_200mm_off":
        assert "[60." in message and "120." in message   # the tool the points say


def test_real_robot_errors_pass_and_corruption_fails_in_library():
    """The thresholds: a realistic robot error (a 16 mm tool error, 0.05 deg joint offsets) passes."""
    from dataclasses import replace

    from pipeline.robot.arm.kinematics import build_model, load_robot, positions

    robot = load_robot(KR210 / "robot.toml")
    q = _q(KR210)[[f"q{j}" for j in range(1, 7)]].astype(float).to_numpy()
    true = replace(robot, tool_xyz_mm=(60.0, 40.0, 104.0))
    meas = positions(build_model(true), np.deg2rad(q + 0.05))
    meas = rf.apply(_rotation([1, 1, 0], 0.2), [1.0, -2.0, 0.5], meas)
    c = rf.consistency(robot, q, meas, frame="base")
    assert c.ok and c.rms_mm < rf.MAX_RMS_MM
    bad = rf.consistency(robot, np.deg2rad(q), meas, frame="base")
    assert not bad.ok and bad.hypothesis == "radians" and abs(bad.tried["radians"] - c.rms_mm) < 1e-6


def test_every_hypothesis_is_tried_when_none_explains():
    # its speed (goal 0.1 s clean, 1 s with every hypothesis) is measured by `make bench` (bench/real_bench.py)
    from pipeline.robot.arm.kinematics import build_model, load_robot

    robot = load_robot(KR210 / "robot.toml")
    poses = _q(KR210)
    q = poses[[f"q{j}" for j in range(1, 7)]].astype(float).to_numpy()
    t = _csv(KR210 / "tracker.csv").set_index("point_id").loc[poses["point_id"], ["x_mm", "y_mm", "z_mm"]]
    meas = t.astype(float).to_numpy()
    model = build_model(robot)
    assert rf.consistency(robot, q, meas, model=model).ok
    bad = rf.consistency(robot, -q, meas, model=model)     # no single cause: every hypothesis tried
    # radians, metres, 6 signs, 15 swaps, 5 couplings to the joint before (+ and -), the tool
    assert not bad.ok and not bad.hypothesis and len(bad.tried) == 1 + 1 + 6 + 15 + 2 * 5 + 1


# ------------------------------------------------------------------ already ingested tables
def test_interim_table_is_checked_too(tmp_path):
    """A table that no longer fits its nominal kinematics is refused by the commands that read it."""
    import pyarrow.parquet as pq

    from pipeline.cli.robot import _interim
    from pipeline.core.files import parquet_metadata, write_parquet

    c = _copy(tmp_path)
    out = tmp_path / "poses.parquet"
    assert _ingest(c, out).exit_code == 0
    assert len(_interim(out)) > 0
    meta = parquet_metadata(out)
    table = pq.read_table(out).to_pandas()
    tampered = table.copy()
    tampered["x_mm"] = tampered["x_mm"] / 1000.0
    bad = tmp_path / "bad.parquet"
    write_parquet(bad, tampered, meta)
    # its campaign is fine: the table itself is named, stale
    with pytest.raises(InputError, match="stale") as exc:
        _interim(bad)
    assert exc.value.path == str(bad) and exc.value.column == "x_mm"
    # its campaign is corrupted now: the campaign's located error with the likely cause
    _flip(1)(c)
    with pytest.raises(InputError, match="joint 1's sign looks flipped") as exc:
        _interim(bad)
    assert exc.value.path == str(c / "poses.csv")
    # and a robot command exits 2 with one line
    from pipeline.cli import cli

    r = CliRunner().invoke(cli, ["robot", "calibrate", "--interim", str(bad), "--robot", str(c / "robot.toml"),
                                 "--spec", str(ROOT / "specs/robot_paper.toml"), "--out", str(tmp_path / "m.json")])
    lines = [s for s in r.stderr.splitlines() if s.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and "sign looks flipped" in lines[0]
    assert not (tmp_path / "m.json").exists()
