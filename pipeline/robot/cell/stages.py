"""The second paper's chain on the virtual cell, one function per stage of ``jointcal robot``:
``closed-loop`` (Eq. 26) and ``evaluate`` (Table 2, Figs. 6-11, ISO 9283 vAP).

Data in, data out: the command reads the ingested campaign and the corrected commands and writes
what these return. The stages before them: :mod:`pipeline.robot.paper.chain`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ...core.errors import InputError
from ...core.tables import FLOAT, STR, read_table
from ..arm.kinematics import directions_from_sequence
from ..campaign.ingest import robot_data
from ..model.estimator import RobotErrorModel
from ..model.fit import stage_effects
from ..paper.closedloop import CYCLE_S, KD, KP, ROUGH_LIMIT_DEG, ROUGH_STEP_DEG, pd_poles
from ..paper.evaluate import table2, vap
from ..paper.mapping import inverse_commands
from .execute import execute_virtual
from .simulate import EXECUTE, ROBOT_FIXTURE, make_cell, rng_for


def _config(seed):
    return dict(ROBOT_FIXTURE, **({"seed": seed} if seed is not None else {}))


# ------------------------------------------------------------------------------ closed-loop
def closed_loop_stage(robot, frame: pd.DataFrame, ids, q_deg, seed=None) -> dict:
    """Run the grating closed loop of joints 1-3 on the virtual cell for every corrected command.

    Parameters
    ----------
    frame : DataFrame
        The ingested campaign (its ``payload_kg`` per point).
    ids : array of str, shape (n,)
        The commands' point ids (rows of ``frame``).
    q_deg : ndarray, shape (n, N), deg
        The corrected commands (:func:`pipeline.robot.paper.chain.read_corrected`).
    seed : int, optional
        The virtual cell's seed (default the fixture's).

    Returns
    -------
    dict: the loop's constants and poles, cycles to converge (median, max, s), the final error
    (arcsec) and an error trace (deg per 12 ms cycle) of a typical target.
    """
    config = _config(seed)
    cell = make_cell(robot, config)
    tg = frame.set_index("point_id").loc[ids]
    mid = (robot.lower_deg + robot.upper_deg) / 2
    dirs = directions_from_sequence(q_deg, start_deg=mid)
    _, res = cell.closed_loop(q_deg, dirs, q_deg[:, :3], tg["payload_kg"].to_numpy(float),
                              rng_for(config["seed"], EXECUTE, 2), trace=True)
    cycles = res["cycles"].reshape(-1, 3)
    k = int(np.argsort(cycles[:, 1])[len(cycles) // 2])       # a typical target (median cycles of joint 2)
    stop = int(cycles[k].max()) + 25
    poles = pd_poles()
    return {"cycle_s": CYCLE_S, "kP": KP, "kD": KD, "rough_step_deg": ROUGH_STEP_DEG, "rough_limit_deg": ROUGH_LIMIT_DEG,
            "poles": [float(p) for p in poles], "stable": bool(np.all(np.abs(poles) < 1)),
            "cycles_median": float(np.median(cycles)), "cycles_max": int(cycles.max()),
            "seconds_max": float(cycles.max() * CYCLE_S),
            "final_error_arcsec_max": float(np.abs(res["final_error_deg"]).max() * 3600),
            "converged": bool(np.all(cycles < 6000)),
            "trace_point": str(ids[k]),
            "trace_error_deg": {f"joint{j + 1}": res["error_deg"][:stop, 3 * k + j].tolist() for j in range(3)},
            "trace_fine": {f"joint{j + 1}": res["fine"][:stop, 3 * k + j].astype(int).tolist() for j in range(3)}}


# --------------------------------------------------------------------------------- evaluate
def read_remeasured(path, target_ids, repeat_ids) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A real robot's re-measured tracker.csv: positions (mm, shape (n, 3)) of ``<id>@kinematic`` and
    ``<id>@feedback`` of every target, and ``<id>@feedback`` of every repeat row (None without any)."""
    t = read_table(path, {"point_id": STR, "x_mm": FLOAT, "y_mm": FLOAT, "z_mm": FLOAT}).set_index("point_id")

    def get(keys):
        missing = [k for k in keys if k not in t.index]
        if missing:
            raise InputError(path, f"no measurement of '{missing[0]}'", None, "point_id")
        return t.loc[keys, ["x_mm", "y_mm", "z_mm"]].to_numpy(float)

    Pk = get([f"{i}@kinematic" for i in target_ids])
    Pf = get([f"{i}@feedback" for i in target_ids])
    Pr = get([f"{i}@feedback" for i in repeat_ids]) if len(repeat_ids) else None
    return Pk, Pf, Pr


