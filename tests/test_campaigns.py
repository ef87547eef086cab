"""Several campaigns of one robot fitted together (contract section 15, issue 52): ``jointcal fit --campaign A
--campaign B``. The campaigns are simulated (synthetic): one virtual KR210 cell measured twice, the second time
in another region of its joint space and from another tracker station (the points moved by a known rigid
transform, ``campaign.toml`` frame = "tracker"). The pipeline never reads the generator's truth; the tests
only compare with the transform they applied themselves and with fits of the same data arranged otherwise.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker

SPEC = ROOT / "specs" / "robot_kinematic.toml"


def _rot(axis, deg):
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


#: the second tracker station: where a point of the robot's base frame lies in that tracker's frame
MOVE_R = _rot(2, 35.0) @ _rot(0, 4.0)
MOVE_T = np.array([2500.0, -800.0, 150.0])


def _moved(folder: Path, out: Path, R=MOVE_R, t=MOVE_T) -> Path:
    """A copy of ``folder`` seen from another tracker station: every point x -> R x + t, frame = "tracker"."""
    shutil.copytree(folder, out)
    tracker = pd.read_csv(out / "tracker.csv", dtype={"point_id": str})
    xyz = tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(float) @ R.T + t
    tracker[["x_mm", "y_mm", "z_mm"]] = np.round(xyz, 4)
    tracker.to_csv(out / "tracker.csv", index=False)
    (out / "campaign.toml").write_text('frame = "tracker"\n', encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    """Campaign ``a`` (the simulated KR210 cell's own campaign, base frame), ``b`` (the same cell measured at
    poses with joint 1 turned the other way (q1 -> -q1), from the second station, the same point ids), ``b_base`` (b's
    points in the base frame, as one station would have measured them)."""
    root = tmp_path_factory.mktemp("campaigns")
    run = cli_invoker()
    a = root / "a"
    a.mkdir()
    shutil.copy(ROOT / "raw" / "robot" / "kr210" / "robot.toml", a / "robot.toml")
    truth = root / "truth.json"
    r = run("simulate", "robot", "--campaign", a, "--truth", truth, "--seed", "52")
    assert r.exit_code == 0, r.output
    poses = pd.read_csv(a / "poses.csv", dtype={"point_id": str})
    # both campaigns alike: the commanded angles of every joint (the cell's gratings of joints 1-3 left out)
    poses.drop(columns=[c for c in poses if c.startswith("grating")]).to_csv(a / "poses.csv", index=False)
    poses = poses[poses["set"].isin(["sample", "target"])]
    other = poses[["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg", "temperature_c"]].copy()
    other["q1"] = -other["q1"]
    pose_file = root / "b_poses.csv"
    other.to_csv(pose_file, index=False)
    b_base = root / "b_base"
    r = run("simulate", "measure", "--truth", truth, "--poses", pose_file, "--campaign", b_base)
    assert r.exit_code == 0, r.output
    b = _moved(b_base, root / "b")
    return {"root": root, "a": a, "b": b, "b_base": b_base, "run": run}


def _fit(cells, name, *campaigns, spec=SPEC):
    out = cells["root"] / f"{name}.json"
    args = ["fit"] + [x for c in campaigns for x in ("--campaign", c)] + ["--spec", spec, "--out", out]
    r = cells["run"](*args)
    assert r.exit_code == 0, r.output
    return json.loads(out.read_text()), r.output


def test_two_stations_recover_each_frame(cells):
    """Fitted together, each campaign keeps its own tracker frame: b's fitted tracker-to-base is the inverse of the
    station move the test applied (to what the spec leaves unexplained), nearer than the ingest's rigid
    registration on the nominal robot alone; a's is its own (the base frame); held-out errors per campaign."""
    doc, console = _fit(cells, "ab", cells["a"], cells["b"])
    entries = doc["campaigns"]
    assert [e["campaign"] for e in entries] == [str(cells["a"]), str(cells["b"])]
    assert "campaign_frame" in doc["effects"]
    assert [p["name"] for p in doc["parameters"] if p["name"].startswith("campaign2_")] == [
        f"campaign2_{t}" for t in ("dx", "dy", "dz", "ex", "ey", "ez")]
    # the truth of the station: tracker -> base is the inverse of the move
    true_T = np.eye(4)
    true_T[:3, :3], true_T[:3, 3] = MOVE_R.T, -MOVE_R.T @ MOVE_T
    pts = pd.read_csv(cells["b"] / "tracker.csv")[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    P = np.c_[pts, np.ones(len(pts))]

    def off(T):
        return float(np.max(np.linalg.norm((P @ np.asarray(T).T - P @ true_T.T)[:, :3], axis=1)))

    fitted, registered = off(entries[1]["tracker_to_base_fitted"]), off(entries[1]["frame"]["tracker_to_base"])
    # the kinematic spec leaves the cell's compliance and transmission errors (0.06 mm RMS held out): the frame
    # is that close, and twice nearer than the registration on the nominal robot
    assert fitted < 0.08, (fitted, registered)
    assert fitted < registered / 2, (fitted, registered)
    assert np.allclose(entries[0]["tracker_to_base_fitted"], np.eye(4))
    for e in entries:
        h = e["heldout"]
        assert h["n_target"] > 50 and h["rms_after_mm"] < 0.7 * h["rms_before_mm"], e
    # totals over both campaigns beside them
    n = doc["heldout"]["n_target"]
    assert n == sum(e["heldout"]["n_target"] for e in entries)
    total = np.sqrt(sum(e["heldout"]["n_target"] * e["heldout"]["rms_after_mm"] ** 2 for e in entries) / n)
    assert doc["heldout"]["rms_after_mm"] == pytest.approx(total, rel=1e-5)
    # the console shows them side by side
    assert "held-out targets per campaign" in console and str(cells["b"]) in console


def test_two_stations_share_the_robot(cells):
    """The robot's shared parameters: the model fitted on a and b (two stations, two frames) predicts as the model
    fitted on the same measurements from one station (b's points in the base frame, one campaign)."""
    together, _ = _fit(cells, "ab2", cells["a"], cells["b"])
    one = cells["root"] / "one"
    one.mkdir()
    shutil.copy(cells["a"] / "robot.toml", one / "robot.toml")
    parts = []
    for name in ("a", "b_base"):
        p = pd.read_csv(cells[name] / "poses.csv", dtype={"point_id": str})
        t = pd.read_csv(cells[name] / "tracker.csv", dtype={"point_id": str})
        p = p[p["set"].isin(["sample", "target"])]
        keep = ["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg", "temperature_c"]
        both = p[keep].merge(t, on="point_id")
        both["point_id"] = name + "_" + both["point_id"]
        parts.append(both)
    merged = pd.concat(parts, ignore_index=True)
    merged[keep].to_csv(one / "poses.csv", index=False)
    merged[["point_id", "x_mm", "y_mm", "z_mm"] + (["sigma_mm"] if "sigma_mm" in merged else [])].to_csv(
        one / "tracker.csv", index=False)
    single, _ = _fit(cells, "one", one)
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.predict import load_model_document

    robot, (data,) = robot_data_sets(one, ("sample", "target"))
    _, _, m_two, _, _ = load_model_document(together, "two")
    _, _, m_one, _, _ = load_model_document(single, "one")
    diff = np.linalg.norm(m_two.predict(data) - m_one.predict(data), axis=1)
    # apart by a fraction of what the kinematic spec leaves unexplained (0.17 mm RMS held out): the second frame's
    # six parameters take a little of it
    assert diff.max() < 0.06 and np.sqrt(np.mean(diff ** 2)) < 0.03, diff
    # the frame's six parameters are determined, each with its stated uncertainty (a tenth of a mm, tens of arcsec)
    u = {p["name"]: p["uncertainty"] for p in together["parameters"] if p["name"].startswith("campaign2_")}
    assert len(u) == 6 and all(0 < v < (0.5 if k[-2] == "d" else 60.0) for k, v in u.items()), u


def test_a_twin_from_another_station_changes_no_robot_parameter(cells):
    """The same measurements seen from a second station add nothing about the robot: fitted with their twin, the
    robot's parameters are those of the campaign alone, and both campaigns' held-out errors are its own."""
    alone, _ = _fit(cells, "a_alone", cells["a"])
    twin = _moved(cells["a"], cells["root"] / "a_twin", _rot(1, -20.0), np.array([-300.0, 1800.0, -90.0]))
    both, _ = _fit(cells, "a_twin", cells["a"], twin)
    mine = {p["name"]: p for p in alone["parameters"]}
    for p in both["parameters"]:
        if p["name"] in mine:
            # equal to within a hundredth of the parameter's uncertainty (the solver's own convergence)
            q = mine[p["name"]]
            assert abs(p["value"] - q["value"]) <= 0.01 * q["uncertainty"] + 1e-9, (p, q)
    for e in both["campaigns"]:
        assert e["heldout"]["rms_after_mm"] == pytest.approx(alone["heldout"]["rms_after_mm"], rel=1e-4)


def test_a_campaign_given_once_fits_as_before(cells):
    """--campaign once: the fit of one campaign, as before this change (no campaign frame, no per-campaign list);
    the same bytes as the library's one-campaign fit writes."""
    doc, _ = _fit(cells, "once", cells["a"])
    assert "campaigns" not in doc and "campaign_frame" not in doc["effects"]
    assert doc["campaign"] == str(cells["a"])
    from pipeline.core.spec import load_spec
    from pipeline.robot.model.fit import fit_campaign

    from pipeline.core.files import write_json

    write_json(cells["root"] / "lib.json", fit_campaign(cells["a"], load_spec(SPEC)))
    lib = json.loads((cells["root"] / "lib.json").read_text())
    doc.pop("provenance")
    assert lib == doc


def _refused(cells, *campaigns):
    out = cells["root"] / "refused.json"
    args = ["fit"] + [x for c in campaigns for x in ("--campaign", c)] + ["--spec", SPEC, "--out", out]
    r = cells["run"](*args)
    lines = [x for x in r.output.splitlines() if x.strip()]
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    assert not out.exists()
    errors = [x for x in lines if "error" in x]
    assert len(errors) == 1, r.output
    return errors[0]


def test_the_same_campaign_twice_is_refused(cells):
    line = _refused(cells, cells["a"], str(cells["a"]) + "/")
    assert f"{cells['a']}/poses.csv" in line and "twice" in line


def test_a_campaign_of_another_robot_is_refused(cells):
    other = cells["root"] / "other_robot"
    shutil.copytree(cells["b"], other)
    text = (other / "robot.toml").read_text(encoding="utf-8")
    # another arm of the same family: its third link 5 mm longer
    import re

    k = [m.start() for m in re.finditer(r"(?m)^\s*a_mm\s*=", text)][2]
    end = text.index("\n", k)
    value = float(text[k:end].split("=")[1])
    (other / "robot.toml").write_text(text[:k] + f"a_mm = {value + 5.0}" + text[end:], encoding="utf-8")
    line = _refused(cells, cells["a"], other)
    assert f"{other}/robot.toml" in line and "one robot" in line


def test_predict_each_campaign_in_its_own_frame(cells):
    """predict --campaign more than once: each campaign's errors and the totals; a campaign the model was fitted on
    is predicted in its own fitted frame, so its errors are the fit's held-out ones (the second station's would be
    off by its whole frame otherwise)."""
    fit, _ = _fit(cells, "ab3", cells["a"], cells["b"])
    out = cells["root"] / "pred.json"
    r = cells["run"]("predict", "--campaign", cells["a"], "--campaign", cells["b"], "--model",
                     cells["root"] / "ab3.json", "--json", out)
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert [c["campaign"] for c in doc["campaigns"]] == [str(cells["a"]), str(cells["b"])]
    for c, e in zip(doc["campaigns"], fit["campaigns"]):
        assert c["n"] == e["heldout"]["n_target"]
        assert c["rms_mm"] == pytest.approx(e["heldout"]["rms_after_mm"], rel=1e-4)
    assert doc["n"] == sum(c["n"] for c in doc["campaigns"]) == len(doc["points"])
    assert {p["campaign"] for p in doc["points"]} == {str(cells["a"]), str(cells["b"])}
    assert 0.0 < doc["coverage_95"] <= 1.0
    # the same point ids in both campaigns: told apart by their campaign
    ids = [(p["campaign"], p["point_id"]) for p in doc["points"]]
    assert len(set(ids)) == len(ids) > len({p["point_id"] for p in doc["points"]})
    assert "all campaigns" in r.output


def test_several_encoder_campaigns_are_refused(cells):
    """--campaign more than once is for robot campaigns of one robot: an encoder campaign among them is named."""
    line = _refused(cells, cells["a"], ROOT / "raw" / "encoder" / "a")
    assert str(ROOT / "raw" / "encoder" / "a") in line and "not a robot campaign" in line


def test_a_campaign_with_its_own_probe_mounting_keeps_it(cells):
    """A campaign whose probe was mounted elsewhere (its robot.toml's [tool] says where; here the SMR 3 mm further
    out along the flange's x and 2 mm along z, its points measured there) fits with the others: its own mounting is
    taken as stated, its own mounting error fitted (``campaign_tool``, near zero: the SMR moved exactly as stated),
    and its held-out errors are those of the same poses measured with the first campaign's mounting."""
    import re

    from pipeline.robot.arm.kinematics import build_model, load_robot, placements

    shift = np.array([3.0, 0.0, 2.0])
    moved = cells["root"] / "b_tool_base"
    shutil.copytree(cells["b_base"], moved)
    robot = load_robot(moved / "robot.toml")
    poses = pd.read_csv(moved / "poses.csv", dtype={"point_id": str})
    tracker = pd.read_csv(moved / "tracker.csv", dtype={"point_id": str})
    q = poses.set_index("point_id").loc[tracker["point_id"], [f"q{j}" for j in range(1, 7)]].to_numpy(float)
    R, _ = placements(build_model(robot), np.deg2rad(q), "flange")
    xyz = tracker[["x_mm", "y_mm", "z_mm"]].to_numpy(float) + np.einsum("nij,j->ni", R, shift)
    tracker[["x_mm", "y_mm", "z_mm"]] = np.round(xyz, 4)
    tracker.to_csv(moved / "tracker.csv", index=False)
    text = (moved / "robot.toml").read_text(encoding="utf-8")
    m = re.search(r"(?m)^xyz_mm\s*=\s*\[([^\]]*)\]", text)
    tool = np.array([float(v) for v in m.group(1).split(",")]) + shift
    (moved / "robot.toml").write_text(text[:m.start()] + f"xyz_mm = {tool.tolist()}" + text[m.end():], encoding="utf-8")
    b_tool = _moved(moved, cells["root"] / "b_tool")
    ref, _ = _fit(cells, "ab_ref", cells["a"], cells["b"])
    doc, _ = _fit(cells, "ab_tool", cells["a"], b_tool)
    assert "campaign_tool" in doc["effects"]
    entry = doc["campaigns"][1]
    assert entry["mounting"]["tool_xyz_mm"] == pytest.approx(tool.tolist())
    own = {p["name"]: p for p in doc["parameters"] if p["name"].startswith("campaign2_tool_")}
    assert len(own) == 3
    # the SMR moved exactly as stated: its own mounting error is within its uncertainty of zero (and small)
    assert all(abs(p["value"]) < max(3 * p["uncertainty"], 0.02) for p in own.values()), own
    for a, b in zip(doc["campaigns"], ref["campaigns"]):
        assert a["heldout"]["rms_after_mm"] == pytest.approx(b["heldout"]["rms_after_mm"], rel=0.05, abs=0.005)
    # predict takes that campaign's mounting too (its errors are the fit's held-out ones)
    out = cells["root"] / "pred_tool.json"
    r = cells["run"]("predict", "--campaign", b_tool, "--model", cells["root"] / "ab_tool.json", "--json", out)
    assert r.exit_code == 0, r.output
    assert json.loads(out.read_text())["rms_mm"] == pytest.approx(entry["heldout"]["rms_after_mm"], rel=1e-4)
