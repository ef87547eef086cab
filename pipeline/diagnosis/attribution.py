"""Which effect makes two fits of one robot differ on a set of poses (issue 52: a decomposition that carries over).

Two models of the same robot and effects (fitted on different campaigns, or on one and on several together) predict
another campaign's poses differently. :func:`effect_swaps` says which effect carries the difference: each model's
prediction with one effect's terms taken from the other model, every time registered again onto the measurements
(the tracker frame re-estimated, as ``jointcal predict --register``) and judged on the chosen poses. Each effect's
terms are its channels' values at the poses (joint-angle offsets, link and frame twists), so effects whose grids
differ (a joint map's knots over each fit's own sampled range) still compare.
"""

from __future__ import annotations

import numpy as np

from ..core.se3 import ARCSEC_PER_MRAD, rigid_fit
from ..robot.arm.kinematics import positions
from ..robot.campaign.frame import apply
from ..robot.model.design import Design


def effect_key(effect) -> tuple:
    """An effect's identity across fits: its name, its joints and any orders (not its fit-time grid)."""
    p = effect.params
    return (effect.name, tuple(sorted(p.get("joints") or ())), tuple(sorted(p.get("orders") or ())))


def effect_terms(robot, effects, coef, data) -> dict:
    """Each effect's change of the error model's configuration at ``data``'s poses.

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect, as fitted (their spec lines carry any fit-time state)
    coef : ndarray, shape (p,), internal units, in the order of ``effects``' parameters
    data : RobotData, n poses

    Returns
    -------
    dict: :func:`effect_key` -> ndarray, shape (n, nq), the effect's channel values (rad, m); the key ``None``
    holds the nominal configurations (n, nq) and ``"design"`` a :class:`Design` of no effect (its model, index).
    """
    out, off = {}, 0
    for e in effects:
        d = Design(robot, [e], data)
        out[effect_key(e)] = d.configurations(np.asarray(coef, float)[off:off + d.p]) - d.Q0
        off += d.p
    base = Design(robot, [], data)
    out[None], out["design"] = base.Q0, base
    return out


def _rms_after_registration(design, Q, measured_mm, register_on, judged) -> float:
    P = positions(design.model, Q)
    R, t = rigid_fit(measured_mm[register_on], P[register_on])
    e = np.linalg.norm(apply(R, t, measured_mm) - P, axis=1)
    return float(np.sqrt(np.mean(e[judged] ** 2)))


def effect_swaps(robot, fit_a, fit_b, data, measured_mm, register_on, judged) -> dict:
    """Swap each effect between two fitted models and judge the predictions on ``judged`` poses.

    Parameters
    ----------
    robot : Robot
    fit_a, fit_b : tuple (effects, coef)
        Two fitted models of ``robot`` (effects as fitted, coefficients in internal units); the effects present in
        both (:func:`effect_key`) are swapped, the others stay each model's own.
    data : RobotData, n poses (joint angles deg, torques N m)
    measured_mm : ndarray, shape (n, 3), mm
        The measured points, in any frame (each prediction is registered onto them rigidly).
    register_on, judged : ndarray, shape (n,), bool
        The poses the rigid registration uses, and those whose errors are judged.

    Returns
    -------
    dict with ``a_mm``, ``b_mm`` (each model's RMS error on the judged poses) and ``effects``: one entry per shared
    effect, ``{"effect": name, "joints", "b_into_a_mm": model a with this effect's terms from b, "a_into_b_mm": model b
    with this effect from a, "joint_rms_arcsec": RMS over the judged poses of the two effects' difference in each
    joint angle}``, in model a's order; ``joint_angles``: one entry per joint, ``{"joint", "b_into_a_mm",
    "a_into_b_mm", "rms_arcsec"}``, the same with the joint's whole angle error (every effect's term on it) swapped.
    """
    measured_mm = np.asarray(measured_mm, float)
    register_on, judged = np.asarray(register_on, bool), np.asarray(judged, bool)
    ta = effect_terms(robot, *fit_a, data)
    tb = effect_terms(robot, *fit_b, data)
    design, Q0 = ta["design"], ta[None]
    keys_a = [effect_key(e) for e in fit_a[0]]
    keys_b = [effect_key(e) for e in fit_b[0]]
    shared = [k for k in keys_a if k in keys_b]

    def judge(mine, theirs, keys, swap):
        Q = Q0 + sum((theirs if k == swap else mine)[k] for k in keys)
        return _rms_after_registration(design, Q, measured_mm, register_on, judged)

    out = {"a_mm": judge(ta, tb, keys_a, None), "b_mm": judge(tb, ta, keys_b, None), "effects": []}
    cols = design.idx.joints
    sum_a, sum_b = sum(ta[k] for k in keys_a), sum(tb[k] for k in keys_b)

    def channel_swap(mine, theirs, c):
        Q = Q0 + mine
        Q[:, c] += theirs[:, c] - mine[:, c]
        return _rms_after_registration(design, Q, measured_mm, register_on, judged)

    # each joint's whole angle error (every effect's term on it: offset, map, compliance, backlash ...), whatever
    # share each model gave each effect: where effects on one joint trade off, only their sum compares
    out["joint_angles"] = [{"joint": int(j + 1), "b_into_a_mm": channel_swap(sum_a, sum_b, c),
                            "a_into_b_mm": channel_swap(sum_b, sum_a, c),
                            "rms_arcsec": float(np.sqrt(np.mean(((sum_a - sum_b)[judged, c] * 1e3 * ARCSEC_PER_MRAD) ** 2)))}
                           for j, c in enumerate(cols)]
    for k in shared:
        diff = (ta[k] - tb[k])[:, cols][judged] * 1e3 * ARCSEC_PER_MRAD
        out["effects"].append({"effect": k[0], "joints": list(k[1]), "b_into_a_mm": judge(ta, tb, keys_a, k),
                               "a_into_b_mm": judge(tb, ta, keys_b, k),
                               "joint_rms_arcsec": np.sqrt(np.mean(diff ** 2, axis=0)).tolist()})
    return out
