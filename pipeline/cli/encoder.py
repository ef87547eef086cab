"""The encoder chain's commands (paper 1): simulate encoder, harmonic, aliasing, select, compensate,
correct, report. ``ingest``, ``validate`` and ``fit`` take either kind (:mod:`pipeline.cli.campaign`).

Library imports are inside the commands: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..core.errors import InputError
from .common import HiddenOption, fail_spec, load_spec, read_interim, read_json


def _hidden_help() -> str:
    from ..encoder.simulate import hidden_effects_help

    return hidden_effects_help()


@click.command("encoder")
@click.option("--out", "out_dir", default="raw/encoder", show_default=True, type=click.Path(file_okay=False),
              help="Folder that receives one campaign folder per module.")
@click.option("--truth", "truth_dir", default="raw/truth/encoder", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the generator's truth (never read by the pipeline).")
@click.option("--module", "modules", multiple=True, default=("a", "b"), show_default=True,
              help="Module(s) to simulate: the fixture's a and b, or any new name (uses module a's physics).")
@click.option("--seed", type=int, default=None, help="Override the fixture's seed.")
@click.option("--runs", type=int, default=6, show_default=True, help="Runs per module.")
@click.option("--two-way", is_flag=True, help="Go round the polygon and come back (73 readings a run).")
@click.option("--hidden", cls=HiddenOption, choices_help=_hidden_help, default=None,
              metavar="EFFECT[:TARGET]",
              help="Hide one effect the paper's spec lacks: {choices}.")
def simulate_encoder_cmd(out_dir, truth_dir, modules, seed, runs, two_way, hidden):
    """Simulate encoder campaigns in the contract's format (default: the shipped fixture)."""
    from ..encoder.effects import effect_class
    from ..encoder.simulate import ENCODER_FIXTURE, hidden_encoder_effect, simulate_encoder, write_encoder_campaign

    for module in modules:
        config = dict(ENCODER_FIXTURE.get(module, ENCODER_FIXTURE["a"]))
        if seed is not None:
            config["seed"] = seed
        hid = hidden_encoder_effect(hidden, config["seed"]) if hidden else None
        if hid and effect_class(hid["effect"]).simulate_two_way:
            two_way = True
        frame, truth = simulate_encoder(module, config, runs=runs, two_way=two_way, hidden=hid)
        folder = write_encoder_campaign(out_dir, module, frame, truth, truth_dir)
        click.echo(f"wrote {folder}/ ({len(frame)} readings, {runs} runs){' with hidden ' + hidden if hidden else ''}", err=True)


@click.command()
@click.option("--interim", required=True, type=click.Path(), help="Ingested encoder Parquet.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Parquet of per-run coefficients.")
@click.option("--n-max", type=int, default=None,
              help="Highest order (default (N-1)//2 for N distinct angles; above N/2 is refused).")
@click.option("--grid-tol", type=float, default=0.05, show_default=True,
              help="Largest distance (deg) of an angle from the even grid for the FFT to apply.")
def harmonic(interim, out, n_max, grid_tol):
    """Per-run harmonic coefficients A_i, B_i, C_i, phi_i by least squares and FFT.

    Convention: error = C_0 + sum C_i sin(i theta + phi_i), phi_i = atan2(A_i, B_i).
    Also reports each run's closure (last reading minus first at the same angle, arcsec).
    """
    from ..core.files import write_parquet
    from ..encoder.aliasing import OrderTooHighError
    from ..encoder.harmonic import analyse_runs

    frame = read_interim(interim)
    try:
        table = analyse_runs(frame, n_max=n_max, grid_tol_deg=grid_tol)
    except OrderTooHighError as exc:
        raise click.BadParameter(str(exc), param_hint="--n-max") from None
    write_parquet(out, table)
    agree = (table["A"] - table["A_fft"]).abs().max()
    click.echo(f"{out}: orders 0..{table['order'].max()} for {table['run'].nunique()} runs; "
               f"N = {table['N'].iloc[0]} distinct angles; |LSQ - FFT| <= {agree:.3g} arcsec; "
               f"closure {table.groupby('run')['closure_arcsec'].first().abs().max():.2f} arcsec at most", err=True)


