"""The ``jointcal`` command: one thin click subcommand per stage.

Commands read files, call the library's pure functions and write results atomically.
Bad input ends with exit status 2 and one line ``file:line:column: message``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

# The linear algebra here is small (hundreds of parameters at most): one BLAS thread is
# faster and steadier than OpenBLAS's spinning pool (measured: up to 100x on two cores).
# Set before numpy is first imported; the user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import click  # noqa: E402

from .errors import InputError


def _fail_spec(spec_path, message, pattern=r"^\s*(orders|n_max)\s*="):
    from .spec import _locate

    try:
        text = Path(spec_path).read_text(encoding="utf-8")
        line, col = _locate(text, pattern)
    except OSError:
        line, col = None, None
    raise InputError(spec_path, message, line, col)


def _read_json(path):
    from .io import read_json_input

    return read_json_input(path)


def _read_interim(path):
    from .io import read_parquet_input

    return read_parquet_input(path)


def campaign_kind(folder) -> str:
    """``"robot"`` when the folder has robot.toml/poses.csv/tracker.csv, else ``"encoder"``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "campaign folder not found")
    if (folder / "robot.toml").exists() or (folder / "poses.csv").exists():
        return "robot"
    return "encoder"


class BadInput(click.ClickException):
    """Bad input as click sees it: exit status 2, one line, no traceback."""

    exit_code = 2

    def show(self, file=None):
        click.echo(f"jointcal: error: {self.message}", err=True)


class JointcalGroup(click.Group):
    """Turns :class:`InputError` raised anywhere in a command into exit 2 with one line."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as exc:
            raise BadInput(exc.one_line()) from None


@click.group(cls=JointcalGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="jointcal")
def cli():
    """jointcal: calibrate robot joints and robots.

    \b
    Encoder chain (one joint module, polygon + autocollimator):
      ingest -> harmonic -> aliasing -> select -> fit -> compensate -> report
    Robot chain (laser tracker): see `jointcal robot --help`.
    Diagnosis: `jointcal diagnose` ranks the physical effects a model lacks.

    Units: angles in degrees, angle errors in arcseconds, lengths in millimetres.
    `make all` runs every stage on the shipped fixtures; `make help` lists the targets.
    """


# ------------------------------------------------------------------------------- simulate
@cli.group()
def simulate():
    """Write synthetic campaigns (seeded, deterministic) with documented physics."""


@simulate.command("encoder")
@click.option("--out", "out_dir", default="raw/encoder", show_default=True, type=click.Path(file_okay=False),
              help="Folder that receives one campaign folder per module.")
@click.option("--truth", "truth_dir", default="raw/truth/encoder", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the generator's truth (never read by the pipeline).")
@click.option("--module", "modules", multiple=True, default=("a", "b"), show_default=True,
              help="Module(s) to simulate: the fixture's a and b, or any new name (uses module a's physics).")
@click.option("--seed", type=int, default=None, help="Override the fixture's seed.")
@click.option("--runs", type=int, default=6, show_default=True, help="Runs per module.")
@click.option("--two-way", is_flag=True, help="Go round the polygon and come back (73 readings a run).")
@click.option("--hidden", default=None, metavar="EFFECT[:TARGET]",
              help="Hide one effect the paper's spec lacks: direction, drift, temperature or harmonic:ORDER.")
def simulate_encoder_cmd(out_dir, truth_dir, modules, seed, runs, two_way, hidden):
    """Simulate encoder campaigns in the contract's format (default: the shipped fixture)."""
    from .simulate import ENCODER_FIXTURE, hidden_encoder_effect, simulate_encoder, write_encoder_campaign

    for module in modules:
        config = dict(ENCODER_FIXTURE.get(module, ENCODER_FIXTURE["a"]))
        if seed is not None:
            config["seed"] = seed
        hid = hidden_encoder_effect(hidden, config["seed"]) if hidden else None
        if hid and hid["effect"] == "direction":
            two_way = True
        frame, truth = simulate_encoder(module, config, runs=runs, two_way=two_way, hidden=hid)
        folder = write_encoder_campaign(out_dir, module, frame, truth, truth_dir)
        click.echo(f"wrote {folder}/ ({len(frame)} readings, {runs} runs){' with hidden ' + hidden if hidden else ''}", err=True)


