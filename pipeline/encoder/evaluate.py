"""Stage ``fit`` (encoder): build the model on the modelling runs, evaluate it on the held-out run.

The result is a plain dict (written as ``results/encoder/<module>_model.json``) holding
the model's terms, the peak-to-peak error of the validation run before and after
compensation and the reduction, with everything needed to rebuild the model.
"""

from __future__ import annotations

import numpy as np

from ..core.crossval import CVResult
from .effects import EncoderData, Harmonic
from .model import EncoderModel, leave_one_run_out, peak_to_peak, residual_without_constant
from .selection import select_orders, split_runs


def fit_encoder(frame, spec, orders) -> dict:
    """Fit the spec's encoder model and evaluate it on the validation runs.

    Parameters
    ----------
    frame : DataFrame
        Ingested readings of one module.
    spec : Spec
        Encoder spec; ``[model] fit`` chooses ``run_average`` (paper) or ``pooled``.
    orders : list of int
        Harmonic orders when the spec leaves them to selection.

    Returns
    -------
    dict with ``terms`` (order, C_arcsec, phi_deg), ``other`` coefficients, run lists,
    ``p2p_before_arcsec``, ``p2p_after_arcsec``, ``reduction_pct``, RMS before/after and the
    validation run's readings, model values and residuals (for the report).
    """
    data = EncoderData.from_frame(frame)
    model_runs, valid_runs = split_runs(data.runs, spec.model)
    effects = spec.effects or [Harmonic()]
    method = spec.model.get("fit", "run_average")
    n_max = _harmonic_n_max(spec)
    train = data.subset(np.isin(data.run, model_runs))
    model = EncoderModel(effects, orders=orders, fit_method=method, n_max=n_max).fit(train)
    out = {"module": str(frame["module"].iloc[0]), "fit": method, "effects": [e.name for e in effects],
           "orders": sorted(model.orders_), "modelling_runs": model_runs, "validation_runs": valid_runs,
           "n_distinct_angles": model.n_distinct_, "terms": model.terms(), "other": model.other_coefficients(),
           "validation": []}
    for r in valid_runs:
        test = data.subset(data.run == r)
        pred = model.predict(test)
        after = test.error_arcsec - pred
        centred = residual_without_constant(test.error_arcsec, pred, test.run)
        out["validation"].append({
            "run": r, "p2p_before_arcsec": peak_to_peak(test.error_arcsec), "p2p_after_arcsec": peak_to_peak(after),
            "rms_before_arcsec": float(np.std(test.error_arcsec)), "rms_after_arcsec": float(np.sqrt(np.mean(centred ** 2))),
            "theta_deg": test.theta_deg, "error_arcsec": test.error_arcsec, "model_arcsec": pred})
    v = out["validation"][0]
    out["p2p_before_arcsec"] = v["p2p_before_arcsec"]
    out["p2p_after_arcsec"] = v["p2p_after_arcsec"]
    out["reduction_pct"] = 100.0 * (1.0 - v["p2p_after_arcsec"] / v["p2p_before_arcsec"])
    return out


def with_orders(effects, orders):
    """The spec's effects with the harmonic orders the fit used."""
    return [Harmonic(orders=orders) if isinstance(e, Harmonic) else e for e in effects]


def fit_encoder_spec(frame, spec, orders=None) -> dict:
    """The whole ``fit`` stage on one module: orders, fit, held-out run, cross-validated RMS.

    Orders the spec leaves open (a ``harmonic`` effect without ``orders``) and not given are
    chosen by the spec's ``[select]`` rule over the modelling runs. Returns
    :func:`fit_encoder`'s dict plus ``cv_rms_arcsec``, the leave-one-run-out RMS that
    ``jointcal diagnose`` ranks effects by (:func:`cross_validate`). Raises ValueError (or OrderTooHighError) when the
    spec and the data disagree.
    """
    h = spec.effect("harmonic")
    if h is not None and not isinstance(h.params.get("orders"), list) and orders is None:
        orders, _, _ = select_orders(frame, spec)
    result = fit_encoder(frame, spec, orders)
    result["cv_rms_arcsec"] = cross_validate(with_orders(spec.effects, result["orders"]), EncoderData.from_frame(frame)).rms
    return result


def cross_validate(effects, data: EncoderData) -> CVResult:
    """Leave-one-run-out held-out residuals of the pooled model of ``effects`` (arcsec).

    Each run is predicted by the model fitted on the other runs only (``pooled``: one unknown
    constant per run, every other coefficient shared), its own start constant removed. The
    fold's models are kept in ``extra["models"]`` (run -> model) for diagnosis's tests.
    """
    res = np.empty(data.theta_deg.size)
    models = {}
    for r, test, model, residual in leave_one_run_out(data, lambda: EncoderModel(effects, fit_method="pooled")):
        res[test] = residual
        models[int(r)] = model
    return CVResult(res[:, None], data.run.copy(), {"models": models})


def _harmonic_n_max(spec):
    h = spec.effect("harmonic")
    return None if h is None else h.params.get("n_max")


def model_from_result(result: dict) -> EncoderModel:
    """Rebuild the harmonic part of a fitted model from its JSON (for compensation)."""
    orders = [t["order"] for t in result["terms"]]
    model = EncoderModel([Harmonic(orders=orders)])
    model.orders_ = orders
    model.keep_constant_ = 0 in orders
    model.C0_ = next((t["C_arcsec"] for t in result["terms"] if t["order"] == 0), 0.0)
    labels, coef = [], []
    for t in result["terms"]:
        if t["order"] == 0:
            continue
        p = np.deg2rad(t["phi_deg"])
        labels += [f"A{t['order']}", f"B{t['order']}"]
        coef += [t["C_arcsec"] * np.sin(p), t["C_arcsec"] * np.cos(p)]
    model.labels_, model.coef_ = labels, np.array(coef)
    return model
