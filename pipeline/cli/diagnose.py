"""``jointcal diagnose`` and ``diagnose-all``: thin commands around :mod:`pipeline.diagnosis`.

Library imports are inside the commands: see :mod:`pipeline.cli.common` (start-up time).
"""

from __future__ import annotations

import click

from ..core.wild import HELP as WILD_HELP


@click.command()
@click.option("--campaign", "campaigns", required=True, multiple=True, type=click.Path(),
              help="Raw campaign folder (encoder or robot); more than once: several robot campaigns of one robot, "
                   "each its own tracker frame (contract section 15).")
@click.option("--spec", "spec_path", required=True, type=click.Path(), help="Model spec (specs/*.toml).")
@click.option("--json", "json_out", required=True, type=click.Path(dir_okay=False),
              help="Where to write the diagnosis (contract section 4).")
@click.option("--report", "report_out", default=None, type=click.Path(dir_okay=False),
              help="Also write a PDF: residuals against every signature, the candidates' gains.")
@click.option("--quiet", is_flag=True, help="Do not print the table.")
@click.option("--workers", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Processes for the candidates' fits (robot: each candidate is a linear correction to one "
                   "shared fit, so 1 is usually as fast).")
@click.option("--keep-outliers", is_flag=True, help="Robot campaign: " + WILD_HELP)
def diagnose(campaigns, spec_path, json_out, report_out, quiet, workers, keep_outliers):
    """Find where the spec's model fails and which physical effect is missing.

    Fits the spec's model with cross-validation (folds by run for an encoder, by pose
    for a robot), then fits it once more with each effect the spec lacks, and ranks them
    by the cross-validated gain. Prints the evidence in the residuals, the physical
    explanation and the [[effect]] lines to paste into the spec. Effects these data
    cannot reveal are named with the reason, not ranked.

    \b
    Robot: the baseline is fitted once; each candidate is a linear correction to it. A
    candidate is recommended only when it also lowers the error on regions of joint
    space held out in turn, and is physically plausible (no joint angle error beyond the
    robot's own error budget, no wild prediction anywhere in the sampled joint box); a
    refused one is listed with the reason. Add every recommended candidate, diagnose again.

    \b
    --campaign more than once (robot): one robot, each campaign its own tracker frame (as fit);
    the folds by pose and by region are each campaign's own, and the baseline's cross-validated
    error is given campaign by campaign beside the totals.
    """
    from ..core.files import write_json
    from ..diagnosis.campaign import run_diagnosis, run_diagnosis_several
    from ..diagnosis.engine import format_table

    def progress(msg):
        if not quiet:
            click.echo(f"  {msg}", err=True)

    if len(campaigns) > 1:
        result, (adapter, spec, data) = run_diagnosis_several(list(campaigns), spec_path, progress, keep_outliers)
    else:
        result, (adapter, spec, data) = run_diagnosis(campaigns[0], spec_path, progress, workers, keep_outliers)
    write_json(json_out, result)
    if report_out:
        from ..diagnosis.report import diagnosis_report  # matplotlib (0.4 s): only with --report

        diagnosis_report(result, adapter, spec, data, report_out, name=", ".join(map(str, campaigns)))
    if not quiet:
        click.echo(format_table(result))
        if result.get("campaigns"):
            click.echo(campaigns_text(result))


def campaigns_text(result: dict) -> str:
    """The baseline's cross-validated RMS of each campaign, side by side (several campaigns)."""
    unit = result["baseline"]["unit"]
    width = max(len(c["campaign"]) for c in result["campaigns"])
    lines = [f"baseline cross-validated per campaign ({unit}):", f"  {'campaign':<{width}}  {'poses':>6}  "
             f"{'by pose':>9}  {'by region':>9}"]
    for c in result["campaigns"]:
        lines.append(f"  {c['campaign']:<{width}}  {c['n_sample']:>6}  {c['cv_rms']:>9.4g}  {c['cv_rms_region']:>9.4g}")
    lines.append(f"  {'all':<{width}}  {sum(c['n_sample'] for c in result['campaigns']):>6}  "
                 f"{result['baseline']['cv_rms']:>9.4g}  {result['baseline']['cv_rms_region']:>9.4g}")
    return "\n".join(lines)

@click.command("diagnose-all")
@click.option("--pair", "pairs", multiple=True, required=True, nargs=3,
              type=(click.Path(), click.Path(), click.Path(dir_okay=False)),
              metavar="CAMPAIGN SPEC JSON", help="A campaign, the spec to diagnose it with, and where to write its JSON.")
@click.option("--report", "report_out", required=True, type=click.Path(dir_okay=False),
              help="One PDF with every campaign's diagnosis.")
def diagnose_all(pairs, report_out):
    """Diagnose several campaigns, each with its spec: a JSON each and one PDF (make all uses this)."""
    from ..core.files import write_json
    from ..diagnosis.campaign import run_diagnosis
    from ..diagnosis.report import diagnosis_report_many

    items = []
    for campaign, spec_path, json_out in pairs:
        click.echo(f"diagnosing {campaign} with {spec_path}", err=True)
        result, (adapter, spec, data) = run_diagnosis(campaign, spec_path)
        write_json(json_out, result)
        best = [c for c in result["candidates"] if c["meaningful"]]
        if result.get("outliers"):
            click.echo(f"  {json_out}: wild measurements left out: " + ", ".join(
                f"{o['point_id']} ({o['set']}, tracker.csv line {o['line']}, {o['error_mm']:.3f} mm)"
                for o in result["outliers"]), err=True)
        click.echo(f"  {json_out}: baseline CV RMS {result['baseline']['cv_rms']:.4g} {result['baseline']['unit']}; "
                   + (f"missing: {', '.join(c['effect'] + ('' if c['target'] is None else ' ' + str(c['target'])) for c in best)}"
                      if best else "nothing meaningful missing"), err=True)
        items.append((result, adapter, spec, data))
    diagnosis_report_many(items, report_out, names=[str(c) for c, _, _ in pairs])
    click.echo(f"{report_out}: written", err=True)
