"""``jointcal fleet`` and ``jointcal simulate fleet`` (thin: the work is in :mod:`pipeline.fleet`).

Library imports are inside the commands: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import click



def _write_unit_files(out_dir: Path, result: dict, spec_path: str) -> dict:
    """Write one unit's results as ``<unit>_<name>``; remove a failed unit's stale results.

    Returns the provenance of the unit's input files (path -> SHA-256), also for a failed unit.
    """
    from ..core.files import provenance, write_csv, write_json

    unit = result["unit"]
    inputs = sorted(str(p) for p in Path(result["campaign"]).iterdir() if p.is_file())
    prov = provenance(inputs, spec_path)
    if result["status"] != "ok":
        for old in out_dir.glob(f"{unit}_*"):
            old.unlink()
        return prov["inputs"]
    for name, obj in sorted(result["files"].items()):
        path = out_dir / f"{unit}_{name}"
        if name.endswith(".csv"):
            write_csv(path, obj, float_format="%.4f")
        else:
            write_json(path, {**obj, "provenance": prov})
    return prov["inputs"]


@click.command()
@click.option("--campaigns", "patterns", multiple=True, required=True, metavar="GLOB",
              help="Campaign folders, a quoted glob such as 'raw/encoder/*' (repeatable). A unit is named by "
                   "its folder.")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="One spec for every unit.")
@click.option("--out-dir", default="results/fleet", show_default=True, type=click.Path(file_okay=False),
              help="Per-unit results: <unit>_model.json, <unit>_table.csv, <unit>_diagnosis.json (robot: <unit>_fit.json).")
@click.option("--table", "table_out", default="results/fleet.parquet", show_default=True,
              type=click.Path(dir_okay=False), help="One row per unit.")
@click.option("--report", "report_out", default="reports/fleet.pdf", show_default=True,
              type=click.Path(dir_okay=False), help="Distribution of reductions, out-of-family units, "
                                                     "most frequent missing effects.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="A running dask.distributed scheduler (tcp://host:8786). Its workers must see the campaign "
                   "folders at the same paths and have jointcal installed. Default: a local cluster.")
@click.option("--workers", type=click.IntRange(1), default=None,
              help="Processes of the local cluster (default: the machine's cores).")
@click.option("--serial", is_flag=True, help="No Dask: every unit in this process, one after the other.")
@click.option("--diagnose/--no-diagnose", default=True, show_default=True,
              help="Run the diagnosis on every unit (the missing-effect counts need it).")
@click.option("--z-out", type=float, default=None,
              help="Robust z of the log cross-validated RMS above which a unit is out of family [default: 3.5].")
def fleet(patterns, spec_path, out_dir, table_out, report_out, scheduler, workers, serial, diagnose, z_out):
    """Run the per-unit pipeline over many campaigns on Dask and compare the units.

    Every unit goes through what `make all` does for one campaign (an encoder module:
    ingest, orders by the spec's rule, fit on the modelling runs, held-out run, compensation
    table, diagnosis; a robot: the spec's model fitted on the sample poses, error on the
    held-out targets, diagnosis). Then the fleet: the distribution of reductions, units whose
    cross-validated residual is out of family, and the effects the diagnosis finds most often.

    A unit with bad input does not stop the others: it is listed with its one-line error,
    its stale results are removed, and the command exits with status 2 at the end.
    Units run on a local Dask cluster unless --scheduler names a running one.
    """
    from ..core.files import provenance, read_text_input, write_parquet
    from ..core.spec import parse_spec
    from ..fleet.engine import MIN_UNITS_FOR_FAMILY, Progress, Z_OUT, find_campaigns, fleet_summary, fleet_table, run_units
    from ..fleet.report import fleet_report

    z = Z_OUT if z_out is None else z_out
    campaigns = find_campaigns(patterns)
    spec_text = read_text_input(spec_path, "spec file")
    spec = parse_spec(spec_text, spec_path)  # a bad spec stops here, before any unit runs
    n_workers = workers or os.cpu_count() or 1
    where = "this process" if serial else (scheduler or f"a local Dask cluster of {n_workers} worker(s)")
    click.echo(f"fleet: {len(campaigns)} {spec.kind} campaign(s) with {spec_path} on {where}", err=True)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    inputs = {}

    def write_and_drop_files(result):
        inputs.update(_write_unit_files(out, result, spec_path))
        return {**result, "files": {}}

    try:
        results = run_units(campaigns, spec_text, spec_path, diagnose=diagnose, scheduler=scheduler,
                            workers=n_workers, serial=serial, progress=Progress(lambda s: click.echo(s, err=True)),
                            on_result=write_and_drop_files)
    except (OSError, TimeoutError) as exc:
        if not scheduler:
            raise
        click.echo(f"jointcal: error: cannot reach the Dask scheduler at {scheduler}: {' '.join(str(exc).split())}",
                   err=True)
        sys.exit(2)
    table = fleet_table(results, spec.kind, z)
    summary = fleet_summary(table)
    write_parquet(table_out, table, {"spec": spec_path, "z_out": z, "diagnose": diagnose, "campaigns": campaigns,
                                     **provenance([], spec_path), "inputs": dict(sorted(inputs.items()))})
    fleet_report(table, summary, report_out, spec_path, z)
    red = summary["reduction_pct"]
    click.echo(f"{table_out}: {summary['ok']}/{summary['units']} units calibrated"
               + (f"; reduction median {red['median']:.1f} %, worst {red['min']:.1f} %" if red["median"] is not None else ""),
               err=True)
    flagged = table[table["out_of_family"]]
    if summary["family_judged"]:
        click.echo(f"out of family: {', '.join(flagged['unit']) if len(flagged) else 'none'}", err=True)
    else:
        click.echo(f"out of family: not judged, {summary['ok']} unit(s) calibrated (a family needs {MIN_UNITS_FOR_FAMILY})",
                   err=True)
    if summary["effects"]:
        top = ", ".join(f"{e['effect']} ({e['units']})" for e in summary["effects"][:5])
        click.echo(f"missing effects found most often: {top}", err=True)
    click.echo(f"{report_out}: written; per-unit results in {out}/", err=True)
    bad = table[table["status"] == "bad input"]
    for line in bad["error"]:
        click.echo(f"jointcal: error: {line}", err=True)
    for _, r in table[table["status"] == "failed"].iterrows():
        click.echo(f"jointcal: unit {r['unit']} failed: {r['error']}", err=True)
    if len(bad):
        sys.exit(2)
    if (table["status"] == "failed").any():
        sys.exit(1)


@click.command("fleet")
@click.option("--out", "out_dir", default="raw/fleet", show_default=True, type=click.Path(file_okay=False),
              help="Folder that receives one campaign folder per module (m0001, m0002, ...).")
@click.option("--truth", "truth_dir", default="raw/truth/fleet", show_default=True,
              type=click.Path(file_okay=False), help="Folder for the generator's truth (never read by the pipeline).")
@click.option("--units", type=click.IntRange(1), default=50, show_default=True, help="Modules to simulate.")
@click.option("--seed", type=int, default=2026, show_default=True)
def simulate_fleet_cmd(out_dir, truth_dir, units, seed):
    """Simulate a production week of joint modules (see pipeline.encoder.simulate.FLEET_FIXTURE).

    Modules of both published designs with their own amplitudes and phases; 30 % from a
    reducer batch with a stable order-6 error below the paper's threshold, 10 % with a warm-up
    drift; with 20 units or more, two with a damaged bearing and one with a loose autocollimator.
    """
    from ..encoder.simulate import simulate_fleet, write_encoder_campaign

    for name, frame, truth in simulate_fleet(units, seed):
        write_encoder_campaign(out_dir, name, frame, truth, truth_dir)
    click.echo(f"wrote {units} modules to {out_dir}/ (truth in {truth_dir}/)", err=True)
