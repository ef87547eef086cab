"""The robot side of diagnosis: folds by pose over the sample set, candidates per joint.

The model is :class:`pipeline.robot.model.estimator.RobotErrorModel` (Gauss-Newton over the sum of the
effects, pinocchio Jacobians). Poses are independent (each is its own tracker measurement),
so a candidate's held-out gain is tested with a paired t test over poses.
"""

from __future__ import annotations

from dataclasses import replace as _replace

import numpy as np

from ..core.crossval import CVResult
from ..core.effect import REGISTRY
from ..core.memory import release_freed_memory
from ..core.parallel import fork_imap
from ..core.se3 import ARCSEC_PER_MRAD
from ..robot.model.design import Design
from ..robot.model.normal import scaled_svd
from ..robot.model.weighting import start_weight
from ..robot.arm.effects import JH_MAX_ORDER, effect_classes, jh_orders  # noqa: F401 (re-exported)
from ..robot.model.estimate import N_FOLDS, cross_validate, fold_description, fold_ids
from ..robot.arm.kinematics import gravity_torques
from ..robot.model.budget import angle_budget, angle_variation, error_scale, lever_arms
from ..robot.model.plausibility import describe_implausible, implausible_parameters
from ..robot.model.noise import noise_estimate
from .linear import BOX_FACTOR, LinearProblem, box_configurations, channel_jacobian, effect_columns, region_folds
from .engine import paired_test

REDUNDANT = 0.02


def span_weights(J) -> np.ndarray:
    """The column span of J (m, k) without its orthonormal basis (m, r): W (k, r) such that the coordinates
    of any X (m, c) in an orthonormal basis of the span are ``W.T @ (J.T @ X)``.

    The span is that of J's columns scaled to unit norm, with singular values above 1e-9 of the largest
    (:func:`pipeline.robot.model.normal.scaled_svd`: a 6-DoF baseline's U would be as large as J again,
    docs/speed.md "Measurements behind the code")."""
    m, k = J.shape
    if k == 0 or m == 0:
        return np.zeros((k, 0))
    norms = np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    sv, Vt = scaled_svd(J, norms)
    keep = sv > 1e-9 * sv[0]
    return (Vt[keep].T / sv[keep]) / norms[:, None]


def campaigns_of(data) -> np.ndarray | None:
    """The campaigns (1-based, sorted) of poses stacked from several campaigns of one robot (contract section
    15: ``RobotData.campaign``); None for one campaign."""
    c = getattr(data, "campaign", None)
    if c is None:
        return None
    u = np.unique(c)
    return u if u.size > 1 else None


def pose_folds(data, n_folds: int = N_FOLDS) -> np.ndarray:
    """Each pose's fold by pose (n,) int: :func:`pipeline.robot.model.estimate.fold_ids`; with several
    campaigns, within each campaign (each fold holds out a share of every campaign's poses, so each
    campaign's own tracker frame is fitted on the rest of its poses)."""
    return _within_campaigns(data, lambda m: fold_ids(int(m.sum()), n_folds))


def campaign_region_folds(data, n_folds: int = N_FOLDS) -> np.ndarray:
    """Each pose's region of joint space (n,) int: :func:`pipeline.diagnosis.linear.region_folds`; with several
    campaigns, the regions of each campaign's own sampled joint box (fold r holds out region r of every
    campaign at once: what a gain is judged on is each campaign's poses away from those it was fitted on)."""
    return _within_campaigns(data, lambda m: region_folds(data.q_deg[m], n_folds))


def _within_campaigns(data, folds_of) -> np.ndarray:
    """``folds_of(mask)`` (the folds of the poses in ``mask``, (m,) int) applied to every campaign's poses
    on their own (one campaign: to all of them at once), shape (n,) int."""
    ids = campaigns_of(data)
    if ids is None:
        return folds_of(np.ones(data.n, bool))
    out = np.empty(data.n, int)
    for k in ids:
        m = data.campaign == k
        out[m] = folds_of(m)
    return out


