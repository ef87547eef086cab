"""Encoder report: builds from the chain's outputs, has every page, same bytes twice."""

import json
import re

import pytest

from conftest import ROOT, cli_invoker
from test_encoder_cli import run_chain


@pytest.fixture(scope="module")
def report_inputs(tmp_path_factory):
    from pipeline.core.files import read_parquet

    invoke = cli_invoker()
    inputs = {}
    for m in "ab":
        work = run_chain(invoke, ROOT / "raw" / "encoder" / m, tmp_path_factory.mktemp(m))
        inputs[m] = {"readings": read_parquet(work / "m.parquet"), "harmonics": read_parquet(work / "h.parquet"),
                     "selection": json.loads((work / "orders.json").read_text()),
                     "model": json.loads((work / "model.json").read_text()), "aliasing": work / "alias.csv"}
    return inputs


def test_report_pages_and_same_bytes_twice(report_inputs, tmp_path):
    from pipeline.encoder.report import encoder_report

    first, second = tmp_path / "one" / "encoder.pdf", tmp_path / "two" / "encoder.pdf"
    encoder_report(report_inputs, first)
    encoder_report(report_inputs, second)
    data = first.read_bytes()
    assert data.startswith(b"%PDF") and data == second.read_bytes()
    # at a glance, Figures 4-9; appendix: numbers, terms beside the paper's, aliasing table
    assert len(re.findall(rb"/Type /Page\b", data)) == 10
    assert not list(first.parent.glob(".*.tmp"))  # written atomically, nothing left behind


def test_report_single_module_without_paper_numbers(report_inputs, tmp_path):
    """A module the paper does not have (any name) still gets a complete report."""
    from pipeline.encoder.report import encoder_report

    out = tmp_path / "c.pdf"
    encoder_report({"c": report_inputs["a"]}, out)
    assert len(re.findall(rb"/Type /Page\b", out.read_bytes())) == 10
