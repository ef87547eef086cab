"""The user's loop on a robot campaign: diagnose, add every recommended effect, diagnose again.

Each round fits the current spec on the sample poses (as ``jointcal fit`` does), measures its error
on the campaign's own held-out target poses and, when another measurement series of the same robot
is given, on that series' target poses after re-estimating only the tracker-to-base transform on
its sample poses (as ``jointcal predict --register`` does); then diagnoses the spec and adds every
recommended candidate's ``[[effect]]`` lines (a set diagnosis verified by refitting it). It stops
when nothing is recommended and no swap helps; a round that does not lower the cross-validated error
is rolled back.

A round may also **swap**: a member of the model that has an overlapping effect (``joint_harmonic`` j,
``joint_map`` j, ``chebyshev`` j model the same joint's angle error, and a round never adds one beside
the other) is replaced by it when the model with the replacement verifies better - every fold
refitted, lower by pose by at least diagnosis' ``min_gain`` and lower by region (:func:`try_swap`).
Without it the first pick of a pair would be permanent.

On a 6-DoF campaign the loop, once ended, is run again on the positions alone; it ends on that loop's spec, or
on both loops' effects together, when that one does better in position held out by pose and no worse by region
(:func:`positions_check_of`: full poses are never worse). Several campaigns of one robot
(:func:`loop_on_several`): each its own tracker frame and folds, a round kept only when no campaign's cross-validated error rises, every round's errors per campaign.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.files import read_text_input
from ..core.memory import release_freed_memory
from ..core.spec import load_spec, parse_spec
from ..robot.arm.effects import jh_orders
from ..robot.model.estimate import fit_effects
from ..core.parallel import can_fork, fork_map
from ..core.se3 import rigid_fit
from ..robot.campaign.frame import apply
from ..robot.campaign.ingest import robot_data_sets
from ..robot.model.fit import check_spec_joints
from ..robot.model.outliers import describe, find_wild
from .engine import MIN_GAIN, diagnose, done_text, label
from .campaign import PER_CAMPAIGN, several_campaigns
from .robot import RobotAdapter, campaigns_of, split_rms

#: Rounds at most (the loop is expected to end within three).
MAX_ROUNDS = 5
#: Effects that model the same joint's angle error (``overlaps_with`` of each other): a swap replaces
#: one of them on a joint by another.
SWAPPABLE = ("joint_map", "joint_harmonic", "chebyshev")
#: Swaps are tried in the first rounds only (a swap needs the next round to measure it: the loop
#: still ends within three rounds).
SWAP_ROUNDS = 2


def _stats(err) -> dict:
    e = np.linalg.norm(np.asarray(err, float), axis=1)
    return {"n": int(e.size), "rms_mm": float(np.sqrt(np.mean(e ** 2))), "max_mm": float(e.max()),
            "mean_mm": float(e.mean())}


def _pose_stats(model, target, register_on=None) -> dict:
    """:func:`_stats` of a model's held-out errors on ``target``, with the orientation's (arcsec) on a 6-DoF
    campaign; ``register_on``: another series' sample poses to re-register its tracker on first."""
    from ..core.se3 import angle_arcsec, orientation_errors

    Rt = np.eye(3)
    if register_on is None:
        out = _stats(target.measured_mm - model.predict(target))
    else:
        Rt, tt = rigid_fit(register_on.measured_mm, model.predict(register_on))
        out = _stats(apply(Rt, tt, target.measured_mm) - model.predict(target))
    if target.has_orientation:
        R, _ = model.predict_pose(target)
        a = angle_arcsec(orientation_errors(R, np.einsum("ij,njk->nik", Rt, target.measured_R)))
        out.update(orientation_rms_arcsec=float(np.sqrt(np.mean(a ** 2))), orientation_max_arcsec=float(a.max()))
    return out


def model_cv(robot, effects, sample) -> tuple[float, float]:
    """Cross-validated RMS (mm) of a model by pose and by region, as diagnosis measures its baseline
    (the shared fit, refitted linearly fold by fold): the loop's yardstick between rounds."""
    adapter = RobotAdapter(robot)
    adapter.linear(list(effects), sample)
    return (adapter.cross_validate(list(effects), sample).rms,
            adapter.cross_validate(list(effects), sample, folds="region").rms)


