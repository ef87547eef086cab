"""Encoder effects (contract section 3, domain ``encoder``) and the encoder's data.

The measurement is error_arcsec(theta) of one joint module, run by run. The encoder model is
linear: error = run constant + sum over effects of :meth:`EncoderEffect.columns` @ coef.
The base class and the registry are :mod:`pipeline.core.effect`; :data:`EFFECTS` is
registered by :mod:`pipeline.encoder` (its ``__init__``).

Each effect class is the plugin unit: it declares in one place its parameters
(``allowed_params``) and regressors (:meth:`EncoderEffect.columns`), the candidates diagnosis
tries (:meth:`~pipeline.core.effect.Effect.candidates`), what it acts on (``acts_on``), whether
and how it is compensated (``compensable``, ``compensation``,
:meth:`EncoderEffect.compensation_columns`), its evidence and residual signature
(:meth:`~pipeline.core.effect.Effect.evidence`, :meth:`EncoderEffect.residual_signature`,
:meth:`EncoderEffect.signature_variable`), its explanation, and how the simulator hides it in a
campaign (:meth:`EncoderEffect.hidden`, :meth:`EncoderEffect.inject`). Diagnosis, simulation,
compensation and the command line loop over :data:`EFFECTS`. ``docs/adding-an-effect.md``
walks through adding one (the worked example is :class:`Polygon`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.effect import Effect
from .harmonic import amplitude_phase, circular_range_deg, harmonic_columns, lsq_coefficients  # noqa: F401 (harmonic_columns re-exported)

from ..core.units import ARCSEC_PER_DEG, REFERENCE_TEMPERATURE_C  # noqa: F401 (named once, for both domains)

#: s per h: drift is stated in arcsec per hour of time within the run
SECONDS_PER_HOUR = 3600.0


@dataclass(frozen=True)
class EncoderData:
    """Readings of one encoder campaign, as arrays of equal length ``n``.

    Attributes
    ----------
    theta_deg : ndarray, shape (n,), deg
        Joint angle of each reading (encoder reading mod 360).
    error_arcsec : ndarray, shape (n,), arcsec
        Derived angle error (contract section 1), relative to the run's first reading.
    run : ndarray, shape (n,), int
        Run number of each reading.
    step : ndarray, shape (n,), int
        Step within the run.
    direction : ndarray, shape (n,), int
        Direction of approach, +1 or -1.
    time_s : ndarray, shape (n,), s, or None
        Time since the run's first reading; None when the campaign has no timestamps.
    temperature_c : ndarray, shape (n,), degC, or None
        Temperature at the reading; None when not recorded.
    face : ndarray, shape (n,), int, or None
        Polygon face the autocollimator looked at: (setting + step) mod faces (contract
        section 1; derived by ingest). None when unknown.
    setting : ndarray, shape (n,), int, or None
        Polygon setting of the run (the face it starts on); None when the campaign does
        not record it (then every run starts on face 0).
    faces : ndarray, shape (n,), int, or None
        Faces of the polygon used for the reading.
    """

    theta_deg: np.ndarray
    error_arcsec: np.ndarray
    run: np.ndarray
    step: np.ndarray
    direction: np.ndarray
    time_s: np.ndarray | None = None
    temperature_c: np.ndarray | None = None
    face: np.ndarray | None = None
    setting: np.ndarray | None = None
    faces: np.ndarray | None = None

    @classmethod
    def from_frame(cls, frame) -> "EncoderData":
        def opt(col):
            if col not in frame or frame[col].isna().all():
                return None
            return frame[col].to_numpy(dtype=float)

        def opt_int(col):
            if col not in frame or frame[col].isna().any():
                return None
            return frame[col].to_numpy(dtype=np.int64)

        direction = frame["direction"].to_numpy(dtype=int) if "direction" in frame else np.ones(len(frame), int)
        return cls(
            theta_deg=frame["theta_deg"].to_numpy(dtype=float),
            error_arcsec=frame["error_arcsec"].to_numpy(dtype=float),
            run=frame["run"].to_numpy(dtype=int),
            step=frame["step"].to_numpy(dtype=int),
            direction=direction,
            time_s=opt("time_s"),
            temperature_c=opt("temperature_c"),
            face=opt_int("face"),
            setting=opt_int("setting"),
            faces=opt_int("faces"),
        )

    def subset(self, mask) -> "EncoderData":
        def cut(a):
            return None if a is None else a[mask]

        return EncoderData(self.theta_deg[mask], self.error_arcsec[mask], self.run[mask], self.step[mask],
                           self.direction[mask], cut(self.time_s), cut(self.temperature_c),
                           cut(self.face), cut(self.setting), cut(self.faces))

    @property
    def runs(self) -> np.ndarray:
        return np.unique(self.run)

    def distinct_angles(self, tol_deg: float = 0.05) -> int:
        """Number of distinct joint angles within one run (the largest over runs)."""
        best = 0
        for r in self.runs:
            th = np.sort(np.mod(self.theta_deg[self.run == r], 360.0))
            gaps = np.diff(np.concatenate([th, [th[0] + 360.0]]))
            best = max(best, int(np.count_nonzero(gaps > tol_deg)) or 1)
        return best


def regress_within_runs(r, X, run):
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


class EncoderEffect(Effect):
    """An encoder effect: a linear term of the error model, and everything else about it.

    Hooks beside those of :class:`pipeline.core.effect.Effect` (all optional but ``columns``):

    ``columns(data)``
        the regressors it adds to the model.
    ``candidates(data, present, n_max=None)`` (classmethod)
        the instances diagnosis tries, given the effects ``present`` (``n_max``: the highest
        harmonic order the campaign resolves).
    ``merge(other)``
        this effect with ``other`` of the same kind folded in (harmonic orders), or None to
        add ``other`` beside it.
    ``compensation_columns(theta_deg, model)``
        for a ``compensable`` effect: its regressors at joint angles alone (the table).
    ``evidence(residual, data)``, ``residual_signature(residual, data, n_max)`` (classmethod),
    ``signature_variable(data)`` (classmethod)
        what diagnosis says and plots; ``signature_rank`` orders them.
    ``hidden(rng, target)`` (classmethod) and ``inject(hidden, run)`` (classmethod)
        the simulator: draw a realistic size for ``--hidden NAME[:TARGET]``, and add the
        effect to one simulated run (see :class:`pipeline.encoder.simulate.SimulatedRun`).
    """

    domain = "encoder"
    #: order of the effect's residual signature in diagnosis's list and plots
    signature_rank: int = 100
    #: ``jointcal simulate encoder --hidden`` syntax for this effect (empty: cannot be simulated)
    hidden_syntax: str = ""
    #: the simulator needs two-way runs for a campaign to show it
    simulate_two_way: bool = False

    def columns(self, data: EncoderData) -> tuple[list[str], np.ndarray]:
        """Regressors this effect adds: labels and a matrix of shape (n, k)."""
        raise NotImplementedError

    @classmethod
    def candidates(cls, data, present, n_max=None):
        return [] if any(e.name == cls.name for e in present) else [cls()]

    def merge(self, other):
        return None

    def compensation_columns(self, theta_deg, model) -> tuple[list[str], np.ndarray]:
        raise NotImplementedError(f"effect '{self.name}' is not compensable: {self.compensation}")

    def evidence(self, residual, data) -> str:
        labels, X = self.columns(data)
        coef, t = regress_within_runs(residual, X, data.run)
        return f"regression of residuals on the effect's signature: t = {np.max(np.abs(t)):.1f}"

    @classmethod
    def residual_signature(cls, residual, data, n_max) -> dict | None:
        return None

    @classmethod
    def signature_variable(cls, data):
        """``(name, (values (n,), unit, kind))`` to plot residuals against, or None."""
        return None

    @classmethod
    def hidden(cls, rng, target: str) -> dict:
        raise ValueError(f"effect '{cls.name}' cannot be hidden in a simulated campaign")

    @classmethod
    def inject(cls, hidden: dict, run) -> None:
        raise NotImplementedError


def _explained(residual, groups, run) -> float:
    """Share of the run-centred residual's sum of squares that the means per group explain."""
    r = np.asarray(residual, float).copy()
    for g in np.unique(run):
        r[run == g] -= r[run == g].mean()
    total = float(r @ r)
    if total <= 0:
        return 0.0
    _, inv = np.unique(groups, return_inverse=True)
    means = np.bincount(inv, weights=r) / np.bincount(inv)
    within = r - means[inv]
    return 1.0 - float(within @ within) / total


