"""``reports/real.pdf`` and ``results/real/transfer.json``: fitted models of real measurement series,
on their own held-out poses and on the other series.

Inputs (``results/real``), for every series S, other series O and spec M (``kinematic``, ``paper``):

* ``S_M.json`` - ``jointcal fit`` (held-out error before = nominal and after, parameters left at nominal);
* ``S_M_self.json`` - ``jointcal predict`` of the fit on its own campaign (error of each held-out pose);
* ``S_M_on_O.json`` - ``jointcal predict --register`` of the fit on the other series.

The per-pose errors are drawn against each joint angle (from the imported ``poses.csv``), so
that an error that follows one joint - the signature of an effect the model lacks - shows.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

from ...core.errors import InputError
from ...core.files import read_json_input
from ...core.plotting import caption, pdf_pages, plt, save, summary_page, text_page

#: the models ``make real`` fits, in the report's order (``load_results`` reads them by these names);
#: any other model (a user's own fit, named by its file) follows them
SPECS = {"kinematic": "geometry + base + tool (specs/robot_kinematic.toml)",
         "paper": "the second paper's spec (specs/robot_paper.toml)",
         "diagnosed": "what the diagnosis loop ended with (results/real/<series>_diagnosed.toml)"}


def model_names(results: dict) -> list[str]:
    """The models of ``results`` (see :func:`transfer_table`) in the report's order: ``SPECS``'
    first, then any other in the order given (a user's --fit order)."""
    found = list(dict.fromkeys(m for s in sorted(results) for m in results[s].get("fits", {})))
    return [m for m in SPECS if m in found] + [m for m in found if m not in SPECS]


def _wrap(text: str, width: int = 86) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width, subsequent_indent="  ")


def _stats(d: dict) -> dict:
    return {k: d[k] for k in ("rms_mm", "max_mm", "mean_mm", "std_mm", "orientation_rms_arcsec", "orientation_max_arcsec",
                              "point_rms_mm", "point_max_mm") if k in d}


def transfer_table(results: dict) -> dict:
    """The numbers of the report (pure).

    Parameters
    ----------
    results : dict
        ``{series: {"fits": {spec: fit JSON}, "self": {spec: predict JSON},
        "on": {spec: {other: predict JSON}}}}``.

    Returns
    -------
    dict ``{series: {"n_sample", "n_target", "nominal", "<spec>", "<spec>_on_<other>",
    "<spec>_left_at_nominal"}}`` with ``rms_mm``/``max_mm``/``mean_mm``/``std_mm`` entries (mm).
    """
    out = {}
    for s in sorted(results):
        r = results[s]
        row = {}
        for spec, fit in sorted(r["fits"].items()):
            h = fit["heldout"]
            row["n_sample"], row["n_target"] = h["n_sample"], h["n_target"]
            row["nominal"] = {"rms_mm": h["rms_before_mm"], "max_mm": h["before"]["max_mm"],
                              "mean_mm": h["before"]["mean_mm"], "std_mm": h["before"]["std_mm"]}
            row[spec] = {"rms_mm": h["rms_after_mm"], "max_mm": h["after"]["max_mm"], "mean_mm": h["after"]["mean_mm"],
                         "std_mm": h["after"]["std_mm"]}
            if "orientation_rms_after_arcsec" in h:   # issue 30: a 6-DoF probe's orientation, held out
                row["nominal"]["orientation_rms_arcsec"] = h["orientation_rms_before_arcsec"]
                row[spec]["orientation_rms_arcsec"] = h["orientation_rms_after_arcsec"]
                row[spec]["orientation_max_arcsec"] = h["orientation_after"]["max_arcsec"]
                own = r.get("self", {}).get(spec) or {}
                if "point_rms_mm" in own:
                    row[spec].update(point_mm=own["point_mm"], point_rms_mm=own["point_rms_mm"],
                                     point_max_mm=own["point_max_mm"])
                if (fit.get("weighting") or {}).get("orientation_weight_mm_per_mrad"):
                    row[f"{spec}_weighting"] = fit["weighting"]
            row[f"{spec}_cv_rms_mm"] = fit.get("cv_rms_mm")
            hw = fit.get("heldout_with_outliers")
            if hw:   # issue 23: the own held-out error with the wild targets, beside the one without them
                row[f"{spec}_with_outliers"] = {"rms_mm": hw["rms_after_mm"], "max_mm": hw["after"]["max_mm"],
                                                "mean_mm": hw["after"]["mean_mm"], "n": hw["n_target"]}
            row[f"{spec}_left_at_nominal"] = sorted(n for n, why in fit.get("not_identified", {}).items()
                                                    if str(why).startswith("weakly"))
            for other, pred in sorted(r["on"].get(spec, {}).items()):
                row[f"{spec}_on_{other}"] = {**_stats(pred), "n": pred["n"],
                                             "outside_sampled_range": pred["outside_sampled_range"]}
            # issue 33: do the stated 95 % intervals hold on poses the fit never saw (own targets, other series)?
            own = r["self"].get(spec) or {}
            if "coverage_95" in own:
                row[f"{spec}_coverage"] = {"own": _coverage(own), **{other: _coverage(pred) for other, pred in
                                                                     sorted(r["on"].get(spec, {}).items())
                                                                     if "coverage_95" in pred}}
            if fit.get("largest_relative_uncertainty"):
                row[f"{spec}_least_sure"] = fit["largest_relative_uncertainty"]
        wild = {o["point_id"]: o for fit in r["fits"].values() for o in fit.get("outliers", [])}
        if wild:   # issue 23: the wild measurements the fits named and left out
            row["outliers"] = [wild[k] for k in sorted(wild)]
        if r.get("together"):
            row["together"] = _together_row(r["together"])
        if r.get("splits"):
            row["splits"] = [_split_row(j, sp) for j, sp in sorted(r["splits"].items())]
        if "loop" in r:
            row["loop"] = [{"round": x["round"], "own": x["own"], "other": x["other"], "cv_rms_mm": x["cv_rms_mm"],
                            "added": [a["label"] for a in x["recommended"]],
                            **({"own_with_outliers": x["own_with_outliers"]} if x.get("own_with_outliers") else {}),
                            **({"swapped": f"{x['swap']['from']} -> {x['swap']['to']}"}
                               if (x.get("swap") or {}).get("made") else {})}
                           for x in r["loop"]["rounds"]]
        out[s] = row
    return out


def _held(h: dict) -> dict:
    """A fit's held-out block (``heldout`` of a fit JSON, or one campaign's) as the report's numbers (mm, arcsec)."""
    out = {"n": h["n_target"], "n_sample": h["n_sample"], "rms_mm": h["rms_after_mm"], "max_mm": h["after"]["max_mm"],
           "nominal_rms_mm": h["rms_before_mm"], "outside_sampled_range": h.get("outside_sampled_range")}
    if "orientation_rms_after_arcsec" in h:
        out["orientation_rms_arcsec"] = h["orientation_rms_after_arcsec"]
    return out


