"""Nothing half-written: an interrupted stage never leaves a file make would take for up to date."""

import signal
import subprocess
import sys

import pandas as pd
import pytest

from conftest import ROOT
from pipeline.core.files import atomic_path, write_parquet


def test_failed_write_leaves_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.parquet"
    target.write_bytes(b"previous")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.parquet"]


def test_written_file_is_complete_and_readable(tmp_path):
    frame = pd.DataFrame({"a": range(1000)})
    write_parquet(tmp_path / "x.parquet", frame)
    assert pd.read_parquet(tmp_path / "x.parquet").equals(frame)
    assert oct((tmp_path / "x.parquet").stat().st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode


def test_killed_stage_leaves_no_output(tmp_path, invoke):
    """Kill `jointcal report` (the slowest encoder stage) just before it publishes its file: none appears."""
    interim, results = tmp_path / "interim", tmp_path / "results"
    spec = ROOT / "specs" / "encoder_paper.toml"
    for m in "ab":
        steps = [("ingest", "--campaign", ROOT / "raw" / "encoder" / m, "--out", interim / f"{m}.parquet"),
                 ("harmonic", "--interim", interim / f"{m}.parquet", "--out", interim / f"{m}_harmonics.parquet"),
                 ("aliasing", "--interim", interim / f"{m}.parquet", "--out", results / f"{m}_aliasing.csv"),
                 ("select", "--interim", interim / f"{m}.parquet", "--harmonics", interim / f"{m}_harmonics.parquet",
                  "--spec", spec, "--out", results / f"{m}_orders.json"),
                 ("fit", "--interim", interim / f"{m}.parquet", "--spec", spec, "--orders", results / f"{m}_orders.json",
                  "--out", results / f"{m}_model.json")]
        for args in steps:
            assert invoke(*args).exit_code == 0, args[0]
    work = tmp_path / "reports"
    work.mkdir()
    out = work / "encoder.pdf"
    # killed at the worst moment, deterministically: the report is whole in its temporary and the
    # stage is about to publish it (os.replace); a timed kill could miss a fast machine and skip
    killer = ("import os, signal\n"
              "os.replace = lambda src, dst: os.kill(os.getpid(), signal.SIGKILL)\n"
              "from pipeline.cli import main\n"
              "main()")
    proc = subprocess.run([sys.executable, "-c", killer, "report", "--interim", str(interim), "--results", str(results),
                           "--out", str(out)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600)
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists()
    left = [p.name for p in work.iterdir()]
    # what is left has a name no make rule produces
    assert left and all(name.startswith(".encoder.pdf.") and name.endswith(".tmp") for name in left), left