def refit_cv(robot, effects, sample, cache=None) -> tuple[float, float]:
    """Cross-validated RMS (mm) of a model with every fold refitted, by pose and by region (how
    diagnosis verifies a set): how a swap is verified."""
    a, b = RobotAdapter(robot, refit_cache=cache).refit_cv(list(effects), sample)
    return a.rms, b.rms


def _one_joint(name: str, j: int, sample) -> str:
    """The ``[[effect]]`` lines of effect ``name`` on joint ``j`` alone (a joint harmonic: every order
    diagnosis tries on the joint's sampled range, :func:`pipeline.robot.arm.effects.jh_orders`)."""
    if name == "joint_harmonic":
        return f'[[effect]]\nname = "joint_harmonic"\njoints = [{j}]\norders = {jh_orders(sample.q_deg[:, j - 1])}'
    return f'[[effect]]\nname = "{name}"\njoints = [{j}]'


def _member_label(e, j) -> str:
    text = f"{e.name} joint {j}"
    if e.name == "joint_harmonic":
        text += f" order {', '.join(map(str, e.orders()))}"
    return text


def swap_options(robot, effects, sample) -> list[dict]:
    """Every model one swap away: a member of :data:`SWAPPABLE` replaced on one of its joints by each
    other effect of :data:`SWAPPABLE` the model does not have on that joint. Each: ``from``, ``to``
    (labels) and ``lines`` (the new model's ``[[effect]]`` lines, the replacement in the member's place)."""
    out = []
    for i, e in enumerate(effects):
        if e.name not in SWAPPABLE:
            continue
        joints = list(e.joints(robot))
        for j in joints:
            for alt in SWAPPABLE:
                if alt == e.name or any(o.name == alt and j in o.joints(robot) for o in effects):
                    continue
                rest = [j2 for j2 in joints if j2 != j]
                keep = [type(e)(**{**e.params, "joints": rest}).spec_lines()] if rest else []
                lines = ([x.spec_lines() for x in effects[:i]] + [_one_joint(alt, j, sample)] + keep
                         + [x.spec_lines() for x in effects[i + 1:]])
                out.append({"from": _member_label(e, j), "to": f"{alt} joint {j}", "lines": lines})
    return out


def _with_effects(text: str, lines: list[str]) -> str:
    """``text`` (a spec) with its ``[[effect]]`` tables replaced by ``lines`` (its header kept)."""
    m = re.search(r"^\s*\[\[effect\]\]", text, re.M)
    head = text[:m.start()] if m else text
    return head.rstrip() + "\n\n" + "\n\n".join(x.rstrip() for x in lines) + "\n"


def _screen_one(shared, k):
    robot, trials, sample = shared
    return model_cv(robot, list(parse_spec(trials[k], "<loop spec>").effects), sample)


def _screen(robot, trials: list[str], sample, jobs: int | None = None) -> list[tuple[float, float]]:
    """:func:`model_cv` of each spec text in ``trials``, in order; in up to ``jobs`` forked processes
    (default: the CPUs this process may use; Linux, not from inside a worker). Each screen is the same
    computation as in one process, so the numbers are the same (what a screen costs: docs/speed.md
    "Measurements behind the code")."""
    from ..robot.model.estimate import cpu_count

    jobs = min(cpu_count() if jobs is None else int(jobs), len(trials))
    if jobs > 1 and can_fork():
        release_freed_memory()   # what the parent no longer holds is not inherited by every worker
        return fork_map(_screen_one, (robot, trials, sample), len(trials), jobs)
    return [model_cv(robot, list(parse_spec(x, "<loop spec>").effects), sample) for x in trials]