def evaluate_stage(robot, frame: pd.DataFrame, spec, mdh_document: dict, ids, q_feedback, corrected_path,
                   tracker_path=None, seed=None) -> tuple[dict, dict]:
    """Table 2 (before / kinematic / feedback, mm), the per-target errors and ISO 9283 vAP.

    The kinematic commands invert the MDH model (``mdh_document``, ``jointcal robot calibrate``); the
    feedback commands are the corrected ones (``ids``, ``q_feedback``: shape (n_targets, N), deg, as
    :func:`pipeline.robot.paper.chain.read_corrected` reads ``corrected_path``). Both run on the
    virtual cell (``seed``), or are read from a real robot's re-measured ``tracker_path``.

    Returns
    -------
    (result, tables): Table 2's JSON (without provenance) and the files beside it by name:
    ``target_errors`` and ``kinematic_commands`` (DataFrames), and with repeat rows
    ``repeat_positions`` (DataFrame) and ``iso9283`` (dict).
    """
    mdh = RobotErrorModel.from_parameters(robot, stage_effects(spec, "kinematic"), mdh_document["parameters"])
    tg = frame[frame["set"] == "target"].reset_index(drop=True)
    data = robot_data(robot, tg)
    qk = inverse_commands(mdh, robot, data)
    if list(ids) != list(tg["point_id"]):
        raise InputError(corrected_path, "point_ids differ from the campaign's targets (run map-joints again)", 2,
                         "point_id")
    nominal = tg[["xn_mm", "yn_mm", "zn_mm"]].to_numpy(float)
    before = tg[["x_mm", "y_mm", "z_mm"]].to_numpy(float) - nominal
    rep = frame[frame["set"] == "repeat"].reset_index(drop=True)
    if tracker_path:
        Pk, Pf, Pr = read_remeasured(tracker_path, tg["point_id"], rep["point_id"])
        source = str(tracker_path)
    else:
        config = _config(seed)
        run = execute_virtual(make_cell(robot, config), robot, frame, qk, q_feedback, config["seed"])
        Pk, Pf, Pr = run["kinematic"], run["feedback"], run.get("repeat_loop")
        source = f"virtual cell, seed {config['seed']}"
    result = table2(before, Pk - nominal, Pf - nominal)
    result["source"] = source
    iso = {}
    if len(rep):
        rep_meas = rep[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        iso["open_loop"] = vap(rep["pose"].to_numpy(), rep["approach"].to_numpy(), rep_meas)
        if Pr is not None:
            iso["closed_loop"] = vap(rep["pose"].to_numpy(), rep["approach"].to_numpy(), Pr)
        result["vAP_mm"] = {k: {p: v["vAP_mm"] for p, v in d.items()} for k, d in iso.items()}
    errs = pd.DataFrame({"point_id": tg["point_id"]})
    for name, e in (("before", before), ("kinematic", Pk - nominal), ("feedback", Pf - nominal)):
        for k, c in enumerate("xyz"):
            errs[f"{name}_d{c}_mm"] = e[:, k]
        errs[f"{name}_abs_mm"] = np.linalg.norm(e, axis=1)
    kc = pd.DataFrame({"point_id": tg["point_id"]})
    for j in range(robot.n_joints):
        kc[f"q{j + 1}"] = qk[:, j]
    tables = {"target_errors": errs, "kinematic_commands": kc}
    if len(rep):
        rows = {"open_loop": rep[["x_mm", "y_mm", "z_mm"]].to_numpy(float)}
        if Pr is not None:
            rows["closed_loop"] = Pr
        rr = pd.DataFrame({"point_id": rep["point_id"], "pose": rep["pose"], "approach": rep["approach"],
                           "cycle": rep["cycle"]})
        for k, v in rows.items():
            for i, c in enumerate("xyz"):
                rr[f"{k}_{c}_mm"] = v[:, i]
        tables["repeat_positions"] = rr
        tables["iso9283"] = iso
    return result, tables
