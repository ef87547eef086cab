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


def _drive_span(C: np.ndarray, mid_q: np.ndarray, lo: np.ndarray, hi: np.ndarray, k: int) -> tuple[float, float]:
    """How far drive ``k`` (0-based) may turn from the middle, the other drives held, with every joint angle it
    moves (``C[:, k] != 0``) inside its sampled range [lo, hi] (deg): (t_lo, t_hi), t_lo <= 0 <= t_hi."""
    t_lo, t_hi = -np.inf, np.inf
    for j in np.flatnonzero(C[:, k]):
        a, b = (lo[j] - mid_q[j]) / C[j, k], (hi[j] - mid_q[j]) / C[j, k]
        t_lo, t_hi = max(t_lo, min(a, b)), min(t_hi, max(a, b))
    return float(t_lo), float(t_hi)


def robot_table(robot, model, sampled: dict, step_deg: float = 1.0) -> pd.DataFrame:
    """Per-drive angle error and correction (arcsec) on a grid over the sampled range.

    A drive's table is in its own angle, the one the controller records and commands. Without coupled
    joints that is the model's joint angle. With them (robot.toml ``[coupling]``: the kinematics take
    joint angles q = C r of the recorded angles r, a FANUC's J2/J3), the model's joint angle errors dq are
    the drives' errors C^-1 dq, so a coupled drive's table holds what it must correct for every joint it
    moves, and each drive is tabled over the range of its own angle that keeps every joint it moves inside
    the sampled range, the other drives at the middle of theirs; where a drive's correction also varies
    with another drive's angle, the returned frame's ``attrs["notes"]`` says so.

    Parameters
    ----------
    robot : Robot
    model : RobotErrorModel (fitted)
    sampled : dict ``{"lower_deg": [N], "upper_deg": [N]}``, the model's joint angles (deg)
    step_deg : float, deg
        Grid step (the range's upper end is added when the step does not divide it).

    Returns
    -------
    DataFrame ``joint, angle_deg, [direction,] error_arcsec, correction_arcsec`` for the drives that have
    an effect to correct (``joint``: the drive's number, ``angle_deg``: its recorded angle; empty when none has).
    """
    _, idx = build_error_model(robot)
    nj = len(robot.joints)
    parts = [(e, sl) for e, sl in effect_slices(robot, model) if e.name in TABLE_EFFECTS]
    has_backlash = any(e.name == "backlash" for e, _ in parts)
    joints = sorted({j for e, _ in parts for j in e.joints(robot) if j <= nj})
    coef = np.asarray(model.coef_, float)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    C = robot.coupling_matrix
    Cinv = np.linalg.inv(C)
    coupled = bool(robot.coupling)
    channel = {int(idx.joints[j]): j for j in range(nj)}

    def joint_errors(q, direction):
        """The model's joint angle error -dq (n, N) rad at joint angles q (n, N) deg."""
        n = len(q)
        dirs = np.full((n, nj), direction, int)
        data = RobotData(q, dirs, np.zeros(n), np.full(n, 20.0), np.zeros((n, nj)), robot.lower_deg, robot.upper_deg)
        dq = np.zeros((n, nj))      # rad
        for e, sl in parts:
            for k, chans in enumerate(e.basis(robot, idx, data)):
                for c, v in chans:
                    if int(c) in channel:
                        dq[:, channel[int(c)]] += coef[sl][k] * np.broadcast_to(np.asarray(v, float), (n,))
        return -dq

    # the drives to table: those whose correction is not zero (every joint of an effect, through C^-1)
    drives = sorted({k + 1 for j in joints for k in np.flatnonzero(Cinv[:, j - 1])}) if coupled else joints
    mid_q = (lo + hi) / 2
    mid_r = robot.recorded_angles(mid_q[None])[0]
    notes = []
    rows = []
    for d in drives:
        if coupled:
            t_lo, t_hi = _drive_span(C, mid_q, lo, hi, d - 1)
            g = _grid(mid_r[d - 1] + t_lo, mid_r[d - 1] + t_hi, step_deg)
            others = sorted({m + 1 for j in joints for m in np.flatnonzero(C[j - 1]) if Cinv[d - 1, j - 1] != 0
                             and m + 1 != d})
            if others:
                notes.append(f"drive {d}'s correction also varies with drive(s) {', '.join(map(str, others))} (coupled "
                             f"joints, robot.toml [coupling]): tabled with them at "
                             + ", ".join(f"{mid_r[m - 1]:.3f}" for m in others) + " deg, the middle of the sampled range")
        else:
            g = _grid(lo[d - 1], hi[d - 1], step_deg)
        for direction in ((1, -1) if has_backlash else (1,)):
            if coupled:
                r = np.tile(mid_r, (len(g), 1))
                r[:, d - 1] = g
                err_q = joint_errors(robot.kinematic_angles(r), direction)
                err = (err_q @ Cinv.T)[:, d - 1] * 1e3 * MRAD_ARCSEC
            else:
                q = np.tile(mid_q, (len(g), 1))
                q[:, d - 1] = g
                err = joint_errors(q, direction)[:, d - 1] * 1e3 * MRAD_ARCSEC
            part = pd.DataFrame({"joint": d, "angle_deg": g})
            if has_backlash:
                part["direction"] = direction
            part["error_arcsec"] = err
            part["correction_arcsec"] = -err
            rows.append(part)
    cols = ["joint", "angle_deg"] + (["direction"] if has_backlash else []) + ["error_arcsec", "correction_arcsec"]
    out = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=cols)
    if coupled:
        notes.insert(0, "coupled joints (robot.toml [coupling]): each table is in its drive's own angle, the one the "
                        "controller records and commands, not the model's joint angle")
    out.attrs["notes"] = notes
    return out


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