def split_rms(cv: CVResult, data) -> list[dict] | None:
    """A cross-validated residual's RMS campaign by campaign: ``[{"index", "n", "rms"}]`` (the residual's unit;
    a 6-DoF residual with ``position_rms_mm`` beside); None for one campaign."""
    ids = campaigns_of(data)
    if ids is None:
        return None
    r = np.asarray(cv.residuals, float)
    r = r.reshape(r.shape[0], -1)
    out = []
    for k in ids:
        m = data.campaign == k
        e = {"index": int(k), "n": int(m.sum()), "rms": float(np.sqrt(np.mean(np.sum(r[m] ** 2, axis=1))))}
        if r.shape[1] == 6:
            e["position_rms_mm"] = float(np.sqrt(np.mean(np.sum(r[m, :3] ** 2, axis=1))))
        out.append(e)
    return out


def _evaluate_one(shared, k):
    """One candidate in a forked worker (the adapter and its shared fit come with the fork)."""
    adapter, base_effects, cands, data = shared
    return adapter._evaluate(cands[k], data, base_effects)


def _effect_label(e) -> str:
    """An effect with its parameters as the user wrote them, e.g. ``joint_map joints=[1]``."""
    params = {k: v for k, v in (getattr(e, "params", {}) or {}).items() if k != "range_deg"}
    return f"{e.name} {' '.join(f'{k}={v}' for k, v in sorted(params.items()))}".rstrip()


