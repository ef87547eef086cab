"""The encoder model: a run constant plus the sum of its effects' terms (stage ``fit``).

Two ways to estimate it, both from the same effect list:

``run_average`` (paper 1, section 4.2)
    Least squares per run with every order up to ``n_max`` (and the other effects' terms),
    then the amplitude of each kept order averaged and its phase averaged on the circle
    over the modelling runs; other coefficients averaged.
``pooled``
    One least-squares fit over all modelling runs with one unknown constant per run
    (each run's error is relative to its first reading). Used by diagnosis.

Follows scikit-learn conventions: nothing happens in ``__init__``, ``fit`` returns
``self``, fitted values end in ``_``.
"""

from __future__ import annotations

import numpy as np

from .aliasing import check_orders, max_full_order
from .effects import EncoderData, Harmonic
from .harmonic import harmonic_columns
from .harmonic import amplitude_phase, circular_mean_deg, circular_range_deg  # noqa: F401 (re-exported)


class EncoderModel:
    """Angle error model of one joint module.

    Parameters
    ----------
    effects : list of EncoderEffect
        The spec's effects. A ``harmonic`` effect without explicit orders uses ``orders``.
    orders : sequence of int, optional
        Harmonic orders when the spec leaves them to selection (order 0 keeps the constant).
    fit_method : {"pooled", "run_average"}
    n_max : int, optional
        Highest order of the per-run analysis in ``run_average`` (default: (N-1)//2).
    """

    def __init__(self, effects, orders=None, fit_method="pooled", n_max=None):
        self.effects = effects
        self.orders = orders
        self.fit_method = fit_method
        self.n_max = n_max

    # ----------------------------------------------------------------------------------
    def _harmonic(self):
        for e in self.effects:
            if isinstance(e, Harmonic):
                return e
        return None

    def _orders(self):
        h = self._harmonic()
        if h is None:
            return []
        return h.orders(default=self.orders or [])

    def _other_columns(self, data):
        labels, cols = [], []
        for e in self.effects:
            if isinstance(e, Harmonic):
                continue
            lab, X = e.columns(data)
            labels += lab
            cols.append(X)
        X = np.column_stack(cols) if cols else np.empty((data.theta_deg.size, 0))
        return labels, X

    def design(self, data: EncoderData):
        """Labels and regressors of the model (without the run constants)."""
        hl, H = harmonic_columns(data.theta_deg, self._orders())
        ol, O = self._other_columns(data)
        return hl + ol, np.hstack([H, O])

    # ----------------------------------------------------------------------------------
    def fit(self, data: EncoderData) -> "EncoderModel":
        n_distinct = data.distinct_angles()
        orders = self._orders()
        check_orders(orders, n_distinct)
        self.n_distinct_ = n_distinct
        self.orders_ = orders
        self.keep_constant_ = 0 in orders
        runs = data.runs
        if self.fit_method == "run_average":
            self._fit_run_average(data, runs, n_distinct)
        elif self.fit_method == "pooled":
            self._fit_pooled(data, runs)
        else:
            raise ValueError(f"unknown fit method {self.fit_method!r}; use 'pooled' or 'run_average'")
        self.C0_ = float(np.mean(self.run_constants_)) if self.keep_constant_ else 0.0
        return self

    def _fit_pooled(self, data, runs):
        labels, X = self.design(data)
        onehot = (data.run[:, None] == runs[None, :]).astype(float)
        M = np.hstack([onehot, X])
        coef, *_ = np.linalg.lstsq(M, data.error_arcsec, rcond=None)
        self.run_constants_ = coef[: runs.size]
        self.labels_ = labels
        self.coef_ = coef[runs.size:]

    def _fit_run_average(self, data, runs, n_distinct):
        n_max = self.n_max if self.n_max is not None else max_full_order(n_distinct)
        check_orders([n_max], n_distinct)
        analysis = list(range(1, n_max + 1))
        keep = [i for i in self.orders_ if i != 0]
        ol, _ = self._other_columns(data.subset(data.run == runs[0]))
        per_run_ab, per_run_other, consts = [], [], []
        for r in runs:
            d = data.subset(data.run == r)
            _, H = harmonic_columns(d.theta_deg, analysis)
            _, O = self._other_columns(d)
            M = np.hstack([np.ones((d.theta_deg.size, 1)), H, O])
            coef, *_ = np.linalg.lstsq(M, d.error_arcsec, rcond=None)
            consts.append(coef[0])
            per_run_ab.append(coef[1:1 + 2 * len(analysis)].reshape(-1, 2))
            per_run_other.append(coef[1 + 2 * len(analysis):])
        ab = np.array(per_run_ab)  # (runs, orders, 2)
        C, phi = amplitude_phase(ab[..., 0], ab[..., 1])
        labels, coef = [], []
        for i in keep:
            j = analysis.index(i)
            c, p = C[:, j].mean(), np.deg2rad(circular_mean_deg(phi[:, j]))
            labels += [f"A{i}", f"B{i}"]
            coef += [c * np.sin(p), c * np.cos(p)]
        self.labels_ = labels + ol
        self.coef_ = np.concatenate([np.array(coef), np.mean(per_run_other, axis=0)]) if ol else np.array(coef)
        self.run_constants_ = np.array(consts)
        self.per_run_amplitude_ = C
        self.per_run_phase_deg_ = phi

    # ----------------------------------------------------------------------------------
    def predict(self, data: EncoderData) -> np.ndarray:
        """Modelled angle error (arcsec), shape (n,), at the readings of ``data``."""
        _, X = self.design(data)
        return self.C0_ + X @ self.coef_

    def predict_theta(self, theta_deg) -> np.ndarray:
        """Modelled error (arcsec) at joint angles alone: the constant and the terms of the
        ``compensable`` effects (their :meth:`~pipeline.encoder.effects.EncoderEffect.compensation_columns`)."""
        theta_deg = np.asarray(theta_deg, float)
        terms = []
        for e in self.effects:
            if e.compensable:
                labels, X = e.compensation_columns(theta_deg, self)
                terms.append(X @ self.coef_[[self.labels_.index(lab) for lab in labels]])
        if not terms:
            return self.C0_ + np.zeros(theta_deg.shape)
        return self.C0_ + (terms[0] if len(terms) == 1 else np.sum(terms, axis=0))

    def terms(self) -> list[dict]:
        """Kept harmonic terms: order, C (arcsec), phi (deg); order 0 as the signed constant."""
        out = [{"order": 0, "C_arcsec": self.C0_, "phi_deg": 0.0}] if self.keep_constant_ else []
        for i in [o for o in self.orders_ if o != 0]:
            a = self.coef_[self.labels_.index(f"A{i}")]
            b = self.coef_[self.labels_.index(f"B{i}")]
            c, p = amplitude_phase(a, b)
            out.append({"order": i, "C_arcsec": float(c), "phi_deg": float(p)})
        return out

    def other_coefficients(self) -> dict:
        """Coefficients of the non-harmonic effects (labels other than A<i>, B<i>)."""
        harmonic = {f"{ab}{i}" for i in self.orders_ for ab in "AB"}
        return {lab: float(v) for lab, v in zip(self.labels_, self.coef_) if lab not in harmonic}


def residual_without_constant(y, yhat, run) -> np.ndarray:
    """Residual with each run's unknown start constant removed (arcsec)."""
    res = np.asarray(y, float) - np.asarray(yhat, float)
    out = np.empty_like(res)
    for r in np.unique(run):
        m = run == r
        out[m] = res[m] - res[m].mean()
    return out


def peak_to_peak(values) -> float:
    values = np.asarray(values, float)
    return float(values.max() - values.min())


def leave_one_run_out(data: EncoderData, make_model):
    """The leave-one-run-out folds of ``data``: yield ``(run, held_out_mask, model, residual)``.

    ``model = make_model().fit(other runs)``; ``residual`` (arcsec) is the held-out run's,
    its own unknown start constant removed (one nuisance parameter), never anything else.
    The one implementation behind ``jointcal fit``'s CV RMS, ``select``'s CV path and diagnosis.
    """
    for r in data.runs:
        test = data.run == r
        model = make_model().fit(data.subset(~test))
        d = data.subset(test)
        yield r, test, model, residual_without_constant(d.error_arcsec, model.predict(d), d.run)