class Harmonic(EncoderEffect):
    name = "harmonic"
    allowed_params = ("orders", "n_max", "average")
    explanation = ("Periodic error of encoder and reducer over one turn: eccentricity of the encoder "
                   "disc or magnet (order 1), tilt (order 2), reducer tooth and wave-generator orders "
                   "and magnetic pole orders (higher orders).")
    signature = "a sinusoid in the residual against joint angle; a peak at this order in the residual spectrum"
    acts_on = "joint angle"
    compensable = True
    compensation = ("a table of the error over joint angle (jointcal compensate): the controller "
                    "subtracts the modelled error from each reading")
    signature_rank = 0
    hidden_syntax = "harmonic:ORDER"

    def orders(self, default=()):
        orders = self.params.get("orders")
        if orders is None or isinstance(orders, str):
            return list(default)
        return sorted(int(o) for o in orders)

    def columns(self, data):
        return harmonic_columns(data.theta_deg, self.orders())

    def target(self):
        orders = self.orders()
        return orders[0] if len(orders) == 1 else None

    @classmethod
    def candidates(cls, data, present, n_max=None):
        kept = set()
        for e in present:
            if isinstance(e, Harmonic):
                kept |= set(e.orders())
        return [cls(orders=[i]) for i in range(1, (n_max or 0) + 1) if i not in kept]

    def merge(self, other):
        if not isinstance(other, Harmonic):
            return None
        return Harmonic(orders=sorted(set(self.orders()) | set(other.orders())))

    def compensation_columns(self, theta_deg, model):
        return harmonic_columns(theta_deg, model.orders_)

    def evidence(self, residual, data):
        r = residual
        i = self.orders()[0]
        amps, phases = [], []
        for run in data.runs:
            m = data.run == run
            A, B = lsq_coefficients(data.theta_deg[m], r[m], [0, i])
            c, p = amplitude_phase(A[1], B[1])
            amps.append(c)
            phases.append(p)
        labels, X = self.columns(data)
        coef, t = regress_within_runs(r, X, data.run)
        c, p = amplitude_phase(coef[0], coef[1])
        return (f"order {i} in the held-out residuals: {c:.2f} arcsec at phase {p:.0f} deg (t = {max(abs(t)):.1f}); "
                f"per run {min(amps):.2f}-{max(amps):.2f} arcsec, phases within {circular_range_deg(phases):.0f} deg")

    @classmethod
    def residual_signature(cls, residual, data, n_max):
        A, B = lsq_coefficients(data.theta_deg, residual, range(n_max + 1))
        C, _ = amplitude_phase(A, B)
        top = np.argsort(C[1:])[::-1][:3] + 1
        return {"signature": "joint angle (spectrum)", "statistic": ", ".join(f"order {i}: {C[i]:.2f} arcsec" for i in top)}

    @classmethod
    def signature_variable(cls, data):
        return "joint angle", (data.theta_deg, "deg", "angle")

    @classmethod
    def hidden(cls, rng, target):
        order = int(target) if target else int(rng.choice([2, 3, 5, 6, 9, 10, 11, 13]))
        return {"effect": "harmonic", "order": order, "arcsec": float(rng.uniform(2, 10)),
                "phase_deg": float(rng.uniform(0, 360))}

    @classmethod
    def inject(cls, hidden, run):
        run.components.append((int(hidden["order"]), float(hidden["arcsec"]), float(hidden.get("phase_deg", 0.0))))


