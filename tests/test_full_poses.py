"""Full poses (contract section 13): a 6-DoF probe's orientation read, checked, fitted, held out and
held on the robot; on a virtual 6-DoF cell and on the real UR10 series (a T-Mac)."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker, six_dof_cell

SPEC = (ROOT / "specs" / "robot_cell.toml").read_text() + """[[effect]]
name = "joint_harmonic"
joints = [2]
orders = [7]
"""
KINEMATIC = ROOT / "specs" / "robot_kinematic.toml"
KR210 = ROOT / "raw" / "robot" / "kr210" / "robot.toml"
IPA = ROOT / "raw" / "real" / "ur10-ipa"
SERIES_C = IPA / "Series_C" / "measurements_random_poses.csv"
ONE_LINE = re.compile(r"^jointcal: error: (?P<file>[^:]+):(?P<line>\d+|-):(?P<col>[^:]+): \S.*$")
POINT = np.array([0.0, 0.0, 300.0])      # a tool point 300 mm out along the probe's z


def _q(frame, n=6):
    return frame[[f"q{j}" for j in range(1, n + 1)]].to_numpy(float)


def _one_line_error(result, column=None):
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    m = ONE_LINE.match(lines[0])
    assert m, lines[0]
    if column is not None:
        assert m["col"] == column, lines[0]
    return m


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A 6-DoF cell (KR210, hidden joint harmonic on joint 2) measured without gratings, and its models."""
    tmp = tmp_path_factory.mktemp("cell6")
    run = cli_invoker()
    six_dof_cell(tmp / "cell", tmp / "truth.json", 3, "--hidden", "joint_harmonic:2")
    poses = pd.read_csv(tmp / "cell" / "poses.csv")
    prog = poses[poses["set"] != "repeat"][["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg"]]
    prog.to_csv(tmp / "measure.csv", index=False)
    r = run("simulate", "measure", "--truth", tmp / "truth.json", "--poses", tmp / "measure.csv",
            "--campaign", tmp / "meas")
    assert r.exit_code == 0, r.output
    (tmp / "spec.toml").write_text(SPEC)
    fits = {}
    for name, extra in (("full", ()), ("positions", ("--positions-only",))):
        r = run("fit", "--campaign", tmp / "meas", "--spec", tmp / "spec.toml", "--out", tmp / f"{name}.json", *extra)
        assert r.exit_code == 0, r.output
        fits[name] = json.loads((tmp / f"{name}.json").read_text())
    return {"tmp": tmp, "run": run, "fits": fits}


def test_a_6dof_cell_measures_the_same_positions_as_its_smr_cell(cell, tmp_path):
    """--probe 6dof adds the probe's orientation; the positions are the SMR cell's, draw for draw."""
    run = cli_invoker()
    (tmp_path / "smr").mkdir()
    shutil.copy(KR210, tmp_path / "smr" / "robot.toml")
    r = run("simulate", "robot", "--campaign", tmp_path / "smr", "--truth", tmp_path / "truth.json", "--seed", "3",
            "--hidden", "joint_harmonic:2")
    assert r.exit_code == 0, r.output
    six = pd.read_csv(cell["tmp"] / "cell" / "tracker.csv")
    smr = pd.read_csv(tmp_path / "smr" / "tracker.csv")
    assert list(smr.columns) == ["point_id", "x_mm", "y_mm", "z_mm", "sigma_mm"]
    assert {"qw", "qx", "qy", "qz", "sigma_arcsec"} <= set(six.columns)
    assert six[smr.columns].equals(smr)
    q = six[["qw", "qx", "qy", "qz"]].to_numpy(float)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    truth = json.loads((cell["tmp"] / "truth.json").read_text())
    assert "tool_rpy_deg" in truth and max(abs(v) for v in truth["tool_rpy_deg"]) > 0


