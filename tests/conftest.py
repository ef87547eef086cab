"""Shared test helpers."""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as the jointcal command does (pipeline/cli/__init__.py)

import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def runner():
    return CliRunner()


def cli_invoker():
    """A function that runs ``jointcal`` in-process; it returns click's Result (exit_code, output, stderr)."""
    from pipeline.cli import cli

    runner = CliRunner()

    def run(*args):
        return runner.invoke(cli, [str(a) for a in args], catch_exceptions=False)

    return run


@pytest.fixture
def invoke():
    return cli_invoker()


def six_dof_cell(folder, truth, seed, *extra):
    """``folder`` made a simulated 6-DoF KR210 cell (``jointcal simulate robot --probe 6dof``, the generator's
    truth written to ``truth``; ``extra``: more options, e.g. ``--hidden``); returns ``folder``."""
    folder = Path(folder)
    folder.mkdir()
    shutil.copy(ROOT / "raw" / "robot" / "kr210" / "robot.toml", folder / "robot.toml")
    r = cli_invoker()("simulate", "robot", "--campaign", folder, "--truth", truth, "--seed", str(seed), *extra,
                      "--probe", "6dof")
    assert r.exit_code == 0, r.output
    return folder


@pytest.fixture
def campaign_copy(tmp_path):
    """A writable copy of a shipped encoder campaign (module a)."""
    dst = tmp_path / "a"
    shutil.copytree(ROOT / "raw" / "encoder" / "a", dst)
    return dst


def ingest_fails_cleanly(folder, out, context=None) -> bool:
    """Run ``jointcal ingest`` on ``folder``; assert it succeeds or fails as the contract says.

    Exit 0 with ``out`` written, or exit 2 with one line ``jointcal: error: <folder>/...``, no
    traceback and no ``out``. Returns whether it succeeded.
    """
    import warnings

    from pipeline.cli import cli

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = CliRunner().invoke(cli, ["ingest", "--campaign", str(folder), "--out", str(out)])
    # a warning would reach the user's stderr beside the one error line (deprecations are not shown)
    shown = [f"{w.category.__name__}: {w.message}" for w in caught
             if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))]
    assert not shown, (context, shown)
    assert result.exit_code in (0, 2), (context, result.output, result.exception)
    assert "Traceback" not in result.output
    if result.exit_code == 2:
        lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("jointcal: error: ") and str(folder) in lines[0], lines
        assert not out.exists()
        return False
    assert out.exists()
    return True
