"""``jointcal import``: a measurement export -> a robot campaign folder (contract section 6).

Thin wrapper: the work is in :mod:`pipeline.robot.campaign.importer` (map, source, tables, split,
atomic install) and :mod:`pipeline.robot.campaign.urdf` (a URDF's arm as the contract's robot).
Library imports are inside the command: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import click


@click.command("import")
@click.option("--source", "source_path", required=True, type=click.Path(dir_okay=False),
              help="The measurement export: one row per pose, in the order the robot visited them.")
@click.option("--map", "map_path", required=True, type=click.Path(dir_okay=False),
              help="map.toml: which source columns are the joints, the positions (and their units, frame), "
                   "the optional columns and the sample/target split.")
@click.option("--robot", "robot_path", required=True, type=click.Path(dir_okay=False),
              help="Nominal kinematics of a 4- to 7-joint arm: a robot.toml (copied), a URDF (then --tip), or a UR's "
                   "calibration.conf (then --ur-model).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Campaign folder to write (robot.toml, poses.csv, tracker.csv, campaign.toml); replaced as a whole.")
@click.option("--tip", default=None, metavar="LINK", help="URDF only: the link whose origin is the SMR (or the flange).")
@click.option("--base", default=None, metavar="LINK",
              help="URDF only: the fixed link whose frame is the robot's base (z along joint 1; default the root).")
@click.option("--tool-mm", "tool_mm", nargs=3, type=float, default=None, metavar="X Y Z",
              help="SMR position (mm) in the --tip link's frame (URDF) or the flange frame (robot.toml, "
                   "calibration.conf).")
@click.option("--ur-model", "ur_model", default=None,
              type=click.Choice(["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"]),
              help="--robot is a Universal Robots calibration.conf of this model: the robot's own factory-calibrated "
                   "kinematics (UR's published DH plus the file's [mounting] deltas) become the nominal robot.")
def import_cmd(source_path, map_path, robot_path, out_dir, tip, base, tool_mm, ur_model):
    """Turn a measurement export into a robot campaign folder (contract sections 2 and 6).

    The robot has N joints, 4 to 7 (its [[joint]] tables, or the URDF's revolute joints from
    --base to --tip); the map's [joints] columns name one source column per joint, q1..qN, and
    another count is refused naming both. Joint angles are written in degrees, positions in mm,
    in the source's row order; poses are split into sample and target by the map's [split]. The result is validated as `jointcal
    ingest` would (nominal consistency included) before it replaces --out; on any problem
    nothing is written and one line names the file, line and column.
    """
    from ..robot.campaign.importer import import_campaign
    from ..robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    s = import_campaign(source_path, map_path, robot_path, out_dir, tip, base, tool_mm, ur_model)
    how = "after a rigid fit of the tracker frame" if s["frame"] == "tracker" else "in the base frame"
    click.echo(f"{out_dir}: {s['n']} poses ({s['sample']} sample, {s['target']} target) from {source_path}; "
               f"nominal kinematics miss them by {s['nominal_rms_mm']:.3f} mm RMS {how}", err=True)
    for w in s.get("warnings", []):
        click.echo(f"  warning: {w}", err=True)
    for n in s.get("notes", []):
        click.echo(f"  note: {n}", err=True)
    o = s.get("orientation")
    if o:
        rpy = ", ".join(f"{v:.3f}" for v in o["mounting_rpy_deg"])
        given = ", ".join(f"{v:g}" for v in o["robot_rpy_deg"])
        used = ("robot.toml's is used" if o["mounting_from"] == "robot.toml"
                else "the estimate is written to the campaign's robot.toml")
        click.echo(f"  orientation: the nominal flange frames miss the measured probe frames by {o['rms_deg']:.3f} deg "
                   f"RMS after the best mounting; probe mounting estimated from the data rpy_deg = [{rpy}], "
                   f"robot.toml's [{given}], {o['apart_deg']:.3f} deg apart: {used}", err=True)

