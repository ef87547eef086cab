"""The encoder stages through the command line, and what bad input does."""

import json

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT


def run_chain(invoke, campaign, work, spec=ROOT / "specs" / "encoder_paper.toml"):
    work.mkdir(parents=True, exist_ok=True)
    steps = [
        ("ingest", "--campaign", campaign, "--out", work / "m.parquet"),
        ("harmonic", "--interim", work / "m.parquet", "--out", work / "h.parquet"),
        ("aliasing", "--interim", work / "m.parquet", "--out", work / "alias.csv"),
        ("select", "--interim", work / "m.parquet", "--harmonics", work / "h.parquet", "--spec", spec,
         "--out", work / "orders.json"),
        ("fit", "--interim", work / "m.parquet", "--spec", spec, "--orders", work / "orders.json",
         "--out", work / "model.json"),
        ("compensate", "--model", work / "model.json", "--out", work / "table.csv", "--step", "0.5"),
    ]
    for args in steps:
        result = invoke(*args)
        assert result.exit_code == 0, (args[0], result.output)
    return work


def test_chain_produces_model_table_and_aliasing(invoke, campaign_copy, tmp_path):
    work = run_chain(invoke, campaign_copy, tmp_path / "work")
    model = json.loads((work / "model.json").read_text())
    table = pd.read_csv(work / "table.csv")
    assert len(table) == 720 and table["theta_deg"].iloc[1] == 0.5
    # the table is the model: evaluate the model's own terms independently at a few angles
    th = np.deg2rad(table["theta_deg"].to_numpy())
    direct = sum(t["C_arcsec"] * (np.sin(t["order"] * th + np.deg2rad(t["phi_deg"])) if t["order"] else 1.0)
                 for t in model["terms"])
    np.testing.assert_allclose(table["error_arcsec"], direct, atol=1e-3)
    alias = pd.read_csv(work / "alias.csv")
    assert alias["N_distinct"].iloc[0] == 36 and alias["order"].max() == 18
    h = pd.read_parquet(work / "h.parquet")
    assert h["order"].max() == 17 and h["N"].iloc[0] == 36
    assert (h["A"] - h["A_fft"]).abs().max() < 0.5  # angles are even to within the joint's own error


def test_correct_reads_stdin_and_undoes_the_model(invoke, runner, campaign_copy, tmp_path):
    from pipeline.cli import cli

    work = run_chain(invoke, campaign_copy, tmp_path / "w")
    model = json.loads((work / "model.json").read_text())
    result = runner.invoke(cli, ["correct", "--model", str(work / "model.json")], input="encoder_deg\n10.0\n95.5\n")
    assert result.exit_code == 0, result.output
    out = pd.read_csv(__import__("io").StringIO(result.stdout))
    # a joint with exactly the modelled error, read back through `correct`, gives the true angle back
    true = out["corrected_deg"].to_numpy()
    th = np.deg2rad(true)
    err = sum(t["C_arcsec"] * (np.sin(t["order"] * th + np.deg2rad(t["phi_deg"])) if t["order"] else 1.0)
              for t in model["terms"])
    np.testing.assert_allclose(true + err / 3600.0, [10.0, 95.5], atol=2e-7)


def test_help_of_every_command(invoke):
    for cmd in ("ingest", "harmonic", "aliasing", "select", "fit", "compensate", "correct", "report", "summary",
                "validate", "simulate"):
        result = invoke(cmd, "--help")
        assert result.exit_code == 0 and "Usage" in result.output


def _rewrite(path, fn):
    frame = pd.read_csv(path, dtype=str, keep_default_na=False)
    changed = fn(frame)
    (frame if changed is None else changed).to_csv(path, index=False)


BAD = {
    "missing column": (lambda f: f.drop(columns=["autocollimator_arcsec"]), "autocollimator_arcsec"),
    "misspelled column": (lambda f: f.rename(columns={"encoder_deg": "encoder_dg"}), "encoder_deg"),
    "NaN": (lambda f: f.loc.__setitem__((5, "encoder_deg"), "nan"), "NaN"),
    "not a number": (lambda f: f.loc.__setitem__((7, "autocollimator_arcsec"), "1.2.3"), "not a number"),
    "infinity": (lambda f: f.loc.__setitem__((3, "autocollimator_arcsec"), "inf"), "finite"),
    "duplicate run step": (lambda f: f.loc.__setitem__((4, "step"), "3"), "duplicate"),
    "radians": (lambda f: f.__setitem__("nominal_deg", (f["nominal_deg"].astype(float) * np.pi / 180).map(str)),
                "radians"),
    "encoder in radians": (lambda f: f.__setitem__("encoder_deg", (f["encoder_deg"].astype(float) * np.pi / 180).map(str)),
                           "radians"),
    "missing step": (lambda f: f.drop(index=10), "missing step"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_exits_2_with_one_located_line(invoke, campaign_copy, tmp_path, case):
    change, words = BAD[case]
    target = campaign_copy / "a_run2.csv"
    _rewrite(target, change)
    out = tmp_path / "x.parquet"
    result = invoke("ingest", "--campaign", campaign_copy, "--out", out)
    assert result.exit_code == 2
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.output
    assert "a_run2.csv:" in lines[0] and words.lower() in lines[0].lower()
    file_, line, column = lines[0].split("jointcal: error: ", 1)[1].split(":")[:3]
    assert line != "-" or case.startswith(("missing column", "misspelled"))
    assert column != "-"
    assert not out.exists()


def test_located_line_points_at_the_bad_cell(invoke, campaign_copy, tmp_path):
    _rewrite(campaign_copy / "a_run3.csv", lambda f: f.loc.__setitem__((9, "encoder_deg"), "nan"))
    result = invoke("ingest", "--campaign", campaign_copy, "--out", tmp_path / "x.parquet")
    # data row 9 (0-based) is line 11 of the file: header is line 1
    assert ":11:encoder_deg:" in result.stderr


def test_order_above_nyquist_is_refused_by_harmonic(invoke, campaign_copy, tmp_path):
    assert invoke("ingest", "--campaign", campaign_copy, "--out", tmp_path / "m.parquet").exit_code == 0
    result = invoke("harmonic", "--interim", tmp_path / "m.parquet", "--out", tmp_path / "h.parquet", "--n-max", "19")
    assert result.exit_code == 2 and "alias" in result.output
    assert not (tmp_path / "h.parquet").exists()


def test_spec_with_unknown_effect_is_located(invoke, campaign_copy, tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text('[model]\nkind = "encoder"\n\n[[effect]]\nname = "harmonik"\n')
    assert invoke("ingest", "--campaign", campaign_copy, "--out", tmp_path / "m.parquet").exit_code == 0
    result = invoke("fit", "--interim", tmp_path / "m.parquet", "--spec", spec, "--out", tmp_path / "o.json")
    assert result.exit_code == 2
    assert "bad.toml:5:1:" in result.stderr and "harmonik" in result.stderr


def test_validate_lists_every_problem(invoke, campaign_copy):
    _rewrite(campaign_copy / "a_run2.csv", lambda f: f.loc.__setitem__((5, "encoder_deg"), "nan"))
    _rewrite(campaign_copy / "a_run4.csv", lambda f: f.drop(columns=["step"]))
    result = invoke("validate", "--campaign", campaign_copy)
    assert result.exit_code == 2
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert any("a_run2.csv:7:encoder_deg" in ln for ln in lines)
    assert any("a_run4.csv:1:step" in ln for ln in lines)
