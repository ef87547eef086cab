"""A fitted robot model as a document, and the model applied to other measurements (contract section 7).

``jointcal fit --campaign`` writes, beside its held-out numbers, everything needed to apply the
model elsewhere (:func:`model_document`): the nominal robot (its ``robot.toml`` text), the spec's
effects (their ``[[effect]]`` tables), every parameter with its unit and whether it was fitted or
left at nominal (and why), the joint ranges of the sample poses the model was fitted on, and the
tracker-to-base transform of the fit's campaign.

``jointcal predict`` (:func:`predict_campaign`) rebuilds that model (:func:`load_model_document`),
predicts every pose of another campaign of the same robot and compares with its tracker points:

* without ``--register`` the other campaign's points are taken as they are (frame ``base``), or,
  when they are in the tracker's frame, through the fit campaign's tracker-to-base transform (the
  tracker has not moved);
* with ``--register`` only the rigid tracker-to-base transform is estimated again, on the other
  campaign's ``sample`` poses (best rigid fit of its points onto the model's predictions); every
  other parameter is the model's.

Errors are ``|measured - predicted|`` (mm) on the ``target`` poses, on every pose when there are none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.effect import carry_over_line
from ...core.errors import InputError
from ...core.spec import parse_spec
from ...core.se3 import angle_arcsec, orientation_errors
from .estimator import RobotErrorModel
from .estimate import point_errors
from .outliers import describe, find_wild
from .uncertainty import beyond_deg, in_gap
from ...core.se3 import rigid_fit, rotation_angle_deg
from ..campaign.frame import apply, from_matrix, to_matrix
from ..campaign.ingest import robot_data_sets
from ..arm.kinematics import Robot, parse_robot

#: Largest difference (mm, deg) between two robot descriptions that are still "the same robot".
SAME_ROBOT_TOL = 1e-6

DOCUMENT_VERSION = 1


def sampled_range(q_deg) -> dict:
    """Joint ranges of the poses a model was fitted on, and the stretches inside them no pose reached.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg

    Returns
    -------
    dict ``{"lower_deg": [N], "upper_deg": [N]}`` and, when a joint's sampled angles leave a stretch wider than
    :data:`pipeline.robot.arm.effects.JOINT_MAP_GAP_DEG` between two of them, ``"gaps_deg": {"j": [[low, high],
    ...]}`` (deg, the sampled angles on either side; j 1-based): the model extrapolates there too
    (:func:`pipeline.robot.model.uncertainty.beyond_deg`).
    """
    from ..arm.effects import JOINT_MAP_GAP_DEG, sampled_gaps

    q = np.asarray(q_deg, float)
    out = {"lower_deg": q.min(axis=0).tolist(), "upper_deg": q.max(axis=0).tolist()}
    gaps = {str(j + 1): g for j in range(q.shape[1]) if (g := sampled_gaps(q[:, j], JOINT_MAP_GAP_DEG / 2))}
    if gaps:
        out["gaps_deg"] = gaps
    return out


def outside_range(q_deg, rng: dict, tol_deg: float = 1e-9) -> np.ndarray:
    """Which poses have a joint outside ``rng`` (see :func:`sampled_range`).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    q = np.asarray(q_deg, float)
    lo, hi = np.asarray(rng["lower_deg"], float), np.asarray(rng["upper_deg"], float)
    return np.any((q < lo - tol_deg) | (q > hi + tol_deg), axis=1)



def beyond_range(q_deg, rng: dict) -> list:
    """Per pose, where it lies beyond the joint angles ``rng`` sampled (:func:`sampled_range`): None where the
    poses were, else ``{"joint": the joint farthest beyond (1-based), "beyond_deg": how far, "joints": every joint
    beyond}`` and, when that joint lies inside its range in a stretch no sample pose reached, ``"gap_deg": [low,
    high]`` (``beyond_deg`` then the distance to the nearer sampled angle; :func:`uncertainty.beyond_deg`).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    """
    out = []
    gaps = in_gap(q_deg, rng)
    for k, row in enumerate(beyond_deg(q_deg, rng)):
        far = np.flatnonzero(row > 1e-9)
        j = int(np.argmax(row))
        out.append(None if not far.size else
                   {"joint": j + 1, "beyond_deg": float(row.max()), "joints": [int(i) + 1 for i in far],
                    **({"gap_deg": gaps[k][j]} if gaps[k][j] is not None else {})})
    return out


