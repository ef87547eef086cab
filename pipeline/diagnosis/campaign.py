"""Diagnosis of a raw campaign folder with a spec: the adapter of its kind, its data, the result."""

from __future__ import annotations

from ..core.campaign import campaign_kind
from ..core.spec import load_spec
from ..robot.fit import check_spec_joints
from ..robot.ingest import robot_data_sets
from .encoder import EncoderAdapter, encoder_data_from_campaign
from .engine import diagnose
from .robot import RobotAdapter


def adapter_and_data(campaign, kind, workers=1):
    """The adapter of a ``kind`` campaign and its data (robot: the sample poses)."""
    if kind == "encoder":
        return EncoderAdapter(), encoder_data_from_campaign(campaign)
    robot, (data, repeat) = robot_data_sets(campaign, ("sample",), ("repeat",))
    return RobotAdapter(robot, workers=workers, repeat=repeat), data


def run_diagnosis(campaign, spec_path, progress=None, workers=1):
    """Load a raw campaign and a spec, check they match, and diagnose.

    Returns the result dict (contract section 4) and ``(adapter, spec, data)`` for the report.
    """
    spec = load_spec(spec_path)
    kind = campaign_kind(campaign)
    spec.require_kind(kind, campaign)
    adapter, data = adapter_and_data(campaign, kind, workers)
    if kind == "robot":
        check_spec_joints(spec, adapter.robot)
    result = diagnose(adapter, spec, data, progress=progress, workers=workers if kind == "encoder" else None)
    result = {"kind": result.pop("kind"), "campaign": str(campaign), "spec": str(spec_path), **result}
    return result, (adapter, spec, data)