def test_orientations_are_fitted_and_held_out(cell):
    """The fit weighs orientations by variance components; held out, the full-pose model predicts the
    probe's orientation better than the positions-only one, its positions no worse."""
    full, pos = cell["fits"]["full"], cell["fits"]["positions"]
    assert full["weighting"]["method"] == "variance components"
    assert full["weighting"]["orientation_weight_mm_per_mrad"] > 0
    assert pos["weighting"]["method"] == "positions only"
    hf, hp = full["heldout"], pos["heldout"]
    assert hf["orientation_rms_after_arcsec"] < 0.8 * hp["orientation_rms_after_arcsec"], (hf, hp)
    assert hf["orientation_rms_after_arcsec"] < 0.5 * hf["orientation_rms_before_arcsec"]
    assert hf["rms_after_mm"] <= 1.05 * hp["rms_after_mm"]
    names = {p["name"] for p in full["parameters"]}
    assert {"tool_ex", "tool_ey", "tool_ez"} <= names
    assert 'orientation = true' in "\n".join(full["spec_effects"])
    assert full["cv_orientation_rms_arcsec"] > 0


def test_the_weight_does_not_hinge_on_where_it_starts(cell):
    """Variance components from a start 100 times off end at the same weight and predictions."""
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimator import RobotErrorModel
    from pipeline.core.spec import parse_spec

    robot, (sample, target) = robot_data_sets(cell["tmp"] / "meas", ("sample",), ("target",))
    effects = list(parse_spec(KINEMATIC.read_text(), KINEMATIC).effects)
    a = RobotErrorModel(robot, effects).fit(sample)
    sample.sigma_arcsec = sample.sigma_arcsec * 100.0
    b = RobotErrorModel(robot, effects).fit(sample)
    assert a.weighting_["started_from"].startswith("the stated")
    wa, wb = a.weighting_["orientation_weight_mm_per_mrad"], b.weighting_["orientation_weight_mm_per_mrad"]
    assert abs(np.log(wa / wb)) < 0.03, (wa, wb)
    Ra, Pa = a.predict_pose(target)
    Rb, Pb = b.predict_pose(target)
    assert np.abs(Pa - Pb).max() < 2e-3


def test_the_variance_components_secant_ends_where_the_plain_iteration_does():
    """A ratio that closes a fixed fraction of the gap a step (as the real series' do, 0.2 on Series A):
    the secant steps end at the same weight as the plain ones, in fewer fits; a secant pointing against
    the plain step is not taken."""
    from pipeline.robot.model.weighting import VCE_RTOL, vce_next

    w_star, c = 0.2958, 0.2

    def ratio(w):                      # the weight the fit at w gives: closes 80 % of the gap in log w
        return w_star * (w / w_star) ** c

    def run(secant):
        w, before, fits = 1.0, None, 0
        while True:
            fits += 1
            h = float(np.log(ratio(w) / w))
            if abs(h) < VCE_RTOL:
                return w, fits
            nxt = vce_next(np.log(w), h, before if secant else None)
            before = (float(np.log(w)), h)
            w = nxt

    (w_plain, n_plain), (w_sec, n_sec) = run(False), run(True)
    assert n_sec < n_plain, (n_sec, n_plain)
    for w in (w_plain, w_sec):
        assert abs(np.log(w / w_star)) < VCE_RTOL / (1 - c), w
    # the plain step at h = -0.1 from log w = 0; a secant (through log w = 1, h = -0.3) that would go uphill
    assert vce_next(0.0, -0.1, (1.0, -0.3)) == pytest.approx(np.exp(-0.1), rel=1e-12)
    # the secant through log w = -1, h = +0.3: the root of h at log w = -0.25
    assert vce_next(0.0, -0.1, (-1.0, 0.3)) == pytest.approx(np.exp(-0.25), rel=1e-12)


