"""``jointcal summary``: ``results/summary.json`` (contract section 5) from the stages' results.

It gathers the results of both chains (encoder models, the robot's Table 2, the real robot's
transfer table), so it sits above them both, with the command line; it reads JSON, and the two
robot specs' effect tables (what "beyond the paper" adds).
"""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import parse_toml
from .common import read_json

#: the paper's robot spec and the one that goes beyond it (what diagnosis found missing)
PAPER_SPEC = "specs/robot_paper.toml"
BEYOND_SPEC = "specs/robot_beyond.toml"


def _joints_text(joints) -> str:
    j = sorted(int(x) for x in joints)
    if len(j) > 2 and j == list(range(j[0], j[-1] + 1)):
        return f"joints {j[0]}-{j[-1]}"
    return ("joint " if len(j) == 1 else "joints ") + ", ".join(map(str, j))


def added_effects(paper_spec=PAPER_SPEC, beyond_spec=BEYOND_SPEC) -> str:
    """What ``beyond_spec`` adds to ``paper_spec``, in words: its ``[[effect]]`` tables that the
    paper's spec lacks, e.g. "backlash of joints 4-6" (read as TOML: the effect vocabulary is
    not needed to compare two tables)."""
    def tables(path):
        return parse_toml(Path(path).read_text(encoding="utf-8"), path).get("effect", [])

    paper = tables(paper_spec)
    parts = []
    for t in tables(beyond_spec):
        if t in paper:
            continue
        joints = t.get("joints")
        parts.append(f"{t['name']} of {_joints_text(joints)}" if joints else t["name"])
    return ", ".join(parts)


def build_summary(encoder_models: dict, robot: dict | None, real: dict | None = None) -> dict:
    """Assemble the summary.

    Parameters
    ----------
    encoder_models : dict module -> model result (``jointcal fit`` JSON)
    robot : dict or None
        ``results/robot/table2.json``: ``before``, ``kinematic``, ``feedback`` statistics
        (min/max/mean/std in mm) and ``max_reduction_pct``.
    """
    out = {"encoder": {}}
    for module in sorted(encoder_models):
        m = encoder_models[module]
        out["encoder"][module] = {"orders": sorted(m["orders"]), "p2p_before_arcsec": m["p2p_before_arcsec"],
                                  "p2p_after_arcsec": m["p2p_after_arcsec"], "reduction_pct": m["reduction_pct"]}
    if robot is not None:
        keys = ("min_mm", "max_mm", "mean_mm", "std_mm")
        out["robot"] = {stage: {k: robot[stage][k] for k in keys} for stage in ("before", "kinematic", "feedback")}
        out["robot"]["max_reduction_pct"] = robot["max_reduction_pct"]
        for extra in ("beyond_paper",):
            if extra in robot:
                out["robot"][extra] = robot[extra]
    if real is not None:
        out["real"] = {"ur10-ipa": real}
    return out


@click.command()
@click.option("--encoder-results", default="results/encoder", show_default=True, type=click.Path(),
              help="Folder with <module>_model.json files.")
@click.option("--robot-results", default="results/robot", show_default=True, type=click.Path(),
              help="Folder with table2.json (robot part), if the robot chain ran.")
@click.option("--real-results", default="results/real", show_default=True, type=click.Path(),
              help="Folder with transfer.json (real section), if the real-robot chain ran.")
@click.option("--out", default="results/summary.json", show_default=True, type=click.Path(dir_okay=False))
def summary(encoder_results, robot_results, real_results, out):
    """Write results/summary.json (contract section 5) from the stages' results."""
    from ..core.files import write_json

    models = {}
    for p in sorted(Path(encoder_results).glob("*_model.json")):
        m = read_json(p)
        models[m["module"]] = m
    robot_path = Path(robot_results) / "table2.json"
    robot = read_json(robot_path) if robot_path.exists() else None
    beyond_path = Path(robot_results) / "beyond" / "table2.json"
    if robot is not None and beyond_path.exists():
        b = read_json(beyond_path)
        robot["beyond_paper"] = {"spec": BEYOND_SPEC, "added": added_effects(PAPER_SPEC, BEYOND_SPEC),
                                 "feedback": b["feedback"], "max_reduction_pct": b["max_reduction_pct"]}
    real_path = Path(real_results) / "transfer.json"
    real = read_json(real_path) if real_path.exists() else None
    write_json(out, build_summary(models, robot, real))
    click.echo(f"{out}: {len(models)} module(s){' and the robot' if robot else ''}", err=True)
