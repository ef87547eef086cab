"""Robot commands: ``jointcal simulate robot`` and the ``jointcal robot`` group (thin wrappers).

Chain (the second paper): ingest -> calibrate (MDH, Eqs. 3-6) -> chebyshev (Eqs. 7-21)
-> map-joints (Eqs. 22-24) -> closed-loop (Eq. 26) -> evaluate (Table 2, Figs. 6-11) -> report.
Also ``jointcal predict`` and the robot side of ``ingest``, ``validate`` and ``fit`` (the helpers
:func:`ingest_robot_to`, :func:`validate_robot`, :func:`fit_robot`).

Each command reads its inputs, calls one library function (the stages: :mod:`pipeline.robot.paper.chain`,
:mod:`pipeline.robot.cell.stages`), writes what it returns and prints one line. Library imports are
inside the commands: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..core.errors import InputError
from ..core.wild import HELP as WILD_HELP
from .common import HiddenOption, load_spec

DEFAULT_SPEC = "specs/robot_paper.toml"
DEFAULT_ROBOT = "raw/robot/kr210/robot.toml"
DEFAULT_INTERIM = "interim/robot/poses.parquet"


def _edge():
    from ..robot.model.lm import limit_blas_threads

    limit_blas_threads(1)


def _warn(msg):
    """A warning on stderr, prefixed ``jointcal:``."""
    click.echo(f"jointcal: {msg}", err=True)


def _progress(msg):
    """A progress line on stderr, indented."""
    click.echo(f"  {msg}", err=True)


def _read_json(path):
    from ..core.files import read_json_input

    return read_json_input(path, "run the stage that makes it first, or `make robot`")


def _interim(path):
    """An ingested robot table, checked against its nominal kinematics (:func:`pipeline.robot.campaign.ingest.check_ingested`)."""
    from ..core.files import parquet_metadata, read_parquet_input
    from ..robot.campaign.ingest import check_ingested

    frame = read_parquet_input(path, "run `jointcal ingest --campaign raw/robot/<robot>` first")
    check_ingested(frame, path, parquet_metadata(path))
    return frame


def _robot(path):
    from ..robot.arm.kinematics import load_robot

    return load_robot(path)


def _paper_robot(path, command: str):
    """The robot of a stage that runs the paper's virtual six-joint cell (gratings on joints 1-3):
    another joint count is refused with one line."""
    from ..robot.paper.chain import require_paper_robot

    robot = _robot(path)
    require_paper_robot(robot, path, command)
    return robot


def _spec(path):
    spec = load_spec(path)
    if spec.kind != "robot":
        raise InputError(path, f"a robot stage needs a spec with kind = \"robot\", found {spec.kind!r}", 1, 1)
    return spec


def warn_unstaged(spec) -> None:
    """Warn about effects that neither stage of the paper's chain takes (``fit`` and ``diagnose`` do)."""
    from ..robot.model.fit import unstaged_effects

    left = unstaged_effects(spec)
    if left:
        click.echo(f"jointcal: warning: {spec.path}: {', '.join(left)} in no stage of [model] kinematic_effects / "
                   "feedback_effects: this chain leaves them out (jointcal fit and diagnose use every effect)", err=True)


# ---------------------------------------------------------------------- ingest / validate
def ingest_robot_to(campaign, out):
    """``jointcal ingest`` for a robot campaign folder."""
    from ..core.files import provenance, write_parquet
    from ..robot.campaign.frame import describe, from_matrix
    from ..robot.campaign.ingest import campaign_files, ingest_robot_with_frame, ingested_metadata

    robot, frame, info = ingest_robot_with_frame(campaign)
    write_parquet(out, frame, ingested_metadata(campaign, info, provenance(campaign_files(campaign))))
    counts = frame["set"].value_counts().to_dict()
    where = (f"tracker frame -> base: {describe(*from_matrix(info['tracker_to_base']))} (fitted on the sample poses)"
             if info["frame"] == "tracker" else "base frame")
    click.echo(f"{out}: {len(frame)} poses of {robot.name} ({', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}); "
               f"{where}; nominal kinematics leave RMS {info['nominal_rms_mm']:.2f} mm after a rigid fit", err=True)


def validate_robot(campaign, problems):
    """``jointcal validate`` for a robot campaign folder: collect every problem."""
    from ..robot.campaign.ingest import load_robot_campaign

    try:
        load_robot_campaign(campaign, problems)
    except InputError as exc:  # pragma: no cover - collected mode does not raise
        problems.append(exc)


# ------------------------------------------------------------------------------ simulate
def _hidden_help() -> str:
    from ..robot.cell.simulate import hidden_effects_help

    return hidden_effects_help()


@click.command("robot")
@click.option("--campaign", default="raw/robot/kr210", show_default=True, type=click.Path(file_okay=False),
              help="Campaign folder holding robot.toml; receives poses.csv and tracker.csv.")
@click.option("--truth", "truth_path", default="raw/truth/robot/kr210.json", show_default=True,
              type=click.Path(dir_okay=False), help="Where the generator's truth goes (never read by the pipeline).")
@click.option("--seed", type=int, default=None, help="Override the fixture's seed.")
@click.option("--hidden", cls=HiddenOption, choices_help=_hidden_help, default=None,
              metavar="EFFECT[:JOINT]",
              help="Add one effect the paper's spec lacks, at a random realistic size: {choices}.")
