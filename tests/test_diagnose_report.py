"""Diagnosis report: written, every page there, same bytes twice; encoder and a d = 3 adapter."""

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import ROOT


def n_pages(path):
    """Number of page objects (``/Type /Page``, not ``/Pages``) in a PDF."""
    return len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", path.read_bytes()))


def expected_pages(result, adapter, data):
    from pipeline.core.plotting import text_page_count
    from pipeline.diagnosis.report import PANELS_PER_PAGE, SUMMARY_FONTSIZE, summary_lines

    variables = adapter.signature_variables(data).values()
    panels = sum(2 if kind == "angle" else 1 for _, _, kind in variables)
    summary = text_page_count(summary_lines(result), SUMMARY_FONTSIZE)
    signatures = int(any(c["meaningful"] for c in result["candidates"]))
    # at a glance, residuals, the recommended effects' signatures, candidates, waterfall, text (appendix)
    return 1 + math.ceil(panels / PANELS_PER_PAGE) + signatures + 2 + summary


# ------------------------------------------------------------------------------ encoder
@pytest.fixture(scope="module")
def encoder_diagnosis():
    from pipeline.diagnosis.campaign import run_diagnosis

    result, (adapter, spec, data) = run_diagnosis(ROOT / "raw" / "encoder" / "a", ROOT / "specs" / "encoder_paper.toml")
    return result, adapter, spec, data


def test_encoder_report_pages_and_same_bytes_twice(encoder_diagnosis, tmp_path):
    from pipeline.diagnosis.report import diagnosis_report

    result, adapter, spec, data = encoder_diagnosis
    first, second = tmp_path / "one" / "diagnosis.pdf", tmp_path / "two" / "diagnosis.pdf"
    diagnosis_report(result, adapter, spec, data, first)
    diagnosis_report(result, adapter, spec, data, second)
    raw = first.read_bytes()
    assert raw.startswith(b"%PDF") and raw == second.read_bytes()
    # at a glance, residuals (angle + spectrum, time, temperature, direction, run), candidates, waterfall,
    # the summary's text (appendix)
    assert n_pages(first) == expected_pages(result, adapter, data) == 5


def test_cli_writes_report(invoke, tmp_path):
    out = tmp_path / "reports" / "diagnosis.pdf"
    res = invoke("diagnose", "--campaign", ROOT / "raw" / "encoder" / "a", "--spec", ROOT / "specs" / "encoder_paper.toml",
                 "--json", tmp_path / "d.json", "--report", out, "--quiet")
    assert res.exit_code == 0, res.output
    assert out.read_bytes().startswith(b"%PDF") and n_pages(out) == 5


def test_hidden_direction_report(invoke, tmp_path):
    """A two-way campaign with a hidden hysteresis: the report is written and the waterfall's
    suggested bars start with the top meaningful candidate."""
    from pipeline.diagnosis.campaign import run_diagnosis
    from pipeline.diagnosis.report import diagnosis_report, suggested_steps

    res = invoke("simulate", "encoder", "--out", tmp_path / "sim", "--truth", tmp_path / "truth", "--module", "a",
                 "--two-way", "--hidden", "direction", "--seed", "5")
    assert res.exit_code == 0, res.output
    result, (adapter, spec, data) = run_diagnosis(tmp_path / "sim" / "a", ROOT / "specs" / "encoder_paper.toml")
    out = tmp_path / "d.pdf"
    diagnosis_report(result, adapter, spec, data, out)
    assert n_pages(out) == expected_pages(result, adapter, data)
    best = [c for c in result["candidates"] if c["meaningful"]]
    assert best and best[0]["effect"] == "direction", [(c["effect"], c["target"], c["gain"]) for c in result["candidates"][:3]]
    steps = suggested_steps(result, adapter, spec, data, adapter.baseline_effects(spec, data))
    assert steps and steps[0]["cv_rms"] == best[0]["cv_rms_with"]
    assert all(s["cv_rms"] > 0 for s in steps)


