"""The loop checks itself (issue 16): a round that does not lower the cross-validated error (by pose
and by region) is rolled back, and the round before's candidates are added one at a time, each kept
only if it helps; the loop never ends on a model worse than its best round. The control logic, with
diagnosis and the fits replaced by stand-ins whose numbers the test chooses."""

from __future__ import annotations

import numpy as np

from pipeline.diagnosis import loop as loop_mod

START = '[model]\nkind = "robot"\n\n[[effect]]\nname = "geometry"\n'
A = '[[effect]]\nname = "backlash"\njoints = [4]'
B = '[[effect]]\nname = "backlash"\njoints = [5]'


class _Data:
    n = 3
    measured_mm = np.zeros((3, 3))
    has_orientation = False  # a position-only campaign


class _Model:
    converged_ = plausible_ = True

    def predict(self, data):
        return np.zeros((data.n, 3))


def _key(effects):
    return tuple(sorted(e.spec_lines() for e in effects if e.name == "backlash"))


def test_a_round_that_makes_it_worse_is_rolled_back(monkeypatch):
    a, b = (loop_mod.parse_spec(f"{START}\n{x}\n").effects[-1].spec_lines() for x in (A, B))
    # cross-validated RMS (by pose, by region) of each model the loop may build
    cv = {(): (1.0, 1.0), tuple(sorted([a, b])): (1.2, 0.9), (a,): (0.8, 0.85), (b,): (1.1, 1.1)}
    recommend = {(): [("backlash joint 4", a, 0.3), ("backlash joint 5", b, 0.1)]}

    def fake_diagnose(adapter, spec, data, progress=None):
        k = _key(spec.effects)
        cands = [{"effect": "backlash", "target": int(lab[-1]), "meaningful": True, "gain": g, "spec_line": line}
                 for lab, line, g in recommend.get(k, [])]
        return {"baseline": {"cv_rms": cv[k][0], "cv_rms_region": cv[k][1], "unit": "mm"}, "candidates": cands}

    monkeypatch.setattr(loop_mod, "diagnose", fake_diagnose)
    monkeypatch.setattr(loop_mod, "fit_effects", lambda robot, effects, data: _Model())
    monkeypatch.setattr(loop_mod, "model_cv", lambda robot, effects, data: cv[_key(effects)])
    out = loop_mod.diagnosis_loop(None, START, _Data(), _Data())
    rounds = out["rounds"]
    assert [r["kept"] for r in rounds] == [True, False, True]
    assert "rolled back" in rounds[1]["rolled_back"]
    assert [(t["label"], t["kept"]) for t in rounds[1]["one_at_a_time"]] == [("backlash joint 4", True),
                                                                              ("backlash joint 5", False)]
    assert out["final_round"] == 3 and out["ended"]
    final = loop_mod.parse_spec(out["final_spec"]).effects
    assert _key(final) == (a,)          # the best model seen, not the round that made it worse


def test_nothing_helps_alone_keeps_the_round_before(monkeypatch):
    a, b = (loop_mod.parse_spec(f"{START}\n{x}\n").effects[-1].spec_lines() for x in (A, B))
    cv = {(): (1.0, 1.0), tuple(sorted([a, b])): (1.2, 0.9), (a,): (1.05, 0.95), (b,): (1.1, 1.1)}
    recommend = {(): [("backlash joint 4", a, 0.3), ("backlash joint 5", b, 0.1)]}

    def fake_diagnose(adapter, spec, data, progress=None):
        k = _key(spec.effects)
        cands = [{"effect": "backlash", "target": int(lab[-1]), "meaningful": True, "gain": g, "spec_line": line}
                 for lab, line, g in recommend.get(k, [])]
        return {"baseline": {"cv_rms": cv[k][0], "cv_rms_region": cv[k][1], "unit": "mm"}, "candidates": cands}

    monkeypatch.setattr(loop_mod, "diagnose", fake_diagnose)
    monkeypatch.setattr(loop_mod, "fit_effects", lambda robot, effects, data: _Model())
    monkeypatch.setattr(loop_mod, "model_cv", lambda robot, effects, data: cv[_key(effects)])
    out = loop_mod.diagnosis_loop(None, START, _Data(), _Data())
    assert [r["kept"] for r in out["rounds"]] == [True, False]
    assert out["final_round"] == 1 and _key(loop_mod.parse_spec(out["final_spec"]).effects) == ()
    assert "rolled back" in out["done"]


def test_a_kept_round_that_raises_a_held_out_max_is_named():
    from pipeline.diagnosis.loop import _flag_max_rises

    def stats(rms, mx):
        return {"rms_mm": rms, "max_mm": mx}

    rounds = [{"round": 1, "kept": True, "own": stats(0.20, 0.90), "other": stats(0.80, 1.54)},
              {"round": 2, "kept": False, "own": stats(0.30, 2.00), "other": stats(0.90, 3.00)},   # rolled back
              {"round": 3, "kept": True, "own": stats(0.10, 0.80), "other": stats(0.75, 1.62)},
              {"round": 4, "kept": True, "own": stats(0.09, 0.8005), "other": None}]
    _flag_max_rises(rounds)
    assert "max_rose" not in rounds[0] and "max_rose" not in rounds[1] and "max_rose" not in rounds[3]
    assert rounds[2]["max_rose"] == ["the max error on the other series' targets rose from 1.540 to 1.620 mm "
                                     "(RMS 0.800 -> 0.750 mm) since round 1"]
