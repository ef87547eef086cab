"""Same inputs, same bytes: the whole pipeline, run once in a scratch copy, writes the Parquet, CSV,
JSON and PDF files whose SHA-256 the committed reference ``tests/data/make-all.sha256`` lists, file
for file and nothing else (issue 32: it ran `make all` twice side by side and compared the two runs,
most of the suite's time; the reference is that comparison with a run made once and kept). A change
meant to change the outputs rewrites the reference: ``make reference`` (mk/reference.py).

The same run carries the real UR10 diagnosis loop's checks (issues #12 and #16): `make all` runs
`jointcal robot diagnose-loop` on both real series, so the loop is judged on what it wrote rather
than run again (the suite's largest cost)."""

import importlib.util
import json

import pytest

from conftest import ROOT


def _reference_module():
    spec = importlib.util.spec_from_file_location("reference", ROOT / "mk" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """The scratch copy that ran `make all` (a list of one, as the loop tests read ``two_runs[0]``)."""
    ref = _reference_module()
    copy = ref.scratch_copy(tmp_path_factory.mktemp("runs") / "one")
    try:
        ref.run_make_all(copy, timeout=1500)
    except RuntimeError as exc:
        pytest.fail(f"make all failed:\n{exc}")
    return [copy]


def test_make_all_gives_the_reference_bytes(two_runs):
    ref = _reference_module()
    files = ref.hashes(two_runs[0])
    assert any(f.endswith(".pdf") for f in files) and any(f.endswith(".parquet") for f in files)
    assert ref.differences(two_runs[0]) == [], "make all wrote other bytes than tests/data/make-all.sha256: " \
        "if that was meant, `make reference` rewrites it (say which files changed, and why)"


def test_the_reference_check_can_fail(tmp_path):
    """The comparison names a changed, a missing and an unlisted file (it is not vacuous)."""
    ref = _reference_module()
    for d in ("interim", "results", "reports"):
        (tmp_path / d).mkdir()
    (tmp_path / "results" / "a.json").write_text("{}\n")
    (tmp_path / "results" / "b.json").write_text("[]\n")
    listed = tmp_path / "ref.sha256"
    ref.write_reference(tmp_path, listed)
    assert ref.differences(tmp_path, listed) == []
    (tmp_path / "results" / "a.json").write_text("{ }\n")
    (tmp_path / "results" / "b.json").unlink()
    (tmp_path / "reports" / "c.pdf").write_bytes(b"%PDF")
    assert ref.differences(tmp_path, listed) == ["changed: results/a.json",
                                                 "missing (in the reference, not written): results/b.json",
                                                 "new (written, not in the reference): reports/c.pdf"]


@pytest.mark.parametrize("name", ["C", "B"])
def test_real_diagnosis_loop_ends_and_carries_over(two_runs, name):
    """Diagnosis on the real UR10 (issue #12): the loop "diagnose, add what it recommends, diagnose
    again" (jointcal robot diagnose-loop, as `make all` runs it) ends within three rounds, reaches the
    black boxes' held-out error with physics, and the model it produces carries over to the other
    series at least as well as a kinematic calibration. Issue 16: every round's set is verified by
    refitting it, never ending worse than it started; on Series B the overlapping pair (chebyshev
    joint 2 beside joint_map joint 2, each meaningful alone) yields one recommendation."""
    loop = json.loads((two_runs[0] / "results" / "real" / f"{name}_loop.json").read_text())
    rounds = loop["rounds"]
    assert loop["ended"] and len(rounds) <= 3, "the loop did not end within three rounds"
    assert len(rounds) >= 2, "diagnosis found nothing on a real robot"
    first, last = rounds[0], rounds[loop["final_round"] - 1]
    for r in rounds:
        v = r["verified_set"]
        if r["recommended"]:
            # the recommended set was refitted as a set and beat the baseline by pose and by region
            assert v["checked"] and v["passed"] and v["members"] == [c["label"] for c in r["recommended"]]
            assert v["cv_rms"] < v["baseline_cv_rms"] and v["cv_rms_region"] < v["baseline_cv_rms_region"]
        # at most one of an overlapping pair, on every joint
        joints = {}
        for c in r["recommended"]:
            eff, _, j = c["label"].split()[:3]
            if eff in ("joint_map", "chebyshev", "joint_harmonic"):
                joints.setdefault(j, set()).add(eff)
        assert all(len(v) == 1 for v in joints.values()), r["recommended"]
    # never ends worse than it started: cross-validated (what the loop decides on), the other series
    # (RMS and max) and its own held-out RMS
    assert last["cv_rms_mm"] <= first["cv_rms_mm"] and last["cv_rms_region_mm"] <= first["cv_rms_region_mm"]
    assert last["other"]["rms_mm"] < first["other"]["rms_mm"] and last["other"]["max_mm"] <= first["other"]["max_mm"]
    assert last["own"]["rms_mm"] < first["own"]["rms_mm"]
    kept = [r for r in rounds if r["kept"]]
    assert all(b["cv_rms_mm"] < a["cv_rms_mm"] for a, b in zip(kept, kept[1:]))
    if name == "C":
        assert last["own"]["rms_mm"] <= 0.15            # gradient boosting's 0.153 mm on the same split
    else:
        refused = {c["label"]: c["reason"] for c in rounds[0]["refused"]}
        assert "joint_map joint 2" in [c["label"] for c in rounds[0]["recommended"]]
        assert refused["chebyshev joint 2"].startswith("overlaps joint_map joint 2"), refused.get("chebyshev joint 2")


def test_quoted_numbers_are_what_make_all_wrote(two_runs):
    """Issue 26: every number the README and docs/ quote from the pipeline's results (registered in
    docs/quoted-numbers.toml) equals the file this suite's own `make all` wrote."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("quotes", ROOT / "mk" / "quotes.py")
    quotes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(quotes)
    assert quotes.check(ROOT, two_runs[0]) == []


def test_real_wild_points_named_and_left_out(two_runs):
    """Issue 23 on the real UR10, as `make all` wrote it: Series B's target 0855 (1.8 mm off under every
    model) is named with its line and size, and B's own errors are given without it (max well below
    it) and, beside them, with it; Series C names nothing. The loops end at or below what they reached
    before wild points were left out and the loop could swap (B 0.134 / C 0.098 mm own, 0.461 / 0.747 mm
    on the other series), and a swap the loop made verified better by pose and by region."""
    real = two_runs[0] / "results" / "real"
    fit_b = json.loads((real / "B_kinematic.json").read_text())
    fit_c = json.loads((real / "C_kinematic.json").read_text())
    assert fit_c["outliers"] == []
    named = {o["point_id"]: o for o in fit_b["outliers"]}
    assert "0855" in named and named["0855"]["set"] == "target" and named["0855"]["line"] > 1
    assert named["0855"]["error_mm"] > 12 * fit_b["outlier_rule"]["sigma_mm"]["target"]
    assert fit_b["heldout_with_outliers"]["after"]["max_mm"] > 1.5 > fit_b["heldout"]["after"]["max_mm"]
    loops = {s: json.loads((real / f"{s}_loop.json").read_text()) for s in "BC"}
    assert "0855" in {o["point_id"] for o in loops["B"]["outliers"]} and loops["C"]["outliers"] == []
    for s, (own, other) in {"B": (0.134, 0.461), "C": (0.098, 0.747)}.items():
        last = loops[s]["rounds"][loops[s]["final_round"] - 1]
        assert last["own"]["rms_mm"] <= own + 5e-4 and last["other"]["rms_mm"] <= other + 5e-4
        for r in loops[s]["rounds"]:
            sw = r.get("swap") or {}
            if sw.get("made"):
                v = sw["verified"]
                assert v["cv_rms_mm"] < v["baseline_cv_rms_mm"] and v["cv_rms_region_mm"] < v["baseline_cv_rms_region_mm"]
    b_last = loops["B"]["rounds"][loops["B"]["final_round"] - 1]
    assert b_last["own_with_outliers"]["max_mm"] > 1.5 > b_last["own"]["max_mm"]


def test_real_u95_intervals_hold_on_held_out_poses_or_say_they_do_not(two_runs):
    """Issue 33 on the real UR10, as `make all` wrote it: for the kinematic fit and the diagnosis loop's
    model of each series, the stated 95 % intervals cover between 90 % and 99 % of the series' own
    held-out targets, and their mean is within 1.5x the errors' 95th percentile (not simply wide). On
    the other series (tracker re-registered) they either still cover 90 % or predict says plainly
    that they do not (coverage_note, and the report's table has the coverage)."""
    real = two_runs[0] / "results" / "real"
    for s, o in (("B", "C"), ("C", "B")):
        for spec in ("kinematic", "diagnosed"):
            own = json.loads((real / f"{s}_{spec}_self.json").read_text())
            assert 0.90 <= own["coverage_95"] <= 0.99, (s, spec, own["coverage_95"])
            assert own["u95_mm"] <= 1.5 * own["error_p95_mm"], (s, spec, own["u95_mm"], own["error_p95_mm"])
            far = json.loads((real / f"{s}_{spec}_on_{o}.json").read_text())
            assert far["coverage_95"] >= 0.90 or "do not hold" in far.get("coverage_note", ""), (s, spec)
    table = json.loads((real / "transfer.json").read_text())
    assert table["B"]["kinematic_coverage"]["own"]["coverage_95"] == pytest.approx(
        json.loads((real / "B_kinematic_self.json").read_text())["coverage_95"])