def _together_row(together: dict) -> dict:
    """One series' numbers in the fit of every series together (issue 52): its held-out error there, and
    the coverage of the stated u95 on it (from the predict JSON of the joint fit, when there is one)."""
    fit, campaign = together["fit"], together["campaign"]
    entry = next(c for c in fit["campaigns"] if Path(c["campaign"]).name == campaign)
    row = {**_held(entry["heldout"]), "with": [Path(c["campaign"]).name for c in fit["campaigns"]],
           "frame_effect": entry["frame_effect"], "cv_rms_mm": fit.get("cv_rms_mm")}
    part = next((c for c in (together.get("self") or {}).get("campaigns", [])
                 if Path(c["campaign"]).name == campaign), None)
    if part and "coverage_95" in part:
        row["coverage"] = _coverage(part)
    return row


def _split_row(joint: int, split: dict) -> dict:
    """A region split's numbers (issue 52): the poses fitted (below the joint's percentile), those judged
    (above it), the error there (mm, arcsec) and the coverage of the stated u95 (from its predict JSON)."""
    fit = split["fit"]
    row = {"joint": joint, "below_deg": fit["sampled_range"]["upper_deg"][joint - 1], **_held(fit["heldout"]),
           "cv_rms_mm": fit.get("cv_rms_mm")}
    above = split.get("above") or {}
    if "coverage_95" in above:
        row["coverage"] = _coverage(above)
    return row


def _full_pose_lines(table: dict, models) -> list[str]:
    """The report's page on a 6-DoF probe's orientation (issue 30): per series and model, held out."""
    lines = ["The probe is a 6-DoF probe: every pose's orientation is measured too. Each fit weighs the",
             "orientation against the position by variance components (weight in mm per mrad of orientation",
             "error). Held-out errors: position (mm), orientation (arcsec, the angle between measured and",
             "predicted probe frames) and a point rigidly fixed to the probe (jointcal predict --point; mm),",
             "which the measured frame observes exactly.", "",
             f"{'series / model':40s}{'pos RMS':>9s}{'ori RMS':>9s}{'ori deg':>9s}{'point':>9s}"]
    for s in sorted(table):
        t = table[s]
        nom = t["nominal"]
        lines.append(f"Series {s}")
        if "orientation_rms_arcsec" in nom:
            lines.append(f"  {'nominal kinematics':38s}{nom['rms_mm']:9.3f}{nom['orientation_rms_arcsec']:9.1f}"
                         f"{nom['orientation_rms_arcsec'] / 3600:9.4f}{'':>9s}")
        for spec in models:
            e = t.get(spec) or {}
            if "orientation_rms_arcsec" not in e:
                continue
            pt = f"{e['point_rms_mm']:9.3f}" if "point_rms_mm" in e else f"{'':>9s}"
            lines.append(f"  {spec + ' (own)':38s}{e['rms_mm']:9.3f}{e['orientation_rms_arcsec']:9.1f}"
                         f"{e['orientation_rms_arcsec'] / 3600:9.4f}{pt}")
            for k in sorted(t):
                if k.startswith(f"{spec}_on_") and "orientation_rms_arcsec" in t[k]:
                    o = t[k]
                    pt = f"{o['point_rms_mm']:9.3f}" if "point_rms_mm" in o else f"{'':>9s}"
                    lines.append(f"  {spec + ' on ' + k.split('_on_')[1]:38s}{o['rms_mm']:9.3f}"
                                 f"{o['orientation_rms_arcsec']:9.1f}{o['orientation_rms_arcsec'] / 3600:9.4f}{pt}")
            w = t.get(f"{spec}_weighting")
            if w:
                lines.append(f"    weighed by {w['method']}: {w['orientation_weight_mm_per_mrad']:.3g} mm per mrad "
                             f"(residual sigma {w['position_sigma_mm']:.3g} mm, {w['orientation_sigma_arcsec']:.1f} "
                             f"arcsec; {w['iterations']} fits)")
        for x in t.get("loop", []):
            own, far = x["own"] or {}, x["other"] or {}
            if "orientation_rms_arcsec" in own:
                lines.append(f"  loop round {x['round']}: own {own['rms_mm']:.3f} mm, {own['orientation_rms_arcsec']:.1f} "
                             f"arcsec; other {far.get('rms_mm', float('nan')):.3f} mm, "
                             f"{far.get('orientation_rms_arcsec', float('nan')):.1f} arcsec")
        lines.append("")
    return lines


def _coverage(pred: dict) -> dict:
    """A predict JSON's coverage of its 95 % intervals: ``coverage_95``, mean ``u95_mm``, the errors'
    95th percentile ``error_p95_mm`` and their ratio ``u95_over_p95``."""
    return {"coverage_95": pred["coverage_95"], "u95_mm": pred["u95_mm"], "error_p95_mm": pred["error_p95_mm"],
            "u95_over_p95": pred["u95_mm"] / pred["error_p95_mm"] if pred["error_p95_mm"] > 0 else None,
            "n": pred["n"]}


