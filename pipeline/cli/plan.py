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
@click.option("--spec", "spec_path", required=True, type=click.Path(dir_okay=False),
              help="The model the poses must determine (a robot spec, e.g. specs/robot_kinematic.toml).")
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
def plan_cmd(robot_path, tip, base, tool_mm, spec_path, pool_path, n, out_path, json_path, campaign, reveal_line,
             criterion, noise_mm, probe, noise_arcsec, ur_model=None):
    """Choose N poses from a pool that determine SPEC's model best (model-robust D-optimal), or that
    reveal a suspected effect (--reveal, Ds-optimal), from joint values and the nominal robot only.

    The parameters and their scaling are those `jointcal fit` identifies; the poses are chosen by a
    greedy start and a Fedorov exchange on log det of the information matrix, and written in an
    order that keeps the robot's path short (nearest neighbour + 2-opt; a move costs its largest
    joint motion; a payload change costs more than any motion, so payloads are visited together). The console and --json say how many parameters the poses identify, which ones
    the pool cannot identify and why, and the position error (mm RMS over the pool) that the
    parameters' uncertainty leaves for --noise-mm.
    """
    from ..core.errors import InputError
    from ..core.files import write_json, write_text
    from ..plan.api import plan_from_pool
    from ..plan.pool import read_pool
    from ..plan.reveal import parse_reveal
    from ..robot.campaign.importer import load_import_robot
    from ..robot.model.lm import limit_blas_threads
    from .common import load_spec

    limit_blas_threads(1)
    robot, _, _ = load_import_robot(robot_path, tip, base, tool_mm, ur_model)
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
    if six:
        summary["probe"] = {"kind": "6dof", "noise_mm": noise_mm, "noise_arcsec": noise_arcsec}
    write_text(out_path, text)
    if json_path:
        write_json(json_path, summary)
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