def test_spectrum_finds_the_order():
    from pipeline.diagnosis.report import residual_spectrum

    theta = np.tile(np.arange(0.0, 360.0, 10.0), 3)
    r = 2.0 * np.sin(np.radians(5 * theta) + 0.3) + 0.01 * np.cos(np.radians(3 * theta))
    orders, amp = residual_spectrum(theta, r[:, None])
    assert orders[0] == 1 and orders[-1] == 17
    assert orders[np.argmax(amp)] == 5 and amp.max() == pytest.approx(2.0, rel=1e-9)
    # d = 3: root sum of squares of the components
    orders, amp3 = residual_spectrum(theta, np.column_stack([r, r, 0 * r]))
    assert amp3[4] == pytest.approx(2.0 * np.sqrt(2), rel=1e-9)


# ------------------------------------------------------------------------------ d = 3 (robot-like)
class _Effect:
    def __init__(self, name, joint=None):
        self.name, self.joint = name, joint
        self.params = {} if joint is None else {"joints": [joint]}

    def target(self):
        return self.joint

    def spec_lines(self):
        return f'[[effect]]\nname = "{self.name}"' + ("" if self.joint is None else f"\njoints = [{self.joint}]")


class _RobotLikeAdapter:
    """Just enough of the adapter interface, with the robot's shapes: d = 3 residuals in mm,
    joint angles, torques, categorical directions, temperature, payload."""

    unit = "mm"

    def baseline_effects(self, spec, data):
        return list(spec.effects)

    def candidates(self, spec, data, base_effects):
        return [_Effect("backlash", 2), _Effect("compliance", 3), _Effect("thermal")]

    @staticmethod
    def add(base_effects, cand):
        return [*base_effects, cand]

    def cross_validate(self, effects, data):
        from pipeline.core.crossval import CVResult

        have = {(e.name, e.joint) for e in effects}
        r = data["noise"].copy()
        if ("geometry", None) not in have:
            r[:, 0] += 0.4 * np.sin(np.radians(data["q"][:, 1]))
        if ("backlash", 2) not in have:
            r[:, 2] += 0.05 * data["dir"][:, 1]
        return CVResult(r, data["pose"].copy())

    def signature_variables(self, data):
        out = {}
        for j in range(6):
            out[f"q{j + 1}"] = (data["q"][:, j], "deg", "angle")
        for j in range(6):
            out[f"gravity torque {j + 1}"] = (data["tau"][:, j], "N m", "continuous")
        for j in range(6):
            out[f"direction {j + 1}"] = (data["dir"][:, j], "+1/-1", "categorical")
        out["temperature"] = (data["temp"], "degC", "continuous")
        out["payload"] = (data["payload"], "kg", "categorical")
        return out


def robot_like_inputs():
    """(result, adapter, spec, data) of a synthetic robot-like diagnosis: backlash on joint 2 missing."""
    rng = np.random.default_rng(3)
    n = 240
    data = {"q": rng.uniform(-170, 170, (n, 6)), "tau": rng.normal(0, 40, (n, 6)),
            "dir": rng.choice([-1.0, 1.0], (n, 6)), "temp": rng.uniform(19, 24, n),
            "payload": rng.choice([0.0, 5.0], n), "noise": rng.normal(0, 0.02, (n, 3)), "pose": np.arange(n)}
    adapter = _RobotLikeAdapter()
    spec = SimpleNamespace(kind="robot", effects=[_Effect("geometry")])
    base = adapter.cross_validate(spec.effects, data)
    with_b = adapter.cross_validate([*spec.effects, _Effect("backlash", 2)], data)

    def cand(effect, target, rms, meaningful, p):
        return {"effect": effect, "target": target, "cv_rms_with": rms, "gain": 1 - rms / base.rms,
                "meaningful": meaningful, "p": p, "t": 3.0, "test": "paired t over 240 blocks",
                "evidence": "long evidence " * 20, "explanation": "a physical explanation " * 10,
                "spec_line": f'[[effect]]\nname = "{effect}"' + ("" if target is None else f"\njoints = [{target}]")}

    result = {"kind": "robot",
              "baseline": {"effects": ["geometry"], "cv_rms": base.rms, "unit": "mm", "folds": "by pose, 5 folds"},
              "candidates": [cand("backlash", 2, with_b.rms, True, 1e-9),
                             cand("compliance", 3, base.rms * 1.002, False, 0.6),
                             cand("thermal", None, base.rms * 0.995, False, 0.03)],
              "not_revealable": [{"effect": "tool", "target": None, "reason": "one tool only", "explanation": ""}],
              "thresholds": {"alpha": 0.05, "p_max": 0.05 / 3, "min_gain": 0.01}}
    return result, adapter, spec, data


