"""Diagnosis of a raw campaign folder with a spec: the adapter of its kind, its data, the result."""

from __future__ import annotations

import numpy as np

from ..core.campaign import campaign_kind
from ..core.errors import InputError
from ..core.spec import load_spec
from ..robot.model.fit import check_spec_joints
from ..robot.campaign.ingest import robot_data_sets
from ..robot.model.outliers import Wild, describe, find_wild
from .encoder import EncoderAdapter, encoder_data_from_campaign
from .engine import diagnose
from .robot import RobotAdapter


#: the effects a diagnosis of several campaigns adds (each campaign's own frame, probe mounting): the fit's own, not
#: the spec's (``jointcal fit`` adds them again), so the spec the loop ends with is without them
PER_CAMPAIGN = ("campaign_frame", "campaign_tool")


def several_campaigns(campaigns, spec, keep_outliers: bool = False, warn=None):
    """Several campaigns of one robot as one diagnosis sees them (contract section 15), as ``jointcal fit`` fits
    them (:func:`pipeline.robot.model.campaigns.fit_campaigns`): each read and registered on its own, its wild
    measurements found against its own model and left out (unless ``keep_outliers``), the poses stacked, each
    marked with its campaign.

    Returns
    -------
    robot : Robot
    sample, target, repeat : RobotData (stacked; ``campaign`` 1-based in the order given)
    target_all : RobotData or None (the targets with the wild ones, when some were left out)
    extra : list of str, the ``[[effect]]`` lines of each campaign's own frame (and probe mounting)
    wild : Wild (every campaign's, each outlier with its ``campaign``: :meth:`Wild.document`)
    """
    from ..robot.model.campaigns import CAMPAIGN_TOOL, campaign_frames, load_campaigns, stacked

    robot, loaded = load_campaigns(campaigns)
    check_spec_joints(spec, robot)
    own = [e for e in spec.effects if e.name not in PER_CAMPAIGN]
    samples, targets, alls, repeats, outliers, wilds = [], [], [], [], [], []
    for c, sample, target, info in loaded:
        if sample.n == 0:
            raise InputError(f"{c}/poses.csv", "no pose has set = sample: a campaign diagnosed with others needs "
                             "sample poses of its own (its tracker frame is fitted on them)", 1, "set")
        wild = find_wild(info.get("mounting_robot", robot), own, sample, target, c, keep_outliers)
        if describe(wild) and warn:
            warn(f"{c}: {describe(wild)}")
        outliers += [{**o, "campaign": c} for o in wild.outliers]
        wilds.append(wild)
        alls.append(target)
        s, t = wild.clean(sample, target)
        samples.append(s)
        targets.append(t)
        repeats.append(robot_data_sets(c, ("repeat",))[1][0])
    offsets = [info.get("mounting_offset") for *_, info in loaded]
    some_wild = any(w.target.any() for w in wilds) and not keep_outliers
    wild = Wild(np.concatenate([w.sample for w in wilds]), np.concatenate([w.target for w in wilds]), outliers,
                {c: w.sigma_mm for (c, *_), w in zip(loaded, wilds)}, keep_outliers,
                "; ".join(f"{c}: {w.no_scale}" for (c, *_), w in zip(loaded, wilds) if w.no_scale))
    extra = [e.spec_lines() for e in campaign_frames(len(loaded))]
    extra += [f'[[effect]]\nname = "{CAMPAIGN_TOOL}"\ncampaign = {k + 1}' for k, o in enumerate(offsets) if o is not None]
    return (robot, stacked(samples, offsets=offsets), stacked(targets, offsets=offsets),
            stacked(repeats, offsets=offsets), stacked(alls, offsets=offsets) if some_wild else None, extra, wild)


def adapter_and_data(campaign, kind, workers=1):
    """The adapter of a ``kind`` campaign and its data (robot: the sample poses)."""
    if kind == "encoder":
        return EncoderAdapter(), encoder_data_from_campaign(campaign)
    robot, (data, repeat) = robot_data_sets(campaign, ("sample",), ("repeat",))
    return RobotAdapter(robot, workers=workers, repeat=repeat), data


def run_diagnosis(campaign, spec_path, progress=None, workers=1, keep_outliers=False):
    """Load a raw campaign and a spec, check they match, and diagnose.

    A robot campaign's wild measurements (:mod:`pipeline.robot.model.outliers`) are named (``outliers``)
    and its wild sample poses left out of the diagnosis, unless ``keep_outliers``.
    Returns the result dict (contract section 4) and ``(adapter, spec, data)`` for the report.
    """
    spec = load_spec(spec_path)
    kind = campaign_kind(campaign)
    spec.require_kind(kind, campaign)
    wild = None
    if kind == "robot":
        robot, (data, target, repeat) = robot_data_sets(campaign, ("sample",), ("target",), ("repeat",))
        check_spec_joints(spec, robot)
        wild = find_wild(robot, list(spec.effects), data, target, campaign, keep_outliers)
        if describe(wild) and progress:
            progress(describe(wild))
        data, _ = wild.clean(data, target)
        adapter = RobotAdapter(robot, workers=workers, repeat=repeat)
    else:
        adapter, data = adapter_and_data(campaign, kind, workers)
    result = diagnose(adapter, spec, data, progress=progress, workers=workers if kind == "encoder" else None)
    result = {"kind": result.pop("kind"), "campaign": str(campaign), "spec": str(spec_path), **result}
    if wild is not None:
        result.update(wild.document())
    return result, (adapter, spec, data)


def run_diagnosis_several(campaigns, spec_path, progress=None, keep_outliers=False):
    """:func:`run_diagnosis` of several robot campaigns of one robot (``jointcal diagnose --campaign`` more than
    once, contract section 15): the spec's effects shared, each campaign its own tracker frame
    (``campaign_frame``) and, where it states one, probe mounting (``campaign_tool``), the folds by pose and by
    region each campaign's own (:func:`pipeline.diagnosis.robot.pose_folds`,
    :func:`pipeline.diagnosis.robot.campaign_region_folds`). The result has ``campaigns``: per campaign, in the
    order given, the baseline's cross-validated RMS by pose and by region on its own poses, beside the totals.
    """
    from dataclasses import replace

    from ..core.spec import parse_spec
    from .robot import split_rms

    spec = load_spec(spec_path)
    spec.require_kind("robot", campaigns[0])
    robot, data, _, repeat, _, extra, wild = several_campaigns(campaigns, spec, keep_outliers, progress)
    frames = list(parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(extra) + "\n", "<campaigns>").effects)
    together = replace(spec, effects=[e for e in spec.effects if e.name not in PER_CAMPAIGN] + frames)
    adapter = RobotAdapter(robot, repeat=repeat)
    result = diagnose(adapter, together, data, progress=progress)
    by_pose = split_rms(adapter.baseline_cv["random"], data)
    by_region = split_rms(adapter.baseline_cv["region"], data)
    per = []
    for c, p, r in zip(campaigns, by_pose, by_region):
        e = {"campaign": str(c), "index": p["index"], "n_sample": p["n"], "cv_rms": p["rms"], "cv_rms_region": r["rms"]}
        if "position_rms_mm" in p:
            e["cv_position_rms_mm"] = p["position_rms_mm"]
        per.append(e)
    result = {"kind": result.pop("kind"), "campaign": str(campaigns[0]), "campaigns": per, "spec": str(spec_path),
              **result}
    result.update(wild.document())
    return result, (adapter, together, data)