def test_a_refit_on_nearly_the_same_poses_starts_from_the_weight_before(cell):
    """A refit without a few poses (``weight_start``): started from the weight the fit before ended with,
    its variance components end at once, where a fit from the usual start ends."""
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimator import RobotErrorModel
    from pipeline.robot.model.weighting import VCE_RTOL
    from pipeline.core.spec import parse_spec

    robot, (sample, _) = robot_data_sets(cell["tmp"] / "meas", ("sample",), ("target",))
    effects = list(parse_spec(KINEMATIC.read_text(), KINEMATIC).effects)
    a = RobotErrorModel(robot, effects).fit(sample)
    keep = np.ones(sample.n, bool)
    keep[[3, 17, 40]] = False
    fewer = sample.subset(keep)
    fresh = RobotErrorModel(robot, effects).fit(fewer)
    warm = RobotErrorModel(robot, effects, weight_start=a.weighting_["orientation_weight_mm_per_mrad"]).fit(fewer)
    assert warm.weighting_["started_from"].startswith("the weight of a fit of the same model")
    assert warm.weighting_["iterations"] <= min(2, fresh.weighting_["iterations"])
    ww, wf = (m.weighting_["orientation_weight_mm_per_mrad"] for m in (warm, fresh))
    assert abs(np.log(ww / wf)) < 3 * VCE_RTOL, (ww, wf)


def test_the_linearised_weight_ends_the_variance_components_in_two_fits(cell):
    """From the usual start (1 mm per mrad, far from this campaign's weight), the next weight is where the
    fit linearised at its solution ends the iteration: the second fit passes the iteration's test on its own
    residuals."""
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.core.se3 import orientation_errors
    from pipeline.robot.model.estimator import RobotErrorModel
    from pipeline.robot.model.weighting import VCE_RTOL
    from pipeline.core.spec import parse_spec

    robot, (sample,) = robot_data_sets(cell["tmp"] / "meas", ("sample",))
    effects = list(parse_spec(KINEMATIC.read_text(), KINEMATIC).effects)
    m = RobotErrorModel(robot, effects).fit(sample)
    w = m.weighting_["orientation_weight_mm_per_mrad"]
    assert abs(np.log(w)) > 10 * VCE_RTOL                 # the start was off
    assert m.weighting_["iterations"] == 2
    R, P = m.predict_pose(sample)
    sp = np.sqrt(np.mean((P - sample.measured_mm) ** 2))
    so = np.sqrt(np.mean(orientation_errors(R, sample.measured_R) ** 2))
    assert abs(np.log(sp / so / w)) < VCE_RTOL


def _skewed(data, arcsec):
    """``data`` with its measured orientations turned by an error no effect of the model can explain (SYNTHETIC: a
    probe's own orientation error, smooth in the pose, ``arcsec`` per axis at most, about the base axes)."""
    from scipy.spatial.transform import Rotation

    q = np.radians(data.q_deg)
    rv = np.stack([np.sin(2 * q[:, 0] + q[:, 3]), np.cos(q[:, 1] + 2 * q[:, 5]), np.sin(q[:, 2] - q[:, 4])], 1)
    data.measured_R = np.einsum("nij,njk->nik", Rotation.from_rotvec(rv * arcsec / 206264.806).as_matrix(),
                                data.measured_R)
    return data


