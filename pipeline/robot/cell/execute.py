"""The virtual cell runs Table 2's commands: kinematic (open loop) and feedback (grating loop on joints 1-3)."""

from __future__ import annotations

import pandas as pd

from ..arm.kinematics import directions_from_sequence
from .simulate import EXECUTE, rng_for


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
