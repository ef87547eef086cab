"""Stage ``ingest``: validate a raw campaign (contract sections 1 and 2) and derive the model's target.

Encoder: every ``*.csv`` of ``raw/encoder/<module>/`` forms one campaign. The derived
measurement of reading k of a run is

    error_arcsec = (encoder_deg[k] - encoder_deg[0]) * 3600
                   - (nominal_deg[k] * 3600 + autocollimator_arcsec[k] + face_error_arcsec[face k])

(encoder unwrapped across 360), at joint angle ``theta_deg = encoder_deg[k] mod 360``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputError, parse_toml
from ..core.files import read_text_input
from ..core.tables import FLOAT, INT, SIGN, STR, TIME, Problems, read_table
from .effects import ARCSEC_PER_DEG

ENCODER_REQUIRED = {"module": STR, "run": INT, "step": INT, "nominal_deg": FLOAT,
                    "encoder_deg": FLOAT, "autocollimator_arcsec": FLOAT}
ENCODER_OPTIONAL = {"direction": SIGN, "timestamp": TIME, "temperature_c": FLOAT, "faces": INT, "setting": INT}

#: the joint error is arcseconds to arcminutes; a reading that disagrees with the
#: polygon's nominal angle by more than this is not the polygon step it claims to be.
MAX_STEP_DISAGREEMENT_DEG = 1.0


def read_campaign_toml(folder: Path, problems: Problems) -> dict:
    path = folder / "campaign.toml"
    if not path.exists():
        return {}
    try:
        return parse_toml(read_text_input(path, "campaign.toml"), path)
    except InputError as exc:
        problems.append(exc)
        return {}


def load_encoder_campaign(folder, problems: Problems | None = None) -> tuple[pd.DataFrame | None, dict]:
    """Read and type-check every CSV of an encoder campaign folder.

    Returns
    -------
    frame : DataFrame or None
        All rows, typed, with ``_file`` and ``_line`` of each row.
    campaign : dict
        ``faces`` and ``face_error_arcsec`` (from ``campaign.toml`` or defaults).
    """
    own = problems is None
    problems = Problems() if own else problems
    folder = Path(folder)
    if not folder.is_dir():
        problems.add(folder, "campaign folder not found")
        problems.raise_first()
    files = sorted(folder.glob("*.csv"))
    if not files:
        problems.add(folder, "no *.csv files in the encoder campaign folder")
    doc = read_campaign_toml(folder, problems)
    faces = int(doc.get("faces", 36))
    face_err = doc.get("polygon", {}).get("face_error_arcsec", [0.0] * faces)
    if len(face_err) != faces:
        problems.add(folder / "campaign.toml", f"[polygon] face_error_arcsec has {len(face_err)} values; expected one per face ({faces})")
    frames = []
    for f in files:
        t = read_table(f, ENCODER_REQUIRED, ENCODER_OPTIONAL, problems)
        if t is not None:
            t.insert(0, "_file", str(f))
            frames.append(t)
    frame = pd.concat(frames, ignore_index=True) if frames and len(frames) == len(files) else None
    if frame is not None:
        check_encoder_rows(frame, faces, problems)
    if own:
        problems.raise_first()
    return frame, {"faces": faces, "face_error_arcsec": [float(x) for x in face_err]}


def _first(frame, mask):
    i = int(np.argmax(np.asarray(mask)))
    return frame["_file"].iloc[i], int(frame["_line"].iloc[i])


def check_encoder_rows(frame: pd.DataFrame, faces: int, problems: Problems) -> None:
    """Cross-row checks: module, run/step keys, step sequence, units of angles."""
    n0 = len(problems)
    modules = frame["module"].unique()
    if len(modules) > 1:
        f, line = _first(frame, frame["module"] != modules[0])
        problems.add(f, f"module '{frame['module'].iloc[frame['module'].ne(modules[0]).argmax()]}' differs from "
                        f"'{modules[0]}'; one campaign folder holds one module", line, "module")
    if (frame["run"] < 1).any():
        f, line = _first(frame, frame["run"] < 1)
        problems.add(f, "run numbers are 1-based; found a run < 1", line, "run")
    if (frame["step"] < 0).any():
        f, line = _first(frame, frame["step"] < 0)
        problems.add(f, "step must be 0 or more", line, "step")
    dup = frame.duplicated(["run", "step"], keep="first")
    if dup.any():
        f, line = _first(frame, dup)
        r, s = frame.loc[dup.idxmax(), ["run", "step"]]
        problems.add(f, f"duplicate (run, step) = ({int(r)}, {int(s)}); each reading must appear once", line, "step")
    if "faces" in frame and (frame["faces"].fillna(faces) < 3).any():
        f, line = _first(frame, frame["faces"].fillna(faces) < 3)
        problems.add(f, "a polygon has at least 3 faces", line, "faces")
    if len(problems) > n0:
        return
    for run, g in frame.groupby("run", sort=True):
        g = g.sort_values("step")
        steps = g["step"].to_numpy()
        expected = np.arange(steps.size)
        if not np.array_equal(steps, expected):
            missing = sorted(set(range(int(steps.max()) + 1)) - set(steps.tolist()))
            i = g.index[0]
            problems.add(g["_file"].loc[i], f"run {run} is missing step(s) {missing[:5]}; steps must run 0..N without gaps",
                         int(g["_line"].loc[i]), "step")
            continue
        if steps.size < 3:
            problems.add(g["_file"].iloc[0], f"run {run} has {steps.size} readings; at least 3 are needed",
                         int(g["_line"].iloc[0]), "step")
            continue
        nominal = g["nominal_deg"].to_numpy()
        f_run = int(g["faces"].iloc[0]) if "faces" in g and np.isfinite(g["faces"].iloc[0]) else faces
        pitch = 360.0 / f_run
        # nominal must be a multiple of the face pitch; a column in radians is caught here
        k = np.round(nominal / pitch)
        off = np.abs(nominal - k * pitch) > 1e-6
        span = np.ptp(nominal)
        if span > 0 and span <= 2 * np.pi + 1e-9 and np.ptp(k) < 2 and steps.size > 4:
            problems.add(g["_file"].iloc[0], f"nominal_deg of run {run} spans only {span:.4f}: the column looks like "
                         "radians; the contract says degrees", int(g["_line"].iloc[0]), "nominal_deg")
            continue
        if off.any():
            j = int(np.argmax(off))
            problems.add(g["_file"].iloc[j], f"nominal_deg {nominal[j]:g} is not a multiple of the face pitch "
                         f"{pitch:g} deg ({f_run} faces)", int(g["_line"].iloc[j]), "nominal_deg")
            continue
        enc = np.unwrap(g["encoder_deg"].to_numpy(), period=360.0)
        moved = enc - enc[0]
        disagree = np.abs(moved - nominal) > MAX_STEP_DISAGREEMENT_DEG
        if disagree.any():
            j = int(np.argmax(disagree))
            if np.ptp(moved) < 2 * np.pi + 1e-6 and np.ptp(nominal) > 10:
                msg = (f"encoder_deg of run {run} moves only {np.ptp(moved):.4f} while the polygon turns "
                       f"{np.ptp(nominal):g} deg: the column looks like radians; the contract says degrees")
                j = 0
            else:
                msg = (f"encoder moved {moved[j]:.4f} deg from the run's start but the polygon step is "
                       f"{nominal[j]:g} deg (more than {MAX_STEP_DISAGREEMENT_DEG} deg apart)")
            problems.add(g["_file"].iloc[j], msg, int(g["_line"].iloc[j]), "encoder_deg")
            continue
        ac = g["autocollimator_arcsec"].to_numpy()
        if np.abs(ac).max() > 3600:
            j = int(np.argmax(np.abs(ac) > 3600))
            problems.add(g["_file"].iloc[j], f"autocollimator reading {ac[j]:g} arcsec is more than one degree; "
                         "an autocollimator reads arcseconds after nulling", int(g["_line"].iloc[j]), "autocollimator_arcsec")


def derive_encoder(frame: pd.DataFrame, campaign: dict) -> pd.DataFrame:
    """Derive ``error_arcsec``, ``theta_deg``, ``face`` and ``time_s`` (pure).

    Parameters
    ----------
    frame : DataFrame
        Checked rows of one campaign (see :func:`load_encoder_campaign`).
    campaign : dict
        ``faces`` (int) and ``face_error_arcsec`` (list, arcsec, one per face).

    Returns
    -------
    DataFrame sorted by (run, step) with the contract columns plus derived ones.
    """
    frame = frame.sort_values(["run", "step"], kind="stable").reset_index(drop=True)
    faces_default = int(campaign.get("faces", 36))
    face_err = np.asarray(campaign.get("face_error_arcsec", [0.0] * faces_default), float)
    n = len(frame)
    out = pd.DataFrame({
        "module": frame["module"].astype(str),
        "run": frame["run"].astype(np.int64),
        "step": frame["step"].astype(np.int64),
        "nominal_deg": frame["nominal_deg"].astype(float),
        "encoder_deg": frame["encoder_deg"].astype(float),
        "autocollimator_arcsec": frame["autocollimator_arcsec"].astype(float),
    })
    out["direction"] = (frame["direction"].fillna(1.0) if "direction" in frame else pd.Series(np.ones(n))).astype(np.int64)
    out["faces"] = (frame["faces"].fillna(faces_default) if "faces" in frame else pd.Series(np.full(n, faces_default))).astype(np.int64)
    out["setting"] = (frame["setting"].fillna(0) if "setting" in frame else pd.Series(np.zeros(n))).astype(np.int64)
    error = np.empty(n)
    time_s = np.full(n, np.nan)
    face = np.empty(n, dtype=np.int64)
    has_time = "timestamp" in frame and frame["timestamp"].notna().any()
    for _, idx in out.groupby("run", sort=True).indices.items():
        enc = np.unwrap(out["encoder_deg"].to_numpy()[idx], period=360.0)
        nom = out["nominal_deg"].to_numpy()[idx]
        nfaces = out["faces"].to_numpy()[idx]
        k = np.mod(np.round(nom * nfaces / 360.0).astype(np.int64) + out["setting"].to_numpy()[idx], nfaces)
        fe = face_err[k] if face_err.size == nfaces[0] else np.zeros(idx.size)
        face[idx] = k
        error[idx] = (enc - enc[0]) * ARCSEC_PER_DEG - (nom * ARCSEC_PER_DEG + out["autocollimator_arcsec"].to_numpy()[idx] + fe)
        if has_time:
            t = frame["timestamp"].iloc[idx]
            time_s[idx] = (t - t.iloc[0]).dt.total_seconds().to_numpy()
    out["face"] = face
    out["theta_deg"] = np.mod(out["encoder_deg"].to_numpy(), 360.0)
    out["error_arcsec"] = error
    out["time_s"] = time_s
    out["temperature_c"] = frame["temperature_c"].astype(float) if "temperature_c" in frame else np.nan
    out["source_file"] = frame["_file"].map(lambda p: Path(p).name).astype(str)
    out["source_line"] = frame["_line"].astype(np.int64)
    return out


def ingest_encoder(folder) -> pd.DataFrame:
    """Validate an encoder campaign folder and return the derived table (raises InputError)."""
    frame, campaign = load_encoder_campaign(folder)
    return derive_encoder(frame, campaign)