def gap_message(points: list) -> str:
    """Words on the points (:func:`predict_campaign`'s ``points``) whose farthest joint lies inside its sampled range
    but in a stretch no sample pose reached (their ``extrapolates`` has ``gap_deg``): per joint how many, in which
    stretches; '' when none."""
    per: dict[int, dict] = {}
    for p in points:
        w = p.get("extrapolates")
        if w and "gap_deg" in w:
            per.setdefault(w["joint"], {}).setdefault(tuple(w["gap_deg"]), []).append(w["beyond_deg"])
    if not per:
        return ""
    return ("points inside the joint ranges but in stretches no sample pose reached (the model extrapolates there "
            "too): " + "; ".join(f"joint {j}: " + ", ".join(f"{len(d)} in [{a:.2f}, {b:.2f}] (up to {max(d):.3g} deg "
                                                               "from a sampled angle)" for (a, b), d in sorted(g.items()))
                                  for j, g in sorted(per.items())))


def outside_calibrated_range(sample_q, target_q, target_ids, target_lines=None) -> list[dict]:
    """Per joint, the targets whose angle lies outside the range the sample poses covered.

    Parameters
    ----------
    sample_q, target_q : ndarray, shape (n, N), deg
    target_ids : sequence of str, length n_targets
    target_lines : sequence of int or None, optional
        Line of each target in poses.csv.

    Returns a list of ``{joint, count, beyond_deg, low_deg, high_deg, point_id, line}`` (the
    worst target of each joint; ``line`` is its line in poses.csv when known).
    """
    sample_q, target_q = np.asarray(sample_q, float), np.asarray(target_q, float)
    lo, hi = sample_q.min(axis=0), sample_q.max(axis=0)
    out = []
    for j in range(sample_q.shape[1]):
        beyond = np.maximum(lo[j] - target_q[:, j], target_q[:, j] - hi[j])
        bad = beyond > 1e-9
        if bad.any():
            k = int(np.argmax(beyond))
            out.append({"joint": j + 1, "count": int(bad.sum()), "beyond_deg": float(beyond[k]), "low_deg": float(lo[j]),
                        "high_deg": float(hi[j]), "point_id": str(target_ids[k]),
                        "line": None if target_lines is None else target_lines[k]})
    return out


def outside_message(outside, worst: bool = False) -> str:
    """The warning about :func:`outside_calibrated_range`'s targets (with the worst target of each
    joint named when ``worst``)."""
    return ("targets outside the joint range the sample poses covered (the model extrapolates there): "
            + "; ".join(f"joint {o['joint']}: {o['count']} target(s), up to {o['beyond_deg']:.3g} deg beyond "
                        f"[{o['low_deg']:.2f}, {o['high_deg']:.2f}]" + (f" (worst {o['point_id']})" if worst else "")
                        for o in outside))


