"""Stage ``report`` (encoder): the paper's Figures 4-9, the aliasing table and this run's
numbers beside the paper's, as one deterministic PDF (``reports/encoder.pdf``).

Pages
-----
1. At a glance: p2p before/after and reduction of each held-out run beside the paper's (a typeset
   table) and each held-out run before and after compensation.
2. Figure 4: original angle error of every run.
3. Figure 5: harmonic characteristic (amplitude per order) of each modelling run.
4. Figure 6: amplitude-order diagram with the selection thresholds.
5. Figure 7: phase of each order over the modelling runs, phase range and stability.
6. Figure 8: the error model over 0-360 deg with the modelling runs' readings.
7. Figure 9: held-out run before and after compensation.
Appendix (monospaced text, last): 8. numbers beside the paper's: p2p before/after and reduction of
the held-out run, the selected orders (paper rule, cross-validated choice, paper), max |LSQ - FFT|,
closures; 9. fitted terms (C_i, phi_i) beside the paper's Eqs. 7/8; 10. aliasing table (Eqs. 3-4)
for the number of distinct angles of this campaign.

Conventions (see :mod:`pipeline.encoder.harmonic`): error = C_0 + sum C_i sin(i theta + phi_i);
angles in deg, angle errors in arcsec. Order 0 is the signed constant C_0; where an
amplitude is drawn, |C_0| is used.
"""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.patches import Patch
import pandas as pd

from .evaluate import model_from_result
from .model import circular_mean_deg
from ..core.plotting import caption, pdf_pages, plt, save, summary_page, text_page
from .simulate import PAPER_MODELS

A4 = (8.27, 11.69)
RUN_COLORS = plt.get_cmap("tab10").colors

# The paper's published numbers (Hu et al. 2020, section 4.2 and Eqs. 7-8).
PAPER = {
    "a": {"p2p_before": 149.53, "p2p_after": 26.62, "reduction": 82.20,
          "orders": [1, 4, 8, 12, 14, 15, 16], "C0": None},
    "b": {"p2p_before": 101.35, "p2p_after": 18.40, "reduction": 81.85,
          "orders": [0, 1, 4, 7, 8, 12, 14, 16], "C0": -11.47},
}
PAPER_AVERAGE_REDUCTION = 82.03
PAPER_N = 37

DATA_NOTE = [
    "Data: the shipped SYNTHETIC fixture (raw/encoder/, written by `jointcal simulate encoder`,",
    "seeded; see raw/README.md), generated from the paper's Eq. 7/8 terms plus noise.",
    "They are not the authors' measurements: agreement with the paper's numbers shows the",
    "pipeline recovers the terms the generator was built on, not a re-run of their experiment.",
]


# ------------------------------------------------------------------------------ helpers
def _paper_terms(module):
    """The paper's terms of a module as {order: (C, phi)}; empty for a module it lacks."""
    terms = dict(PAPER_MODELS.get(module, {}))
    c0 = PAPER.get(module, {}).get("C0")
    if c0 is not None:
        terms[0] = (c0, 0.0)
    return dict(sorted(terms.items()))


def _paper_curve(module, theta_deg):
    terms = _paper_terms(module)
    if not terms:
        return None
    th = np.deg2rad(theta_deg)
    return sum(c if i == 0 else c * np.sin(i * th + np.deg2rad(p)) for i, (c, p) in terms.items())


def _unwrap_deg(theta_deg):
    """Angles of consecutive readings made continuous (the closing reading lands at ~360)."""
    th = np.rad2deg(np.unwrap(np.deg2rad(np.asarray(theta_deg, float))))
    if th.size and th[0] >= 180.0:  # a run starting just below 360 starts at ~0 on the plot
        th = th - 360.0
    return th