# ---------------------------------------------------------------------------------- ingest
@cli.command()
@click.option("--campaign", required=True, type=click.Path(), help="Raw campaign folder, e.g. raw/encoder/a.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Parquet file to write.")
def ingest(campaign, out):
    """Validate a raw campaign (contract sections 1-2) and write the derived table as Parquet.

    Encoder: adds error_arcsec (joint reading minus polygon + autocollimator reference,
    relative to the run's first reading) and theta_deg (encoder reading mod 360).
    """
    from .io import write_parquet

    if campaign_kind(campaign) == "robot":
        from .robot_cli import ingest_robot_to

        ingest_robot_to(campaign, out)
        return
    from .ingest import ingest_encoder

    from .io import provenance

    frame = ingest_encoder(campaign)
    files = sorted(Path(campaign).glob("*.csv")) + sorted(Path(campaign).glob("campaign.toml"))
    write_parquet(out, frame, {"campaign": str(campaign), **provenance(files)})
    click.echo(f"{out}: {len(frame)} readings, {frame['run'].nunique()} runs of module {frame['module'].iloc[0]}", err=True)


@cli.command()
@click.option("--campaign", required=True, type=click.Path(), help="Raw campaign folder.")
def validate(campaign):
    """Check a raw campaign without writing anything; list every problem, exit 2 if any."""
    from .tables import Problems

    problems = Problems()
    if campaign_kind(campaign) == "robot":
        from .robot_cli import validate_robot

        validate_robot(campaign, problems)
    else:
        from .ingest import load_encoder_campaign

        try:
            load_encoder_campaign(campaign, problems)
        except InputError:
            pass
    for p in problems:
        click.echo(p.one_line(), err=True)
    if problems:
        sys.exit(2)
    click.echo(f"{campaign}: no problems found", err=True)


# -------------------------------------------------------------------------------- harmonic
@cli.command()
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
    from .aliasing import OrderTooHighError
    from .harmonic import analyse_runs
    from .io import write_parquet

    frame = _read_interim(interim)
    try:
        table = analyse_runs(frame, n_max=n_max, grid_tol_deg=grid_tol)
    except OrderTooHighError as exc:
        raise click.BadParameter(str(exc), param_hint="--n-max") from None
    write_parquet(out, table)
    agree = (table["A"] - table["A_fft"]).abs().max()
    click.echo(f"{out}: orders 0..{table['order'].max()} for {table['run'].nunique()} runs; "
               f"N = {table['N'].iloc[0]} distinct angles; |LSQ - FFT| <= {agree:.3g} arcsec; "
               f"closure {table.groupby('run')['closure_arcsec'].first().abs().max():.2f} arcsec at most", err=True)


@cli.command()
@click.option("--interim", required=True, type=click.Path(), help="Ingested encoder Parquet.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="CSV of the aliasing table.")
@click.option("--highest", type=int, default=100, show_default=True, help="Highest order listed as a source.")
def aliasing(interim, out, highest):
    """Tabulate which higher orders fold into each fitted order (paper 1, Eqs. 3-4)."""
    import pandas as pd

    from .aliasing import alias_table, max_full_order, max_order
    from .effects import EncoderData
    from .io import write_csv

    data = EncoderData.from_frame(_read_interim(interim))
    N = data.distinct_angles()
    rows = alias_table(N, max_order(N), highest)
    table = pd.DataFrame([{"order": r["order"], "folds_from": " ".join(map(str, r["cos_from"])),
                           "sin_added": " ".join(map(str, r["sin_plus"])),
                           "sin_subtracted": " ".join(map(str, r["sin_minus"])), "equation": r["equation"]}
                          for r in rows])
    table.insert(0, "N_distinct", N)
    write_csv(out, table)
    click.echo(f"{out}: N = {N} distinct angles, highest order {max_order(N)} "
               f"(both sine and cosine up to {max_full_order(N)})", err=True)


# ---------------------------------------------------------------------------------- select
@cli.command()
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
    import numpy as np

    from .effects import EncoderData
    from .io import provenance, write_json
    from .select import cv_select, select_orders
    from .spec import load_spec

    spec = load_spec(spec_path)
    frame = _read_interim(interim)
    table = _read_interim(harmonics)
    try:
        paper_orders, model_runs, rule = select_orders(frame, spec, table)
    except ValueError as exc:
        _fail_spec(spec_path, str(exc), r"^\s*(modelling_runs|validation_runs)\s*=")
    h = spec.effect("harmonic")
    explicit = h is not None and isinstance(h.params.get("orders"), list)
    data = EncoderData.from_frame(frame)
    n_fit = int(table["order"].max())
    train = data.subset(np.isin(data.run, model_runs))
    cv_orders, path = cv_select(train, n_fit)
    chosen = sorted(h.params["orders"]) if explicit else paper_orders
    write_json(out, {"module": str(frame["module"].iloc[0]), "orders": chosen,
                     "rule": "spec" if explicit else spec.select.get("rule", "paper"),
                     "paper_rule_orders": paper_orders, "cv_orders": cv_orders,
                     "cv_path": [{"added": a, "cv_rms_arcsec": b} for a, b in path],
                     "thresholds": spec.select, "modelling_runs": model_runs,
                     "table": rule.to_dict(orient="records"),
                     "provenance": provenance([interim, harmonics], spec_path)})
    click.echo(f"{out}: paper rule {paper_orders}; cross-validated {cv_orders}; using {chosen}", err=True)


# ------------------------------------------------------------------------------------- fit
@cli.command()
@click.option("--interim", default=None, type=click.Path(), help="Ingested encoder Parquet (jointcal ingest).")
@click.option("--campaign", default=None, type=click.Path(), help="Or a raw campaign folder (ingested on the fly).")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="Model spec (specs/*.toml).")
@click.option("--orders", "orders_path", type=click.Path(), default=None,
              help="Selection JSON (jointcal select). Without it, orders the spec leaves open are chosen by "
                   "the spec's [select] rule on the modelling runs.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Model JSON to write.")
