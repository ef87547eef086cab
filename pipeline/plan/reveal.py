"""``--reveal "EFFECT"``: the suspected effect, what poses must have to show it, and the
``jointcal plan --reveal …`` line diagnosis names when an effect is not revealable."""

from __future__ import annotations

import shlex

import numpy as np

from ..core.effect import REGISTRY
from ..core.errors import InputError, parse_toml


def parse_reveal(text: str, where: str = "--reveal"):
    """The effect of an ``[[effect]]`` line such as ``name = "compliance", joints = [5]``.

    Raises InputError (``where`` as the file, column 1) when it is not a robot effect line.
    """
    try:
        doc = parse_toml(f"effect = {{{text}}}", where)["effect"]
    except InputError as exc:
        raise InputError(where, f"not an [[effect]] line ({exc.message}); write e.g. "
                         "'name = \"compliance\", joints = [5]'", 1, 1) from None
    name = doc.pop("name", None)
    if not isinstance(name, str):
        raise InputError(where, "the effect line needs name = \"...\", e.g. 'name = \"compliance\", joints = [5]'", 1, 1)
    try:
        effect = REGISTRY.make("robot", name, **doc)
    except KeyError:
        raise InputError(where, f"unknown robot effect {name!r} (known: {', '.join(REGISTRY.names('robot'))})",
                         1, 1) from None
    problems = effect.check()
    if problems:
        raise InputError(where, problems[0], 1, 1)
    return effect


def reveal_text(effect) -> str:
    """The ``--reveal`` argument of an effect (its ``[[effect]]`` table on one line)."""
    lines = effect.spec_lines().splitlines()[1:]
    return ", ".join(lines)


def what_poses_need(effect) -> str:
    """What poses must have to show ``effect`` at all (payload steps, directions, postures)."""
    joints = effect.params.get("joints")
    js = ", ".join(map(str, joints)) if joints else "each joint"
    if effect.name == "compliance":
        return (f"postures that load joint {js} (its gravity torque varying by 50 N m or more between poses: arm "
                f"stretched out and folded, the joint's link horizontal and vertical) and payload steps at the "
                f"flange (a pool with a payload_kg column, the same postures with several payloads)")
    if effect.name == "backlash":
        return (f"joint {js} reaching poses turning both ways: the plan writes dir columns, approach each pose with "
                f"the joint turning as its dir says (overshoot a few degrees and come back when the path does not); "
                f"the same pose from both directions tells the play apart from the joint's offset")
    if effect.name == "thermal":
        return "poses measured at temperatures at least a few K apart (a warm-up, or a day and a night)"
    if effect.name in ("joint_harmonic", "joint_map"):
        return f"joint {js} spread over its whole range, other joints varied independently of it"
    if effect.name == "chebyshev":
        return "every joint spread over its range, independently of the others"
    return "poses spread over the joint ranges"


def plan_line(effect, spec_path="SPEC", robot_path="ROBOT", pool_path="POOL.csv", campaign=None, n=None) -> str:
    """The ``jointcal plan --reveal …`` command line that plans poses to reveal ``effect``."""
    k = n if n is not None else 30
    parts = ["jointcal", "plan", "--robot", robot_path, "--spec", spec_path, "--pool", pool_path]
    if campaign:
        parts += ["--campaign", str(campaign)]
    parts += ["--reveal", reveal_text(effect), "--n", str(k), "--out", "PLAN.csv"]
    return " ".join(shlex.quote(p) for p in parts)


def reveal_hint(effect, campaign=None, spec_path="SPEC") -> dict:
    """For diagnosis's ``not_revealable`` entries: the plan line and what the poses need."""
    robot_path = "ROBOT"
    if campaign:
        robot_path = f"{str(campaign).rstrip('/')}/robot.toml"
    return {"plan": plan_line(effect, spec_path, robot_path, "POOL.csv", campaign), "needs": what_poses_need(effect)}


def doubled_for_backlash(q_deg, payload_kg, joints):
    """The pool with every pose twice, reached with the backlash joints turning + and - (for Ds)."""
    q = np.asarray(q_deg, float)
    n, nj = q.shape
    d = np.ones((2 * n, nj), int)
    for j in joints:
        d[n:, j - 1] = -1
    return np.vstack([q, q]), np.concatenate([payload_kg, payload_kg]), d, np.concatenate([np.arange(n), np.arange(n)])