@click.command()
@click.option("--interim", required=True, type=click.Path(), help="Ingested encoder Parquet.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="CSV of the aliasing table.")
@click.option("--highest", type=int, default=100, show_default=True, help="Highest order listed as a source.")
def aliasing(interim, out, highest):
    """Tabulate which higher orders fold into each fitted order (paper 1, Eqs. 3-4)."""
    from ..core.files import write_csv
    from ..encoder.aliasing import alias_frame, max_full_order, max_order
    from ..encoder.effects import EncoderData

    N = EncoderData.from_frame(read_interim(interim)).distinct_angles()
    write_csv(out, alias_frame(N, highest))
    click.echo(f"{out}: N = {N} distinct angles, highest order {max_order(N)} "
               f"(both sine and cosine up to {max_full_order(N)})", err=True)


@click.command()
@click.option("--interim", required=True, type=click.Path(), help="Ingested encoder Parquet.")
@click.option("--harmonics", required=True, type=click.Path(), help="Per-run coefficients (jointcal harmonic).")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="Encoder spec with [select] thresholds.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="JSON of the selection.")
def select(interim, harmonics, spec_path, out):
    """Choose harmonic orders: the paper's rule, and beside it a cross-validated choice.

    Paper rule over the modelling runs: keep an order whose mean amplitude is at least
    amplitude_strong_arcsec, or at least amplitude_min_arcsec with a phase range of at most
    phase_range_max_deg. The CV choice adds orders while the leave-one-run-out RMS falls.
    """
    from ..core.files import provenance, write_json
    from ..encoder.selection import selection_document

    spec = load_spec(spec_path)
    frame = read_interim(interim)
    table = read_interim(harmonics)
    try:
        doc = selection_document(frame, spec, table)
    except ValueError as exc:
        fail_spec(spec_path, str(exc), r"^\s*(modelling_runs|validation_runs)\s*=")
    doc["provenance"] = provenance([interim, harmonics], spec_path)
    write_json(out, doc)
    click.echo(f"{out}: paper rule {doc['paper_rule_orders']}; cross-validated {doc['cv_orders']}; using {doc['orders']}",
               err=True)


@click.command()
@click.option("--model", "model_path", required=True, type=click.Path(), help="Model JSON (jointcal fit).")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="CSV table to write.")
@click.option("--step", type=float, default=0.1, show_default=True, help="Angle step of the table (deg).")
def compensate(model_path, out, step):
    """Write the compensation table: modelled error and correction (arcsec) every STEP degrees."""
    from ..core.files import write_csv
    from ..encoder.compensate import compensation_table
    from ..encoder.evaluate import model_from_result

    model = model_from_result(read_json(model_path))
    try:
        table = compensation_table(model, step)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--step") from None
    write_csv(out, table, float_format="%.4f")
    click.echo(f"{out}: {len(table)} angles, correction {table['correction_arcsec'].min():.2f} .. "
               f"{table['correction_arcsec'].max():.2f} arcsec", err=True)


@click.command()
@click.option("--model", "model_path", required=True, type=click.Path(), help="Model JSON (jointcal fit).")
@click.option("--input", "input_path", default="-", show_default=True, type=click.Path(),
              help="CSV with a column of joint readings, or - for standard input.")
@click.option("--column", default="encoder_deg", show_default=True, help="Column of readings (deg).")
@click.option("--output", "output_path", default="-", show_default=True, type=click.Path(),
              help="Where to write the CSV with corrected_deg and correction_arcsec added.")
def correct(model_path, input_path, column, output_path):
    """Correct joint readings (deg) with a fitted model: corrected = reading - error(reading).

    \b
    Example:
      printf 'encoder_deg\\n10.0\\n95.5\\n' | jointcal correct --model results/encoder/a_model.json
    """
    import pandas as pd

    from ..core.files import read_text_input, write_csv
    from ..core.tables import FLOAT, read_table, text_table
    from ..encoder.compensate import correct_readings
    from ..encoder.evaluate import model_from_result

    model = model_from_result(read_json(model_path))
    if input_path == "-":
        tmp_name = "<stdin>"
        table = text_table(sys.stdin.read(), tmp_name)
        if table is None:
            raise InputError(tmp_name, "no input on standard input", 1, None) from None
        raw, lines = table
        if column not in raw.columns:
            raise InputError(tmp_name, f"missing column '{column}'", 1, column)
        values = pd.to_numeric(raw[column], errors="coerce")
        if values.isna().any() or not values.map(lambda v: abs(v) < float("inf")).all():
            i = int(values.isna().to_numpy().argmax())
            raise InputError(tmp_name, f"'{raw[column].iloc[i]}' is not a finite number", int(lines[i]), column)
        frame = raw
        readings = values.to_numpy(float)
    else:
        readings = read_table(input_path, {column: FLOAT})[column].to_numpy(float)
        frame = text_table(read_text_input(input_path, "input"), input_path)[0]
    corrected, correction = correct_readings(model, readings)
    frame = frame.copy()
    frame["corrected_deg"] = [f"{v:.7f}" for v in corrected]
    frame["correction_arcsec"] = [f"{v:.3f}" for v in correction]
    if output_path == "-":
        click.echo(frame.to_csv(index=False, lineterminator="\n"), nl=False)
    else:
        write_csv(output_path, frame)


@click.command()
@click.option("--kind", type=click.Choice(["encoder"]), default="encoder", show_default=True)
@click.option("--results", "results_dir", default="results/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>_model.json, _orders.json, _aliasing.csv.")
@click.option("--interim", "interim_dir", default="interim/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>.parquet and <module>_harmonics.parquet.")
@click.option("--module", "modules", multiple=True, default=("a", "b"), show_default=True)
@click.option("--out", default="reports/encoder.pdf", show_default=True, type=click.Path(dir_okay=False))
def report(kind, results_dir, interim_dir, modules, out):
    """Write the PDF report: the paper's Figures 4-9, the aliasing table, numbers beside the paper's."""
    from ..encoder.report import encoder_report

    inputs = {}
    for m in modules:
        inputs[m] = {"readings": read_interim(Path(interim_dir) / f"{m}.parquet"),
                     "harmonics": read_interim(Path(interim_dir) / f"{m}_harmonics.parquet"),
                     "selection": read_json(Path(results_dir) / f"{m}_orders.json"),
                     "model": read_json(Path(results_dir) / f"{m}_model.json"),
                     "aliasing": Path(results_dir) / f"{m}_aliasing.csv"}
    encoder_report(inputs, out)
    click.echo(f"{out}: written", err=True)
