"""A fit never does worse than a model nested in it (issue 16): geometry + base + tool + joint maps +
`chebyshev` joint 4 beside `joint_map` joint 4 fits the sample poses of a real UR10 worse than
geometry + base + tool alone; `jointcal fit` refuses it with one line naming the overlapping pair
(exit 1, nothing written). Without the overlapping effect the same model fits."""

from __future__ import annotations

import json

import numpy as np

from conftest import ROOT

REAL = ROOT / "raw" / "real" / "ur10-ipa"
SERIES_B = REAL / "Series_B" / "measurements_joint_configurations.csv"
HEAD = '[model]\nkind = "robot"\n' + "".join(f'\n[[effect]]\nname = "{n}"\n' for n in ("geometry", "base", "tool"))
MAPS = '\n[[effect]]\nname = "joint_map"\njoints = [1, 2, 3, 4, 5]\n'
CHEB4 = '\n[[effect]]\nname = "chebyshev"\norder = 3\njoints = [4]\n'


def _import_b(invoke, tmp_path, n: int) -> None:
    """The first ``n`` poses of real Series B, imported to ``tmp_path / "B"``."""
    lines = SERIES_B.read_bytes().decode().split("\r\n")[:n + 1]
    src = tmp_path / "src.csv"
    src.write_text("\r\n".join(lines) + "\r\n", newline="")
    r = invoke("import", "--source", src, "--map", REAL / "map.toml", "--robot", REAL / "robot.toml",
               "--out", tmp_path / "B")
    assert r.exit_code == 0, r.output


def test_fit_refuses_a_model_worse_than_the_one_nested_in_it(invoke, tmp_path):
    _import_b(invoke, tmp_path, 400)
    bad, good = tmp_path / "bad.toml", tmp_path / "good.toml"
    bad.write_text(HEAD + MAPS + CHEB4)
    good.write_text(HEAD + MAPS)
    out = tmp_path / "fit.json"
    r = invoke("fit", "--campaign", tmp_path / "B", "--spec", bad, "--out", out)
    assert r.exit_code == 1 and "Traceback" not in r.output
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("jointcal: error")]
    assert len(err) == 1 and "joint_map joint 4 and chebyshev joint 4" in err[0], err
    assert "nested" in err[0] and not out.exists()
    r = invoke("fit", "--campaign", tmp_path / "B", "--spec", good, "--out", out)
    assert r.exit_code == 0, r.output
    fit = json.loads(out.read_text())
    assert fit["plausible"] and "conflict" not in fit


def test_a_chebyshev_fit_too_big_for_dense_svds_fits_alike(invoke, tmp_path, monkeypatch):
    """A fit in the leading singular directions (a Chebyshev model's) beyond DENSE_SVD_MAX is iterated on
    its normal equations, its directions from the SVD of a QR's triangular factor (issue 32): on real
    poses it keeps the same directions and predicts what the dense SVDs' fit predicts."""
    from pipeline.core.spec import parse_spec
    from pipeline.robot.campaign.ingest import robot_data_sets
    from pipeline.robot.model import normal
    from pipeline.robot.model.estimate import fit_effects

    _import_b(invoke, tmp_path, 300)
    robot, (sample,) = robot_data_sets(tmp_path / "B", ("sample",))
    effects = list(parse_spec(HEAD + '\n[[effect]]\nname = "joint_map"\njoints = [1, 2]\n' + CHEB4, "t").effects)
    dense = fit_effects(robot, effects, sample, checks=False)
    monkeypatch.setattr(normal, "DENSE_SVD_MAX", 0)
    big = fit_effects(robot, list(parse_spec(HEAD + '\n[[effect]]\nname = "joint_map"\njoints = [1, 2]\n' + CHEB4,
                                             "t").effects), sample, checks=False)
    assert big.basis_.shape == dense.basis_.shape and big.converged_ == dense.converged_
    gap = np.abs(big.predict(sample) - dense.predict(sample)).max()
    moved = np.abs(dense.predict(sample) - sample.measured_mm).max()
    assert gap < 1e-6 * max(moved, 1.0), (gap, moved)
