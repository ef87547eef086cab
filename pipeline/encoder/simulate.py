"""Stage ``simulate``: synthetic campaigns with stated physics (the shipped fixtures).

Encoder (polygon + autocollimator, paper 1)
-------------------------------------------
The joint's true angle error is

    e_r(theta) = sum_i C_i (1 + a_ri) sin(i theta + phi_i + p_ri)     published orders (Eqs. 7, 8)
               + sum_j c_j sin(j theta + psi_rj)                      weaker orders, phase wandering
               + (a hidden effect, when asked: see hidden_encoder_effect) + noise

per run r: a_ri ~ N(0, amp_spread), p_ri ~ N(0, phase_spread_i) is the run-to-run spread of
Figure 4; psi_rj is drawn per run (the weak orders' phases wander); a few weak orders keep
a fixed phase (stable but small). A run starts with the polygon's face 0 nulled at true
angle 0, turns the joint one face pitch at a time and nulls the autocollimator each time,
imperfectly: the autocollimator reads the residual ``u ~ U(-nulling, nulling)`` arcsec. The
true angle at step k is k * pitch + u_k; the encoder reads true angle + e_r(true angle)
+ reading noise. The truth (all drawn parameters) is written outside the campaign folder.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.files import write_json, write_text
from .effects import ARCSEC_PER_DEG, EFFECTS, REFERENCE_TEMPERATURE_C, effect_class


class SimulatedRun:
    """One simulated run while the hidden effect is injected into it (all angles deg, errors arcsec).

    An effect's :meth:`~pipeline.encoder.effects.EncoderEffect.inject` may append terms
    ``(order, C_arcsec, phi_deg)`` to ``components`` (errors of the joint over its angle),
    append arrays of shape (n,) to ``error_terms`` (added to the reading's error), replace
    ``temperature_c`` or ``true_deg``, and set ``setting`` (the polygon face the run starts
    on; then written as the ``setting`` column) and ``face`` (face of each reading).
    """

    def __init__(self, number, seed, faces, steps, nominal_deg, direction, time_s, temperature_c, true_deg, components):
        self.number, self.seed, self.faces = number, seed, faces
        self.steps, self.nominal_deg, self.direction = steps, nominal_deg, direction
        self.time_s, self.temperature_c, self.true_deg = time_s, temperature_c, true_deg
        self.components = components
        self.error_terms: list[np.ndarray] = []
        self.setting: int | None = None
        self.face: np.ndarray | None = None

    def lab_temperature(self, swing_k: float) -> np.ndarray:
        """The run's lab temperature with another swing (see :func:`lab_temperature`)."""
        return lab_temperature(self.seed, self.number, self.time_s, swing_k=swing_k)

# Published models (paper 1, Eqs. 7 and 8): order -> (C arcsec, phi deg)
PAPER_MODELS = {
    "a": {1: (14.10, 243.75), 4: (6.91, 26.73), 8: (18.05, 46.50), 12: (6.66, 264.24),
          14: (33.36, 20.82), 15: (8.94, 57.88), 16: (19.60, 247.91)},
    "b": {1: (24.31, 15.81), 4: (10.18, 187.75), 7: (4.86, 147.06), 8: (13.85, 258.45),
          12: (4.68, 213.24), 14: (17.71, 115.24), 16: (8.64, 128.30)},
}

# Generator settings of the shipped fixture, one per module. Amplitudes in arcsec, phases in deg.
ENCODER_FIXTURE = {
    "a": {
        "seed": 20200328,
        "published": PAPER_MODELS["a"],
        "phase_spread_deg": {1: 9.0},      # order 1 of module a is not phase-stable in the paper
        "default_phase_spread_deg": 2.6,   # Figure 7: stable orders vary by about 10 deg
        "amp_spread": 0.03,
        "weak_wandering": {2: 3.0, 3: 2.75, 5: 2.55, 6: 2.3, 7: 2.55, 9: 2.05, 10: 2.05, 11: 1.85, 13: 2.3, 17: 1.6},
        "weak_stable": {},
        "noise_arcsec": 0.9,
        "nulling_arcsec": 1.5,
    },
    "b": {
        "seed": 20200368,
        "published": PAPER_MODELS["b"],
        "phase_spread_deg": {},
        "default_phase_spread_deg": 2.6,
        "amp_spread": 0.03,
        "weak_wandering": {2: 2.15, 3: 1.9, 5: 1.9, 9: 1.7, 10: 1.7, 11: 1.45, 13: 1.7, 15: 1.9, 17: 1.2},
        "weak_stable": {6: (2.0, 300.0)},  # stable phase but too small to keep (paper: order 6 of b)
        "noise_arcsec": 0.7,
        "nulling_arcsec": 1.5,
    },
}


def simulate_encoder(module: str, config: dict, runs: int = 6, faces: int = 36, two_way: bool = False,
                     start=dt.datetime(2020, 1, 6, 9, 0, tzinfo=dt.timezone.utc), hidden=None):
    """Simulate one joint module's campaign.

    Parameters
    ----------
    module : str
    config : dict
        See :data:`ENCODER_FIXTURE`.
    runs, faces : int
    two_way : bool
        Go round and come back (2 * faces + 1 readings, direction -1 on the way back).
    hidden : dict, optional
        Extra effect, ``{"effect": NAME, ...}`` as :func:`hidden_encoder_effect` draws it (e.g.
        ``{"effect": "direction", "arcsec": h}``); the effect's class injects it
        (:meth:`pipeline.encoder.effects.EncoderEffect.inject` on a :class:`SimulatedRun`).

    Returns
    -------
    frame : DataFrame in the contract's encoder format
    truth : dict of every drawn parameter
    """
    rng = np.random.default_rng(config["seed"])
    pitch = 360.0 / faces
    published = config["published"]
    rows, truth_runs = [], []
    hidden = hidden or {}
    hidden_cls = effect_class(hidden["effect"]) if hidden else None
    for r in range(1, runs + 1):
        comp = []
        for i, (C, phi) in sorted(published.items()):
            spread = config["phase_spread_deg"].get(i, config["default_phase_spread_deg"])
            comp.append((i, C * (1 + rng.normal(0, config["amp_spread"])), phi + rng.normal(0, spread)))
        for j, c in sorted(config["weak_wandering"].items()):
            comp.append((j, c * (1 + rng.normal(0, 0.1)), rng.uniform(0, 360)))
        for j, (c, psi) in sorted(config["weak_stable"].items()):
            comp.append((j, c, psi + rng.normal(0, 3.0)))

        k = np.arange(faces + 1)
        steps = np.concatenate([k, k[-2::-1]]) if two_way else k
        direction = np.concatenate([np.ones(faces + 1), -np.ones(faces)]) if two_way else np.ones(faces + 1)
        n = steps.size
        nominal = steps * pitch
        ac = np.round(rng.uniform(-config["nulling_arcsec"], config["nulling_arcsec"], n), 2)
        true_deg = nominal + ac / ARCSEC_PER_DEG
        t_start = start + dt.timedelta(days=3 * (r - 1), minutes=float(rng.uniform(0, 120)))
        t_s = np.cumsum(np.concatenate([[0.0], rng.uniform(50, 70, n - 1)]))
        rng.normal(0, 0.1)  # kept so the main random stream (and the fixture) is unchanged
        temp = lab_temperature(config["seed"], r, t_s)
        noise = rng.normal(0, config["noise_arcsec"], n)
        run = SimulatedRun(number=r, seed=config["seed"], faces=faces, steps=steps, nominal_deg=nominal,
                           direction=direction, time_s=t_s, temperature_c=temp, true_deg=true_deg, components=comp)
        if hidden_cls is not None:
            hidden_cls.inject(hidden, run)
        temp, true_deg = run.temperature_c, run.true_deg
        orders = np.array([c[0] for c in comp], float)
        amps = np.array([c[1] for c in comp])
        phases = np.deg2rad([c[2] for c in comp])

        def err(theta_deg):
            th = np.deg2rad(np.asarray(theta_deg, float))[:, None]
            return (amps * np.sin(orders * th + phases)).sum(axis=1)

        e = err(true_deg) + noise
        for term in run.error_terms:
            e = e + term
        if config.get("error_of") == "reading":
            # error as a function of the joint's own reading (the contract's theta): solve
            # reading = true + e(reading) by fixed-point iteration (|de/dtheta| << 1)
            other = e - err(true_deg)  # noise and any hidden non-harmonic effect
            reading = true_deg + e / ARCSEC_PER_DEG
            for _ in range(4):
                reading = true_deg + (err(reading) + other) / ARCSEC_PER_DEG
            e = (reading - true_deg) * ARCSEC_PER_DEG
        encoder = true_deg + e / ARCSEC_PER_DEG
        stamps = [(t_start + dt.timedelta(seconds=float(s))).strftime("%Y-%m-%dT%H:%M:%SZ") for s in t_s]
        for s in range(n):
            row = {"module": module, "run": r, "step": s, "nominal_deg": nominal[s],
                   "encoder_deg": np.mod(encoder[s], 360.0), "autocollimator_arcsec": ac[s],
                   "direction": int(direction[s]), "timestamp": stamps[s],
                   "temperature_c": round(float(temp[s]), 2)}
            if run.setting is not None:
                row["setting"] = run.setting
            rows.append(row)
        truth_runs.append({"run": r, "components": [{"order": int(o), "C_arcsec": float(a), "phi_deg": float(np.rad2deg(p) % 360)}
                                                   for o, a, p in zip(orders, amps, phases)]})
    frame = pd.DataFrame(rows)
    # "generator": this function's name when the shipped truth (raw/truth) was written (now
    # pipeline.encoder.simulate.simulate_encoder); kept so that `make fixtures` rewrites it byte for byte
    truth = {"module": module, "generator": "pipeline.simulate.simulate_encoder", "config": _plain(config),
             "hidden": hidden, "runs": truth_runs}
    return frame, truth


def lab_temperature(seed: int, run: int, t_s, swing_k: float = 0.4):
    """Temperature (degC) during a run: its own start, trend and slow wander per run.

    A separate random stream (seed, run) so that the temperature does not change the other
    draws. ``swing_k`` scales how much it moves within a run (about +-swing_k K).
    """
    g = np.random.default_rng([seed, run, 11])
    u = np.asarray(t_s, float) / max(float(t_s[-1]), 1.0)
    wander = sum(g.normal(0, swing_k / 3) * np.sin(np.pi * (k + 1) * u + g.uniform(0, 2 * np.pi)) for k in range(3))
    return REFERENCE_TEMPERATURE_C + g.normal(0, 0.5) + g.uniform(-swing_k, swing_k) * u + wander


def _plain(obj):
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, tuple):
        return [_plain(v) for v in obj]
    return obj