def try_swap(robot, text: str, sample, cache=None, say=None, min_gain: float = MIN_GAIN,
             base: tuple[float, float] | None = None) -> dict | None:
    """The best swap of the model ``text`` if one verifies better (see the module docstring); None
    when the model has nothing to swap.

    Each swap is screened as diagnosis screens a candidate (:func:`model_cv`: one shared fit,
    corrected linearly fold by fold); the best one below the model by pose and by region is verified
    with every fold refitted (:func:`refit_cv`). ``base``: the model's own :func:`model_cv` when already
    known (the round's diagnosis measured it). Returns ``made``, ``from``, ``to``, the numbers and
    ``text`` (the swapped spec, when made)."""
    say = say or (lambda s: None)
    effects = list(parse_spec(text, "<loop spec>").effects)
    options = swap_options(robot, effects, sample)
    if not options:
        return None
    base = base if base is not None else model_cv(robot, effects, sample)
    trials = [_with_effects(text, o["lines"]) for o in options]
    screened = []
    for o, trial, (cv, cv_r) in zip(options, trials, _screen(robot, trials, sample)):
        screened.append({"from": o["from"], "to": o["to"], "cv_rms_mm": cv, "cv_rms_region_mm": cv_r, "text": trial})
        say(f"  swap {o['from']} -> {o['to']}: {cv:.4g} mm by pose, {cv_r:.4g} mm by region "
            f"(the model: {base[0]:.4g} / {base[1]:.4g})")
    out = {"made": False, "baseline_cv_rms_mm": base[0], "baseline_cv_rms_region_mm": base[1],
           "screened": [{k: v for k, v in x.items() if k != "text"} for x in screened]}
    better = [x for x in screened if x["cv_rms_mm"] < base[0] * (1.0 - min_gain) and x["cv_rms_region_mm"] < base[1]]
    if not better:
        out["why"] = "no swap lowers the error by pose and by region"
        return out
    best = min(better, key=lambda x: (x["cv_rms_mm"], x["cv_rms_region_mm"]))
    b, br = refit_cv(robot, effects, sample, cache)
    s, sr = refit_cv(robot, list(parse_spec(best["text"], "<loop spec>").effects), sample, cache)
    made = s < b * (1.0 - min_gain) and sr < br
    out.update({"from": best["from"], "to": best["to"], "made": bool(made),
                "verified": {"cv_rms_mm": s, "cv_rms_region_mm": sr, "baseline_cv_rms_mm": b,
                             "baseline_cv_rms_region_mm": br,
                             "method": "each fold refitted (nonlinear least squares from the start), by pose and "
                                       "by region"}})
    out["why"] = (f"{best['from']} -> {best['to']}, every fold refitted: {b:.4g} -> {s:.4g} mm by pose, "
                  f"{br:.4g} -> {sr:.4g} mm by region: " + ("swapped" if made else "not better: kept as it was"))
    say(f"swap {out['why']}")
    if made:
        out["text"] = best["text"]
    return out


