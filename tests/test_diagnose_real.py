"""Diagnosis on the real UR10 (issue #12): the loop "diagnose, add what it recommends, diagnose again"
ends within three rounds, reaches the black boxes' held-out error with physics, and the model it
produces carries over to the other measurement series at least as well as a kinematic calibration."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ROOT, cli_invoker
from pipeline.diagnosis.engine import diagnose
from pipeline.diagnosis.robot import RobotAdapter
from pipeline.robot.ingest import robot_data_sets
from pipeline.robot.evaluate import fit_effects
from pipeline.robot.frame import apply, rigid_fit
from pipeline.core.spec import parse_spec

REAL = ROOT / "raw" / "real" / "ur10-ipa"
SOURCES = {"B": "Series_B/measurements_joint_configurations.csv", "C": "Series_C/measurements_random_poses.csv"}


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("real")
    out = {}
    for s, src in SOURCES.items():
        r = cli_invoker()("import", "--source", REAL / src, "--map", REAL / "map.toml", "--robot", REAL / "robot.toml",
                          "--out", tmp / s)
        assert r.exit_code == 0, r.output
        robot, (smp, tgt) = robot_data_sets(tmp / s, ("sample",), ("target",))
        out[s] = (robot, smp, tgt)
    return out


def _errors(model, other):
    """(own-series target errors, other-series target errors after re-registering the tracker)."""
    robot, smp, tgt = other
    ps, pt = model.predict(smp), model.predict(tgt)
    R, t = rigid_fit(smp.measured_mm, ps)
    return np.linalg.norm(apply(R, t, tgt.measured_mm) - pt, axis=1)


def _rms(e):
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.mark.parametrize("name", ["C", "B"])
def test_following_the_recommendations_ends_and_carries_over(series, name):
    other = series["B" if name == "C" else "C"]
    robot, smp, tgt = series[name]
    text = (ROOT / "specs" / "robot_kinematic.toml").read_text()
    first = None
    for rnd in range(4):
        spec = parse_spec(text)
        model = fit_effects(robot, list(spec.effects), smp)
        own = np.linalg.norm(tgt.measured_mm - model.predict(tgt), axis=1)
        far = _errors(model, other)
        first = first or (own, far)
        result = diagnose(RobotAdapter(robot), spec, smp)
        best = [c for c in result["candidates"] if c["meaningful"]]
        # nothing refused or cancelling is ever recommended, and high-order global harmonics are not
        assert not any(c.get("refused") for c in best)
        if not best:
            break
        text += "\n" + "\n\n".join(c["spec_line"] for c in best) + "\n"
    assert rnd <= 3, "the loop did not end within three rounds"
    assert rnd >= 1, "diagnosis found nothing on a real robot"
    # never worse on the other series (RMS or max), and better than the kinematic calibration
    assert _rms(far) < _rms(first[1]) and far.max() <= first[1].max() + 1e-9
    if name == "C":
        assert _rms(own) <= 0.15            # gradient boosting's 0.153 mm on the same split