def test_orientation_rows_the_model_cannot_explain_do_not_cost_the_positions(cell):
    """Issue 52, full poses never worse: where the probe's orientations carry an error the model cannot explain
    (200 arcsec, ten times the probe's noise), the variance components weigh it as noise and the fit trades position
    for orientation (held out: more than 1.05x the positions-only fit's position error). The position guard lowers
    the weight until the orientations no longer cost the positions held out: within 1.05x, the orientation still
    far better than the positions alone. On the clean campaign the guard leaves the weight as it is."""
    from pipeline.core.se3 import angle_arcsec, orientation_errors
    from pipeline.core.spec import parse_spec
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimate import fit_effects

    robot, (sample, target) = robot_data_sets(cell["tmp"] / "meas", ("sample",), ("target",))
    effects = list(parse_spec(SPEC, "<spec>").effects)
    clean = fit_effects(robot, effects, sample)
    sample, target = _skewed(sample, 200.0), _skewed(target, 200.0)

    def held_out(m):
        R, P = m.predict_pose(target)
        return (float(np.sqrt(np.mean(np.sum((target.measured_mm - P) ** 2, axis=1)))),
                float(np.sqrt(np.mean(angle_arcsec(orientation_errors(R, target.measured_R)) ** 2))))

    alone = held_out(fit_effects(robot, effects, sample, orientation=False))
    model = fit_effects(robot, effects, sample)
    guard = model.weighting_.get("position_guard", {})
    traded = held_out(fit_effects(robot, effects, sample,
                                  orientation_weight=guard.get("vce_weight_mm_per_mrad", model.weight_)))
    assert traded[0] > 1.05 * alone[0], (traded, alone)         # the trade the fixture carries
    got = held_out(model)
    assert got[0] <= 1.05 * alone[0], (got, alone, guard)
    assert got[1] < 0.8 * alone[1], (got, alone)
    assert clean.weighting_["position_guard"]["factor"] == 1.0
    assert clean.weight_ == clean.weighting_["position_guard"]["vce_weight_mm_per_mrad"]
    assert guard["factor"] < 1.0 and model.weight_ == pytest.approx(guard["weight_mm_per_mrad"])
    assert guard["cv_position_rms_mm"] <= 1.025 * guard["cv_position_rms_positions_only_mm"] + 1e-12
    assert model.weighting_["orientation_weight_mm_per_mrad"] == model.weight_


def test_folds_in_forked_processes_give_the_same_cross_validation(cell):
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimate import cross_validate
    from pipeline.core.spec import parse_spec

    robot, (sample, _) = robot_data_sets(cell["tmp"] / "meas", ("sample",), ("target",))
    effects = list(parse_spec(KINEMATIC.read_text(), KINEMATIC).effects)
    one = cross_validate(robot, effects, sample, orientation_weight=0.4)
    two = cross_validate(robot, effects, sample, orientation_weight=0.4, jobs=2)
    assert np.array_equal(one.residuals, two.residuals)
    assert np.array_equal(one.extra["orientation"], two.extra["orientation"])


def test_predict_gives_orientation_and_a_tool_point(cell):
    tmp, run = cell["tmp"], cell["run"]
    r = run("predict", "--campaign", tmp / "meas", "--model", tmp / "full.json", "--json", tmp / "self.json",
            "--point", "0 0 300")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp / "self.json").read_text())
    assert out["orientation_n"] == out["n"]
    assert abs(out["orientation_rms_arcsec"] - cell["fits"]["full"]["heldout"]["orientation_rms_after_arcsec"]) < 1e-3
    assert out["point_mm"] == [0.0, 0.0, 300.0]
    # the point 300 mm out: the position error and the orientation error's lever arm together
    pe = np.array([p["point_error_mm"] for p in out["points"]])
    e = np.array([p["error_mm"] for p in out["points"]])
    lever = np.array([p["orientation_error_arcsec"] for p in out["points"]]) / 206264.806 * 300.0
    assert np.all(pe <= e + lever + 1e-6)
    assert out["point_rms_mm"] > out["rms_mm"]