def format_encoder_csv(frame: pd.DataFrame) -> str:
    """Contract CSV text with fixed number formats (same data, same bytes)."""
    out = frame.copy()
    out["nominal_deg"] = out["nominal_deg"].map(lambda v: f"{v:.1f}")
    out["encoder_deg"] = out["encoder_deg"].map(lambda v: f"{v:.7f}")
    out["autocollimator_arcsec"] = out["autocollimator_arcsec"].map(lambda v: f"{v:.2f}")
    out["temperature_c"] = out["temperature_c"].map(lambda v: f"{v:.2f}")
    return out.to_csv(index=False, lineterminator="\n")


def write_encoder_campaign(out_dir, module: str, frame: pd.DataFrame, truth: dict | None = None, truth_dir=None):
    """Write a simulated module as ``<out_dir>/<module>/<module>_run<r>.csv`` (and its truth
    as ``<truth_dir>/<module>.json``, outside the campaign). Returns the campaign folder."""
    folder = Path(out_dir) / module
    folder.mkdir(parents=True, exist_ok=True)
    for r, g in frame.groupby("run", sort=True):
        write_text(folder / f"{module}_run{r}.csv", format_encoder_csv(g))
    if truth is not None and truth_dir is not None:
        write_json(Path(truth_dir) / f"{module}.json", truth)
    return folder


