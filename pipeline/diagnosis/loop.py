"""The user's loop on a robot campaign: diagnose, add every recommended effect, diagnose again.

Each round fits the current spec on the sample poses (as ``jointcal fit`` does), measures its error
on the campaign's own held-out target poses and, when another measurement series of the same robot
is given, on that series' target poses after re-estimating only the tracker-to-base transform on
its sample poses (as ``jointcal predict --register`` does); then diagnoses the spec and adds every
recommended candidate's ``[[effect]]`` lines (a set diagnosis verified by refitting it). It stops
when nothing is recommended; a round that does not lower the cross-validated error is rolled back.
"""

from __future__ import annotations

import numpy as np

from ..core.spec import parse_spec
from ..robot.evaluate import fit_effects
from ..robot.frame import apply, rigid_fit
from .engine import diagnose, done_text, label
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


def model_cv(robot, effects, sample) -> tuple[float, float]:
    """Cross-validated RMS (mm) of a model by pose and by region, as diagnosis measures its baseline
    (the shared fit, refitted linearly fold by fold): the loop's yardstick between rounds."""
    adapter = RobotAdapter(robot)
    adapter.linear(list(effects), sample)
    return (adapter.cross_validate(list(effects), sample).rms,
            adapter.cross_validate(list(effects), sample, folds="region").rms)


def diagnosis_loop(robot, spec_text: str, sample, target, other=None, max_rounds: int = MAX_ROUNDS,
                   progress=None, repeat=None) -> dict:
    """Run the loop (see the module docstring).

    A round is kept only when its cross-validated RMS, by pose and by region, is lower than the
    round before's. Otherwise it is rolled back and the candidates of the round before are added
    one at a time (best first), each kept only when it lowers both; the loop says so. So it never
    ends on a model worse (cross-validated) than the one it started from or than its best round.

    Parameters
    ----------
    robot : Robot
    spec_text : str
        The starting spec (TOML text of a robot spec).
    sample, target : RobotData
        The campaign's sample poses (fitted, diagnosed) and target poses (held out), mm.
    other : (RobotData, RobotData), optional
        Sample and target poses of another series of the same robot.
    repeat : RobotData, optional
        The campaign's repeat poses (the noise estimate).

    Returns
    -------
    dict with ``rounds`` (each: ``effects``, ``own`` and ``other`` error statistics in mm, the
    diagnosis' ``cv_rms_mm`` and ``cv_rms_region_mm``, ``recommended``, ``refused``, ``verified_set``,
    ``kept`` and, for a round rolled back, ``rolled_back`` and ``one_at_a_time``), ``final_spec``
    (TOML text of the last round kept), ``final_round``, ``ended`` and ``done`` (in words).
    """
    say = progress or (lambda s: None)
    text = spec_text.rstrip() + "\n"
    rounds, prev, done = [], None, ""
    refits = {}   # refitted cross-validations, shared by the rounds (a verified set is the next baseline)
    for k in range(1, max_rounds + 1):
        spec = parse_spec(text, "<loop spec>")
        say(f"round {k}: {' + '.join(spec.names())}")
        model = fit_effects(robot, list(spec.effects), sample)
        row = {"round": k, "effects": [e.spec_lines() for e in spec.effects],
               "own": _stats(target.measured_mm - model.predict(target)) if target.n else None,
               "other": _stats(errors_elsewhere(model, *other)) if other is not None else None,
               "converged": bool(model.converged_), "plausible": bool(model.plausible_)}
        result = diagnose(RobotAdapter(robot, repeat=repeat, refit_cache=refits), spec, sample, progress=say)
        best = [c for c in result["candidates"] if c["meaningful"]]
        row["cv_rms_mm"] = result["baseline"]["cv_rms"]
        row["cv_rms_region_mm"] = result["baseline"].get("cv_rms_region")
        row["recommended"] = [{"label": label(c), "gain": c["gain"], "gain_region": c.get("gain_region"),
                               "spec_line": c["spec_line"]} for c in best]
        row["refused"] = [{"label": label(c), "gain": c["gain"], "reason": c["refused"]}
                          for c in result["candidates"] if c.get("refused") and c["gain"] > 0]
        row["verified_set"] = result.get("verified_set")
        row["noise"] = result.get("noise")
        rounds.append(row)
        if prev is not None and not (row["cv_rms_mm"] < prev["cv"] and row["cv_rms_region_mm"] < prev["cv_region"]):
            row["kept"] = False
            row["rolled_back"] = (f"its cross-validated RMS ({row['cv_rms_mm']:.4g} mm by pose, "
                                  f"{row['cv_rms_region_mm']:.4g} mm by region) is not below round {prev['round']}'s "
                                  f"({prev['cv']:.4g} / {prev['cv_region']:.4g} mm): rolled back")
            say(f"round {k}: {row['rolled_back']}; adding round {prev['round']}'s candidates one at a time")
            text, cur, cur_r, tried = prev["text"], prev["cv"], prev["cv_region"], []
            for c in prev["recommended"]:
                trial = text + "\n" + c["spec_line"] + "\n"
                cv, cv_r = model_cv(robot, list(parse_spec(trial, "<loop spec>").effects), sample)
                keep = cv < cur and cv_r < cur_r
                tried.append({"label": c["label"], "cv_rms_mm": cv, "cv_rms_region_mm": cv_r, "kept": keep})
                say(f"  + {c['label']}: {cv:.4g} mm by pose, {cv_r:.4g} mm by region: "
                    + ("kept" if keep else "left out"))
                if keep:
                    text, cur, cur_r = trial, cv, cv_r
            row["one_at_a_time"] = tried
            if not any(t["kept"] for t in tried):
                done = (f"round {k} made the model worse and was rolled back; none of round {prev['round']}'s "
                        f"candidates lowers the error alone: the model of round {prev['round']} is kept")
                break
            # the next round diagnoses the model built one at a time; it is measured against round prev
            prev = {**prev, "recommended": []}
            continue
        row["kept"] = True
        prev = {"round": k, "cv": row["cv_rms_mm"], "cv_region": row["cv_rms_region_mm"], "text": text,
                "recommended": row["recommended"]}
        if not best:
            done = f"nothing recommended: {done_text(result)}"
            break
        text += "\n" + "\n\n".join(c["spec_line"] for c in best) + "\n"
    final = max((r for r in rounds if r.get("kept")), key=lambda r: r["round"])
    return {"rounds": rounds, "final_spec": prev["text"] if prev else text, "final_round": final["round"],
            "ended": bool(done), "done": done or f"stopped after {max_rounds} rounds"}
