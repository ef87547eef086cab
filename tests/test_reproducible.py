"""Same inputs, same bytes: the whole pipeline, run twice in two scratch copies, writes identical
Parquet, CSV, JSON and PDF files."""

import os
import shutil
import subprocess
from pathlib import Path

from conftest import ROOT


def scratch_copy(dst: Path) -> Path:
    shutil.copytree(ROOT, dst, symlinks=True,
                    ignore=shutil.ignore_patterns(".venv", ".git", "interim", "results", "reports", "__pycache__",
                                                  ".pytest_cache", ".hypothesis", "*.egg-info"))
    for d in ("interim", "results", "reports"):
        (dst / d).mkdir()
    os.symlink(ROOT / ".venv", dst / ".venv")
    # the shared venv's stamp must stay newer than the copy's install inputs: never reinstall from here
    for f in ("pyproject.toml", "constraints.txt"):
        os.utime(dst / f, (0, 0))
    return dst


def test_two_runs_give_the_same_bytes(tmp_path):
    copies = [scratch_copy(tmp_path / name) for name in ("one", "two")]
    procs = [subprocess.Popen(["make", "-s", "all"], cwd=c, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for c in copies]
    for p in procs:
        out, _ = p.communicate(timeout=1500)   # two whole pipelines on a shared 2-core machine
        assert p.returncode == 0, out[-3000:]
    files = sorted(str(f.relative_to(copies[0])) for d in ("interim", "results", "reports")
                   for f in (copies[0] / d).rglob("*") if f.is_file())
    assert any(f.endswith(".pdf") for f in files) and any(f.endswith(".parquet") for f in files)
    differ = [f for f in files if (copies[0] / f).read_bytes() != (copies[1] / f).read_bytes()]
    assert differ == []
    assert sorted(str(f.relative_to(copies[1])) for d in ("interim", "results", "reports")
                  for f in (copies[1] / d).rglob("*") if f.is_file()) == files
