"""How sure (contract section 14, issue 33): parameter uncertainties, correlations, u95_mm, coverage_95."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from conftest import ROOT, cli_invoker, six_dof_cell

KR210 = ROOT / "raw" / "robot" / "kr210"
KINEMATIC = ROOT / "specs" / "robot_kinematic.toml"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sure")
    fit = tmp / "fit.json"
    r = cli_invoker()("fit", "--campaign", KR210, "--spec", KINEMATIC, "--out", fit)
    assert r.exit_code == 0, r.output
    return fit, json.loads(fit.read_text()), r.output


# ------------------------------------------------------------------ the 95 % radius
def test_radius95_is_exact_for_an_isotropic_and_a_one_axis_error():
    from pipeline.robot.model.uncertainty import radius95

    s = 0.3
    iso = radius95(np.array([np.eye(3) * s ** 2]))[0]
    assert iso == pytest.approx(s * np.sqrt(stats.chi2.ppf(0.95, 3)), rel=1e-12)
    one = radius95(np.array([np.diag([s ** 2, 0.0, 0.0])]))[0]
    assert one == pytest.approx(1.959964 * s, rel=1e-6)


def test_radius95_holds_95_percent_of_an_anisotropic_gaussian_error():
    from pipeline.robot.model.uncertainty import radius95

    rng = np.random.default_rng(0)
    for lam in ([1.0, 0.3, 0.05], [1.0, 1.0, 0.1], [0.2, 0.1, 0.1]):
        Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        S = Q @ np.diag(lam) @ Q.T
        e = rng.multivariate_normal(np.zeros(3), S, 200_000)
        share = np.mean(np.linalg.norm(e, axis=1) <= radius95(S[None])[0])
        assert 0.94 < share < 0.96, (lam, share)


def test_unexplained_scatter_is_the_cross_validation_less_the_parameters_part():
    from pipeline.robot.model.uncertainty import unexplained_covariance

    rng = np.random.default_rng(1)
    r = rng.normal(0.0, 0.2, (20_000, 3))
    part = np.broadcast_to(np.eye(3) * 0.01, (len(r), 3, 3))
    U = unexplained_covariance(r, part)
    assert np.allclose(U, np.eye(3) * (0.04 - 0.01), atol=2e-3)
    # a parameters' part larger than the scatter leaves nothing, never a negative variance
    assert np.allclose(unexplained_covariance(r, part * 10.0), 0.0)


def test_extrapolation_adds_nothing_inside_the_sampled_ranges_and_grows_beyond_them():
    from pipeline.robot.model.uncertainty import extrapolation_covariance

    sampled = {"lower_deg": [-10.0, -10.0], "upper_deg": [10.0, 10.0]}
    q = np.array([[0.0, 0.0], [10.0, -10.0], [15.0, 0.0], [30.0, 0.0], [90.0, 0.0]])
    Jq = np.zeros((len(q), 3, 2))
    Jq[:, 0, 0] = 1000.0          # joint 1 moves the point along x, 1 m lever
    Jq[:, 1, 1] = 500.0
    U = np.eye(3) * 0.3 ** 2 / 3.0
    S = extrapolation_covariance(q, sampled, Jq, U)
    sx = np.sqrt(S[:, 0, 0])
    assert sx[0] == 0.0 and sx[1] == 0.0
    assert 0.0 < sx[2] < sx[3]
    # capped one sampled width (20 deg) beyond the edge, at the unexplained 1-sigma size
    assert sx[3] == pytest.approx(np.sqrt(0.3 ** 2 / 3.0)) and sx[4] == pytest.approx(sx[3])
    assert np.allclose(S[:, 1:, 1:], 0.0)


# ------------------------------------------------------------------ the fit's statement
def test_fit_states_each_fitted_parameters_uncertainty_and_the_correlated_pairs(fitted):
    _, doc, output = fitted
    by = {p["name"]: p for p in doc["parameters"]}
    for p in doc["parameters"]:
        assert "uncertainty" in p
        if p["fixed"]:
            assert p["uncertainty"] is None            # not fitted: no statement
        else:
            assert p["uncertainty"] > 0 and np.isfinite(p["uncertainty"])
    assert doc["correlations"], "a 6-joint MDH model with base and tool has strongly correlated pairs"
    groups = [set(g["parameters"]) for g in doc["identification"]["redundant"]]
    for c in doc["correlations"]:
        assert abs(c["value"]) > 0.9 and c["a"] in by and c["b"] in by
        assert c["redundant"] == any({c["a"], c["b"]} <= g for g in groups)
    assert doc["correlations"] == sorted(doc["correlations"], key=lambda c: (-abs(c["value"]), c["a"], c["b"]))
    # the console names the least sure parameters with what they are
    worst = doc["largest_relative_uncertainty"][0]
    assert worst["name"] in output and "least sure" in output
    pu = doc["prediction_uncertainty"]
    assert pu["coverage_factor"] > 0 and len(pu["unexplained_mm2"]) == 3
    assert len(pu["covariance"]) == len(pu["parameters"]) == sum(not p["fixed"] for p in doc["parameters"])


def test_parameter_uncertainties_cover_the_truth_on_virtual_cells():
    """Four virtual cells with known truth (the 20-cell run is `make bench`, bench/uncertainty_bench.py)."""
    from pipeline.robot.arm.kinematics import load_robot
    from pipeline.robot.cell.coverage import parameter_coverage

    out = parameter_coverage(load_robot(KR210 / "robot.toml"), range(100, 104))
    assert out["n"] > 100
    # the stated covariance as a whole: the errors' squared Mahalanobis distance is chi2(dof) if it is
    # right; refused outside its central 99.9 % (sigmas a third too small or too large are refused)
    k = out["mahalanobis_dof"]
    assert stats.chi2.ppf(0.0005, k) < out["mahalanobis2"] < stats.chi2.ppf(0.9995, k), out
    # one parameter at a time (correlated within a cell: loose bounds; 20 cells in make bench)
    assert 0.8 <= out["within_1_96_sigma"] <= 1.0, out
    assert 0.5 <= out["within_1_sigma"] <= 0.85, out


# ------------------------------------------------------------------ points
def test_predict_gives_each_point_its_u95_and_the_coverage(fitted, tmp_path):
    fit, _, _ = fitted
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", KR210, "--model", fit, "--json", out)
    assert r.exit_code == 0, r.output
    p = json.loads(out.read_text())
    u = np.array([x["u95_mm"] for x in p["points"]])
    e = np.array([x["error_mm"] for x in p["points"]])
    assert np.all(u > 0)
    assert p["coverage_95"] == pytest.approx(np.mean(e <= u))
    assert p["u95_mm"] == pytest.approx(u.mean(), rel=1e-5)       # written to 6 digits
    assert p["error_p95_mm"] == pytest.approx(np.quantile(e, 0.95), rel=1e-5)
    assert "within their u95_mm" in r.output


def test_a_campaign_that_scatters_more_is_told_plainly(fitted, tmp_path):
    """Another campaign of the robot, measured with ten times the scatter the model knows of: the
    intervals cannot hold, and predict says so (console and JSON) instead of staying silent."""
    fit, doc, _ = fitted
    other = tmp_path / "noisy"
    shutil.copytree(KR210, other)
    t = pd.read_csv(other / "tracker.csv", dtype={"point_id": str})
    rng = np.random.default_rng(7)
    scale = 10.0 * doc["prediction_uncertainty"]["unexplained_rms_mm"] / np.sqrt(3.0)
    for c in ("x_mm", "y_mm", "z_mm"):
        t[c] = t[c] + rng.normal(0.0, scale, len(t))
    t.to_csv(other / "tracker.csv", index=False, float_format="%.6f")
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", other, "--model", fit, "--json", out, "--register", "--keep-outliers")
    assert r.exit_code == 0, r.output
    p = json.loads(out.read_text())
    assert p["coverage_95"] < 0.9
    assert p["registration"]["coverage_95"] < 0.9
    assert "do not hold" in p["coverage_note"] and "do not hold" in r.output


def test_correct_writes_u95_per_row(fitted, tmp_path):
    fit, _, _ = fitted
    out = tmp_path / "c.csv"
    r = cli_invoker()("correct", "--model", fit, "--targets", KR210 / "poses.csv", "--out", out,
                      "--closed-loop-joints", "1 2 3")
    assert r.exit_code == 0, r.output
    c = pd.read_csv(out, dtype={"point_id": str})
    assert "u95_mm" in c and (c["u95_mm"] > 0).all()
    ok = c["status"] == "ok"
    # a row outside the sampled joint ranges (left as given) states more than the corrected rows do
    if (~ok).any():
        assert c.loc[~ok, "u95_mm"].max() > c.loc[ok, "u95_mm"].median()


def test_plan_states_the_u95_its_poses_promise(tmp_path):
    out, js = tmp_path / "plan.csv", tmp_path / "plan.json"
    r = cli_invoker()("plan", "--robot", KR210 / "robot.toml", "--spec", KINEMATIC, "--pool", KR210 / "poses.csv",
                      "--n", "30", "--out", out, "--json", js)
    assert r.exit_code == 0, r.output
    s = json.loads(js.read_text())
    noise = s["noise_mm"]
    # the parameters' scatter and the noise together: more than the noise alone's 95 % radius
    assert s["predicted_u95_mm"] > noise * np.sqrt(stats.chi2.ppf(0.95, 3))
    assert s["predicted_u95_mm"] < noise * np.sqrt(stats.chi2.ppf(0.95, 3)) + 3 * s["predicted_rms_mm"]


def test_the_real_report_tables_coverage_own_and_on_the_other_series():
    from pipeline.robot.reporting.real_report import transfer_table

    stats_ = {"max_mm": 1.0, "mean_mm": 0.5, "std_mm": 0.1}
    fit = {"heldout": {"n_sample": 10, "n_target": 5, "rms_before_mm": 1.0, "rms_after_mm": 0.5, "before": stats_,
                       "after": stats_},
           "largest_relative_uncertainty": [{"name": "dd6", "value": 0.01, "uncertainty": 0.02, "unit": "mm",
                                             "relative": 2.0, "meaning": "x"}]}

    def pred(cov, u, p95):
        return {"n": 5, "rms_mm": 0.5, "max_mm": 1.0, "mean_mm": 0.5, "std_mm": 0.1, "outside_sampled_range": 0,
                "coverage_95": cov, "u95_mm": u, "error_p95_mm": p95, "points": []}

    t = transfer_table({"B": {"fits": {"kinematic": fit}, "self": {"kinematic": pred(0.96, 0.8, 0.8)},
                              "on": {"kinematic": {"C": pred(0.4, 0.8, 1.6)}}}})
    c = t["B"]["kinematic_coverage"]
    assert c["own"]["coverage_95"] == 0.96 and c["own"]["u95_over_p95"] == pytest.approx(1.0)
    assert c["C"]["coverage_95"] == 0.4 and c["C"]["u95_over_p95"] == pytest.approx(0.5)
    assert t["B"]["kinematic_least_sure"][0]["name"] == "dd6"


def test_a_model_written_before_it_states_no_u95_and_still_predicts(fitted, tmp_path):
    fit, doc, _ = fitted
    old = {k: v for k, v in doc.items() if k != "prediction_uncertainty"}
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    out = tmp_path / "p.json"
    r = cli_invoker()("predict", "--campaign", KR210, "--model", path, "--json", out)
    assert r.exit_code == 0, r.output
    p = json.loads(out.read_text())
    assert "coverage_95" not in p and "u95_mm" not in p["points"][0]


def test_least_sure_parameters_of_equal_uncertainty_are_named_in_name_order():
    """A pair the data cannot tell apart has one relative uncertainty but for its last digits: it is named
    in the order of its names, whichever rounding a kernel leaves (the order of the largest is kept)."""
    from pipeline.robot.model.uncertainty import largest_relative

    def params(eps):
        return [{"name": "dtheta1", "value": 1.0, "uncertainty": 0.5 * (1 + eps), "unit": "mrad"},
                {"name": "base_ez", "value": -1.0, "uncertainty": 0.5, "unit": "mrad"},
                {"name": "dd6", "value": 0.1, "uncertainty": 0.2, "unit": "mm"},
                {"name": "tool_dx", "value": 1.0, "uncertainty": 0.01, "unit": "mm"}]

    for eps in (1e-13, -1e-13, 0.0, 2e-8, -2e-8):      # 2e-8: the rounding measured on a real series' pair
        assert [r["name"] for r in largest_relative(params(eps))] == ["dd6", "base_ez", "dtheta1"]
    assert [r["name"] for r in largest_relative(params(1e-3))] == ["dd6", "dtheta1", "base_ez"]


def test_propagated_covariance_is_each_poses_sandwich(monkeypatch):
    """J_i C J_i^T pose by pose (and its trace), also across the blocks the product is taken in."""
    from pipeline.robot.model import uncertainty

    rng = np.random.default_rng(7)
    J = rng.normal(size=(11, 6, 9))
    A = rng.normal(size=(9, 9))
    C = A @ A.T
    monkeypatch.setattr(uncertainty, "_BLOCK", 4)
    S = uncertainty.prediction_covariance(J, C)
    assert S.shape == (11, 6, 6)
    for i in range(11):
        np.testing.assert_allclose(S[i], J[i] @ C @ J[i].T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(uncertainty.prediction_variance(J, C), np.trace(S, axis1=1, axis2=2), rtol=1e-12)
    assert uncertainty.prediction_covariance(J[:0], C).shape == (0, 6, 6)
    assert uncertainty.prediction_variance(J[:0], C).shape == (0,)


@pytest.mark.parametrize("probe", ["smr", "6dof"])
def test_a_large_campaigns_covariance_is_the_dense_one(probe, tmp_path, monkeypatch):
    """Beyond DENSE_SVD_MAX entries the covariance comes from the sparse Jacobian by blocks of rows (its
    sv and V from a QR, the fitted degrees of freedom from the penalty rows): the dense SVD's numbers."""
    from pipeline.core.spec import parse_spec
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model import normal, uncertainty
    from pipeline.robot.model.estimate import fit_effects

    camp = KR210 if probe != "6dof" else six_dof_cell(tmp_path / "cell", tmp_path / "truth.json", 3)
    robot, (sample,) = robot_data_sets(camp, ("sample",))
    spec = parse_spec('[model]\nkind = "robot"\n\n[[effect]]\nname = "geometry"\n\n[[effect]]\nname = "base"\n\n'
                      '[[effect]]\nname = "tool"\n\n[[effect]]\nname = "joint_map"\njoints = [2]\n', "<test>")
    model = fit_effects(robot, list(spec.effects), sample, checks=False)
    assert np.asarray(model.penalty_).shape[0] > 0          # the joint map's smoothness rows take part
    dense = uncertainty.parameter_covariance(model, sample)
    monkeypatch.setattr(normal, "DENSE_SVD_MAX", 1000)   # every campaign is large: blocks of rows too
    large = uncertainty.parameter_covariance(model, sample)
    C0, C1 = dense["covariance"], large["covariance"]
    assert np.abs(C0).max() > 0
    np.testing.assert_allclose(C1, C0, rtol=0, atol=1e-9 * np.abs(C0).max())
    assert large["dof"] == pytest.approx(dense["dof"], rel=1e-9)
    assert large["sigma_mm"] == pytest.approx(dense["sigma_mm"], rel=1e-9)
    assert large["n_obs"] == dense["n_obs"]
    # propagated over the parameters the covariance holds (the others' zero rows and columns left out): the same
    # (here as if every third parameter were left at nominal: its row and column 0)
    Cz = C0.copy()
    Cz[::3], Cz[:, ::3] = 0.0, 0.0
    mv = uncertainty.moving(Cz)
    assert mv.sum() == mv.size - len(range(0, mv.size, 3))
    full = uncertainty.prediction_covariance(uncertainty.model_jacobian(model, sample), Cz)
    part = uncertainty.prediction_covariance(uncertainty.model_jacobian(model, sample, mv), Cz[np.ix_(mv, mv)])
    assert np.abs(full).max() > 0
    np.testing.assert_allclose(part, full, rtol=1e-12, atol=1e-12 * np.abs(full).max())


def test_parameter_meanings_say_robot_tomls_dh_plus_beta():
    """Issue 53: robot.toml's link transform is classic DH plus beta (contract section 2), for a robot written
    by hand or imported from a URDF; the fit console and reports named its parameters "MDH". Each geometry
    parameter names the robot.toml key it corrects."""
    from pipeline.robot.model.uncertainty import meaning

    for name, key in (("dd3", "d_mm of joint 3"), ("da2", "a_mm of joint 2"), ("dalpha4", "alpha_deg of joint 4"),
                      ("dbeta2", "beta_deg of joint 2")):
        text = meaning(name)
        assert key in text and "MDH" not in text, (name, text)
    assert "DH + beta" in meaning("dbeta2")
