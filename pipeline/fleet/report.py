"""``reports/fleet.pdf``: the fleet's reductions, its out-of-family units, its missing effects."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.ticker import FuncFormatter

from ..core.plotting import caption, pdf_pages, plt, save, summary_page, text_page
from .engine import FAMILY_MEASURE, MIN_UNITS_FOR_FAMILY

#: the first paper's held-out peak-to-peak reductions (Eqs. 7, 8: modules a and b)
PAPER_REDUCTIONS = {"encoder": (82.20, 81.85), "robot": (75.0,)}


def fleet_report(table: pd.DataFrame, summary: dict, out, spec_path: str, z_out: float) -> None:
    """Write the fleet report.

    Parameters
    ----------
    table : DataFrame
        ``fleet.parquet`` (one row per unit; see :data:`pipeline.fleet.engine.COLUMNS`).
    summary : dict
        :func:`pipeline.fleet.engine.fleet_summary` of the table.
    """
    ok = table[table["status"] == "ok"]
    kind = str(table["kind"].iloc[0]) if len(table) else "encoder"
    unit = str(ok["unit_of_error"].iloc[0]) if len(ok) else ""
    measure = str(ok["measure"].iloc[0]) if len(ok) else ""
    flagged = ok[ok["out_of_family"]]
    with pdf_pages(out, "jointcal fleet report") as pdf:
        # page 1: the fleet in words and numbers
        red = summary["reduction_pct"]
        lines = [f"{summary['units']} {kind} units with {spec_path}: {summary['ok']} calibrated, "
                 f"{summary['bad_input']} refused (bad input), {summary['failed']} failed", ""]
        if red["median"] is not None:
            lines += [f"reduction of the {measure}: median {red['median']:.1f} %, 10th percentile {red['p10']:.1f} %, "
                      f"worst {red['min']:.1f} %  (paper: {', '.join(f'{p:.2f} %' for p in PAPER_REDUCTIONS[kind])})",
                      f"held-out RMS after compensation: median {ok['heldout_rms'].median():.3g} {unit}; "
                      f"cross-validated RMS: median {ok[FAMILY_MEASURE].median():.3g} {unit}", ""]
        if summary["family_judged"]:
            lines += [f"Out of family (cross-validated RMS more than {z_out:g} robust standard deviations above the "
                      f"median, log scale): {len(flagged)} unit(s)"]
        else:
            lines += [f"Out of family: not judged, {summary['ok']} unit(s) calibrated (a family needs {MIN_UNITS_FOR_FAMILY})"]
        for _, r in flagged.sort_values("robust_z", ascending=False).iterrows():
            lines.append(f"  {r['unit']}: {r['why_flagged']}")
        lines += ["", "Effects the diagnosis finds missing, across the fleet (units where the effect is meaningful):"]
        eff = pd.DataFrame(summary["effects"])
        if len(eff):
            for _, e in eff.iterrows():
                lines.append(f"  {e['effect']:<22s} {int(e['units']):5d} units  ({e['share_pct']:.0f} %)")
        else:
            lines.append("  none: the spec's model explains every unit down to its noise")
        bad = table[table["status"] != "ok"]
        if len(bad):
            lines += ["", "Units that did not run:"] + [f"  {r['unit']}: {r['status']}: {r['error']}" for _, r in bad.iterrows()]
        _summary(pdf, table, summary, ok, flagged, eff, kind, unit, measure, spec_path)
        text_page(pdf, "Fleet: calibration of many units with one spec", lines, fontsize=8)
        if not len(ok):
            return

        # page 2: distribution of reductions and of held-out residuals
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8.27, 11.69 * 0.8))
        r = ok["reduction_pct"].to_numpy(float)
        ax1.hist(r, bins=_bins(r, 30), color="tab:blue", alpha=0.8)
        for p in PAPER_REDUCTIONS[kind]:
            ax1.axvline(p, color="k", ls="--", lw=1)
        ax1.text(min(PAPER_REDUCTIONS[kind]), ax1.get_ylim()[1] * 0.97, "paper ", va="top", ha="right", fontsize=8)
        ax1.set_xlabel(f"reduction of the {measure} (%)")
        ax1.set_ylabel("units")
        ax1.set_title(f"Distribution of reductions over {len(ok)} units")
        res = ok[FAMILY_MEASURE].to_numpy(float)
        bins = np.geomspace(res.min() * 0.9, res.max() * 1.1, 30)
        ax2.hist(res[~ok["out_of_family"].to_numpy(bool)], bins=bins, color="tab:green", alpha=0.8, label="in family")
        if len(flagged):
            ax2.hist(flagged[FAMILY_MEASURE].to_numpy(float), bins=bins, color="tab:red", label="out of family")
        med = float(np.exp(np.median(np.log(res))))
        ax2.axvline(med, color="k", lw=1, label=f"median {med:.3g} {unit}")
        limit = _limit(ok, z_out)
        if limit is not None:
            ax2.axvline(limit, color="tab:red", ls="--", lw=1, label=f"out-of-family limit {limit:.3g} {unit}")
        for _, f in flagged.iterrows():
            ax2.annotate(f["unit"], (f[FAMILY_MEASURE], 0.5), rotation=90, fontsize=7, va="bottom")
        ax2.set_xscale("log")
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        ax2.xaxis.set_major_formatter(plain)
        ax2.xaxis.set_minor_formatter(plain)
        ax2.set_xlabel(f"cross-validated RMS residual ({unit}, log scale): each run / fold predicted by a model "
                       "fitted without it")
        ax2.set_ylabel("units")
        ax2.set_title("Residuals across the fleet: out-of-family units flagged")
        ax2.legend(loc="upper right")
        fig.tight_layout(rect=(0, 0.04, 1, 1))
        caption(fig, "Top: the paper's reductions (dashed) against the fleet's; bottom: a unit far right of the "
                     "family is flagged (red) and named.")
        save(pdf, fig)

        # page 3: the missing effects (every unit's before and after is page 1's picture, not repeated here)
        fig, ax2 = plt.subplots(1, 1, figsize=(8.27, 11.69 * 0.8))      # the size of page 2
        if len(eff):
            top = eff.head(15).iloc[::-1]
            ax2.barh(top["effect"], top["units"], color="tab:purple")
            for y, (n, s) in enumerate(zip(top["units"], top["share_pct"])):
                ax2.text(n, y, f" {n} ({s:.0f} %)", va="center", fontsize=8)
            ax2.set_xlim(0, top["units"].max() * 1.25)
        else:
            ax2.text(0.5, 0.5, "no unit lacks an effect the diagnosis can show", ha="center", transform=ax2.transAxes)
        ax2.set_xlabel(f"units whose diagnosis finds the effect missing (of {len(ok)})")
        ax2.set_title("Effects the diagnosis finds most often (add them to the spec)")
        fig.tight_layout(rect=(0, 0.05, 1, 1))
        caption(fig, "An effect missing on many units is a design or batch defect, worth adding to the spec; one "
                     "missing on a few is those units' own (their diagnosis, in the appendix).")
        save(pdf, fig)


def _before_after(ax, ok, flagged, measure, unit):
    """Every calibrated unit: its error before against after compensation (held out), flagged ones named."""
    inf = ok[~ok["out_of_family"]]
    ax.scatter(inf["before"], inf["after"], s=12, color="tab:blue", label="in family")
    if len(flagged):
        ax.scatter(flagged["before"], flagged["after"], s=24, color="tab:red", marker="x", label="out of family")
        for _, f in flagged.iterrows():
            ax.annotate(f["unit"], (f["before"], f["after"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    lo, hi = 0.0, float(np.nanmax(ok["before"])) * 1.05
    for share in (0.1, 0.2, 0.3):
        ax.plot([lo, hi], [lo, hi * share], color="grey", lw=0.7, ls=":")
        ax.text(0.4 * hi, 0.4 * hi * share, f"{100 * (1 - share):.0f} % less", fontsize=7, va="bottom", ha="center",
                color="0.35")
    ax.set_xlabel(f"{measure} before ({unit})")
    ax.set_ylabel(f"after compensation ({unit})")
    ax.set_title("Every unit: before and after (held out)")
    ax.legend(loc="upper left")


def _summary(pdf, table, summary, ok, flagged, eff, kind, unit, measure, spec_path):
    """Page 1: the fleet's headline numbers (typeset) and every unit's before / after, flagged ones named."""
    red = summary["reduction_pct"]
    f1 = lambda v: "—" if v is None else f"{v:.1f}"  # noqa: E731
    header = ["units", "cali-\nbrated", "refused", "failed", "median\nreduction (%)", "10th percentile\nreduction (%)",
              "worst\nreduction (%)", "paper\nreduction (%)", f"median held-out\nRMS ({unit})", "out of\nfamily"]
    rows = [[str(summary["units"]), str(summary["ok"]), str(summary["bad_input"]), str(summary["failed"]),
             f1(red["median"]), f1(red["p10"]), f1(red["min"]), ", ".join(f"{p:.2f}" for p in PAPER_REDUCTIONS[kind]),
             f"{ok['heldout_rms'].median():.3g}" if len(ok) else "—",
             str(len(flagged)) if summary["family_judged"] else "not judged"]]
    notes = []
    if len(flagged):
        worst = flagged.sort_values("robust_z", ascending=False)
        notes.append("Out of family: " + ", ".join(worst["unit"].astype(str).head(8))
                     + (" ..." if len(worst) > 8 else "") + " (why: appendix).")
    if len(eff):
        notes.append("Missing most often: " + ", ".join(f"{e['effect']} ({int(e['units'])} units)"
                                                       for _, e in eff.head(3).iterrows()) + ".")

    def draw(fig, rect):
        ax = fig.add_axes(rect)
        if len(ok):
            _before_after(ax, ok, flagged, measure, unit)
        else:
            ax.set_axis_off()
            ax.text(0.5, 0.5, "no unit calibrated", ha="center", va="center", transform=ax.transAxes)

    summary_page(pdf, f"Fleet: {summary['units']} {kind} units calibrated with one spec",
                 f"Spec {spec_path}; every unit calibrated and judged on its own held-out data ({measure}).", header,
                 rows, draw, "Each point is one unit; the dotted lines mark 70, 80 and 90 % less error. Units above "
                 "the cloud gained less than the family: they are flagged and named, and their diagnosis says what "
                 "they lack.", notes=notes, align=["r"] * len(header), table_fontsize=8.0)


def _bins(x, n):
    lo, hi = float(np.min(x)), float(np.max(x))
    return np.linspace(lo - 0.5, hi + 0.5, n) if hi - lo < 1 else n


def _limit(ok, z_out):
    """The held-out RMS at which robust z reaches ``z_out`` (None when undefined)."""
    z = ok["robust_z"].to_numpy(float)
    logr = np.log(ok[FAMILY_MEASURE].to_numpy(float))
    good = np.isfinite(z)
    if good.sum() < 2:
        return None
    med = float(np.median(logr))
    mad = float(np.median(np.abs(logr - med)))
    return float(np.exp(med + z_out * mad / 0.6745)) if mad > 0 else None
