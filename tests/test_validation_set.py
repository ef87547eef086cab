"""A validation set (every pose `target`, no `sample`) imports as it is (contract section 6);
`predict` applies a model to it as measured, and `predict --register` on it is refused with one line
(issue 16)."""

from __future__ import annotations

import json
import re

from conftest import ROOT

REAL = ROOT / "raw" / "real" / "ur10-ipa"
SERIES_C = REAL / "Series_C" / "measurements_random_poses.csv"
ONE_LINE = re.compile(r"^jointcal: error: (?P<file>[^:]+):(?P<line>\d+|-):(?P<col>[^:]+): \S.*$")


def _rows(lines, first, last, set_value=None):
    """Rows first..last-1 of the source (header kept), with a `set` column when asked."""
    head, body = lines[0], lines[first:last]
    if set_value is None:
        return [head] + body
    return [head + ";set"] + [row + f";{set_value}" for row in body]


def test_validation_only_import_and_predict(invoke, tmp_path):
    lines = SERIES_C.read_bytes().decode().split("\r\n")
    fit_src, val_src = tmp_path / "fit.csv", tmp_path / "val.csv"
    fit_src.write_text("\r\n".join(_rows(lines, 1, 301)) + "\r\n", newline="")
    val_src.write_text("\r\n".join(_rows(lines, 301, 321, "target")) + "\r\n", newline="")
    text = (REAL / "map.toml").read_text()
    val_map = tmp_path / "val_map.toml"
    val_map.write_text(text.replace("sample_fraction = 0.6\nseed = 1", 'column = "set"'))
    args = ("--robot", REAL / "robot.toml")
    r = invoke("import", "--source", fit_src, "--map", REAL / "map.toml", *args, "--out", tmp_path / "fit")
    assert r.exit_code == 0, r.output
    r = invoke("import", "--source", val_src, "--map", val_map, *args, "--out", tmp_path / "val")
    assert r.exit_code == 0, r.output
    poses = (tmp_path / "val" / "poses.csv").read_text().splitlines()
    assert len(poses) == 21 and all(",target," in p for p in poses[1:])
    r = invoke("fit", "--campaign", tmp_path / "fit", "--spec", ROOT / "specs" / "robot_kinematic.toml",
               "--out", tmp_path / "fit.json")
    assert r.exit_code == 0, r.output
    held = json.loads((tmp_path / "fit.json").read_text())["heldout"]["rms_after_mm"]
    # the model as measured: the tracker stayed put, so its points go through the fit's transform
    r = invoke("predict", "--campaign", tmp_path / "val", "--model", tmp_path / "fit.json", "--json", tmp_path / "p.json")
    assert r.exit_code == 0, r.output
    p = json.loads((tmp_path / "p.json").read_text())
    assert p["n"] == 20 and p["evaluated_on"] == "target"
    # as good as on the fit's own held-out poses (nominal kinematics miss these poses by about 1 mm)
    assert p["rms_mm"] < 2.0 * held and p["rms_mm"] < 0.8
    # --register needs sample poses: one line, exit 2, nothing written
    out = tmp_path / "reg.json"
    r = invoke("predict", "--campaign", tmp_path / "val", "--model", tmp_path / "fit.json", "--json", out, "--register")
    assert r.exit_code == 2 and "Traceback" not in r.output
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and ONE_LINE.match(err[0]) and "sample poses to register on" in err[0], err
    assert not out.exists()