class Direction(EncoderEffect):
    name = "direction"
    explanation = ("Hysteresis or backlash in the reducer: the joint reads differently when the angle is "
                   "approached turning forwards than backwards, by a constant offset.")
    signature = "residuals of forward (+1) and backward (-1) approaches differ by a constant"
    acts_on = "direction of approach"
    compensation = ("not in the angle table: a controller that knows the direction of the last motion "
                    "could add the fitted half-hysteresis with its sign")
    signature_rank = 3
    hidden_syntax = "direction"
    simulate_two_way = True

    def columns(self, data):
        return ["hysteresis_half_arcsec"], data.direction.astype(float)[:, None]

    def can_reveal(self, data):
        for r in data.runs:
            if np.unique(data.direction[data.run == r]).size > 1:
                return True, ""
        return False, "every run approaches its angles from one direction only; two-way runs are needed"

    def evidence(self, residual, data):
        r = residual
        labels, X = self.columns(data)
        coef, t = regress_within_runs(r, X, data.run)
        fwd, bwd = r[data.direction > 0], r[data.direction < 0]
        return (f"held-out residual approaching forwards minus backwards = {fwd.mean() - bwd.mean():+.2f} arcsec "
                f"(fitted half-hysteresis {coef[0]:+.2f} arcsec, t = {t[0]:.1f})")

    @classmethod
    def residual_signature(cls, residual, data, n_max):
        if np.unique(data.direction).size > 1:
            d = residual[data.direction > 0].mean() - residual[data.direction < 0].mean()
            return {"signature": "direction of approach", "statistic": f"forward - backward {d:+.2f} arcsec"}
        return None

    @classmethod
    def signature_variable(cls, data):
        return "direction of approach", (data.direction.astype(float), "+1/-1", "categorical")

    @classmethod
    def hidden(cls, rng, target):
        return {"effect": "direction", "arcsec": float(rng.uniform(1, 8))}

    @classmethod
    def inject(cls, hidden, run):
        run.error_terms.append(float(hidden["arcsec"]) * run.direction)


