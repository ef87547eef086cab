"""Diagnosis of a raw campaign folder with a spec: the adapter of its kind, its data, the result."""

from __future__ import annotations

from ..core.campaign import campaign_kind
from ..core.spec import load_spec
from ..robot.model.fit import check_spec_joints
from ..robot.campaign.ingest import robot_data_sets
from ..robot.model.outliers import describe, find_wild
from .encoder import EncoderAdapter, encoder_data_from_campaign
from .engine import diagnose
from .robot import RobotAdapter


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
