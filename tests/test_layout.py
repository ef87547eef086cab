"""Make knows the code it runs: a stage's prerequisites are its command's import closure
(mk/deps.py), which holds every module the command really loads."""

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

from conftest import ROOT

spec = importlib.util.spec_from_file_location("deps", ROOT / "mk" / "deps.py")
deps = importlib.util.module_from_spec(spec)
spec.loader.exec_module(deps)


@pytest.fixture(scope="module")
def modules():
    found = deps.discover(ROOT)
    deps.analyse(found)
    return found


def code_of(modules, module, function):
    """Files of CODE.<module>.<function> (what mk/deps.mk lists for a command)."""
    names = deps.entry_closure(modules) | deps.command_closure(modules, f"pipeline.cli.{module}", function)
    return {str(modules[n].path.relative_to(ROOT)) for n in names}


def test_closure_of_every_module_agrees_with_import_linters_graph(modules):
    """mk/deps.py reads the import statements itself; grimp (import-linter's graph) is an independent reader."""
    graph = grimp.build_graph("pipeline")
    for name in modules:
        if deps.is_cli(name):
            continue
        upstream = graph.find_upstream_modules(name)
        assert upstream <= deps.library_closure([name], modules), name


@pytest.mark.parametrize("campaign,kind", [("raw/encoder/a", "encoder"), ("raw/robot/kr210", "robot")])
def test_a_command_loads_only_modules_its_stage_depends_on(modules, campaign, kind):
    """Run `jointcal validate` and list the package modules the process loaded: all are in its CODE list."""
    probe = ("import atexit, json, sys\n"
             "atexit.register(lambda: print(json.dumps(sorted(m.__file__ for n, m in list(sys.modules.items())"
             " if (n == 'pipeline' or n.startswith('pipeline.')) and getattr(m, '__file__', None))), file=sys.stderr))\n"
             "from pipeline.cli import main\n"
             f"main(['validate', '--campaign', {campaign!r}])\n")
    run = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    loaded = {str(Path(f).resolve().relative_to(ROOT)) for f in json.loads(run.stderr.splitlines()[-1])}
    assert {"encoder": "pipeline/encoder/ingest.py", "robot": "pipeline/robot/campaign/ingest.py"}[kind] in loaded
    assert loaded <= code_of(modules, "campaign", "validate")


def prerequisites(target):
    db = subprocess.run(["make", "-pq", target], cwd=ROOT, capture_output=True, text=True).stdout
    lines = [ln for ln in db.splitlines() if ln.startswith(f"{target}:") and ln.strip() != f"{target}:"]
    assert lines, f"make knows no prerequisites of {target}"
    return set(re.findall(r"pipeline/\S+\.py", lines[-1]))


@pytest.mark.parametrize("target,deep", [
    # the examples: the fit rule named model.py and evaluate.py only; robot.mk omitted the kinematics
    ("results/encoder/a_model.json", ["pipeline/encoder/selection.py", "pipeline/encoder/harmonic.py",
                                      "pipeline/encoder/aliasing.py", "pipeline/encoder/effects.py",
                                      "pipeline/core/spec.py", "pipeline/core/crossval.py"]),
    ("results/robot/mdh.json", ["pipeline/robot/arm/kinematics.py", "pipeline/robot/model/lm.py", "pipeline/robot/arm/effects.py"]),
    ("reports/diagnosis.pdf", ["pipeline/diagnosis/report.py", "pipeline/robot/model/estimate.py", "pipeline/encoder/evaluate.py"]),
    ("results/fleet.parquet", ["pipeline/fleet/engine.py", "pipeline/fleet/report.py", "pipeline/robot/model/fit.py"]),
])
def test_stage_rules_depend_on_the_modules_deep_in_their_closure(target, deep):
    have = prerequisites(target)
    assert set(deep) <= have, sorted(set(deep) - have)
    assert "pipeline/cli/main.py" in have  # and on the command line that starts it