class RobotAdapter:
    """How diagnosis fits, cross-validates and explains a robot model.

    The baseline is fitted once on every sample pose; candidates are linear corrections to it
    (:mod:`pipeline.robot_linear`), cross-validated by pose (random folds) and by region of joint
    space (region folds), and looked at for plausibility before they are recommended.
    """

    unit = "mm"
    #: the effects diagnosis tries (a test may give a registry of its own)
    registry = REGISTRY
    parallel = False  # candidates are linear corrections to one shared fit: milliseconds each

    def __init__(self, robot, n_folds: int = N_FOLDS, workers: int = 1, repeat=None, refit_cache=None,
                 keep_linear: bool = True):
        self.robot = robot
        self.n_folds = n_folds
        self.workers = workers
        self.repeat = repeat
        self.refit_cache = refit_cache
        #: False (the diagnosis loop): the shared fit and the candidates' columns are let go once every
        #: candidate is measured (:meth:`linear_done`), before the recommended set's refits
        self.keep_linear = keep_linear
        self._lin = None
        self._blocks = {}
        #: the shared baseline's cross-validated residuals by fold kind ("random", "region"), once measured
        self.baseline_cv = {}

    def linear_done(self, data) -> None:
        """Diagnosis has measured every candidate on the shared fit; what follows refits (the recommended
        set, fold by fold). Without ``keep_linear`` the shared fit's dense columns (hundreds of MB for a 6-DoF
        baseline) and the candidates' are let go here, not held through those refits;
        the orientation weight, the shared fit's, is kept."""
        if self.keep_linear:
            return
        if data.has_orientation:
            self.weight(data)
        self._lin, self._blocks = None, {}
        release_freed_memory()

    # ------------------------------------------------------------------ model assembly
    def baseline_effects(self, spec, data):
        return list(spec.effects)

    def candidates(self, spec, data, base_effects):
        """Every robot effect's candidates (:meth:`pipeline.robot.arm.effects.RobotEffect.candidates`), in
        diagnosis order: the whole-robot effects, then the per-joint ones joint by joint, then the
        periodic joint errors per joint and order."""
        return [c for cls in effect_classes(self.registry) for c in cls.candidates(data, list(base_effects))]

    @staticmethod
    def add(base_effects, cand):
        return [*base_effects, cand]

    def reveal_problem(self, cand, data, base_effects):
        """Why these data cannot show ``cand`` on top of the baseline (or '').

        * a joint read by a grating enters the model at its true angle: its angle errors
          never reach the residuals (and the closed loop removes them);
        * a candidate whose signature lies (almost) in the span of the baseline's - an SMR
          offset on the flange against the last link's MDH parameters, a periodic error of a
          joint whose angle-error map is in the model - cannot be told apart from what the
          model already has: less than ``REDUNDANT`` of the norm of each of its Jacobian
          columns is outside the baseline's column space.
        """
        gj = getattr(data, "grating_joints", ())
        if getattr(cand, "on_joint_angle", False) and cand.target() in gj:
            return (f"joint {cand.target()} is read by its grating: the model takes its true angle, so its "
                    "angle errors never reach the residuals (and the closed loop removes them)")
        if base_effects:
            lin = self.linear(base_effects, data)
            blk = self.block(cand, data, base_effects)
            if blk.k == 0:
                return "it has no parameter these poses move"
            # the candidate's columns' products with the baseline's and its own (shared with its cross-validation)
            Gbc, Gcc = lin._products(blk)[:2]
            own = np.maximum(np.diag(Gcc), 1e-300)
            inside = np.sum((self._base_span(lin).T @ Gbc) ** 2, axis=0)
            frac = np.sqrt(np.clip(1.0 - inside / own, 0.0, 1.0))
            if np.all(frac < REDUNDANT):
                who = self._closest(lin, Gbc, own, base_effects)
                return (f"on these poses its signature is that of {who} already "
                        f"(at most {100 * frac.max():.1f} % of it lies outside): it cannot be told apart")
        return ""

    def _base_span(self, lin):
        """The baseline's column span as :func:`span_weights` (kept with the problem)."""
        if getattr(lin, "_W", None) is None:
            lin._W = span_weights(lin.base.J)
        return lin._W

    def _closest(self, lin, Gbc, own, base_effects) -> str:
        """The baseline effect(s) whose columns explain most of the candidate's signature (for the reason).

        ``Gbc`` (kb, kc) is J_base^T J_cand, ``own`` (kc,) the candidate's squared column norms."""
        names = lin.base.names
        if getattr(lin, "_W_effects", None) is None:
            lin._W_effects = []
            for e in lin.model.effects_ if lin.model is not None else []:
                own_names = set(e.parameter_names(self.robot))
                cols = [k for k, n in enumerate(names) if n in own_names]
                if cols:
                    lin._W_effects.append((_effect_label(e), cols, span_weights(lin.base.J[:, cols])))
        best, score = [], []
        total = np.sqrt(np.sum(own))
        for lab, cols, W in lin._W_effects:
            score.append(np.linalg.norm(W.T @ Gbc[cols]) / max(total, 1e-300))
            best.append(lab)
        if not best:
            return " + ".join(e.name for e in base_effects)
        k = int(np.argmax(score))
        return best[k] if score[k] > 0.9 else " + ".join(best)

    def _jacobian(self, effects, data):
        d = Design(self.robot, [e.prepared(self.robot, data) for e in effects], data)
        if data.has_orientation:
            d.weight = self.weight(data)
            _, _, J = d.pose_and_jacobian(np.zeros(d.p))
            J[:, 3:] *= d.weight
            return J.reshape(-1, d.p)
        _, J = d.predict_and_jacobian(np.zeros(d.p))
        return J.reshape(-1, d.p)

    # ------------------------------------------------------------------ shared baseline
    def linear(self, base_effects, data):
        """The baseline fitted once on every sample pose (cached for this list of effects)."""
        key = (id(data), tuple(id(e) for e in base_effects))
        if self._lin is None or self._lin[0] != key:
            folds = {"random": pose_folds(data, self.n_folds), "region": campaign_region_folds(data, self.n_folds)}
            if getattr(self, "_base_effects", None) is None:
                self._base_effects = list(base_effects)
            # the problem it replaces goes first: two 6-DoF baselines at once were the loop's peak (issue 32)
            self._lin, self._blocks = None, {}
            self._lin = (key, LinearProblem(self.robot, list(base_effects), data, folds,
                                            weight=getattr(data, "diagnosis_weight", None)
                                            or getattr(self, "_weight", None)))
            if data.has_orientation and getattr(self, "_weight", None) is None:
                self._weight = self._lin[1].weight
            self._blocks = {}
        return self._lin[1]

    def block(self, cand, data, base_effects):
        lin = self.linear(base_effects, data)
        if id(cand) not in self._blocks:
            self._blocks[id(cand)] = (cand, lin.block(cand))
        return self._blocks[id(cand)][1]

    def _linear_extra(self, effects, data):
        """The blocks of ``effects`` beyond the cached baseline, or None when not that baseline."""
        if self._lin is None:
            return None
        key, lin = self._lin
        n_base = len(key[1])
        if key[0] != id(data) or tuple(id(e) for e in effects[:n_base]) != key[1]:
            return None
        return lin, [self.block(e, data, effects[:n_base]) for e in effects[n_base:]]

    # ------------------------------------------------------------------ cross-validation
    def fold_description(self, data):
        return (f"{fold_description(data, self.n_folds)}; {self.n_folds} regions of joint space held out in turn "
                "to check that a gain carries over")

    def cross_validate(self, effects, data, folds: str = "random") -> CVResult:
        """Held-out residuals of the model ``effects``: linear corrections to the shared baseline
        when ``effects`` extends it, else the model refitted on every fold (random folds:
        :func:`pipeline.robot.model.estimate.cross_validate`, as ``jointcal fit``)."""
        lin_extra = self._linear_extra(list(effects), data)
        if lin_extra is not None:
            lin, blocks = lin_extra
            out = CVResult(lin.cv(blocks, folds), np.arange(data.n))
            if not blocks:
                # the baseline's own (what a diagnosis of several campaigns splits campaign by campaign)
                self.baseline_cv[folds] = out
            return out
        return self._refit(effects, data, folds)

    def refit_cv(self, effects, data) -> tuple[CVResult, CVResult]:
        """Held-out residuals of ``effects`` with every fold refitted (the estimator ``jointcal fit``
        uses, from the start), by pose and by region: how a recommended set is verified. Kept in
        ``refit_cache`` (a dict the loop shares between rounds: a round's verified set is the next
        round's baseline) under the effects' spec lines and the data."""
        key = (id(data), data.n, tuple(e.spec_lines() for e in effects), self.weight(data))
        cache = self.refit_cache if self.refit_cache is not None else {}
        if key not in cache:
            cache[key] = (self._refit(effects, data, "random"), self._refit(effects, data, "region"))
        return cache[key]

    def noise_estimate(self, data) -> dict:
        """The measurement's noise (3-D RMS, mm) from repeated poses (:func:`pipeline.robot.model.noise.noise_estimate`);
        with several campaigns, each campaign's own (pairs are never taken across two tracker stations), pooled."""
        repeat = getattr(self, "repeat", None)
        ids = campaigns_of(data)
        if ids is None:
            return noise_estimate(self.robot, data, repeat)
        parts = []
        for k in ids:
            rep = repeat.subset(repeat.campaign == k) if repeat is not None and repeat.campaign is not None else None
            parts.append((int(k), noise_estimate(self.robot, data.subset(data.campaign == k), rep)))
        known = [(k, x) for k, x in parts if x["rms"] is not None]
        n = sum(x["n"] for _, x in known)
        rms = float(np.sqrt(sum(x["n"] * x["rms"] ** 2 for _, x in known) / n)) if n else None
        return {"rms": rms, "n": int(n), "source": "; ".join(f"campaign {k}: {x['source']}" for k, x in parts)}

    def weight(self, data):
        """The orientation rows' weight (mm per mrad) of every residual this adapter compares on a 6-DoF
        campaign: its shared baseline's (variance components); None for positions only."""
        if not data.has_orientation:
            return None
        if getattr(data, "diagnosis_weight", None):
            # one yardstick for a whole diagnosis loop: the weight its first round found
            return data.diagnosis_weight
        if getattr(self, "_weight", None) is None:
            self._weight = self.linear(self._base_effects, data).weight if getattr(self, "_base_effects", None) \
                else start_weight(data)[0]
        return self._weight

    def _full(self, res, ori, data):
        """Position residuals (n, 3) mm and orientation errors (n, 3) mrad (predicted - measured) as one
        residual per pose: (n, 6), the orientation in mm-equivalent (:meth:`weight`)."""
        return np.hstack([res, -self.weight(data) * ori]) if ori is not None else res

    def _refit(self, effects, data, folds):
        if folds == "random":
            cv = cross_validate(self.robot, effects, data, self.n_folds, orientation_weight=self.weight(data),
                                folds=pose_folds(data, self.n_folds) if campaigns_of(data) is not None else None)
            return CVResult(self._full(cv.residuals, cv.extra.get("orientation"), data), np.arange(data.n))
        cv = cross_validate(self.robot, effects, data, self.n_folds, orientation_weight=self.weight(data),
                            folds=campaign_region_folds(data, self.n_folds))
        return CVResult(self._full(cv.residuals, cv.extra.get("orientation"), data), np.arange(data.n))

    def components(self, cv: CVResult, data) -> dict | None:
        """A 6-DoF campaign's full held-out residual split: the position RMS (mm) and the orientation RMS
        (arcsec); None for positions only."""
        r = np.asarray(cv.residuals, float)
        if r.ndim != 2 or r.shape[1] != 6 or not data.has_orientation:
            return None
        w = self.weight(data)
        return {"position_rms_mm": float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1)))),
                "orientation_rms_arcsec": float(np.sqrt(np.mean(np.sum((r[:, 3:] / w) ** 2, axis=1)))) * ARCSEC_PER_MRAD}

    def significance(self, cand, base: CVResult, with_cv: CVResult, data) -> dict:
        """Paired one-sided t test of the drop in squared held-out residual, pose by pose."""
        return paired_test(base, with_cv)

    def evaluate(self, base_effects, cands, data, say=None) -> list[dict]:
        """Every candidate added to the shared baseline: held-out residuals under the random and the
        region folds, and why it is implausible ('' when it is not). Progress with the time left."""
        import time

        say = say or (lambda s: None)
        self.linear(base_effects, data)     # the baseline fitted here, once: forked workers share it
        out, t0, last = [], time.perf_counter(), 0.0
        if self.workers > 1 and len(cands) > 1:
            results = fork_imap(_evaluate_one, (self, base_effects, cands, data), len(cands), self.workers, chunksize=4)
            for k, res in enumerate(results):
                out.append({"with": CVResult(res[0], np.arange(data.n)),
                            "region": CVResult(res[1], np.arange(data.n)), "refused": res[2]})
                now = time.perf_counter() - t0
                if now - last > 2.0 or k + 1 == len(cands):
                    last = now
                    say(f"candidates fitted: {k + 1}/{len(cands)} ({now:.0f} s, about "
                        f"{now / (k + 1) * (len(cands) - k - 1):.0f} s left)")
            return out
        for k, cand in enumerate(cands):
            r1, r2, why = self._evaluate(cand, data, base_effects)
            out.append({"with": CVResult(r1, np.arange(data.n)), "region": CVResult(r2, np.arange(data.n)),
                        "refused": why})
            now = time.perf_counter() - t0
            if now - last > 2.0 or k + 1 == len(cands):
                last = now
                left = now / (k + 1) * (len(cands) - k - 1)
                say(f"candidates fitted: {k + 1}/{len(cands)} ({now:.0f} s, about {left:.0f} s left)")
        return out

    def _evaluate(self, cand, data, base_effects):
        lin = self.linear(base_effects, data)
        blk = self.block(cand, data, base_effects)
        return lin.cv([blk], "random"), lin.cv([blk], "region"), self.implausible(cand, data, base_effects, [blk])

    def implausible(self, cand, data, base_effects, blocks) -> str:
        """Why the model with the candidate is not physically plausible ('' when it is).

        * its parameters beyond a real robot's bounds (:data:`pipeline.lm.PLAUSIBLE_BOUNDS`; for
          curves and polynomials, what they produce over the sampled joint range);
        * a joint angle error beyond the robot's own error budget anywhere in the sampled joint box:
          the largest error measured on these poses (nominal model) divided by the joint's lever arm
          to the SMR - a term of 1,000 arcsec on joint 2, cancelled by its neighbour on the sampled
          poses, is refused here;
        * a change of the predicted position beyond twice the measured error scale anywhere in the
          sampled joint box: a term that is wild between or beside the poses it was fitted on.
        """
        lin = self.linear(base_effects, data)
        parts, _ = lin.fit_all(blocks)
        blk, dc = blocks[-1], parts[-1]
        e = cand.prepared(self.robot, data)
        params = [{"name": n, "value": float(v * f), "unit": u} for n, v, (u, f) in zip(blk.names, dc, blk.units)]
        bad = implausible_parameters(e.checked_values(self.robot, params, data.q_deg))
        if bad:
            return f"parameters no real robot has: {describe_implausible(bad)}"
        scale, worst, dq, budget, lever = self._box_change(lin, base_effects, data, e, parts)
        over = np.flatnonzero(dq > budget)
        if over.size:
            j = int(over[np.argmax(dq[over] / budget[over])])
            return (f"it makes joint {j + 1}'s angle error vary by up to {np.degrees(dq[j]) * 3600:.0f} arcsec in the sampled "
                    f"joint box, beyond the robot's own error budget there ({np.degrees(budget[j]) * 3600:.0f} arcsec: "
                    f"the largest error measured, {scale:.3g} mm, at joint {j + 1}'s lever arm of {lever[j]:.0f} mm)")
        _, contrib = lin.fit_all(blocks)
        own = float(np.max(np.linalg.norm(sum(contrib), axis=1)))
        if worst > BOX_FACTOR * max(scale, own):
            return (f"it would predict {worst:.3g} mm of change somewhere in the sampled joint box, beyond "
                    f"{BOX_FACTOR:g} x the largest error measured ({scale:.3g} mm) and its largest change on the "
                    f"poses it was fitted on ({own:.3g} mm): wild between or beside those poses")
        return ""

    def _box_change(self, lin, base_effects, data, cand_prepared, parts):
        """Largest change (mm) the refit predicts at random configurations in the sampled joint box,
        and the measured error scale (largest error of the nominal model on the sample poses)."""
        if getattr(lin, "_box", None) is None:
            qb = box_configurations(data.q_deg)
            n = len(qb)
            rng = np.random.default_rng(1)
            payload = np.full(n, float(np.median(data.payload_kg)))
            box = _replace(data, q_deg=qb, dir=rng.choice([-1, 1], size=(n, qb.shape[1])), payload_kg=payload,
                           temperature_c=np.full(n, float(np.median(data.temperature_c))),
                           torque_nm=gravity_torques(self.robot, qb, payload), measured_mm=None,
                           point_id=np.array([], dtype=object), measured_R=None, sigma_mm=None, sigma_arcsec=None,
                           # several campaigns: the box in the first campaign's frame, with the model robot's probe
                           campaign=None, mounting_offset=None)
            effects = lin.model.effects_ if lin.model is not None else []
            d = Design(self.robot, effects, box, lin.idx_model)
            Jext = channel_jacobian(d, lin.coef)
            Jb = d.parameter_jacobian(Jext).reshape(-1, d.p) \
                if d.p else np.zeros((3 * n, 0))
            if lin.model is not None:
                Jb = Jb[:, ~np.isin(d.names, lin.model.fixed_)]
            nominal = Design(self.robot, [], data).predict(np.zeros(0))
            scale = error_scale(data.measured_mm, nominal)
            # lever arm of each joint to the SMR (mm per rad of its angle), median over the sample poses
            lever = lever_arms(lin.Jext[:, :3], lin.idx_model[1].joints)
            lin._box = (box, Jext, Jb, scale, lever)
        box, Jext, Jb, scale, lever = lin._box
        Jc, _, _ = effect_columns(self.robot, cand_prepared, box, Jext, lin.idx_model)
        change = (Jb @ parts[0] if Jb.shape[1] else 0.0) + (Jc @ parts[-1] if Jc.shape[1] else 0.0)
        change = np.asarray(change).reshape(-1, 3)
        # the candidate's own joint angle errors (rad) at the box configurations
        dc = Design(self.robot, [cand_prepared], box, lin.idx_model)
        dQ = dc.configurations(parts[-1]) - dc.Q0 if dc.p else np.zeros_like(dc.Q0)
        # about its mean: a constant angle error is the joint's offset, which geometry carries
        dq = angle_variation(dQ[:, dc.idx.joints])
        budget = angle_budget(scale, lever)
        return scale, (float(np.max(np.linalg.norm(change, axis=1))) if change.size else 0.0), dq, budget, lever

    # ------------------------------------------------------------------ evidence
    def _signature(self, cand, data):
        """Jacobian of the SMR position w.r.t. the candidate's parameters at nominal: (n, 3, k); (n, 6, k) on a
        6-DoF campaign, the probe frame's turn in mm-equivalent (:meth:`weight`) below the position."""
        d = Design(self.robot, [cand.prepared(self.robot, data)], data)
        if data.has_orientation:
            d.weight = self.weight(data)
            _, _, J = d.pose_and_jacobian(np.zeros(d.p))
            J[:, 3:] *= d.weight
            return J, d.names, d.units
        _, J = d.predict_and_jacobian(np.zeros(d.p))
        return J, d.names, d.units

    def evidence(self, cand, base: CVResult, data) -> str:
        J, names, units = self._signature(cand, data)
        r = base.residuals.reshape(-1)
        X = J.reshape(-1, J.shape[-1])
        pen = cand.prepared(self.robot, data).penalty(self.robot, data.n)
        if pen is not None:
            # a smooth curve: fitted with its own smoothness penalty, reported as a whole
            coef = np.linalg.lstsq(np.vstack([X, pen]), np.concatenate([r, np.zeros(pen.shape[0])]), rcond=None)[0]
            share = 1.0 - float(np.sum((r - X @ coef) ** 2) / max(np.sum(r ** 2), 1e-300))
            unit, factor = units[0]
            amp = float(np.ptp(coef) / 2 * factor)
            return (f"the held-out residuals follow this effect's signature: a smooth curve of +-{amp:.3g} {unit} "
                    f"({len(names)} grid values) explains {100 * share:.1f} % of the residual variance")
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        fit = X @ coef
        dof = max(1, r.size - X.shape[1])
        s2 = float(np.sum((r - fit) ** 2) / dof)
        try:
            se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(X.T @ X)), 1e-300))
        except np.linalg.LinAlgError:
            se = np.full(coef.size, np.inf)
        t = coef / se
        k = int(np.argmax(np.abs(t)))
        unit, factor = units[k]
        share = 1.0 - float(np.sum((r - fit) ** 2) / max(np.sum(r ** 2), 1e-300))
        text = (f"the held-out residuals contain this effect's signature: {names[k]} = {coef[k] * factor:+.3g} {unit} "
                f"(t = {t[k]:.1f}); it explains {100 * share:.1f} % of the residual variance")
        return text

    def signature_variables(self, data) -> dict:
        out = {}
        n_joints = data.q_deg.shape[1]
        for j in range(n_joints):
            out[f"q{j + 1}"] = (data.q_deg[:, j], "deg", "continuous")
        for j in range(n_joints):
            out[f"gravity torque {j + 1}"] = (data.torque_nm[:, j], "N m", "continuous")
        for j in range(n_joints):
            out[f"direction of last motion {j + 1}"] = (data.dir[:, j].astype(float), "+1/-1", "categorical")
        out["temperature"] = (data.temperature_c, "degC", "continuous")
        out["payload"] = (data.payload_kg, "kg", "categorical" if np.unique(data.payload_kg).size <= 6 else "continuous")
        return out

    def residual_view(self, base: CVResult, data) -> list[dict]:
        """For every signature variable, the strongest linear trend of a residual component on it."""
        out = []
        for name, (values, unit, kind) in self.signature_variables(data).items():
            x = np.asarray(values, float)
            if np.ptp(x) == 0:
                out.append({"signature": name, "statistic": "constant in these data"})
                continue
            xc = (x - x.mean()) / x.std()
            best = None
            for c, axis in enumerate("xyz"):
                y = base.residuals[:, c] - base.residuals[:, c].mean()
                slope = float(xc @ y / (xc @ xc))
                s = float(np.sqrt(np.sum((y - slope * xc) ** 2) / max(1, y.size - 2) / (xc @ xc)))
                t = slope / s if s > 0 else 0.0
                if best is None or abs(t) > abs(best[2]):
                    best = (axis, slope, t)
            axis, slope, t = best
            out.append({"signature": name, "statistic": f"{axis}: {slope:+.3f} mm per standard deviation of {name} (t = {t:.1f})"})
        return out