class Drift(EncoderEffect):
    name = "drift"
    explanation = ("Error that grows with time within a run: thermal growth of the joint or the fixture "
                   "while it runs, or mechanical creep of the mounting.")
    signature = "residual grows linearly with time since the run's start; the closure reading does not return to zero"
    acts_on = "time within the run"
    compensation = "not compensable by a table over joint angle: it belongs to the measurement run, not to the joint"
    signature_rank = 1
    hidden_syntax = "drift"

    def columns(self, data):
        return ["drift_arcsec_per_h"], (data.time_s / SECONDS_PER_HOUR)[:, None]

    def can_reveal(self, data):
        if data.time_s is None:
            return False, "the campaign has no timestamps"
        if np.ptp(data.time_s) <= 0:
            return False, "all readings share one timestamp"
        return True, ""

    def evidence(self, residual, data):
        labels, X = self.columns(data)
        coef, t = regress_within_runs(residual, X, data.run)
        return (f"held-out residual grows {coef[0]:+.2f} arcsec per hour within runs (t = {t[0]:.1f}); "
                f"runs last {np.ptp(data.time_s) / 60:.0f} min at most")

    @classmethod
    def residual_signature(cls, residual, data, n_max):
        if data.time_s is None:
            return None
        coef, t = regress_within_runs(residual, (data.time_s / SECONDS_PER_HOUR)[:, None], data.run)
        return {"signature": "time within run", "statistic": f"{coef[0]:+.2f} arcsec/h (t = {t[0]:.1f})"}

    @classmethod
    def signature_variable(cls, data):
        if data.time_s is None:
            return None
        return "time within run", (data.time_s / 60.0, "min", "continuous")

    @classmethod
    def hidden(cls, rng, target):
        return {"effect": "drift", "arcsec_per_h": float(rng.choice([-1, 1]) * rng.uniform(2, 15))}

    @classmethod
    def inject(cls, hidden, run):
        run.error_terms.append(float(hidden["arcsec_per_h"]) * run.time_s / SECONDS_PER_HOUR)


