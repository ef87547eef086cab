"""The robot side of diagnosis: folds by pose over the sample set, candidates per joint.

The model is :class:`pipeline.robot.calibrate.RobotErrorModel` (Gauss-Newton over the sum of the
effects, pinocchio Jacobians). Poses are independent (each is its own tracker measurement),
so a candidate's held-out gain is tested with a paired t test over poses.
"""

from __future__ import annotations

import numpy as np

from ..core.crossval import CVResult
from ..core.effect import REGISTRY
from ..robot.calibrate import Design
from ..robot.evaluate import N_FOLDS, cross_validate, fold_description
from .engine import paired_test

JH_MAX_ORDER = 16
REDUNDANT = 0.02
PER_JOINT = ("backlash", "compliance", "joint_harmonic", "chebyshev")
WHOLE = ("geometry", "base", "tool", "thermal")


def jh_orders(q_deg, top=16):
    """Orders of a periodic joint error worth a candidate on these poses.

    Over a joint range of R degrees, order k completes k R / 360 cycles. Below half a cycle
    every order looks alike (an offset, a slope and a gentle curve, mostly taken up by the
    joint's MDH offset), so order 1 stands for all of them; every order that completes half a
    cycle or more, up to ``top``, is a candidate of its own.
    """
    R = float(np.ptp(q_deg))
    if R <= 0:
        return []
    first = max(1, int(np.ceil(180.0 / R)))
    return sorted({1} | set(range(min(first, top + 1), top + 1)))


class RobotAdapter:
    """How diagnosis fits, cross-validates and explains a robot model."""

    unit = "mm"
    parallel = True  # each candidate is 5 L-M fits: worth a process each

    def __init__(self, robot, n_folds: int = N_FOLDS):
        self.robot = robot
        self.n_folds = n_folds

    # ------------------------------------------------------------------ model assembly
    def baseline_effects(self, spec, data):
        return list(spec.effects)

    def candidates(self, spec, data, base_effects):
        present = {}
        for e in base_effects:
            joints = e.joints() if hasattr(e, "joints") and "joints" in e.allowed_params else None
            present.setdefault(e.name, set()).update(joints or range(1, 7))
        out = []
        for name in WHOLE:
            if name not in present:
                out.append(REGISTRY.make("robot", name))
        for name in PER_JOINT:
            if name == "joint_harmonic":
                continue
            for j in range(1, 7):
                if j not in present.get(name, set()):
                    out.append(REGISTRY.make("robot", name, joints=[j]))
        # a periodic joint error, one candidate per joint and order (1..16 cycles per turn,
        # the orders of the first paper's joint modules), as for an encoder
        have_jh = {(j, k) for e in base_effects if e.name == "joint_harmonic" for j in e.joints() for k in e.orders()}
        for j in range(1, 7):
            for k in jh_orders(data.q_deg[:, j - 1]):
                if (j, k) not in have_jh:
                    out.append(REGISTRY.make("robot", "joint_harmonic", joints=[j], orders=[k]))
        return out

    @staticmethod
    def add(base_effects, cand):
        return [*base_effects, cand]

    def reveal_problem(self, cand, data, base_effects):
        """Why these data cannot show ``cand`` on top of the baseline (or '').

        * a joint read by a grating enters the model at its true angle: its angle errors
          never reach the residuals (and the closed loop removes them);
        * a candidate whose signature lies (almost) in the span of the baseline's - an SMR
          offset on the flange against the last link's MDH parameters - cannot be told
          apart from what the model already has: less than ``REDUNDANT`` of the norm of each
          of its Jacobian columns is outside the baseline's column space.
        """
        gj = getattr(data, "grating_joints", ())
        if cand.name in ("backlash", "compliance", "joint_harmonic") and cand.target() in gj:
            return (f"joint {cand.target()} is read by its grating: the model takes its true angle, so its "
                    "angle errors never reach the residuals (and the closed loop removes them)")
        if base_effects:
            Jc, _, _ = self._signature(cand, data)
            Jb = self._jacobian(base_effects, data)
            Xc = Jc.reshape(-1, Jc.shape[-1])
            U, sv, _ = np.linalg.svd(Jb / np.maximum(np.linalg.norm(Jb, axis=0), 1e-300), full_matrices=False)
            U = U[:, sv > 1e-9 * sv[0]]
            outside = Xc - U @ (U.T @ Xc)
            frac = np.linalg.norm(outside, axis=0) / np.maximum(np.linalg.norm(Xc, axis=0), 1e-300)
            if np.all(frac < REDUNDANT):
                return (f"on these poses its signature is that of {' + '.join(e.name for e in base_effects)} already "
                        f"(at most {100 * frac.max():.1f} % of it lies outside): it cannot be told apart")
        return ""

    def _jacobian(self, effects, data):
        d = Design(self.robot, list(effects), data)
        _, J = d.predict_and_jacobian(np.zeros(d.p))
        return J.reshape(-1, d.p)

    # ------------------------------------------------------------------ cross-validation
    def fold_description(self, data):
        return fold_description(data, self.n_folds)

    def cross_validate(self, effects, data) -> CVResult:
        """k-fold by pose (:func:`pipeline.robot.evaluate.cross_validate`, as ``jointcal fit``)."""
        return cross_validate(self.robot, effects, data, self.n_folds)

    def significance(self, cand, base: CVResult, with_cv: CVResult, data) -> dict:
        """Paired one-sided t test of the drop in squared held-out residual, pose by pose."""
        return paired_test(base, with_cv)

    # ------------------------------------------------------------------ evidence
    def _signature(self, cand, data):
        """Jacobian of the SMR position w.r.t. the candidate's parameters at nominal: (n, 3, k)."""
        d = Design(self.robot, [cand], data)
        _, J = d.predict_and_jacobian(np.zeros(d.p))
        return J, d.names, d.units

    def evidence(self, cand, base: CVResult, data) -> str:
        J, names, units = self._signature(cand, data)
        r = base.residuals.reshape(-1)
        X = J.reshape(-1, J.shape[-1])
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
        for j in range(6):
            out[f"q{j + 1}"] = (data.q_deg[:, j], "deg", "continuous")
        for j in range(6):
            out[f"gravity torque {j + 1}"] = (data.torque_nm[:, j], "N m", "continuous")
        for j in range(6):
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
