"""Stage ``diagnose``: where does the model fail, and which physical effect is missing?

The engine is the same for an encoder and a robot; a domain *adapter* says how to fit a
list of effects and predict held-out points:

1. Fit the spec's model with cross-validation (folds by run for an encoder, by pose for a
   robot) and keep every held-out residual: the baseline CV RMS.
2. For every effect the spec lacks (and every target of it: an order, a joint), fit the
   model once more with that effect added, again cross-validated: ``cv_rms_with`` and
   ``gain = 1 - cv_rms_with / baseline``.
3. Decide whether the gain is meaningful: the adapter tests whether the candidate's
   signature is really in the held-out residuals (encoder: is its coefficient consistent
   from run to run, a fixed- or random-effects test across runs; robot: a paired test of
   the held-out squared residuals over independent poses). The p-value must be at most
   ``alpha / number of candidates`` (Bonferroni; alpha = 1 %: on clean simulated encoder
   campaigns with nothing missing, 2.5 % of campaigns raised an alarm, measured over 80) and the gain at least ``min_gain``. Otherwise
   the candidate is listed after the meaningful ones, marked ``"meaningful": false``.
4. Evidence: regress the baseline's residuals on the candidate's own signature (its
   regressors) and report what is found there in the effect's units (e.g. "forward -
   backward = 4.1 arcsec, t = 9"), so the user sees *why* in the data.

Effects a campaign cannot reveal (one direction only, no timestamps, one payload ...) are
not ranked; they are listed under ``not_revealable`` with the reason.
"""

from __future__ import annotations

import os

import numpy as np
# scipy.special's distribution functions are what scipy.stats' sf calls, without importing scipy.stats (docs/speed.md)
from scipy import special

from ..core.crossval import CVResult
from ..core.parallel import fork_map

ALPHA = 0.01
MIN_GAIN = 0.01
#: a held-out RMS more than this many times the baseline's is a fit the held-out rows do not determine
#: (a region left out takes the only poses that fix a parameter): its gain is given as 1 - this, flagged
BLOWUP = 100.0


def relative_gain(with_rms: float, base_rms: float) -> tuple[float, bool]:
    """``1 - with_rms / base_rms`` and whether the held-out fit blew up (a non-finite RMS, or beyond
    :data:`BLOWUP` times the baseline's: then the gain is ``1 - BLOWUP``, not a ratio of ~0 and ~1e135)."""
    if not (np.isfinite(base_rms) and base_rms > 0):
        return 0.0, False
    if not np.isfinite(with_rms) or with_rms > BLOWUP * base_rms:
        return 1.0 - BLOWUP, True
    return 1.0 - with_rms / base_rms, False


def paired_test(base: CVResult, other: CVResult) -> dict:
    """One-sided paired test of the drop in squared held-out residual, summed per block.

    Returns ``{"stat": t, "p": p, "method": ...}`` (Student t with blocks - 1 dof).
    """
    rb = np.sum(np.asarray(base.residuals).reshape(len(base.blocks), -1) ** 2, axis=1)
    ro = np.sum(np.asarray(other.residuals).reshape(len(other.blocks), -1) ** 2, axis=1)
    d = rb - ro
    blocks = base.blocks
    uniq, inv = np.unique(blocks, return_inverse=True)
    D = np.bincount(inv, weights=d, minlength=uniq.size)
    method = f"paired t over {uniq.size} blocks"
    if uniq.size < 2:
        return {"stat": 0.0, "p": 1.0, "method": method}
    sd = D.std(ddof=1)
    if sd == 0:
        return {"stat": np.inf if D.mean() > 0 else 0.0, "p": 0.0 if D.mean() > 0 else 1.0, "method": method}
    t = float(D.mean() / (sd / np.sqrt(uniq.size)))
    return {"stat": t, "p": float(special.stdtr(uniq.size - 1, -t)), "method": method}


def _cv_one(job):
    adapter, data, base_effects, cand = job
    try:
        return adapter.cross_validate(adapter.add(base_effects, cand), data)
    except np.linalg.LinAlgError:
        return None


def _cv_shared(shared, k):
    adapter, data, base_effects, cands = shared
    return _cv_one((adapter, data, base_effects, cands[k]))


