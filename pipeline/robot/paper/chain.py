"""The second paper's chain up to the corrected commands, one function per stage of ``jointcal robot``:
``calibrate`` (MDH, Eqs. 3-6), ``chebyshev`` (Eqs. 7-21) and ``map-joints`` (Eqs. 22-24).

Each stage takes the ingested campaign (a DataFrame), the robot and the spec and returns what the
command writes, with the problems that make the result unusable; the command reads and writes the
files and refuses. The closed loop and Table 2 run on the virtual cell: :mod:`pipeline.robot.cell.stages`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ...core.errors import InputError
from ...core.spec import _locate
from ...core.tables import FLOAT, STR, read_table
from ..arm.kinematics import PAPER_JOINTS, directions_from_sequence
from ..campaign.ingest import has_gratings, robot_data
from ..model.estimator import calibrate_mdh
from ..model.chebyshev import cross_check_problems, identify, model_from_json
from ..model.fit import fit_problems, stage_effects
from ..model.lm import lm_options_problem
from ..model.predict import outside_calibrated_range, outside_message
from .mapping import joint_mapping


def require_paper_robot(robot, path, command: str) -> None:
    """Refuse (one line at ``path``) a robot that is not the paper's six-joint cell, for a stage that
    runs it (gratings on joints 1-3)."""
    if robot.n_joints != PAPER_JOINTS:
        raise InputError(path, f"jointcal robot {command} runs the second paper's six-joint cell (gratings on joints "
                         f"1-3, Eqs. 22-24); this robot has {robot.n_joints} joints: use jointcal fit / predict / "
                         "diagnose, which take any arm of 4 to 7 joints", 1, 1)


def _sample(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[frame["set"] == "sample"]


# ------------------------------------------------------------------------------- calibrate
def calibrate_stage(robot, frame: pd.DataFrame, spec, provenance: dict) -> tuple[dict, list[str], float]:
    """MDH calibration of the stage's effects (``[model] kinematic_effects``) on the sample poses.

    Parameters
    ----------
    frame : DataFrame
        The ingested campaign, every set (``jointcal ingest``).
    provenance : dict
        The inputs' hashes, recorded in the report.

    Returns
    -------
    (report, problems, seconds): the report written (mm, arcsec), why it must not be used (empty when
    usable: :func:`pipeline.robot.model.fit.fit_problems`), and the wall time (s; not a result).
    """
    model, report = calibrate_mdh(robot, robot_data(robot, _sample(frame)), stage_effects(spec, "kinematic"))
    report["provenance"] = provenance
    seconds = report.pop("seconds")  # wall time is not a result: same inputs, same bytes
    report.update(converged=bool(model.converged_), convergence=model.convergence_, plausible=bool(model.plausible_),
                  implausible=model.implausible_)
    return report, fit_problems(report), seconds


# ------------------------------------------------------------------------------- chebyshev
def check_lm_options(spec, spec_path) -> None:
    """Refuse a spec's ``[model.lm]`` constants of the improved L-M that are unknown or out of range,
    at the key's line (or the table's)."""
    problem = lm_options_problem(spec.model.get("lm", {}))
    if problem:
        text = Path(spec.path).read_text(encoding="utf-8")
        where = _locate(text, rf"^\s*{problem[0]}\s*=")
        raise InputError(spec_path, f"[model.lm]: {problem[1]}",
                         *(where if where[0] else _locate(text, r"^\s*\[model\.lm\]")))


def chebyshev_stage(robot, frame: pd.DataFrame, spec, spec_path, gratings: bool,
                    provenance: dict) -> tuple[dict, list[str], dict]:
    """Chebyshev error transfer matrices (``[model] feedback_effects``) by the improved L-M, with
    scipy's least squares beside it, on the sample poses (grating angles of joints 1-3 when
    ``gratings`` and the campaign has them).

    Returns
    -------
    (result, problems, seconds): the result written (gamma mm, lambda arcsec, costs mm^2), why it
    must not be used (:func:`pipeline.robot.model.chebyshev.cross_check_problems`), and each
    solver's wall time (s; not a result).
    """
    effects = stage_effects(spec, "feedback")
    if not effects:
        raise InputError(spec_path, "the spec has no chebyshev effect (add [[effect]] name = \"chebyshev\")", 1, 1)
    check_lm_options(spec, spec_path)
    sample = _sample(frame)
    use = gratings and has_gratings(sample)
    result = identify(robot, robot_data(robot, sample, use_gratings=use), effects, spec.model.get("lm", {}))
    result["uses_gratings"] = bool(use)
    result["provenance"] = provenance
    seconds = {"lm": result["lm"].pop("seconds"), "scipy": result["scipy"].pop("seconds")}  # not a result
    return result, cross_check_problems(result), seconds


# ------------------------------------------------------------------------------ map-joints
def feedback_model(robot, spec, document: dict):
    """The Chebyshev model of ``jointcal robot chebyshev``'s JSON, for the spec's feedback effects."""
    return model_from_json(robot, stage_effects(spec, "feedback"), document)


def targets(frame: pd.DataFrame) -> pd.DataFrame:
    """The campaign's target rows, in visiting order."""
    return frame[frame["set"] == "target"]