def model_document(robot: Robot, effects, model, sample_q_deg, frame: dict | None = None, sample=None) -> dict:
    """The JSON-ready description of a fitted robot model (the part of ``fit.json`` that predict reads).

    Parameters
    ----------
    robot : Robot
        Nominal robot of the fit's campaign.
    effects : list of RobotEffect
    model : RobotErrorModel
        Fitted (``coef_``, ``names_``, ``units_``, ``identifiability_``).
    sample_q_deg : ndarray, shape (n, N), deg
        Joint angles of the poses the model was fitted on.
    frame : dict, optional
        ``{"frame": "base" | "tracker", "tracker_to_base": 4x4 list (mm)}`` of the fit's campaign.
    sample : RobotData, optional
        The poses the model was fitted on: then the document also says which angle each joint's
        model takes (``joint_angles``: ``"commanded"`` or the secondary encoder's column, e.g.
        ``"grating1_deg"``) and the payloads it was fitted at (``payloads_kg``), which ``jointcal
        correct`` and ``jointcal export`` assume (:mod:`pipeline.robot.model.rigid`).
    """
    ident = getattr(model, "identifiability_", None) or {}
    reasons = ident.get("fixed_reasons", {})
    params = []
    for p in model.parameters():
        entry = dict(p)
        if p["fixed"]:
            entry["why_fixed"] = reasons.get(p["name"], {}).get("reason", "not identifiable on these poses")
        params.append(entry)
    made_for = {}
    if sample is not None:
        from .rigid import fitted_payloads, joint_angle_sources

        made_for = {"joint_angles": joint_angle_sources(robot.n_joints, getattr(sample, "grating_joints", ())),
                    "payloads_kg": fitted_payloads(sample.payload_kg)}
    return {"version": DOCUMENT_VERSION,
            "robot_toml": robot.to_toml(),
            "spec_effects": [e.spec_lines() for e in getattr(model, "effects_", effects)],
            "parameters": params,
            "sampled_range": sampled_range(sample_q_deg),
            "frame": frame or {"frame": "base", "tracker_to_base": np.eye(4).tolist()},
            **made_for,
            "identification": {"rank_tol": ident.get("rank_tol"), "condition_number": ident.get("condition_number"),
                               "fixed": {n: r.get("reason") for n, r in reasons.items()},
                               # what the measurements cannot tell apart, group by group, and how it is held
                               # (contract section 8: nearest the nominal robot in typical sizes)
                               "redundant": ident.get("redundant_groups", [])}}


def unseen_directions(doc: dict, model) -> np.ndarray:
    """The parameter directions (internal units, shape (p, m)) that the fit's measurements could not
    see, from the fit JSON's ``identification.redundant`` groups (none in a JSON written before them)."""
    groups = ((doc.get("identification") or {}).get("redundant") or []) if isinstance(doc, dict) else []
    index = {n: k for k, n in enumerate(model.names_)}
    cols = []
    for g in groups if isinstance(groups, list) else []:
        for direction in (g.get("unseen_directions") or []) if isinstance(g, dict) else []:
            v = np.zeros(len(model.names_))
            for name, value in direction.items() if isinstance(direction, dict) else []:
                if name in index and isinstance(value, (int, float)) and np.isfinite(value):
                    v[index[name]] = float(value) / model.units_[index[name]][1]
            if np.any(v):
                cols.append(v)
    return np.stack(cols, axis=1) if cols else np.zeros((len(model.names_), 0))


def carry_over_note(doc: dict) -> str:
    """For a fit JSON ``doc`` (:func:`model_document`): which of its effects carry over beyond the joint ranges its
    poses sampled and which are local (:func:`pipeline.core.effect.carry_over_line`); '' when its effects cannot be
    read."""
    try:
        spec = parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(doc["spec_effects"]) + "\n", "fit JSON")
    except (InputError, KeyError, TypeError):
        return ""
    return carry_over_line(spec.effects)


