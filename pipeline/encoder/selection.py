"""Stage ``select``: which harmonic orders go into the model.

Paper rule (paper 1, section 4.2): over the modelling runs, an order is kept when its mean
amplitude is prominent and its phase is stable from run to run, or its amplitude is so
large that it must be kept whatever its phase does:

    keep i  if  mean C_i >= amplitude_strong_arcsec
            or (mean C_i >= amplitude_min_arcsec and phase range_i <= phase_range_max_deg)

(order 0: amplitude |mean C_0|, phase = its sign). Side by side, a data-driven choice:
forward selection by leave-one-run-out cross-validated RMS.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .effects import EncoderData, Harmonic
from .harmonic import analyse_runs
from .model import EncoderModel, circular_range_deg, leave_one_run_out

PAPER_DEFAULTS = {"amplitude_strong_arcsec": 10.0, "amplitude_min_arcsec": 4.0, "phase_range_max_deg": 30.0}


def split_runs(runs, spec_model: dict) -> tuple[list[int], list[int]]:
    """Modelling and validation runs: from the spec, else all but the last / the last."""
    runs = sorted(int(r) for r in runs)
    model_runs = spec_model.get("modelling_runs")
    valid_runs = spec_model.get("validation_runs")
    if model_runs is None and valid_runs is None:
        return runs[:-1], runs[-1:]
    if model_runs is None:
        model_runs = [r for r in runs if r not in valid_runs]
    if valid_runs is None:
        valid_runs = [r for r in runs if r not in model_runs]
    missing = sorted((set(model_runs) | set(valid_runs)) - set(runs))
    if missing:
        raise ValueError(f"the spec names run(s) {missing} that the campaign does not have (runs: {runs})")
    return sorted(model_runs), sorted(valid_runs)


def paper_rule(harmonics: pd.DataFrame, runs, thresholds: dict | None = None) -> tuple[list[int], pd.DataFrame]:
    """Apply the paper's amplitude + phase-stability rule.

    Parameters
    ----------
    harmonics : DataFrame
        Output of :func:`pipeline.encoder.harmonic.analyse_runs` (run, order, A, B, C, phi_deg).
    runs : sequence of int
        Modelling runs.
    thresholds : dict
        ``amplitude_strong_arcsec``, ``amplitude_min_arcsec`` (arcsec), ``phase_range_max_deg`` (deg).

    Returns
    -------
    orders : list of int
    table : DataFrame, one row per order: mean_C_arcsec, phase_range_deg, prominent, stable, kept
    """
    t = {**PAPER_DEFAULTS, **(thresholds or {})}
    h = harmonics[harmonics["run"].isin(list(runs))]
    rows = []
    for order, g in h.groupby("order", sort=True):
        if order == 0:
            amp = abs(float(g["A"].mean()))
            signs = np.sign(g["A"].to_numpy())
            prange = 0.0 if np.unique(signs).size == 1 else 180.0
        else:
            amp = float(g["C"].mean())
            prange = circular_range_deg(g["phi_deg"].to_numpy())
        strong = amp >= t["amplitude_strong_arcsec"]
        prominent = amp >= t["amplitude_min_arcsec"]
        stable = prange <= t["phase_range_max_deg"]
        kept = bool(strong or (prominent and stable))
        rows.append({"order": int(order), "mean_C_arcsec": amp, "phase_range_deg": prange,
                     "strong": bool(strong), "prominent": bool(prominent), "stable": bool(stable), "kept": kept})
    table = pd.DataFrame(rows)
    return [int(o) for o in table.loc[table["kept"], "order"]], table


def loro_cv_rms(data: EncoderData, effects, orders=None, fit_method="pooled", n_max=None) -> float:
    """Leave-one-run-out cross-validated RMS residual (arcsec).

    Each run is predicted by a model fitted on the other runs only; its own unknown start
    constant is removed (one nuisance parameter), never anything else.
    """
    runs = data.runs
    if runs.size < 2:
        raise ValueError("cross-validation needs at least two runs")
    sq, n = 0.0, 0
    make = lambda: EncoderModel(effects, orders=orders, fit_method=fit_method, n_max=n_max)  # noqa: E731
    for _, _, _, res in leave_one_run_out(data, make):
        sq += float(res @ res)
        n += res.size
    return float(np.sqrt(sq / n))


def cv_select(data: EncoderData, n_max: int, min_gain: float = 0.01, fit_method="pooled"):
    """Forward selection of orders 1..n_max by leave-one-run-out CV RMS.

    Adds the order that lowers the CV RMS most, while it lowers it by more than
    ``min_gain`` (relative). Returns (orders, path) where path lists (order added, cv_rms).
    """
    chosen: list[int] = []
    best = loro_cv_rms(data, [Harmonic(orders=[])], fit_method=fit_method)
    path = [(None, best)]
    candidates = list(range(1, n_max + 1))
    while candidates:
        scores = {i: loro_cv_rms(data, [Harmonic(orders=sorted(chosen + [i]))], fit_method=fit_method)
                  for i in candidates}
        i = min(scores, key=lambda k: (scores[k], k))
        if scores[i] > best * (1.0 - min_gain):
            break
        chosen.append(i)
        candidates.remove(i)
        best = scores[i]
        path.append((i, best))
    return sorted(chosen), path


def select_orders(frame, spec, harmonics=None):
    """Orders the spec's [select] rule keeps, over the spec's modelling runs.

    Parameters
    ----------
    frame : DataFrame
        Ingested readings (``jointcal ingest``).
    spec : Spec
    harmonics : DataFrame, optional
        Per-run coefficients (``jointcal harmonic``); computed here when not given.

    Returns
    -------
    orders : list of int, model_runs : list of int, table : DataFrame (see :func:`paper_rule`)
    """
    model_runs, _ = split_runs(frame["run"].unique(), spec.model)
    if harmonics is None:
        h = spec.effect("harmonic")
        harmonics = analyse_runs(frame[frame["run"].isin(model_runs)], n_max=h.params.get("n_max") if h else None)
    orders, table = paper_rule(harmonics, model_runs, spec.select)
    return orders, model_runs, table


def selection_document(frame, spec, harmonics) -> dict:
    """``jointcal select``'s result: the paper rule's orders, the cross-validated choice, and the orders used.

    Parameters
    ----------
    frame : DataFrame
        Ingested readings (``jointcal ingest``; angles deg, errors arcsec).
    spec : Spec
        An encoder spec with ``[select]`` thresholds; its harmonic effect's explicit ``orders`` win.
    harmonics : DataFrame
        Per-run coefficients (``jointcal harmonic``; amplitudes arcsec, phases deg).

    Returns
    -------
    dict
        ``module``, ``orders`` (used), ``rule``, ``paper_rule_orders``, ``cv_orders``, ``cv_path`` (each
        order added with the leave-one-run-out RMS, arcsec), ``thresholds``, ``modelling_runs``, ``table``.

    Raises
    ------
    ValueError
        The spec's modelling or validation runs do not fit the data (:func:`select_orders`).
    """
    paper_orders, model_runs, rule = select_orders(frame, spec, harmonics)
    h = spec.effect("harmonic")
    explicit = h is not None and isinstance(h.params.get("orders"), list)
    data = EncoderData.from_frame(frame)
    n_fit = int(harmonics["order"].max())
    train = data.subset(np.isin(data.run, model_runs))
    cv_orders, path = cv_select(train, n_fit)
    chosen = sorted(h.params["orders"]) if explicit else paper_orders
    return {"module": str(frame["module"].iloc[0]), "orders": chosen,
            "rule": "spec" if explicit else spec.select.get("rule", "paper"),
            "paper_rule_orders": paper_orders, "cv_orders": cv_orders,
            "cv_path": [{"added": a, "cv_rms_arcsec": b} for a, b in path],
            "thresholds": spec.select, "modelling_runs": model_runs,
            "table": rule.to_dict(orient="records")}
