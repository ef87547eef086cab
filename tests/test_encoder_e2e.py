"""End to end on the shipped fixture: the paper's numbers, the truth never read, same bytes twice."""

import filecmp
import json
import sys

import pytest

from conftest import ROOT, cli_invoker
from test_encoder_cli import run_chain

PAPER = {"a": {"orders": [1, 4, 8, 12, 14, 15, 16], "reduction": 82.20, "before": 149.53, "after": 26.62},
         "b": {"orders": [0, 1, 4, 7, 8, 12, 14, 16], "reduction": 81.85, "before": 101.35, "after": 18.40}}


class _TruthGuard:
    """An audit hook that fails any attempt to open the generator's truth while armed."""

    armed = False
    opened: list = []

    @classmethod
    def hook(cls, event, args):
        if cls.armed and event == "open" and args and "truth" in str(args[0]):
            cls.opened.append(str(args[0]))
            raise PermissionError(f"the pipeline opened the generator's truth: {args[0]}")


sys.addaudithook(_TruthGuard.hook)


@pytest.fixture(scope="module")
def fixture_results(tmp_path_factory):
    invoke = cli_invoker()
    out = {}
    _TruthGuard.armed = True
    try:
        for m in "ab":
            work = run_chain(invoke, ROOT / "raw" / "encoder" / m, tmp_path_factory.mktemp(m))
            out[m] = {"work": work, "model": json.loads((work / "model.json").read_text()),
                      "orders": json.loads((work / "orders.json").read_text())}
    finally:
        _TruthGuard.armed = False
    return out


@pytest.mark.parametrize("module", ["a", "b"])
def test_paper_rule_returns_the_papers_orders(fixture_results, module):
    assert fixture_results[module]["orders"]["paper_rule_orders"] == PAPER[module]["orders"]
    assert fixture_results[module]["model"]["orders"] == PAPER[module]["orders"]


@pytest.mark.parametrize("module", ["a", "b"])
def test_reduction_matches_the_paper(fixture_results, module):
    model = fixture_results[module]["model"]
    assert model["validation_runs"] == [6] and model["modelling_runs"] == [1, 2, 3, 4, 5]
    assert abs(model["reduction_pct"] - PAPER[module]["reduction"]) <= 3.0
    assert abs(model["p2p_before_arcsec"] / PAPER[module]["before"] - 1) <= 0.10
    assert abs(model["p2p_after_arcsec"] / PAPER[module]["after"] - 1) <= 0.10


def test_truth_was_never_opened(fixture_results):
    assert _TruthGuard.opened == []
    assert (ROOT / "raw" / "truth" / "encoder" / "a.json").exists()  # it exists; the pipeline just never looks


def test_the_guard_can_fail():
    _TruthGuard.armed = True
    try:
        with pytest.raises(PermissionError):
            open(ROOT / "raw" / "truth" / "encoder" / "a.json")
    finally:
        _TruthGuard.armed = False
        _TruthGuard.opened.clear()


def test_same_inputs_same_bytes(invoke, tmp_path, monkeypatch):
    """Two runs of the chain in two folders, with the same relative paths: every byte equal."""
    from pathlib import Path

    outs = []
    for name in ("one", "two"):
        (tmp_path / name).mkdir()
        monkeypatch.chdir(tmp_path / name)
        outs.append(tmp_path / name / run_chain(invoke, ROOT / "raw" / "encoder" / "a", Path("work")))
    for name in ("m.parquet", "h.parquet", "alias.csv", "orders.json", "model.json", "table.csv"):
        assert filecmp.cmp(outs[0] / name, outs[1] / name, shallow=False), name


def test_fixture_regenerates_byte_for_byte(invoke, tmp_path):
    result = invoke("simulate", "encoder", "--out", tmp_path / "enc", "--truth", tmp_path / "truth")
    assert result.exit_code == 0, result.output
    for m in "ab":
        shipped = sorted((ROOT / "raw" / "encoder" / m).glob("*.csv"))
        assert shipped, "fixture missing"
        for f in shipped:
            assert filecmp.cmp(f, tmp_path / "enc" / m / f.name, shallow=False), f.name