@click.option("--robot", "robot_path", default=None, type=click.Path(dir_okay=False),
              help="Simulate this robot instead of the campaign's robot.toml: a robot.toml with 4 to 7 [[joint]] "
                   "tables, or a URDF (with --tip); copied into the campaign as its robot.toml.")
@click.option("--tip", default=None, help="URDF --robot: the link whose origin is the SMR.")
@click.option("--base", default=None, help="URDF --robot: the base link (default: the URDF's root).")
@click.option("--probe", type=click.Choice(["smr", "6dof"]), default="smr", show_default=True,
              help="What the tracker measures: an SMR's position, or a 6-DoF probe's position and orientation "
                   "(tracker.csv qw, qx, qy, qz; noise 20 arcsec per axis, the probe's true mounting 120 arcsec "
                   "per axis off robot.toml's [tool] rpy_deg; both in the truth).")
def simulate_robot_cmd(campaign, truth_path, seed, hidden, robot_path, tip, base, probe):
    """Simulate the laser-tracker campaign of a virtual cell (seeded; lengths mm, angles deg).

    Without --robot: the paper's KR210 cell (raw/robot/kr210): 100 sample + 104 target poses in the
    paper's Table 1 joint ranges inside a 600 x 1000 x 600 mm box with the end orientation within
    +-10 deg, visited in random order, and ISO 9283 repeat rows (P1-P3, 30 cycles, three 100 mm
    approaches). With --robot (any serial arm of 4 to 7 joints, e.g. raw/robot/panda/robot.toml):
    the same physics scaled to the arm (test box 0.9 x its reach, orientation within +-30 deg,
    payload a tenth of its mass, no ISO rows, no gratings). Physics: raw/README.md.
    """
    from ..core.files import write_json, write_text
    from ..robot.campaign.importer import load_import_robot
    from ..robot.cell.simulate import cell_config, hidden_robot_effect, simulated_campaign

    _edge()
    robot_text = None
    if robot_path is not None:
        robot, robot_text, _ = load_import_robot(robot_path, tip, base)
    else:
        robot = _robot(Path(campaign) / "robot.toml")
    config = cell_config(robot, seed, paper=robot_path is None)
    if probe == "6dof":
        from ..robot.cell.simulate import PROBE_6DOF

        config.update(PROBE_6DOF)
    try:
        hid = hidden_robot_effect(hidden, config["seed"], robot.n_joints) if hidden else None
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--hidden") from None
    files, truth, n = simulated_campaign(robot, config, hid)
    if robot_text is not None:
        write_text(Path(campaign) / "robot.toml", robot_text)
    for name, text in files.items():
        write_text(Path(campaign) / name, text)
    write_json(truth_path, truth)
    click.echo(f"wrote {campaign}/poses.csv and tracker.csv ({n} poses){' with hidden ' + hidden if hidden else ''}",
               err=True)


# --------------------------------------------------------------------------- robot group
@click.group("robot")
def robot_group():
    """Robot chain (second paper): calibrate -> chebyshev -> map-joints -> closed-loop -> evaluate -> report.

    \b
    Start with `jointcal ingest --campaign raw/robot/kr210 --out interim/robot/poses.parquet`.
    Units: lengths and position errors mm, joint angles deg, angle errors arcsec.
    """


def _common(f):
    f = click.option("--interim", default=DEFAULT_INTERIM, show_default=True, type=click.Path(),
                     help="Ingested campaign (jointcal ingest).")(f)
    f = click.option("--robot", "robot_path", default=DEFAULT_ROBOT, show_default=True, type=click.Path(),
                     help="Nominal robot.toml of the campaign.")(f)
    return f


def _refuse(where, message: str, out) -> None:
    """A result that must not be used: one line, exit status 1 (not bad input), no output file
    (a previous one at ``out`` is removed, so no stale model reaches the next stage)."""
    stale = Path(out).exists()
    if stale:
        Path(out).unlink()
    click.echo(f"jointcal: error: {where}: {message}; nothing written{f' (removed the previous {out})' if stale else ''}",
               err=True)
    sys.exit(1)


@robot_group.command("calibrate")
@_common
@click.option("--spec", "spec_path", default=DEFAULT_SPEC, show_default=True, type=click.Path(),
              help="Robot spec; [model] kinematic_effects names the effects of this stage.")
@click.option("--out", default="results/robot/mdh.json", show_default=True, type=click.Path(dir_okay=False))
def calibrate_cmd(interim, robot_path, spec_path, out):
    """MDH kinematic calibration on the sample poses (Eqs. 3-6, least squares iterated).

    Reports rank and condition number of the scaled Jacobian and the parameters that the poses
    cannot identify (fixed at 0). Parameters in mm and arcsec.
    """
    from ..core.files import provenance, write_json
    from ..robot.paper.chain import calibrate_stage

    _edge()
    robot, frame, spec = _robot(robot_path), _interim(interim), _spec(spec_path)
    warn_unstaged(spec)
    report, problems, seconds = calibrate_stage(robot, frame, spec, provenance([interim, robot_path], spec_path))
    if problems:
        _refuse(interim, f"MDH calibration unusable: {'; '.join(problems)}", out)
    write_json(out, report)
    click.echo(f"{out}: rank {report['rank']}/{report['n_params']}, condition {report['condition_number']:.0f}, "
               f"fixed {', '.join(report['not_identifiable']) or 'none'}; RMS {report['rms_before_mm']:.3f} -> "
               f"{report['rms_after_mm']:.3f} mm ({seconds:.2f} s)", err=True)