def _pad_ylim(ax, values, top=0.25, bottom=0.08):
    """Room above (legend) and below (notes) the data."""
    v = np.concatenate([np.ravel(np.asarray(x, float)) for x in values])
    v = v[np.isfinite(v)]
    if v.size:
        lo, hi = v.min(), v.max()
        span = max(hi - lo, 1e-9)
        ax.set_ylim(lo - bottom * span, hi + top * span)


def _wrap(text, width=104, indent="       "):
    return textwrap.wrap(text, width=width, subsequent_indent=indent, break_on_hyphens=False)


def _runs_sorted(readings):
    for r, g in readings.sort_values(["run", "step"]).groupby("run", sort=True):
        yield int(r), g


def _wrap180(x):
    return (np.asarray(x, float) + 180.0) % 360.0 - 180.0


def _fmt(v, spec=".2f", missing="—"):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return missing
    return format(v, spec)


def _orders_str(orders):
    return " ".join(str(int(o)) for o in orders) if orders is not None else "—"


def _panel_figure(modules, suptitle):
    """A4 page, one panel per module (a, b, ...), stacked."""
    n = len(modules)
    fig, axes = plt.subplots(n, 1, figsize=A4, squeeze=False)
    fig.suptitle(suptitle, fontsize=12, weight="bold")
    return fig, [ax[0] for ax in axes]


def _panel_title(ax, k, module, text):
    ax.set_title(f"({chr(ord('a') + k)}) joint module {module}: {text}", loc="left")


def _finish(fig, what=None, h_pad=None):
    """Lay the panels out under the title; ``what``: the caption sentence (what to see)."""
    fig.tight_layout(rect=(0, 0.035 if what else 0, 1, 0.96), h_pad=h_pad)
    if what:
        caption(fig, what)


def _modelling_runs(inp):
    runs = inp["selection"].get("modelling_runs") or inp["model"].get("modelling_runs")
    return [int(r) for r in runs]


def _n_distinct(inp):
    h = inp["harmonics"]
    if "N" in h and len(h):
        return int(h["N"].iloc[0])
    return int(inp["model"].get("n_distinct_angles", 0))