def _uncertainty_pages(pdf, results: dict, table: dict, series: list) -> None:
    """Issue 33: the stated 95 % intervals against the errors of poses the fit never saw, and the
    parameters the fits are least sure of."""
    specs = [sp for sp in model_names(results) if any(f"{sp}_coverage" in table[s] for s in series)]
    if not specs:
        return
    lines = _wrap("Each fitted model states, for every pose, u95_mm: the radius within which it expects the robot "
                  "to land with 95 % probability (the parameters' covariance propagated to the pose, the scatter its "
                  "5-fold cross-validation leaves unexplained, and beyond the sampled joint ranges the error its own "
                  "region splits show there; docs/uncertainty.md). Coverage: the share of poses within their u95_mm, on the "
                  "series' own held-out targets and on the other series (tracker re-registered). It should be "
                  "about 95 %; mean u95 / p95 (the errors' 95th percentile) near 1 says the intervals are not "
                  "simply wide.")
    lines += ["", f"{'series / model / on':34s}{'n':>6s}{'coverage':>10s}{'mean u95':>10s}{'p95 err':>9s}{'ratio':>7s}"]
    for s in series:
        for sp in specs:
            cov = table[s].get(f"{sp}_coverage") or {}
            for where, c in cov.items():
                label = f"{s} {sp} " + ("own targets" if where == "own" else f"on {where}")
                lines.append(f"  {label:32s}{c['n']:6d}{100 * c['coverage_95']:9.1f}%{c['u95_mm']:10.3f}"
                             f"{c['error_p95_mm']:9.3f}{c['u95_over_p95'] or float('nan'):7.2f}")
    failing = [f"{s} {sp} on {o} ({100 * p['coverage_95']:.0f} %)" for s in series for sp in specs
               for o, p in sorted(results[s]["on"].get(sp, {}).items()) if p.get("coverage_note")]
    if failing:
        lines += [""] + _wrap("Where they do not hold (predict warns): " + ", ".join(failing) + ". The other series "
                              "scatters more than the fit's own did: measured on another day, in another part of the "
                              "joint space; the stated uncertainty is the fit campaign's, and no model can know the "
                              "difference from its own campaign.")
    lines += ["", "The parameters each fit is least sure of (1 sigma; relative to the value):"]
    for s in series:
        for sp in specs:
            for r in table[s].get(f"{sp}_least_sure", [])[:2]:
                lines += _wrap(f"  {s} {sp}: {r['name']} = {r['value']:.4g} +- {r['uncertainty']:.2g} {r['unit']} "
                               f"({100 * r['relative']:.0f} %){': ' + r['meaning'] if r['meaning'] else ''}")
    lines += _wrap("A relative uncertainty beyond 50 % means the poses cannot tell the parameter from 0; a "
                   "parameter in a group the measurements cannot tell apart is stated as its representative "
                   "nearest the nominal robot (docs/physical-redundancy.md).")
    text_page(pdf, "How sure: stated 95 % intervals on poses the fit never saw", lines)
    fig, axes = plt.subplots(len(series), len(specs), figsize=(8.27, 3.6 * len(series)), squeeze=False)
    for i, s in enumerate(series):
        for k, sp in enumerate(specs):
            ax = axes[i, k]
            own = results[s]["self"].get(sp) or {}
            top = 0.0
            for pred, label, style in [(own, f"own targets of {s}", dict(ms=2, alpha=0.6, zorder=3))] + [
                    (p, f"on series {o} (registered)", dict(ms=2, alpha=0.35))
                    for o, p in sorted(results[s]["on"].get(sp, {}).items())]:
                pts = [p for p in pred.get("points", []) if "u95_mm" in p]
                if not pts:
                    continue
                u = np.array([p["u95_mm"] for p in pts])
                e = np.array([p["error_mm"] for p in pts])
                ax.plot(u, e, ".", label=f"{label}: {100 * np.mean(e <= u):.1f} % within", **style)
                top = max(top, float(u.max()), float(e.max()))
            ax.plot([0, top], [0, top], "k-", lw=0.8)
            ax.set_xlim(0, top * 1.05)
            ax.set_ylim(0, top * 1.05)
            ax.set_xlabel("stated u95_mm (mm)")
            ax.set_ylabel("|error| (mm)")
            ax.set_title(f"series {s}, {sp} model", fontsize=9)
            if ax.get_legend_handles_labels()[1]:
                ax.legend(loc="upper left", fontsize=7)
    fig.suptitle("Error of each pose against its stated 95 % radius (below the line: within)", fontsize=9)
    fig.tight_layout(rect=(0, 0.07 / len(series), 1, 1))
    caption(fig, "About 95 % of the points should lie below the diagonal; far fewer says the stated intervals are "
                 "too narrow there (the full table is in the appendix).")
    save(pdf, fig)


def _verdicts(table: dict, models=tuple(SPECS)) -> list[str]:
    """Plain-words lines: does each model carry over to the other series as well as geometry does?"""
    out = []
    for s, t in sorted(table.items()):
        for k in sorted(t):
            if not k.startswith("kinematic_on_"):
                continue
            other = k.split("_on_")[1]
            ref = t[k]["rms_mm"]
            for spec in models:
                key = f"{spec}_on_{other}"
                if spec == "kinematic" or key not in t:
                    continue
                v = t[key]["rms_mm"]
                if v > 1.1 * ref:
                    out.append(f"{spec} fitted on {s} is {v / ref:.1f}x worse than geometry + base + tool on {other} "
                               f"({v:.3f} vs {ref:.3f} mm RMS): its extra terms fit {s}'s own poses "
                               f"({t[spec]['rms_mm']:.3f} vs {t['kinematic']['rms_mm']:.3f} mm) but extrapolate outside "
                               f"the joint ranges {s} sampled ({t[key]['outside_sampled_range']}/{t[key]['n']} poses "
                               "of the other series are outside).")
                elif v < ref:
                    out.append(f"{spec} fitted on {s} carries over to {other}: {v:.3f} vs {ref:.3f} mm RMS.")
    return out


def _described(results: dict, model: str) -> str:
    """A user's model in words: its effects (from its fit JSON), else its name."""
    for r in results.values():
        fit = r.get("fits", {}).get(model)
        if fit and fit.get("effects"):
            eff = fit["effects"]
            names = [e if isinstance(e, str) else (e.get("name") or e.get("effect") or str(e)) for e in eff]
            return " + ".join(names)
    return model


def _fmt(v, spec=".3f"):
    return "—" if v is None or not np.isfinite(v) else format(v, spec)


def _summary(pdf, results, table, campaigns, series, models, note):
    """Page 1: the headline numbers (nominal and every model; own held-out and other series; position,
    orientation, a point on the probe; coverage of the stated u95) and the errors of the held-out poses
    against each joint angle, first model against last, the worst poses marked."""
    ori = any("orientation_rms_arcsec" in table[s].get(m, {}) for s in series for m in models)
    pt = any("point_rms_mm" in table[s].get(m, {}) for s in series for m in models)
    cov = any(f"{m}_coverage" in table[s] for s in series for m in models)
    header = ["series / model", "own\nRMS (mm)", "own\nmax (mm)", "other\nRMS (mm)", "other\nmax (mm)"]
    if ori:
        header.append("orientation\nRMS (″)")
    if pt:
        header.append("probe point\nRMS (mm)")
    if cov:
        header.append("within u95 (%)\nown / other")
    rows, bold = [], []
    for s in series:
        t = table[s]
        bold.append(len(rows))
        rows.append([f"Series {s} ({t['n_sample']} sample, {t['n_target']} held-out poses)"] + [""] * (len(header) - 1))
        nom = t["nominal"]
        row = ["  nominal kinematics", _fmt(nom["rms_mm"]), _fmt(nom["max_mm"]), "—", "—"]
        if ori:
            row.append(_fmt(nom.get("orientation_rms_arcsec"), ".1f"))
        if pt:
            row.append("—")
        if cov:
            row.append("—")
        rows.append(row)
        for m in models:
            if m not in t:
                continue
            e = t[m]
            on = [t[k] for k in sorted(t) if k.startswith(f"{m}_on_")]
            o = on[0] if on else {}
            row = [f"  {m}", _fmt(e["rms_mm"]), _fmt(e["max_mm"]), _fmt(o.get("rms_mm")), _fmt(o.get("max_mm"))]
            if ori:
                row.append(_fmt(e.get("orientation_rms_arcsec"), ".1f"))
            if pt:
                row.append(_fmt(e.get("point_rms_mm")))
            if cov:
                c = t.get(f"{m}_coverage") or {}
                own = c.get("own", {}).get("coverage_95")
                far = [v["coverage_95"] for k, v in c.items() if k != "own"]
                row.append(f"{_fmt(None if own is None else 100 * own, '.1f')} / "
                           f"{_fmt(100 * far[0] if far else None, '.1f')}")
            rows.append(row)
    notes = []
    first, last = (models[0], models[-1]) if models else (None, None)
    for s in series:
        t = table[s]
        if last not in t:
            continue
        nom, own = t["nominal"]["rms_mm"], t[last]["rms_mm"]
        text = (f"Series {s}: the {last} model lowers the own held-out RMS from {nom:.3f} to {own:.3f} mm "
                f"({nom / own:.1f}x)" if own > 0 else f"Series {s}:")
        on_last = [(k.split("_on_")[1], t[k]) for k in sorted(t) if k.startswith(f"{last}_on_")]
        on_first = {k.split("_on_")[1]: t[k] for k in sorted(t) if k.startswith(f"{first}_on_")}
        for o, v in on_last:
            text += f"; on series {o} it gives {v['rms_mm']:.3f} mm"
            if last != first and o in on_first:
                ref = on_first[o]["rms_mm"]
                text += (f", {first} {ref:.3f} mm: " + ("it carries over" if v["rms_mm"] < ref else
                                                         "it does not carry over"))
        notes.append(text + ".")
    pic_series = [s for s in series if s in campaigns and any(results[s]["self"].get(m) for m in models)]

    def draw(fig, rect):
        _joint_picture(fig, rect, results, campaigns, pic_series, models)

    sub = ("Each campaign is split into sample poses (fitted) and held-out target poses by jointcal import. 'own': "
           "the held-out poses of the series the model was fitted on; 'other': the other series, after re-estimating "
           "only the tracker-to-base transform (jointcal predict --register); 'nominal': the nominal kinematics after "
           "the best rigid fit of the tracker frame" + ("; orientation and probe point: on the own held-out poses"
                                                        if ori or pt else "")
           + ("; within u95: the share of poses inside the model's stated 95 % radius" if cov else "") + "."
           + (f" {note}" if note else ""))
    cap = (f"Each dot is one held-out pose: its position error against each joint angle, {first} model in grey"
           + (f", {last} model in blue" if last != first else "")
           + "; red: the worst 5 % of poses of the " + f"{last} model. A trend along one joint, or red dots "
           "gathered at one end of its range, is where the model fails.")
    summary_page(pdf, "Calibrated robot: errors on poses the fit never saw", sub, header, rows, draw, cap,
                 notes=notes, bold_rows=bold, table_fontsize=8.0)


