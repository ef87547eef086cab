"""I/O at the edges: atomic, deterministic writers and hashing.

Every output is written to a temporary file in the same folder and renamed, so an
interrupted stage never leaves a half-written file that ``make`` takes for up to date.
The same data always give the same bytes.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from .. import __version__
from .errors import InputError

# pyarrow and pandas are imported inside the functions that use them: their import time
# (docs/speed.md) everything loading this module would pay (every command, the spec loader,
# `jointcal summary` that reads and writes only JSON)

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; results are ordinary files
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


# Decimals a written number keeps, by the unit its key ends in (issue 15, "same bytes on any machine"):
# a fit's or a statistic's last bits differ from one CPU or BLAS build to another (measured: 1e-12 to
# 1e-10 mm, 1e-8 in a diagnosis gain), so numbers with a unit are written at a fixed resolution far below
# any measurement (a nanometre, a micro-arcsecond) and far above that noise. Keys without a unit keep 12
# significant digits; a key without a unit inside one with a unit (``"RP_mm": {"+x": ...}``) takes its parent's.
RESOLUTION_DECIMALS = {"_mm": 6, "_um": 3, "_arcsec": 6, "_pct": 4, "gain": 6,
                       "cv_rms": 6, "cv_rms_with": 6, "cv_rms_region": 6}      # in the campaign's unit, mm or arcsec


def _decimals_for(key: str, inherited):
    for suffix, decimals in RESOLUTION_DECIMALS.items():
        if key.endswith(suffix):
            return decimals
    return inherited


def _jsonable(obj, decimals=None):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v, _decimals_for(str(k), decimals)) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, decimals) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_jsonable(v, decimals) for v in obj.tolist()]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        if not math.isfinite(value):
            return None
        if decimals is not None:
            value = round(value, decimals) + 0.0
        # 12 significant digits: stable across platforms, far below any measurement noise.
        return float(f"{value:.12g}")
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def to_resolution(obj, decimals: int):
    """``obj`` with every float rounded to ``decimals`` decimal places (absolute, in its own unit).

    For numbers a computation gives only up to rounding noise: a linear-algebra result (an SVD, a
    Newton solve) differs in its last bits from one CPU or BLAS build to another, and a quantity
    that is zero comes out as +-1e-14. Written with 12 *significant* digits such noise is written
    too; rounded to a fixed absolute resolution far above the noise (and far below anything that
    matters: 1e-9 deg is 4 micro-arcseconds, 1e-6 mm a nanometre) it is the same number everywhere.
    The JSON writer's own rounding (:func:`_jsonable`) with ``decimals`` for every number: a key whose
    unit has a resolution of its own (:data:`RESOLUTION_DECIMALS`) keeps that one, as it will in the file.
    """
    return _jsonable(obj, decimals)


def write_json(path, obj) -> None:
    write_text(path, json.dumps(_jsonable(obj), indent=2) + "\n")


def _significant(frame, digits: int = 11):
    """A copy of ``frame`` with every float column rounded to ``digits`` significant digits of the
    column's largest magnitude (one absolute resolution per column), and its ``attrs`` written by
    the JSON rules.

    A least-squares fit's amplitudes differ by 1e-15 between CPUs and BLAS builds, and a value that
    is zero comes out as +-1e-16; Parquet stores all 53 bits, so the file (and every hash of it
    downstream) would differ. Rounded to the column's resolution by Python's correctly rounded
    decimal arithmetic, the result is the same on every machine.
    """
    floats = [c for c in frame.columns if frame[c].dtype.kind == "f"]
    if not floats and not frame.attrs:
        return frame
    out = frame.copy()
    out.attrs = _jsonable(frame.attrs)       # stored in the file too (pandas metadata): same rules as JSON
    for c in floats:
        values = out[c].to_numpy(dtype=float).tolist()
        finite = [abs(v) for v in values if math.isfinite(v)]
        top = max(finite, default=0.0)
        if top == 0.0:
            continue
        exponent = int(f"{top:.{digits - 1}e}".split("e")[1])          # decimal exponent of the largest value
        decimals = digits - 1 - exponent
        out[c] = np.array([round(v, decimals) + 0.0 if math.isfinite(v) else v for v in values], dtype=float)
    return out


def write_parquet(path, frame, metadata: dict | None = None) -> None:
    """Write a DataFrame to Parquet deterministically (no index, fixed compression).

    ``metadata`` (e.g. :func:`provenance`) is stored as JSON under the schema key ``jointcal``.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(_significant(frame), preserve_index=False)
    if metadata is not None:
        meta = dict(table.schema.metadata or {})
        meta[b"jointcal"] = json.dumps(_jsonable(metadata), sort_keys=True).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd", write_statistics=False)


def read_parquet(path):
    import pandas as pd

    return pd.read_parquet(path)


def parquet_metadata(path) -> dict:
    """The ``jointcal`` metadata of a Parquet file written by :func:`write_parquet` ({} if none)."""
    import pyarrow.parquet as pq

    meta = pq.read_schema(path).metadata or {}
    return json.loads(meta[b"jointcal"]) if b"jointcal" in meta else {}


def write_csv(path, frame, float_format="%.6f") -> None:
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=float_format, lineterminator="\n")


def sha256_file(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(inputs, spec=None) -> dict:
    """SHA-256 of every input file, the spec and the jointcal version."""
    files = sorted({str(p) for p in inputs})
    out = {"jointcal_version": __version__, "inputs": {f: sha256_file(f) for f in files}}
    if spec is not None:
        out["spec"] = {str(spec): sha256_file(spec)}
    return out


# ------------------------------------------------------------------ located input readers
def read_text_input(path, what: str = "file") -> str:
    """UTF-8 text of an input file; missing or undecodable -> InputError."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"{what} is not UTF-8 text ({exc.reason})", 1, 1) from None


def read_bytes_input(path, what: str = "file", folder: str | None = None) -> bytes:
    """The bytes of an input file, as they are; missing (or a folder) -> InputError."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except IsADirectoryError:
        raise InputError(path, folder or f"{what}: a folder, not a file") from None


def read_json_input(path, hint: str = "run the stage that makes it first, or `make all`"):
    """A stage's JSON result; missing or invalid -> InputError naming the line and column."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, f"file not found ({hint})") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON: {exc.msg}", exc.lineno, exc.colno) from None


def read_parquet_input(path, hint: str = "run `jointcal ingest` first, or `make all`"):
    """An interim Parquet table; missing -> InputError."""
    if not Path(path).exists():
        raise InputError(path, f"file not found ({hint})")
    return read_parquet(path)