def _cross_validate_all(adapter, data, base_effects, cands, jobs):
    """Cross-validate the model with each candidate added; in ``jobs`` forked processes."""
    if jobs <= 1 or len(cands) < 2:
        return [_cv_one((adapter, data, base_effects, c)) for c in cands]
    return fork_map(_cv_shared, (adapter, data, base_effects, cands), len(cands), jobs)


def diagnose(adapter, spec, data, alpha: float = ALPHA, min_gain: float = MIN_GAIN, progress=None,
             workers: int | None = None) -> dict:
    """Rank the effects the spec lacks by cross-validated gain.

    Parameters
    ----------
    adapter : EncoderAdapter or RobotAdapter
    spec : Spec
    data : the adapter's data object
    alpha : float
        Family-wise false-alarm rate: a candidate is meaningful when its test's p-value is
        at most alpha / (number of candidates tried) and its gain at least ``min_gain``.
    min_gain : float
    progress : callable(str), optional
    workers : int, optional
        Processes for the candidates' fits (default: 2 for adapters marked ``parallel``).

    Returns
    -------
    dict in the contract's ``diagnose`` format, plus ``not_revealable``, ``residual_signatures``
    and, per candidate, ``meaningful`` and ``t``.
    """
    say = progress or (lambda s: None)
    base_effects = adapter.baseline_effects(spec, data)
    say(f"baseline: {', '.join(e.name for e in base_effects)}")
    regional = hasattr(adapter, "evaluate")
    if regional:
        adapter.linear(base_effects, data)     # the one shared fit every model below is a correction to
    base = adapter.cross_validate(base_effects, data)
    base_region = adapter.cross_validate(base_effects, data, folds="region") if regional else None
    residual_view = adapter.residual_view(base, data)
    candidates, unrevealable, cand_objects = [], [], {}
    revealable = []
    for cand in adapter.candidates(spec, data, base_effects):
        ok, why = cand.can_reveal(data)
        extra = adapter.reveal_problem(cand, data, base_effects) if (ok and hasattr(adapter, "reveal_problem")) else ""
        if extra:
            ok, why = False, extra
        if ok:
            revealable.append(cand)
        else:
            helps = getattr(cand, "poses_can_help", None)
            unrevealable.append({"effect": cand.name, "target": cand.target(), "reason": why,
                                 "explanation": cand.explanation,
                                 **(_plan_hint(cand, spec) if helps is None or helps(data) else {})})
    if regional:
        say(f"{len(revealable)} candidates, each a linear correction to the shared baseline fit")
        evaluated = adapter.evaluate(base_effects, revealable, data, say)
        fits = [ev["with"] for ev in evaluated]
    else:
        jobs = workers if workers is not None else (min(2, os.cpu_count() or 1) if getattr(adapter, "parallel", False)
                                                    else 1)
        say(f"{len(revealable)} candidates, {jobs} process(es)")
        fits = _cross_validate_all(adapter, data, base_effects, revealable, jobs)
        evaluated = [{} for _ in fits]
    for cand, with_cv, ev in zip(revealable, fits, evaluated):
        if with_cv is None:
            unrevealable.append({"effect": cand.name, "target": cand.target(),
                                 "reason": "the fit with this effect is singular on these data", "explanation": cand.explanation})
            continue
        gain = 1.0 - with_cv.rms / base.rms if base.rms > 0 else 0.0     # the contract's gain, as it is
        test = adapter.significance(cand, base, with_cv, data)
        candidates.append({
            "effect": cand.name, "target": cand.target(), "cv_rms_with": with_cv.rms, "gain": gain,
            "meaningful": False, "p": test["p"], "t": min(float(test["stat"]), 1e9), "test": test["method"],
            "evidence": adapter.evidence(cand, base, data),
            "explanation": cand.explanation, "spec_line": cand.spec_lines(),
        })
        if hasattr(cand, "orders") and cand.name == "joint_harmonic":
            candidates[-1]["order"] = cand.orders()[0] if len(cand.orders()) == 1 else cand.orders()
        if ev.get("region") is not None:
            candidates[-1]["cv_rms_region"] = ev["region"].rms
            candidates[-1]["gain_region"], blown = relative_gain(ev["region"].rms, base_region.rms)
            if blown:
                candidates[-1]["region_undetermined"] = True
        if ev.get("refused"):
            candidates[-1]["refused"] = ev["refused"]
        split = _components(adapter, base, with_cv, data)
        if split:
            candidates[-1].update(split)
            candidates[-1]["explanation"] = cand.explanation + " " + split["seen"]
        cand_objects[id(candidates[-1])] = cand
    # Bonferroni over the candidates tried: the chance that any candidate of a model that
    # lacks nothing is marked meaningful stays below alpha.
    p_max = alpha / max(1, len(candidates))
    for c in candidates:
        c["meaningful"] = bool(c["gain"] >= min_gain and c["p"] <= p_max)
        if c["meaningful"] and "gain_region" in c and c["gain_region"] <= 0.0:
            c["meaningful"] = False
            c["refused"] = (f"does not carry over to poses away from those it was fitted on: held out region by "
                            f"region of joint space, the RMS goes from {base_region.rms:.4g} to "
                            f"{c['cv_rms_region']:.4g} {adapter.unit} ({region_gain_text(c)})"
                            + ("; with a region held out the other regions' poses do not determine the effect"
                               if c.get("region_undetermined") else ""))
        elif c["meaningful"] and c.get("refused"):
            c["meaningful"] = False
    candidates.sort(key=lambda c: (not c["meaningful"], -c["gain"]))
    _forward_check(adapter, data, base_effects, base, candidates, cand_objects, p_max, min_gain, say,
                   base_region if regional else None)
    if hasattr(adapter, "linear_done"):
        adapter.linear_done(data)
    verified = (verify_set(adapter, data, base_effects, candidates, cand_objects, min_gain, say, base, base_region)
                if hasattr(adapter, "refit_cv") else None)
    candidates.sort(key=lambda c: (not c["meaningful"], -c["gain"]))
    noise = adapter.noise_estimate(data) if hasattr(adapter, "noise_estimate") else None
    base_split = adapter.components(base, data) if hasattr(adapter, "components") else None
    out = {
        "kind": spec.kind,
        "baseline": {"effects": [e.name for e in base_effects], "cv_rms": base.rms, "unit": adapter.unit,
                     "folds": adapter.fold_description(data),
                     **({"cv_rms_region": base_region.rms} if regional else {}),
                     **({"residual": "position and orientation: per pose the position error (mm) and the orientation "
                                     "error (mrad) times orientation_weight_mm_per_mrad",
                         "orientation_weight_mm_per_mrad": adapter.weight(data),
                         "cv_position_rms_mm": base_split["position_rms_mm"],
                         "cv_orientation_rms_arcsec": base_split["orientation_rms_arcsec"]} if base_split else {})},
        "candidates": candidates,
        "not_revealable": unrevealable,
        "thresholds": {"alpha": alpha, "p_max": p_max, "min_gain": min_gain},
        "residual_signatures": residual_view,
    }
    if verified is not None:
        out["verified_set"] = verified
    if noise is not None:
        out["noise"] = noise
    if not any(c["meaningful"] for c in candidates):
        say(f"no candidate is meaningful: {done_text(out)}")
    return out