class Temperature(EncoderEffect):
    name = "temperature"
    explanation = ("Angle error proportional to temperature: thermal expansion of the encoder ring, the "
                   "reducer or the mounting changes the reading as the joint warms or cools.")
    signature = "residual correlates with the temperature change within a run"
    acts_on = "temperature"
    compensation = ("not in the angle table: a controller reading the joint's temperature could subtract "
                    "the fitted arcsec per K times (temperature - 20 degC)")
    signature_rank = 2
    hidden_syntax = "temperature"

    def columns(self, data):
        return ["temperature_arcsec_per_K"], (data.temperature_c - REFERENCE_TEMPERATURE_C)[:, None]

    def can_reveal(self, data):
        if data.temperature_c is None:
            return False, "the campaign records no temperature"
        spread = max((np.ptp(data.temperature_c[data.run == r]) for r in data.runs), default=0.0)
        if spread < 0.05:
            return False, "temperature does not change within a run (a constant per run is absorbed by the run's unknown start error)"
        return True, ""

    def evidence(self, residual, data):
        labels, X = self.columns(data)
        coef, t = regress_within_runs(residual, X, data.run)
        return (f"held-out residual changes {coef[0]:+.2f} arcsec per K of temperature (t = {t[0]:.1f}); "
                f"temperature spans {np.nanmin(data.temperature_c):.1f}-{np.nanmax(data.temperature_c):.1f} degC")

    @classmethod
    def residual_signature(cls, residual, data, n_max):
        if data.temperature_c is None:
            return None
        coef, t = regress_within_runs(residual, (data.temperature_c - REFERENCE_TEMPERATURE_C)[:, None], data.run)
        return {"signature": "temperature", "statistic": f"{coef[0]:+.2f} arcsec/K (t = {t[0]:.1f})"}

    @classmethod
    def signature_variable(cls, data):
        if data.temperature_c is None:
            return None
        return "temperature", (data.temperature_c, "degC", "continuous")

    @classmethod
    def hidden(cls, rng, target):
        return {"effect": "temperature", "arcsec_per_K": float(rng.choice([-1, 1]) * rng.uniform(1, 6))}

    @classmethod
    def inject(cls, hidden, run):
        run.temperature_c = run.lab_temperature(swing_k=3.0)
        run.error_terms.append(float(hidden["arcsec_per_K"]) * (run.temperature_c - REFERENCE_TEMPERATURE_C))