def diagnosis_loop(robot, spec_text: str, sample, target, other=None, max_rounds: int = MAX_ROUNDS,
                   progress=None, repeat=None, target_all=None, positions_check: bool = True) -> dict:
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
    target_all : RobotData, optional
        The target poses with the wild ones (``target`` is without them): each round's error on them
        too, ``own_with_outliers``.
    positions_check : bool
        On a 6-DoF campaign, end no worse in position than the loop on the positions alone
        (:func:`positions_check_of`).

    Returns
    -------
    dict with ``rounds`` (each: ``effects``, ``own`` and ``other`` error statistics in mm, the
    diagnosis' ``cv_rms_mm`` and ``cv_rms_region_mm``, ``recommended``, ``refused``, ``verified_set``,
    ``kept``, ``swap`` (:func:`try_swap`, when the model had something to swap) and, for a round rolled
    back, ``rolled_back`` and ``one_at_a_time``; with several campaigns ``campaigns``, :func:`_per_campaign`),
    ``final_spec`` (TOML text of the last round kept, or of the positions-only loop's), ``final_round``,
    ``ended``, ``done`` (in words) and, on a 6-DoF campaign, ``positions_only`` (:func:`positions_check_of`).
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
               "own": _pose_stats(model, target) if target.n else None,
               "other": _pose_stats(model, other[1], other[0]) if other is not None else None,
               **({"own_with_outliers": _stats(target_all.measured_mm - model.predict(target_all))}
                  if target_all is not None and target_all.n else {}),
               "converged": bool(model.converged_), "plausible": bool(model.plausible_)}
        # the round's baseline is measured as model_cv measures it once the loop's weight is fixed (a 6-DoF
        # campaign's first round finds it) or with positions alone: the swaps' yardstick, not measured again
        same_yardstick = not sample.has_orientation or bool(getattr(sample, "diagnosis_weight", None))
        release_freed_memory()   # the round before freed its columns and fits: not held into this one
        adapter = RobotAdapter(robot, repeat=repeat, refit_cache=refits, keep_linear=False)
        result = diagnose(adapter, spec, sample, progress=say)
        if sample.has_orientation and not getattr(sample, "diagnosis_weight", None):
            # a 6-DoF campaign: every round's full residual (positions and weighted orientations) is
            # weighed alike, by the first round's variance-component weight, so that the rounds'
            # cross-validated RMS compare
            sample.diagnosis_weight = adapter.weight(sample)
        best = [c for c in result["candidates"] if c["meaningful"]]
        row["cv_rms_mm"] = result["baseline"]["cv_rms"]
        row["cv_rms_region_mm"] = result["baseline"].get("cv_rms_region")
        if "cv_orientation_rms_arcsec" in result["baseline"]:
            row["cv_position_rms_mm"] = result["baseline"]["cv_position_rms_mm"]
            row["cv_orientation_rms_arcsec"] = result["baseline"]["cv_orientation_rms_arcsec"]
        row["recommended"] = [{"label": label(c), "gain": c["gain"], "gain_region": c.get("gain_region"),
                               "spec_line": c["spec_line"]} for c in best]
        row["refused"] = [{"label": label(c), "gain": c["gain"], "reason": c["refused"]}
                          for c in result["candidates"] if c.get("refused") and c["gain"] > 0]
        row["verified_set"] = result.get("verified_set")
        row["noise"] = result.get("noise")
        if campaigns_of(sample) is not None:
            row["campaigns"] = _per_campaign(model, target, adapter, sample)
        rounds.append(row)
        risen = _campaign_rises(prev, row)
        if prev is not None and (risen or not (row["cv_rms_mm"] < prev["cv"]
                                              and row["cv_rms_region_mm"] < prev["cv_region"])):
            row["kept"] = False
            row["rolled_back"] = (f"its cross-validated RMS ({row['cv_rms_mm']:.4g} mm by pose, "
                                  f"{row['cv_rms_region_mm']:.4g} mm by region) is not below round {prev['round']}'s "
                                  f"({prev['cv']:.4g} / {prev['cv_region']:.4g} mm): rolled back") if not risen else (
                f"{risen} since round {prev['round']}: rolled back")
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
        # the round's shared fit is done with: not held (nor inherited by the swaps' forked screens) beside theirs
        adapter = None
        prev = {"round": k, "cv": row["cv_rms_mm"], "cv_region": row["cv_rms_region_mm"], "text": text,
                "recommended": row["recommended"], "campaigns": row.get("campaigns")}
        known = ((row["cv_rms_mm"], row["cv_rms_region_mm"])
                 if same_yardstick and row["cv_rms_region_mm"] is not None else None)
        swap = (try_swap(robot, text, sample, refits, say, base=known) if (k <= SWAP_ROUNDS and k < max_rounds)
                else None)
        if swap is not None:
            row["swap"] = {x: v for x, v in swap.items() if x != "text"}
        if not best and not (swap and swap["made"]):
            done = f"nothing recommended: {done_text(result)}" + ("; no swap verifies better" if swap else "")
            break
        if swap and swap["made"]:
            text = swap["text"]
            alt = [e for e in parse_spec(text, "<loop spec>").effects if e.name == swap["to"].split()[0]]
            added = []
            for c in best:
                obj = parse_spec(f"[model]\nkind = \"robot\"\n\n{c['spec_line']}\n", "<candidate>").effects[0]
                if any(obj.overlaps(a, robot) for a in alt):
                    row.setdefault("dropped_for_swap", []).append(label(c))
                else:
                    added.append(c)
            best = added
        if best:
            text += "\n" + "\n\n".join(c["spec_line"] for c in best) + "\n"
    _flag_max_rises(rounds)
    final = max((r for r in rounds if r.get("kept")), key=lambda r: r["round"])
    out = {"rounds": rounds, "final_spec": prev["text"] if prev else text, "final_round": final["round"],
           "ended": bool(done), "done": done or f"stopped after {max_rounds} rounds"}
    if positions_check and sample.has_orientation:
        out["positions_only"] = check = positions_check_of(robot, spec_text, out["final_spec"], sample, target, other,
                                                          max_rounds, say, repeat, refits)
        if check["used"]:
            out["final_spec"] = check["result_spec"]
            out["done"] += f"; {check['why']}"
    return out