def fit(interim, campaign, spec_path, orders_path, out):
    """Fit the spec's model on the modelling runs; evaluate it on the held-out run.

    Reports the peak-to-peak error of the validation run before and after compensation
    (the paper's measure) and the leave-one-run-out cross-validated RMS of the spec's
    model (the measure `jointcal diagnose` ranks effects by), so the effect of a line
    added to the spec is seen in both.
    """

    from .aliasing import OrderTooHighError
    from .evaluate import fit_encoder_spec
    from .io import provenance, write_json
    from .spec import load_spec

    spec = load_spec(spec_path)
    if (interim is None) == (campaign is None):
        raise click.UsageError("give exactly one of --interim or --campaign")
    if campaign is not None:
        if campaign_kind(campaign) == "robot":
            from .robot_cli import fit_robot

            fit_robot(campaign, spec, spec_path, out)
            return
        from .ingest import ingest_encoder

        frame = ingest_encoder(campaign)
    else:
        frame = _read_interim(interim)
    spec.require_kind("encoder", campaign or interim)
    orders = _read_json(orders_path)["orders"] if orders_path else None
    try:
        result = fit_encoder_spec(frame, spec, orders)
    except OrderTooHighError as exc:
        _fail_spec(spec_path, str(exc))
    except ValueError as exc:
        _fail_spec(spec_path, str(exc), r"^\s*(modelling_runs|validation_runs)\s*=")
    inputs = [interim or campaign] + ([orders_path] if orders_path else [])
    result["provenance"] = provenance([p for p in inputs if p and not Path(p).is_dir()] +
                                      (sorted(str(f) for f in Path(campaign).glob("*.csv")) if campaign else []),
                                      spec_path)
    write_json(out, result)
    click.echo(f"{out}: {' + '.join(result['effects'])}; orders {result['orders']}; validation run "
               f"{result['validation_runs']}: p2p {result['p2p_before_arcsec']:.2f} -> {result['p2p_after_arcsec']:.2f} "
               f"arcsec ({result['reduction_pct']:.2f} % less); cross-validated RMS {result['cv_rms_arcsec']:.3f} arcsec",
               err=True)


# ------------------------------------------------------------------------------ compensate
@cli.command()
@click.option("--model", "model_path", required=True, type=click.Path(), help="Model JSON (jointcal fit).")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="CSV table to write.")
@click.option("--step", type=float, default=0.1, show_default=True, help="Angle step of the table (deg).")
def compensate(model_path, out, step):
    """Write the compensation table: modelled error and correction (arcsec) every STEP degrees."""
    from .compensate import compensation_table
    from .evaluate import model_from_result
    from .io import write_csv

    model = model_from_result(_read_json(model_path))
    try:
        table = compensation_table(model, step)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--step") from None
    write_csv(out, table, float_format="%.4f")
    click.echo(f"{out}: {len(table)} angles, correction {table['correction_arcsec'].min():.2f} .. "
               f"{table['correction_arcsec'].max():.2f} arcsec", err=True)