class Polygon(EncoderEffect):
    """The polygon's own face errors (contract section 3): one per face, summing to zero.

    A face error f_k (arcsec) is what the joint turns beyond the polygon's nominal angle
    when the autocollimator is nulled on face k; ingest subtracts ``face_error_arcsec[face k]``
    (the certificate in ``campaign.toml``, zeros without one) from each reading, so an
    uncertified f_k stays in ``error_arcsec`` as ``+f_k``. The regressors are one column per
    face but the last, ``+1`` on readings of face k and ``-1`` on readings of the last face
    (whose error is minus the sum of the others): the coefficients are the face errors as a
    certificate states them, ready for ``[polygon] face_error_arcsec``. Within one setting the face of a reading is a function of the joint angle,
    so the face errors and the joint's error are indistinguishable; runs starting on
    different faces (``setting``) tell them apart: fully when two settings differ by a
    number of faces d coprime with the number of faces F. Otherwise the face-error pattern
    of harmonic order m of the face index, with m * d / F whole for every difference d,
    looks the same from every setting and stays confounded with the joint's order m
    (settings 0, 12, 24 of 36 faces: orders 3, 6, 9, ...); the fit and the cross-validated
    RMS are unaffected, but those components of the face errors are not determined.
    """

    name = "polygon"
    explanation = ("The polygon's own face errors: each face of the reference polygon deviates a little "
                   "from its nominal angle (the certificate's deviations, summing to zero over the faces). "
                   "They are errors of the reference, not of the joint; runs started on different faces "
                   "(setting) separate them from the joint's error.")
    signature = "residuals follow the polygon face (setting + step) rather than the joint angle"
    acts_on = "polygon face (the reference, not the joint)"
    compensation = ("not compensated in the joint: an error of the reference polygon. The fitted face "
                    "errors can be written into campaign.toml as its certificate ([polygon] face_error_arcsec)")
    signature_rank = 4
    hidden_syntax = "polygon[:SETTINGS]"

    @staticmethod
    def n_faces(data) -> int:
        if data.faces is not None and data.faces.size:
            return int(data.faces.max())
        return int(data.face.max()) + 1 if data.face is not None and data.face.size else 0

    def columns(self, data):
        if data.face is None:
            raise ValueError("the polygon effect needs the face of each reading (ingest derives it)")
        F = self.n_faces(data)
        X = np.zeros((data.face.size, max(F - 1, 0)))
        last = data.face == F - 1
        for k in range(F - 1):
            X[data.face == k, k] = 1.0
            X[last, k] = -1.0
        return [f"face_error_arcsec_{k}" for k in range(F - 1)], X

    @staticmethod
    def face_errors(coef) -> np.ndarray:
        """All face errors (arcsec) from the coefficients (the last is minus the sum of the others)."""
        coef = np.asarray(coef, float)
        return np.append(coef, -coef.sum())

    def can_reveal(self, data):
        if data.face is None:
            return False, "the campaign has no polygon faces"
        if data.setting is None or np.unique(data.setting).size < 2:
            return False, ("every run starts on the same face, so the face errors follow the joint angle; "
                           "runs at two or more settings (column setting) are needed")
        return True, ""

    @classmethod
    def candidates(cls, data, present, n_max=None):
        # offered when some run starts off face 0 (column `setting`): a campaign that never
        # moves the polygon is the contract's default, and naming an effect it cannot show on
        # every such campaign would be noise (and change every existing diagnosis)
        if (data.setting is None or data.face is None or not np.any(data.setting != 0)
                or any(e.name == cls.name for e in present)):
            return []
        return [cls()]

    @staticmethod
    def _angle_step(data):
        F = Polygon.n_faces(data)
        return np.mod(np.round(data.theta_deg * F / 360.0).astype(np.int64), F)

    def evidence(self, residual, data):
        labels, X = self.columns(data)
        coef, t = regress_within_runs(residual, X, data.run)
        f = self.face_errors(coef)
        by_face = _explained(residual, data.face, data.run)
        by_angle = _explained(residual, self._angle_step(data), data.run)
        return (f"held-out residual follows the polygon face (face means explain {100 * by_face:.0f} % of it) "
                f"rather than the joint angle ({100 * by_angle:.0f} %) over {np.unique(data.setting).size} settings; "
                f"face errors {f.min():+.2f} to {f.max():+.2f} arcsec (RMS {np.sqrt(np.mean(f ** 2)):.2f}, "
                f"max |t| = {np.max(np.abs(t)):.1f})")

    @classmethod
    def residual_signature(cls, residual, data, n_max):
        if not cls().can_reveal(data)[0]:
            return None
        by_face = _explained(residual, data.face, data.run)
        by_angle = _explained(residual, cls._angle_step(data), data.run)
        return {"signature": "polygon face",
                "statistic": f"face means explain {100 * by_face:.0f} %, joint-angle means {100 * by_angle:.0f} %"}

    @classmethod
    def signature_variable(cls, data):
        if not cls().can_reveal(data)[0]:
            return None
        return "polygon face", (data.face.astype(float), "", "categorical")

    @classmethod
    def hidden(cls, rng, target):
        """Face errors of a 36-face polygon, 1-4 arcsec RMS, summing to zero; ``target``:
        the number of settings (default 3, see :func:`spread_settings`)."""
        faces = 36
        n_settings = int(target) if target else 3
        if not 1 <= n_settings <= faces:
            raise ValueError(f"polygon:{target}: the number of settings must be 1..{faces}")
        f = rng.normal(0.0, float(rng.uniform(1, 4)), faces)
        f = f - f.mean()
        return {"effect": "polygon", "face_error_arcsec": [round(float(v), 3) for v in f],
                "settings": spread_settings(n_settings, faces)}

    @classmethod
    def inject(cls, hidden, run):
        f = np.asarray(hidden["face_error_arcsec"], float)
        if f.size != run.faces:
            raise ValueError(f"the hidden polygon has {f.size} face errors; the simulated polygon has {run.faces} faces")
        settings = hidden.get("settings", [0])
        run.setting = int(settings[(run.number - 1) % len(settings)])
        run.face = np.mod(run.setting + run.steps, run.faces)
        # nulled on face k, whose normal is off by f_k, the joint has turned f_k further than the
        # polygon's nominal angle says (ingest subtracts a certificate's f_k again)
        run.true_deg = run.true_deg + f[run.face] / ARCSEC_PER_DEG


def spread_settings(n: int, faces: int) -> list[int]:
    """``n`` settings spread over the polygon, one face more than an even spread each, so
    that consecutive settings differ by a number of faces coprime with ``faces`` when one
    exists near faces / n (36 faces: 3 settings -> 0, 13, 26; 2 -> 0, 19)."""
    step = faces // n
    while step > 1 and math.gcd(step + 1, faces) != 1:
        step -= 1
    return [(j * (step + 1)) % faces for j in range(n)] if n > 1 else [0]


#: the encoder vocabulary, registered by pipeline.encoder (the order diagnosis tries them in)
EFFECTS = (Direction, Drift, Temperature, Harmonic, Polygon)


def effect_class(name: str) -> type[EncoderEffect]:
    """The encoder effect class of ``name`` (KeyError when there is none)."""
    for cls in EFFECTS:
        if cls.name == name:
            return cls
    raise KeyError(name)
