"""Bad robot inputs end with exit status 2 and one line naming file, line and column."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

RAW = Path("raw/robot/kr210")
JC = str(Path(sys.executable).parent / "jointcal")


def _campaign(tmp_path):
    dst = tmp_path / "kr210"
    shutil.copytree(RAW, dst)
    return dst


def _edit(path, fn):
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(fn(lines)))


def _cell(line, col, value):
    parts = line.rstrip("\n").split(",")
    parts[col] = value
    return ",".join(parts) + "\n"


def rename_col(lines):
    lines[0] = lines[0].replace("q3,", "q_3,")
    return lines


def nan_q2(lines):
    lines[5] = _cell(lines[5], 3, "nan")
    return lines


def dup_id(lines):
    lines[7] = _cell(lines[7], 0, lines[6].split(",")[0])
    return lines


def radians(lines):
    lines[4] = _cell(lines[4], 3, "-1.6")
    return lines


def outside(lines):
    lines[9] = _cell(lines[9], 2, "40.0")
    return lines


def extra_tracker(lines):
    return lines + ["Z999,1.0,2.0,3.0,0.015\n"]


def drop_tracker(lines):
    return lines[:3] + lines[4:]


def metres(lines):
    out = [lines[0]]
    for line in lines[1:]:
        p = line.rstrip("\n").split(",")
        out.append(",".join([p[0]] + [f"{float(v) / 1000:.6f}" for v in p[1:4]] + p[4:]) + "\n")
    return out


def toml_missing_a(lines):
    # drop a_mm of the third [[joint]] table
    starts = [i for i, s in enumerate(lines) if s.startswith("[[joint]]")]
    k = next(i for i in range(starts[2], len(lines)) if lines[i].startswith("a_mm"))
    return lines[:k] + lines[k + 1:]


def coupling_unknown_joint(lines):
    return lines + ["\n[coupling]\n", "q9 = { q2 = 1.0, q3 = 1.0 }\n"]


def coupling_singular(lines):
    return lines + ["\n[coupling]\n", "q3 = { q2 = 1.0 }\n"]


def coupling_bad_factor(lines):
    return lines + ["\n[coupling]\n", "q3 = { q2 = \"one\", q3 = 1.0 }\n"]


CASES = [
    ("poses.csv", rename_col, "poses.csv:1:q3", "misspelled"),
    ("poses.csv", nan_q2, "poses.csv:6:q2", "NaN"),
    ("poses.csv", dup_id, "poses.csv:8:point_id", "duplicate"),
    ("poses.csv", radians, "poses.csv:5:q2", "radians"),
    ("poses.csv", outside, "poses.csv:10:q1", "outside"),
    ("tracker.csv", extra_tracker, "tracker.csv:", "no row in poses.csv"),
    ("tracker.csv", drop_tracker, "poses.csv:", "no tracker point"),
    ("tracker.csv", metres, "tracker.csv:2:x_mm", "metres"),
    ("robot.toml", toml_missing_a, "robot.toml:", "missing field 'a_mm'"),
    ("robot.toml", coupling_unknown_joint, "robot.toml:", "[coupling] 'q9' is not a joint q1..q6"),
    ("robot.toml", coupling_singular, "robot.toml:", "cannot be recovered"),
    ("robot.toml", coupling_bad_factor, "robot.toml:", "must be a recorded joint q1..q6 with a finite factor"),
]


@pytest.mark.parametrize("fname,edit,where,what", CASES, ids=[c[1].__name__ for c in CASES])
def test_bad_input_exit_2_one_line(tmp_path, fname, edit, where, what):
    camp = _campaign(tmp_path)
    _edit(camp / fname, edit)
    r = subprocess.run([JC, "ingest", "--campaign", str(camp), "--out", str(tmp_path / "p.parquet")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = [s for s in r.stderr.splitlines() if s.strip()]
    assert len(lines) == 1, r.stderr
    assert where in lines[0] and what in lines[0], lines[0]
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "p.parquet").exists()
    if fname == "robot.toml":
        # the line of the [[joint]] table that lacks the field, or of the [coupling] key / section at fault
        text = (camp / "robot.toml").read_text().splitlines()
        line = int(re.search(r"robot\.toml:(\d+):", lines[0]).group(1))
        assert text[line - 1].startswith("[coupling]" if edit is coupling_singular else
                                          "q" if "coupling" in edit.__name__ else "[[joint]]"), text[line - 1]


def test_targets_outside_the_sampled_range_warn_and_strict_refuses(tmp_path):
    """A compensation asked outside the joint range the model was identified on: warning, or exit 2 with --strict."""
    import subprocess
    import sys

    from conftest import ROOT

    jc = [sys.executable, "-c", "from pipeline.cli import main; main()"]
    interim = tmp_path / "poses.parquet"
    subprocess.run(jc + ["ingest", "--campaign", str(ROOT / "raw/robot/kr210"), "--out", str(interim)], check=True,
                   capture_output=True, cwd=ROOT)
    common = ["robot", "--help"]
    assert subprocess.run(jc + common, capture_output=True).returncode == 0
    base = ["robot", "chebyshev", "--interim", str(interim), "--robot", str(ROOT / "raw/robot/kr210/robot.toml"),
            "--out", str(tmp_path / "cheb.json")]
    subprocess.run(jc + base, check=True, capture_output=True, cwd=ROOT)
    mapping = ["robot", "map-joints", "--interim", str(interim), "--robot", str(ROOT / "raw/robot/kr210/robot.toml"),
               "--model", str(tmp_path / "cheb.json")]
    warn = subprocess.run(jc + mapping + ["--out", str(tmp_path / "a.csv")], capture_output=True, text=True, cwd=ROOT)
    assert warn.returncode == 0 and "warning: targets outside the joint range" in warn.stderr
    strict = subprocess.run(jc + mapping + ["--out", str(tmp_path / "b.csv"), "--strict"], capture_output=True, text=True,
                            cwd=ROOT)
    assert strict.returncode == 2 and not (tmp_path / "b.csv").exists()
    line = [ln for ln in strict.stderr.splitlines() if ln.strip()]
    assert len(line) == 1 and "poses.csv:" in line[0] and ":q" in line[0] and "Traceback" not in strict.stderr


def test_interim_tables_record_their_provenance(tmp_path):
    import hashlib
    import subprocess
    import sys

    from conftest import ROOT
    from pipeline.core.files import parquet_metadata

    jc = [sys.executable, "-c", "from pipeline.cli import main; main()"]
    out = tmp_path / "a.parquet"
    subprocess.run(jc + ["ingest", "--campaign", str(ROOT / "raw/encoder/a"), "--out", str(out)], check=True,
                   capture_output=True, cwd=ROOT)
    meta = parquet_metadata(out)
    assert meta["jointcal_version"]
    f = ROOT / "raw/encoder/a/a_run3.csv"
    assert meta["inputs"][str(f)] == hashlib.sha256(f.read_bytes()).hexdigest()


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_non_finite_integer_is_one_line_and_no_warning(tmp_path, value):
    """'inf' in a direction column: one located line, and no numpy warning beside it on stderr."""
    from conftest import ROOT, ingest_fails_cleanly

    camp = tmp_path / "cell"
    shutil.copytree(ROOT / "raw" / "robot" / "kr210", camp)
    lines = (camp / "poses.csv").read_text().splitlines()
    fields = lines[3].split(",")
    fields[lines[0].split(",").index("dir1")] = value
    lines[3] = ",".join(fields)
    (camp / "poses.csv").write_text("\n".join(lines) + "\n")
    assert not ingest_fails_cleanly(camp, tmp_path / "poses.parquet", value)