@robot_group.command("chebyshev")
@_common
@click.option("--spec", "spec_path", default=DEFAULT_SPEC, show_default=True, type=click.Path(),
              help="Robot spec with a chebyshev effect (order, joints).")
@click.option("--gratings/--no-gratings", default=True, show_default=True,
              help="Use the grating readings of joints 1-3 (grating1_deg..) as their angles when present.")
@click.option("--out", default="results/robot/chebyshev.json", show_default=True, type=click.Path(dir_okay=False))
def chebyshev_cmd(interim, robot_path, spec_path, gratings, out):
    """Identify the Chebyshev error transfer matrices (Eqs. 7-13) with the improved L-M (Eqs. 14-21).

    scipy.optimize.least_squares is run beside it as a cross-check; both costs (0.5 ||F||^2, mm^2),
    iterations and times are reported. Coefficients gamma in mm, lambda in arcsec.

    When either solver did not converge, their costs differ by more than 1 %, or a coefficient is
    beyond what a real robot can have (5 deg, 100 mm), nothing is written (a previous OUT is
    removed, so no stale model reaches map-joints) and the command exits 1 with one line saying why.
    """
    from ..core.files import provenance, write_json
    from ..robot.paper.chain import chebyshev_stage

    _edge()
    robot, frame, spec = _robot(robot_path), _interim(interim), _spec(spec_path)
    warn_unstaged(spec)
    result, problems, seconds = chebyshev_stage(robot, frame, spec, spec_path, gratings,
                                                provenance([interim, robot_path], spec_path))
    lm, sp = result["lm"], result["scipy"]
    if problems:
        _refuse(interim, f"Chebyshev identification unusable: {'; '.join(problems)}", out)
    write_json(out, result)
    click.echo(f"{out}: {result['n_params']} coefficients, rank {result['rank']}; improved L-M cost {lm['cost_mm2']:.5f} "
               f"({lm['iterations']} it, {seconds['lm']:.2f} s), scipy {sp['cost_mm2']:.5f} ({sp['iterations']} ev, "
               f"{seconds['scipy']:.2f} s)", err=True)


@robot_group.command("map-joints")
@_common
@click.option("--spec", "spec_path", default=DEFAULT_SPEC, show_default=True, type=click.Path())
@click.option("--model", "model_path", default="results/robot/chebyshev.json", show_default=True, type=click.Path(),
              help="Chebyshev model (jointcal robot chebyshev).")
@click.option("--out", default="results/robot/corrected_targets.csv", show_default=True, type=click.Path(dir_okay=False))
@click.option("--strict", is_flag=True,
              help="Refuse (exit 2) when a target lies outside the joint range the sample poses covered, "
                   "instead of warning: the model would extrapolate there.")
@click.option("--max-correction-deg", default=0.5, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Refuse (exit 1, nothing written) when any corrected command differs from its target by more "
                   "than this (deg). The paper's corrections are arcseconds; 0.5 deg moves a point 1 m out by "
                   "8.7 mm, more than a robot's error left to correct: beyond it the model or the mapping "
                   "(near a singular pose) is wrong.")
def map_joints_cmd(interim, robot_path, spec_path, model_path, out, strict, max_correction_deg):
    """Corrected commands of joints 1-3 for every target (Eqs. 22-24), deg.

    Targets outside the joint range covered by the sample poses (where the model was
    identified) are named in a warning; with --strict they are refused. A correction larger
    than --max-correction-deg is refused (exit 1, one line naming the target and the joint,
    nothing written; a previous OUT is removed).

    Columns: point_id, q1..q6 (commanded, deg), q1_corrected..q3_corrected (deg), dq1..dq3 (deg,
    the Eq. 23 angle errors; corrected = commanded - dq), dx_mm, dy_mm, dz_mm (predicted error).
    """
    import numpy as np

    from ..core.files import parquet_metadata, write_csv
    from ..robot.paper.chain import feedback_model, map_joints, outside_refusal, targets_outside
    from ..robot.model.predict import outside_message

    _edge()
    robot, frame, spec = _paper_robot(robot_path, "map-joints"), _interim(interim), _spec(spec_path)
    model = feedback_model(robot, spec, _read_json(model_path))
    outside = targets_outside(robot, frame)
    if outside:
        if strict:
            raise outside_refusal(outside, interim, parquet_metadata(interim))
        click.echo(f"jointcal: warning: {outside_message(outside)}", err=True)
    table, dth, refusal = map_joints(robot, frame, spec, model, max_correction_deg)
    if refusal:
        _refuse(model_path, refusal, out)
    write_csv(out, table, float_format="%.7f")
    click.echo(f"{out}: {len(table)} targets, |dq| up to {np.abs(dth).max() * 3600:.1f} arcsec", err=True)


@robot_group.command("closed-loop")
@_common
@click.option("--corrected", default="results/robot/corrected_targets.csv", show_default=True, type=click.Path(),
              help="Corrected commands (jointcal robot map-joints).")