def _trade(adapter, before, after, data, min_gain) -> str:
    """On a 6-DoF campaign, what a change of the model made worse held out: the position or the orientation
    RMS risen by more than ``min_gain`` (a set that lowers one by raising the other is not kept); ''."""
    if not hasattr(adapter, "components"):
        return ""
    a, b = adapter.components(before, data), adapter.components(after, data)
    if not a or not b:
        return ""
    rises = []
    if b["position_rms_mm"] > a["position_rms_mm"] * (1.0 + min_gain):
        rises.append(f"the position error rises from {a['position_rms_mm']:.4g} to {b['position_rms_mm']:.4g} mm")
    if b["orientation_rms_arcsec"] > a["orientation_rms_arcsec"] * (1.0 + min_gain):
        rises.append(f"the orientation error rises from {a['orientation_rms_arcsec']:.1f} to "
                     f"{b['orientation_rms_arcsec']:.1f} arcsec")
    return "; ".join(rises)


def _components(adapter, base, with_cv, data) -> dict:
    """A 6-DoF campaign's candidate: its held-out position and orientation RMS apart, and which of the two
    showed it, in words ({} for positions only)."""
    if not hasattr(adapter, "components"):
        return {}
    b, w = adapter.components(base, data), adapter.components(with_cv, data)
    if not b or not w:
        return {}
    gp = 1.0 - w["position_rms_mm"] / b["position_rms_mm"] if b["position_rms_mm"] > 0 else 0.0
    go = 1.0 - w["orientation_rms_arcsec"] / b["orientation_rms_arcsec"] if b["orientation_rms_arcsec"] > 0 else 0.0
    where = ("both the position and the orientation" if min(gp, go) > 0.5 * max(gp, go) > 0 else
             "the orientation" if go > gp else "the position")
    seen = (f"Seen in {where}: held out, the probe's orientation error goes from {b['orientation_rms_arcsec']:.1f} to "
            f"{w['orientation_rms_arcsec']:.1f} arcsec ({100 * go:+.1f} %), its position error from "
            f"{b['position_rms_mm']:.4g} to {w['position_rms_mm']:.4g} mm ({100 * gp:+.1f} %).")
    return {"cv_position_rms_mm_with": w["position_rms_mm"], "cv_orientation_rms_arcsec_with": w["orientation_rms_arcsec"],
            "gain_position": gp, "gain_orientation": go, "seen_in": where, "seen": seen}


