"""Evaluation of the robot stages (the second paper's Section 3, Table 2, Figures 6-11).

* ``before``: the campaign's target points as measured with the nominal commands.
* ``kinematic``: open loop with commands from the calibrated MDH model (inverse correction
  so that the calibrated model reaches the nominal pose of the target).
* ``feedback``: Chebyshev model + joint mapping (Eqs. 22-24) + grating closed loop on
  joints 1-3 (Eq. 26); joints 4-6 stay open loop and keep their backlash.

The commands are executed by the virtual cell (rebuilt from its seed, never from the truth
file) or, for a real robot, measured again and passed as a tracker file whose point_ids
are ``<point_id>@kinematic`` / ``<point_id>@feedback`` (targets) and
``<point_id>@feedback`` (repeat rows, closed loop).

ISO 9283 multi-directional pose accuracy variation at each pose P_j:
``vAP = max over approach pairs (h, k) of || barycentre_h - barycentre_k ||`` (mm).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..core.crossval import CVResult
from .calibrate import Design, RobotErrorModel
from .chebyshev import chebyshev_estimator
from .simulate import EXECUTE, directions_from_sequence, rng_for

PAPER_TABLE2 = {"before": {"min_mm": 0.10, "max_mm": 0.76, "mean_mm": 0.42, "std_mm": 0.16},
                "kinematic": {"min_mm": 0.03, "max_mm": 0.42, "mean_mm": 0.24, "std_mm": 0.08},
                "feedback": {"min_mm": 0.03, "max_mm": 0.19, "mean_mm": 0.10, "std_mm": 0.04},
                "max_reduction_pct": 75.0}


def error_stats(err_mm) -> dict:
    """Absolute positioning error statistics (Eq. 27) of error vectors (n, 3) mm."""
    n = np.linalg.norm(np.asarray(err_mm, float), axis=1)
    return {"min_mm": float(n.min()), "max_mm": float(n.max()), "mean_mm": float(n.mean()),
            "std_mm": float(n.std(ddof=1)) if n.size > 1 else 0.0, "n": int(n.size)}


def table2(before, kinematic, feedback) -> dict:
    out = {"before": error_stats(before), "kinematic": error_stats(kinematic), "feedback": error_stats(feedback)}
    out["max_reduction_pct"] = 100.0 * (1.0 - out["feedback"]["max_mm"] / out["before"]["max_mm"])
    out["max_reduction_vs_kinematic_pct"] = 100.0 * (1.0 - out["feedback"]["max_mm"] / out["kinematic"]["max_mm"])
    out["paper"] = PAPER_TABLE2
    return out


def vap(labels_pose, labels_approach, xyz_mm) -> dict:
    """ISO 9283 multi-directional pose accuracy variation per pose (mm) and repeatability RP."""
    df = pd.DataFrame({"pose": labels_pose, "approach": labels_approach})
    xyz = np.asarray(xyz_mm, float)
    out = {}
    for pose, g in df.groupby("pose", sort=True):
        bary, rp = {}, {}
        for a, h in g.groupby("approach", sort=True):
            p = xyz[h.index.to_numpy()]
            c = p.mean(axis=0)
            bary[a] = c
            d = np.linalg.norm(p - c, axis=1)
            rp[a] = float(d.mean() + 3 * d.std(ddof=1)) if len(d) > 1 else 0.0
        keys = sorted(bary)
        v = max((np.linalg.norm(bary[a] - bary[b]) for i, a in enumerate(keys) for b in keys[i + 1:]), default=0.0)
        out[pose] = {"vAP_mm": float(v), "RP_mm": rp, "barycentres_mm": {k: bary[k].tolist() for k in keys}}
    return out


def execute_virtual(cell, robot, frame: pd.DataFrame, q_kinematic, q_feedback, seed) -> dict:
    """Run the kinematic and feedback commands and the repeat test on the virtual cell.

    Parameters
    ----------
    frame : DataFrame
        Ingested campaign (all sets, visiting order).
    q_kinematic, q_feedback : ndarray, shape (n_targets, 6), deg
        Commands of the targets (in the frame's target order); for the feedback run,
        joints 1-3 of ``q_feedback`` are also the grating loop's targets.

    Returns
    -------
    dict with measured positions (mm) ``kinematic``, ``feedback`` (targets), ``repeat_loop``
    (repeat rows, closed loop on joints 1-3) and the loop results.
    """
    tg = frame[frame["set"] == "target"]
    payload = tg["payload_kg"].to_numpy(float)
    temp = tg["temperature_c"].to_numpy(float)
    mid = (robot.lower_deg + robot.upper_deg) / 2
    rng = rng_for(seed, EXECUTE, 1)
    dk = directions_from_sequence(q_kinematic, start_deg=mid)
    Pk = cell.measure(cell.open_loop(q_kinematic, dk, payload, rng), rng, temp)
    rng = rng_for(seed, EXECUTE, 2)
    df = directions_from_sequence(q_feedback, start_deg=mid)
    qt, loop = cell.closed_loop(q_feedback, df, q_feedback[:, :3], payload, rng)
    Pf = cell.measure(qt, rng, temp)
    rep = frame[frame["set"] == "repeat"]
    out = {"kinematic": Pk, "feedback": Pf, "loop": loop}
    if len(rep):
        rng = rng_for(seed, EXECUTE, 3)
        joints = range(1, cell.robot.n_joints + 1)
        qr = rep[[f"q{j}" for j in joints]].to_numpy(float)
        dr = rep[[f"dir{j}" for j in joints]].to_numpy(int)
        qt, loop_r = cell.closed_loop(qr, dr, qr[:, :3], rep["payload_kg"].to_numpy(float), rng)
        out["repeat_loop"] = cell.measure(qt, rng, rep["temperature_c"].to_numpy(float))
        out["repeat_loop_cycles"] = loop_r["cycles"]
    return out


def fit_effects(robot, effects, data):
    """Fit a robot error model (a list of effects) on ``data``: the estimator diagnosis uses.

    Gauss-Newton with step halving; a model with Chebyshev terms is solved in the span of the
    leading singular directions, as the Chebyshev stage does (:func:`pipeline.robot.chebyshev.chebyshev_estimator`).
    """
    if any(e.name == "chebyshev" for e in effects):
        return chebyshev_estimator(robot, effects, "gauss-newton").fit(data)
    return RobotErrorModel(robot, effects, solver="gauss-newton").fit(data)


def heldout_fit(robot, effects, sample, target, model=None) -> dict:
    """Fit the spec's model on the sample poses; its error on the held-out target poses.

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
        The whole model (every stage's effects together).
    sample, target : RobotData
        Sample poses (fit) and target poses (held out), with tracker positions ``measured_mm``
        of shape (n, 3), mm.

    Returns
    -------
    dict: ``before`` (nominal model) and ``after`` (fitted model) error statistics of the targets
    (mm, Eq. 27), ``rms_before_mm`` / ``rms_after_mm`` (RMS of the 3-D error), ``max_reduction_pct``,
    ``rms_reduction_pct``, the fitted ``parameters`` and the fit's identifiability.
    ``model``: the model already fitted on ``sample`` (else it is fitted here).
    """
    model = model if model is not None else fit_effects(robot, effects, sample)
    nominal = Design(robot, [], target).predict(np.zeros(0))
    before = target.measured_mm - nominal
    after = target.measured_mm - model.predict(target)

    def rms(e):
        return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))

    out = {"n_sample": int(sample.n), "n_target": int(target.n), "before": error_stats(before),
           "after": error_stats(after), "rms_before_mm": rms(before), "rms_after_mm": rms(after)}
    out["max_reduction_pct"] = 100.0 * (1.0 - out["after"]["max_mm"] / out["before"]["max_mm"])
    out["rms_reduction_pct"] = 100.0 * (1.0 - out["rms_after_mm"] / out["rms_before_mm"])
    ident = getattr(model, "identifiability_", None) or {}
    out["identifiability"] = {k: ident[k] for k in ("rank", "n_params", "condition_number", "not_identifiable")
                              if k in ident}
    out["parameters"] = model.parameters()
    return out


# ------------------------------------------------------------------ cross-validation by pose
#: folds of the cross-validated RMS (``jointcal fit``) and of diagnosis
N_FOLDS = 5


def fold_ids(n: int, k: int = N_FOLDS, seed: int = 0) -> np.ndarray:
    """Fold of each pose: a seeded permutation cut into k nearly equal parts."""
    perm = np.random.default_rng(seed).permutation(n)
    folds = np.empty(n, int)
    folds[perm] = np.arange(n) % k
    return folds


def fold_description(data, n_folds: int = N_FOLDS) -> str:
    return f"{n_folds}-fold by pose over {data.n} sample poses"


def cross_validate(robot, effects, data, n_folds: int = N_FOLDS) -> CVResult:
    """Held-out residuals (mm, shape (n, 3)) of ``effects`` fitted by :func:`fit_effects`, k-fold by pose.

    Each fold of poses (:func:`fold_ids`) is predicted by the model fitted on the others; without
    effects, by the nominal kinematics. Poses are the independent blocks.
    """
    folds = fold_ids(data.n, n_folds)
    res = np.empty((data.n, 3))
    for f in range(n_folds):
        test = folds == f
        train, held = data.subset(~test), data.subset(test)
        if not effects:
            pred = Design(robot, [], held).predict(np.zeros(0))
        else:
            pred = fit_effects(robot, effects, train).predict(held)
        res[test] = data.measured_mm[test] - pred
    return CVResult(res, np.arange(data.n))