def test_a_program_corrected_with_orientations_lands_at_the_tool_point(cell):
    """Open loop on the hidden-effect cell: commands corrected by the full-pose model, measured by the cell,
    put a point 300 mm out on the probe within 1.25 x the model's held-out error there + 5 um."""
    from pipeline.robot.arm.kinematics import build_model, load_robot, placements
    from pipeline.robot.campaign.orientation import quaternions_to_matrices

    tmp, run = cell["tmp"], cell["run"]
    r = run("predict", "--campaign", tmp / "meas", "--model", tmp / "full.json", "--json", tmp / "held.json",
            "--point", "0 0 300")
    assert r.exit_code == 0, r.output
    held = json.loads((tmp / "held.json").read_text())["point_rms_mm"]
    poses = pd.read_csv(tmp / "meas" / "poses.csv", dtype={"point_id": str})
    targets = poses[poses["set"] == "target"][["point_id"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg"]]
    targets.to_csv(tmp / "program.csv", index=False)
    r = run("correct", "--model", tmp / "full.json", "--targets", tmp / "program.csv", "--out", tmp / "corr.csv")
    assert r.exit_code == 0, r.output
    corr = pd.read_csv(tmp / "corr.csv", dtype={"point_id": str})
    ok = corr["status"] == "ok"
    assert (corr.loc[ok, "orientation_held"] == "all").sum() >= 0.85 * len(corr)
    corr["set"] = "target"
    corr["payload_kg"] = targets["payload_kg"].to_numpy()
    corr.to_csv(tmp / "corrected_poses.csv", index=False)
    r = run("simulate", "measure", "--truth", tmp / "truth.json", "--poses", tmp / "corrected_poses.csv",
            "--campaign", tmp / "landed")
    assert r.exit_code == 0, r.output
    landed = pd.read_csv(tmp / "landed" / "tracker.csv", dtype={"point_id": str}).set_index("point_id")
    landed = landed.loc[corr.loc[ok, "point_id"]]
    R_meas = quaternions_to_matrices(landed[["qw", "qx", "qy", "qz"]].to_numpy(float))
    P_meas = landed[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    robot = load_robot(KR210)
    R_aim, P_aim = placements(build_model(robot), np.deg2rad(_q(targets[ok.to_numpy()])), "smr")
    aim = P_aim + np.einsum("nij,j->ni", R_aim, POINT)
    got = P_meas + np.einsum("nij,j->ni", R_meas, POINT)
    rms = float(np.sqrt(np.mean(np.sum((got - aim) ** 2, axis=1))))
    assert rms <= 1.25 * held + 0.005, (rms, held)


# ------------------------------------------------------------------------------ bad input
def _campaign_with(tmp_path, edit):
    src = ROOT / "raw" / "robot" / "kr210"
    dst = tmp_path / "c"
    shutil.copytree(src, dst)
    t = pd.read_csv(dst / "tracker.csv", dtype=str)
    t = edit(t)
    t.to_csv(dst / "tracker.csv", index=False)
    return dst


def test_a_quaternion_that_is_not_unit_is_refused_at_its_line(tmp_path, invoke):
    def edit(t):
        t["qw"], t["qx"], t["qy"], t["qz"] = "1", "0", "0", "0"
        t.loc[4, "qw"] = "0.5"
        return t
    folder = _campaign_with(tmp_path, edit)
    r = invoke("ingest", "--campaign", folder, "--out", tmp_path / "out.parquet")
    m = _one_line_error(r, "qw")
    assert m["line"] == "6" and "norm" in r.stderr
    assert not (tmp_path / "out.parquet").exists()


def test_a_missing_orientation_column_is_refused(tmp_path, invoke):
    def edit(t):
        t["qw"], t["qx"], t["qy"] = "1", "0", "0"
        return t
    folder = _campaign_with(tmp_path, edit)
    r = invoke("ingest", "--campaign", folder, "--out", tmp_path / "out.parquet")
    _one_line_error(r, "qw")
    assert "'qz' is missing" in r.stderr


def test_orientations_of_another_robot_frame_are_refused(tmp_path, invoke):
    """Unit quaternions that are not the probe frames (here every pose the same frame) do not fit a robot."""
    def edit(t):
        t["qw"], t["qx"], t["qy"], t["qz"] = "1", "0", "0", "0"
        return t
    folder = _campaign_with(tmp_path, edit)
    r = invoke("ingest", "--campaign", folder, "--out", tmp_path / "out.parquet")
    _one_line_error(r, "qw")
    assert "orientations do not fit" in r.stderr


def _map(tmp_path, old, new):
    text = (IPA / "map.toml").read_text().replace(old, new)
    assert text != (IPA / "map.toml").read_text()
    path = tmp_path / "map.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("old,new,fix", [('sequence = "XYZ"', 'sequence = "zyx"', 'sequence = "XYZ"'),
                                         ('unit = "deg"\n\n[uncertainty]', 'unit = "rad"\n\n[uncertainty]',
                                          'unit = "deg"')])
def test_import_refuses_a_wrong_sequence_or_unit_naming_the_right_one(tmp_path, invoke, old, new, fix):
    path = _map(tmp_path, old, new)
    r = invoke("import", "--source", SERIES_C, "--map", path, "--robot", IPA / "robot.toml", "--out", tmp_path / "C")
    m = _one_line_error(r)
    assert m["file"].endswith("map.toml") and fix in r.stderr, r.stderr
    assert not (tmp_path / "C").exists()


def test_the_real_t_mac_orientation_imports_with_its_mounting(tmp_path, invoke):
    r = invoke("import", "--source", SERIES_C, "--map", IPA / "map.toml", "--robot", IPA / "robot.toml",
               "--out", tmp_path / "C")
    assert r.exit_code == 0, r.output
    m = re.search(r"by (\d+\.\d+) deg RMS after the best mounting; probe mounting estimated from the data rpy_deg = "
                  r"\[([^\]]+)\]", r.stderr)
    assert m, r.stderr
    assert float(m[1]) < 0.2                             # README: 0.078 deg under R = Rx Ry Rz
    rpy = [float(v) for v in m[2].split(",")]
    assert abs(rpy[2] + 90.0) < 0.5 and max(abs(rpy[0]), abs(rpy[1])) < 0.5
    t = pd.read_csv(tmp_path / "C" / "tracker.csv")
    assert {"qw", "qx", "qy", "qz", "sigma_arcsec"} <= set(t.columns)


def test_a_campaign_of_positions_only_is_fitted_as_before():
    """No orientation columns: the model has no orientation parameter and the JSON no orientation key."""
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model.estimate import fit_effects
    from pipeline.core.spec import parse_spec

    robot, (sample,) = robot_data_sets(ROOT / "raw" / "robot" / "kr210", ("sample",))
    assert not sample.has_orientation
    effects = list(parse_spec(KINEMATIC.read_text(), KINEMATIC).effects)
    m = fit_effects(robot, effects, sample)
    assert "tool_ex" not in m.names_ and m.weighting_ is None and m.orientation_rms_arcsec_ is None


def test_plan_counts_what_a_6dof_probe_adds(tmp_path, invoke):
    """Planned for a 6-DoF probe, the same pool identifies more of the kinematic model (the probe's turn on
    the flange, the last joint's frame) and the console and JSON say it was planned for the orientation."""
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.simulate import draw_poses, make_cell

    robot = load_robot(KR210)
    Q = draw_poses(robot, 150, np.random.default_rng(21), [1200.0, 1600.0, 1200.0], 30.0, make_cell(robot).model_nominal)
    pool = pd.DataFrame({"point_id": [f"P{k:03d}" for k in range(len(Q))]})
    for j in range(6):
        pool[f"q{j + 1}"] = Q[:, j]
    pool.to_csv(tmp_path / "pool.csv", index=False)
    out = {}
    for probe in ("smr", "6dof"):
        r = invoke("plan", "--robot", KR210, "--spec", KINEMATIC, "--pool", tmp_path / "pool.csv", "--n", 25,
                   "--out", tmp_path / f"{probe}.csv", "--json", tmp_path / f"{probe}.json", "--probe", probe)
        assert r.exit_code == 0, r.output
        out[probe] = json.loads((tmp_path / f"{probe}.json").read_text())
    assert out["6dof"]["n_params"] > out["smr"]["n_params"]            # the probe's turn: 3 more
    assert out["6dof"]["parameters_identifiable"] > out["smr"]["parameters_identifiable"]
    assert out["6dof"]["probe"]["kind"] == "6dof" and "probe" not in out["smr"]
    assert out["6dof"]["predicted_rms_mm"] <= out["smr"]["predicted_rms_mm"] * 1.05


def test_a_target_row_may_give_the_orientation_to_reach(cell):
    """qw..qz on a --targets row: the full-pose model's corrected commands put the probe frame there."""
    from scipy.spatial.transform import Rotation

    from pipeline.correct.robot import ModelKinematics, correct_commands
    from pipeline.correct.targets import read_targets
    from pipeline.robot.model.predict import load_model_document

    tmp = cell["tmp"]
    robot, effects, model, sampled, _ = load_model_document(cell["fits"]["full"], "full.json")
    kin = ModelKinematics(robot, model)
    poses = pd.read_csv(tmp / "meas" / "poses.csv", dtype={"point_id": str})
    rows = poses[poses["set"] == "target"].head(20)
    q = _q(rows)
    R_nom, P_nom = kin.nominal(q)
    turn = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(150.0 / 3600)]).as_matrix()
    R_aim = np.einsum("ij,njk->nik", turn, R_nom)
    quat = Rotation.from_matrix(R_aim).as_quat()[:, [3, 0, 1, 2]]
    table = rows[["point_id"] + [f"q{j}" for j in range(1, 7)]].copy()
    table["payload_kg"] = rows["payload_kg"].to_numpy()
    for k, c in enumerate(("qw", "qx", "qy", "qz")):
        table[c] = quat[:, k]
    table.to_csv(tmp / "oriented_targets.csv", index=False)
    tg = read_targets(tmp / "oriented_targets.csv", 6)
    assert tg.target_R is not None and np.allclose(tg.target_R, R_aim, atol=1e-9)
    res = correct_commands(kin, tg.q_deg, tg.target_mm, tg.dirs, tg.payload_kg, tg.temperature_c, sampled,
                           target_R=tg.target_R)
    ok = res.status == "ok"
    assert ok.sum() >= 15 and set(res.orientation_held[ok]) == {"all"}
    R, P, _ = kin.pose(res.q_deg[ok], res.dirs[ok], tg.payload_kg[ok], tg.temperature_c[ok])
    from pipeline.core.se3 import angle_arcsec, orientation_errors

    assert angle_arcsec(orientation_errors(R, R_aim[ok])).max() < 2.0           # reached, to the damping
    assert np.linalg.norm(P - P_nom[ok], axis=1).max() < 1e-3
    plain = correct_commands(kin, tg.q_deg, tg.target_mm, tg.dirs, tg.payload_kg, tg.temperature_c, sampled)
    assert np.abs(plain.dq_arcsec[ok] - res.dq_arcsec[ok]).max() > 50.0          # the turn took joint motion


