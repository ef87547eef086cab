"""The encoder side of diagnosis: folds by run, candidates from the encoder vocabulary.

Every effect-specific piece (candidate targets, evidence, residual signatures, what to plot
against) is a hook of the effect's class in :mod:`pipeline.encoder.effects`; this adapter
loops over :data:`~pipeline.encoder.effects.EFFECTS` and names none of them (but the harmonic
orders a spec leaves to the paper's selection rule).

Diagnosis fits the effects jointly over runs (``pooled``: one unknown constant per run,
every other coefficient shared). The paper's per-run averaging cannot separate effects
that are collinear within a run but not across runs (a temperature that rises with time
looks like drift inside one run), so the pooled fit is the fair judge of every candidate.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import special  # scipy.stats' chi2.sf and f.sf are special.chdtrc and fdtrc (2 s less to import)

from ..core.crossval import CVResult
from ..encoder.aliasing import max_full_order
from ..encoder.effects import EFFECTS, EncoderData, Harmonic
from ..encoder.evaluate import cross_validate
from ..encoder.harmonic import analyse_runs
from ..encoder.ingest import ingest_encoder
from ..encoder.selection import paper_rule
from .engine import paired_test


def per_run_harmonics(data: EncoderData, n_max: int) -> pd.DataFrame:
    """Per-run harmonics (orders 0..n_max) of an EncoderData: :func:`pipeline.encoder.harmonic.analyse_runs`."""
    frame = pd.DataFrame({"run": data.run, "step": data.step, "theta_deg": data.theta_deg,
                          "error_arcsec": data.error_arcsec, "direction": data.direction})
    return analyse_runs(frame, n_max=n_max)


class EncoderAdapter:
    """How diagnosis fits, cross-validates and explains an encoder model."""

    unit = "arcsec"

    def __init__(self, n_max=None):
        self.n_max = n_max

    def _n_max(self, data):
        return self.n_max if self.n_max is not None else max_full_order(data.distinct_angles())

    # ------------------------------------------------------------------ model assembly
    def baseline_effects(self, spec, data):
        effects = []
        for e in spec.effects:
            if isinstance(e, Harmonic) and not isinstance(e.params.get("orders"), list):
                n_max = int(e.params.get("n_max", self._n_max(data)))
                orders, _ = paper_rule(per_run_harmonics(data, n_max), data.runs, spec.select)
                e = Harmonic(orders=orders)
            effects.append(e)
        return effects

    def candidates(self, spec, data, base_effects):
        n_max = self._n_max(data)
        return [c for cls in EFFECTS for c in cls.candidates(data, base_effects, n_max=n_max)]

    @staticmethod
    def add(base_effects, cand):
        merged, done = [], False
        for e in base_effects:
            m = None if done else e.merge(cand)
            merged.append(e if m is None else m)
            done = done or m is not None
        return merged if done else [*base_effects, cand]

    # ------------------------------------------------------------------ cross-validation
    def fold_description(self, data):
        return f"leave-one-run-out, {data.runs.size} folds"

    def cross_validate(self, effects, data) -> CVResult:
        """Leave-one-run-out (:func:`pipeline.encoder.evaluate.cross_validate`, as ``jointcal fit``)."""
        return cross_validate(effects, data)

    def significance(self, cand, base: CVResult, with_cv: CVResult, data) -> dict:
        """Is the candidate's signature consistently in the data, run after run?

        Per run r, take the model *with* the candidate fitted on the other runs, and its
        held-out residual on run r with the candidate's own term added back (the partial
        residual: what is left for the candidate once every other effect is accounted for
        by out-of-run estimates). Regress it on the candidate's regressors within the run
        (run constant removed): coefficient b_r, covariance V_r from the within-run scatter.
        Cochran's Q says whether the runs agree beyond that scatter. If they agree, the
        fixed-effects mean is tested with chi-square; if they do not (a harmonic whose phase
        wanders from run to run) the run-to-run scatter is the noise and the mean is tested
        with Hotelling's T^2 over runs. Runs where the signature cannot be estimated (one
        direction only) are left out.
        """
        labels, X = cand.columns(data)
        k = X.shape[1]
        bs, Vs = [], []
        for run in data.runs:
            m = data.run == run
            model = with_cv.extra["models"][int(run)]
            idx = [model.labels_.index(lab) for lab in labels]
            part = with_cv.residuals[m, 0] + X[m] @ model.coef_[idx]
            # the model's other regressors are partialled out too: an out-of-run estimate of
            # a correlated term (drift vs. low harmonics in a one-way run) must not leak in
            _, full = model.design(data.subset(m))
            others = np.delete(full, idx, axis=1)
            Z = np.hstack([X[m], others]) if m.sum() > k + others.shape[1] + 3 else X[m]
            Z = Z - Z.mean(axis=0)
            rr = part - part.mean()
            Xr = Z[:, :k]
            if m.sum() <= Z.shape[1] + 1 or np.linalg.matrix_rank(Xr, tol=1e-9 * max(1.0, np.abs(Xr).max())) < k:
                continue
            try:
                ZtZ_inv = np.linalg.inv(Z.T @ Z)
            except np.linalg.LinAlgError:
                continue
            coef = ZtZ_inv @ (Z.T @ rr)
            s2 = float(np.sum((rr - Z @ coef) ** 2) / (m.sum() - Z.shape[1] - 1))
            bs.append(coef[:k])
            Vs.append(s2 * ZtZ_inv[:k, :k])
        R = len(bs)
        if R == 0:
            return paired_test(base, with_cv)
        bs, Vs = np.array(bs), np.array(Vs)
        W = np.array([np.linalg.inv(V) for V in Vs])
        Wsum = W.sum(axis=0)
        bf = np.linalg.solve(Wsum, np.einsum("rij,rj->i", W, bs))
        Q = float(sum((b - bf) @ w @ (b - bf) for b, w in zip(bs, W)))
        p_het = float(special.chdtrc(k * (R - 1), Q)) if R > 1 else 1.0
        if p_het >= 0.05 or R <= k:
            chi = float(bf @ Wsum @ bf)
            why = (f"runs agree: heterogeneity p = {p_het:.2g}" if p_het >= 0.05 else
                   f"{k} coefficients, too few runs to test over runs: heterogeneity p = {p_het:.2g}")
            return {"stat": float(np.sqrt(chi)), "p": float(special.chdtrc(k, chi)),
                    "method": f"fixed effects over {R} runs ({why})"}
        mean = bs.mean(axis=0)
        S = np.cov(bs.T, ddof=1).reshape(k, k)
        T2 = float(R * mean @ np.linalg.solve(S, mean))
        F = T2 * (R - k) / (k * (R - 1))
        return {"stat": float(np.sqrt(T2)), "p": float(special.fdtrc(k, R - k, F)),
                "method": f"Hotelling T2 over {R} runs (runs disagree: heterogeneity p = {p_het:.2g})"}

    # ------------------------------------------------------------------ evidence
    def evidence(self, cand, base: CVResult, data) -> str:
        """The candidate's own evidence (:meth:`pipeline.core.effect.Effect.evidence`)."""
        return cand.evidence(base.residuals[:, 0], data)

    def signature_variables(self, data) -> dict:
        """What to plot the held-out residuals against: name -> (values (n,), unit, kind).

        kind is "continuous" or "categorical"; "angle" variables also get a spectrum.
        One per effect that declares one (:meth:`EncoderEffect.signature_variable`), and the run.
        """
        out = {}
        for cls in sorted(EFFECTS, key=lambda c: c.signature_rank):
            var = cls.signature_variable(data)
            if var is not None:
                out[var[0]] = var[1]
        out["run"] = (data.run.astype(float), "", "categorical")
        return out

    def residual_view(self, base: CVResult, data) -> list[dict]:
        """Residual against every signature an encoder effect would leave (for the JSON and report)."""
        r = base.residuals[:, 0]
        n_max = self._n_max(data)
        views = (cls.residual_signature(r, data, n_max) for cls in sorted(EFFECTS, key=lambda c: c.signature_rank))
        return [v for v in views if v is not None]


def encoder_data_from_campaign(folder) -> EncoderData:
    return EncoderData.from_frame(ingest_encoder(folder))


__all__ = ["EncoderAdapter", "encoder_data_from_campaign", "per_run_harmonics"]