#: The full-pose loop's spec gives way to the positions-only loop's when that one's position error held out by
#: pose (every fold refitted with the orientations) is lower by more than this share (issue 52: full poses are
#: never worse in position than positions alone, within 1.05x), its orientation error not higher by more than it
POSITIONS_TOLERANCE = 0.05


def _positions(data):
    """``data`` without its orientations (a 6-DoF campaign seen as positions only)."""
    if data is None:
        return None
    from dataclasses import replace

    out = replace(data, measured_R=None, sigma_arcsec=None)
    if hasattr(data, "grating_joints"):
        out.grating_joints = data.grating_joints
    return out


def union_spec(robot, final_spec: str, positions_spec: str) -> str | None:
    """Both loops' effects: the full-pose loop's spec with every effect of the positions-only loop's spec that it
    lacks and that overlaps none of its own (:meth:`~pipeline.robot.arm.effects.RobotEffect.overlaps`: two models of
    one joint's angle error are never fitted side by side); None where that is one of the two specs."""
    full = list(parse_spec(final_spec, "<loop spec>").effects)
    have = {e.spec_lines() for e in full}
    extra = [e for e in parse_spec(positions_spec, "<loop spec>").effects
             if e.spec_lines() not in have and not any(e.overlaps(f, robot) for f in full)]
    if not extra:
        return None
    lines = [e.spec_lines() for e in full + extra]
    if sorted(lines) == sorted(e.spec_lines() for e in parse_spec(positions_spec, "<loop spec>").effects):
        return None
    return _with_effects(final_spec, lines)


def _same_effects(a: str, b: str) -> bool:
    return [e.spec_lines() for e in parse_spec(a, "<loop spec>").effects] == \
        [e.spec_lines() for e in parse_spec(b, "<loop spec>").effects]


#: what :func:`positions_check_of` may end on instead of the full-pose loop's spec, in words
ALTERNATIVES = {"positions": "the positions-only loop's spec", "union": "both loops' effects together"}


