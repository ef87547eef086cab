"""Several campaigns of one robot fitted together (contract section 15): ``jointcal fit --campaign A
--campaign B ...``.

The robot is one: every effect of the spec is shared by the campaigns. Each campaign was measured from
its own tracker station, so each keeps its own tracker-to-base frame: the first campaign's frame is the
model's base frame (the spec's ``base`` effect, when it has one), and for every campaign after the first
the fit adds a ``campaign_frame`` effect (:class:`pipeline.robot.arm.effects.CampaignFrame`: six
parameters, that campaign's shift and turn from the first's). The frame is an effect like any other:
listed in the model's effects, fitted, given its uncertainty, and explained in words. A campaign whose robot.toml
states a probe mounting of its own keeps it (``RobotData.mounting_offset``) and gets a ``campaign_tool``
effect: its own mounting error beside the shared ``tool``.

Each campaign is read and registered on its own (its ``campaign.toml``, its nominal-consistency check), its
wild measurements are found against its own flexible model (:mod:`pipeline.robot.model.outliers`), and its
point ids need only be unique within it. The held-out results come per campaign (``campaigns``) beside
the totals over every campaign (``heldout``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...core.effect import REGISTRY
from ..campaign.ingest import robot_data_sets
from .estimate import heldout_fit
from .fit import check_spec_joints, robot_fit_result
from .outliers import Wild, WildSearch, describe
from .predict import outside_calibrated_range, outside_message, outside_range, same_robot_problem

#: the effect that carries a campaign's own tracker frame (:class:`pipeline.robot.arm.effects.CampaignFrame`)
CAMPAIGN_FRAME = "campaign_frame"
#: the effect that carries a campaign's own probe mounting error (:class:`pipeline.robot.arm.effects.CampaignTool`)
CAMPAIGN_TOOL = "campaign_tool"


def _silent(message: str) -> None:
    pass


def check_distinct(campaigns) -> None:
    """Refuse a campaign folder given twice (one line naming its poses.csv)."""
    seen = {}
    for c in campaigns:
        key = Path(c).resolve()
        if key in seen:
            raise InputError(Path(c) / "poses.csv", f"the campaign {c} is given twice (--campaign {seen[key]} already "
                             "names it): each campaign once", None, None)
        seen[key] = c


def campaign_frames(n_campaigns: int) -> list:
    """The ``campaign_frame`` effects of campaigns 2..n (the first campaign's frame is the model's base)."""
    return [REGISTRY.make("robot", CAMPAIGN_FRAME, campaign=k) for k in range(2, n_campaigns + 1)]


def mounting_offset(robot, other) -> np.ndarray | None:
    """The error model's tool channels (dx, dy, dz m; ex, ey, ez rad; :attr:`RobotData.mounting_offset`) that
    put ``other``'s probe mounting (its robot.toml's ``[tool]``) in place of ``robot``'s; None when they are
    the same."""
    dxyz = (np.asarray(other.tool_xyz_mm, float) - np.asarray(robot.tool_xyz_mm, float)) / 1000.0
    R = np.asarray(robot.tool_rotation, float).T @ np.asarray(other.tool_rotation, float)
    if not np.any(dxyz) and np.allclose(R, np.eye(3), rtol=0.0, atol=1e-15):
        return None
    # R = Rx(a) Ry(b) Rz(c): the error model's turns about the probe's own axes, in that order
    b = np.arcsin(np.clip(R[0, 2], -1.0, 1.0))
    a = np.arctan2(-R[1, 2], R[2, 2])
    c = np.arctan2(-R[0, 1], R[0, 0])
    return np.concatenate([dxyz, [a, b, c]])


def stacked(parts, index: int = 1, offsets=None):
    """One :class:`~pipeline.robot.arm.effects.RobotData` of the campaigns' data sets ``parts`` (in order),
    each pose marked with its campaign (``campaign``, 1-based from ``index``); ``offsets``: each part's
    :func:`mounting_offset` (6,) or None (``mounting_offset`` only when one is not None)."""
    def cat(name):
        arrays = [getattr(p, name) for p in parts]
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    offsets = list(offsets) if offsets is not None else [None] * len(parts)
    mounting = None
    if any(o is not None for o in offsets):
        mounting = np.concatenate([np.tile(np.zeros(6) if o is None else np.asarray(o, float), (p.n, 1))
                                   for p, o in zip(parts, offsets)])

    first = parts[0]
    out = replace(first, q_deg=cat("q_deg"), dir=cat("dir"), payload_kg=cat("payload_kg"),
                  temperature_c=cat("temperature_c"), torque_nm=cat("torque_nm"), measured_mm=cat("measured_mm"),
                  point_id=cat("point_id"), measured_R=cat("measured_R"), sigma_mm=cat("sigma_mm"),
                  sigma_arcsec=cat("sigma_arcsec"),
                  campaign=np.concatenate([np.full(p.n, index + k, int) for k, p in enumerate(parts)]),
                  mounting_offset=mounting)
    joints = {tuple(getattr(p, "grating_joints", ())) for p in parts}
    out.grating_joints = joints.pop() if len(joints) == 1 else ()
    return out


def load_campaigns(campaigns):
    """Each campaign read, registered and checked to be of the first's robot.

    A campaign whose robot.toml states a probe mounting of its own (``[tool]``) is of the robot too: its
    ``info`` then has ``mounting`` (its ``tool_xyz_mm``, ``tool_rpy_deg``) and ``mounting_offset``
    (:func:`mounting_offset`).

    Returns
    -------
    robot : Robot (the first campaign's)
    loaded : list of ``(folder, sample, target, frame_info)``, in the order given
    """
    check_distinct(campaigns)
    robot, loaded = None, []
    for c in campaigns:
        r, (sample, target), info = robot_data_sets(c, ("sample",), ("target",), with_frame=True)
        if robot is None:
            robot = r
        else:
            why = same_robot_problem(robot, replace(r, tool_xyz_mm=robot.tool_xyz_mm, tool_rpy_deg=robot.tool_rpy_deg))
            if not why:
                offset = mounting_offset(robot, r)
                if offset is not None:
                    info = {**info, "mounting": {"tool_xyz_mm": [float(v) for v in r.tool_xyz_mm],
                                                 "tool_rpy_deg": [float(v) for v in r.tool_rpy_deg]},
                            "mounting_offset": offset, "mounting_robot": r}
            if why:
                why = why.replace("in the model's robot", f"in {campaigns[0]}'s robot").replace(
                    "a model applies to the robot it was fitted on", "the campaigns fitted together must be of one robot")
                raise InputError(Path(c) / "robot.toml", f"not the robot of {campaigns[0]}: {why}", None, None)
        if sample.has_orientation != (loaded[0][1].has_orientation if loaded else sample.has_orientation):
            raise InputError(Path(c) / "tracker.csv", "this campaign's tracker.csv has orientations (qw..qz) and "
                             f"{campaigns[0]}'s has not, or the other way round: fit campaigns of one kind together",
                             1, None)
        loaded.append((str(c), sample, target, info))
    return robot, loaded


def fit_campaigns(campaigns, spec, keep_outliers: bool = False, warn=_silent, orientation: bool = True,
                  progress=_silent) -> dict:
    """``jointcal fit`` with ``--campaign`` given more than once (module docstring).

    Parameters
    ----------
    campaigns : list of path
        Robot campaign folders of one robot, two or more, each once.
    spec : Spec
        The robot model; each campaign after the first adds its ``campaign_frame`` effect.
    keep_outliers, warn, orientation, progress
        As :func:`pipeline.robot.model.fit.fit_campaign`.

    Returns
    -------
    dict: the fit document of :func:`pipeline.robot.model.fit.robot_fit_result` over every campaign's poses
    (``heldout``: the totals), with ``campaigns``: per campaign, in the order given, ``{"campaign", "index",
    "frame", "tracker_to_base_fitted", "frame_effect", "n_sample", "n_target", "heldout", "outliers"}`` and
    ``mounting`` for a campaign with a probe mounting of its own (docs/formats.md, "Several campaigns"); wild
    measurements carry their ``campaign``.
    """
    spec.require_kind("robot", campaigns[0])
    robot, loaded = load_campaigns(campaigns)
    check_spec_joints(spec, robot)
    own = [e for e in spec.effects if e.name not in (CAMPAIGN_FRAME, CAMPAIGN_TOOL)]
    for c, sample, target, _ in loaded:
        if sample.n == 0:
            raise InputError(Path(c) / "poses.csv", "no pose has set = sample: a campaign fitted with others needs "
                             "sample poses of its own (its tracker frame is fitted on them)", 1, "set")
        outside = outside_calibrated_range(sample.q_deg, target.q_deg, target.point_id) if target.n else []
        if outside:
            warn(f"warning: {c}: {outside_message(outside, worst=True)}")
    # each campaign's wild measurements, against its own flexible model (as when it is fitted alone)
    wilds = []
    for c, sample, target, info in loaded:
        # against the campaign's own robot.toml (its own probe mounting, where it states one)
        mine = info.get("mounting_robot", robot)
        wild = WildSearch(mine, own, sample, target, c, keep_outliers, background=False).result()
        if describe(wild):
            warn(f"{c}: {describe(wild)}")
        wilds.append(wild)
    outliers = []
    for (c, *_), wild in zip(loaded, wilds):
        outliers += [{**o, "campaign": c} for o in wild.outliers]
    wild = Wild(np.concatenate([w.sample for w in wilds]), np.concatenate([w.target for w in wilds]), outliers,
                {c: w.sigma_mm for (c, *_), w in zip(loaded, wilds)}, keep_outliers,
                "; ".join(f"{c}: {w.no_scale}" for (c, *_), w in zip(loaded, wilds) if w.no_scale))
    offsets = [info.get("mounting_offset") for *_, info in loaded]
    sample = stacked([s for _, s, _, _ in loaded], offsets=offsets)
    target = stacked([t for _, _, t, _ in loaded], offsets=offsets)
    # a spec's own campaign_frame (campaign_tool) tables (a fit JSON's spec_effects given back as a spec) are the
    # fit's to add
    effects = own + campaign_frames(len(loaded)) + [REGISTRY.make("robot", CAMPAIGN_TOOL, campaign=k + 1)
                                                   for k, o in enumerate(offsets) if o is not None]
    together = replace(spec, effects=effects)
    out = robot_fit_result(campaigns[0], together, (robot, sample, target, loaded[0][3]), wild,
                           orientation=orientation, warn=_silent, progress=progress)
    out["campaign"] = str(campaigns[0])
    out["campaigns"] = per_campaign(robot, effects, out, loaded, wilds, keep_outliers)
    return out


def per_campaign(robot, effects, out: dict, loaded, wilds, keep_outliers: bool) -> list[dict]:
    """The fit's held-out results campaign by campaign (the model of ``out`` rebuilt from its parameters)."""
    from .estimator import RobotErrorModel

    model = RobotErrorModel.from_parameters(robot, _fitted_effects(out), out["parameters"])
    entries = []
    for k, ((c, sample, target, info), wild) in enumerate(zip(loaded, wilds)):
        s, t = (sample, target) if keep_outliers else wild.clean(sample, target)
        offset = info.get("mounting_offset")
        s = stacked([s], index=k + 1, offsets=[offset])
        t = stacked([t], index=k + 1, offsets=[offset]) if t.n else t
        frame = {key: v for key, v in info.items() if not key.startswith("mounting")}
        entry = {"campaign": c, "index": k + 1, "frame": frame,
                 "tracker_to_base_fitted": fitted_tracker_to_base(robot, out["parameters"], k + 1, info["tracker_to_base"]),
                 "frame_effect": CAMPAIGN_FRAME if k else "base", "n_sample": int(s.n), "n_target": int(t.n)}
        if offset is not None:
            entry["mounting"] = {**info["mounting"], "offset": [float(v) for v in offset],
                                 "effect": CAMPAIGN_TOOL}
        if t.n:
            h = heldout_fit(robot, effects, s, t, model=model)
            h.pop("parameters", None)
            h.pop("identifiability", None)
            # outside the joint ranges the model was fitted on (every campaign's sample poses)
            h["outside_sampled_range"] = int(outside_range(t.q_deg, out["sampled_range"]).sum())
            entry["heldout"] = h
        entry["outliers"] = [o for o in out.get("outliers", []) if o.get("campaign") == c]
        entries.append(entry)
    return entries


def base_frame(robot, values_mm_arcsec) -> np.ndarray:
    """The base frame (4x4, mm) the error model's base channels put at ``values_mm_arcsec`` (dx, dy, dz mm; ex, ey,
    ez arcsec: a ``base`` effect's parameters, or those plus a ``campaign_frame``'s)."""
    import pinocchio as pin

    from ...core.se3 import ARCSEC_PER_RAD
    from ..arm.kinematics import TWIST, build_error_model

    model, idx = build_error_model(robot)
    q = np.zeros(idx.nq)
    v = np.asarray(values_mm_arcsec, float)
    q[idx.base] = np.concatenate([v[:3] * 1e-3, v[3:] / ARCSEC_PER_RAD])
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    M = data.oMi[model.getJointId(f"base_{TWIST[-1]}")]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = M.rotation, M.translation * 1e3
    return T


def fitted_tracker_to_base(robot, parameters, index: int, tracker_to_base) -> list:
    """Campaign ``index``'s tracker frame in the model's base frame (4x4 list, mm): the transform its ingest
    registered (``tracker_to_base``), then its ``campaign_frame`` (none for the first campaign): a point the
    tracker of that campaign measured, in the frame the first campaign's tracker puts the robot's base."""
    by = {p["name"]: float(p["value"]) for p in parameters}
    from ..arm.kinematics import TWIST

    shared = np.array([by.get(f"base_{t}", 0.0) for t in TWIST])
    own = np.array([by.get(f"campaign{index}_{t}", 0.0) for t in TWIST]) if index > 1 else np.zeros(6)
    T = base_frame(robot, shared) @ np.linalg.inv(base_frame(robot, shared + own)) @ np.asarray(tracker_to_base, float)
    return [list(map(float, r)) for r in T]


def _fitted_effects(out: dict) -> list:
    """The fitted model's effects (as prepared for the fit: a joint map's grid) from the fit document."""
    from ...core.spec import parse_spec

    spec = parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(out["spec_effects"]) + "\n", "<fit>")
    return list(spec.effects)


