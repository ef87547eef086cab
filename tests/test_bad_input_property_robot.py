"""Property: a mutated robot campaign is ingested cleanly or refused with exit 2 and one located
line; never a traceback, never an output file when it fails."""

import shutil

import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import ROOT, ingest_fails_cleanly

SOURCE = ROOT / "raw" / "robot" / "kr210"
GARBAGE = ["", "nan", "inf", "abc", "1e999", "-", "1,5", "12:00", "999", "-999", "0.5", "3.14159", "1e-400", "T001", "sample"]
POSE_COLS = ["point_id", "set", "q1", "q2", "q3", "q4", "q5", "q6", "dir1", "dir4", "payload_kg", "temperature_c"]
TRACK_COLS = ["point_id", "x_mm", "y_mm", "z_mm"]

mutation = st.one_of(
    st.tuples(st.just("cell"), st.sampled_from(["poses.csv", "tracker.csv"]), st.integers(0, 400),
              st.sampled_from(POSE_COLS + TRACK_COLS), st.sampled_from(GARBAGE)),
    st.tuples(st.just("drop_column"), st.sampled_from(["poses.csv", "tracker.csv"]), st.sampled_from(POSE_COLS + TRACK_COLS)),
    st.tuples(st.just("drop_row"), st.sampled_from(["poses.csv", "tracker.csv"]), st.integers(0, 400)),
    st.tuples(st.just("duplicate_row"), st.sampled_from(["poses.csv", "tracker.csv"]), st.integers(0, 400)),
    st.tuples(st.just("scale"), st.sampled_from(["poses.csv", "tracker.csv"]),
              st.sampled_from(["q2", "q5", "x_mm", "z_mm"]), st.sampled_from([3.141592653589793 / 180, 1 / 1000])),
    st.tuples(st.just("toml_line"), st.sampled_from(["a_mm", "alpha_deg", "lower_deg", "mass_kg"])),
)


def apply(folder, m):
    kind = m[0]
    if kind == "toml_line":
        path = folder / "robot.toml"
        lines = path.read_text().splitlines()
        for k, line in enumerate(lines):
            if line.strip().startswith(m[1]):
                del lines[k]
                break
        path.write_text("\n".join(lines) + "\n")
        return
    path = folder / m[1]
    frame = pd.read_csv(path, dtype=str, keep_default_na=False)
    if kind == "cell" and m[3] in frame and len(frame):
        frame.loc[frame.index[m[2] % len(frame)], m[3]] = m[4]
    elif kind == "drop_column":
        frame = frame.drop(columns=[m[2]], errors="ignore")
    elif kind == "drop_row" and len(frame):
        frame = frame.drop(index=frame.index[m[2] % len(frame)])
    elif kind == "duplicate_row" and len(frame):
        frame = pd.concat([frame, frame.iloc[[m[2] % len(frame)]]], ignore_index=True)
    elif kind == "scale" and m[2] in frame:
        frame[m[2]] = (pd.to_numeric(frame[m[2]], errors="coerce") * m[3]).map(repr)
    frame.to_csv(path, index=False)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutations=st.lists(mutation, min_size=1, max_size=2))
def test_mutated_robot_campaigns_fail_cleanly(tmp_path_factory, mutations):
    folder = tmp_path_factory.mktemp("robot") / "kr210"
    shutil.copytree(SOURCE, folder)
    for m in mutations:
        apply(folder, m)
    ingest_fails_cleanly(folder, folder.parent / "poses.parquet", mutations)