@click.option("--seed", type=int, default=None, help="Seed of the virtual cell (default: the fixture's).")
@click.option("--out", default="results/robot/closed_loop.json", show_default=True, type=click.Path(dir_okay=False))
def closed_loop_cmd(interim, robot_path, corrected, seed, out):
    """Grating closed loop of joints 1-3 on the virtual cell (Eq. 26): 12 ms cycle, rough
    +-0.002 deg/cycle until |e| < 0.007 deg, then PD with kP = 0.05, kD = 0.65.

    Writes the loop's poles, cycles to converge per target and joint, and an error trace
    (deg per 12 ms cycle) for the convergence figure.
    """
    from ..core.files import write_json
    from ..robot.cell.stages import closed_loop_stage
    from ..robot.paper.chain import read_corrected

    _edge()
    robot, frame = _paper_robot(robot_path, "closed-loop"), _interim(interim)
    ids, q = read_corrected(corrected, robot)
    out_json = closed_loop_stage(robot, frame, ids, q, seed)
    poles = out_json["poles"]
    write_json(out, out_json)
    click.echo(f"{out}: poles {', '.join(f'{p:.3f}' for p in poles)}; median {out_json['cycles_median']:.0f} cycles, "
               f"max {out_json['cycles_max']} ({out_json['seconds_max']:.1f} s); final |e| <= "
               f"{out_json['final_error_arcsec_max']:.3f} arcsec", err=True)


@robot_group.command("evaluate")
@_common
@click.option("--spec", "spec_path", default=DEFAULT_SPEC, show_default=True, type=click.Path())
@click.option("--mdh", "mdh_path", default="results/robot/mdh.json", show_default=True, type=click.Path())
@click.option("--corrected", default="results/robot/corrected_targets.csv", show_default=True, type=click.Path())
@click.option("--tracker", "tracker_path", default=None, type=click.Path(),
              help="Re-measured tracker.csv of a real robot (point_ids <id>@kinematic, <id>@feedback); "
                   "default: the virtual cell executes the commands.")
@click.option("--seed", type=int, default=None, help="Seed of the virtual cell (default: the fixture's).")
@click.option("--out", default="results/robot/table2.json", show_default=True, type=click.Path(dir_okay=False))
def evaluate_cmd(interim, robot_path, spec_path, mdh_path, corrected, tracker_path, seed, out):
    """Table 2 (before / kinematic / feedback: range, mean, std of the absolute error, mm), the
    per-target errors (Figs. 7-11) and ISO 9283 vAP at P1-P3 with and without the loop (Fig. 6).

    Also writes <out dir>/target_errors.csv, iso9283.json and kinematic_commands.csv.
    """
    from ..core.files import provenance, write_csv, write_json
    from ..robot.cell.stages import evaluate_stage
    from ..robot.paper.chain import read_corrected

    _edge()
    robot, frame, spec = _paper_robot(robot_path, "evaluate"), _interim(interim), _spec(spec_path)
    mdh_json = _read_json(mdh_path)
    ids, qf = read_corrected(corrected, robot)
    result, tables = evaluate_stage(robot, frame, spec, mdh_json, ids, qf, corrected, tracker_path, seed)
    result["provenance"] = provenance([interim, robot_path, mdh_path, corrected] + ([tracker_path] if tracker_path else []),
                                      spec_path)
    outdir = Path(out).parent
    write_csv(outdir / "target_errors.csv", tables["target_errors"], float_format="%.5f")
    write_csv(outdir / "kinematic_commands.csv", tables["kinematic_commands"], float_format="%.7f")
    if "repeat_positions" in tables:
        write_csv(outdir / "repeat_positions.csv", tables["repeat_positions"], float_format="%.5f")
        write_json(outdir / "iso9283.json", tables["iso9283"])
    write_json(out, result)
    b, k, f = result["before"], result["kinematic"], result["feedback"]
    click.echo(f"{out}: max {b['max_mm']:.3f} -> kinematic {k['max_mm']:.3f} -> feedback {f['max_mm']:.3f} mm "
               f"(mean {b['mean_mm']:.3f} / {k['mean_mm']:.3f} / {f['mean_mm']:.3f}); max reduced by "
               f"{result['max_reduction_pct']:.1f} %", err=True)


@robot_group.command("report")
@click.option("--results", "results_dir", default="results/robot", show_default=True, type=click.Path())
@click.option("--beyond", "beyond_path", default=None, type=click.Path(),
              help="Table 2 JSON of a spec beyond the paper's (e.g. results/robot/beyond/table2.json).")
@click.option("--diagnosis", "diagnosis_path", default=None, type=click.Path(),
              help="Diagnosis JSON of the paper's spec on this campaign (what was found missing).")
@click.option("--out", default="reports/robot.pdf", show_default=True, type=click.Path(dir_okay=False))
def report_cmd(results_dir, beyond_path, diagnosis_path, out):
    """Write reports/robot.pdf: Figures 6-11 and Table 2 beside the paper's numbers (mm, deg, arcsec);
    with --beyond, a page with what adding the effects diagnosis found does to Table 2."""
    from ..robot.reporting.report import robot_report

    _edge()
    r = Path(results_dir)
    beyond = None
    if beyond_path:
        beyond = {"table2": _read_json(beyond_path),
                  "diagnosis": _read_json(diagnosis_path) if diagnosis_path else None}
    robot_report({"beyond": beyond, "table2": _read_json(r / "table2.json"), "mdh": _read_json(r / "mdh.json"),
                  "chebyshev": _read_json(r / "chebyshev.json"), "closed_loop": _read_json(r / "closed_loop.json"),
                  "iso": _read_json(r / "iso9283.json") if (r / "iso9283.json").exists() else {},
                  "errors": r / "target_errors.csv", "repeat": r / "repeat_positions.csv"}, out)
    click.echo(f"{out}: written", err=True)


@robot_group.command("real-report")
@click.option("--fit", "fits", multiple=True, type=click.Path(dir_okay=False),
              help="Your robot: a jointcal fit JSON (repeat for more models; each named by its file name). "
                   "Then --predict, --campaign (and --other) are read instead of --results/--campaigns.")
