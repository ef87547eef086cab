"""Issue 15: the same bytes on any machine. Numbers whose last bits are rounding noise (they differ
from one CPU or BLAS build to another) must not reach a file."""

import json

import numpy as np
import pandas as pd

from pipeline.core.files import write_json, write_parquet


def _ulps(x, k):
    return np.nextafter(x, np.inf) if k > 0 else np.nextafter(x, -np.inf)


def test_json_numbers_with_a_unit_do_not_carry_rounding_noise(tmp_path):
    base = {"rms_mm": 0.39486903084, "RP_mm": {"+x": 0.0536613493863}, "gain": 0.0846657549182,
            "error_arcsec": [12.345678901234, 1.3e-14], "ratio": 0.123456789012345}
    noisy = json.loads(json.dumps(base))
    noisy["rms_mm"] = 0.394869030843                        # the same number on another CPU (measured)
    noisy["RP_mm"]["+x"] = 0.0536613493865
    noisy["gain"] = 0.0846657549185
    noisy["error_arcsec"][1] = -2.9e-14
    write_json(tmp_path / "a.json", base)
    write_json(tmp_path / "b.json", noisy)
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    out = json.loads((tmp_path / "a.json").read_text())
    assert out["error_arcsec"] == [12.345679, 0.0] and out["rms_mm"] == 0.394869
    assert out["ratio"] == 0.123456789012                  # no unit: 12 significant digits, as before


def test_parquet_floats_and_attrs_do_not_carry_rounding_noise(tmp_path):
    v = np.array([18.490133490861275, 355.7714739940877, 1e-3, -0.0])
    frames = []
    for k in (+1, -1):
        f = pd.DataFrame({"A": [_ulps(x, k) for x in v], "n": [1, 2, 3, 4]})
        f.attrs = {"fit": {"rms_mm": 0.3438304299857143 + k * 2e-13}}
        frames.append(f)
    write_parquet(tmp_path / "a.parquet", frames[0])
    write_parquet(tmp_path / "b.parquet", frames[1])
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()
    back = pd.read_parquet(tmp_path / "a.parquet")
    assert np.allclose(back["A"], v, rtol=1e-9, atol=0)