#: The residual is "at the noise" when its RMS is at most this many times the noise estimate's.
NOISE_FACTOR = 1.2


def done_text(result: dict) -> str:
    """What it means that nothing is recommended, in honest words: "explains the data down to their
    noise" only when the cross-validated residual is at the measurement noise (``result['noise']``,
    estimated from repeated or near-identical measurements); otherwise "nothing more that carries
    over", with the residual and the noise estimate side by side."""
    unit = result["baseline"]["unit"]
    cv = result["baseline"]["cv_rms"]
    noise = result.get("noise")
    if noise is None:           # a domain without a noise estimate (encoder: runs are the folds)
        return (f"the model has nothing more that carries over to other runs (cross-validated RMS {cv:.4g} {unit}; "
                "no noise estimate)")
    rms = noise.get("rms")
    if rms is not None and cv <= NOISE_FACTOR * rms:
        return (f"the model explains the data down to their noise (cross-validated RMS {cv:.4g} {unit}, "
                f"noise {rms:.4g} {unit}, {noise['source']})")
    side = (f"noise estimate {rms:.4g} {unit} ({noise['source']})" if rms is not None
            else f"noise unknown: {noise['source']}")
    return (f"the model has nothing more that carries over to other poses (cross-validated RMS {cv:.4g} {unit}; "
            f"{side})")


def _overlap_with(obj, accepted, base_effects) -> str:
    """The effect ``obj`` overlaps (a recommended one, or one in the model), as a user reads it; ''."""
    if not hasattr(obj, "overlaps"):
        return ""
    for c, other in accepted:
        joints = obj.overlaps(other)
        if joints:
            return label(c)
    for e in base_effects:
        joints = obj.overlaps(e) if hasattr(e, "overlaps") else []
        if joints:
            return f"{e.name} joint {', '.join(map(str, joints))} (in the model)"
    return ""