@click.option("--predict", "predicts", multiple=True, type=click.Path(dir_okay=False),
              help="jointcal predict JSON of each --fit on its own campaign (held-out poses), in the same order.")
@click.option("--other", "others", multiple=True, type=click.Path(dir_okay=False),
              help="Optional: jointcal predict --register JSON of each --fit on another campaign, in the same order.")
@click.option("--campaign", "campaign_dir", default=None, type=click.Path(file_okay=False),
              help="The imported campaign the --fit JSONs were fitted on (its poses.csv gives the joint angles); "
                   "default: the one the first --fit JSON names, when it is there.")
@click.option("--other-name", default="other", show_default=True, help="What to call the --other campaign.")
@click.option("--results", "results_dir", default="results/real", show_default=True, type=click.Path(),
              help="make real: folder with <series>_<spec>.json (fit), _self.json and _on_<other>.json (predict).")
@click.option("--campaigns", "campaigns_dir", default="interim/real", show_default=True, type=click.Path(),
              help="make real: folder with one imported campaign per series (jointcal import).")
@click.option("--note", default=None, help="A sentence about the data set, printed under the first page's title.")
@click.option("--out-json", default=None, type=click.Path(dir_okay=False),
              help="The report's numbers (summary.json's real section); default: results/real/transfer.json, "
                   "or none with --fit.")
@click.option("--out", default="reports/real.pdf", show_default=True, type=click.Path(dir_okay=False))
def real_report_cmd(fits, predicts, others, campaign_dir, other_name, results_dir, campaigns_dir, note, out_json, out):
    """Write a report of a robot's fitted models on poses they never saw: nominal and each model's errors
    (mm, arcsec) on the campaign's held-out poses and on another campaign (registered), coverage of the
    stated u95, and each held-out pose's error against each joint angle (deg).

    Your robot: --fit FIT.json --predict PRED.json [--campaign CAMPAIGN] [--other PRED_ON.json].
    make real: --results and --campaigns (every series' fits by make's file names)."""
    from ..core.files import write_json
    from ..robot.reporting.real_report import (fitted_campaign, load_campaign, load_campaigns, load_results,
                                                   load_user_results, model_names, real_report)

    if fits:
        results = load_user_results(list(fits), list(predicts), list(others), "campaign", other_name)
        campaign_dir = campaign_dir or fitted_campaign(results["campaign"]["fits"], fits[0])
        name = Path(campaign_dir).name or "campaign"
        results = {name: results["campaign"]}
        campaigns = {name: load_campaign(campaign_dir)}
    else:
        campaigns = load_campaigns(campaigns_dir)
        results = load_results(results_dir, list(campaigns))
        out_json = out_json or "results/real/transfer.json"
    table = real_report(results, campaigns, out, note)
    if out_json:
        write_json(out_json, table)
    models = model_names(results)
    click.echo(f"{out}: written" + (f"; {out_json}" if out_json else "") + ": " + "; ".join(
        f"{s}: " + ", ".join(f"{m} {t[m]['rms_mm']:.3f} mm own" + "".join(
            f", {k.split('_on_')[1]} {t[k]['rms_mm']:.3f}" for k in sorted(t) if k.startswith(f"{m}_on_"))
            for m in models if m in t)
        for s, t in table.items()), err=True)


@robot_group.command("region-split")
@click.option("--campaign", "campaign_dir", required=True, type=click.Path(file_okay=False),
              help="An imported campaign (jointcal import --out).")
@click.option("--joint", required=True, type=int, help="The joint whose angle splits the poses.")
@click.option("--percentile", default=60.0, show_default=True, type=click.FloatRange(0, 100, min_open=True, max_open=True),
              help="Of the joint's angles over the campaign's sample poses: the split's threshold.")
@click.option("--out", required=True, type=click.Path(file_okay=False), help="The split campaign's folder.")
def region_split_cmd(campaign_dir, joint, percentile, out):
    """Write a campaign split by region: its sample poses at or below a joint's percentile are the
    sample (fitted), every pose above it the targets. `jointcal fit --campaign OUT` then states the
    error of a model on a region of the joint it never saw (mm)."""
    from ..robot.campaign.regions import write_region_split

    r = write_region_split(campaign_dir, joint, out, percentile)
    click.echo(f"{out}: q{joint} <= {r['threshold_deg']:.3f} deg ({percentile:g}th percentile): "
               f"{r['n_sample']} sample poses; above it {r['n_target']} target poses", err=True)


@robot_group.command("diagnose-loop")
@click.option("--campaign", required=True, multiple=True, type=click.Path(),
              help="Robot campaign (raw folder) to diagnose; more than once: several campaigns of one robot, each "
                   "its own tracker frame (contract section 15).")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="The robot spec to start from.")
@click.option("--other", "other_campaign", default=None, type=click.Path(),
              help="Another campaign of the same robot: each round's model is also judged on it (tracker re-registered).")
@click.option("--json", "json_out", required=True, type=click.Path(dir_okay=False),
              help="Each round: the model, its held-out and other-series errors (mm), what diagnosis recommended "
                   "and refused.")
