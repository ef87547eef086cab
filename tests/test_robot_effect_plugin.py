"""A robot effect is one class: diagnosis's candidates, the grating rule and the simulator's
``--hidden`` come from the effect classes in the registry, so a new class registered (in a
registry of its own here) is tried by diagnosis without touching any other file; and the
registry-driven candidate list keeps the order diagnosis had when it named effects itself
(results depend on it)."""

import numpy as np

from conftest import ROOT
from pipeline.core.effect import Registry
from pipeline.diagnosis.robot import RobotAdapter
from pipeline.robot.arm.effects import EFFECTS, RobotData, RobotEffect, jh_orders
from pipeline.robot.arm.kinematics import load_robot
from pipeline.robot.cell.simulate import hidden_effects_help, hidden_robot_effect

ROBOT = load_robot(ROOT / "raw" / "robot" / "kr210" / "robot.toml")


def data(n=30, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = ROBOT.lower_deg, ROBOT.upper_deg
    q = rng.uniform(lo, hi, (n, 6))
    return RobotData(q, np.ones((n, 6), int), np.zeros(n), np.full(n, 20.0), np.zeros((n, 6)), lo, hi)


def key(e):
    return (e.name, e.params.get("joints"), e.params.get("orders"))


def test_candidates_keep_the_order_diagnosis_had_when_it_named_effects():
    d = data()
    base = [cls() for cls in EFFECTS if cls.name in ("geometry", "base")]
    base.append(next(cls for cls in EFFECTS if cls.name == "backlash")(joints=[4, 5, 6]))
    got = [key(c) for c in RobotAdapter(ROBOT).candidates(None, d, base)]
    # the list as diagnosis wrote it before the effects declared their own candidates
    want = [("tool", None, None), ("thermal", None, None)]
    want += [("backlash", [j], None) for j in (1, 2, 3)]
    for name in ("compliance", "joint_map", "chebyshev"):
        want += [(name, [j], None) for j in range(1, 7)]
    want += [("joint_harmonic", [j], [k]) for j in range(1, 7) for k in jh_orders(d.q_deg[:, j - 1])]
    assert got == want


def test_a_new_effect_is_one_class():
    class Stiction(RobotEffect):
        """A throwaway effect: declared here only, registered in a registry of its own."""
        name = "stiction"
        diagnosis_order = 4.5          # between backlash and compliance
        on_joint_angle = True
        acts_on = "joint angle"

    registry = Registry()
    registry.register(*EFFECTS, Stiction)
    adapter = RobotAdapter(ROBOT)
    adapter.registry = registry
    d = data()
    cands = adapter.candidates(None, d, [])
    names = [c.name for c in cands]
    assert [c.params["joints"] for c in cands if c.name == "stiction"] == [[j] for j in range(1, 7)]
    first = names.index("stiction")
    assert names[first - 1] == "backlash" and names[first + 6] == "compliance"
    # an angle error of a joint read by its grating never reaches the residuals
    d.grating_joints = (1, 2, 3)
    on_grating = next(c for c in cands if c.name == "stiction" and c.target() == 2)
    assert "grating" in adapter.reveal_problem(on_grating, d, [])
    # and the shared registry does not know it
    assert "stiction" not in [c.name for c in RobotAdapter(ROBOT).candidates(None, d, [])]


def test_hidden_effects_come_from_the_classes():
    assert hidden_effects_help() == "base, tool, thermal, backlash:J, compliance:J or joint_harmonic:J"
    h = hidden_robot_effect("backlash:5", 15)
    assert h["effect"] == "backlash" and h["joint"] == 5 and 40 <= h["arcsec"] <= 120
    for bad in ("geometry", "nope"):
        try:
            hidden_robot_effect(bad, 15)
        except ValueError as exc:
            assert "backlash:J" in str(exc)
        else:
            raise AssertionError(f"{bad} was accepted")
