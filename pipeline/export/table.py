"""``jointcal export --format table``: one compensation table per joint for its drive (contract section 8).

CSV ``joint, angle_deg, error_arcsec, correction_arcsec`` (+ ``direction`` when the model has backlash),
equally spaced over the joint's sampled range. The error is the contract's: the angle the joint reports
minus its true angle. A robot model's joint at command (reading) q turns to q + dq(q), so the error is
-dq and the drive corrects its reading by ``correction = -error`` (exactly as a joint module's encoder
correction, whose model exports the same table). Only what is a function of the joint's own angle
goes in: ``joint_map`` and ``joint_harmonic`` (and ``backlash``, by the direction of the last motion).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..robot.arm.effects import MRAD_ARCSEC, RobotData
from ..robot.arm.kinematics import build_error_model
from .chain import TABLE_EFFECTS, effect_slices


def _grid(lo: float, hi: float, step: float) -> np.ndarray:
    n = int(np.floor((hi - lo) / step + 1e-9))
    g = lo + step * np.arange(n + 1)
    return g if g[-1] >= hi - 1e-9 else np.append(g, hi)


def robot_table(robot, model, sampled: dict, step_deg: float = 1.0) -> pd.DataFrame:
    """Per-joint angle error and correction (arcsec) on a grid over the sampled range.

    Parameters
    ----------
    robot : Robot
    model : RobotErrorModel (fitted)
    sampled : dict ``{"lower_deg": [N], "upper_deg": [N]}``
    step_deg : float, deg
        Grid step (the sampled range's upper end is added when the step does not divide it).

    Returns
    -------
    DataFrame ``joint, angle_deg, [direction,] error_arcsec, correction_arcsec`` for the joints that
    have an effect of their own angle (empty when none has).
    """
    _, idx = build_error_model(robot)
    nj = len(robot.joints)
    parts = [(e, sl) for e, sl in effect_slices(robot, model) if e.name in TABLE_EFFECTS]
    has_backlash = any(e.name == "backlash" for e, _ in parts)
    joints = sorted({j for e, _ in parts for j in e.joints(robot) if j <= nj})
    coef = np.asarray(model.coef_, float)
    rows = []
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    for j in joints:
        g = _grid(lo[j - 1], hi[j - 1], step_deg)
        for direction in ((1, -1) if has_backlash else (1,)):
            q = np.tile((lo + hi) / 2, (len(g), 1))
            q[:, j - 1] = g
            dirs = np.full((len(g), nj), direction, int)
            data = RobotData(q, dirs, np.zeros(len(g)), np.full(len(g), 20.0), np.zeros((len(g), nj)),
                             robot.lower_deg, robot.upper_deg)
            dq = np.zeros(len(g))      # rad
            for e, sl in parts:
                for k, chans in enumerate(e.basis(robot, idx, data)):
                    for c, v in chans:
                        if int(c) == int(idx.joints[j - 1]):
                            dq += coef[sl][k] * np.broadcast_to(np.asarray(v, float), (len(g),))
            err = -dq * 1e3 * MRAD_ARCSEC
            part = pd.DataFrame({"joint": j, "angle_deg": g})
            if has_backlash:
                part["direction"] = direction
            part["error_arcsec"] = err
            part["correction_arcsec"] = -err
            rows.append(part)
    cols = ["joint", "angle_deg"] + (["direction"] if has_backlash else []) + ["error_arcsec", "correction_arcsec"]
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=cols)


def encoder_table(model, step_deg: float = 1.0, joint=1) -> pd.DataFrame:
    """An encoder model's table in the same format (one joint, 0-360 deg)."""
    from ..encoder.compensate import compensation_table

    t = compensation_table(model, step_deg)
    return pd.DataFrame({"joint": joint, "angle_deg": t["theta_deg"], "error_arcsec": t["error_arcsec"],
                         "correction_arcsec": t["correction_arcsec"]})


def table_csv(table: pd.DataFrame, comments: list[str]) -> str:
    """CSV text with ``# `` comment lines first (same inputs, same bytes)."""
    out = table.copy()
    out["angle_deg"] = out["angle_deg"].map(lambda v: f"{v:.6f}")
    for c in ("error_arcsec", "correction_arcsec"):
        out[c] = out[c].map(lambda v: f"{v:.6f}")
    head = "".join(f"# {c}\n" for c in comments)
    return head + out.to_csv(index=False, lineterminator="\n")
