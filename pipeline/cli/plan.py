"""``jointcal plan``: choose the poses to measure (contract section 9).

Thin wrapper: the work is in :mod:`pipeline.plan` (pool, design, reveal). Library imports are
inside the command: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import click


@click.command("plan")
@click.option("--robot", "robot_path", required=True, type=click.Path(dir_okay=False),
              help="Nominal kinematics: a robot.toml, a URDF (then --tip) or a UR calibration.conf (then --ur-model), "
                   "as `jointcal import` takes it.")
@click.option("--tip", default=None, metavar="LINK", help="URDF only: the link whose origin is the SMR (or the flange).")
@click.option("--base", default=None, metavar="LINK", help="URDF only: the fixed link whose frame is the robot's base.")
@click.option("--tool-mm", "tool_mm", nargs=3, type=float, default=None, metavar="X Y Z",
              help="SMR position (mm) in the --tip link's frame (URDF) or the flange frame (robot.toml).")
@click.option("--ur-model", "ur_model", default=None,
              type=click.Choice(["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"]),
              help="--robot is a Universal Robots calibration.conf of this model (as `jointcal import` takes it).")
@click.option("--spec", "spec_path", default=None, type=click.Path(dir_okay=False),
              help="The model the poses must determine (a robot spec, e.g. specs/robot_kinematic.toml). Required "
                   "unless --model gives it.")
@click.option("--pool", "pool_path", required=True, type=click.Path(dir_okay=False),
              help="CSV of feasible poses: point_id, q1 … qN (deg), optional payload_kg (kg): poses the robot "
                   "can reach and the tracker can see (from offline programming or a collision checker).")
@click.option("--n", "n", required=True, type=click.IntRange(min=1), help="Number of poses to choose.")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Plan CSV to write, in visiting order: point_id, q1 … qN (deg), payload_kg when the pool has "
                   "it, dir1 … dirN when the plan needs approach directions (backlash), set = sample: ready to "
                   "become a campaign's poses.csv.")
@click.option("--json", "json_path", default=None, type=click.Path(dir_okay=False),
              help="Also write the plan's summary: n, criterion, parameters_identifiable, predicted_rms_mm (mm), the "
                   "predicted error against the number of poses (curve), the path length (deg).")
@click.option("--campaign", "campaign", default=None, type=click.Path(file_okay=False),
              help="A campaign already measured: plan N more poses to add to it (never one it has).")
@click.option("--reveal", "reveal_line", default=None, metavar="EFFECT",
              help="An [[effect]] line, e.g. 'name = \"compliance\", joints = [5]': choose the poses that best "
                   "tell this effect apart from the spec's model (Ds-optimal).")
@click.option("--criterion", type=click.Choice(["robust", "D", "I"]), default="robust", show_default=True,
              help="robust: log det of the information on the model's parameters and on the error transfer terms "
                   "(order 2) it lacks, held by a prior (model-robust D-optimal; poses that also hold where the "
                   "model is not exact). D: log det of the model's information only (D-optimal). I: D, then "
                   "exchanges that lower the mean prediction variance over the pool (slower). --reveal is always "
                   "Ds-optimal.")
@click.option("--noise-mm", "noise_mm", default=0.05, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Measurement noise (mm, standard deviation of each coordinate) for predicted_rms_mm.")
@click.option("--probe", type=click.Choice(["smr", "6dof"]), default="smr", show_default=True,
              help="What the tracker will measure: an SMR's position, or a 6-DoF probe's position and orientation "
                   "(then the poses are chosen for the information the orientation adds too; a --campaign measured "
                   "with orientations implies 6dof).")
@click.option("--noise-arcsec", "noise_arcsec", default=20.0, show_default=True,
              type=click.FloatRange(min=0, min_open=True),
              help="--probe 6dof: the orientation's noise (arcsec, 1 sigma per axis; a T-Mac repeats to about 20), "
                   "which weighs it against --noise-mm.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="A fitted robot model (jointcal fit's JSON): choose the pool's poses that most lower this model's "
                   "prediction variance over --region (V-optimal), to be measured as a second campaign with its own "
                   "tracker frame and fitted with the model's campaign (jointcal fit --campaign MODEL'S --campaign "
                   "NEW). The spec is the model's unless --spec is given; the poses it was fitted on are read from "
                   "--campaign, else from the campaign the model names. Its joint maps are laid over the region too.")
@click.option("--region", "region_path", default=None, type=click.Path(),
              help="With --model: where the model must hold. A CSV of poses (point_id, q1 … qN (deg): a targets "
                   "file, another pool), a campaign folder (the joint values of all its poses; never its "
                   "measurements), or a robot program (.src, .mod, .ls, .script, as jointcal correct --program "
                   "reads it, played by the nominal controller). Default: the pool itself (the poses the user will "
                   "work in).")
def plan_cmd(robot_path, tip, base, tool_mm, spec_path, pool_path, n, out_path, json_path, campaign, reveal_line,
             criterion, noise_mm, probe, noise_arcsec, model_path=None, region_path=None, ur_model=None):
    """Choose N poses from a pool that determine SPEC's model best (model-robust D-optimal), or that
    reveal a suspected effect (--reveal, Ds-optimal), from joint values and the nominal robot only.

    The parameters and their scaling are those `jointcal fit` identifies; the poses are chosen by a
    greedy start and a Fedorov exchange on log det of the information matrix, and written in an
    order that keeps the robot's path short (nearest neighbour + 2-opt; a move costs its largest
    joint motion; a payload change costs more than any motion, so payloads are visited together). The console and --json say how many parameters the poses identify, which ones
    the pool cannot identify and why, and the position error (mm RMS over the pool) that the
    parameters' uncertainty leaves for --noise-mm.

    With --model FIT.json: the poses of a second campaign (its own tracker frame) that most lower the
    fitted model's prediction variance over --region (V-optimal; the model's joint maps laid over the
    region as unknowns, the region judged after its own registration, as predict --register judges it).
    Measure them, fit them with the model's campaign (fit --campaign FIRST --campaign NEW), and the model
    holds there too (docs/planning.md).
    """
    from ..core.errors import InputError
    from ..plan.api import plan_from_pool
    from ..plan.pool import read_pool
    from ..plan.reveal import parse_reveal
    from ..robot.campaign.importer import load_import_robot
    from ..robot.model.lm import limit_blas_threads
    from .common import load_spec

    if spec_path is None and model_path is None:
        raise click.UsageError("give --spec SPEC (the model the poses must determine) or --model FIT.json")
    if region_path is not None and model_path is None:
        raise click.UsageError("--region needs --model FIT.json (the model that must hold over the region)")
    if model_path is not None and reveal_line is not None:
        raise click.UsageError("--reveal and --model are two different plans: give one of them")
    limit_blas_threads(1)
    robot, _, _ = load_import_robot(robot_path, tip, base, tool_mm, ur_model)
    if model_path is not None:
        return _plan_region(robot, robot_path, model_path, spec_path, pool_path, region_path, campaign, n, out_path,
                            json_path, noise_mm, probe, noise_arcsec)
    spec = load_spec(spec_path)
    spec.require_kind("robot", f"the robot {robot_path}")
    reveal = parse_reveal(reveal_line) if reveal_line is not None else None
    pool = read_pool(pool_path, robot)
    measured = None
    if campaign is not None:
        from ..robot.campaign.ingest import robot_data_sets

        crobot, (measured,) = robot_data_sets(campaign, ("sample", "target", "repeat"))
        if len(crobot.joints) != len(robot.joints):
            raise InputError(f"{campaign}/robot.toml", f"the campaign's robot has {len(crobot.joints)} joints, "
                             f"--robot {robot_path} has {len(robot.joints)}", None, None)

    def say(msg):
        click.echo(f"plan: {msg}", err=True)

    six = probe == "6dof" or (measured is not None and measured.has_orientation)
    text, summary = plan_from_pool(robot, spec.effects, pool, n, measured, reveal, noise_mm, say, criterion,
                                   noise_arcsec if six else None)
    _write_plan(out_path, json_path, text, summary, six, noise_mm, noise_arcsec)
    pred = summary["predicted_rms_mm"]
    click.echo(f"{out_path}: {summary['n']} poses ({summary['criterion']}); {summary['parameters_identifiable']} of "
               f"{summary['n_params']} parameters identified"
               + (f"; predicted error {pred:.3f} mm RMS over the pool for {noise_mm:g} mm noise" if pred is not None
                  else "; too few poses to determine the model")
               + (f" (u95_mm {summary['predicted_u95_mm']:.3f} mm with the noise)"
                  if summary.get("predicted_u95_mm") is not None else "")
               + f"; path {summary['path_deg']:.0f} deg", err=True)
    from ..plan.design import parameter_notes

    for line in parameter_notes(summary):
        click.echo(line, err=True)
    for note in summary["notes"]:
        click.echo(f"note: {note}", err=True)


def _model_spec(model_path, spec_path):
    """The spec to plan for: --spec, else the fitted model's own (its JSON's spec_lines); and the model's
    campaign folders (as its JSON names them)."""
    from ..core.errors import InputError
    from ..core.files import read_json_input
    from ..core.spec import parse_spec
    from .common import load_spec

    doc = read_json_input(model_path, "fit a model first: jointcal fit --campaign DIR --spec SPEC --out FIT.json")
    if not isinstance(doc, dict) or doc.get("kind") != "robot":
        raise InputError(model_path, "not a fitted robot model (jointcal fit --campaign's JSON, \"kind\": \"robot\")",
                         None, None)
    if spec_path is not None:
        spec = load_spec(spec_path)
    else:
        lines = doc.get("spec_lines")
        if not isinstance(lines, list) or not all(isinstance(x, str) for x in lines):
            raise InputError(model_path, "the model has no spec_lines: give --spec", None, None)
        from .. import encoder, robot  # noqa: F401  (their effects registered, as load_spec does)
        spec = parse_spec("[model]\nkind = \"robot\"\n\n" + "\n\n".join(lines) + "\n", str(model_path))
    names = [c["campaign"] for c in doc.get("campaigns", []) if isinstance(c, dict) and "campaign" in c]
    if not names and isinstance(doc.get("campaign"), str):
        names = [doc["campaign"]]
    return spec, names


def _region_q(region_path, robot):
    """The region's joint values (R, N) deg (the controller's) and payloads (R,) kg: a campaign folder's poses,
    a robot program played by the nominal controller, or a CSV of poses."""
    from pathlib import Path

    import numpy as np

    from ..core.errors import InputError
    from ..plan.pool import read_pool

    path = Path(region_path)
    if path.is_dir() and (path / "poses.csv").is_file():
        pool = read_pool(path / "poses.csv", robot)
        return pool.q_deg, pool.payload_kg
    from ..programs.io import EXTENSIONS

    if path.is_dir() or path.suffix.lower() in EXTENSIONS:
        from ..programs.io import read_program
        from ..programs.run import played_poses

        played = played_poses(read_program(path), robot)
        if not len(played.q_deg):
            raise InputError(path, "no motion of the program could be played on the nominal robot", None, None)
        return np.asarray(played.q_deg, float), np.asarray(played.payload_kg, float)
    pool = read_pool(path, robot)
    return pool.q_deg, pool.payload_kg


def _plan_region(robot, robot_path, model_path, spec_path, pool_path, region_path, campaign, n, out_path, json_path,
                 noise_mm, probe, noise_arcsec):
    """``plan --model FIT.json [--region ...]``: the poses of a new campaign that make the model hold over the
    region."""
    from pathlib import Path

    from ..core.errors import InputError
    from ..plan.api import plan_for_region
    from ..plan.pool import read_pool
    from ..robot.campaign.ingest import robot_data_sets

    spec, names = _model_spec(model_path, spec_path)
    spec.require_kind("robot", f"the robot {robot_path}")
    folders = [campaign] if campaign is not None else names
    missing = [c for c in folders if not (Path(c) / "poses.csv").is_file()]
    if not folders or missing:
        raise InputError(model_path, f"the poses the model was fitted on are needed: its campaign "
                         f"{missing[0] if missing else '(none named)'} is not here; give --campaign DIR", None, None)
    parts = []
    for c in folders:
        crobot, (sample,) = robot_data_sets(c, ("sample",))
        if len(crobot.joints) != len(robot.joints):
            raise InputError(f"{c}/robot.toml", f"the campaign's robot has {len(crobot.joints)} joints, "
                             f"--robot {robot_path} has {len(robot.joints)}", None, None)
        parts.append(sample)
    measured = parts[0]
    if len(parts) > 1:
        from ..plan.design import concat_data

        for p in parts[1:]:
            measured = concat_data(measured, p)
    pool = read_pool(pool_path, robot)
    if region_path is not None:
        region_q, region_pay = _region_q(region_path, robot)
    else:
        region_q, region_pay = None, None

    def say(msg):
        click.echo(f"plan: {msg}", err=True)

    six = probe == "6dof" or measured.has_orientation
    text, summary = plan_for_region(robot, spec.effects, pool, region_q, n, measured, noise_mm, say,
                                    noise_arcsec if six else None, region_pay)
    summary["model"] = str(model_path)
    summary["region"]["source"] = str(region_path) if region_path is not None else str(pool_path)
    _write_plan(out_path, json_path, text, summary, six, noise_mm, noise_arcsec)
    reg = summary["region"]
    click.echo(f"{out_path}: {summary['n']} poses (V-optimal over the region's {reg['n']} poses, a new campaign "
               f"with its own tracker frame); predicted error over the region from the parameters' scatter "
               f"{reg['predicted_rms_mm_before']:.3f} -> {reg['predicted_rms_mm']:.3f} mm RMS for {noise_mm:g} mm "
               f"noise; path {summary['path_deg']:.0f} deg", err=True)
    for note in summary["notes"]:
        click.echo(f"note: {note}", err=True)


def _write_plan(out_path, json_path, text: str, summary: dict, six: bool, noise_mm: float, noise_arcsec: float) -> None:
    """A plan's poses (PLAN.csv) and, with ``--json``, its summary, which names a 6-DoF probe's noise (``six``)."""
    from ..core.files import write_json, write_text

    if six:
        summary["probe"] = {"kind": "6dof", "noise_mm": noise_mm, "noise_arcsec": noise_arcsec}
    write_text(out_path, text)
    if json_path:
        write_json(json_path, summary)