def hidden_encoder_effect(text: str, seed: int) -> dict:
    """Parse ``EFFECT[:TARGET]`` and draw a realistic size for it (seeded).

    Sizes are drawn by the effect's class (:meth:`~pipeline.encoder.effects.EncoderEffect.hidden`)
    between "barely above the reading noise" and "large": direction 1-8 arcsec half-hysteresis,
    drift 2-15 arcsec/h, temperature 1-6 arcsec/K, harmonic 2-10 arcsec at a random phase,
    polygon face errors of 1-4 arcsec RMS with runs at several settings.
    """
    rng = np.random.default_rng([seed, 7])
    name, _, target = text.partition(":")
    try:
        cls = effect_class(name)
    except KeyError:
        cls = None
    if cls is None or not cls.hidden_syntax:
        raise ValueError(f"unknown hidden encoder effect {name!r}; use {hidden_effects_help()}")
    return cls.hidden(rng, target)


def hidden_effects_help() -> str:
    """The ``--hidden`` choices, from the effects that can be simulated."""
    names = [cls.hidden_syntax for cls in EFFECTS if cls.hidden_syntax]
    return ", ".join(names[:-1]) + " or " + names[-1]


def clean_encoder_config(module: str = "a", seed: int = 0, noise_arcsec: float = 0.9) -> dict:
    """A module with the paper's published terms, fixed from run to run, and iid reading noise.

    The error is defined on the joint's reading (the contract's ``theta_deg``), so a model
    with the right effects meets the noise floor ``noise_arcsec`` exactly. (Defined on the
    true angle, as in the fixture, the strong orders also leave sum and difference orders of
    about 0.1-0.2 arcsec on the reading axis, which a long clean campaign can resolve.)
    Used by tests and tutorials of diagnosis.
    """
    return {"seed": seed, "published": PAPER_MODELS[module], "phase_spread_deg": {},
            "default_phase_spread_deg": 0.0, "amp_spread": 0.0, "weak_wandering": {}, "weak_stable": {},
            "noise_arcsec": noise_arcsec, "nulling_arcsec": 1.5, "error_of": "reading"}