def load_model_document(doc: dict, path) -> tuple:
    """Rebuild a fitted model from :func:`model_document` (``fit.json``); bad content -> InputError.

    Returns
    -------
    robot : Robot
    effects : list of RobotEffect
    model : RobotErrorModel
    sampled : dict (:func:`sampled_range`)
    frame : dict
    """
    need = ("robot_toml", "spec_effects", "parameters", "sampled_range")
    if not isinstance(doc, dict) or doc.get("kind") not in (None, "robot") or any(k not in doc for k in need):
        missing = [k for k in need if not isinstance(doc, dict) or k not in doc]
        raise InputError(path, "not a fitted robot model: write one with `jointcal fit --campaign <robot campaign> "
                               f"--spec <robot spec> --out FIT.json`{' (missing ' + missing[0] + ')' if missing else ''}",
                         1, 1)
    try:
        robot = parse_robot(doc["robot_toml"], f"{path} (robot_toml)")
        spec = parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(doc["spec_effects"]) + "\n", f"{path} (spec_effects)")
    except InputError as exc:
        raise InputError(path, f"the model's {exc.path.split('(')[-1].rstrip(')')} is not valid: {exc.message}", 1, 1) from None
    effects = list(spec.effects)
    params = doc["parameters"]
    try:
        model = RobotErrorModel.from_parameters(robot, effects, params)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(path, f"the model's parameters do not match its effects ({exc})", 1, 1) from None
    if not np.all(np.isfinite(model.coef_)):
        raise InputError(path, "the model has a parameter that is not a finite number", 1, 1)
    model.unseen_ = unseen_directions(doc, model)
    # how the fit weighed positions and orientations (a 6-DoF fit: ``jointcal correct`` holds its orientation)
    model.weighting_ = doc.get("weighting") if isinstance(doc.get("weighting"), dict) else None
    frame = doc.get("frame") or {"frame": "base", "tracker_to_base": np.eye(4).tolist()}
    return robot, effects, model, doc["sampled_range"], frame


#: Why ``jointcal predict`` leaves a 6-DoF campaign's orientation errors out for a model fitted on positions alone.
ORIENTATION_NOT_JUDGED = ("the model was fitted on a campaign without the probe's orientations, so it never "
                          "determined how the probe is turned on the flange; the angle between its probe frame and "
                          "the measured one would be robot.toml's nominal mounting's error, not the model's "
                          "(fit the model on a campaign with orientations to judge them)")


def fitted_orientation(document: dict) -> bool:
    """Whether the fit of ``document`` (a fit JSON) saw a 6-DoF probe's orientations: it weighed them against the
    positions, or (``--positions-only``) registered the probe's mounting on them; its ``weighting`` says which. A
    fit on a campaign of positions alone has no ``weighting``."""
    return isinstance(document, dict) and isinstance(document.get("weighting"), dict)


def same_robot_problem(a: Robot, b: Robot) -> str:
    """Why ``b`` is not the robot ``a`` describes ('' when it is: same joints and tool)."""
    fields = ("a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg")
    if a.n_joints != b.n_joints:
        return (f"{b.n_joints} joints here, {a.n_joints} in the model's robot '{a.name}': a model applies to the "
                "robot it was fitted on")
    for i, (ja, jb) in enumerate(zip(a.joints, b.joints)):
        for f in fields:
            if abs(getattr(ja, f) - getattr(jb, f)) > SAME_ROBOT_TOL:
                return (f"joint {i + 1}: {f} = {getattr(jb, f):g} here, {getattr(ja, f):g} in the model's robot "
                        f"'{a.name}': a model applies to the robot it was fitted on")
    if np.max(np.abs(np.subtract(a.tool_rpy_deg, b.tool_rpy_deg))) > SAME_ROBOT_TOL:
        return (f"tool rpy_deg = {list(b.tool_rpy_deg)} here, {list(a.tool_rpy_deg)} in the model: the probe was "
                "mounted otherwise (fit the model again with this tool)")
    if np.max(np.abs(np.subtract(a.tool_xyz_mm, b.tool_xyz_mm))) > SAME_ROBOT_TOL:
        return (f"tool xyz_mm = {list(b.tool_xyz_mm)} here, {list(a.tool_xyz_mm)} in the model: the SMR was moved "
                "(fit the model again with this tool)")
    return ""


def error_summary(err_mm) -> dict:
    """RMS, max, mean, std (mm) of 3-D errors of shape (n, 3)."""
    n = np.linalg.norm(np.asarray(err_mm, float), axis=1)
    return {"n": int(n.size), "rms_mm": float(np.sqrt(np.mean(n ** 2))), "max_mm": float(n.max()),
            "mean_mm": float(n.mean()), "std_mm": float(n.std(ddof=1)) if n.size > 1 else 0.0}


