"""Diagnosis report (``jointcal diagnose --report PDF``): where the model fails, and why.

Generic over the domain adapter (encoder: d = 1 residual in arcsec; robot: d = 3 residual
x, y, z in mm). Deterministic bytes (see :mod:`pipeline.core.plotting`).

Pages
-----
1. At a glance: every campaign's baseline (its spec's effects) and top candidates as a typeset
   table (cross-validated RMS with unit, gain, p, verdict), and each campaign's waterfall: the
   held-out RMS as each effect of the spec is added in turn, then the top meaningful candidate.
Then, per campaign:
2. Held-out residuals of the baseline against every signature variable the adapter names,
   one small panel each, with a binned mean (continuous) or per-category means with
   standard-error bars (categorical); every "angle" variable also gets a residual spectrum
   (amplitude of orders 1..17 from one least-squares fit against the angle). For d = 3
   the norm |r| is drawn as points and the signed x, y, z components as binned means.
   Nine panels a page; more pages when the adapter names more variables.
   Then each recommended (meaningful) effect next to the residual it explains: the baseline's
   held-out residual against the signature variable whose pattern the effect removes most, and
   the same with the effect added (:func:`explained_signature`).
3. Candidates: gain (%) of each candidate, meaningful ones highlighted, with the
   thresholds (min gain, Bonferroni p).
4. Waterfall, full size.
Appendix (last): the summary as text: the candidate table, for every meaningful candidate the
evidence, explanation and the ``[[effect]]`` lines to paste into the spec, the refused ones and
the effects these data cannot reveal, with the reasons.
"""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..core.plotting import caption, fit_text, pdf_pages, plt, save, summary_page, text_page, title_on_page
from .engine import done_text, label, target_text, verified_text, waterfall

A4 = (8.27, 11.69)
MAX_ORDER = 17
PANELS_PER_PAGE = 9          # 3 x 3 grid on an A4 page
SUMMARY_FONTSIZE = 8                 # the summary's text pages (the appendix), pt
MAX_BARS = 30                        # candidates drawn on the candidates page (every one: the appendix)
SUMMARY_WIDTH = 100
COMPONENT_COLORS = ("tab:red", "tab:green", "tab:purple")
MEAN_COLOR = "black"
HIGHLIGHT = "tab:blue"
GREY = "0.75"
MODEL_COLOR = "tab:orange"


# ------------------------------------------------------------------------------ helpers
def _fmt_target(target) -> str:
    return "-" if target is None else str(target)


#: characters of a campaign's name a figure title keeps (a user's deep folder: its last ones)
NAME_CHARS = 40


def _short(name: str) -> str:
    """``name``, or its last ``NAME_CHARS`` characters after "..." (a title must fit its page)."""
    name = str(name)
    return name if len(name) <= NAME_CHARS else "..." + name[-(NAME_CHARS - 3):]


def _label(c) -> str:
    """``direction``, ``harmonic order 13``, ``backlash joint 2``, ``joint_harmonic joint 3 order 8``
    (contract: target is the order of a harmonic, else the 1-based joint)."""
    return label(c)


def _effect_label(e) -> str:
    """An effect with its parameters, e.g. ``harmonic orders=[1, 4, 8]``."""
    params = getattr(e, "params", {}) or {}
    extra = " ".join(f"{k}={v}" for k, v in sorted(params.items()))
    return f"{e.name} {extra}".rstrip()


def _residual_parts(residuals):
    """(magnitude, components): magnitude is r itself for d = 1 and |r| for d > 1."""
    r = np.asarray(residuals, float)
    r = r.reshape(r.shape[0], -1)
    if r.shape[1] == 1:
        return r[:, 0], None
    return np.sqrt(np.sum(r ** 2, axis=1)), r


def _component_names(d):
    return ("x", "y", "z") if d == 3 else tuple(f"r{k + 1}" for k in range(d))


def _bins(x, max_unique=60, n_bins=12):
    """Group indices for a binned mean: one group per distinct value when there are few,
    else quantile bins. Returns (centres, list of index arrays)."""
    ok = np.isfinite(x)
    xv = x[ok]
    idx_all = np.flatnonzero(ok)
    if xv.size == 0:
        return np.array([]), []
    uniq = np.unique(np.round(xv, 6))
    if uniq.size <= max_unique:
        groups = [idx_all[np.round(xv, 6) == u] for u in uniq]
        return uniq, groups
    edges = np.unique(np.quantile(xv, np.linspace(0, 1, n_bins + 1)))
    which = np.clip(np.searchsorted(edges, xv, side="right") - 1, 0, edges.size - 2)
    centres, groups = [], []
    for b in range(edges.size - 1):
        g = idx_all[which == b]
        if g.size:
            centres.append(float(np.mean(x[g])))
            groups.append(g)
    return np.array(centres), groups


def _mean_se(y, groups):
    m = np.array([np.mean(y[g]) for g in groups])
    se = np.array([np.std(y[g], ddof=1) / np.sqrt(g.size) if g.size > 1 else 0.0 for g in groups])
    return m, se