@pytest.fixture(scope="module")
def robot_like():
    return robot_like_inputs()


def test_vector_residual_report(robot_like, tmp_path):
    from pipeline.diagnosis.report import diagnosis_report

    result, adapter, spec, data = robot_like
    first, second = tmp_path / "a.pdf", tmp_path / "b.pdf"
    diagnosis_report(result, adapter, spec, data, first)
    diagnosis_report(result, adapter, spec, data, second)
    assert first.read_bytes() == second.read_bytes()
    # 6 angles (+ 6 spectra), 6 torques, 6 directions, temperature, payload = 26 panels: 3 pages; backlash 2's
    # signature
    assert n_pages(first) == expected_pages(result, adapter, data) == 1 + 3 + 1 + 2 + 1


def test_the_signature_a_recommended_effect_explains(robot_like):
    """Backlash of joint 2 (hidden in z, following joint 2's direction of last motion): the page that shows
    it next to its residual draws that direction and component, not another variable."""
    from pipeline.diagnosis.report import explained_signature

    result, adapter, spec, data = robot_like
    base = adapter.cross_validate(spec.effects, data)
    after = adapter.cross_validate([*spec.effects, _Effect("backlash", 2)], data)
    assert explained_signature(adapter.signature_variables(data), base.residuals, after.residuals) == ("direction 2", 2)
    # geometry, missing, leaves 0.4 mm sin(q2) in x: added, it explains q2's pattern in x
    none = adapter.cross_validate([], data)
    assert explained_signature(adapter.signature_variables(data), none.residuals, base.residuals) == ("q2", 0)


def test_candidates_not_revealable_for_one_reason_are_said_once():
    """A joint's harmonics of every order, none revealable for the same reason, are one item of the
    appendix with their orders and one plan; another joint's, or another reason, stays an item of its own."""
    from pipeline.diagnosis.report import summary_lines

    def item(joint, order, reason="joint 1 is read by its grating"):
        return {"effect": "joint_harmonic", "target": joint, "reason": reason, "needs": "joint spread",
                "plan": f"jointcal plan --reveal 'name = \"joint_harmonic\", joints = [{joint}], orders = [{order}]'"}

    result = {"kind": "robot", "unit": "mm", "baseline": {"cv_rms": 0.1, "cv_rms_region": 0.12, "unit": "mm", "effects": ["geometry"],
                           "folds": "5-fold"},
              "candidates": [], "meaningful": [], "not_revealable":
              [item(1, 1), item(1, 5), item(1, 6), item(2, 1, "joint 2 is read by its grating"), item(1, 7, "other")]}
    lines = [l.strip() for l in summary_lines(result)]
    said = [l for l in lines if l.startswith("- joint_harmonic")]
    assert said[0].startswith("- joint_harmonic 1 (orders 1, 5, 6): joint 1 is read by its grating")
    assert said[1].startswith("- joint_harmonic 2: joint 2") and said[2].startswith("- joint_harmonic 1: other")
    assert len(said) == 3
    assert sum("plan them with" in l for l in lines) == 3