def predict_campaign(model, data, sets, measured_mm, sampled: dict, register: bool, measured_R=None,
                     point_mm=None, stated=None) -> dict:
    """Apply a fitted model to another campaign's poses (contract section 7).

    Parameters
    ----------
    model : RobotErrorModel
        Fitted model (its robot is the campaign's).
    data : RobotData
        Every pose of the other campaign (joint angles deg, directions, torques N m).
    sets : ndarray of str, shape (n,)
        ``sample`` / ``target`` / ``repeat`` of each pose; ``wild`` for a pose left out of the
        registration and of the errors (:mod:`pipeline.robot.model.outliers`).
    measured_mm : ndarray, shape (n, 3), mm
        Tracker points in the model's base frame (without ``register``), or in any frame
        (with ``register``: only a rigid transform onto the predictions is estimated).
    sampled : dict
        Joint ranges the model was fitted on (:func:`sampled_range`).
    register : bool
        Re-estimate the rigid tracker-to-base transform on the ``sample`` poses first.
    measured_R : ndarray, shape (n, 3, 3), optional
        A 6-DoF probe's measured frames, in the frame of ``measured_mm`` (contract section 13).
    point_mm : array_like, shape (3,), mm, optional
        A point rigidly fixed to the probe (probe frame, e.g. a tool's TCP): its error too.
    stated : dict, optional
        The model's stated uncertainty (:func:`pipeline.robot.model.uncertainty.load_prediction`): then
        every point has its ``u95_mm`` (contract section 14) and the result ``coverage_95`` (the share of
        the evaluated points within it), ``u95_mm`` (their mean), ``error_p95_mm`` (the 95th percentile of
        the errors) and, with ``register``, ``registration_coverage_95`` (the same on the sample poses the
        registration used: a first sign, before any target, of whether the intervals hold here).

    Returns
    -------
    dict with the contract's keys (``n``, ``rms_mm``, ``max_mm``, ``mean_mm``, ``std_mm``,
    ``outside_sampled_range``, ``points``) and ``evaluated_on``, ``registration``; with
    ``measured_R`` also ``orientation_n``, ``orientation_rms_arcsec``, ``orientation_max_arcsec``
    (and per point ``orientation_error_arcsec``); with ``point_mm`` also ``point_rms_mm``,
    ``point_max_mm`` (and per point ``point_error_mm``).
    """
    sets = np.asarray(sets).astype(str)
    if measured_R is not None:
        R_pred, pred = model.predict_pose(data)
        meas_R = np.asarray(measured_R, float)
    else:
        pred = model.predict(data)
    meas = np.asarray(measured_mm, float)
    registration = None
    if register:
        meas, meas_R, registration = _register(sets, meas, pred, meas_R if measured_R is not None else None)
    ev = sets == "target"
    if not ev.any():
        ev = sets != "wild"     # every pose but the wild ones (pipeline.robot.model.outliers)
    err = meas[ev] - pred[ev]
    out = error_summary(err)
    out["outside_sampled_range"] = int(outside_range(data.q_deg[ev], sampled).sum())
    out["evaluated_on"] = "target" if (sets == "target").any() else "all"
    out["registration"] = registration
    e = np.linalg.norm(err, axis=1)
    out["points"] = [{"point_id": str(p), "error_mm": float(v)} for p, v in zip(np.asarray(data.point_id)[ev], e)]
    for point, where in zip(out["points"], beyond_range(data.q_deg[ev], sampled)):
        if where is not None:
            point["extrapolates"] = where
    if measured_R is not None:
        a = angle_arcsec(orientation_errors(R_pred[ev], meas_R[ev]))
        out.update({"orientation_n": int(a.size), "orientation_rms_arcsec": float(np.sqrt(np.mean(a ** 2))),
                    "orientation_max_arcsec": float(a.max()), "orientation_mean_arcsec": float(a.mean())})
        for pt, v in zip(out["points"], a):
            pt["orientation_error_arcsec"] = float(v)
        if point_mm is not None:
            pe = np.linalg.norm(point_errors(R_pred[ev], pred[ev], meas_R[ev], meas[ev], point_mm), axis=1)
            out.update({"point_mm": [float(v) for v in point_mm], "point_rms_mm": float(np.sqrt(np.mean(pe ** 2))),
                        "point_max_mm": float(pe.max()), "point_mean_mm": float(pe.mean())})
            for pt, v in zip(out["points"], pe):
                pt["point_error_mm"] = float(v)
    if stated is not None:
        _with_stated(out, model, data, sets, ev, stated, sampled, e, a if measured_R is not None else None, meas, pred)
    return out