def residual_spectrum(angle_deg, residuals, max_order=MAX_ORDER, noise=False):
    """Amplitude of orders 1..max_order in the residual against an angle (one LSQ fit).

    For d > 1 the amplitudes of the components are combined as a root sum of squares.
    Orders the distinct angles cannot resolve are left out. Returns (orders, amplitude),
    and with ``noise=True`` also the RMS amplitude white noise of the fit's residual scatter
    would show at each order (a guide: peaks well above it are signal).
    """
    th = np.radians(np.asarray(angle_deg, float))
    r = np.asarray(residuals, float).reshape(th.size, -1)
    ok = np.isfinite(th) & np.all(np.isfinite(r), axis=1)
    th, r = th[ok], r[ok]
    n_distinct = np.unique(np.round(np.degrees(th) % 360.0, 2)).size
    top = int(min(max_order, (n_distinct - 1) // 2))
    if top < 1:
        return (np.arange(0), np.zeros(0)) + ((np.zeros(0),) if noise else ())
    orders = np.arange(1, top + 1)
    X = np.column_stack([np.ones_like(th)] + [f(i * th) for i in orders for f in (np.cos, np.sin)])
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    A, B = coef[1::2], coef[2::2]
    amp = np.sqrt(np.sum(A ** 2 + B ** 2, axis=1))
    if not noise:
        return orders, amp
    dof = max(1, th.size - X.shape[1])
    s2 = np.sum((r - X @ coef) ** 2, axis=0) / dof                      # per component
    cov = np.linalg.pinv(X.T @ X)
    var_ab = np.diag(cov)[1::2] + np.diag(cov)[2::2]
    return orders, amp, np.sqrt(var_ab * np.sum(s2))


# ------------------------------------------------------------------------------ page 1
def wild_lines(result, wrap) -> list[str]:
    """The wild measurements named (contract section 12), one line each; [] when there are none."""
    wild = result.get("outliers") or []
    if not wild:
        return []
    kept = (result.get("outlier_rule") or {}).get("kept")
    out = [f"Wild measurements ({len(wild)}): " + ("kept in the fit (--keep-outliers)" if kept else
                                                   "left out of the fit and of every cross-validation")]
    for o in wild:
        out += wrap(f"- {o['point_id']} ({o['set']}, tracker.csv line {o['line']}): {o['error_mm']:.3f} mm off")
    rule = (result.get("outlier_rule") or {}).get("rule")
    if rule:
        out += wrap(f"rule: {rule}")
    return out + [""]


def summary_lines(result, base_effects=None, width=SUMMARY_WIDTH):
    """The summary page's lines (plain text, wrapped to ``width``)."""
    b = result["baseline"]
    unit = b["unit"]
    th = result.get("thresholds", {})
    wrap = lambda s, ind="   ": textwrap.wrap(str(s), width, initial_indent=ind, subsequent_indent=ind + "  ") or [ind]
    lines = ["Baseline model (the spec's effects):"]
    if base_effects:
        for e in base_effects:
            lines += wrap(_effect_label(e))
    else:
        lines += wrap(" + ".join(b["effects"]) or "nothing")
    lines += [f"Cross-validated RMS: {b['cv_rms']:.4g} {unit}   ({b.get('folds', 'held-out folds')})", ""]
    lines += wild_lines(result, wrap)
    if th:
        lines += wrap(f"A candidate is meaningful when its gain >= {100 * th['min_gain']:.3g} % and "
                      f"p <= alpha / N = {th['alpha']:g} / {len(result['candidates'])} = {th['p_max']:.2g} "
                      "(Bonferroni: with nothing missing, any false alarm has chance < alpha)"
                      + ("; and when it also lowers the error on regions of joint space held out in turn "
                         f"(baseline {b['cv_rms_region']:.4g} {unit}) and is physically plausible - otherwise it is "
                         "refused, with the reason below." if "cv_rms_region" in b else "."), "")
        lines.append("")
    head = f"{'#':>3}  {'effect':<16}{'target':>7}  {'cv_rms_with':>12}  {'gain':>7}  {'p':>8}  meaningful"
    lines += [head, "-" * len(head)]
    for k, c in enumerate(result["candidates"], 1):
        lines.append(f"{k:>3}  {c['effect']:<16}{target_text(c):>7}  {c['cv_rms_with']:>8.4g} {unit:<3}  "
                     f"{100 * c['gain']:>6.1f}%  {c['p']:>8.1e}  "
                     + ("YES" if c["meaningful"] else "no, refused" if c.get("refused") else "no"))
    if not result["candidates"]:
        lines.append("   (no candidate could be tried)")
    lines.append("")
    best = [c for c in result["candidates"] if c["meaningful"]]
    if best:
        lines.append("Meaningful candidates: add every one to the spec, then diagnose again.")
        if len(best) > 1:
            lines += wrap("Each was re-tested on top of the ones before it (best first): one that only mimicked "
                          "another is marked 'explained by' instead. The waterfall page shows them added in turn.",
                          "   ")
        for c in best:
            lines.append("")
            lines.append(f"* {_label(c)}: held-out RMS {b['cv_rms']:.4g} -> {c['cv_rms_with']:.4g} {unit} "
                         f"(gain {100 * c['gain']:.1f} %, p = {c['p']:.1e})")
            lines += wrap("evidence:    " + c["evidence"], "   ")
            lines += wrap("explanation: " + c["explanation"], "   ")
            if c.get("test"):
                lines += wrap("test:        " + c["test"], "   ")
            lines.append("   add to the spec:")
            lines += ["      " + ln for ln in c["spec_line"].splitlines()]
    else:
        lines += wrap(f"No candidate lowers the held-out error beyond noise in a way that carries over: "
                      f"{done_text(result)}; nothing to add.", "")
    v = result.get("verified_set")
    if v and v.get("checked"):
        lines.append("")
        lines += wrap(verified_text(v, unit), "")
    refused = [c for c in result["candidates"] if c.get("refused")]
    if refused:
        lines += ["", "Refused although they lower the error on neighbouring poses (why):"]
        for c in refused:
            lines += wrap(f"- {_label(c)}: {c['refused']}", "   ")
    nr = result.get("not_revealable", [])
    if nr:
        lines += ["", "Not revealable by these data (not ranked):"]
        for group in _same_reason(nr):
            u = group[0]
            tgt = "" if u["target"] is None else f" {u['target']}"
            orders = [o for o in (_orders(v.get("plan")) for v in group) if o]
            which = f" (orders {', '.join(orders)})" if len(orders) == len(group) > 1 else (
                f" ({len(group)} candidates)" if len(group) > 1 else "")
            lines += wrap(f"- {u['effect']}{tgt}{which}: {u['reason']}", "   ")
            if u.get("plan"):
                first = " (the first of them)" if len(group) > 1 else ""
                lines += wrap(f"  to reveal it, the poses need {u['needs']}; plan them with{first}: {u['plan']}", "   ")
    return lines


def _same_reason(items: list[dict]) -> list[list[dict]]:
    """The not-revealable candidates grouped by effect, joint, reason and what would reveal them, in
    order of first appearance (a joint's harmonics of every order share one reason: said once)."""
    groups: dict[tuple, list[dict]] = {}
    for u in items:
        groups.setdefault((u["effect"], u["target"], u["reason"], u.get("needs")), []).append(u)
    return list(groups.values())


def _orders(plan) -> str | None:
    """The harmonic order a candidate's ``--reveal`` names (``orders = [k]``), or None."""
    import re

    m = re.search(r"orders = \[([0-9, ]+)\]", plan or "")
    return m.group(1) if m else None


def _summary_pages(pdf, result, base_effects, name=None):
    """The summary as text (the appendix; as many pages as it takes)."""
    lines = summary_lines(result, base_effects)
    title = f"Diagnosis of {name or result['kind']}: candidates, evidence, what cannot be revealed"
    text_page(pdf, title, lines, fontsize=SUMMARY_FONTSIZE)


# ------------------------------------------------------------------------------ page 2
def _panel_residual(ax, name, values, unit, kind, mag, comps, res_unit):
    x = np.asarray(values, float)
    fin = x[np.isfinite(x)]
    if fin.size and np.ptp(fin) <= 1e-9 * max(1.0, float(np.max(np.abs(fin)))):
        # the same value at every point (a joint gravity cannot load, say): drawn at its value, no offset axis
        x = np.where(np.isfinite(x), round(float(np.mean(fin)), 9) + 0.0, x)
    d_is_vec = comps is not None
    ylab = f"|residual| ({res_unit})" if d_is_vec else f"residual ({res_unit})"
    if kind == "categorical":
        cats = np.unique(x[np.isfinite(x)])
        pos = np.arange(cats.size)
        groups = [np.flatnonzero(x == c) for c in cats]
        jitter = np.random.default_rng(0).uniform(-0.18, 0.18, x.size)
        where = np.full(x.size, np.nan)
        for p, g in zip(pos, groups):
            where[g] = p
        ax.scatter(where + jitter, mag, s=3, color=GREY, lw=0, zorder=1)
        m, se = _mean_se(mag, groups)
        ax.errorbar(pos, m, yerr=se, fmt="o", color=MEAN_COLOR, ms=4, capsize=3, zorder=3,
                    label="mean |r| +- SE" if d_is_vec else "mean +- SE")
        if 1 < cats.size <= 4 and not d_is_vec:
            for p_, m_ in zip(pos, m):
                ax.annotate(f"{m_ + 0.0:+.2f}", (p_, m_), xytext=(-5, 0), textcoords="offset points",
                            ha="right", va="center", fontsize=6.5, zorder=4,
                            bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
        if d_is_vec:
            names = _component_names(comps.shape[1])
            cm, cse = [], []
            for j, col in enumerate(COMPONENT_COLORS[:comps.shape[1]]):
                mj, sej = _mean_se(comps[:, j], groups)
                cm.append(mj)
                cse.append(sej)
                ax.errorbar(pos + 0.12 * (j + 1), mj, yerr=sej, fmt="s", color=col, ms=3, capsize=2, zorder=3,
                            label=f"mean {names[j]}")
            cm, cse = np.array(cm), np.array(cse)
            j = int(np.argmax(np.ptp(cm, axis=1)))
            # name the component that moves most between categories, if beyond 3 standard errors
            if 1 < cats.size <= 4 and np.ptp(cm[j]) > 3 * np.sqrt(np.sum(cse[j] ** 2)):
                for p_ in pos:
                    ax.annotate(f"{names[j]} {cm[j, p_] + 0.0:+.2g}", (p_ + 0.12 * (j + 1), cm[j, p_]), xytext=(4, 0),
                                textcoords="offset points", ha="left", va="center", fontsize=6, zorder=4,
                                color=COMPONENT_COLORS[j],
                                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
        ax.set_xticks(pos)
        ax.set_xticklabels([f"{c:g}" for c in cats])
        ax.set_xlim(-0.6, cats.size - 0.4 + (0.7 if d_is_vec else 0))
    else:
        ax.scatter(x, mag, s=3, color=GREY, lw=0, zorder=1)
        centres, groups = _bins(x)
        if len(groups):
            m, se = _mean_se(mag, groups)
            ax.plot(centres, m, "-", color=MEAN_COLOR, lw=1.3, zorder=3,
                    label="binned mean |r|" if d_is_vec else "binned mean")
            ax.fill_between(centres, m - se, m + se, color=MEAN_COLOR, alpha=0.15, lw=0, zorder=2)
            if d_is_vec:
                for j, col in enumerate(COMPONENT_COLORS[:comps.shape[1]]):
                    mj, _ = _mean_se(comps[:, j], groups)
                    ax.plot(centres, mj, "-", color=col, lw=1.0, zorder=3,
                            label=f"mean {_component_names(comps.shape[1])[j]}")
        if kind == "angle" and np.nanmax(x) - np.nanmin(x) > 180:
            ax.set_xticks(np.arange(np.ceil(np.nanmin(x) / 90 - 0.15) * 90, np.nanmax(x) + 0.15 * 90, 90))
        else:
            ax.locator_params(axis="x", nbins=4)      # a third of a page wide: room for four labels
    ax.axhline(0.0, color="0.4", lw=0.6, zorder=0)
    ax.set_xlabel(f"{name} ({unit})" if unit else name)
    ax.set_ylabel(ylab)
    ax.set_title(name, fontsize=9)
    ax.legend(loc="upper right", fontsize=5.5 if d_is_vec else 6, framealpha=0.7)


def _panel_spectrum(ax, name, values, residuals, res_unit, highlight=(), in_model=()):
    orders, amp, floor = residual_spectrum(values, residuals, noise=True)
    d = np.asarray(residuals).reshape(len(values), -1).shape[1]
    if orders.size == 0:
        ax.text(0.5, 0.5, "too few distinct angles\nfor a spectrum", ha="center", va="center", transform=ax.transAxes)
    else:
        colors = [HIGHLIGHT if o in highlight else "0.45" for o in orders]
        ax.bar(orders, amp, color=colors, width=0.7)
        ax.step(np.r_[orders - 0.5, orders[-1] + 0.5], np.r_[floor, floor[-1]], where="post",
                color="tab:red", ls="--", lw=0.8, zorder=3)
        handles = [Line2D([], [], color="tab:red", ls="--", lw=0.8, label="noise level")]
        fitted = [o for o in orders if o in in_model]
        if fitted:
            # fitted orders leave ~nothing in the residual: mark them at the foot of the axis
            ax.plot(fitted, np.zeros(len(fitted)), "^", color=MODEL_COLOR, ms=4, clip_on=False, zorder=4)
            handles.append(Line2D([], [], ls="", marker="^", color=MODEL_COLOR, ms=4, label="order in the model"))
        if any(o in highlight for o in orders):
            handles.append(Patch(color=HIGHLIGHT, label="meaningful candidate"))
        if handles:
            ax.legend(handles=handles, loc="upper left", fontsize=6, framealpha=0.7)
        ax.set_xticks(orders)
        ax.set_xticklabels([str(o) if o % 2 else "" for o in orders])
        ax.tick_params(axis="x", labelsize=7)
        ax.set_xlim(0.3, orders[-1] + 0.7)
        k = int(np.argmax(amp))
        ax.annotate(f"{amp[k]:.2g} {res_unit}", (orders[k], amp[k]), ha="center", va="bottom", fontsize=6)
        ymax = max(amp.max(), floor.max())
        ax.set_ylim(0, ymax * 1.3 if ymax > 0 else 1)
    ax.set_xlabel(f"harmonic order in {name} (cycles / rev)")
    ax.set_ylabel(f"amplitude ({res_unit})" if d == 1 else f"amplitude, RSS of x,y,z ({res_unit})")
    ax.set_title(f"residual spectrum vs {name}", fontsize=9)


def _model_orders(base_effects):
    """Harmonic orders the baseline already fits (effects on every angle, no joints given)."""
    out = set()
    for e in base_effects:
        params = getattr(e, "params", {}) or {}
        if "harmonic" in e.name and "joints" not in params and isinstance(params.get("orders"), (list, tuple)):
            out |= {int(o) for o in params["orders"]}
    return out


def _residual_pages(pdf, result, adapter, base, data, base_effects=(), name=None):
    res_unit = getattr(adapter, "unit", result["baseline"]["unit"])
    mag, comps = _residual_parts(base.residuals)
    # harmonic orders a meaningful candidate names: highlight them in the spectrum
    marked = {c["target"] for c in result["candidates"] if c["meaningful"] and c["effect"] == "harmonic"}
    panels = []
    for var, (values, unit, kind) in adapter.signature_variables(data).items():
        panels.append(("res", var, values, unit, kind))
        if kind == "angle":
            panels.append(("spec", var, values, unit, kind))
    in_model = _model_orders(base_effects)
    pages = [panels[i:i + PANELS_PER_PAGE] for i in range(0, len(panels), PANELS_PER_PAGE)]
    what = ("|held-out residual| (points) and mean x, y, z components (lines)" if comps is not None
            else "held-out residual")
    for p, page in enumerate(pages):
        rows = -(-len(page) // 3)
        fig, axes = plt.subplots(rows, 3, figsize=(A4[0], 1.0 + 3.4 * rows), squeeze=False)
        axes = axes.ravel()
        for ax, (typ, var, values, unit, kind) in zip(axes, page):
            if typ == "res":
                _panel_residual(ax, var, values, unit, kind, mag, comps, res_unit)
            else:
                _panel_spectrum(ax, var, values, base.residuals, res_unit, marked, in_model)
        for ax in axes[len(page):]:
            ax.set_visible(False)
        suffix = "" if len(pages) == 1 else f" ({p + 1}/{len(pages)})"
        head = fit_text(f"{_short(name) + ': ' if name else ''}baseline {what} against every signature{suffix}",
                        0.92 * A4[0], 10)
        fig.suptitle(head, fontsize=10)
        H = 1.0 + 3.4 * rows
        cap = (f"Baseline: {' + '.join(result['baseline']['effects']) or 'nothing'}, cross-validated RMS "
               f"{base.rms:.4g} {res_unit} ({result['baseline'].get('folds', '')}). A trend against a variable, or "
               "a spectral peak above the noise level, is what the model misses.")
        fig.tight_layout(rect=(0, 0.75 / H, 1, 1 - (0.3 + 0.17 * head.count("\n")) / H), h_pad=1.6)
        caption(fig, cap, y=0.08 / H)
        save(pdf, fig)


# ------------------------------------------------------------------------------ signatures
MAX_SIGNATURES = 4


def _structure(r, groups):
    """How much of ``r`` (n, d) the group means carry beyond noise: sum over groups and components of
    n_g mean_g^2, less what scatter alone gives (the residual variance once a group: its expectation
    when the means are noise), so many small groups score no more than a few large ones."""
    means = float(sum(g.size * np.sum(np.mean(r[g], axis=0) ** 2) for g in groups))
    return means - len(groups) * float(np.sum(np.var(r, axis=0)))


def _groups(values, kind):
    x = np.asarray(values, float)
    if kind == "categorical":
        cats = np.unique(x[np.isfinite(x)])
        return cats, [np.flatnonzero(x == c) for c in cats]
    return _bins(x)


def explained_signature(variables, before, after):
    """The signature variable whose residual structure an added effect removes most.

    Parameters
    ----------
    variables : dict name -> (values (n,), unit, kind), the adapter's signature variables
    before, after : ndarray, shape (n,) or (n, d), held-out residuals without and with the effect
        (the adapter's unit)

    Returns
    -------
    (name, component) : the variable, and the residual component (0-based) whose group means fell most
    """
    b = np.asarray(before, float).reshape(len(before), -1)
    a = np.asarray(after, float).reshape(len(after), -1)
    best, best_drop, best_comp = None, -np.inf, 0
    for name, (values, _, kind) in variables.items():
        _, groups = _groups(values, kind)
        if len(groups) < 2:
            continue
        drops = [_structure(b[:, [k]], groups) - _structure(a[:, [k]], groups) for k in range(b.shape[1])]
        k = int(np.argmax(drops))
        if drops[k] > best_drop:
            best, best_drop, best_comp = name, drops[k], k
    return best, best_comp


def _signature_runs(result, adapter, spec, data, base_effects, base):
    """Each meaningful candidate (the first MAX_SIGNATURES): its held-out residuals when added alone, and the
    signature variable it explains."""
    best = [c for c in result["candidates"] if c["meaningful"]][:MAX_SIGNATURES]
    if not best:
        return []
    objs = {o.spec_lines(): o for o in adapter.candidates(spec, data, base_effects) if hasattr(o, "spec_lines")}
    variables = adapter.signature_variables(data)
    out = []
    for c in best:
        obj = objs.get(c["spec_line"])
        if obj is None:
            continue
        try:
            after = adapter.cross_validate(adapter.add(list(base_effects), obj), data)
        except np.linalg.LinAlgError:
            continue
        name, comp = explained_signature(variables, base.residuals, after.residuals)
        if name is not None:
            out.append({"candidate": c, "variable": name, "component": comp, "after": after})
    return out


def _signature_page(pdf, result, adapter, data, base, runs, name=None):
    """Each recommended effect's signature next to the residual it explains: the baseline's held-out residual
    against the variable the effect explains (left) and with the effect added (right), binned means drawn."""
    if not runs:
        return
    unit = getattr(adapter, "unit", result["baseline"]["unit"])
    variables = adapter.signature_variables(data)
    d = np.asarray(base.residuals).reshape(len(base.residuals), -1).shape[1]
    comp_names = _component_names(d) if d > 1 else ("",)
    H = 1.2 + 2.6 * len(runs)
    fig, axes = plt.subplots(len(runs), 2, figsize=(A4[0], H), squeeze=False, sharey="row")
    for (axl, axr), run in zip(axes, runs):
        values, vunit, kind = variables[run["variable"]]
        centres, groups = _groups(values, kind)
        x = np.asarray(values, float)
        k = run["component"]
        comp = f" {comp_names[k]}" if d > 1 else ""
        for ax, res, title in ((axl, base.residuals, "baseline"), (axr, run["after"].residuals,
                                                                      "+ " + _label(run["candidate"]))):
            r = np.asarray(res, float).reshape(len(res), -1)[:, k]
            jitter = (np.random.default_rng(0).uniform(-0.15, 0.15, x.size) if kind == "categorical" else 0.0)
            ax.scatter(x + jitter, r, s=3, color=GREY, lw=0, zorder=1)
            m, se = _mean_se(r, groups)
            if kind == "categorical":
                ax.errorbar(centres, m, yerr=se, fmt="o", color=MEAN_COLOR, ms=4, capsize=3, zorder=3)
                ax.set_xticks(centres)
                ax.set_xticklabels([f"{c:g}" for c in centres])
            else:
                ax.plot(centres, m, "-", color=MEAN_COLOR, lw=1.3, zorder=3)
                ax.fill_between(centres, m - se, m + se, color=MEAN_COLOR, alpha=0.15, lw=0, zorder=2)
                ax.locator_params(axis="x", nbins=5)
            ax.axhline(0.0, color="0.4", lw=0.6, zorder=0)
            ax.set_xlabel(f"{run['variable']} ({vunit})" if vunit else run["variable"])
            rms = float(np.sqrt(np.mean(np.sum(np.asarray(res, float).reshape(len(res), -1) ** 2, axis=1))))
            ax.set_title(f"{title}: held-out RMS {rms:.4g} {unit}", fontsize=8.5)
        axl.set_ylabel(f"residual{comp} ({unit})")
    head = fit_text(f"{_short(name) + ': ' if name else ''}each recommended effect next to the residual it explains",
                    0.92 * A4[0], 10)
    fig.suptitle(head, fontsize=10)
    fig.tight_layout(rect=(0, 0.5 / H, 1, 1 - (0.3 + 0.17 * head.count("\n")) / H))
    caption(fig, "Left: the baseline's held-out residual against the variable whose pattern the effect removes most "
                 "(black: the mean per bin or category); right: the same with the effect added. A pattern on the left "
                 "that is gone on the right is the effect's signature.", y=0.06 / H)
    save(pdf, fig)


# ------------------------------------------------------------------------------ page 3
def _candidates_page(pdf, result, name=None):
    every = result["candidates"]
    cands = every[:MAX_BARS]
    th = result.get("thresholds", {})
    unit = result["baseline"]["unit"]
    height = min(A4[1], max(4.0, 1.6 + 0.24 * len(cands)))
    fig, ax = plt.subplots(figsize=(A4[0], height))
    if not cands:
        ax.text(0.5, 0.5, "no candidate could be tried on these data", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
    else:
        y = np.arange(len(cands))[::-1]
        gains = np.array([100 * c["gain"] for c in cands])
        colors = [HIGHLIGHT if c["meaningful"] else GREY for c in cands]
        ax.barh(y, gains, color=colors, height=0.7)
        ax.set_yticks(y)
        ax.set_yticklabels([_label(c) for c in cands], fontsize=8)
        for c, yy in zip(cands, y):
            g = 100 * c["gain"]
            why = ""
            if th and not c["meaningful"]:
                why = "; p too large" if c["p"] > th["p_max"] else ("; gain too small" if c["gain"] < th["min_gain"] else "")
                why = "" if c["gain"] <= 0 else why
            ax.annotate(f" {g:+.1f} %  (p = {c['p']:.1e}, {c['cv_rms_with']:.4g} {unit}{why})",
                        (max(g, 0.0), yy), va="center", ha="left", fontsize=6.5,
                        color="black" if c["meaningful"] else "0.35")
        lo, hi = min(0.0, gains.min()), max(0.0, gains.max())
        span = max(hi - lo, 1.0)
        ax.set_xlim(lo - 0.05 * span, hi + 0.75 * span)
        ax.set_ylim(-0.7, len(cands) - 0.3)
        ax.axvline(0.0, color="0.3", lw=0.8)
        if th:
            ax.axvline(100 * th["min_gain"], color="tab:orange", ls="--", lw=1,
                       label=f"min gain {100 * th['min_gain']:.3g} %")
        handles = [Patch(color=HIGHLIGHT, label="meaningful"), Patch(color=GREY, label="within noise")]
        h2, _ = ax.get_legend_handles_labels()
        ax.legend(handles=handles + h2, loc="lower right", fontsize=7)
        ax.set_xlabel(f"gain = 1 - cv_rms_with / baseline ({result['baseline']['cv_rms']:.4g} {unit})  (%)")
        ax.grid(axis="y", visible=False)
    sub = ""
    if th:
        sub = (f"\nmeaningful: gain >= {100 * th['min_gain']:.3g} % and p <= alpha/N = {th['alpha']:g}/{len(cands)}"
               f" = {th['p_max']:.2g} (Bonferroni)")
    more = f" (the first {len(cands)} of {len(every)}; every one in the appendix)" if len(every) > len(cands) else ""
    head = f"{_short(name) + ': ' if name else ''}cross-validated gain of adding each candidate effect{more}"
    ax.set_title(fit_text(head, 0.85 * A4[0], 10), fontsize=10)
    fig.tight_layout(rect=(0, 0.9 / height, 1, 1))
    title_on_page(fig, ax, head, 10, rect=(0, 0.9 / height, 1, 1))
    caption(fig, "Blue bars are the effects to add: they lower the held-out error beyond noise." + sub.replace("\n", " ")
            + ".", y=0.1 / height)
    save(pdf, fig)


# ------------------------------------------------------------------------------ page 4
MAX_SUGGESTED = 3


def suggested_steps(result, adapter, spec, data, base_effects, max_n=MAX_SUGGESTED):
    """The meaningful candidates added one after the other (best first), cross-validated.

    The diagnosis tests every candidate alone against the baseline; two candidates whose
    signatures are correlated in this campaign (time within a run and direction of
    approach, when every run sweeps forwards then backwards) can both look meaningful.
    Adding them in turn shows whether the second still lowers the held-out error.
    Returns a list of ``{"label", "cv_rms"}``; the first uses the diagnosis' own number.
    """
    best = [c for c in result["candidates"] if c["meaningful"]][:max_n]
    if not best:
        return []
    steps = [{"label": _label(best[0]), "cv_rms": best[0]["cv_rms_with"]}]
    if len(best) == 1:
        return steps
    # keyed by the whole [[effect]] table: harmonics of one joint differ by their order only
    objs = {o.spec_lines(): o for o in adapter.candidates(spec, data, base_effects)}
    effects = list(base_effects)
    for k, c in enumerate(best):
        obj = objs.get(c["spec_line"])
        if obj is None:
            break
        effects = adapter.add(effects, obj)
        if k == 0:
            continue
        try:
            rms = adapter.cross_validate(effects, data).rms
        except np.linalg.LinAlgError:
            break
        steps.append({"label": _label(c), "cv_rms": rms})
    return steps


def _waterfall(ax, result, steps, base_effects, suggested=(), fontsize=7, width=22, rotate=False):
    """Held-out RMS as each effect of the spec is added in turn, then the suggested ones (bars)."""
    unit = result["baseline"]["unit"]
    min_gain = result.get("thresholds", {}).get("min_gain", 0.0)
    labels = ["nothing\n(constants only)"]
    for s, e in zip(steps[1:], base_effects):      # a narrow panel: the effect's name only
        labels.append("+ " + "\n".join(textwrap.wrap(e.name if rotate else _effect_label(e), width)))
    values = [s["cv_rms"] for s in steps]
    colors = ["0.45"] * len(values)
    hatches = [None] * len(values)
    for k, s in enumerate(suggested):
        labels.append("+ " + "\n".join(textwrap.wrap(s["label"], width)) + ("\n(suggested)" if k == 0 else "\n(then)"))
        values.append(s["cv_rms"])
        colors.append(HIGHLIGHT if k == 0 else "lightsteelblue")
        hatches.append("//")
    x = np.arange(len(values))
    bars = ax.bar(x, values, color=colors, width=0.6, edgecolor="white")
    for bar, h in zip(bars, hatches):
        if h:
            bar.set_hatch(h)
    top = max(values) if values else 1.0
    for k, v in enumerate(values):
        txt = f"{v:.4g}"
        if k and values[k - 1] > 0:
            change = v / values[k - 1] - 1.0
            txt += f"\n{100 * change:+.1f} %"
            if k >= len(steps) + 1 and -change < min_gain:
                txt += "\nno gain"
        ax.annotate(txt, (k, v), ha="center", va="bottom", fontsize=fontsize, xytext=(0, 2), textcoords="offset points")
    ax.set_xticks(x)
    if rotate:      # a narrow panel: the labels on one line each, turned
        ax.set_xticklabels([lb.replace("\n", " ") for lb in labels], fontsize=fontsize, rotation=90)
    else:
        ax.set_xticklabels(labels, fontsize=fontsize)
    ax.set_ylim(0, top * 1.3)
    ax.set_ylabel(f"cross-validated RMS ({unit})")
    ax.grid(axis="x", visible=False)


def _waterfall_page(pdf, result, steps, base_effects, suggested=(), name=None):
    fig, ax = plt.subplots(figsize=(A4[0], A4[1] / 2))
    _waterfall(ax, result, steps, base_effects, suggested)
    if suggested:
        note = ("Blue: the top meaningful candidate added to the spec's model"
                + ("; light blue: the next meaningful ones added after it, in turn." if len(suggested) > 1 else "."))
    else:
        note = "No meaningful candidate: nothing to add."
    head = f"{_short(name) + ': ' if name else ''}held-out error as each effect of the spec is added in turn"
    ax.set_title(fit_text(head, 0.85 * A4[0], 10), fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    title_on_page(fig, ax, head, 10, rect=(0, 0.1, 1, 1))
    caption(fig, f"Each bar is the cross-validated RMS ({result['baseline'].get('folds', '')}) with the effects up to "
                 f"it; the change against the bar before is under each value. {note}")
    save(pdf, fig)


def _headline_rows(result, name=None, top=6):
    """The summary table's rows of one campaign: baseline, then the top candidates."""
    b = result["baseline"]
    unit = b["unit"]
    rows = [[name or result["kind"], "", "", "", "", ""],
            ["", "baseline: " + (" + ".join(b["effects"]) or "nothing"), f"{b['cv_rms']:.4g}", "", "", ""]]
    for c in result["candidates"][:top]:
        verdict = "add it" if c["meaningful"] else "refused" if c.get("refused") else "within noise"
        rows.append(["", "+ " + _label(c), f"{c['cv_rms_with']:.4g}", f"{100 * c['gain']:+.1f}", f"{c['p']:.1e}",
                     verdict])
    return rows, unit


def _summary_first_page(pdf, runs):
    """Page 1: every campaign's baseline and top candidates (a typeset table) and its waterfall."""
    header = ["campaign", "model", "cross-validated\nRMS", "gain\n(%)", "p", "verdict"]
    rows, bold, units = [], [], []
    top = 6 if len(runs) == 1 else 3
    for r in runs:
        bold.append(len(rows))
        rr, unit = _headline_rows(r["result"], r["name"], top)
        for row in rr[1:]:
            row[2] += f" {unit}"
        rows += rr
        units.append(unit)
    found = [(r["name"] or r["result"]["kind"], [c for c in r["result"]["candidates"] if c["meaningful"]]) for r in runs]
    notes = [f"{n}: add {', '.join(_label(c) for c in best)}." if best else f"{n}: nothing meaningful is missing."
             for n, best in found]

    def draw(fig, rect):
        left, bottom, width, height = rect
        gs = fig.add_gridspec(1, len(runs), left=left, right=left + width,
                              bottom=bottom + (0.14 if len(runs) > 1 else 0.06), top=bottom + height, wspace=0.45)
        for k, r in enumerate(runs):
            ax = fig.add_subplot(gs[0, k])
            _waterfall(ax, r["result"], r["steps"], r["base_effects"], r["suggested"][:1],
                       fontsize=6 if len(runs) > 1 else 7, width=40 if len(runs) > 1 else 22, rotate=len(runs) > 1)
            ax.set_title(r["name"] or r["result"]["kind"], fontsize=9)

    summary_page(pdf, "Diagnosis: what the model misses", "Each campaign's baseline model (its spec's effects) is "
                 "cross-validated; each candidate effect is added in turn and kept only when it lowers the held-out "
                 "error beyond noise (gain and Bonferroni p) and carries over to held-out regions.",
                 header, rows, draw, "The waterfall: held-out RMS as the spec's effects are added one by one, then the "
                 "top meaningful candidate (blue, hatched). A blue bar well below the last grey one is an effect the "
                 "model misses; the full candidate lists and reasons are in the appendix.",
                 notes=notes, align=["l", "l", "r", "r", "r", "l"], bold_rows=bold, table_fontsize=7.5)


# ------------------------------------------------------------------------------ entry
def _prepare(result, adapter, spec, data, progress=None, name=None):
    base_effects = adapter.baseline_effects(spec, data)
    base = adapter.cross_validate(base_effects, data)
    steps = waterfall(adapter, spec, data, progress)
    suggested = suggested_steps(result, adapter, spec, data, base_effects)
    signatures = _signature_runs(result, adapter, spec, data, base_effects, base)
    return {"result": result, "adapter": adapter, "data": data, "base_effects": base_effects, "base": base,
            "steps": steps, "suggested": suggested, "signatures": signatures, "name": name}


def _pages(pdf, r):
    name = r["name"]
    _residual_pages(pdf, r["result"], r["adapter"], r["base"], r["data"], r["base_effects"], name)
    _signature_page(pdf, r["result"], r["adapter"], r["data"], r["base"], r["signatures"], name)
    _candidates_page(pdf, r["result"], name)
    _waterfall_page(pdf, r["result"], r["steps"], r["base_effects"], r["suggested"], name)
    _summary_pages(pdf, r["result"], r["base_effects"], name)      # console text: the appendix


def diagnosis_pages(pdf, result, adapter, spec, data, progress=None, name=None):
    """Add one campaign's diagnosis pages to an open PDF (its summary page first)."""
    r = _prepare(result, adapter, spec, data, progress, name)
    _summary_first_page(pdf, [r])
    _pages(pdf, r)


def diagnosis_report(result, adapter, spec, data, out, progress=None, name=None):
    """Write the diagnosis PDF to ``out`` (see the module docstring for the pages)."""
    with pdf_pages(out, f"jointcal diagnosis ({result['kind']})") as pdf:
        diagnosis_pages(pdf, result, adapter, spec, data, progress, name)
    return out


def diagnosis_report_many(items, out, progress=None, names=None):
    """One PDF for several campaigns: ``items`` is a list of (result, adapter, spec, data); ``names``
    (optional) what to call each campaign. One summary page for all, then each campaign's pages."""
    names = list(names) if names else [None] * len(items)
    runs = [_prepare(result, adapter, spec, data, progress, n) for (result, adapter, spec, data), n in zip(items, names)]
    with pdf_pages(out, "jointcal diagnosis") as pdf:
        _summary_first_page(pdf, runs)
        for r in runs:
            _pages(pdf, r)
    return out


__all__ = ["diagnosis_report", "diagnosis_report_many", "diagnosis_pages", "explained_signature", "residual_spectrum",
           "suggested_steps", "summary_lines"]
