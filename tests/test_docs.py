"""The README a newcomer reads in five minutes, the manual in docs/, and quoted numbers that cannot go
stale (issue 26). The quotes themselves are checked against what `make all` wrote in
tests/test_reproducible.py; here: the checker fails on a number that differs, and the pages hold
together."""

import importlib.util
import json
import re
import subprocess
import sys

import pytest

from conftest import ROOT

spec = importlib.util.spec_from_file_location("quotes", ROOT / "mk" / "quotes.py")
quotes = importlib.util.module_from_spec(spec)
spec.loader.exec_module(quotes)

# the README's sections before issue 26 moved them into docs/: each must still be a heading somewhere
FORMER_SECTIONS = [
    "Layout", "The joint-module pipeline (paper 1)", "Reading `reports/encoder.pdf`", "The robot pipeline (paper 2)",
    "Beyond the paper: what the robot's model is missing", "Robot diagnosis, measured",
    "Real robots: your tracker files in, models that transfer", "Diagnosis on the real robot: the loop, measured",
    "The model on the robot: corrected programs and exports", "Planning the poses to measure",
    "Any serial arm: 4 to 7 joints", "Diagnosis: what is the model missing?",
    "Tutorial: find a hidden effect, add it, watch the error fall", "Tutorial on the robot",
    "Fleet: many units on Dask", "Bad input, numerical honesty, same bytes", "Speed and scale",
    "Side by side with FIGAROH 1.0.2", "Fleet at scale",
]


def test_readme_is_short_and_maps_every_docs_page():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.encode()) <= 12 * 1024
    linked = set(re.findall(r"\]\(docs/([\w-]+\.md)\)", readme))
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    assert pages - linked == set(), "docs pages missing from the README's map"
    assert linked - pages == set(), "the README links pages that do not exist"
    for cmd in ("make all", "make test", "jointcal import", "jointcal fit", "diagnose-loop", "jointcal correct",
                "jointcal export", "jointcal plan"):
        assert cmd in readme


def test_every_docs_page_says_what_it_is_for_and_every_former_section_is_found():
    headings = []
    for page in sorted((ROOT / "docs").glob("*.md")):
        lines = page.read_text().splitlines()
        assert lines[0].startswith("# ") and lines[1] == "" and lines[2].strip(), page.name
        headings += [re.sub(r"^#+\s*", "", l) for l in lines if l.startswith("#")]
    for section in FORMER_SECTIONS:
        assert any(h.startswith(section) or section in h for h in headings), section


def test_every_registered_quote_is_on_its_page_once():
    """A page edited so that a registered quote is gone (or doubled) fails without any results."""
    import tomllib
    reg = tomllib.loads((ROOT / "docs" / "quoted-numbers.toml").read_text())["quote"]
    assert len(reg) >= 30
    for q in reg:
        found = quotes.pattern(q["template"]).findall((ROOT / q["page"]).read_text())
        assert len(found) == 1, (q["page"], q["template"])


@pytest.fixture
def tiny(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "r.json").write_text(json.dumps({"a": {"rms_mm": 0.49260}, "loop": [{"x": 1.5}]}))
    (tmp_path / "results" / "c.csv").write_text("point_id,status\n1,ok\n2,ok\n3,no_solution\n")
    (tmp_path / "docs").mkdir()
    (tmp_path / "PAGE.md").write_text("held-out 0.493 mm; loop 1.50; 3 rows, 2 ok\n")
    (tmp_path / "docs" / "quoted-numbers.toml").write_text(
        '[[quote]]\npage = "PAGE.md"\ntemplate = "held-out {} mm; loop {};"\n'
        'values = ["results/r.json:a.rms_mm:.3f", "results/r.json:loop.0.x:.2f"]\n\n'
        '[[quote]]\npage = "PAGE.md"\ntemplate = "{} rows, {} ok"\n'
        'values = ["results/c.csv:rows:d", "results/c.csv:count(status=ok):d"]\n')
    return tmp_path


def test_the_check_passes_when_the_numbers_agree(tiny):
    assert quotes.check(tiny, tiny) == []


def test_the_check_fails_on_a_number_that_differs_and_fix_rewrites_it(tiny):
    d = json.loads((tiny / "results" / "r.json").read_text())
    d["a"]["rms_mm"] = 0.4874
    (tiny / "results" / "r.json").write_text(json.dumps(d))
    (tiny / "results" / "c.csv").write_text("point_id,status\n1,ok\n2,ok\n3,ok\n4,x\n")
    problems = quotes.check(tiny, tiny)
    assert len(problems) == 2
    assert "'held-out 0.487 mm; loop 1.50;'" in problems[0] and "'4 rows, 3 ok'" in problems[1]
    assert quotes.check(tiny, tiny, fix=True)
    assert (tiny / "PAGE.md").read_text() == "held-out 0.487 mm; loop 1.50; 4 rows, 3 ok\n"
    assert quotes.check(tiny, tiny) == []


def test_the_check_names_a_missing_result(tiny):
    (tiny / "results" / "r.json").unlink()
    problems = quotes.check(tiny, tiny)
    assert len(problems) == 1 and "cannot read its number" in problems[0]


def test_jointcal_help_lists_the_job_in_order():
    out = subprocess.run([sys.executable, "-m", "pipeline.cli", "--help"], capture_output=True, text=True,
                         cwd=ROOT).stdout
    if not out:   # no __main__: the installed entry point
        out = subprocess.run([str(ROOT / ".venv" / "bin" / "jointcal"), "--help"], capture_output=True,
                             text=True).stdout
    order = [out.index(f"\n  {c} ") for c in ("plan", "import", "fit", "diagnose", "correct", "export")]
    assert order == sorted(order)


def test_every_module_path_the_pages_name_exists():
    """A page that names `pipeline/....py` names a file that is there (raw/README.md named two modules
    that had moved)."""
    pages = [ROOT / "README.md", ROOT / "raw" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    missing = [(p.name, m) for p in pages for m in re.findall(r"pipeline/[\w/]+\.py", p.read_text())
               if not (ROOT / m).is_file()]
    assert missing == []