def verify_set(adapter, data, base_effects, candidates, objects, min_gain, say, base, base_region) -> dict:
    """The candidates recommended in one round, verified as a set: one real refit per fold
    (``adapter.refit_cv``: by pose and by region), not the linear corrections each was tested by.
    The baseline is refitted fold by fold too (``base`` / ``base_region``, diagnosis' linear ones, are
    not used: on a joint-map model they are 8 % below its refits).

    The set must beat the baseline the way each member did: lower the refitted error by pose by at
    least ``min_gain`` and lower it by region, and gain at least what its best member gained alone
    (less ``min_gain``: the members' gains are linear corrections, the set's refits).
    When it does not, the set is rebuilt greedily: members best first, each kept only when the
    refitted error falls by pose and by region; the others are marked not meaningful, with the
    reason. Returns what was verified and what it gave (JSON-ready).
    """
    members = [c for c in candidates if c["meaningful"]]
    if not members:
        return {"members": [], "checked": False}
    say(f"verifying the recommended set by refitting it: {' + '.join(label(c) for c in members)}")
    b, br = adapter.refit_cv(list(base_effects), data)
    effects = list(base_effects)
    for c in members:
        effects = adapter.add(effects, objects[id(c)])
    s, sr = adapter.refit_cv(effects, data)
    best_alone = max(c["gain"] for c in members)
    gain = 1.0 - s.rms / b.rms if b.rms > 0 else 0.0
    # the members' gains are linear corrections, the set's refits (of the set and of the baseline
    # alike: a joint map's baseline refitted fold by fold loses more than its linear correction says)
    trade = _trade(adapter, b, s, data, min_gain)
    ok = gain >= min_gain and sr.rms < br.rms and gain >= best_alone - min_gain and not trade
    out = {"members": [label(c) for c in members], "checked": True, "baseline_cv_rms": b.rms,
           "baseline_cv_rms_region": br.rms, "cv_rms": s.rms, "cv_rms_region": sr.rms, "gain": gain,
           "gain_region": relative_gain(sr.rms, br.rms)[0], "passed": bool(ok), "dropped": [],
           "method": "each fold refitted (nonlinear least squares from the start), by pose and by region"}
    split_b = adapter.components(b, data) if hasattr(adapter, "components") else None
    if split_b:
        split_s = adapter.components(s, data)
        out.update(baseline_cv_position_rms_mm=split_b["position_rms_mm"],
                   baseline_cv_orientation_rms_arcsec=split_b["orientation_rms_arcsec"],
                   cv_position_rms_mm=split_s["position_rms_mm"], cv_orientation_rms_arcsec=split_s["orientation_rms_arcsec"])
    if trade:
        out["trade"] = trade
        say(f"the set trades one error for the other ({trade})")
    if ok:
        return out
    say(f"the set does worse together ({s.rms:.4g} by pose, {sr.rms:.4g} by region, against {b.rms:.4g} / "
        f"{br.rms:.4g}): adding its members one at a time, best first")
    first = {"members": out["members"], "cv_rms": s.rms, "cv_rms_region": sr.rms}
    cur, cur_r, effects, kept = b, br, list(base_effects), []
    for c in members:
        trial = adapter.add(effects, objects[id(c)])
        t, tr = adapter.refit_cv(trial, data)
        traded = _trade(adapter, cur, t, data, min_gain)
        if t.rms < cur.rms * (1.0 - min_gain) and tr.rms < cur_r.rms and not traded:
            kept.append(c)
            effects, cur, cur_r = trial, t, tr
            say(f"  + {label(c)}: kept ({t.rms:.4g} by pose, {tr.rms:.4g} by region)")
        else:
            c["meaningful"] = False
            c["refused"] = (f"dropped from the recommended set: refitted with "
                            f"{' + '.join(label(k) for k in kept) or 'the baseline'}, it takes the error from "
                            f"{cur.rms:.4g} to {t.rms:.4g} by pose and {cur_r.rms:.4g} to {tr.rms:.4g} by region"
                            + (f", and trades one error for the other ({traded})" if traded else ""))
            out["dropped"].append(label(c))
            say(f"  + {label(c)}: dropped ({t.rms:.4g} by pose, {tr.rms:.4g} by region)")
    out.update(members=[label(c) for c in kept], cv_rms=cur.rms, cv_rms_region=cur_r.rms,
               gain=1.0 - cur.rms / b.rms if b.rms > 0 else 0.0,
               gain_region=relative_gain(cur_r.rms, br.rms)[0], passed=bool(kept), first_try=first)
    return out