def predict_campaigns(campaigns, document: dict, model_path, register: bool, keep_outliers: bool = False,
                      warn=_silent, point_mm=None) -> dict:
    """``jointcal predict`` with ``--campaign`` more than once: the model applied to each campaign as
    :func:`pipeline.robot.model.predict.predict_other_campaign` does (a campaign the model was fitted on, among
    several, in its own fitted frame), and the totals over all of them.

    Returns
    -------
    dict: the totals over every campaign's evaluated points (``n``, ``rms_mm``, ``max_mm``, ``mean_mm``,
    ``std_mm``, ``outside_sampled_range``; ``coverage_95`` and ``u95_mm`` when the model states its
    uncertainty; 6-DoF: ``orientation_n``, ``orientation_rms_arcsec``, ``orientation_max_arcsec``), ``points``
    (each with its ``campaign``), ``outliers`` (each with its ``campaign``) and ``campaigns``: each campaign's
    own result, in the order given, with ``campaign`` (its folder).
    """
    from .predict import error_summary, predict_other_campaign

    check_distinct(campaigns)
    parts = []
    for c in campaigns:
        result = predict_other_campaign(c, document, model_path, register, keep_outliers,
                                        lambda m, c=c: warn(f"{c}: {m}"), point_mm)
        parts.append({"campaign": str(c), **result})
    points = [{**p, "campaign": part["campaign"]} for part in parts for p in part["points"]]
    e = np.array([p["error_mm"] for p in points], float)
    out = error_summary(np.c_[e, np.zeros((e.size, 2))])
    out["outside_sampled_range"] = int(sum(part["outside_sampled_range"] for part in parts))
    if all("coverage_95" in part for part in parts):
        u = np.array([p["u95_mm"] for p in points], float)
        out["coverage_95"] = float(np.mean(e <= u))
        out["u95_mm"] = float(np.mean(u))
    if all("orientation_rms_arcsec" in part for part in parts):
        a = np.array([p["orientation_error_arcsec"] for p in points], float)
        out.update({"orientation_n": int(a.size), "orientation_rms_arcsec": float(np.sqrt(np.mean(a ** 2))),
                    "orientation_max_arcsec": float(a.max())})
    out["points"] = points
    out["outliers"] = [{**o, "campaign": part["campaign"]} for part in parts for o in part.get("outliers", [])]
    out["campaigns"] = parts
    return out