def _pct(c: dict | None) -> str:
    return _fmt(None if not c else 100 * c["coverage_95"], ".1f")


def where_rows(table: dict, model: str) -> tuple[list, list, list[str]]:
    """The table of "where the models hold" (issue 52; pure): ``model`` of each series on its own held-out
    poses and on the other series, the series fitted together, and the region splits; the rows to set bold;
    plain-words notes. Columns: fitted on, judged on, poses, RMS and max (mm), orientation RMS (arcsec),
    within u95 (%), RMS against the own held-out RMS of the series judged."""
    series = sorted(table)
    own = {s: table[s][model]["rms_mm"] for s in series if model in table[s]}
    rows, bold, notes = [], [], []

    def add(fitted, judged, e, of, cov=None):
        rows.append([f"  {fitted}", judged, str(e.get("n", "")), _fmt(e.get("rms_mm")), _fmt(e.get("max_mm")),
                     _fmt(e.get("orientation_rms_arcsec"), ".1f"), _pct(cov),
                     _fmt(e["rms_mm"] / own[of] if own.get(of) else None, ".2f")])

    if own:
        bold.append(len(rows))
        rows.append([f"Each series' own model ({model})"] + [""] * 7)
        for s in series:
            if model not in table[s]:
                continue
            t = table[s]
            c = t.get(f"{model}_coverage") or {}
            add(f"series {s}", f"{s}'s held-out", {**t[model], "n": t["n_target"]}, s, c.get("own"))
            for k in sorted(t):
                if k.startswith(f"{model}_on_"):
                    o = k.split("_on_")[1]
                    add(f"series {s}", f"{o} (registered)", t[k], o, c.get(o))
    together = {s: table[s]["together"] for s in series if table[s].get("together")}
    if together:
        bold.append(len(rows))
        names = " + ".join(next(iter(together.values()))["with"])
        rows.append([f"Fitted together: {names}, each its own tracker frame"] + [""] * 7)
        for s, t in together.items():
            add(names, f"{s}'s held-out", t, s, t.get("coverage"))
        carried = [f"{o}'s on {s} {table[o][f'{model}_on_{s}']['rms_mm']:.3f} mm" for s in together for o in series
                   if f"{model}_on_{s}" in table[o]]
        notes.append("Fitted together, one model holds out at " + ", ".join(
            f"{t['rms_mm']:.3f} mm on {s} ({t['rms_mm'] / own[s]:.2f}x its own model's {own[s]:.3f})"
            for s, t in together.items() if own.get(s)) + ": the robot is one; what a single series teaches "
            "does not carry over to the other's region" + (f" (one series' model on the other: {', '.join(carried)})"
                                                            if carried else "") + ".")
    for s in series:
        splits = table[s].get("splits") or []
        if not splits:
            continue
        bold.append(len(rows))
        rows.append([f"Region splits inside {s}: fitted below a joint's 60th percentile, judged above"] + [""] * 7)
        for sp in splits:
            add(f"{s}, q{sp['joint']} <= {sp['below_deg']:.1f} deg ({sp['n_sample']})", f"q{sp['joint']} above it",
                sp, s, sp.get("coverage"))
        if own.get(s):
            notes.append(f"Inside {s}, judged beyond the range of one joint it was fitted on, the error rises from "
                         f"{own[s]:.3f} mm (own held-out) to " + ", ".join(
                             f"{sp['rms_mm']:.2f} (q{sp['joint']})" for sp in splits)
                         + " mm: what a joint's map learned fades outside the range it sampled.")
    return rows, bold, notes


def _where_page(pdf, results, table, campaigns, series, models) -> None:
    """Issue 52: a summary-like page of where the last model holds: on the other series, the series fitted
    together, the region splits; the picture: where in the workspace each model fails."""
    model = models[-1] if models else None
    if model is None or not any(table[s].get("together") or table[s].get("splits") for s in series):
        return
    rows, bold, notes = where_rows(table, model)
    header = ["fitted on (sample poses)", "judged on", "poses", "RMS\n(mm)", "max\n(mm)", "orientation\nRMS (″)",
              "within\nu95 (%)", "x own\nheld-out"]
    sub = ("The same model judged where it was fitted (own held-out poses), on the other series (tracker "
           "re-registered), every series together (the spec the loop ends with on them all, robot diagnose-loop "
           "--campaign ... --campaign ..., then fit: one robot, each series its own tracker frame) and inside one series split by region (jointcal robot region-split: "
           "fitted on the sample poses below a joint's 60th percentile, judged on every pose above). 'x own': RMS "
           "over the own model's held-out RMS of the series judged.")
    pic = [s for s in series if s in campaigns and "x_mm" in campaigns[s]]

    def draw(fig, rect):
        _workspace_picture(fig, rect, results, campaigns, pic, model)

    cap = ("Each mark is one held-out pose, coloured by its position error (RMS in mm in the titles), a column per "
           "model; top: in the two joints whose ranges the series share least; bottom: where it puts the probe "
           "(nominal kinematics, base frame, from above). In the workspace the series overlap; in the joints they "
           "do not, and a model fails in the joint region its series never sampled.")
    summary_page(pdf, "Where the models hold: other series, fitted together, region splits", sub, header, rows,
                 draw, cap, notes=notes, bold_rows=bold, align=["l", "l", "r", "r", "r", "r", "r", "r"],
                 table_fontsize=7.5)


