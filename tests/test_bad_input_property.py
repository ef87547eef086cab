"""Property: whatever is done to a valid campaign, ingest either succeeds or exits 2 with one
located line, never a traceback, and never leaves an output file behind when it fails."""

import shutil

import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import ROOT, ingest_fails_cleanly

SOURCE = ROOT / "raw" / "encoder" / "b"
COLUMNS = ["module", "run", "step", "nominal_deg", "encoder_deg", "autocollimator_arcsec", "direction",
           "timestamp", "temperature_c"]
GARBAGE = ["", "nan", "NaN", "inf", "-inf", "abc", "1e999", "0x10", "1,5", "  ", "None", "3.14.15", "-", "1e-400",
           "2", "-1", "0", "999999", "12:00", "2020-13-45T99:99:99Z"]

mutation = st.one_of(
    st.tuples(st.just("cell"), st.integers(0, 36), st.sampled_from(COLUMNS), st.sampled_from(GARBAGE)),
    st.tuples(st.just("drop_column"), st.sampled_from(COLUMNS)),
    st.tuples(st.just("rename_column"), st.sampled_from(COLUMNS), st.sampled_from(["Step", "encoder", "nominal_rad", "x"])),
    st.tuples(st.just("duplicate_row"), st.integers(0, 36)),
    st.tuples(st.just("drop_row"), st.integers(0, 36)),
    st.tuples(st.just("scale"), st.sampled_from(["nominal_deg", "encoder_deg"]), st.sampled_from([3.141592653589793 / 180, 1 / 1000, 60.0])),
    st.tuples(st.just("truncate"), st.integers(0, 3)),
    st.tuples(st.just("empty_file"),),
)


def apply(frame: pd.DataFrame, path, m):
    kind = m[0]
    if kind == "cell":
        if m[2] in frame and m[1] < len(frame):
            frame.loc[frame.index[m[1]], m[2]] = m[3]
    elif kind == "drop_column":
        frame = frame.drop(columns=[m[1]], errors="ignore")
    elif kind == "rename_column":
        frame = frame.rename(columns={m[1]: m[2]})
    elif kind == "duplicate_row":
        if len(frame):
            frame = pd.concat([frame, frame.iloc[[m[1] % len(frame)]]], ignore_index=True)
    elif kind == "drop_row":
        frame = frame.drop(index=m[1], errors="ignore")
    elif kind == "scale":
        if m[1] in frame:
            frame[m[1]] = (pd.to_numeric(frame[m[1]], errors="coerce") * m[2]).map(repr)
    elif kind == "truncate":
        frame = frame.iloc[: m[1]]
    elif kind == "empty_file":
        path.write_text("")
        return
    frame.to_csv(path, index=False)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutations=st.lists(mutation, min_size=1, max_size=3), target=st.integers(1, 6))
def test_mutated_campaigns_fail_cleanly(tmp_path_factory, mutations, target):
    folder = tmp_path_factory.mktemp("camp") / "b"
    shutil.copytree(SOURCE, folder)
    path = folder / f"b_run{target}.csv"
    for m in mutations:
        if path.stat().st_size == 0:
            break
        frame = pd.read_csv(path, dtype=str, keep_default_na=False)
        apply(frame, path, m)
    out = folder.parent / "out.parquet"
    if ingest_fails_cleanly(folder, out, mutations):
        derived = pd.read_parquet(out)
        assert derived["error_arcsec"].abs().max() < 3600  # a valid-looking result must be a sane one