def _register(sets, meas, pred, meas_R):
    """The measured points (n, 3) mm and frames (n, 3, 3) (``meas_R``, or None) moved by the rigid transform
    that best takes the ``sample`` poses' measurements onto the predictions ``pred`` (n, 3) mm, and the
    registration's document."""
    on = sets == "sample"
    if not on.any():
        raise ValueError("--register needs sample poses to register on: this campaign has none (a validation "
                         "set, every pose target); without --register the model is applied to it as measured")
    if on.sum() < 3:
        raise ValueError("--register needs at least 3 sample poses in the campaign to estimate the "
                         "tracker-to-base transform on")
    R, t = rigid_fit(meas[on], pred[on])
    meas = apply(R, t, meas)
    if meas_R is not None:
        meas_R = np.einsum("ij,njk->nik", R, meas_R)
    registration = {"on": "sample", "n": int(on.sum()), "rotation_deg": float(rotation_angle_deg(R)),
                    "translation_mm": np.asarray(t).tolist(), "matrix": np.asarray(to_matrix(R, t)).tolist()}
    return meas, meas_R, registration


def _with_stated(out, model, data, sets, ev, stated, sampled, e, a, meas, pred) -> None:
    """Each evaluated point's ``u95_mm`` (and ``u95_arcsec``) and the coverage of the errors ``e`` (mm) and
    ``a`` (arcsec, None without orientations) by them, added to ``out`` (:func:`predict_campaign`)."""
    from .uncertainty import P95, coverage, u95

    u = u95(model, data.subset(ev), stated, sampled)
    for point, v in zip(out["points"], u["u95_mm"]):
        point["u95_mm"] = float(v)
    if "u95_arcsec" in u and a is not None:
        for point, v in zip(out["points"], u["u95_arcsec"]):
            point["u95_arcsec"] = float(v)
        out["orientation_coverage_95"] = coverage(a, u["u95_arcsec"])
        out["u95_arcsec"] = float(np.mean(u["u95_arcsec"]))
        out["orientation_error_p95_arcsec"] = float(np.quantile(a, P95))
    out["coverage_95"] = coverage(e, u["u95_mm"])
    out["u95_mm"] = float(np.mean(u["u95_mm"]))
    far = np.any(beyond_deg(data.q_deg[ev], sampled) > 1e-9, axis=1)     # as each point's extrapolates
    out["u95_inside_mm"] = float(np.mean(u["u95_mm"][~far])) if (~far).any() else None
    out["u95_outside_mm"] = float(np.mean(u["u95_mm"][far])) if far.any() else None
    out["error_p95_mm"] = float(np.quantile(e, P95))
    out["u95_parts_mm"] = {k: float(np.sqrt(np.mean(u[k] ** 2)))
                           for k in ("parameters_mm", "unexplained_mm", "extrapolation_mm")}
    if out["registration"] is not None:
        on = sets == "sample"
        ur = u95(model, data.subset(on), stated, sampled)["u95_mm"]
        out["registration"]["coverage_95"] = coverage(np.linalg.norm(meas[on] - pred[on], axis=1), ur)