# ------------------------------------------------------------------------------- pages
def _numbers_page(pdf, inputs):
    modules = list(inputs)
    L = []
    L += DATA_NOTE
    L.append("")
    L.append("1. Held-out run: peak-to-peak angle error (p2p = max - min over its readings), arcsec")
    L.append(f"   {'module':<7}{'run':<5}{'before':>9}{'after':>9}{'reduct.%':>10}   |"
             f"{'paper before':>13}{'after':>8}{'reduct.%':>10}")
    ours = []
    for m in modules:
        mod = inputs[m]["model"]
        p = PAPER.get(m, {})
        run = ",".join(str(r) for r in mod.get("validation_runs", []))
        L.append(f"   {m:<7}{run:<5}{mod['p2p_before_arcsec']:>9.2f}{mod['p2p_after_arcsec']:>9.2f}"
                 f"{mod['reduction_pct']:>10.2f}   |{_fmt(p.get('p2p_before')):>13}{_fmt(p.get('p2p_after')):>8}"
                 f"{_fmt(p.get('reduction')):>10}")
        ours.append(mod["reduction_pct"])
    L.append(f"   {'average':<12}{'':>18}{np.mean(ours):>10.2f}   |{'':>21}{PAPER_AVERAGE_REDUCTION:>10.2f}")
    for m in modules:
        for v in inputs[m]["model"].get("validation", []):
            L.append(f"   module {m}, run {v['run']}: RMS {v['rms_before_arcsec']:.2f} -> "
                     f"{v['rms_after_arcsec']:.2f} arcsec (after: run constant removed)")
    L.append("")
    L.append("2. Selected harmonic orders (0 = constant term)")
    for m in modules:
        sel = inputs[m]["selection"]
        L.append(f"   module {m}")
        L.append(f"     paper rule, this run : {_orders_str(sel.get('paper_rule_orders'))}")
        L.append(f"     cross-validated (CV) : {_orders_str(sel.get('cv_orders'))}")
        L.append(f"     paper (Eq. 7/8)      : {_orders_str(PAPER.get(m, {}).get('orders'))}")
        L.append(f"     used in the model    : {_orders_str(inputs[m]['model'].get('orders'))}"
                 f"   (rule: {sel.get('rule', '?')})")
        path = sel.get("cv_path") or []
        if path:
            steps = ", ".join(("start" if s["added"] is None else f"+{s['added']}") + f" {s['cv_rms_arcsec']:.2f}"
                              for s in path)
            L += _wrap(f"     CV path (leave-one-run-out RMS, arcsec): {steps}")
    th = inputs[modules[0]]["selection"].get("thresholds", {})
    L.append(f"   Paper rule over modelling runs {_orders_str(_modelling_runs(inputs[modules[0]]))}: keep an order with")
    L.append(f"   mean amplitude >= {th.get('amplitude_strong_arcsec', '?')} arcsec, or >= "
             f"{th.get('amplitude_min_arcsec', '?')} arcsec with phase range <= {th.get('phase_range_max_deg', '?')} deg.")
    L.append("")
    L.append("3. Per-run harmonic analysis: least squares vs FFT, and closure")
    for m in modules:
        h = inputs[m]["harmonics"]
        d = []
        for col in ("A", "B"):
            if f"{col}_fft" in h:
                diff = (h[col] - h[f"{col}_fft"]).abs().to_numpy(float)
                d.append(np.nanmax(diff) if np.isfinite(diff).any() else np.nan)
        dmax = max(d) if d and np.isfinite(d).any() else None
        L.append(f"   module {m}: N = {_n_distinct(inputs[m])} distinct angles, "
                 f"{int(h['readings'].iloc[0]) if 'readings' in h else '?'} readings a run; "
                 f"max |LSQ - FFT| over A_i, B_i = {_fmt(dmax, '.3f')} arcsec")
        clos = h.groupby("run", sort=True)["closure_arcsec"].first()
        L += _wrap("     closure (last reading - first, same face), arcsec: "
                   + "  ".join(f"run {int(r)}: {_fmt(float(c), '+.2f')}" for r, c in clos.items()))
    N = _n_distinct(inputs[modules[0]])
    L.append(f"   LSQ uses all readings (the closing one weights face 0 twice); the FFT the {N}")
    L.append("   distinct angles, so they differ slightly; the closure is a repeatability check.")
    L.append("")
    L.append("4. Sampling")
    L.append(f"   The polygon gives N = {N} distinct angles per turn; the closing reading revisits")
    L.append(f"   the first face (closure check, not a new angle). The paper counted N = {PAPER_N}.")
    L.append(f"   Highest resolvable order N/2 = {N // 2} (cosine only); both terms up to {(N - 1) // 2}.")
    text_page(pdf, "Encoder report: this run's numbers beside the paper's (Hu et al. 2020)", L, fontsize=7.6)