def apart_joints(campaigns: dict, k: int = 2) -> list[int]:
    """The ``k`` joints (1-based) whose sampled ranges the series share least (pure): for each joint, the
    overlap of the series' ranges over their union (the smallest over every pair of series), smallest first;
    with one series, joints 1 .. k."""
    names = sorted(campaigns)
    n = min(sum(1 for c in campaigns[s].columns if c[:1] == "q" and c[1:].isdigit()) for s in names)
    score = []
    for j in range(1, n + 1):
        r = [(float(campaigns[s][f"q{j}"].min()), float(campaigns[s][f"q{j}"].max())) for s in names]
        shared = [max(0.0, min(a[1], b[1]) - max(a[0], b[0])) / max(max(a[1], b[1]) - min(a[0], b[0]), 1e-9)
                  for i, a in enumerate(r) for b in r[i + 1:]]
        score.append((min(shared) if shared else j, j))
    return sorted(j for _, j in sorted(score)[:k])


def _workspace_picture(fig, rect, results, campaigns, series, model):
    """Held-out poses of every series, coloured by |error| (mm), a column per model (each series' own
    model, the series fitted together): in the joints whose ranges the series share least (deg), and in the
    workspace seen from above (x, y mm, base frame)."""
    columns = []
    for o in series:
        pts = [(o, (results[o]["self"].get(model) or {}).get("points") or [])]
        pts += [(s, (results[o]["on"].get(model, {}).get(s) or {}).get("points") or []) for s in series if s != o]
        columns.append((f"{o}'s model", pts))
    tog = next((results[s]["together"] for s in series if (results[s].get("together") or {}).get("self")), None)
    if tog:
        columns.append(("fitted together", [(Path(c["campaign"]).name, c["points"]) for c in tog["self"]["campaigns"]
                                            if Path(c["campaign"]).name in series]))
    columns = [(label, [(s, p) for s, p in parts if p]) for label, parts in columns]
    columns = [c for c in columns if c[1]]
    if not columns:
        ax = fig.add_axes(rect)
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no per-pose errors to draw", ha="center", va="center", transform=ax.transAxes)
        return
    ja, jb = apart_joints({s: campaigns[s] for s in series})
    views = [(f"q{ja}", f"q{jb}", f"q{ja} (deg)", f"q{jb} (deg)"), ("x_mm", "y_mm", "x (mm)", "y (mm)")]
    left, bottom, width, height = rect
    top = bottom + height
    height = min(height, 0.5)
    bottom = top - height
    gs = fig.add_gridspec(2, len(columns), left=left, right=left + width * 0.9, bottom=bottom, top=top,
                          wspace=0.1, hspace=0.32)
    errs = np.concatenate([[p["error_mm"] for p in pts] for _, parts in columns for _, pts in parts])
    vmax = float(np.quantile(errs, 0.99)) if errs.size else 1.0
    markers = dict(zip(series, "o^sDv<>"))
    sc = None
    for i, (cx, cy, lx, ly) in enumerate(views):
        for k, (label, parts) in enumerate(columns):
            ax = fig.add_subplot(gs[i, k])
            for s, pts in parts:
                poses = campaigns[s].set_index("point_id")
                if cx not in poses or cy not in poses:
                    continue
                kept = [p for p in pts if p["point_id"] in poses.index]
                e = np.array([p["error_mm"] for p in kept])
                xy = poses.loc[[p["point_id"] for p in kept], [cx, cy]].to_numpy(float)
                order = np.argsort(e)              # the largest errors drawn last, on top
                sc = ax.scatter(xy[order, 0], xy[order, 1], c=e[order], s=3 if markers[s] == "o" else 4,
                                marker=markers[s], cmap="viridis", vmin=0, vmax=vmax, linewidths=0)
            if i == 0:
                rms = [f"{s}{' (own)' if label == f'{s}' + chr(39) + 's model' else ''} "
                       f"{np.sqrt(np.mean(np.square([p['error_mm'] for p in pts]))):.3f}" for s, pts in parts]
                ax.set_title(f"{label}\non " + ", ".join(rms) + " mm", fontsize=7)
            ax.tick_params(labelsize=6, length=2, pad=1)
            ax.locator_params(nbins=4)
            ax.set_xlabel(lx, fontsize=7, labelpad=1)
            if k == 0:
                ax.set_ylabel(ly, fontsize=7)
            else:
                ax.tick_params(labelleft=False)
    if sc is not None:
        cax = fig.add_axes((left + width * 0.93, bottom + height * 0.15, 0.015, height * 0.7))
        cb = fig.colorbar(sc, cax=cax)
        cb.set_label("|position error| (mm)", fontsize=7)
        cb.ax.tick_params(labelsize=6)
        handles = [plt.Line2D([], [], ls="", marker=markers[s], color="0.3", ms=4, label=f"series {s}") for s in series]
        fig.legend(handles=handles, loc="upper left", ncol=1, fontsize=7, frameon=False,
                   bbox_to_anchor=(left + width * 0.91, top + 0.01))


def _joint_picture(fig, rect, results, campaigns, series, models):
    """Error of each held-out pose against each joint angle (a row per series, a panel per joint):
    the first model grey, the last blue, the last model's worst 5 % red (mm against deg)."""
    if not series or not models:
        ax = fig.add_axes(rect)
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no per-pose errors to draw", ha="center", va="center", transform=ax.transAxes)
        return
    first, last = models[0], models[-1]
    qn = max(sum(1 for c in campaigns[s].columns if c[:1] == "q" and c[1:].isdigit()) for s in series)
    left, bottom, width, height = rect
    top = bottom + height
    height = min(height, 0.2 * len(series) + 0.06 * (len(series) - 1))     # panels no taller than about wide
    bottom = top - height
    gs = fig.add_gridspec(len(series), qn, left=left, right=left + width, bottom=bottom, top=bottom + height,
                          wspace=0.12, hspace=0.35)
    handles = {}
    for i, s in enumerate(series):
        poses = campaigns[s].set_index("point_id")
        top = 0.0
        drawn = []
        for m in dict.fromkeys((first, last)):
            pred = results[s]["self"].get(m)
            if not pred:
                continue
            pts = pd.DataFrame(pred["points"])
            q = poses.loc[pts["point_id"], [f"q{j + 1}" for j in range(qn) if f"q{j + 1}" in poses]].to_numpy(float)
            e = pts["error_mm"].to_numpy(float)
            drawn.append((m, q, e))
            top = max(top, float(e.max()))
        for j in range(qn):
            ax = fig.add_subplot(gs[i, j])
            for m, q, e in drawn:
                if j >= q.shape[1]:
                    continue
                colour = "0.6" if (m == first and first != last) else "tab:blue"
                h, = ax.plot(q[:, j], e, ".", ms=1.8, color=colour, alpha=0.7, zorder=2 if m == last else 1)
                handles.setdefault(f"{m} model", h)
                if m == last and e.size >= 20:
                    worst = e >= np.quantile(e, 0.95)
                    h, = ax.plot(q[worst, j], e[worst], ".", ms=3.5, color="tab:red", zorder=3)
                    handles.setdefault(f"worst 5 % of the {m} model", h)
            ax.set_ylim(0, 1.05 * top if top > 0 else 1)
            ax.tick_params(labelsize=6, length=2, pad=1)
            ax.locator_params(axis="x", nbins=3)
            ax.set_xlabel(f"q{j + 1} (deg)", fontsize=7, labelpad=1)
            if j == 0:
                ax.set_ylabel(f"series {s}\n|error| (mm)", fontsize=7)
            else:
                ax.tick_params(labelleft=False)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=len(handles), fontsize=7,
                   bbox_to_anchor=(left + width / 2, bottom + height + 0.005), markerscale=2.5, frameon=False)