def targets_outside(robot, frame: pd.DataFrame) -> list[dict]:
    """The targets outside the joint ranges the sample poses covered (where the model extrapolates):
    :func:`pipeline.robot.model.predict.outside_calibrated_range`, with each target's poses.csv line."""
    tg = targets(frame)
    qcols = [f"q{j}" for j in range(1, robot.n_joints + 1)]
    lines = [int(v) + 2 if np.isfinite(v) else None for v in tg["visit"]] if "visit" in tg else None
    return outside_calibrated_range(frame.loc[frame["set"] == "sample", qcols], tg[qcols], tg["point_id"].to_numpy(),
                                    lines)


def outside_refusal(outside: list[dict], interim, metadata: dict) -> InputError:
    """``--strict``'s refusal of targets outside the sampled ranges: at the first one's line of the
    campaign's poses.csv (``metadata["campaign"]`` of the ingested file) or at the ingested file."""
    first = outside[0]
    source = metadata.get("campaign")
    where = (Path(source) / "poses.csv", first.get("line")) if source else (interim, None)
    return InputError(where[0], f"{outside_message(outside)} (first: {first['point_id']}); refused by --strict",
                      where[1], f"q{first['joint']}")


def map_joints(robot, frame: pd.DataFrame, spec, model, max_correction_deg: float) -> tuple[pd.DataFrame, np.ndarray,
                                                                                               str]:
    """Corrected commands of the grating joints for every target (Eqs. 22-24).

    The targets run in their own order from mid-range: a direction-aware effect (backlash) is
    predicted with the directions of that run, not of the survey.

    Returns
    -------
    (table, dq, refusal): the corrected-targets table (``point_id``, ``q1..qN`` deg, ``q<j>_corrected``
    deg, ``dq<j>`` deg, ``d{x,y,z}_mm``), the corrections, shape (n_targets, n_grating_joints), deg,
    and why the table must not be used (a correction beyond ``max_correction_deg``; empty when usable).
    """
    tg = targets(frame)
    data = robot_data(robot, tg)
    data = replace(data, dir=directions_from_sequence(data.q_deg, start_deg=(robot.lower_deg + robot.upper_deg) / 2))
    dP = model.predict_error(data)
    joints = tuple(spec.model.get("grating_joints", [1, 2, 3]))
    dth, qc = joint_mapping(robot, data.q_deg, dP, joints)
    size = np.where(np.isfinite(dth), np.abs(dth), np.inf)
    beyond = size > max_correction_deg
    refusal = ""
    if beyond.any():
        k, c = np.unravel_index(int(np.argmax(size)), size.shape)
        refusal = (f"target {tg['point_id'].iloc[k]} needs joint {joints[c]} corrected by {dth[k, c]:.4g} deg, "
                   f"beyond --max-correction-deg {max_correction_deg:g} ({int(beyond.any(axis=1).sum())} of {len(tg)} "
                   "targets beyond; the model, or the mapping near a singular pose, is not plausible there)")
    table = pd.DataFrame({"point_id": tg["point_id"].to_numpy()})
    for j in range(robot.n_joints):
        table[f"q{j + 1}"] = data.q_deg[:, j]
    for j in joints:
        table[f"q{j}_corrected"] = qc[:, j - 1]
    for k, j in enumerate(joints):
        table[f"dq{j}"] = dth[:, k]
    for k, c in enumerate("xyz"):
        table[f"d{c}_mm"] = dP[:, k]
    return table, dth, refusal


def read_corrected(path, robot) -> tuple[np.ndarray, np.ndarray]:
    """The commands of a corrected-targets table (``jointcal robot map-joints``): point ids and
    ``q1..qN`` (deg, shape (n, N)) with each ``q<j>_corrected`` column in place of its joint."""
    joints = range(1, robot.n_joints + 1)
    t = read_table(path, {"point_id": STR, **{f"q{j}": FLOAT for j in joints}},
                   {f"q{j}_corrected": FLOAT for j in joints})
    q = t[[f"q{j}" for j in joints]].to_numpy(float).copy()
    for j in joints:
        c = f"q{j}_corrected"
        if c in t:
            q[:, j - 1] = t[c].to_numpy(float)
    return t["point_id"].to_numpy(object), q
