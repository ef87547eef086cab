"""The user's loop on a robot campaign: diagnose, add every recommended effect, diagnose again.

Each round fits the current spec on the sample poses (as ``jointcal fit`` does), measures its error
on the campaign's own held-out target poses and, when another measurement series of the same robot
is given, on that series' target poses after re-estimating only the tracker-to-base transform on
its sample poses (as ``jointcal predict --register`` does); then diagnoses the spec and adds every
recommended candidate's ``[[effect]]`` lines. It stops when nothing is recommended.
"""

from __future__ import annotations

import numpy as np

from ..core.spec import parse_spec
from ..robot.evaluate import fit_effects
from ..robot.frame import apply, rigid_fit
from .engine import diagnose, label
from .robot import RobotAdapter

#: Rounds at most (the loop is expected to end within three).
MAX_ROUNDS = 5


def _stats(err) -> dict:
    e = np.linalg.norm(np.asarray(err, float), axis=1)
    return {"n": int(e.size), "rms_mm": float(np.sqrt(np.mean(e ** 2))), "max_mm": float(e.max()),
            "mean_mm": float(e.mean())}


def errors_elsewhere(model, sample, target) -> np.ndarray:
    """Errors (n, 3) mm of ``model`` on another series' target poses, its tracker re-registered on the
    series' sample poses (rigid fit of their points onto the model's predictions)."""
    R, t = rigid_fit(sample.measured_mm, model.predict(sample))
    return apply(R, t, target.measured_mm) - model.predict(target)


def diagnosis_loop(robot, spec_text: str, sample, target, other=None, max_rounds: int = MAX_ROUNDS,
                   progress=None) -> dict:
    """Run the loop (see the module docstring).

    Parameters
    ----------
    robot : Robot
    spec_text : str
        The starting spec (TOML text of a robot spec).
    sample, target : RobotData
        The campaign's sample poses (fitted, diagnosed) and target poses (held out), mm.
    other : (RobotData, RobotData), optional
        Sample and target poses of another series of the same robot.

    Returns
    -------
    dict with ``rounds`` (each: ``effects``, ``own`` and ``other`` error statistics in mm, the
    diagnosis' ``cv_rms``, ``recommended`` and ``refused``) and ``final_spec`` (TOML text).
    """
    say = progress or (lambda s: None)
    text = spec_text.rstrip() + "\n"
    rounds = []
    for k in range(1, max_rounds + 1):
        spec = parse_spec(text, "<loop spec>")
        say(f"round {k}: {' + '.join(spec.names())}")
        model = fit_effects(robot, list(spec.effects), sample)
        row = {"round": k, "effects": [e.spec_lines() for e in spec.effects],
               "own": _stats(target.measured_mm - model.predict(target)) if target.n else None,
               "other": _stats(errors_elsewhere(model, *other)) if other is not None else None,
               "converged": bool(model.converged_), "plausible": bool(model.plausible_)}
        result = diagnose(RobotAdapter(robot), spec, sample, progress=say)
        best = [c for c in result["candidates"] if c["meaningful"]]
        row["cv_rms_mm"] = result["baseline"]["cv_rms"]
        row["recommended"] = [{"label": label(c), "gain": c["gain"], "gain_region": c.get("gain_region"),
                               "spec_line": c["spec_line"]} for c in best]
        row["refused"] = [{"label": label(c), "gain": c["gain"], "reason": c["refused"]}
                          for c in result["candidates"] if c.get("refused") and c["gain"] > 0]
        rounds.append(row)
        if not best:
            break
        text += "\n" + "\n\n".join(c["spec_line"] for c in best) + "\n"
    return {"rounds": rounds, "final_spec": text, "ended": not rounds[-1]["recommended"]}