def load_user_results(fits, predicts, others=(), series="campaign", other_name="other") -> dict:
    """:func:`transfer_table`'s input from a user's own files (any robot): each ``jointcal fit`` JSON
    with the ``jointcal predict`` JSON of it on its own campaign and, optionally, on another campaign
    (``predict --register``). A model is named by its fit file's name without ``.json``.

    Parameters
    ----------
    fits, predicts : list of paths, one predict a fit, in the same order
    others : list of paths, empty or one a fit
    """
    if len(predicts) != len(fits):
        raise InputError(predicts[0] if predicts else fits[0],
                         f"{len(fits)} --fit but {len(predicts)} --predict: give one predict JSON a fit, in order")
    if others and len(others) != len(fits):
        raise InputError(others[0], f"{len(fits)} --fit but {len(others)} --other: give none or one a fit")
    r = {"fits": {}, "self": {}, "on": {}}
    for k, (f, p) in enumerate(zip(fits, predicts)):
        name = Path(f).name.removesuffix(".json")
        r["fits"][name] = read_json_input(f)
        r["self"][name] = read_json_input(p)
        r["on"][name] = {other_name: read_json_input(others[k])} if others else {}
    return {series: r}


def fitted_campaign(fits: dict, first_fit) -> str:
    """The imported campaign a user's fits were fitted on, from the first fit JSON (its ``campaign``);
    bad input (one line, naming the fit file) when it does not name one, or the folder is not there.

    Parameters
    ----------
    fits : dict ``{model: fit JSON}`` in the --fit order
    first_fit : path of the first --fit JSON (named in the message)
    """
    doc = next(iter(fits.values()), {})
    named = doc.get("campaign")
    if len(doc.get("campaigns") or []) > 1:    # fitted on several campaigns: which one is for the user to say
        named = None
    if not named or not (Path(named) / "poses.csv").exists():
        why = (f"it names {named}, which has no poses.csv here" if named else
               "it does not name a single campaign")
        raise InputError(first_fit, f"--fit needs --campaign, the imported campaign it was fitted on (the folder "
                                    f"jointcal import wrote, whose poses.csv gives the joint angles): {why}")
    return str(named)


def load_campaign(campaign_dir):
    """One imported campaign's ``poses.csv`` (point_id, set, q1..qN deg), with where each pose puts the
    probe in the workspace (:func:`with_workspace`); missing is bad input."""
    path = Path(campaign_dir) / "poses.csv"
    if not path.exists():
        raise InputError(path, "no imported campaign here: give the folder jointcal import wrote (--out)")
    return with_workspace(pd.read_csv(path, dtype={"point_id": str}), Path(campaign_dir) / "robot.toml")