def _summary(pdf, inputs):
    """Page 1: p2p before / after / reduction of each module's held-out run beside the paper's (typeset),
    and each held-out run's error before and after compensation against the joint angle."""
    modules = list(inputs)
    header = ["module", "held-out\nrun", "p2p before\n(arcsec)", "p2p after\n(arcsec)", "reduction\n(%)",
              "paper before\n(arcsec)", "paper after\n(arcsec)", "paper\nreduction (%)", "harmonic orders\nin the model"]
    rows, ours = [], []
    for m in modules:
        mod = inputs[m]["model"]
        p = PAPER.get(m, {})
        rows.append([m, ",".join(str(r) for r in mod.get("validation_runs", [])), f"{mod['p2p_before_arcsec']:.2f}",
                     f"{mod['p2p_after_arcsec']:.2f}", f"{mod['reduction_pct']:.2f}", _fmt(p.get("p2p_before")),
                     _fmt(p.get("p2p_after")), _fmt(p.get("reduction")), _orders_str(mod.get("orders"))])
        ours.append(mod["reduction_pct"])
    rows.append(["average", "", "", "", f"{np.mean(ours):.2f}", "", "", f"{PAPER_AVERAGE_REDUCTION:.2f}", ""])
    notes = [f"Module {m}: selected orders {_orders_str(inputs[m]['model'].get('orders'))}; the paper's "
             f"{_orders_str(PAPER[m]['orders'])}." for m in modules if m in PAPER]

    def draw(fig, rect):
        left, bottom, width, height = rect
        gs = fig.add_gridspec(len(modules), 1, left=left, right=left + width, bottom=bottom, top=bottom + height,
                              hspace=0.45)
        for k, m in enumerate(modules):
            ax = fig.add_subplot(gs[k, 0])
            mod = inputs[m]["model"]
            for v in mod.get("validation", []):
                x = _unwrap_deg(v["theta_deg"])
                before = np.asarray(v["error_arcsec"], float)
                after = before - np.asarray(v["model_arcsec"], float)
                ax.plot(x, before, "-o", ms=2.5, lw=1, color="tab:blue", label=f"run {v['run']} before")
                ax.plot(x, after, "-o", ms=2.5, lw=1, color="tab:orange", label=f"run {v['run']} after")
            ax.set_title(f"module {m}: held-out run {_orders_str(mod.get('validation_runs', []))}, "
                         f"p2p {mod['p2p_before_arcsec']:.2f} → {mod['p2p_after_arcsec']:.2f}″", fontsize=9, loc="left")
            ax.set_xlabel("joint angle θ (deg)")
            ax.set_ylabel("angle error (arcsec)")
            ax.set_xlim(-5, 365)
            ax.set_xticks(np.arange(0, 361, 30))
            if ax.get_legend_handles_labels()[1]:
                ax.legend(loc="upper right", ncol=2, fontsize=7)

    summary_page(pdf, "Joint modules: angle error before and after compensation", " ".join(DATA_NOTE)
                 + " Held-out run: not used in the fit (first paper, Hu et al. 2020, section 4.2).", header, rows, draw,
                 "What remains after compensation (orange) is what the harmonic model misses: a pattern repeating "
                 "around the turn is a harmonic order it left out, a step or drift is not periodic. Figures 4-9 of the "
                 "paper follow; the numbers in full are in the appendix.", notes=notes, align=["l"] + ["r"] * 7 + ["l"],
                 table_fontsize=8.0)