@click.option("--spec-out", default=None, type=click.Path(dir_okay=False), help="The spec the loop ends with.")
@click.option("--rounds", type=click.IntRange(1, 10), default=5, show_default=True, help="Rounds at most.")
@click.option("--keep-outliers", is_flag=True, help=WILD_HELP)
def diagnose_loop_cmd(campaign, spec_path, other_campaign, json_out, spec_out, rounds, keep_outliers):
    """The user's loop, run for you: diagnose, add every recommended effect, diagnose again, until
    nothing is recommended. Prints each round's held-out error (mm) on the campaign's own target
    poses and, with --other, on the other series' target poses (jointcal predict --register).

    Each round's recommended set is verified by refitting it (by pose and by region); a round whose
    cross-validated RMS is not below the round before's is rolled back and its candidates added one
    at a time, best first, each kept only if it helps. The loop never ends worse than it started.

    A round may also swap a member of the model for the effect that overlaps it (joint_harmonic j,
    joint_map j, chebyshev j) when the model with the swap verifies better, every fold refitted, by
    pose and by region (rounds 1-2). Wild measurements of both series are named and left out.

    \b
    --campaign more than once: one robot, each campaign its own tracker frame (as fit), its own
    folds by pose and by region; a round is kept only when no campaign's cross-validated error
    rises, and each round's errors are printed campaign by campaign."""
    from ..core.files import write_json, write_text
    from ..diagnosis.engine import verified_text
    from ..diagnosis.loop import loop_on_campaigns

    _edge()

    say, warn = _progress, _warn
    result = loop_on_campaigns(list(campaign), spec_path, other_campaign, rounds, keep_outliers, say, warn)
    write_json(json_out, result)
    if spec_out:
        write_text(spec_out, result["final_spec"])
    for r in result["rounds"]:
        own, far = r["own"], r["other"]
        click.echo(f"{json_out}: round {r['round']}: held-out RMS {own['rms_mm']:.3f} mm (max {own['max_mm']:.3f})"
                   + (f", other series {far['rms_mm']:.3f} mm (max {far['max_mm']:.3f})" if far else "")
                   + f"; cross-validated {r['cv_rms_mm']:.4g} mm by pose, {r['cv_rms_region_mm']:.4g} by region"
                   + f"; recommended: {', '.join(x['label'] for x in r['recommended']) or 'nothing'}", err=True)
        for c in r.get("campaigns", []):
            click.echo(f"  {c['campaign']}: held-out RMS "
                       + (f"{c['own']['rms_mm']:.3f} mm (max {c['own']['max_mm']:.3f})" if c["own"] else "- (no targets)")
                       + f"; cross-validated {c['cv_rms_mm']:.4g} mm by pose, {c['cv_rms_region_mm']:.4g} by region",
                       err=True)
        v = r.get("verified_set") or {}
        if v.get("checked"):
            click.echo(f"  {verified_text(v, 'mm')}", err=True)
        if r.get("own_with_outliers"):
            w = r["own_with_outliers"]
            click.echo(f"  with the wild targets: held-out RMS {w['rms_mm']:.3f} mm (max {w['max_mm']:.3f})", err=True)
        for note in r.get("max_rose", []):
            click.echo(f"  round {r['round']}: warning: {note}; the loop decides on the cross-validated RMS",
                       err=True)
        if (r.get("swap") or {}).get("from"):
            click.echo(f"  round {r['round']}: swap {r['swap']['why']}", err=True)
        if r.get("rolled_back"):
            click.echo(f"  round {r['round']}: {r['rolled_back']}; one at a time: "
                       + ", ".join(f"{t['label']} {'kept' if t['kept'] else 'left out'}" for t in r["one_at_a_time"]),
                       err=True)
    check = result.get("positions_only")
    if check and check["used"]:
        own = check.get("own")
        click.echo(f"{json_out}: {result['done']}" + (f"; its held-out RMS {own['rms_mm']:.3f} mm (max {own['max_mm']:.3f})"
                                                      if own else ""), err=True)
        return
    click.echo(f"{json_out}: {result['done']}; the spec of round {result['final_round']} is the result", err=True)


def fit_robot(campaign, spec, spec_path, out, keep_outliers=False, orientation=True):
    """``jointcal fit --campaign`` for a robot campaign (see :func:`robot_fit_result`); wild measurements
    named and left out (:mod:`pipeline.robot.model.outliers`) unless ``keep_outliers``."""
    from ..core.files import provenance, write_json
    from ..robot.campaign.ingest import campaign_files
    from ..robot.model.fit import fit_campaign, fit_problems

    _edge()

    warn, progress = _warn, _progress
    result = fit_campaign(campaign, spec, keep_outliers, warn, orientation=orientation, progress=progress)
    result["provenance"] = provenance(campaign_files(campaign), spec_path)
    problems = fit_problems(result)
    if problems:
        _refuse(campaign, '; '.join(problems), out)
    write_json(out, result)
    _fit_console(out, result)


def fit_robots(campaigns, spec, spec_path, out, keep_outliers=False, orientation=True):
    """``jointcal fit`` with ``--campaign`` more than once: several campaigns of one robot fitted together
    (:func:`pipeline.robot.model.campaigns.fit_campaigns`); the held-out errors of each campaign side by side."""
    from ..core.files import provenance, write_json
    from ..robot.campaign.ingest import campaign_files
    from ..robot.model.campaigns import fit_campaigns
    from ..robot.model.fit import fit_problems

    _edge()

    warn, progress = _warn, _progress
    result = fit_campaigns(campaigns, spec, keep_outliers, warn, orientation=orientation, progress=progress)
    result["provenance"] = provenance([f for c in campaigns for f in campaign_files(c)], spec_path)
    problems = fit_problems(result)
    if problems:
        _refuse(", ".join(campaigns), '; '.join(problems), out)
    write_json(out, result)
    _fit_console(out, result)
    click.echo(campaigns_table(result), err=True)


