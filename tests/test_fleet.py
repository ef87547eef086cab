"""`jointcal fleet`: 50 simulated modules on a LocalCluster of 2 workers, the same bytes in one
process, the truth never read, out-of-family units flagged, bad units not stopping the others."""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker

SEED = 7  # not the shipped fleet's seed (2026)
UNITS = 50


class _TruthGuard:
    """An audit hook that fails any attempt to open the generator's truth while armed."""

    armed = False
    installed = False
    truth = ""

    @classmethod
    def hook(cls, event, args):
        if cls.armed and event == "open" and args and cls.truth and cls.truth in str(args[0]):
            raise PermissionError(f"the pipeline opened the generator's truth: {args[0]}")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Simulate 50 modules; run the fleet on a LocalCluster of 2 workers (through --scheduler) and
    again in this process (--serial) with the truth guarded."""
    from dask.distributed import LocalCluster

    tmp = tmp_path_factory.mktemp("fleet")
    run = cli_invoker()
    r = run("simulate", "fleet", "--out", tmp / "raw", "--truth", tmp / "truth", "--units", UNITS, "--seed", SEED)
    assert r.exit_code == 0, r.output
    spec = ROOT / "specs" / "encoder_paper.toml"
    out = {}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert len(cluster.workers) == 2
        args = ("fleet", "--campaigns", f"{tmp}/raw/*", "--spec", spec, "--out-dir", tmp / "dask",
                "--table", tmp / "dask.parquet", "--report", tmp / "dask.pdf", "--scheduler", cluster.scheduler_address)
        r = run(*args)
        assert r.exit_code == 0, r.output
        out["dask_output"] = r.output
    if not _TruthGuard.installed:
        sys.addaudithook(_TruthGuard.hook)
        _TruthGuard.installed = True
    _TruthGuard.truth = str(tmp / "truth")
    _TruthGuard.armed = True
    try:
        r = run("fleet", "--campaigns", f"{tmp}/raw/*", "--spec", spec, "--out-dir", tmp / "serial",
                "--table", tmp / "serial.parquet", "--report", tmp / "serial.pdf", "--serial")
    finally:
        _TruthGuard.armed = False
    assert r.exit_code == 0, r.output
    truth = {p.stem: json.loads(p.read_text()) for p in (tmp / "truth").glob("*.json")}
    return {"tmp": tmp, "table": pd.read_parquet(tmp / "dask.parquet"), "truth": truth, **out}


def test_every_unit_has_its_results(fleet):
    t, tmp = fleet["table"], fleet["tmp"]
    assert len(t) == UNITS and (t["status"] == "ok").all()
    assert list(t["unit"]) == sorted(fleet["truth"])
    for unit in t["unit"]:
        model = json.loads((tmp / "dask" / f"{unit}_model.json").read_text())
        assert model["module"] == unit and model["validation_runs"] == [6]
        table = pd.read_csv(tmp / "dask" / f"{unit}_table.csv")
        assert len(table) == 3600
        np.testing.assert_allclose(table["correction_arcsec"], -table["error_arcsec"])
        diag = json.loads((tmp / "dask" / f"{unit}_diagnosis.json").read_text())
        assert diag["kind"] == "encoder" and "provenance" in diag
    assert (tmp / "dask.pdf").read_bytes().startswith(b"%PDF")


def test_cluster_and_one_process_give_the_same_bytes(fleet):
    tmp = fleet["tmp"]
    assert (tmp / "dask.parquet").read_bytes() == (tmp / "serial.parquet").read_bytes()
    assert (tmp / "dask.pdf").read_bytes() == (tmp / "serial.pdf").read_bytes()
    names = sorted(p.name for p in (tmp / "dask").iterdir())
    assert names == sorted(p.name for p in (tmp / "serial").iterdir()) and len(names) == 3 * UNITS
    for name in names:
        assert (tmp / "dask" / name).read_bytes() == (tmp / "serial" / name).read_bytes(), name


def test_out_of_family_units_are_the_damaged_ones(fleet):
    t = fleet["table"]
    role = t["unit"].map({u: v["role"] for u, v in fleet["truth"].items()})
    damaged = set(t.loc[role.isin(["bearing", "loose_mount"]), "unit"])
    assert len(damaged) == 3
    flagged = set(t.loc[t["out_of_family"], "unit"])
    assert flagged == damaged
    assert t.loc[t["out_of_family"], "why_flagged"].str.contains("fleet median").all()


def test_most_frequent_missing_effect_is_the_batch_defect(fleet):
    from pipeline.fleet.engine import effect_counts

    t = fleet["table"]
    role = t["unit"].map({u: v["role"] for u, v in fleet["truth"].items()})
    counts = effect_counts(t)
    assert counts.iloc[0]["effect"] == "harmonic 6"
    has6 = t["missing_effects"].str.split("; ").map(lambda keys: "harmonic 6" in keys)
    assert has6[role == "harmonic6"].mean() >= 0.7
    assert has6[role != "harmonic6"].mean() <= 0.05
    assert "harmonic 6" in fleet["dask_output"]


def test_reductions_are_those_of_the_paper_for_in_family_units(fleet):
    t = fleet["table"]
    red = t.loc[~t["out_of_family"], "reduction_pct"]
    assert 75 < red.median() < 90
    assert (t.loc[t["out_of_family"], "reduction_pct"].min() < red.median())


def test_a_bad_unit_does_not_stop_the_others(tmp_path):
    src = ROOT / "raw" / "fleet"
    for unit in ("m0001", "m0002", "m0003"):
        shutil.copytree(src / unit, tmp_path / "raw" / unit)
    bad = tmp_path / "raw" / "m0002" / "m0002_run3.csv"
    lines = bad.read_text().splitlines()
    fields = lines[5].split(",")
    fields[4] = "12.3.4"  # encoder_deg
    lines[5] = ",".join(fields)
    bad.write_text("\n".join(lines) + "\n")
    (tmp_path / "res").mkdir()
    stale = tmp_path / "res" / "m0002_model.json"
    stale.write_text("{}")
    r = cli_invoker()("fleet", "--campaigns", f"{tmp_path}/raw/*", "--spec", ROOT / "specs" / "encoder_paper.toml",
                      "--out-dir", tmp_path / "res", "--table", tmp_path / "fleet.parquet",
                      "--report", tmp_path / "fleet.pdf", "--workers", 2)
    assert r.exit_code == 2
    errors = [line for line in r.output.splitlines() if line.startswith("jointcal: error:")]
    assert len(errors) == 1 and f"{bad}:6:encoder_deg:" in errors[0]
    assert "Traceback" not in r.output
    t = pd.read_parquet(tmp_path / "fleet.parquet")
    assert dict(zip(t["unit"], t["status"])) == {"m0001": "ok", "m0002": "bad input", "m0003": "ok"}
    assert not stale.exists()
    assert (tmp_path / "res" / "m0003_table.csv").exists()


def test_a_pattern_without_campaigns_is_one_line(tmp_path):
    r = cli_invoker()("fleet", "--campaigns", f"{tmp_path}/nothing/*", "--spec", ROOT / "specs" / "encoder_paper.toml",
                      "--out-dir", tmp_path / "res", "--serial")
    assert r.exit_code == 2
    assert r.output.strip().count("\n") == 0 and "matches no campaign folder" in r.output
    assert not (tmp_path / "res").exists()


def test_out_of_family_rule_on_a_known_table():
    from pipeline.fleet.engine import flag_out_of_family

    rng = np.random.default_rng(0)
    r = np.exp(rng.normal(np.log(5.0), 0.1, 40))
    r[[3, 17]] *= 3.0
    frame = pd.DataFrame({"unit": [f"u{i}" for i in range(40)], "status": "ok", "cv_rms": r,
                          "unit_of_error": "arcsec", "missing_effects": ""})
    frame.loc[5, "status"] = "bad input"
    frame.loc[5, "cv_rms"] = 1e6
    flagged = flag_out_of_family(frame)
    assert list(flagged.index[flagged["out_of_family"]]) == [3, 17]
    assert np.isnan(flagged.loc[5, "robust_z"])
    few = flag_out_of_family(frame.head(6))
    assert not few["out_of_family"].any()


def test_a_fleet_of_robots(tmp_path):
    """A plant re-checks its robots: two virtual cells, one with a hidden thermal expansion."""
    run = cli_invoker()
    for name, seed, hidden in (("cell1", 31, None), ("cell2", 32, "thermal")):
        (tmp_path / "raw" / name).mkdir(parents=True)
        shutil.copy(ROOT / "raw" / "robot" / "kr210" / "robot.toml", tmp_path / "raw" / name)
        args = ["simulate", "robot", "--campaign", tmp_path / "raw" / name, "--truth", tmp_path / f"{name}.json",
                "--seed", seed] + (["--hidden", hidden] if hidden else [])
        assert run(*args).exit_code == 0
    r = run("fleet", "--campaigns", f"{tmp_path}/raw/*", "--spec", ROOT / "specs" / "robot_paper.toml",
            "--out-dir", tmp_path / "res", "--table", tmp_path / "fleet.parquet", "--report", tmp_path / "fleet.pdf",
            "--serial", "--no-diagnose")
    assert r.exit_code == 0, r.output
    t = pd.read_parquet(tmp_path / "fleet.parquet")
    assert list(t["unit"]) == ["cell1", "cell2"] and (t["unit_of_error"] == "mm").all()
    assert (t["after"] < 0.5 * t["before"]).all()  # the fitted model beats the nominal one on held-out targets
    assert "not judged" in r.output  # two robots are not a family
    fit = json.loads((tmp_path / "res" / "cell2_fit.json").read_text())
    assert fit["heldout"]["n_target"] > 0 and fit["effects"] == ["geometry", "base", "chebyshev"]


def test_the_shipped_fleet_regenerates_byte_for_byte(tmp_path):
    r = cli_invoker()("simulate", "fleet", "--out", tmp_path / "raw", "--truth", tmp_path / "truth")
    assert r.exit_code == 0
    shipped = sorted(p.relative_to(ROOT / "raw" / "fleet") for p in (ROOT / "raw" / "fleet").rglob("*.csv"))
    assert len(shipped) == 50 * 6
    assert shipped == sorted(p.relative_to(tmp_path / "raw") for p in (tmp_path / "raw").rglob("*.csv"))
    for rel in shipped:
        assert (tmp_path / "raw" / rel).read_bytes() == (ROOT / "raw" / "fleet" / rel).read_bytes(), rel