def positions_check_of(robot, spec_text: str, final_spec: str, sample, target, other, max_rounds, say, repeat,
                       refits) -> dict:
    """Full poses are never worse (issue 52): the loop run again on the positions alone, and its spec (and both
    loops' effects together, :func:`union_spec`) compared with the full-pose loop's on the 6-DoF sample poses,
    every fold refitted with the orientations (:meth:`RobotAdapter.refit_cv`, by pose: what the held-out targets
    are; by region: what the loop keeps a round on).

    Why: the loop's decisions depend on its path. On a 6-DoF campaign the orientation rows rank the candidates
    otherwise (a joint's compliance before its angle-error map, say); once one is in the model, the other no
    longer lowers the error held out by region (one region where it extrapolates outweighs the others where
    it helps), and the loop ends where the positions-only loop, which took the map first, does much better
    by pose and on the held-out targets. The positions-only loop's decisions passed the same rules (by pose and
    by region) on the same poses' positions: the orientations must not make the loop stop short of them. What
    each loop found may hold together: the union of the two specs is judged by the same rule.

    An alternative is the result when, held out by pose, its position error is lower than the full-pose loop's
    spec's by more than :data:`POSITIONS_TOLERANCE` and its orientation error not higher by more than it, and,
    held out by region, its position error is not higher (the loop's own rule for a round); of several, the one
    lowest in position by pose.

    Returns
    -------
    dict: ``final_spec`` (the positions-only loop's), ``rounds`` (its number of rounds), ``done``,
    ``own_positions_fit`` (its last kept round's held-out target errors, fitted on the positions alone), the refitted
    cross-validated errors of the specs compared (``full``, ``positions`` and, where it is another spec,
    ``union``: ``position_rms_mm``, ``orientation_rms_arcsec`` by pose, ``position_rms_region_mm``,
    ``orientation_rms_region_arcsec`` by region), ``union_spec`` (where judged), ``used`` (the result is not the
    full-pose loop's spec), ``taken`` (``"full"``, ``"positions"`` or ``"union"``), ``result_spec`` and ``own``
    (then: its held-out target errors, fitted with the orientations) and ``why``.
    """
    say("positions only: the loop again on the positions alone (full poses must not end worse in position)")
    inner = diagnosis_loop(robot, spec_text, _positions(sample), _positions(target),
                           None if other is None else (_positions(other[0]), _positions(other[1])), max_rounds,
                           lambda m: say(f"  positions only: {m}"), repeat=_positions(repeat), positions_check=False)
    last = max((r for r in inner["rounds"] if r.get("kept")), key=lambda r: r["round"])
    out = {"final_spec": inner["final_spec"], "rounds": len(inner["rounds"]), "done": inner["done"],
           "own_positions_fit": last["own"], "used": False, "taken": "full"}
    if _same_effects(inner["final_spec"], final_spec):
        out["why"] = "the loop on the positions alone ends on the same spec"
        return out
    specs = {"full": final_spec, "positions": inner["final_spec"]}
    both = union_spec(robot, final_spec, inner["final_spec"])
    if both is not None:
        specs["union"] = out["union_spec"] = both
    adapter = RobotAdapter(robot, refit_cache=refits)
    for key, text in specs.items():
        a, b = adapter.refit_cv(list(parse_spec(text, "<loop spec>").effects), sample)
        out[key] = adapter.components(a, sample)
        if b is not None:
            r = adapter.components(b, sample)
            out[key].update(position_rms_region_mm=r["position_rms_mm"],
                            orientation_rms_region_arcsec=r["orientation_rms_arcsec"])
    f = out["full"]

    def better(c):
        region = ("position_rms_region_mm" not in c or "position_rms_region_mm" not in f
                  or c["position_rms_region_mm"] <= f["position_rms_region_mm"])
        return (c["position_rms_mm"] < f["position_rms_mm"] * (1.0 - POSITIONS_TOLERANCE) and region
                and c["orientation_rms_arcsec"] <= f["orientation_rms_arcsec"] * (1.0 + POSITIONS_TOLERANCE))
    passing = [k for k in specs if k != "full" and better(out[k])]
    taken = min(passing, key=lambda k: out[k]["position_rms_mm"]) if passing else "full"
    out["used"], out["taken"] = taken != "full", taken
    if out["used"]:
        out["result_spec"] = specs[taken]
        if target.n:
            # the result's held-out targets (what each round reports as ``own``), fitted with the orientations
            out["own"] = _pose_stats(fit_effects(robot, list(parse_spec(specs[taken], "<loop spec>").effects),
                                                 sample), target)

    def said(k):
        c = out[k]
        region = (f", by region {c['position_rms_region_mm']:.4g} mm" if "position_rms_region_mm" in c else "")
        return f"{c['position_rms_mm']:.4g} mm and {c['orientation_rms_arcsec']:.1f} arcsec{region}"
    alts = "; ".join(f"{ALTERNATIVES[k]} at {said(k)}" for k in specs if k != "full")
    out["why"] = (f"refitted with the orientations fold by fold, {alts}, against the full-pose loop's "
                  f"{said('full')} (by pose): "
                  + (f"{ALTERNATIVES[taken]} is the result" if out["used"] else "the full-pose loop's spec is kept"))
    say(f"positions only: {out['why']}")
    return out