def campaigns_table(result: dict) -> str:
    """The held-out errors of each campaign of a fit of several, side by side (console lines)."""
    entries = result.get("campaigns") or []
    oriented = any("orientation_rms_after_arcsec" in (e.get("heldout") or {}) for e in entries)
    head = f"  {'campaign':<28} {'frame':<16} {'sample':>6} {'target':>6} {'RMS before':>10} {'RMS after':>10} {'max after':>10}"
    head += f" {'orient. RMS':>12}" if oriented else ""
    lines = ["  held-out targets per campaign (mm" + (", orientation arcsec" if oriented else "") + "):", head]
    rows = [(e["campaign"], "base" if e["index"] == 1 else f"campaign{e['index']}_*", e["n_sample"], e["n_target"],
             e.get("heldout")) for e in entries]
    h = result.get("heldout")
    rows.append(("all campaigns", "", sum(e["n_sample"] for e in entries), sum(e["n_target"] for e in entries), h))
    for name, frame, ns, nt, he in rows:
        text = f"  {name:<28} {frame:<16} {ns:>6} {nt:>6} "
        if he:
            text += f"{he['rms_before_mm']:>10.3f} {he['rms_after_mm']:>10.4f} {he['after']['max_mm']:>10.3f}"
            if oriented:
                text += f" {he.get('orientation_rms_after_arcsec', float('nan')):>12.1f}"
        else:
            text += f"{'no targets':>10}"
        lines.append(text)
    return "\n".join(lines)


def predicted_table(json_out, result: dict) -> str:
    """``jointcal predict`` on several campaigns: each campaign's errors side by side, and the totals."""
    oriented = "orientation_rms_arcsec" in result
    stated = "coverage_95" in result
    head = f"  {'campaign':<28} {'evaluated':>10} {'RMS':>8} {'max':>8} {'outside':>8}"
    head += (f" {'in u95':>7}" if stated else "") + (f" {'orient. RMS':>12}" if oriented else "")
    lines = [f"{json_out}: {len(result['campaigns'])} campaigns (mm" + (", orientation arcsec" if oriented else "")
             + "; outside: poses outside the sampled joint ranges; in u95: share within their u95_mm):", head]
    for name, r in [(c["campaign"], c) for c in result["campaigns"]] + [("all campaigns", result)]:
        text = f"  {name:<28} {r['n']:>10} {r['rms_mm']:>8.3f} {r['max_mm']:>8.3f} {r['outside_sampled_range']:>8}"
        text += f" {100 * r['coverage_95']:>6.1f}%" if stated else ""
        text += f" {r['orientation_rms_arcsec']:>12.1f}" if oriented else ""
        lines.append(text)
    return "\n".join(lines)


def _fit_console(out, result: dict) -> None:
    """The console lines of ``jointcal fit`` on robot campaigns: held-out errors, cross-validation,
    identification, how sure."""
    h = result.get("heldout")
    held = (f"held-out targets ({h['n_target']}): max {h['before']['max_mm']:.3f} -> {h['after']['max_mm']:.3f} mm, "
            f"RMS {h['rms_before_mm']:.3f} -> {h['rms_after_mm']:.3f} mm; ") if h else "no target poses to hold out; "
    hw = result.get("heldout_with_outliers")
    if hw:
        held += (f"with the {hw['n_target'] - h['n_target']} wild target(s): max {hw['after']['max_mm']:.3f} mm, "
                 f"RMS {hw['rms_after_mm']:.3f} mm; ")
    if h and "orientation_rms_after_arcsec" in h:
        held += (f"orientation RMS {h['orientation_rms_before_arcsec']:.1f} -> {h['orientation_rms_after_arcsec']:.1f} "
                 f"arcsec ({h['orientation_rms_after_arcsec'] / 3600:.4f} deg); ")
    wt = result.get("weighting")
    if wt and "orientation_weight_mm_per_mrad" in wt:
        held += (f"weighed by {wt['method']}: {wt['orientation_weight_mm_per_mrad']:.3g} mm per mrad "
                 f"({wt['iterations']} fits); ")
    elif wt:
        held += f"{wt['method']}; "
    fixed = result["not_identified"]
    weak = [n for n, why in fixed.items() if why.startswith("weakly")]
    groups = (result.get("identification") or {}).get("redundant") or []
    unseen = sum(int(g.get("unseen", 0)) for g in groups if isinstance(g, dict))
    n_par = len(result.get("parameters") or [])
    click.echo(f"{out}: {' + '.join(result['effects'])}; {held}cross-validated RMS {result['cv_rms_mm']:.4f} mm "
               f"({result['cv_folds']}); "
               + (f"rank {n_par - unseen - len(fixed)} of {n_par} parameters: {unseen} combination(s) of "
                  f"{sum(len(g.get('parameters', [])) for g in groups)} parameters the measurements cannot see, held "
                  "nearest the nominal robot (identification.redundant), " if unseen and n_par else "")
               + f"{len(fixed)} parameter(s) left at nominal"
               + (f", weakly determined: {', '.join(weak[:6])}{' ...' if len(weak) > 6 else ''}" if weak else ""),
               err=True)
    if result.get("largest_relative_uncertainty"):
        from ..robot.model.uncertainty import describe_beyond, describe_relative

        pu = result["prediction_uncertainty"]
        beyond = describe_beyond(pu)
        click.echo(f"  least sure (1 sigma): {describe_relative(result['largest_relative_uncertainty'])}; "
                   f"{len(result['correlations'])} pair(s) correlated beyond 0.9; a pose inside the sampled ranges is "
                   f"stated to +-{pu['unexplained_rms_mm']:.3f} mm (1 sigma, unexplained scatter) and more from the "
                   "parameters" + (f"; {beyond}" if beyond else "") + " (u95_mm: jointcal predict)", err=True)
    from ..robot.model.predict import carry_over_note

    note = carry_over_note(result)
    if note:
        click.echo(f"  {note}", err=True)