def _forward_check(adapter, data, base_effects, base, candidates, objects, p_max, min_gain, say, base_region=None):
    """Re-test each further meaningful candidate given the ones already accepted.

    Candidates are tested one at a time against the baseline; two can both look meaningful
    when one only mimics the other (in a two-way run, time within the run follows the
    direction of approach, so drift mimics hysteresis). Going down the meaningful ones by
    gain, each is refitted on top of those accepted so far; if what it adds there is within
    noise it is marked not meaningful, with ``explained_by`` naming what explains it.
    """
    accepted = []
    current_effects, current = list(base_effects), base
    current_region = base_region
    for c in [c for c in candidates if c["meaningful"]]:
        clash = _overlap_with(objects[id(c)], [(a, objects[id(a)]) for a in accepted], base_effects)
        if clash:
            # one of an overlapping pair at most: their columns model the same thing, and together
            # the fit trades one against the other (docs/speed.md "Measurements behind the code")
            c["meaningful"] = False
            c["overlaps"] = clash
            c["refused"] = (f"overlaps {clash}: both model the same joint's angle error, and a round recommends "
                            "at most one of an overlapping pair")
            continue
        if not accepted:
            accepted.append(c)
            current_effects = adapter.add(current_effects, objects[id(c)])
            current = adapter.cross_validate(current_effects, data)
            if base_region is not None:
                current_region = adapter.cross_validate(current_effects, data, folds="region")
            continue
        cand = objects[id(c)]
        say(f"re-testing {label(c)} given {', '.join(label(a) for a in accepted)}")
        trial_effects = adapter.add(current_effects, cand)
        trial = adapter.cross_validate(trial_effects, data)
        extra_gain = 1.0 - trial.rms / current.rms if current.rms > 0 else 0.0
        test = adapter.significance(cand, current, trial, data)
        c["given_accepted"] = {"effects": [label(a) for a in accepted], "extra_gain": extra_gain, "p": test["p"]}
        trial_region = adapter.cross_validate(trial_effects, data, folds="region") if base_region is not None else None
        carries = trial_region is None or trial_region.rms < current_region.rms
        if extra_gain >= min_gain and test["p"] <= p_max and carries:
            accepted.append(c)
            current_effects, current, current_region = trial_effects, trial, trial_region
        elif extra_gain >= min_gain and test["p"] <= p_max:
            c["meaningful"] = False
            c["refused"] = (f"with {' + '.join(label(a) for a in accepted)} in the model, it no longer lowers the error "
                            f"on regions of joint space it was not fitted on ({current_region.rms:.4g} -> "
                            f"{trial_region.rms:.4g})")
        else:
            c["meaningful"] = False
            c["explained_by"] = label(accepted[-1]) if len(accepted) == 1 else [label(a) for a in accepted]
            c["evidence"] += (f"; but with {' + '.join(label(a) for a in accepted)} in the model it adds only "
                              f"{100 * extra_gain:.1f} % (p = {test['p']:.2g}): it was mimicking that effect")


def label(c: dict) -> str:
    """A candidate as a user reads it: ``backlash joint 2``, ``joint_harmonic joint 3 order 8``,
    ``harmonic order 6``, ``thermal``."""
    if c.get("target") is None:
        return c["effect"]
    if c["effect"] == "harmonic":
        return f"harmonic order {c['target']}"
    text = f"{c['effect']} joint {c['target']}"
    if c.get("order") is not None:
        text += f" order {c['order']}"
    return text


def region_gain_text(c: dict) -> str:
    """A candidate's gain held out by region, in per cent; a fit that blew up is said as such."""
    if c.get("region_undetermined"):
        return f"more than {BLOWUP:g} times the baseline's RMS"
    return f"{100 * c.get('gain_region', 0.0):+.1f} %"


def target_text(c: dict) -> str:
    """The target column: the joint, with the order of a joint harmonic (``3/k8``)."""
    if c.get("target") is None:
        return "-"
    return f"{c['target']}/k{c['order']}" if c.get("order") is not None else str(c["target"])