def _per_campaign(model, target, adapter, sample) -> list[dict]:
    """A round's errors campaign by campaign (several campaigns): ``index``, ``n_sample``, the held-out target
    statistics ``own`` (:func:`_pose_stats`), and the diagnosis baseline's cross-validated RMS by pose and by
    region (``cv_rms_mm``, ``cv_rms_region_mm``; 6-DoF: ``cv_position_rms_mm``), each campaign's poses of its own
    folds (:func:`pipeline.diagnosis.robot.split_rms`)."""
    by_pose = split_rms(adapter.baseline_cv["random"], sample)
    by_region = split_rms(adapter.baseline_cv["region"], sample)
    out = []
    for p, r in zip(by_pose, by_region):
        k = p["index"]
        t = target.subset(target.campaign == k) if target.n and target.campaign is not None else None
        e = {"index": k, "n_sample": p["n"], "own": _pose_stats(model, t) if t is not None and t.n else None,
             "cv_rms_mm": p["rms"], "cv_rms_region_mm": r["rms"]}
        if "position_rms_mm" in p:
            e["cv_position_rms_mm"] = p["position_rms_mm"]
        out.append(e)
    return out


def _campaign_rises(prev, row) -> str:
    """With several campaigns: which campaign's cross-validated RMS (by pose or by region) rose from the kept round
    before (''): a round is kept only when it holds on every campaign's poses and regions it was not fitted on."""
    if not prev or not prev.get("campaigns") or not row.get("campaigns"):
        return ""
    out = []
    for a, b in zip(prev["campaigns"], row["campaigns"]):
        for key, what in (("cv_rms_mm", "by pose"), ("cv_rms_region_mm", "by region")):
            if b[key] > a[key]:
                out.append(f"campaign {b['index']}'s cross-validated RMS {what} rose from {a[key]:.4g} to "
                           f"{b[key]:.4g} mm")
    return "; ".join(out)


#: A held-out maximum that rises by more than this (mm) from one kept round to the next is named.
MAX_RISE_MM = 0.001


def _flag_max_rises(rounds: list[dict]) -> None:
    """Name, in each kept round's ``max_rose``, the held-out maxima (own target poses, the other series)
    that rose from the kept round before: the loop decides on the campaign's cross-validated RMS, so a
    round can lower the RMS and still move some pose further off; the user should know."""
    before = None
    for r in rounds:
        if not r.get("kept"):
            continue
        if before is not None:
            notes = []
            for key, what in (("own", "this series' held-out targets"), ("other", "the other series' targets")):
                a, b = before.get(key), r.get(key)
                if a and b and b["max_mm"] > a["max_mm"] + MAX_RISE_MM:
                    notes.append(f"the max error on {what} rose from {a['max_mm']:.3f} to {b['max_mm']:.3f} mm "
                                 f"(RMS {a['rms_mm']:.3f} -> {b['rms_mm']:.3f} mm) since round {before['round']}")
            if notes:
                r["max_rose"] = notes
        before = r


def _silent(message: str) -> None:
    pass


def loop_on_campaigns(campaign, spec_path, other_campaign=None, max_rounds: int = MAX_ROUNDS,
                      keep_outliers: bool = False, progress=None, warn=_silent) -> dict:
    """``jointcal robot diagnose-loop``: :func:`diagnosis_loop` on a robot campaign folder, judged also
    on ``other_campaign`` (another series of the same robot) when given.

    ``campaign``: one folder, or a list of folders (``--campaign`` more than once, contract section 15: one
    robot, each campaign its own tracker frame; :func:`loop_on_several`). A list of one is one folder.

    Each campaign's wild measurements are named (``warn``, one line each) and left out
    (:mod:`pipeline.robot.model.outliers`) unless ``keep_outliers``; the rounds' errors with the
    campaign's wild targets beside are ``own_with_outliers``. The result names the campaigns, the
    starting spec (``spec_path``) and the outliers (contract section 12).
    """
    if not isinstance(campaign, (str, bytes)) and not hasattr(campaign, "__fspath__"):
        campaigns = list(campaign)
        if len(campaigns) > 1:
            return loop_on_several(campaigns, spec_path, other_campaign, max_rounds, keep_outliers, progress, warn)
        campaign = campaigns[0]
    spec = load_spec(spec_path)
    spec.require_kind("robot", campaign)
    robot, (sample, target, repeat) = robot_data_sets(campaign, ("sample",), ("target",), ("repeat",))
    check_spec_joints(spec, robot)
    wild = find_wild(robot, list(spec.effects), sample, target, campaign, keep_outliers)
    if describe(wild):
        warn(f"{campaign}: {describe(wild)}")
    target_all = target if (wild.target.any() and not wild.kept) else None
    sample, target = wild.clean(sample, target)
    other, wild_other = _other_series(other_campaign, spec, keep_outliers, warn)
    result = diagnosis_loop(robot, read_text_input(spec_path, "spec file"), sample, target, other, max_rounds, progress, repeat=repeat,
                            target_all=target_all)
    result.update(campaign=str(campaign), spec=str(spec_path), other=str(other_campaign) if other_campaign else None)
    result.update(wild.document())
    if wild_other is not None:
        result["other_outliers"] = wild_other.outliers
    return result