@click.command("predict")
@click.option("--campaign", "campaigns", required=True, multiple=True, type=click.Path(),
              help="Another campaign of the same robot (raw folder: robot.toml, poses.csv, tracker.csv); more than "
                   "once: each campaign's errors (`campaigns` in the JSON) and the totals over all of them.")
@click.option("--model", "model_path", required=True, type=click.Path(),
              help="Fitted robot model (jointcal fit --campaign ... --out FIT.json).")
@click.option("--json", "json_out", required=True, type=click.Path(dir_okay=False), help="Result JSON to write.")
@click.option("--register", is_flag=True,
              help="Estimate the rigid tracker-to-base transform again on the campaign's sample poses first "
                   "(the tracker was moved); every other parameter is the model's.")
@click.option("--keep-outliers", is_flag=True, help=WILD_HELP)
@click.option("--point", "point", default=None, metavar='"X Y Z"',
              help="A 6-DoF campaign: also the error of this point rigidly fixed to the probe (mm, probe frame; "
                   "e.g. \"0 0 300\" for a tool centre point 300 mm out along the probe's z), which the measured "
                   "probe frame observes exactly: point_rms_mm, point_max_mm, per point point_error_mm.")
def predict_cmd(campaigns, model_path, json_out, register, keep_outliers, point):
    """Predict every pose of another campaign with a fitted model and compare with its tracker points.

    Errors |measured - predicted| (mm) on the campaign's target poses (on every pose when it has
    none): n, rms_mm, max_mm, mean_mm, std_mm, outside_sampled_range (poses outside the joint
    ranges the model was fitted on, where it extrapolates) and one line per point. Wild measurements
    of the campaign are named and left out of the registration and of those errors (``with_outliers``:
    the errors with the wild targets beside); see --keep-outliers. A campaign measured with a 6-DoF
    probe (tracker.csv qw..qz) also gets its orientation errors: the angle between the measured and
    the predicted probe frames (orientation_rms_arcsec, orientation_max_arcsec, per point). A campaign the
    model was fitted on together with others (jointcal fit --campaign A --campaign B) is predicted in its own
    fitted tracker frame unless --register.
    """
    import numpy as np

    from ..core.files import provenance, write_json
    from ..robot.campaign.ingest import campaign_files
    from ..robot.model.predict import predict_other_campaign

    _edge()

    warn = _warn
    point_mm = None
    if point is not None:
        try:
            point_mm = [float(v) for v in point.replace(",", " ").split()]
        except ValueError:
            point_mm = []
        if len(point_mm) != 3 or not np.all(np.isfinite(point_mm)):
            raise click.BadParameter(f"{point!r}: give three numbers in mm, \"X Y Z\" in the probe frame",
                                     param_hint="--point")
    if len(campaigns) > 1:
        from ..robot.model.campaigns import predict_campaigns

        result = predict_campaigns(list(campaigns), _read_json(model_path), model_path, register, keep_outliers, warn,
                                   point_mm)
        result["provenance"] = provenance([f for c in campaigns for f in campaign_files(c)] + [model_path])
        write_json(json_out, result)
        click.echo(predicted_table(json_out, result), err=True)
        return
    campaign = campaigns[0]
    result = predict_other_campaign(campaign, _read_json(model_path), model_path, register, keep_outliers, warn,
                                    point_mm)
    result["provenance"] = provenance(campaign_files(campaign) + [model_path])
    write_json(json_out, result)
    reg = result["registration"]
    click.echo(f"{json_out}: {result['n']} {result['evaluated_on']} poses: RMS {result['rms_mm']:.3f} mm, max "
               f"{result['max_mm']:.3f} mm; {result['outside_sampled_range']} outside the sampled joint ranges"
               + (f"; re-registered on {reg['n']} sample poses ({reg['rotation_deg']:.3f} deg, "
                  f"{np.linalg.norm(reg['translation_mm']):.2f} mm)" if reg else "")
               + (f"; with the wild targets: RMS {result['with_outliers']['rms_mm']:.3f} mm, max "
                  f"{result['with_outliers']['max_mm']:.3f} mm" if "with_outliers" in result else "")
               + (f"; orientation RMS {result['orientation_rms_arcsec']:.1f} arcsec, max "
                  f"{result['orientation_max_arcsec']:.1f} arcsec" if "orientation_rms_arcsec" in result else "")
               + (f"; the point {' '.join(f'{v:g}' for v in result['point_mm'])} mm on the probe: RMS "
                  f"{result['point_rms_mm']:.3f} mm, max {result['point_max_mm']:.3f} mm" if "point_rms_mm" in result
                  else "")
               + ("; orientation not judged (the model was fitted on a campaign without orientations)"
                  if "orientation_not_judged" in result else "")
               + (f"; {100 * result['coverage_95']:.1f} % within their u95_mm (mean {result['u95_mm']:.3f} mm, "
                  f"errors' 95th percentile {result['error_p95_mm']:.3f} mm)" if "coverage_95" in result else ""),
               err=True)