def test_a_targets_quaternion_that_is_not_unit_is_refused(tmp_path):
    from pipeline.core.errors import InputError
    from pipeline.correct.targets import read_targets

    t = pd.DataFrame({"point_id": ["a", "b"], **{f"q{j}": [10.0, 20.0] for j in range(1, 7)},
                      "qw": [1.0, 0.7], "qx": [0.0, 0.0], "qy": [0.0, 0.0], "qz": [0.0, 0.0]})
    t.to_csv(tmp_path / "t.csv", index=False)
    with pytest.raises(InputError) as exc:
        read_targets(tmp_path / "t.csv", 6)
    assert exc.value.line == 3 and exc.value.column == "qw"


def test_each_predicted_orientation_states_its_u95_arcsec(cell):
    """How sure, for the orientation too (contract section 14): u95_arcsec per point, and it holds."""
    tmp, run = cell["tmp"], cell["run"]
    full = cell["fits"]["full"]
    assert "unexplained_orientation_mrad2" in full["prediction_uncertainty"]
    names = [p["name"] for p in full["parameters"]]
    u = {p["name"]: p["uncertainty"] for p in full["parameters"]}
    assert u["tool_ex"] is not None and u["tool_ex"] > 0          # seen in the orientation, not the position
    r = run("predict", "--campaign", tmp / "meas", "--model", tmp / "full.json", "--json", tmp / "u95.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp / "u95.json").read_text())
    assert all("u95_arcsec" in p for p in out["points"]) and "tool_ex" in names
    assert 0.85 <= out["orientation_coverage_95"] <= 1.0, out["orientation_coverage_95"]
    assert out["u95_arcsec"] <= 2.0 * out["orientation_error_p95_arcsec"]
