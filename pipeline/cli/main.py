"""The ``jointcal`` group: every command, added here explicitly from its module.

The command modules define their commands and import nothing of this one; this module
imports them and adds their commands to the group (and to ``jointcal simulate``).
"""

from __future__ import annotations

import sys

import click

from ..core.errors import InputError
from . import campaign, deploy, diagnose, encoder, fleet, importer, plan, robot, summary


class BadInput(click.ClickException):
    """Bad input as click sees it: exit status 2, one line, no traceback."""

    exit_code = 2

    def show(self, file=None):
        click.echo(f"jointcal: error: {self.message}", err=True)


#: ``jointcal --help`` lists the commands in the order of the job, under these headings.
WORKFLOW = (
    ("Before measuring", ("plan", "simulate")),
    ("Measurements in", ("import", "validate", "ingest")),
    ("Joint module (paper 1)", ("harmonic", "aliasing", "select")),
    ("Fit and judge on other poses", ("fit", "predict")),
    ("Diagnose: what is the model missing", ("diagnose", "diagnose-all", "robot")),
    ("On the robot", ("correct", "compensate", "export")),
    ("Reports and many units", ("report", "summary", "fleet")),
)


class JointcalGroup(click.Group):
    """Turns :class:`InputError` raised anywhere in a command into exit 2 with one line; lists the
    commands in the order of the job (:data:`WORKFLOW`)."""

    def list_commands(self, ctx):
        ordered = [name for _, names in WORKFLOW for name in names if name in self.commands]
        return ordered + sorted(set(self.commands) - set(ordered))

    def format_commands(self, ctx, formatter):
        listed = set()
        for heading, names in WORKFLOW + (("Other", tuple(self.list_commands(ctx))),):
            rows = [(n, self.commands[n].get_short_help_str(formatter.width - 6 - max(map(len, names))))
                    for n in names if n in self.commands and n not in listed]
            listed.update(n for n, _ in rows)
            if rows:
                with formatter.section(heading):
                    formatter.write_dl(rows)

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
    A robot (laser tracker), any serial arm of 4 to 7 joints:
      plan -> (measure) -> import -> fit -> robot diagnose-loop -> correct / export
      (`jointcal simulate robot` and `simulate measure` stand in for a cell and its tracker)
    A joint module (polygon + autocollimator), the first paper:
      ingest -> harmonic -> aliasing -> select -> fit -> compensate -> report
    The second paper's chain: `jointcal robot --help`.

    Units: angles in degrees, angle errors in arcseconds, lengths in millimetres.
    `make all` runs every stage on the shipped fixtures; `make help` lists the targets.
    """


@cli.group()
def simulate():
    """Write synthetic campaigns (seeded, deterministic) with documented physics."""


for _command in (
    campaign.ingest, campaign.validate, campaign.fit,                                       # either kind
    encoder.harmonic, encoder.aliasing, encoder.select, encoder.compensate, deploy.correct, encoder.report,
    summary.summary,
    robot.robot_group, robot.predict_cmd,
    diagnose.diagnose, diagnose.diagnose_all,
    fleet.fleet,
    importer.import_cmd,
    deploy.export_cmd,
    plan.plan_cmd,
):
    cli.add_command(_command)
for _command in (encoder.simulate_encoder_cmd, robot.simulate_robot_cmd, fleet.simulate_fleet_cmd, deploy.measure_cmd):
    simulate.add_command(_command)


def main(argv=None):
    """Entry point. Bad input -> one line on stderr and exit status 2 (see :class:`BadInput`).

    The command's work done (its files written and renamed, its lines printed), the process ends at once:
    the exit handlers run (temporary files, worker processes) and the streams are flushed, but the
    interpreter does not tear down its modules and arrays one by one (docs/speed.md). An
    exception that is not a command's end (a bug) takes the normal way, with its traceback."""
    try:
        cli.main(args=argv, prog_name="jointcal")
    except InputError as exc:  # raised outside a subcommand (e.g. while parsing options)
        click.echo(f"jointcal: error: {exc.one_line()}", err=True)
        _end(2)
    except SystemExit as exc:      # click's standalone mode ends every command so
        _end(exc.code)
    _end(0)


def _end(code) -> None:
    import atexit
    import os

    if isinstance(code, str):      # sys.exit("message"): printed, status 1, as Python does
        print(code, file=sys.stderr)
        code = 1
    code = 0 if code is None else int(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):          # a closed pipe: nothing more can reach it
            code = code or 1
    os._exit(code)