def _silent(message: str) -> None:
    pass


def own_campaign(document: dict, campaign):
    """The entry of ``document``'s ``campaigns`` (a model fitted on several campaigns, contract section 15) that
    is the folder ``campaign``; None when it is none of them (or the model was fitted on one campaign)."""
    entries = document.get("campaigns") if isinstance(document, dict) else None
    if not isinstance(entries, list):
        return None
    here = Path(campaign).resolve()
    for e in entries:
        if isinstance(e, dict) and isinstance(e.get("campaign"), str) and isinstance(e.get("index"), int) \
                and isinstance(e.get("frame"), dict) and Path(e["campaign"]).resolve() == here:
            return e
    return None


def predict_other_campaign(campaign, document: dict, model_path, register: bool, keep_outliers: bool = False,
                           warn=_silent, point_mm=None) -> dict:
    """``jointcal predict``: a fitted model (``document``, the JSON of ``jointcal fit --campaign`` read
    from ``model_path``) applied to every pose of another campaign of the same robot.

    Without ``register`` a tracker-frame campaign's points go through the fit campaign's
    tracker-to-base transform (the tracker has not moved); a campaign the model was fitted on among several
    (:func:`own_campaign`) through its own transform and its own fitted frame (``campaign_frame``). The campaign's wild measurements are
    named (``warn``) and left out of the registration and of the errors (``with_outliers``: the
    errors with the wild targets beside) unless ``keep_outliers``. The result has no provenance.
    """
    robot_m, effects, model, sampled, fit_frame = load_model_document(document, model_path)
    robot, (data,), frame_info, table = robot_data_sets(campaign, ("sample", "target", "repeat"), with_frame=True,
                                                        with_table=True)
    own = own_campaign(document, campaign)
    mounting = own.get("mounting") if own is not None and isinstance(own.get("mounting"), dict) else None
    problem = same_robot_problem(robot_m, robot)
    if problem and mounting is not None and problem.startswith("tool"):
        # one of the model's campaigns, with the probe mounting of its own the model was fitted with
        problem = "" if (np.allclose(robot.tool_xyz_mm, mounting.get("tool_xyz_mm"), rtol=0, atol=1e-9) and
                         np.allclose(robot.tool_rpy_deg, mounting.get("tool_rpy_deg"), rtol=0, atol=1e-9)) else problem
    if problem:
        raise InputError(Path(campaign) / "robot.toml", problem, 1, 1)
    if own is not None:
        # one of the campaigns the model was fitted on (contract section 15): its own probe mounting, and (unless
        # re-registered) its own tracker frame
        data.campaign = np.full(data.n, int(own["index"]))
        if mounting is not None:
            data.mounting_offset = np.tile(np.asarray(mounting["offset"], float), (data.n, 1))
        if not register:
            fit_frame = own["frame"]
    meas, meas_R = data.measured_mm, data.measured_R
    if point_mm is not None and meas_R is None:
        raise InputError(Path(campaign) / "tracker.csv", "--point needs the probe's orientation (a 6-DoF probe: "
                         "columns qw, qx, qy, qz); this campaign has positions only", 1, "qw")
    not_judged = ""
    if meas_R is not None and not fitted_orientation(document):
        # the model's probe frame is the nominal mounting's: its angle to the measured one is not the model's error
        not_judged = ORIENTATION_NOT_JUDGED + (" (nor the error of --point, which rests on it)" if point_mm is not None
                                               else "")
        warn(f"note: orientation not judged: {not_judged}")
        meas_R, point_mm = None, None
    if not register and frame_info and frame_info.get("frame") == "tracker":
        # the tracker has not moved: its points go through the fit campaign's transform
        raw = table[["x_tracker_mm", "y_tracker_mm", "z_tracker_mm"]].to_numpy(float)
        meas = apply(*from_matrix(fit_frame["tracker_to_base"]), raw)
        if meas_R is not None and "qw_tracker" in table:
            from ..campaign.orientation import quaternions_to_matrices

            raw_R = quaternions_to_matrices(table[["qw_tracker", "qx_tracker", "qy_tracker", "qz_tracker"]].to_numpy(float))
            meas_R = np.einsum("ij,njk->nik", from_matrix(fit_frame["tracker_to_base"])[0], raw_R)
    sets = table["set"].to_numpy().astype(object)
    wild = find_wild(robot, effects, data.subset(sets == "sample"), data.subset(sets == "target"), campaign,
                     keep_outliers)
    if describe(wild):
        warn(describe(wild))
    if not wild.kept:
        sets[np.flatnonzero(sets == "sample")[wild.sample]] = "wild"
    clean = sets.copy()
    if not wild.kept:
        clean[np.flatnonzero(sets == "target")[wild.target]] = "wild"
    from .uncertainty import load_prediction

    stated = load_prediction(document, model)
    try:
        result = predict_campaign(model, data, clean, meas, sampled, register, meas_R, point_mm, stated)
        if wild.target.any() and not wild.kept:
            full = predict_campaign(model, data, sets, meas, sampled, register, meas_R, point_mm)
            result["with_outliers"] = {k: full[k] for k in ("n", "rms_mm", "max_mm", "mean_mm", "std_mm")}
    except ValueError as exc:
        raise InputError(Path(campaign) / "poses.csv", str(exc), None, "set") from None
    result.update(wild.document())
    if not_judged:
        result["orientation_not_judged"] = not_judged
    ev = clean == "target" if (clean == "target").any() else clean != "wild"
    outside = outside_calibrated_range(np.array([sampled["lower_deg"], sampled["upper_deg"]], float), data.q_deg[ev],
                                       np.asarray(data.point_id)[ev])
    gaps = gap_message(result["points"])
    if outside or gaps:
        # before any error is looked at: where the model extrapolates, and (stated u95) how much wider it says it is
        warn("warning: " + "; ".join(m for m in (outside and outside_message(outside, worst=True).replace(
            'targets', 'points', 1), gaps) if m)
             + (f"; their mean u95_mm {result['u95_outside_mm']:.3f} against {result['u95_inside_mm']:.3f} inside"
                if result.get("u95_outside_mm") is not None and result.get("u95_inside_mm") is not None else ""))
        # what of the model holds there (the effect registry's word on each effect, pipeline.core.effect)
        line = carry_over_line(effects)
        if line:
            warn(f"  {line}")
    note = coverage_note(result)
    if note:
        result["coverage_note"] = note
        warn(f"warning: {note}")
    return result