def _other_series(other_campaign, spec, keep_outliers, warn):
    """Another series' (sample, target) poses without its wild ones, and its :class:`Wild` (None, None without one)."""
    if not other_campaign:
        return None, None
    robot_o, (os_, ot) = robot_data_sets(other_campaign, ("sample",), ("target",))
    wild_other = find_wild(robot_o, list(spec.effects), os_, ot, other_campaign, keep_outliers)
    if describe(wild_other):
        warn(f"{other_campaign}: {describe(wild_other)}")
    return wild_other.clean(os_, ot), wild_other


def _without_per_campaign(text: str) -> str:
    """A spec text without the loop's per-campaign effects (:data:`PER_CAMPAIGN`)."""
    effects = parse_spec(text, "<loop spec>").effects
    return _with_effects(text, [e.spec_lines() for e in effects if e.name not in PER_CAMPAIGN])


def loop_on_several(campaigns, spec_path, other_campaign=None, max_rounds: int = MAX_ROUNDS,
                    keep_outliers: bool = False, progress=None, warn=_silent) -> dict:
    """The loop on several campaigns of one robot (``--campaign`` more than once, contract section 15).

    The robot's effects are shared; each campaign after the first has its own tracker frame
    (``campaign_frame``) and, where its robot.toml states another probe mounting, its own ``campaign_tool``,
    in every round's model. The folds by pose and by region are each campaign's own
    (:func:`pipeline.diagnosis.robot.pose_folds`, :func:`pipeline.diagnosis.robot.campaign_region_folds`), and a
    round is kept only when no campaign's cross-validated error rises (:func:`diagnosis_loop`). Each round
    reports every campaign's held-out and cross-validated errors (``campaigns``) beside the totals. The spec the
    loop ends with (``final_spec``) is the robot's: without the campaigns' own frames, which ``jointcal fit``
    adds for the campaigns it is given.
    """
    spec = load_spec(spec_path)
    spec.require_kind("robot", campaigns[0])
    robot, sample, target, repeat, target_all, extra, wild = several_campaigns(campaigns, spec, keep_outliers,
                                                                                   warn)
    other, wild_other = _other_series(other_campaign, spec, keep_outliers, warn)
    text = _with_effects(read_text_input(spec_path, "spec file"),
                         [e.spec_lines() for e in spec.effects if e.name not in PER_CAMPAIGN] + extra)
    result = diagnosis_loop(robot, text, sample, target, other, max_rounds, progress, repeat=repeat,
                            target_all=target_all)
    result["final_spec"] = _without_per_campaign(result["final_spec"])
    for r in result["rounds"]:
        for c in r.get("campaigns", []):
            c["campaign"] = str(campaigns[c["index"] - 1])
    result.update(campaign=str(campaigns[0]), campaigns=[str(c) for c in campaigns], spec=str(spec_path),
                  other=str(other_campaign) if other_campaign else None)
    result.update(wild.document())
    if wild_other is not None:
        result["other_outliers"] = wild_other.outliers
    return result
