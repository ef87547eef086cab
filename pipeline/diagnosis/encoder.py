"""The encoder side of diagnosis: folds by run, candidates from the encoder vocabulary.

Diagnosis fits the effects jointly over runs (``pooled``: one unknown constant per run,
every other coefficient shared). The paper's per-run averaging cannot separate effects
that are collinear within a run but not across runs (a temperature that rises with time
looks like drift inside one run), so the pooled fit is the fair judge of every candidate.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from ..core.crossval import CVResult
from ..encoder.aliasing import max_full_order
from ..encoder.effects import Direction, Drift, EncoderData, Harmonic, Temperature
from ..encoder.evaluate import cross_validate
from ..encoder.harmonic import amplitude_phase, analyse_runs, lsq_coefficients
from ..encoder.model import circular_range_deg
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
        have = {e.name for e in base_effects}
        out = [cls() for cls in (Direction, Drift, Temperature) if cls.name not in have]
        kept = set()
        for e in base_effects:
            if isinstance(e, Harmonic):
                kept |= set(e.orders())
        out += [Harmonic(orders=[i]) for i in range(1, self._n_max(data) + 1) if i not in kept]
        return out

    @staticmethod
    def add(base_effects, cand):
        if isinstance(cand, Harmonic):
            merged, done = [], False
            for e in base_effects:
                if isinstance(e, Harmonic) and not done:
                    merged.append(Harmonic(orders=sorted(set(e.orders()) | set(cand.orders()))))
                    done = True
                else:
                    merged.append(e)
            return merged if done else [*base_effects, cand]
        return [*base_effects, cand]

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
        p_het = float(stats.chi2.sf(Q, k * (R - 1))) if R > 1 else 1.0
        if p_het >= 0.05 or R <= k:
            chi = float(bf @ Wsum @ bf)
            return {"stat": float(np.sqrt(chi)), "p": float(stats.chi2.sf(chi, k)),
                    "method": f"fixed effects over {R} runs (runs agree: heterogeneity p = {p_het:.2g})"}
        mean = bs.mean(axis=0)
        S = np.cov(bs.T, ddof=1).reshape(k, k)
        T2 = float(R * mean @ np.linalg.solve(S, mean))
        F = T2 * (R - k) / (k * (R - 1))
        return {"stat": float(np.sqrt(T2)), "p": float(stats.f.sf(F, k, R - k)),
                "method": f"Hotelling T2 over {R} runs (runs disagree: heterogeneity p = {p_het:.2g})"}

    # ------------------------------------------------------------------ evidence
    def evidence(self, cand, base: CVResult, data) -> str:
        r = base.residuals[:, 0]
        if isinstance(cand, Harmonic):
            i = cand.orders()[0]
            amps, phases = [], []
            for run in data.runs:
                m = data.run == run
                A, B = lsq_coefficients(data.theta_deg[m], r[m], [0, i])
                c, p = amplitude_phase(A[1], B[1])
                amps.append(c)
                phases.append(p)
            labels, X = cand.columns(data)
            coef, t = _regress(r, X, data.run)
            c, p = amplitude_phase(coef[0], coef[1])
            return (f"order {i} in the held-out residuals: {c:.2f} arcsec at phase {p:.0f} deg (t = {max(abs(t)):.1f}); "
                    f"per run {min(amps):.2f}-{max(amps):.2f} arcsec, phases within {circular_range_deg(phases):.0f} deg")
        labels, X = cand.columns(data)
        coef, t = _regress(r, X, data.run)
        if isinstance(cand, Direction):
            fwd, bwd = r[data.direction > 0], r[data.direction < 0]
            return (f"held-out residual approaching forwards minus backwards = {fwd.mean() - bwd.mean():+.2f} arcsec "
                    f"(fitted half-hysteresis {coef[0]:+.2f} arcsec, t = {t[0]:.1f})")
        if isinstance(cand, Drift):
            return (f"held-out residual grows {coef[0]:+.2f} arcsec per hour within runs (t = {t[0]:.1f}); "
                    f"runs last {np.ptp(data.time_s) / 60:.0f} min at most")
        if isinstance(cand, Temperature):
            return (f"held-out residual changes {coef[0]:+.2f} arcsec per K of temperature (t = {t[0]:.1f}); "
                    f"temperature spans {np.nanmin(data.temperature_c):.1f}-{np.nanmax(data.temperature_c):.1f} degC")
        return f"regression of residuals on the effect's signature: t = {np.max(np.abs(t)):.1f}"

    def signature_variables(self, data) -> dict:
        """What to plot the held-out residuals against: name -> (values (n,), unit, kind).

        kind is "continuous" or "categorical"; "angle" variables also get a spectrum.
        """
        out = {"joint angle": (data.theta_deg, "deg", "angle")}
        if data.time_s is not None:
            out["time within run"] = (data.time_s / 60.0, "min", "continuous")
        if data.temperature_c is not None:
            out["temperature"] = (data.temperature_c, "degC", "continuous")
        out["direction of approach"] = (data.direction.astype(float), "+1/-1", "categorical")
        out["run"] = (data.run.astype(float), "", "categorical")
        return out

    def residual_view(self, base: CVResult, data) -> list[dict]:
        """Residual against every signature an encoder effect would leave (for the JSON and report)."""
        r = base.residuals[:, 0]
        out = []
        A, B = lsq_coefficients(data.theta_deg, r, range(self._n_max(data) + 1))
        C, _ = amplitude_phase(A, B)
        top = np.argsort(C[1:])[::-1][:3] + 1
        out.append({"signature": "joint angle (spectrum)", "statistic": ", ".join(f"order {i}: {C[i]:.2f} arcsec" for i in top)})
        if data.time_s is not None:
            coef, t = _regress(r, (data.time_s / 3600.0)[:, None], data.run)
            out.append({"signature": "time within run", "statistic": f"{coef[0]:+.2f} arcsec/h (t = {t[0]:.1f})"})
        if data.temperature_c is not None:
            coef, t = _regress(r, (data.temperature_c - 20.0)[:, None], data.run)
            out.append({"signature": "temperature", "statistic": f"{coef[0]:+.2f} arcsec/K (t = {t[0]:.1f})"})
        if np.unique(data.direction).size > 1:
            d = r[data.direction > 0].mean() - r[data.direction < 0].mean()
            out.append({"signature": "direction of approach", "statistic": f"forward - backward {d:+.2f} arcsec"})
        return out


def _regress(r, X, run):
    """Coefficients and t values of r on X with one constant per run removed (arcsec units)."""
    X = np.asarray(X, float)
    Xc = X.copy()
    rc = np.asarray(r, float).copy()
    for g in np.unique(run):
        m = run == g
        Xc[m] -= Xc[m].mean(axis=0)
        rc[m] -= rc[m].mean()
    coef, *_ = np.linalg.lstsq(Xc, rc, rcond=None)
    dof = max(1, rc.size - Xc.shape[1] - np.unique(run).size)
    s2 = float(np.sum((rc - Xc @ coef) ** 2) / dof)
    try:
        cov = s2 * np.linalg.inv(Xc.T @ Xc)
        se = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    except np.linalg.LinAlgError:
        se = np.full(coef.size, np.inf)
    return coef, coef / se


def encoder_data_from_campaign(folder) -> EncoderData:
    return EncoderData.from_frame(ingest_encoder(folder))


__all__ = ["EncoderAdapter", "encoder_data_from_campaign", "per_run_harmonics"]