def format_table(result: dict, width: int = 110) -> str:
    """The diagnosis as a plain-text table for the terminal."""
    unit = result["baseline"]["unit"]
    lines = [f"baseline ({' + '.join(result['baseline']['effects']) or 'nothing'}): cross-validated RMS "
             f"{result['baseline']['cv_rms']:.4g} {unit}  [{result['baseline'].get('folds', '')}]", ""]
    for o in result.get("outliers") or []:
        lines.insert(-1, f"wild measurement: {o['point_id']} ({o['set']}, tracker.csv line {o['line']}): "
                         f"{o['error_mm']:.3f} mm off" + (" (kept)" if result["outlier_rule"].get("kept") else
                                                            " (left out)"))
    region = "cv_rms_region" in result["baseline"]
    head = (f"{'#':>2}  {'effect':<15}{'target':>7}  {'cv_rms_with':>11}  {'gain':>7}"
            + (f"  {'regions':>8}" if region else "") + f"  {'p':>8}  meaningful")
    lines += [head, "-" * len(head)]
    for k, c in enumerate(result["candidates"], 1):
        verdict = ("yes" if c["meaningful"] else
                   f"no (explained by {_names(c['explained_by'])})" if c.get("explained_by") else
                   "no (refused: see below)" if c.get("refused") else "no (within noise)")
        lines.append(f"{k:>2}  {c['effect']:<15}{target_text(c):>7}  {c['cv_rms_with']:>11.4g}  {100 * c['gain']:>6.1f}%"
                     + ((f"  {'>' + format(BLOWUP, 'g') + 'x':>8}" if c.get("region_undetermined") else
                         f"  {100 * c.get('gain_region', 0.0):>7.1f}%") if region else "")
                     + f"  {c['p']:>8.1e}  {verdict}")
    best = [c for c in result["candidates"] if c["meaningful"]]
    lines.append("")
    if best:
        lines.append(f"Add every meaningful candidate to the spec ({len(best)}; they were re-tested together), "
                     "then diagnose again:")
        for c in best:
            lines += [f"* {label(c)}: held-out RMS {result['baseline']['cv_rms']:.4g} -> {c['cv_rms_with']:.4g} {unit}",
                      f"  evidence:    {c['evidence']}", f"  explanation: {c['explanation']}", "  add to the spec:"]
            lines += ["    " + ln for ln in c["spec_line"].splitlines()]
            lines.append("")
    else:
        lines.append("No candidate lowers the held-out error beyond noise in a way that carries over: nothing to add")
        lines.append(f"({done_text(result)}).")
    v = result.get("verified_set")
    if v and v.get("checked"):
        lines.append(verified_text(v, unit))
    refused = [c for c in result["candidates"] if c.get("refused")]
    if refused:
        lines.append("")
        lines.append("Refused although they lower the error on neighbouring poses:")
        for c in refused:
            lines.append(f"- {label(c)}: {c['refused']}")
    for u in result.get("not_revealable", []):
        tgt = "" if u["target"] is None else f" {u['target']}"
        lines.append(f"not revealable by these data: {u['effect']}{tgt}: {u['reason']}")
        if u.get("plan"):
            lines.append(f"  to reveal it, the poses need {u['needs']}; plan them with: {u['plan']}")
    return "\n".join(lines)


def verified_text(v: dict, unit: str) -> str:
    """One paragraph: which set was verified by a real refit, and what it gave."""
    text = (f"Verified as a set (each fold refitted, by pose and by region): "
            f"{' + '.join(v['members']) or 'nothing'}: {v['baseline_cv_rms']:.4g} -> {v['cv_rms']:.4g} {unit} by pose "
            f"({100 * v['gain']:+.1f} %), {v['baseline_cv_rms_region']:.4g} -> {v['cv_rms_region']:.4g} {unit} by region")
    if v.get("first_try"):
        f = v["first_try"]
        text += (f"; all together ({' + '.join(f['members'])}) gave {f['cv_rms']:.4g} by pose and "
                 f"{f['cv_rms_region']:.4g} by region, so they were added one at a time, best first"
                 + (f", dropping {', '.join(v['dropped'])}" if v["dropped"] else ""))
    return text + "."


def _names(x) -> str:
    return ", ".join(x) if isinstance(x, list) else str(x)


def waterfall(adapter, spec, data, progress=None) -> list[dict]:
    """Held-out error as each effect of the spec is added in turn (in the spec's order).

    Returns a list of ``{"effects": [...], "added": name, "cv_rms": value}``, starting from
    the empty model (nothing but the per-run / per-campaign constants the adapter always fits).
    """
    effects = adapter.baseline_effects(spec, data)
    steps = [{"effects": [], "added": "(nothing)", "cv_rms": adapter.cross_validate([], data).rms}]
    for k in range(1, len(effects) + 1):
        if progress:
            progress(f"waterfall: + {effects[k - 1].name}")
        steps.append({"effects": [e.name for e in effects[:k]], "added": effects[k - 1].name,
                      "cv_rms": adapter.cross_validate(effects[:k], data).rms})
    return steps


def _plan_hint(effect, spec) -> dict:
    """For a robot effect these poses cannot reveal: the ``jointcal plan --reveal`` line that plans
    poses which would, and what those poses need (``plan``, ``needs``); {} for other domains."""
    if getattr(effect, "domain", None) != "robot":
        return {}
    from ..plan.reveal import reveal_hint

    return reveal_hint(effect, "CAMPAIGN", getattr(spec, "path", None) or "SPEC")