def with_workspace(poses: pd.DataFrame, robot_path) -> pd.DataFrame:
    """``poses`` with ``x_mm, y_mm, z_mm``: the probe's nominal position at each pose in the robot's base
    frame (mm; the campaign's ``robot.toml``, its coupled joints combined), where the pose is in the
    workspace. Without a ``robot.toml`` the poses are returned as they are."""
    from ..arm.kinematics import build_model, load_robot, positions

    if not Path(robot_path).exists():
        return poses
    robot = load_robot(robot_path)
    cols = [f"q{j}" for j in range(1, robot.n_joints + 1)]
    if not all(c in poses for c in cols):
        return poses
    q = robot.kinematic_angles(poses[cols].to_numpy(float))
    xyz = positions(build_model(robot), np.radians(q), "smr")
    out = poses.copy()
    out["x_mm"], out["y_mm"], out["z_mm"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return out


def load_campaigns(campaigns_dir) -> dict:
    """The imported campaign of every series (``<campaigns_dir>/<series>/poses.csv``, jointcal import),
    by series name in sorted order; none is bad input."""
    series = sorted(p.name for p in Path(campaigns_dir).iterdir() if (p / "poses.csv").exists()) \
        if Path(campaigns_dir).is_dir() else []
    if not series:
        raise InputError(campaigns_dir, "no imported campaign (<series>/poses.csv): run `make real` or jointcal import")
    return {s: load_campaign(Path(campaigns_dir) / s) for s in series}


def load_results(results_dir, series) -> dict:
    """Read the fit and predict JSONs of every series (see the module docstring)."""
    d = Path(results_dir)
    out = {}
    for s in series:
        others = [o for o in series if o != s]
        r = {"fits": {}, "self": {}, "on": {}}
        for spec in SPECS:
            if not (d / f"{s}_{spec}.json").exists():
                continue
            r["fits"][spec] = read_json_input(d / f"{s}_{spec}.json")
            r["self"][spec] = read_json_input(d / f"{s}_{spec}_self.json")
            r["on"][spec] = {o: read_json_input(d / f"{s}_{spec}_on_{o}.json") for o in others
                             if (d / f"{s}_{spec}_on_{o}.json").exists()}
        if (d / f"{s}_loop.json").exists():
            r["loop"] = read_json_input(d / f"{s}_loop.json")
        if (d / f"{s}_export.json").exists():   # jointcal export --heldout (issue #18)
            r["export"] = read_json_input(d / f"{s}_export.json")
        # issue 52: the series fitted together; region splits (jointcal robot region-split, then fit and predict)
        together = d / f"{''.join(series)}_together.json"
        if len(series) > 1 and together.exists():
            self_path = together.with_name(together.stem + "_self.json")
            r["together"] = {"fit": read_json_input(together), "campaign": s,
                             "self": read_json_input(self_path) if self_path.exists() else None}
        splits = {}
        for j in range(1, 8):
            f = d / f"{s}_split_q{j}.json"
            if f.exists():
                a = f.with_name(f.stem + "_above.json")
                splits[j] = {"fit": read_json_input(f), "above": read_json_input(a) if a.exists() else None}
        if splits:
            r["splits"] = splits
        out[s] = r
    return out


def real_report(results: dict, campaigns: dict, out, note: str | None = None) -> dict:
    """Write the report; returns :func:`transfer_table`.

    Parameters
    ----------
    results : dict (see :func:`transfer_table`)
    campaigns : dict series -> DataFrame of the imported ``poses.csv`` (point_id, set, q1..qN deg)
    out : path of the PDF
    note : str, optional
        A sentence about the data set (where it comes from, what others measured on it), printed under
        the first page's title; none for a user's own robot.
    """
    table = transfer_table(results)
    series = sorted(table)
    models = model_names(results)
    with pdf_pages(out, "jointcal real-robot report") as pdf:
        _summary(pdf, results, table, campaigns, series, models, note)
        _where_page(pdf, results, table, campaigns, series, models)
        lines = ["Real laser-tracker measurements: errors on poses the fit never saw (mm)", "",
                 "Each series is split into sample poses (fitted) and target poses (held out) by",
                 "`jointcal import`. 'nominal' is the nominal kinematics after the best rigid fit of the",
                 "tracker frame; 'on <other>' applies the fitted model to the other series after",
                 "re-estimating only the tracker-to-base transform (jointcal predict --register).", ""]
        head = f"{'series / model':44s}{'RMS':>8s}{'max':>8s}{'mean':>8s}"
        for s in series:
            t = table[s]
            lines += [f"Series {s}: {t['n_sample']} sample, {t['n_target']} target poses"]
            if t.get("outliers"):
                lines += _wrap("  wild measurements, left out of every fit and error below (docs/wild-points.md): "
                               + ", ".join(f"{w['point_id']} ({w['set']}, tracker.csv line {w['line']}, "
                                           f"{w['error_mm']:.2f} mm)" for w in t["outliers"]))
            lines.append(head)
            lines.append(f"  {'nominal kinematics':42s}{t['nominal']['rms_mm']:8.3f}{t['nominal']['max_mm']:8.3f}"
                         f"{t['nominal']['mean_mm']:8.3f}")
            for spec in models:
                if spec not in t:
                    continue
                e = t[spec]
                lines.append(f"  {spec + ' (own held-out poses)':42s}{e['rms_mm']:8.3f}{e['max_mm']:8.3f}{e['mean_mm']:8.3f}")
                w = t.get(f"{spec}_with_outliers")
                if w:
                    lines.append(f"  {'  with the wild targets':42s}{w['rms_mm']:8.3f}{w['max_mm']:8.3f}{w['mean_mm']:8.3f}")
                for k in sorted(t):
                    if k.startswith(f"{spec}_on_"):
                        o = t[k]
                        lines.append(f"  {spec + ' on series ' + k.split('_on_')[1] + ' (registered)':42s}"
                                     f"{o['rms_mm']:8.3f}{o['max_mm']:8.3f}{o['mean_mm']:8.3f}"
                                     f"  ({o['outside_sampled_range']}/{o['n']} outside)")
                weak = t.get(f"{spec}_left_at_nominal") or []
                lines.append(f"    left at nominal (weakly determined by these poses): {', '.join(weak) or 'none'}")
            lines.append("")
        lines += ["'outside': poses of the other series with a joint outside the joint ranges the model",
                  "was fitted on (it extrapolates there).", ""]
        verdicts = _verdicts(table, models)
        if verdicts:
            lines += ["What carries over:"] + [f"  {v}" for v in verdicts] + [""]
        lines += ["Models:"] + [f"  {k}: {SPECS.get(k, _described(results, k))}" for k in models]
        if note:
            lines += [""] + _wrap(note)
        text_page(pdf, "Own held-out poses and the other series, model by model", lines)
        if any("orientation_rms_arcsec" in table[s].get(spec, {}) for s in series for spec in models):
            text_page(pdf, "Full poses: the probe's orientation and a point on the probe", _full_pose_lines(table, models))

        exported = {s: results[s]["export"] for s in series if results[s].get("export")}
        if exported:   # what reaches the robot (jointcal export --heldout): held-out RMS, mm
            lines = ["The diagnosis loop's final model of each series, and what of it a robot takes, on the",
                     "series' own held-out target poses (RMS, mm):", "",
                     f"{'series':8s}{'nominal':>9s}{'kinematic':>11s}{'full model':>12s}{'URDF / UR':>11s}{'+ tables':>10s}"
                     "  left out by tables"]
            for s, h in exported.items():
                kin = results[s]["self"].get("kinematic", {}).get("rms_mm", float("nan"))
                lines.append(f"{s:8s}{h['nominal_rms_mm']:9.3f}{kin:11.3f}{h['full_rms_mm']:12.3f}{h['chain_rms_mm']:11.3f}"
                             f"{h['chain_tables_rms_mm']:10.3f}  {', '.join(h['chain_tables_left_out']) or 'nothing'}")
            lines += ["", "URDF / UR: the rigid chain nearest the whole model (geometry, base and tool fitted to",
                      "the model's own predictions at the poses it was fitted on; jointcal export --format urdf",
                      "or ur); + tables: the chain fitted with the per-joint compensation tables (joint maps,",
                      "backlash) applied in the drives (--format table, export --with-tables). Only jointcal",
                      "correct, which filters the program through the whole model, carries compliance: its",
                      "commands land at the full model's error. kinematic: a geometry + base + tool fit on its",
                      "own; the URDF's chain is as good as it, the model's own geometry alone (fitted together",
                      "with the joint maps and compliance) is not:"]
            lines += [f"  {s}: the model's own geometry {h['model_geometry_rms_mm']:.3f} mm, with the tables "
                      f"{h['model_geometry_tables_rms_mm']:.3f} mm" for s, h in exported.items()
                      if "model_geometry_rms_mm" in h]
            text_page(pdf, "What reaches the robot: exports judged on held-out poses", lines)

        # the diagnosis loop: what was added each round, and the error it left (own, other series)
        for s in series:
            loop = results[s].get("loop")
            if not loop:
                continue
            o = [x for x in series if x != s]
            lines = [f"Starting from geometry + base + tool, `jointcal robot diagnose-loop` diagnoses series {s}'s "
                     "sample poses,", "adds every recommended effect and diagnoses again, until nothing is recommended.",
                     f"Each round's model is judged on {s}'s held-out target poses and on series "
                     f"{', '.join(o)} (tracker re-registered).", "",
                     f"{'round':>5}  {'CV RMS':>8}  {'own RMS / max':>15}  {'other RMS / max':>17}  added after this round"]
            for x in loop["rounds"]:
                own, far = x["own"], x["other"]
                sw = x.get("swap") or {}
                added = ", ".join(a["label"] for a in x["recommended"] if a["label"] not in x.get("dropped_for_swap", []))
                if sw.get("made"):
                    added = f"swap {sw['from']} -> {sw['to']}" + (f"; {added}" if added else "")
                added = added or "nothing: the loop ends"
                lines.append(f"{x['round']:>5}  {x['cv_rms_mm']:>8.3f}  {own['rms_mm']:>6.3f} / {own['max_mm']:>6.3f}  "
                             f"{(far or {}).get('rms_mm', float('nan')):>7.3f} / {(far or {}).get('max_mm', float('nan')):>6.3f}"
                             f"  {added}")
            # issue 16: each round's set verified by refitting it; rounds rolled back; the words it ends with
            lines.append("")
            for key, where in (("outliers", s), ("other_outliers", ", ".join(o))):
                wild = loop.get(key) or []
                if wild:   # issue 23: named, left out of every fit and error above
                    lines += _wrap(f"Wild measurements of series {where}, left out of the loop (own / other errors "
                                   "above are without them): " + ", ".join(
                                       f"{w['point_id']} ({w['set']}, tracker.csv line {w['line']}, {w['error_mm']:.2f} mm)"
                                       for w in wild) + ".")
            for x in loop["rounds"]:
                if x.get("own_with_outliers"):
                    w = x["own_with_outliers"]
                    lines += _wrap(f"round {x['round']}: with the wild targets, own RMS {w['rms_mm']:.3f} mm, max "
                                   f"{w['max_mm']:.3f} mm")
                sw = x.get("swap") or {}
                if sw.get("from"):
                    lines += _wrap(f"round {x['round']}: swap {sw['why']}")
                for note in x.get("max_rose", []):   # the loop decides on the cross-validated RMS alone
                    lines += _wrap(f"round {x['round']}: {note}")
            for x in loop["rounds"]:
                v = x.get("verified_set") or {}
                if v.get("checked"):
                    lines += _wrap(f"round {x['round']}: verified as a set (each fold refitted): "
                                   f"{' + '.join(v['members']) or 'nothing'}: {v['baseline_cv_rms']:.4g} -> "
                                   f"{v['cv_rms']:.4g} mm by pose, {v['baseline_cv_rms_region']:.4g} -> "
                                   f"{v['cv_rms_region']:.4g} mm by region"
                                   + (f"; dropped {', '.join(v['dropped'])}" if v.get("dropped") else ""))
                if x.get("rolled_back"):
                    lines += _wrap(f"round {x['round']}: {x['rolled_back']}")
            if loop.get("done"):
                lines += _wrap(f"The loop ends: {loop['done']}.")
            last = loop["rounds"][-1]
            refused = last.get("refused", []) + [r for x in loop["rounds"][:-1] for r in x.get("refused", [])]
            if refused:
                lines += ["", "Refused along the way although they lowered the error on neighbouring poses (first 12):"]
                seen = set()
                for r in refused:
                    if r["label"] in seen:
                        continue
                    seen.add(r["label"])
                    lines.append(f"  {r['label']}: {r['reason']}")
                    if len(seen) >= 12:
                        break
            lines += ["", "All errors in mm. 'CV RMS': the diagnosis' cross-validated RMS over the sample poses.",
                      "joint_map: each joint's angle error against its own angle, a smooth curve on a 2 deg grid over",
                      "the sampled range, fading to zero beyond it (the first paper's subject, joint by joint)."]
            text_page(pdf, f"Series {s}: diagnose, add, diagnose again", lines)

        _uncertainty_pages(pdf, results, table, series)

        # bars: own held-out vs other series, per series and model
        fig, axes = plt.subplots(1, len(series), figsize=(8.27, 4.2), squeeze=False)
        for ax, s in zip(axes[0], series):
            t = table[s]
            labels, own, other = ["nominal"], [t["nominal"]["rms_mm"]], [np.nan]
            for spec in models:
                if spec in t:
                    labels.append(spec)
                    own.append(t[spec]["rms_mm"])
                    k = next((k for k in sorted(t) if k.startswith(f"{spec}_on_")), None)
                    other.append(t[k]["rms_mm"] if k else np.nan)
            x = np.arange(len(labels))
            ax.bar(x - 0.2, own, 0.4, label=f"own held-out poses of {s}")
            if np.isfinite(other).any():
                ax.bar(x + 0.2, other, 0.4, label="other series (registered)")
            for xi, v in zip(x, own):
                ax.text(xi - 0.2, v, f"{v:.2f}", ha="center", va="bottom", fontsize=7)
            for xi, v in zip(x, other):
                if np.isfinite(v):
                    ax.text(xi + 0.2, v, f"{v:.2f}", ha="center", va="bottom", fontsize=7)
            ax.set_xticks(x, labels)
            ax.set_yscale("log")
            vals = [v for v in own + other if np.isfinite(v)]
            ax.set_ylim(min(vals) / 1.5, max(vals) * 2.0)
            ax.yaxis.set_major_locator(FixedLocator([0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50]))
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            ax.yaxis.set_minor_formatter(NullFormatter())
            ax.set_ylabel("RMS position error (mm, log)")
            ax.set_title(f"model fitted on series {s}")
            ax.legend(loc="upper left")
            ax.tick_params(axis="x", labelsize=7)
        fig.suptitle("Held-out RMS error of each model: own target poses and the other series", fontsize=10)
        fig.tight_layout(rect=(0, 0.1, 1, 1))
        caption(fig, "A model that is lower on its own poses but not on the other series fits its own campaign's "
                     "poses without carrying over (log scale: equal steps are equal ratios).")
        save(pdf, fig)

        # per-pose error against each joint angle (held-out poses of each series)
        for s in series:
            for spec in models:
                pred = results[s]["self"].get(spec)
                if pred is None or s not in campaigns:
                    continue
                poses = campaigns[s].set_index("point_id")
                pts = pd.DataFrame(pred["points"])
                qcols = []
                while f"q{len(qcols) + 1}" in poses:
                    qcols.append(f"q{len(qcols) + 1}")
                q = poses.loc[pts["point_id"], qcols].to_numpy(float)
                e = pts["error_mm"].to_numpy(float)
                rows = -(-len(qcols) // 3)           # a panel per joint, three a row
                fig, axes = plt.subplots(rows, 3, figsize=(8.27, 2.8 * rows), sharey=True, squeeze=False)
                for j, ax in enumerate(axes.ravel()):
                    if j >= len(qcols):
                        ax.set_visible(False)
                        continue
                    ax.plot(q[:, j], e, ".", ms=2, alpha=0.5)
                    # a running median shows a trend the cloud hides
                    order = np.argsort(q[:, j])
                    if e.size >= 40:   # noqa: PLR2004 (fewer poses: no median to draw, no legend)
                        k = max(10, e.size // 30)
                        med = pd.Series(e[order]).rolling(k, center=True, min_periods=k // 2).median()
                        ax.plot(q[order, j], med, "-", lw=1.2, color="C3", label="running median")
                    ax.set_xlabel(f"q{j + 1} (deg)")
                    if j % 3 == 0:
                        ax.set_ylabel("|error| (mm)")
                if axes[0, 0].get_legend_handles_labels()[1]:
                    axes[0, 0].legend(loc="upper right")
                fig.suptitle(f"Series {s}, {spec} model: error of each held-out pose against each joint angle "
                             f"(RMS {pred['rms_mm']:.3f} mm)", fontsize=9)
                fig.tight_layout(rect=(0, 0.09, 1, 1))
                caption(fig, "A trend along one joint's angle (the running median rising or falling) is an effect "
                             "the model lacks; a flat cloud is noise.")
                save(pdf, fig)
    return table