def _fig4(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 4 (paper): original angle error of the joint modules")
    for k, (m, ax) in enumerate(zip(modules, axes)):
        valid = set(inputs[m]["model"].get("validation_runs", []))
        for j, (r, g) in enumerate(_runs_sorted(inputs[m]["readings"])):
            x = _unwrap_deg(g["theta_deg"].to_numpy())
            label = f"run {r}" + (" (validation)" if r in valid else "")
            ax.plot(x, g["error_arcsec"].to_numpy(), "-o", ms=3, lw=1.0, color=RUN_COLORS[j % 10], label=label)
        _panel_title(ax, k, m, "every run, error relative to its first reading")
        ax.set_xlabel("joint angle θ (deg)")
        ax.set_ylabel("angle error (arcsec)")
        ax.set_xlim(-5, 365)
        ax.set_xticks(np.arange(0, 361, 30))
        _pad_ylim(ax, [inputs[m]["readings"]["error_arcsec"].to_numpy(float)], top=0.2, bottom=0.05)
        ax.legend(ncol=3, loc="upper right")
    _finish(fig, "Every run repeats the same pattern around the turn: the joint's own periodic error, which the "
                 "harmonic model fits; run to run scatter is the noise.")
    save(pdf, fig)


def _fig5(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 5 (paper): harmonic characteristic of each modelling run")
    for k, (m, ax) in enumerate(zip(modules, axes)):
        h = inputs[m]["harmonics"]
        runs = _modelling_runs(inputs[m])
        orders = np.sort(h["order"].unique())
        width = 0.8 / max(len(runs), 1)
        for j, r in enumerate(runs):
            g = h[h["run"] == r].set_index("order").reindex(orders)
            off = (j - (len(runs) - 1) / 2) * width
            ax.bar(orders + off, g["C"].abs().to_numpy(), width=width, color=RUN_COLORS[j % 10], label=f"run {r}")
        _panel_title(ax, k, m, f"amplitude C_i per order, runs {_orders_str(runs)}")
        ax.set_xlabel("harmonic order i  (order 0: |C_0|)")
        ax.set_ylabel("amplitude C_i (arcsec)")
        ax.set_xticks(orders)
        ax.legend(ncol=len(runs), loc="upper left")
    _finish(fig, "Orders whose amplitude is large in every run are the joint's; small, varying ones are noise.")
    save(pdf, fig)


def _fig6(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 6 (paper): harmonic amplitude-order diagram")
    for k, (m, ax) in enumerate(zip(modules, axes)):
        sel = inputs[m]["selection"]
        t = pd.DataFrame(sel["table"]).sort_values("order")
        th = sel.get("thresholds", {})
        kept = t["kept"].to_numpy(bool)
        colors = np.where(kept, "tab:red", "0.65")
        ax.bar(t["order"], t["mean_C_arcsec"], color=colors, width=0.7)
        handles = [Patch(color="tab:red", label="kept (paper rule, this run)"), Patch(color="0.65", label="dropped")]
        strong, low = th.get("amplitude_strong_arcsec"), th.get("amplitude_min_arcsec")
        if strong is not None:
            ax.axhline(strong, color="k", ls="--", lw=1, label=f"strong: ≥ {strong:g} arcsec (kept)")
        if low is not None:
            ax.axhline(low, color="k", ls=":", lw=1,
                       label=f"prominent: ≥ {low:g} arcsec (kept if phase range ≤ {th.get('phase_range_max_deg', '?'):g} deg)")
        paper = _paper_terms(m)
        if paper:
            ax.plot(list(paper), [abs(c) for c, _ in paper.values()], "kD", ms=4, mfc="none",
                    label="paper Eq. 7/8 amplitude")
        for o, c, kk in zip(t["order"], t["mean_C_arcsec"], kept):
            if kk:
                ax.annotate(f"{c:.1f}", (o, c), textcoords="offset points", xytext=(0, 3), ha="center", fontsize=7)
        _panel_title(ax, k, m, f"mean amplitude over runs {_orders_str(_modelling_runs(inputs[m]))}")
        ax.set_xlabel("harmonic order i  (order 0: |C_0|)")
        ax.set_ylabel("mean amplitude C_i (arcsec)")
        ax.set_xticks(t["order"])
        ax.set_ylim(0, max(t["mean_C_arcsec"].max(), max((abs(c) for c, _ in paper.values()), default=0)) * 1.3)
        h0, _ = ax.get_legend_handles_labels()
        ax.legend(handles=handles + h0, loc="upper center", ncol=2)
    _finish(fig, "Red bars: the orders the paper's rule keeps (strong, or prominent with a stable phase); grey: dropped.")
    save(pdf, fig)


def _fig7(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 7 (paper): phase of each order over the modelling runs")
    for k, (m, ax) in enumerate(zip(modules, axes)):
        sel = inputs[m]["selection"]
        th = sel.get("thresholds", {})
        limit = th.get("phase_range_max_deg")
        t = pd.DataFrame(sel["table"]).sort_values("order").set_index("order")
        h = inputs[m]["harmonics"]
        runs = _modelling_runs(inputs[m])
        hm = h[h["run"].isin(runs)]
        orders = np.sort(hm["order"].unique())
        for o in orders:
            g = hm[hm["order"] == o].sort_values("run")
            phi = g["phi_deg"].to_numpy(float)
            dev = _wrap180(phi - circular_mean_deg(phi))
            stable = bool(t.loc[o, "stable"]) if o in t.index else False
            kept = bool(t.loc[o, "kept"]) if o in t.index else False
            if stable:
                ax.axvspan(o - 0.45, o + 0.45, color="tab:green", alpha=0.12, lw=0)
            ax.vlines(o, dev.min(), dev.max(), color="tab:red" if kept else "0.5", lw=3 if kept else 1.5)
            for j, (r, d) in enumerate(zip(g["run"], dev)):
                ax.plot(o, d, "o", ms=3.5, color=RUN_COLORS[runs.index(int(r)) % 10])
            rng = float(t.loc[o, "phase_range_deg"]) if o in t.index else np.nan
            ax.text(o, 188, f"{rng:.0f}", ha="center", va="bottom", fontsize=7,
                    color="tab:red" if kept else "0.3", weight="bold" if kept else "normal")
        for j, r in enumerate(runs):
            ax.plot([], [], "o", ms=3.5, color=RUN_COLORS[j % 10], label=f"run {r}")
        ax.plot([], [], "-", lw=3, color="tab:red", label="kept order (range bar)")
        ax.fill_between([], [], [], color="tab:green", alpha=0.25, label=f"stable: range ≤ {limit:g} deg" if limit else "stable")
        if limit:
            for s in (-1, 1):
                ax.axhline(s * limit / 2, color="k", ls=":", lw=0.8)
        _panel_title(ax, k, m, "phase φ_i minus its circular mean; numbers on top: phase range (deg)")
        ax.set_xlabel("harmonic order i  (order 0: φ = 90 for C_0 > 0, 270 for C_0 < 0)")
        ax.set_ylabel("φ_i − circular mean (deg)")
        ax.set_xticks(orders)
        ax.set_xlim(orders.min() - 0.6, orders.max() + 0.6)
        ax.set_ylim(-185, 212)
        ax.set_yticks(np.arange(-180, 181, 45))
        ax.legend(ncol=4, loc="lower left", fontsize=7, framealpha=0.95)
    _finish(fig, "An order whose phase stays put over the runs (a narrow range) is a real error term; a scattered "
                 "phase is noise.", h_pad=3)
    save(pdf, fig)


def _fig8(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 8 (paper): curve of the angle error model and error scatter")
    grid = np.arange(0.0, 360.0 + 1e-9, 0.25)
    for k, (m, ax) in enumerate(zip(modules, axes)):
        runs = _modelling_runs(inputs[m])
        rd = inputs[m]["readings"]
        ys = [rd.loc[rd["run"].isin(runs), "error_arcsec"].to_numpy(float)]
        for j, (r, g) in enumerate(_runs_sorted(rd[rd["run"].isin(runs)])):
            ax.plot(_unwrap_deg(g["theta_deg"].to_numpy()), g["error_arcsec"].to_numpy(), "o", ms=3,
                    color=RUN_COLORS[j % 10], alpha=0.8, label=f"run {r} readings")
        model = model_from_result(inputs[m]["model"])
        ys.append(model.predict_theta(grid))
        ax.plot(grid, ys[-1], "-", color="k", lw=1.4,
                label=f"model, this run (orders {_orders_str(inputs[m]['model']['orders'])})")
        paper = _paper_curve(m, grid)
        if paper is not None:
            ax.plot(grid, paper, "--", color="tab:red", lw=1.0, label="paper Eq. 7/8" if len(modules) > 1 else "paper")
        _panel_title(ax, k, m, f"model fitted on runs {_orders_str(runs)}")
        ax.set_xlabel("joint angle θ (deg)")
        ax.set_ylabel("angle error (arcsec)")
        ax.set_xlim(-5, 365)
        ax.set_xticks(np.arange(0, 361, 30))
        _pad_ylim(ax, ys, top=0.3, bottom=0.05)
        ax.legend(ncol=3, loc="upper center", fontsize=7)
    _finish(fig, "The fitted model should follow the readings of every modelling run; the paper's model is drawn beside it.")
    save(pdf, fig)


def _fig9(pdf, inputs):
    modules = list(inputs)
    fig, axes = _panel_figure(modules, "Figure 9 (paper): held-out run before and after compensation")
    for k, (m, ax) in enumerate(zip(modules, axes)):
        mod = inputs[m]["model"]
        p = PAPER.get(m, {})
        ys = []
        for v in mod.get("validation", []):
            x = _unwrap_deg(v["theta_deg"])
            before = np.asarray(v["error_arcsec"], float)
            after = before - np.asarray(v["model_arcsec"], float)
            ys += [before, after]
            ax.plot(x, before, "-o", ms=3, lw=1, color="tab:blue",
                    label=f"run {v['run']} before: p2p {v['p2p_before_arcsec']:.2f} arcsec")
            ax.plot(x, after, "-o", ms=3, lw=1, color="tab:orange",
                    label=f"run {v['run']} after: p2p {v['p2p_after_arcsec']:.2f} arcsec")
        note = [f"this run: {mod['p2p_before_arcsec']:.2f} → {mod['p2p_after_arcsec']:.2f} arcsec, "
                f"{mod['reduction_pct']:.2f} % less"]
        if p:
            note.append(f"paper:    {p['p2p_before']:.2f} → {p['p2p_after']:.2f} arcsec, {p['reduction']:.2f} % less")
        ax.text(0.99, 0.02, "\n".join(note), transform=ax.transAxes, ha="right", va="bottom", family="monospace",
                fontsize=7.5, bbox=dict(boxstyle="round", fc="white", ec="0.6", alpha=0.9))
        _panel_title(ax, k, m, f"validation run {_orders_str(mod.get('validation_runs', []))} (not used in the fit)")
        ax.set_xlabel("joint angle θ (deg)")
        ax.set_ylabel("angle error (arcsec)")
        ax.set_xlim(-5, 365)
        ax.set_xticks(np.arange(0, 361, 30))
        _pad_ylim(ax, ys, top=0.22, bottom=0.2)
        ax.legend(loc="upper left")
    _finish(fig, "Orange, the held-out run after compensation, should be flat: what remains is what the model misses.")
    save(pdf, fig)


def _terms_page(pdf, inputs):
    L = ["Model: error(θ) = C_0 + Σ C_i sin(i θ + φ_i); C in arcsec, φ in deg.",
         "This run: amplitude averaged and phase averaged on the circle over the modelling runs",
         "(paper, section 4.2). Δφ wrapped to (-180, 180]. '—': term absent on that side.", ""]
    for m in inputs:
        ours = {int(t["order"]): (float(t["C_arcsec"]), float(t["phi_deg"])) for t in inputs[m]["model"]["terms"]}
        paper = _paper_terms(m)
        L.append(f"Joint module {m}  ({'paper: Eq. 7' if m == 'a' else 'paper: Eq. 8' if m == 'b' else 'not in the paper'})")
        L.append(f"  {'order':>5} | {'C this':>8} {'φ this':>8} | {'C paper':>8} {'φ paper':>8} | {'ΔC':>7} {'Δφ':>7}")
        L.append("  " + "-" * 67)
        for o in sorted(set(ours) | set(paper)):
            c1, p1 = ours.get(o, (None, None))
            c2, p2 = paper.get(o, (None, None))
            dc = c1 - c2 if c1 is not None and c2 is not None else None
            dp = float(_wrap180(p1 - p2)) if p1 is not None and p2 is not None and o != 0 else None
            ph1 = "" if o == 0 and p1 is not None else _fmt(p1)
            ph2 = "" if o == 0 and p2 is not None else _fmt(p2)
            L.append(f"  {o:>5} | {_fmt(c1):>8} {ph1:>8} | {_fmt(c2):>8} {ph2:>8} | "
                     f"{_fmt(dc, '+.2f'):>7} {_fmt(dp, '+.2f'):>7}")
        only_here = sorted(set(ours) - set(paper))
        only_paper = sorted(set(paper) - set(ours))
        if only_here or only_paper:
            L.append(f"  only in this run: {_orders_str(only_here) or '—'};  only in the paper: {_orders_str(only_paper) or '—'}")
        if 0 in ours or 0 in paper:
            L.append("  Order 0 is the mean of the runs' constants; each run's error is zeroed at its")
            L.append("  first reading, so C_0 ≈ −(periodic error at the start angle) and does not change p2p.")
        L.append("")
    text_page(pdf, "Fitted model terms beside the paper's Eqs. 7/8", L, fontsize=8.5)


def _aliasing_page(pdf, inputs):
    tables = {}
    for m in inputs:
        t = pd.read_csv(inputs[m]["aliasing"], dtype=str, keep_default_na=False)
        tables[m] = t
    groups = {}
    for m, t in tables.items():
        groups.setdefault(t.to_csv(index=False), []).append(m)
    L = []
    for _, ms in groups.items():
        t = tables[ms[0]]
        N = int(t["N_distinct"].iloc[0]) if "N_distinct" in t and len(t) else _n_distinct(inputs[ms[0]])
        L.append(f"Module(s) {', '.join(ms)}: N = {N} distinct angles per run.")
        L.append(f"  Each run has {N + 1} readings: the last revisits the first face, so it is a closure")
        L.append(f"  check, not a new angle. The paper used N = {PAPER_N} (its Eq. 4: a17 = A17 + A20 + ...);")
        L.append(f"  with N = {N}, order j folds onto |j mod N| (folded into 0..{N // 2}): a_i gets A_(kN±i),")
        L.append("  b_i gets +B_(kN+i) and −B_(kN−i). Sources listed up to order 100.")
        L.append("")
        L.append(f"  {'i':>2}  {'folds in from (cos)':<21} equation (Eq. 4 style)")
        for _, row in t.iterrows():
            eq = row["equation"].split(";  ")
            L.append(f"  {row['order']:>2}  {row['folds_from']:<21} {eq[0]}")
            for e in eq[1:]:
                L.append(f"  {'':>2}  {'':<21} {e}")
        if N % 2 == 0:
            L.append(f"  Note: order {N // 2} = N/2 has no sine term (sin({N // 2}θ) is 0 at every sample), so a")
            L.append(f"  b{N // 2} line above, if any, is an artefact of the table; only a{N // 2} is estimable.")
        L.append("")
    text_page(pdf, "Aliasing of harmonic orders (paper Eqs. 3-4)", L, fontsize=8)


# ------------------------------------------------------------------------------- entry
def encoder_report(inputs: dict, out) -> None:
    """Write the encoder report PDF.

    Parameters
    ----------
    inputs : dict
        ``{module: {"readings", "harmonics", "selection", "model", "aliasing"}}`` as built by
        ``jointcal report``: the ingested readings and per-run harmonics (DataFrames), the
        selection and model JSON (dicts) and the aliasing CSV (path).
    out : path
        PDF to write (atomically; same inputs give the same bytes).
    """
    inputs = {m: inputs[m] for m in sorted(inputs)}
    with pdf_pages(out, "jointcal encoder report: Figures 4-9 of Hu et al. (2020)") as pdf:
        _summary(pdf, inputs)
        _numbers_page(pdf, inputs)
        _fig4(pdf, inputs)
        _fig5(pdf, inputs)
        _fig6(pdf, inputs)
        _fig7(pdf, inputs)
        _fig8(pdf, inputs)
        _fig9(pdf, inputs)
        _terms_page(pdf, inputs)
        _aliasing_page(pdf, inputs)