#: Coverage of the 95 % intervals below this on a campaign says they do not hold there (the console
#: warns, the JSON's ``coverage_note`` says it): with 100 points, 95 % intervals cover fewer than 90 %
#: by chance with probability 0.02.
COVERAGE_LOW = 0.90


def coverage_note(result: dict) -> str:
    """In words, when a model's stated ``u95_mm`` do not hold on a campaign (coverage below
    :data:`COVERAGE_LOW` on the evaluated points, or on the registration's sample poses); '' when they do."""
    cov = result.get("coverage_95")
    if cov is None:
        return ""
    reg = (result.get("registration") or {}).get("coverage_95")
    if cov >= COVERAGE_LOW and (reg is None or reg >= COVERAGE_LOW):
        return ""
    where = f"{result['n']} {result['evaluated_on']} poses"
    return (f"the model's 95 % intervals do not hold on this campaign: {100 * cov:.0f} % of the {where} are "
            f"within their u95_mm (mean {result['u95_mm']:.3f} mm; the errors' 95th percentile is "
            f"{result['error_p95_mm']:.3f} mm)"
            + (f", {100 * reg:.0f} % of the {result['registration']['n']} sample poses registered on"
               if reg is not None else "")
            + ": this campaign scatters more than the one the model was fitted on (another day, set-up or part "
              "of the workspace); the stated uncertainty is the fit campaign's, not this one's")
