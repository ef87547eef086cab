"""Commands that take a campaign of either kind: ``ingest``, ``validate``, ``fit``.

An encoder campaign goes to the encoder chain, a robot campaign (robot.toml, poses.csv,
tracker.csv) to the robot's (:mod:`pipeline.cli.robot`).

Library imports are inside the commands: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..core.campaign import campaign_kind
from ..core.errors import InputError
from ..core.wild import HELP as WILD_HELP
from .common import fail_spec, load_spec, read_interim, read_json
from .robot import fit_robot, fit_robots, ingest_robot_to, validate_robot


@click.command()
@click.option("--campaign", required=True, type=click.Path(), help="Raw campaign folder, e.g. raw/encoder/a.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Parquet file to write.")
def ingest(campaign, out):
    """Validate a raw campaign (contract sections 1-2) and write the derived table as Parquet.

    Encoder: adds error_arcsec (joint reading minus polygon + autocollimator reference,
    relative to the run's first reading) and theta_deg (encoder reading mod 360).
    Robot (any arm of 4 to 7 joints): poses.csv has q1..qN (N = robot.toml's [[joint]] tables);
    adds dir1..dirN, the nominal SMR position and the gravity torques tau1..tauN (N m).
    """
    from ..core.files import provenance, write_parquet
    from ..encoder.ingest import ingest_encoder

    if campaign_kind(campaign) == "robot":
        ingest_robot_to(campaign, out)
        return
    frame = ingest_encoder(campaign)
    files = sorted(Path(campaign).glob("*.csv")) + sorted(Path(campaign).glob("campaign.toml"))
    write_parquet(out, frame, {"campaign": str(campaign), **provenance(files)})
    click.echo(f"{out}: {len(frame)} readings, {frame['run'].nunique()} runs of module {frame['module'].iloc[0]}", err=True)


@click.command()
@click.option("--campaign", required=True, type=click.Path(), help="Raw campaign folder.")
def validate(campaign):
    """Check a raw campaign without writing anything; list every problem, exit 2 if any."""
    from ..core.tables import Problems
    from ..encoder.ingest import load_encoder_campaign

    problems = Problems()
    if campaign_kind(campaign) == "robot":
        validate_robot(campaign, problems)
    else:
        try:
            load_encoder_campaign(campaign, problems)
        except InputError:
            pass
    for p in problems:
        click.echo(p.one_line(), err=True)
    if problems:
        sys.exit(2)
    click.echo(f"{campaign}: no problems found", err=True)


@click.command()
@click.option("--interim", default=None, type=click.Path(), help="Ingested encoder Parquet (jointcal ingest).")
@click.option("--campaign", "campaigns", multiple=True, type=click.Path(),
              help="Or a raw campaign folder (ingested on the fly). A robot's: give it more than once to fit several "
                   "campaigns of one robot together (each with its own tracker frame; contract section 15).")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="Model spec (specs/*.toml).")
@click.option("--orders", "orders_path", type=click.Path(), default=None,
              help="Selection JSON (jointcal select). Without it, orders the spec leaves open are chosen by "
                   "the spec's [select] rule on the modelling runs.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Model JSON to write.")
@click.option("--keep-outliers", is_flag=True, help="Robot campaign: " + WILD_HELP)
@click.option("--positions-only", is_flag=True,
              help="Robot campaign with a 6-DoF probe's orientations (tracker.csv qw..qz): fit the positions alone "
                   "(the probe's mounting is then registered on the orientations); the held-out orientation error "
                   "is still given. Default: positions and orientations, weighed by variance components.")
def fit(interim, campaigns, spec_path, orders_path, out, keep_outliers, positions_only):
    """Fit the spec's model and judge it on data it was not fitted on (encoder or robot).

    \b
    Encoder campaign: fitted on the modelling runs, evaluated on the held-out validation run:
      peak-to-peak error before/after compensation (arcsec, the paper's measure) and the
      leave-one-run-out cross-validated RMS.
    Robot campaign (--campaign with robot.toml): fitted on the `sample` poses, evaluated on the
      `target` poses: error before (nominal) and after (mm), the 5-fold cross-validated RMS over
      the sample poses, the parameters left at nominal and why; the JSON is a model that
      `jointcal predict` applies to other measurements. With a 6-DoF probe (tracker.csv qw, qx,
      qy, qz) the orientations are fitted too: each pose's residual is its position (mm) and its
      orientation error (mrad) times a weight (mm per mrad) estimated from the residuals
      (variance components, `weighting` in the JSON); held-out orientation errors in arcsec.

    Several robot campaigns (--campaign more than once, one robot): the robot's parameters are shared,
      each campaign after the first keeps its own tracker frame (a `campaign_frame` effect, 6 parameters);
      held-out errors per campaign (`campaigns` in the JSON) beside the totals (`heldout`).

    Either way, the effect of a line added to the spec shows in both numbers.
    """
    from ..core.files import provenance, write_json
    from ..encoder.aliasing import OrderTooHighError
    from ..encoder.evaluate import fit_encoder_spec
    from ..encoder.ingest import ingest_encoder

    spec = load_spec(spec_path)
    if (interim is None) == (not campaigns):
        raise click.UsageError("give exactly one of --interim or --campaign")
    if len(campaigns) > 1:
        not_robot = [c for c in campaigns if campaign_kind(c) != "robot"]
        if not_robot:
            raise InputError(not_robot[0], "--campaign given more than once fits several robot campaigns of one "
                             "robot together; this folder is not a robot campaign (robot.toml, poses.csv, tracker.csv)")
        fit_robots(list(campaigns), spec, spec_path, out, keep_outliers, orientation=not positions_only)
        return
    campaign = campaigns[0] if campaigns else None
    if campaign is not None:
        if campaign_kind(campaign) == "robot":
            fit_robot(campaign, spec, spec_path, out, keep_outliers, orientation=not positions_only)
            return
        frame = ingest_encoder(campaign)
    else:
        frame = read_interim(interim)
    spec.require_kind("encoder", campaign or interim)
    orders = read_json(orders_path)["orders"] if orders_path else None
    try:
        result = fit_encoder_spec(frame, spec, orders)
    except OrderTooHighError as exc:
        fail_spec(spec_path, str(exc))
    except ValueError as exc:
        fail_spec(spec_path, str(exc), r"^\s*(modelling_runs|validation_runs)\s*=")
    inputs = [interim or campaign] + ([orders_path] if orders_path else [])
    result["provenance"] = provenance([p for p in inputs if p and not Path(p).is_dir()] +
                                      (sorted(str(f) for f in Path(campaign).glob("*.csv")) if campaign else []),
                                      spec_path)
    write_json(out, result)
    click.echo(f"{out}: {' + '.join(result['effects'])}; orders {result['orders']}; validation run "
               f"{result['validation_runs']}: p2p {result['p2p_before_arcsec']:.2f} -> {result['p2p_after_arcsec']:.2f} "
               f"arcsec ({result['reduction_pct']:.2f} % less); cross-validated RMS {result['cv_rms_arcsec']:.3f} arcsec",
               err=True)
