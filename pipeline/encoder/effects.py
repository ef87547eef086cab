"""Encoder effects (contract section 3, domain ``encoder``) and the encoder's data.

The measurement is error_arcsec(theta) of one joint module, run by run. The encoder model is
linear: error = run constant + sum over effects of :meth:`EncoderEffect.columns` @ coef.
The base class and the registry are :mod:`pipeline.core.effect`; :data:`EFFECTS` is
registered by :mod:`pipeline.encoder` (its ``__init__``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.effect import Effect


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
    """

    theta_deg: np.ndarray
    error_arcsec: np.ndarray
    run: np.ndarray
    step: np.ndarray
    direction: np.ndarray
    time_s: np.ndarray | None = None
    temperature_c: np.ndarray | None = None

    @classmethod
    def from_frame(cls, frame) -> "EncoderData":
        def opt(col):
            if col not in frame or frame[col].isna().all():
                return None
            return frame[col].to_numpy(dtype=float)

        direction = frame["direction"].to_numpy(dtype=int) if "direction" in frame else np.ones(len(frame), int)
        return cls(
            theta_deg=frame["theta_deg"].to_numpy(dtype=float),
            error_arcsec=frame["error_arcsec"].to_numpy(dtype=float),
            run=frame["run"].to_numpy(dtype=int),
            step=frame["step"].to_numpy(dtype=int),
            direction=direction,
            time_s=opt("time_s"),
            temperature_c=opt("temperature_c"),
        )

    def subset(self, mask) -> "EncoderData":
        def cut(a):
            return None if a is None else a[mask]

        return EncoderData(self.theta_deg[mask], self.error_arcsec[mask], self.run[mask], self.step[mask],
                           self.direction[mask], cut(self.time_s), cut(self.temperature_c))

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


class EncoderEffect(Effect):
    domain = "encoder"

    def columns(self, data: EncoderData) -> tuple[list[str], np.ndarray]:
        """Regressors this effect adds: labels and a matrix of shape (n, k)."""
        raise NotImplementedError


def harmonic_columns(theta_deg, orders) -> tuple[list[str], np.ndarray]:
    """cos/sin regressors of ``orders`` (order 0 excluded: it is the run constant).

    Parameters
    ----------
    theta_deg : ndarray, shape (n,), deg
    orders : sequence of int

    Returns
    -------
    labels : list of str, ``A<i>``, ``B<i>`` for each order i >= 1
    X : ndarray, shape (n, 2 * k)
        Columns cos(i theta), sin(i theta), so that A_i cos + B_i sin = C_i sin(i theta + phi_i).
    """
    th = np.deg2rad(np.asarray(theta_deg, dtype=float))
    labels, cols = [], []
    for i in orders:
        if i == 0:
            continue
        labels += [f"A{i}", f"B{i}"]
        cols += [np.cos(i * th), np.sin(i * th)]
    X = np.column_stack(cols) if cols else np.empty((th.size, 0))
    return labels, X


class Harmonic(EncoderEffect):
    name = "harmonic"
    allowed_params = ("orders", "n_max", "average")
    explanation = ("Periodic error of encoder and reducer over one turn: eccentricity of the encoder "
                   "disc or magnet (order 1), tilt (order 2), reducer tooth and wave-generator orders "
                   "and magnetic pole orders (higher orders).")
    signature = "a sinusoid in the residual against joint angle; a peak at this order in the residual spectrum"

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


class Direction(EncoderEffect):
    name = "direction"
    explanation = ("Hysteresis or backlash in the reducer: the joint reads differently when the angle is "
                   "approached turning forwards than backwards, by a constant offset.")
    signature = "residuals of forward (+1) and backward (-1) approaches differ by a constant"

    def columns(self, data):
        return ["hysteresis_half_arcsec"], data.direction.astype(float)[:, None]

    def can_reveal(self, data):
        for r in data.runs:
            if np.unique(data.direction[data.run == r]).size > 1:
                return True, ""
        return False, "every run approaches its angles from one direction only; two-way runs are needed"


class Drift(EncoderEffect):
    name = "drift"
    explanation = ("Error that grows with time within a run: thermal growth of the joint or the fixture "
                   "while it runs, or mechanical creep of the mounting.")
    signature = "residual grows linearly with time since the run's start; the closure reading does not return to zero"

    def columns(self, data):
        return ["drift_arcsec_per_h"], (data.time_s / 3600.0)[:, None]

    def can_reveal(self, data):
        if data.time_s is None:
            return False, "the campaign has no timestamps"
        if np.ptp(data.time_s) <= 0:
            return False, "all readings share one timestamp"
        return True, ""


class Temperature(EncoderEffect):
    name = "temperature"
    explanation = ("Angle error proportional to temperature: thermal expansion of the encoder ring, the "
                   "reducer or the mounting changes the reading as the joint warms or cools.")
    signature = "residual correlates with the temperature change within a run"

    def columns(self, data):
        return ["temperature_arcsec_per_K"], (data.temperature_c - 20.0)[:, None]

    def can_reveal(self, data):
        if data.temperature_c is None:
            return False, "the campaign records no temperature"
        spread = max((np.ptp(data.temperature_c[data.run == r]) for r in data.runs), default=0.0)
        if spread < 0.05:
            return False, "temperature does not change within a run (a constant per run is absorbed by the run's unknown start error)"
        return True, ""


#: the encoder vocabulary, registered by pipeline.encoder
EFFECTS = (Harmonic, Direction, Drift, Temperature)