@cli.command()
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
    import io as _io

    import pandas as pd

    from .compensate import correct_readings
    from .evaluate import model_from_result
    from .io import write_csv
    from .tables import FLOAT, read_table

    model = model_from_result(_read_json(model_path))
    if input_path == "-":
        text = sys.stdin.read()
        tmp_name = "<stdin>"
        buf = _io.StringIO(text)
        try:
            raw = pd.read_csv(buf, dtype=str, keep_default_na=False)
        except pd.errors.EmptyDataError:
            raise InputError(tmp_name, "no input on standard input", 1, None) from None
        if column not in raw.columns:
            raise InputError(tmp_name, f"missing column '{column}'", 1, column)
        values = pd.to_numeric(raw[column], errors="coerce")
        if values.isna().any() or not values.map(lambda v: abs(v) < float("inf")).all():
            i = int(values.isna().to_numpy().argmax())
            raise InputError(tmp_name, f"'{raw[column].iloc[i]}' is not a finite number", i + 2, column)
        frame = raw
        readings = values.to_numpy(float)
    else:
        frame = read_table(input_path, {column: FLOAT})
        readings = frame[column].to_numpy(float)
        frame = pd.read_csv(input_path, dtype=str, keep_default_na=False)
    corrected, correction = correct_readings(model, readings)
    frame = frame.copy()
    frame["corrected_deg"] = [f"{v:.7f}" for v in corrected]
    frame["correction_arcsec"] = [f"{v:.3f}" for v in correction]
    if output_path == "-":
        click.echo(frame.to_csv(index=False, lineterminator="\n"), nl=False)
    else:
        write_csv(output_path, frame)


# ---------------------------------------------------------------------------------- report
@cli.command()
@click.option("--kind", type=click.Choice(["encoder"]), default="encoder", show_default=True)
@click.option("--results", "results_dir", default="results/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>_model.json, _orders.json, _aliasing.csv.")
@click.option("--interim", "interim_dir", default="interim/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>.parquet and <module>_harmonics.parquet.")
@click.option("--module", "modules", multiple=True, default=("a", "b"), show_default=True)
@click.option("--out", default="reports/encoder.pdf", show_default=True, type=click.Path(dir_okay=False))
def report(kind, results_dir, interim_dir, modules, out):
    """Write the PDF report: the paper's Figures 4-9, the aliasing table, numbers beside the paper's."""
    from .report import encoder_report

    inputs = {}
    for m in modules:
        inputs[m] = {"readings": _read_interim(Path(interim_dir) / f"{m}.parquet"),
                     "harmonics": _read_interim(Path(interim_dir) / f"{m}_harmonics.parquet"),
                     "selection": _read_json(Path(results_dir) / f"{m}_orders.json"),
                     "model": _read_json(Path(results_dir) / f"{m}_model.json"),
                     "aliasing": Path(results_dir) / f"{m}_aliasing.csv"}
    encoder_report(inputs, out)
    click.echo(f"{out}: written", err=True)


# --------------------------------------------------------------------------------- summary
@cli.command()
@click.option("--encoder-results", default="results/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>_model.json files.")
@click.option("--robot-results", default="results/robot", show_default=True, type=click.Path(),
              help="Folder with table2.json (robot part), if the robot chain ran.")
@click.option("--real-results", default="results/real", show_default=True, type=click.Path(),
              help="Folder with transfer.json (real section), if the real-robot chain ran.")
@click.option("--out", default="results/summary.json", show_default=True, type=click.Path(dir_okay=False))
def summary(encoder_results, robot_results, real_results, out):
    """Write results/summary.json (contract section 5) from the stages' results."""
    from .io import write_json
    from .summary import build_summary

    models = {}
    for p in sorted(Path(encoder_results).glob("*_model.json")):
        m = _read_json(p)
        models[m["module"]] = m
    robot_path = Path(robot_results) / "table2.json"
    robot = _read_json(robot_path) if robot_path.exists() else None
    beyond_path = Path(robot_results) / "beyond" / "table2.json"
    if robot is not None and beyond_path.exists():
        b = _read_json(beyond_path)
        robot["beyond_paper"] = {"spec": "specs/robot_beyond.toml", "added": "backlash of joints 4-6",
                                 "feedback": b["feedback"], "max_reduction_pct": b["max_reduction_pct"]}
    real_path = Path(real_results) / "transfer.json"
    real = _read_json(real_path) if real_path.exists() else None
    write_json(out, build_summary(models, robot, real))
    click.echo(f"{out}: {len(models)} module(s){' and the robot' if robot else ''}", err=True)


def _register_optional():
    """Robot and diagnosis commands live in their own modules."""
    for name in ("robot_cli", "diagnose_cli", "fleet_cli", "import_cli"):
        try:
            module = __import__(f"pipeline.{name}", fromlist=["register"])
        except ImportError:
            continue
        module.register(cli)


_register_optional()


def main(argv=None):
    """Entry point. Bad input -> one line on stderr and exit status 2 (see :class:`BadInput`)."""
    try:
        cli.main(args=argv, prog_name="jointcal")
    except InputError as exc:  # raised outside a subcommand (e.g. while registering)
        click.echo(f"jointcal: error: {exc.one_line()}", err=True)
        sys.exit(2)