# ------------------------------------------------------------------------------ fleet
#: a simulated production week: modules of both published designs, each with its own
#: amplitudes and phases; some share a missing effect, a few are out of family
FLEET_FIXTURE = {"units": 50, "seed": 2026, "runs": 6,
                 "share_harmonic6": 0.3,   # a reducer batch: stable order 6, 2.5-3.5 arcsec (below the paper's 4)
                 "share_drift": 0.1,       # a warm-up drift of 6-12 arcsec/h during the runs
                 "out_of_family": {"bearing": 2, "loose_mount": 1}}


def fleet_unit(k: int, seed: int, role: str) -> tuple[str, dict, dict | None, dict]:
    """Name, generator config, hidden effect and truth note of the fleet's unit ``k``.

    ``role`` is ``"normal"``, ``"harmonic6"``, ``"drift"``, ``"bearing"`` (a damaged bearing:
    an order-3 error of 18-24 arcsec whose phase changes from run to run, so no fixed model can
    follow it) or ``"loose_mount"`` (the autocollimator reads with 10 arcsec noise).
    """
    g = np.random.default_rng([seed, k, 3])
    family = "a" if g.random() < 0.5 else "b"
    base = ENCODER_FIXTURE[family]
    published = {o: (C * g.uniform(0.8, 1.2), float((phi + g.normal(0, 15)) % 360))
                 for o, (C, phi) in PAPER_MODELS[family].items()}
    weak = {o: c * g.uniform(0.8, 1.2) for o, c in base["weak_wandering"].items()}
    config = {"seed": int(seed * 100000 + k), "published": published, "phase_spread_deg": {},
              "default_phase_spread_deg": 2.6, "amp_spread": 0.03, "weak_wandering": weak, "weak_stable": {},
              "noise_arcsec": float(g.uniform(0.6, 1.0)), "nulling_arcsec": 1.5}
    hidden = None
    if role == "harmonic6":
        hidden = {"effect": "harmonic", "order": 6, "arcsec": float(g.uniform(2.5, 3.5)),
                  "phase_deg": float(300 + g.normal(0, 10))}
    elif role == "drift":
        hidden = {"effect": "drift", "arcsec_per_h": float(g.choice([-1, 1]) * g.uniform(6, 12))}
    elif role == "bearing":
        config["weak_wandering"] = {**weak, 3: float(g.uniform(18, 24))}
    elif role == "loose_mount":
        config["noise_arcsec"] = 10.0
    name = f"m{k + 1:04d}"
    return name, config, hidden, {"unit": name, "family": family, "role": role}


def fleet_roles(n: int, seed: int, spec: dict | None = None) -> list[str]:
    """Role of every unit (seeded shuffle): shares of shared effects, a count of out-of-family ones."""
    spec = {**FLEET_FIXTURE, **(spec or {})}
    roles = []
    for name, count in spec["out_of_family"].items():
        roles += [name] * (count if n >= 20 else 0)
    roles += ["harmonic6"] * int(round(spec["share_harmonic6"] * n))
    roles += ["drift"] * int(round(spec["share_drift"] * n))
    roles = roles[:n] + ["normal"] * max(0, n - len(roles))
    return [str(r) for r in np.random.default_rng([seed, 5]).permutation(roles)]


def simulate_fleet(n: int, seed: int, runs: int = 6):
    """Yield ``(name, frame, truth)`` for ``n`` simulated joint modules (see :func:`fleet_unit`)."""
    for k, role in enumerate(fleet_roles(n, seed)):
        name, config, hidden, note = fleet_unit(k, seed, role)
        frame, truth = simulate_encoder(name, config, runs=runs, hidden=hidden)
        yield name, frame, {**note, **truth}
