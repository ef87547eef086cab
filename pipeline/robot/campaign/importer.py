"""``jointcal import``: a measurement export (one row per pose) -> a robot campaign folder.

Contract section 6. The map (``map.toml``) says how to read the export::

    [source]    delimiter = ";"  decimal = ","            (defaults "," and ".")
                timestamp_format = "%Y%m%d%H%M%S"        (optional: how [columns] timestamp is written,
                                                          strptime's directives; default ISO-8601)
                delimiter = " "                          (runs of spaces and tabs)
                header = false                           (no header line: columns by number, 1 = the first)
    [joints]    columns = [N source columns, one per joint]  unit = "rad" | "deg"
                coupling = { q3 = { q2 = 1.0, q3 = 1.0 } }  (optional: coupled joints, as robot.toml's
                                                          [coupling]; written into the campaign's robot.toml)
    [position]  columns = [3 source columns]  unit = "mm" | "m"  frame = "tracker" | "base"
    [columns]   contract column = source column          (optional: point_id, temperature_c,
                payload_kg, timestamp, sigma_mm, dir1..dirN)
    [split]     sample_fraction = 0.6  seed = 1          (seeded random split; default seed 0)
                or column = "set"                        (values sample / target)
    [orientation]  columns = [3, 4 or 6 source columns]  kind = "euler" | "quaternion" | "rotvec" | "nest"
                (nest: SMRs 2 and 3 of a nest of three, [position] being SMR 1)
                sequence = "XYZ" (euler: upper case intrinsic, lower case extrinsic)  unit = "deg" | "rad"
                                                         (optional: a 6-DoF probe, contract section 13)
    [uncertainty]  position_columns = [3]  orientation_columns = [3]   (optional: per-pose 1-sigma,
                per axis, in the position's and the orientation's units)

Everything here is pure (text in, text out) except :func:`read_source_file` and
:func:`install_campaign`. The source's row order is kept (it is the visiting order);
unmapped columns are ignored. point_id defaults to the 1-based data row number, zero padded.
Every problem is an :class:`InputError` naming the map's line and column, or the source's
line and column name, or the robot file.
"""

from __future__ import annotations

import contextlib
import csv
import difflib
import hashlib
import io
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...core.errors import InputError, parse_toml
from ...core.files import _UMASK, read_bytes_input, read_text_input
from ...core.tables import SeenIds
from .frame import JOINT_UNITS, LENGTH_UNITS, MAX_RMS_MM, other_units, refit, unit_hypotheses
from .ingest import ingest_robot
from ..arm.kinematics import MAX_JOINTS, MIN_JOINTS, build_model, parse_robot
from .urdf import FK_TOLERANCE_MM, robot_from_urdf, tag_line

SECTIONS = ("source", "joints", "position", "orientation", "uncertainty", "columns", "split")
KEYS = {"source": ("delimiter", "decimal", "timestamp_format", "header"), "joints": ("columns", "unit", "coupling"), "position": ("columns", "unit", "frame"),
        "split": ("sample_fraction", "seed", "column"), "orientation": ("columns", "kind", "sequence", "unit"),
        "uncertainty": ("position_columns", "orientation_columns")}
EXTRA_COLUMNS = ("point_id", "temperature_c", "payload_kg", "timestamp", "sigma_mm") + tuple(
    f"dir{j}" for j in range(1, MAX_JOINTS + 1))
FRAMES = ("tracker", "base")
NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
# a rigid-fit residual beyond this is no robot's error: a unit mix-up is looked for (mm RMS)
IMPLAUSIBLE_RMS_MM = 20.0


# ------------------------------------------------------------------------------ the map
class _Locator:
    """Lines and columns of the keys and values of a small TOML file (for error messages)."""

    def __init__(self, text: str):
        self.lines = text.splitlines()
        self.sections: dict[str, tuple[int, int]] = {}
        self.keys: dict[tuple[str, str], tuple[int, int]] = {}
        section = ""
        for n, raw in enumerate(self.lines, 1):
            s = raw.strip()
            m = re.match(r"^\[\s*([^\[\]]+?)\s*\]", s)
            if m and not s.startswith("[["):
                section = m.group(1).strip().strip("\"'")
                self.sections.setdefault(section, (n, len(raw) - len(raw.lstrip()) + 1))
                continue
            m = re.match(r"^(\s*)[\"']?([A-Za-z0-9_-]+)[\"']?\s*=", raw)
            if m:
                self.keys.setdefault((section, m.group(2)), (n, len(m.group(1)) + 1))

    def section(self, name):
        return self.sections.get(name, (1, 1))

    def key(self, section, key):
        return self.keys.get((section, key), self.section(section))

    def value(self, section, key, item: str):
        """Line and column of the quoted string ``item`` in the value of ``key``."""
        line, col = self.key(section, key)
        if (section, key) not in self.keys:
            return line, col
        for k in range(line - 1, min(len(self.lines), line + 20)):
            text = self.lines[k]
            if k > line - 1 and re.match(r"^\s*(\[|[\"']?[A-Za-z0-9_-]+[\"']?\s*=)", text):
                break
            for q in ('"', "'"):
                at = text.find(q + item + q, col - 1 if k == line - 1 else 0)
                if at >= 0:
                    return k + 1, at + 1
            if item.isdigit():            # a column given by number: [1, 2, 3]
                m = re.search(r"(?<![\w.])" + item + r"(?![\w.])", text[(col - 1 if k == line - 1 else 0):])
                if m:
                    return k + 1, m.start() + (col if k == line - 1 else 1)
        return line, col


@dataclass
class ImportMap:
    """A checked ``map.toml``."""

    path: str
    delimiter: str
    decimal: str
    joint_columns: list
    joint_unit: str
    position_columns: list
    position_unit: str
    frame: str
    columns: dict                       # contract column -> source column
    sample_fraction: float | None
    seed: int
    split_column: str | None
    where: _Locator = field(repr=False)
    #: ``{"columns", "kind", "sequence", "unit"}`` of a 6-DoF probe's orientation, or None
    orientation: dict | None = None
    #: ``{"position_columns", "orientation_columns"}`` (each a list or None), or None
    uncertainty: dict | None = None
    #: strptime format of the source's timestamp column, or None (ISO-8601)
    timestamp_format: str | None = None
    #: False: the source has no header line; its columns are named by number ("1" = the first)
    header: bool = True
    #: ``[joints] coupling``: coupled joints as :attr:`pipeline.robot.arm.kinematics.Robot.coupling` (() none)
    coupling: tuple = ()

    def locate_column(self, name: str):
        """Line and column in the map where the source column ``name`` is named."""
        for sec, key, values in (("joints", "columns", self.joint_columns), ("position", "columns", self.position_columns)):
            if name in values:
                return self.where.value(sec, key, name)
        for key, src in self.columns.items():
            if src == name:
                return self.where.value("columns", key, name)
        if self.orientation and name in self.orientation["columns"]:
            return self.where.value("orientation", "columns", name)
        for key, values in (self.uncertainty or {}).items():
            if values and name in values:
                return self.where.value("uncertainty", key, name)
        if self.split_column == name:
            return self.where.value("split", "column", name)
        return 1, 1

    def describe_split(self) -> str:
        if self.split_column is not None:
            return f'column = "{self.split_column}"'
        return f"sample_fraction = {self.sample_fraction:g}, seed = {self.seed}"


def _fail(path, where: _Locator, section, key, message, item=None):
    line, col = where.value(section, key, item) if item is not None else where.key(section, key)
    raise InputError(path, message, line, col)


def _unknown(path, where, found, known, section=None):
    for k in found:
        if k not in known:
            close = difflib.get_close_matches(k, known, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else f" (known: {', '.join(known)})"
            if section is None:
                line, col = where.sections.get(k, where.keys.get(("", k), (1, 1)))
                raise InputError(path, f"unknown section [{k}] in the map{hint}", line, col)
            line, col = where.key(section, k)
            raise InputError(path, f"unknown key '{k}' in [{section}]{hint}", line, col)


def _numbered(doc, section: str, key: str) -> None:
    """A headerless source's column numbers (1-based integers) in ``doc[section][key]`` as the strings
    ``"1"``, ``"2"`` ... its columns are named by; anything else is left for the checks that follow."""
    v = doc.get(section, {}).get(key)
    ok = lambda x: isinstance(x, int) and not isinstance(x, bool) and x >= 1  # noqa: E731
    if isinstance(v, list):
        doc[section][key] = [str(x) if ok(x) else x for x in v]
    elif ok(v):
        doc[section][key] = str(v)


def _string_list(path, where, doc, section, key, n, what):
    count = f"{n.start} to {n.stop - 1}" if isinstance(n, range) else n
    if section not in doc:
        raise InputError(path, f"the map has no [{section}] section; it needs {key} = [{count} source columns] ({what})",
                         1, 1)
    if key not in doc[section]:
        line, col = where.section(section)
        raise InputError(path, f"[{section}] needs {key} = [{count} source column names] ({what})", line, col)
    v = doc[section][key]
    ok = (lambda m: m in n) if isinstance(n, range) else (lambda m: m == n)
    if not isinstance(v, list) or not ok(len(v)) or not all(isinstance(s, str) and s.strip() for s in v):
        got = f"{len(v)} entries" if isinstance(v, list) else repr(v)
        _fail(path, where, section, key, f"[{section}] {key} must list {count} source column names ({what}); got {got}")
    return [s.strip() for s in v]


def _choice(path, where, doc, section, key, choices, default=None):
    table = doc.get(section, {})
    if key not in table:
        if default is not None:
            return default
        line, col = where.section(section)
        raise InputError(path, f"[{section}] needs {key} = " + " or ".join(f'"{c}"' for c in choices), line, col)
    v = table[key]
    if not isinstance(v, str) or v.strip() not in choices:
        close = difflib.get_close_matches(str(v), list(choices), n=1) if isinstance(v, str) else []
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        _fail(path, where, section, key, f"[{section}] {key} = {v!r} is not one of " + ", ".join(f'"{c}"' for c in choices)
              + hint)
    return v.strip()


def parse_map(text: str, path="<map.toml>") -> ImportMap:
    """Parse and check a map (contract section 6); every problem is a located InputError."""
    doc = parse_toml(text, path)
    where = _Locator(text)
    _unknown(path, where, list(doc), list(SECTIONS))
    for sec in doc:
        if not isinstance(doc[sec], dict):
            line, col = where.key("", sec)
            raise InputError(path, f"'{sec}' must be a [{sec}] section", line, col)
        if sec in KEYS:
            _unknown(path, where, list(doc[sec]), list(KEYS[sec]), sec)
    src = doc.get("source", {})
    delimiter = src.get("delimiter", ",")
    decimal = src.get("decimal", ".")
    if not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in "\"'\r\n" or delimiter.isalnum() \
            or delimiter in ".-+":
        _fail(path, where, "source", "delimiter",
              f"[source] delimiter = {delimiter!r} must be one character such as \",\", \";\" or \"\\t\"")
    if decimal not in (".", ","):
        _fail(path, where, "source", "decimal", f"[source] decimal = {decimal!r} must be \".\" or \",\"")
    if decimal == delimiter:
        _fail(path, where, "source", "decimal",
              f"[source] decimal and delimiter are both {delimiter!r}; a decimal comma needs another delimiter (\";\")")
    header = src.get("header", True)
    if not isinstance(header, bool):
        _fail(path, where, "source", "header", f"[source] header = {header!r} must be true (the first line names the "
              "columns) or false (no header: columns by number, 1 = the first)")
    if not header:
        for section, key in (("joints", "columns"), ("position", "columns"), ("orientation", "columns"),
                             ("uncertainty", "position_columns"), ("uncertainty", "orientation_columns"),
                             ("split", "column")):
            _numbered(doc, section, key)
        for key in list(doc.get("columns", {})):
            _numbered(doc, "columns", key)
    tformat = src.get("timestamp_format")
    if tformat is not None:
        if not isinstance(tformat, str) or "%" not in tformat:
            _fail(path, where, "source", "timestamp_format",
                  f"[source] timestamp_format = {tformat!r} must be a strptime format such as \"%Y%m%d%H%M%S\"")
        if "timestamp" not in doc.get("columns", {}):
            _fail(path, where, "source", "timestamp_format",
                  "[source] timestamp_format without a [columns] timestamp to read with it")
    joints = _string_list(path, where, doc, "joints", "columns", range(MIN_JOINTS, MAX_JOINTS + 1),
                          "joint angles q1..qN in order from the base, one per joint of the robot")
    junit = _choice(path, where, doc, "joints", "unit", tuple(JOINT_UNITS))
    pos = _string_list(path, where, doc, "position", "columns", 3, "the SMR's x, y, z")
    punit = _choice(path, where, doc, "position", "unit", tuple(LENGTH_UNITS))
    frame = _choice(path, where, doc, "position", "frame", FRAMES)
    cols = doc.get("columns", {})
    if "set" in cols:
        _fail(path, where, "columns", "set", "'set' is taken from [split]: write column = \"...\" there")
    _unknown(path, where, list(cols), list(EXTRA_COLUMNS), "columns")
    for k, v in cols.items():
        if not isinstance(v, str) or not v.strip():
            _fail(path, where, "columns", k, f"[columns] {k} must name one source column (a string), got {v!r}")
    columns = {k: v.strip() for k, v in cols.items()}
    if "split" not in doc:
        raise InputError(path, "the map has no [split] section: give sample_fraction = 0.6 and seed = 1 (a seeded "
                         "random split into sample and target poses) or column = \"<source column with sample/target>\"",
                         1, 1)
    split = doc["split"]
    fraction = seed = column = None
    if "column" in split:
        if "sample_fraction" in split or "seed" in split:
            _fail(path, where, "split", "column", "[split] takes either column or sample_fraction (+ seed), not both")
        column = split["column"]
        if not isinstance(column, str) or not column.strip():
            _fail(path, where, "split", "column", f"[split] column must name a source column, got {column!r}")
        column = column.strip()
    else:
        if "sample_fraction" not in split:
            line, col = where.section("split")
            raise InputError(path, "[split] needs sample_fraction (0 < f < 1, with seed) or column", line, col)
        fraction = split["sample_fraction"]
        if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0.0 < fraction < 1.0:
            _fail(path, where, "split", "sample_fraction",
                  f"[split] sample_fraction = {fraction!r} must be a number strictly between 0 and 1")
        fraction = float(fraction)
        seed = split.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            _fail(path, where, "split", "seed", f"[split] seed = {seed!r} must be a non-negative integer")
    orientation = _orientation_section(path, where, doc)
    uncertainty = None
    if "uncertainty" in doc:
        uncertainty = {}
        for key, what in (("position_columns", "the 1-sigma of x, y, z"),
                          ("orientation_columns", "the 1-sigma of the three orientation angles")):
            uncertainty[key] = (_string_list(path, where, doc, "uncertainty", key, 3, what)
                                if key in doc["uncertainty"] else None)
        if uncertainty["orientation_columns"] and orientation is None:
            _fail(path, where, "uncertainty", "orientation_columns",
                  "[uncertainty] orientation_columns without an [orientation] section to say what they belong to")
        if uncertainty["position_columns"] and "sigma_mm" in columns:
            _fail(path, where, "uncertainty", "position_columns",
                  "[uncertainty] position_columns and [columns] sigma_mm both give the position's uncertainty: keep one")
    if not header:
        for name in joints + pos + list(columns.values()) + ([column] if column else []) + \
                (orientation["columns"] if orientation else []) + \
                [c for v in (uncertainty or {}).values() for c in (v or [])]:
            if not name.isdigit():
                line, col = ImportMap(str(path), delimiter, decimal, joints, junit, pos, punit, frame, columns,
                                      fraction, 0, column, where, orientation, uncertainty).locate_column(name)
                raise InputError(path, f"column '{name}' is a name, but [source] header = false: the file has no header "
                                 "to name it; give the column's number (1 = the first), unquoted", line, col)
    coupling = ()
    if "coupling" in doc.get("joints", {}):
        from ..arm.kinematics import parse_coupling

        try:
            coupling = parse_coupling(doc["joints"]["coupling"], len(joints), path, text, "joints")
        except InputError as exc:
            line, col = where.key("joints", "coupling")
            raise InputError(path, exc.message.replace("[joints]", "[joints] coupling"), line, col) from None
    return ImportMap(str(path), delimiter, decimal, joints, junit, pos, punit, frame, columns, fraction,
                     int(seed or 0), column, where, orientation, uncertainty, tformat, header, coupling)


def _orientation_section(path, where, doc):
    """The map's ``[orientation]`` (contract sections 6 and 13), checked; None when absent."""
    from .orientation import KINDS, ORIENTATION_UNITS, SEQUENCES

    if "orientation" not in doc:
        return None
    kind = _choice(path, where, doc, "orientation", "kind", KINDS)
    n = {"quaternion": 4, "nest": 6}.get(kind, 3)
    what = {"euler": "three Euler angles, in the order of the sequence", "quaternion": "w, x, y, z",
            "rotvec": "a rotation vector's x, y, z",
            "nest": "SMR 2's x, y, z then SMR 3's, in [position]'s unit; [position] is SMR 1"}[kind]
    cols = _string_list(path, where, doc, "orientation", "columns", n, what)
    sec = doc["orientation"]
    sequence = None
    if kind == "euler":
        if "sequence" not in sec:
            line, col = where.section("orientation")
            raise InputError(path, "[orientation] kind = \"euler\" needs sequence = \"XYZ\" (the axes in the order of "
                             "the columns; upper case intrinsic, lower case extrinsic)", line, col)
        sequence = sec["sequence"]
        if not isinstance(sequence, str) or sequence not in SEQUENCES:
            _fail(path, where, "orientation", "sequence", f"[orientation] sequence = {sequence!r} is not an Euler "
                  "sequence: three of x, y, z with no axis twice in a row, all upper case (intrinsic, e.g. \"XYZ\") "
                  "or all lower case (extrinsic, e.g. \"zyx\")")
    elif "sequence" in sec:
        _fail(path, where, "orientation", "sequence", f"[orientation] sequence is for kind = \"euler\"; kind is {kind!r}")
    unit = None
    if kind not in ("quaternion", "nest"):
        unit = _choice(path, where, doc, "orientation", "unit", ORIENTATION_UNITS)
    elif "unit" in sec:
        _fail(path, where, "orientation", "unit", f"[orientation] a {kind} has no unit"
              + (" of its own: its SMRs are in [position]'s" if kind == "nest" else ""))
    if kind == "nest" and "orientation_columns" in doc.get("uncertainty", {}):
        _fail(path, where, "uncertainty", "orientation_columns", "[uncertainty] orientation_columns: a nest's "
              "orientation has no columns of its own (its SMRs' position_columns weigh it)")
    return {"columns": cols, "kind": kind, "sequence": sequence, "unit": unit}


# --------------------------------------------------------------------------- the source
@dataclass
class Source:
    """The export's header, data rows (lists of str) and the physical line of each row."""

    path: str
    header: list
    rows: list
    lines: list
    sha256: str


def decode(data: bytes) -> str:
    """UTF-8 (with or without BOM); failing that Windows-1252, as spreadsheets write."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("cp1252", errors="replace")


def parse_source(text: str, imap: ImportMap, path="<source>", sha256: str = "") -> Source:
    """Split the export into header and rows; every mapped column must be in the header.

    ``delimiter = " "`` splits on runs of spaces and tabs; ``header = false``: no header line, the
    columns are named ``"1"``, ``"2"`` ... (the fields of the first row).
    """
    header, hline, rows, lines = None, None, [], []
    name = Path(path).name
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=imap.delimiter, skipinitialspace=imap.delimiter == " ")
    try:
        for rec in reader:
            if imap.delimiter == " ":
                rec = [f for f in rec if f != ""] if rec else rec
            if not rec or all(not f.strip() for f in rec):
                continue
            if header is None and imap.header:
                header, hline = [h.strip() for h in rec], reader.line_num
                continue
            if header is None:
                header, hline = [str(k) for k in range(1, len(rec) + 1)], reader.line_num
            rows.append(rec)
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise InputError(path, f"not readable as delimited text ({exc})", reader.line_num, None) from None
    if header is None:
        raise InputError(path, "file is empty; expected " + ("a header line and " if imap.header else "")
                         + "one row per pose", 1, None)
    counts: dict[str, int] = {}
    for h in header:
        counts[h] = counts.get(h, 0) + 1
    needed = [c for c in imap.joint_columns + imap.position_columns + list(imap.columns.values())
              + ([imap.split_column] if imap.split_column else [])
              + (imap.orientation["columns"] if imap.orientation else [])
              + [c for v in (imap.uncertainty or {}).values() for c in (v or [])]]
    for col_name in needed:
        if col_name not in counts and not imap.header:
            line, col = imap.locate_column(col_name)
            raise InputError(imap.path, f"column {col_name} is beyond the {len(header)} fields of line {hline} of {name} "
                             f"(a file without a header, [source] header = false: columns are numbered from 1; "
                             f"delimiter {imap.delimiter!r})", line, col)
        numeric = sum(bool(NUMBER.match(h.replace(",", ".") if imap.decimal == "," else h)) for h in header)
        if col_name not in counts and numeric > len(header) / 2:
            line, col = imap.locate_column(col_name)
            raise InputError(imap.path, f"column '{col_name}' is not in the header of {name}: line {hline} is numbers "
                             f"({numeric} of its {len(header)} fields), not column names: a file without a header; set "
                             "[source] header = false and give the columns by number (1 = the first)", line, col)
    for name in needed:
        if name not in counts:
            line, col = imap.locate_column(name)
            close = difflib.get_close_matches(name, header, n=3, cutoff=0.6)
            hint = f"; close: {', '.join(repr(c) for c in close)}" if close else ""
            if len(header) == 1:
                seen = [d for d in (",", ";", "\t", "|") if d in header[0] and d != imap.delimiter]
                hint += (f"; the header splits into one column with delimiter {imap.delimiter!r}"
                         + (f" but contains {seen[0]!r}: set [source] delimiter" if seen else ""))
            raise InputError(imap.path, f"column '{name}' is not in the header of {Path(path).name} (line {hline}){hint}",
                             line, col)
        if counts[name] > 1:
            line, col = imap.locate_column(name)
            raise InputError(imap.path, f"column '{name}' appears {counts[name]} times in the header of "
                             f"{Path(path).name}; it is ambiguous", line, col)
    if not rows:
        raise InputError(path, "header only, no data rows", hline, None)
    for rec, ln in zip(rows, lines):
        if len(rec) != len(header):
            first = "the header has" if imap.header else f"line {hline} (the first; no header) has"
            raise InputError(path, f"{len(rec)} fields, {first} {len(header)} (delimiter {imap.delimiter!r}, "
                             f"decimal {imap.decimal!r})", ln, None)
    return Source(str(path), header, rows, lines, sha256)


def read_source_file(path, imap: ImportMap) -> Source:
    path = Path(path)
    data = read_bytes_input(path, "source file", "the source is a folder; give the exported file")
    return parse_source(decode(data), imap, str(path), hashlib.sha256(data).hexdigest())


def numbers(source: Source, imap: ImportMap, name: str, required: bool = True) -> np.ndarray:
    """A source column as floats (NaN where empty and not required); located errors."""
    k = source.header.index(name)
    out = np.empty(len(source.rows))
    comma = imap.decimal == ","
    for i, rec in enumerate(source.rows):
        s = rec[k].strip()
        if not s:
            if required:
                raise InputError(source.path, f"empty value; '{name}' is needed (a number)", source.lines[i], name)
            out[i] = np.nan
            continue
        t = s.replace(",", ".") if comma and "." not in s else s
        if not NUMBER.match(t):
            if comma and "." in s and NUMBER.match(s):
                hint = "; the map says decimal = \",\" but this is a decimal point: [source] decimal = \".\"?"
            elif not comma and "," in s and NUMBER.match(s.replace(",", ".")):
                hint = "; the map says decimal = \".\" but this is a decimal comma: [source] decimal = \",\"?"
            elif s.lower().lstrip("+-") in ("nan", "inf", "infinity"):
                hint = "; expected a finite number"
            else:
                hint = ""
            raise InputError(source.path, f"'{s}' is not a number{hint}", source.lines[i], name)
        out[i] = float(t)
    return out


def strings(source: Source, name: str) -> list:
    k = source.header.index(name)
    return [rec[k].strip() for rec in source.rows]


def iso_times(source: Source, imap: ImportMap, name: str) -> list:
    """The source column ``name`` as ISO-8601 text (blank stays blank).

    With ``[source] timestamp_format`` every value is read by ``datetime.strptime`` and written
    ``YYYY-MM-DDTHH:MM:SS[.ffffff][+HH:MM]``; without it the values must already be ISO-8601 and
    are passed through as given. A value that does not parse names its line and column.
    """
    import datetime as _dt

    import pandas as pd

    text = strings(source, name)
    fmt = imap.timestamp_format
    if fmt is None:
        given = pd.Series(text, dtype=object)
        blank = given == ""
        parsed = pd.to_datetime(given.where(~blank), errors="coerce", utc=True, format="ISO8601")
        bad = (parsed.isna() & ~blank).to_numpy()
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(source.path, f"'{text[i]}' is not an ISO-8601 time (mapped to timestamp); say how it is "
                             "written with [source] timestamp_format, e.g. \"%Y%m%d%H%M%S\"", source.lines[i], name)
        return text
    out = []
    for i, t in enumerate(text):
        if not t:
            out.append("")
            continue
        try:
            stamp = _dt.datetime.strptime(t, fmt)
        except ValueError:
            raise InputError(source.path, f"'{t}' does not match [source] timestamp_format {fmt!r}",
                             source.lines[i], name) from None
        out.append(stamp.isoformat())
    return out


# ------------------------------------------------------------------------ the campaign
def seeded_split(n: int, fraction: float, seed: int) -> np.ndarray:
    """``sample`` / ``target`` for n poses in visiting order: round(fraction n) random samples."""
    n_sample = int(round(fraction * n))
    sets = np.full(n, "target", dtype=object)
    sets[np.random.default_rng(seed).permutation(n)[:n_sample]] = "sample"
    return sets


def _fmt(v: float, decimals: int) -> str:
    if not np.isfinite(v):
        return ""
    s = f"{v:.{decimals}f}".rstrip("0")
    s = s + "0" if s.endswith(".") else s
    return "0.0" if s in ("-0.0", "0.0") else s


def _csv(header, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


@dataclass
class Campaign:
    """The imported campaign in memory: file texts and the arrays behind them."""

    files: dict          # name -> text
    q_deg: np.ndarray
    xyz_mm: np.ndarray
    sets: np.ndarray
    point_id: list
    columns: dict        # contract column (poses/tracker) -> source column
    R_meas: np.ndarray | None = None     # (n, 3, 3) a 6-DoF probe's frames, as measured (the positions' frame)


def read_orientations(source: Source, imap: ImportMap) -> np.ndarray:
    """The probe frames (n, 3, 3) the map's ``[orientation]`` reads; a quaternion that is not unit is refused."""
    from . import orientation as ro

    o = imap.orientation
    v = np.column_stack([numbers(source, imap, c) for c in o["columns"]])
    if o["kind"] == "nest":
        scale = LENGTH_UNITS[imap.position_unit]
        p1 = np.column_stack([numbers(source, imap, c) for c in imap.position_columns]) * scale
        R, spread, worst = ro.nest_frames(p1, v[:, :3] * scale, v[:, 3:] * scale)
        if len(spread) and spread[worst] > ro.NEST_TOL_MM:
            raise InputError(source.path, f"the nest's SMRs are {spread[worst]:.3g} mm off their distances at the other "
                             f"poses here (limit {ro.NEST_TOL_MM:g} mm): an SMR reseated, swapped or mistaken?",
                             source.lines[worst], o["columns"][0])
        if not np.all(np.isfinite(R)):
            i = int(np.argmax(~np.isfinite(R).all(axis=(1, 2))))
            raise InputError(source.path, "the nest's three SMRs lie on one line here: they give no orientation",
                             source.lines[i], o["columns"][0])
        return R
    if o["kind"] == "quaternion":
        norm = np.linalg.norm(v, axis=1)
        bad = ~(np.abs(norm - 1.0) <= ro.QUATERNION_NORM_TOL)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(source.path, f"the quaternion ({', '.join(o['columns'])}) has norm {norm[i]:.6g}, not 1 "
                             "(a unit quaternion, w first, is a rotation): are these columns a quaternion, in the order "
                             "w, x, y, z?", source.lines[i], o["columns"][0])
        return ro.quaternions_to_matrices(v / norm[:, None])
    if o["kind"] == "rotvec":
        return ro.rotvecs_to_matrices(v, o["unit"])
    return ro.euler_to_matrices(v, o["sequence"], o["unit"])


def orientation_readings(source: Source, imap: ImportMap) -> dict:
    """The probe frames under the map's reading and under every other of its kind (the import's check):
    label -> (n, 3, 3)."""
    from . import orientation as ro

    o = imap.orientation
    if o["kind"] == "nest":
        return {"a nest of three SMRs": read_orientations(source, imap)}
    v = np.column_stack([numbers(source, imap, c) for c in o["columns"]])
    out = {}
    if o["kind"] == "euler":
        for unit in ro.ORIENTATION_UNITS:
            for seq in ro.SEQUENCES:
                out[f'sequence = "{seq}", unit = "{unit}"'] = ro.euler_to_matrices(v, seq, unit)
    elif o["kind"] == "rotvec":
        for unit in ro.ORIENTATION_UNITS:
            out[f'unit = "{unit}"'] = ro.rotvecs_to_matrices(v, unit)
    else:
        norm = np.linalg.norm(v, axis=1, keepdims=True)
        out["columns in the order w, x, y, z"] = ro.quaternions_to_matrices(v / norm)
        out["columns in the order x, y, z, w"] = ro.quaternions_to_matrices((v / norm)[:, [3, 0, 1, 2]])
    return out


def stated_reading(imap: ImportMap) -> str:
    """The label of :func:`orientation_readings` that is the map's own."""
    o = imap.orientation
    if o["kind"] == "euler":
        return f'sequence = "{o["sequence"]}", unit = "{o["unit"]}"'
    if o["kind"] == "rotvec":
        return f'unit = "{o["unit"]}"'
    if o["kind"] == "nest":
        return "a nest of three SMRs"
    return "columns in the order w, x, y, z"


def build_campaign(source: Source, imap: ImportMap, robot, robot_text: str, provenance: list) -> Campaign:
    """poses.csv, tracker.csv, robot.toml and campaign.toml texts (pure; same input -> same bytes).

    ``provenance``: comment lines for campaign.toml (file names, hashes; no absolute paths).
    """
    n = len(source.rows)
    q = np.column_stack([numbers(source, imap, c) for c in imap.joint_columns]) * JOINT_UNITS[imap.joint_unit]
    xyz = np.column_stack([numbers(source, imap, c) for c in imap.position_columns]) * LENGTH_UNITS[imap.position_unit]
    cols = {f"q{j + 1}": c for j, c in enumerate(imap.joint_columns)}
    cols.update({k: c for k, c in zip(("x_mm", "y_mm", "z_mm"), imap.position_columns)})
    cols.update(imap.columns)
    if "point_id" in imap.columns:
        pid = strings(source, imap.columns["point_id"])
        seen = SeenIds()
        for i, p in enumerate(pid):
            if not p:
                raise InputError(source.path, "empty point id", source.lines[i], imap.columns["point_id"])
            first = seen.earlier(p, source.lines[i])
            if first is not None:
                raise InputError(source.path, f"point id '{p}' repeats line {first}; ids must be unique",
                                 source.lines[i], imap.columns["point_id"])
    else:
        width = max(4, len(str(n)))
        pid = [f"{i + 1:0{width}d}" for i in range(n)]
    if imap.split_column is not None:
        raw = strings(source, imap.split_column)
        sets = np.array([s.lower() for s in raw], dtype=object)
        bad = ~np.isin(sets, ("sample", "target"))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(source.path, f"'{raw[i]}' is not sample or target (the [split] column of the map)",
                             source.lines[i], imap.split_column)
        cols["set"] = imap.split_column
    else:
        sets = seeded_split(n, imap.sample_fraction, imap.seed)
    # a validation set (every pose target, taken from the file's own column) imports as it is
    validation = imap.split_column is not None and n > 0 and bool((sets == "target").all())
    if not (sets == "sample").any() and not validation:
        line, col = imap.where.key("split", "column" if imap.split_column else "sample_fraction")
        raise InputError(imap.path, f"no pose is a sample pose ({n} rows): nothing to fit a model on", line, col)
    if imap.split_column is None and not (sets == "target").any():
        line, col = imap.where.key("split", "sample_fraction")
        raise InputError(imap.path, f"sample_fraction = {imap.sample_fraction:g} of {n} rows leaves no target pose",
                         line, col)
    n_joints = robot.n_joints
    extra_pose = [c for c in ("payload_kg", "temperature_c", "timestamp") + tuple(f"dir{j}" for j in range(1, n_joints + 1))
                  if c in imap.columns]
    values = {}
    unc = imap.uncertainty or {}
    if unc.get("position_columns"):
        stds = np.column_stack([numbers(source, imap, c, required=False) for c in unc["position_columns"]])
        values["sigma_mm"] = [_fmt(x, 9) for x in np.sqrt(np.mean(stds ** 2, axis=1)) * LENGTH_UNITS[imap.position_unit]]
    R_meas = read_orientations(source, imap) if imap.orientation else None
    quats = None
    if R_meas is not None:
        from .orientation import matrices_to_quaternions

        quats = matrices_to_quaternions(R_meas)
        if unc.get("orientation_columns"):
            stds = np.column_stack([numbers(source, imap, c, required=False) for c in unc["orientation_columns"]])
            per = 3600.0 if imap.orientation["unit"] == "deg" else 3600.0 * 180.0 / np.pi
            values["sigma_arcsec"] = [_fmt(x, 6) for x in np.sqrt(np.mean(stds ** 2, axis=1)) * per]
    for c in extra_pose + (["sigma_mm"] if "sigma_mm" in imap.columns else []):
        src = imap.columns[c]
        if c == "timestamp":
            values[c] = iso_times(source, imap, src)
            continue
        v = numbers(source, imap, src, required=False)
        if c == "sigma_mm":
            v = v * LENGTH_UNITS[imap.position_unit]
        if c.startswith("dir"):
            bad = np.isfinite(v) & ~np.isin(v, (-1.0, 1.0))
            if bad.any():
                i = int(np.argmax(bad))
                raise InputError(source.path, f"'{source.rows[i][source.header.index(src)].strip()}' is not +1 or -1 "
                                 f"(mapped to {c})", source.lines[i], src)
            values[c] = ["" if not np.isfinite(x) else str(int(x)) for x in v]
        else:
            values[c] = [_fmt(x, 9) for x in v]
    pose_header = ["point_id", "set"] + [f"q{j}" for j in range(1, n_joints + 1)] + extra_pose
    pose_rows = [[pid[i], sets[i]] + [_fmt(x, 10) for x in q[i]] + [values[c][i] for c in extra_pose] for i in range(n)]
    track_header = ["point_id", "x_mm", "y_mm", "z_mm"] + (["sigma_mm"] if "sigma_mm" in values else [])
    track_rows = [[pid[i]] + [_fmt(x, 9) for x in xyz[i]] + ([values["sigma_mm"][i]] if "sigma_mm" in values else [])
                  for i in range(n)]
    if quats is not None:
        track_header += ["qw", "qx", "qy", "qz"] + (["sigma_arcsec"] if "sigma_arcsec" in values else [])
        for i in range(n):
            track_rows[i] += [_fmt(x, 12) for x in quats[i]] + ([values["sigma_arcsec"][i]]
                                                                 if "sigma_arcsec" in values else [])
    n_s = int((sets == "sample").sum())
    camp = ["# Robot campaign written by `jointcal import` (contract sections 2 and 6).", *provenance,
            f"# {n} poses in the source's row order: {n_s} sample, {n - n_s} target ([split] {imap.describe_split()})",
            f"# frame: the positions are in the {'tracker' if imap.frame == 'tracker' else 'robot base'}'s frame",
            f'frame = "{imap.frame}"', ""]
    files = {"robot.toml": robot_text, "poses.csv": _csv(pose_header, pose_rows),
             "tracker.csv": _csv(track_header, track_rows), "campaign.toml": "\n".join(camp)}
    return Campaign(files, q, xyz, sets, pid, cols, R_meas)


# -------------------------------------------------------------- plausibility (unit hints)
# The other readings of the units and their refit are pipeline.robot.campaign.frame's (the engine of
# the nominal-consistency check's hypotheses); what fits well enough, and the message, are the import's.
def _spread(P: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((P - P.mean(0)) ** 2, axis=1)))) if len(P) else 0.0


def _relative(rms: float, nominal: np.ndarray, measured: np.ndarray) -> float:
    """``rms`` relative to the smaller spread of the two point clouds (0: perfect, ~1: nothing fits)."""
    scale = min(_spread(nominal), _spread(measured))
    return rms / scale if scale > 0 else np.inf


def _as_given(robot, model, q_deg, xyz_mm, frame: str):
    """The poses with finite angles and positions, their nominal SMR positions (mm) and the
    nominal-vs-measured RMS (mm) after a rigid fit (tracker frame) or as it is (base frame)."""
    ok = np.isfinite(q_deg).all(1) & np.isfinite(xyz_mm).all(1)
    q, xyz = q_deg[ok], xyz_mm[ok]
    nominal, rms = refit(robot, model, q, xyz, rigid=frame == "tracker")
    return q, xyz, nominal, rms


def nominal_rms(robot, q_deg, xyz_mm, frame: str) -> float:
    """Nominal-vs-measured RMS (mm): after a rigid fit (tracker frame) or as it is (base frame).

    Parameters
    ----------
    robot : pipeline.robot.arm.kinematics.Robot
    q_deg : ndarray, shape (n, N), deg
    xyz_mm : ndarray, shape (n, 3), mm
        Poses with a non-finite angle or coordinate are left out.
    frame : {"tracker", "base"}
    """
    return _as_given(robot, build_model(robot), q_deg, xyz_mm, frame)[3]


def check_units(camp: Campaign, imap: ImportMap, robot, source: Source) -> float:
    """Refuse joint angles or positions whose unit the map mislabels; returns the nominal RMS (mm).

    The magnitudes are checked first (positions below 5 labelled mm; values beyond 1 km
    labelled m), then, when the nominal kinematics fit the data implausibly badly, the other
    units are tried (deg -> rad only when every value is within +-2 pi): if one reading fits
    well (RMS below 20 mm and a tenth of the points' spread), the map's unit line is named
    with the fix. Anything else is left to the nominal-consistency check of ingest. The
    readings and their refit are :func:`pipeline.robot.campaign.frame.unit_hypotheses` and
    :func:`pipeline.robot.campaign.frame.refit`.
    """
    where = imap.where
    ax = np.abs(camp.xyz_mm[np.isfinite(camp.xyz_mm)])
    if imap.position_unit == "mm" and len(ax) > 9 and ax.max() < 5.0:
        _fail(imap.path, where, "position", "unit", f"every position is below 5 (largest {ax.max():.4g}) though the map "
              "says unit = \"mm\": they look like metres; set unit = \"m\"")
    if imap.position_unit == "m" and len(ax) and ax.max() > 1e6:
        _fail(imap.path, where, "position", "unit", f"positions up to {ax.max() / 1000:.4g} with unit = \"m\" are beyond "
              "1 km: they look like millimetres; set unit = \"mm\"")
    model, rigid = build_model(robot), imap.frame == "tracker"
    q, xyz, nominal, rms = _as_given(robot, model, camp.q_deg, camp.xyz_mm, imap.frame)
    if rms <= IMPLAUSIBLE_RMS_MM:
        return rms
    jmax = float(np.nanmax(np.abs(camp.q_deg / JOINT_UNITS[imap.joint_unit])))
    units = (imap.joint_unit, imap.position_unit)
    readings = other_units(units, radians=jmax <= 2 * np.pi + 1e-9)
    best = None
    for (ju, pu), q_alt, xyz_alt in unit_hypotheses(q, xyz, units, readings):
        nom, alt = refit(robot, model, q_alt, xyz_alt, rigid=rigid, given=(q, nominal))
        alt_rel = _relative(alt, nom, xyz_alt)
        if alt < IMPLAUSIBLE_RMS_MM and alt_rel < 0.1 and (best is None or alt_rel < best[3]):
            best = (ju, pu, alt, alt_rel)
    if best is None:
        return rms
    ju, pu, alt, _ = best
    fixes = ([f"[joints] unit = \"{ju}\""] if ju != imap.joint_unit else []) + \
            ([f"[position] unit = \"{pu}\""] if pu != imap.position_unit else [])
    why = []
    if ju != imap.joint_unit:
        why.append(f"the joint angles look like {ju}, not {imap.joint_unit}"
                   + (f" (every value is within +-2 pi, largest {jmax:.4g})" if ju == "rad" else ""))
    if pu != imap.position_unit:
        why.append(f"the positions look like {pu}, not {imap.position_unit}")
    fit = "after a rigid fit of the tracker frame" if imap.frame == "tracker" else "in the base frame"
    section = "joints" if ju != imap.joint_unit else "position"
    _fail(imap.path, where, section, "unit",
          f"{' and '.join(why)}: the robot's nominal kinematics miss the measured points by {rms:.4g} mm RMS {fit} "
          f"as the map says, by {alt:.4g} mm with {ju} and {pu}; set {' and '.join(fixes)}")
    return rms


def check_orientation(camp: Campaign, imap: ImportMap, robot, robot_text: str, source: Source):
    """A 6-DoF probe's orientations checked as the units are, and the probe's mounting estimated.

    The tracker's rotation comes from the positions (the rigid fit of the nominal SMR positions, or
    none with frame = "base"); under the map's reading and every other of its kind (each Euler
    sequence, intrinsic and extrinsic, in deg and rad; a rotation vector in deg and rad; a quaternion
    w first or last) the probe's mounting on the flange is the best rotation onto the measured frames
    (:func:`pipeline.robot.campaign.orientation.mounting`). The map's reading is refused, naming the
    better one, when it leaves more than :data:`~pipeline.robot.campaign.orientation.STATED_BAD_DEG`
    RMS and another fits :data:`~pipeline.robot.campaign.orientation.BETTER_FACTOR` times better.

    Returns
    -------
    robot, robot_text : the campaign's robot, with the estimated mounting as ``[tool] rpy_deg`` when
        robot.toml's is more than :data:`~pipeline.robot.campaign.orientation.MOUNTING_TOL_DEG` away
    summary : dict (mounting_rpy_deg, robot_rpy_deg, apart_deg, rms_deg, mounting_from)
    """
    from . import orientation as ro
    from .frame import fit_residuals
    from ..arm.kinematics import placements, positions

    ok = np.isfinite(camp.q_deg).all(1) & np.isfinite(camp.xyz_mm).all(1)
    rows = (camp.sets[ok] == "sample") if (camp.sets[ok] == "sample").sum() >= 3 else np.ones(int(ok.sum()), bool)
    model = build_model(robot)
    q = np.deg2rad(camp.q_deg[ok])
    Rf, _ = placements(model, q, "flange")
    R_tb = np.eye(3)
    if imap.frame == "tracker":
        R, _, _ = fit_residuals(positions(model, q), camp.xyz_mm[ok], rows)
        R_tb = R.T
    readings = {k: v[ok] for k, v in orientation_readings(source, imap).items()}
    hyps = ro.orientation_hypotheses(readings, Rf, R_tb, rows)
    by = {label: (r, M) for label, r, M in hyps}
    stated = stated_reading(imap)
    rms, M = by[stated]
    best_label, best_rms, _ = hyps[0]
    o = imap.orientation
    key = {"euler": "sequence", "rotvec": "unit", "quaternion": "columns", "nest": "columns"}[o["kind"]]
    if best_label != stated and rms > ro.STATED_BAD_DEG and best_rms * ro.BETTER_FACTOR < rms:
        fix = best_label if o["kind"] != "quaternion" else "columns = [w, x, y, z] in that order"
        if o["kind"] == "euler" and best_label.split(",")[1].strip() == f'unit = "{o["unit"]}"':
            fix = best_label.split(",")[0]
        elif o["kind"] == "euler" and best_label.split(",")[0].strip() == f'sequence = "{o["sequence"]}"':
            fix, key = best_label.split(",")[1].strip(), "unit"
        _fail(imap.path, imap.where, "orientation", key,
              f"the orientations fit the robot's nominal flange frames to {rms:.3g} deg RMS as the map reads them "
              f"({stated}), to {best_rms:.3g} deg with {best_label}, after the best probe mounting: set [orientation] "
              f"{fix}")
    if rms > ro.MAX_ORIENTATION_RMS_DEG:
        _fail(imap.path, imap.where, "orientation", "columns",
              f"the orientations fit the robot's nominal flange frames to {rms:.3g} deg RMS after the best probe "
              f"mounting, where a real robot's orientation errors stay below {ro.MAX_ORIENTATION_RMS_DEG:g} deg, and no "
              f"other reading fits (best: {best_label}, {best_rms:.3g} deg): check the columns and that they are the "
              "probe frame in the positions' frame")
    apart = float(ro.angles_deg(M, robot.tool_rotation))
    summary = {"mounting_rpy_deg": ro.rpy_deg(M).tolist(), "robot_rpy_deg": list(robot.tool_rpy_deg),
               "apart_deg": apart, "rms_deg": rms, "mounting_from": "robot.toml"}
    if apart > ro.MOUNTING_TOL_DEG:
        rpy = tuple(round(float(v), 3) + 0.0 for v in ro.rpy_deg(M))
        robot = replace(robot, tool_rpy_deg=rpy)
        head, _, _ = robot_text.partition('name = "')
        robot_text = (head + f"# [tool] rpy_deg: the probe's mounting estimated from the orientations by `jointcal "
                      f"import` (robot file's: {list(summary['robot_rpy_deg'])}, {apart:.2f} deg away)\n"
                      + robot.to_toml())
        summary["mounting_from"] = "estimated"
    return robot, robot_text, summary


def check_limits(camp: Campaign, imap: ImportMap, robot, source: Source) -> None:
    """Joint angles outside robot.toml's ranges, named at the source line and column.

    When most poses are outside the ranges in the map's joint unit and every pose is inside them in
    the other one (degrees labelled radians, or radians labelled degrees), the message names the
    map's unit line as the likely fix; a single wild value gets no such hint.
    """
    lo, hi = np.asarray(robot.lower_deg, float), np.asarray(robot.upper_deg, float)

    def outside(q_deg):
        return np.isfinite(q_deg) & ((q_deg < lo - 1e-6) | (q_deg > hi + 1e-6))

    other = {"deg": "rad", "rad": "deg"}[imap.joint_unit]
    as_other = camp.q_deg / JOINT_UNITS[imap.joint_unit] * JOINT_UNITS[other]
    beyond = outside(camp.q_deg)
    poses_out = beyond.any(axis=1)
    hint = ""
    if poses_out.mean() > 0.5 and not outside(as_other).any():
        hint = (f"; {int(poses_out.sum())} of {len(poses_out)} poses are outside the joint ranges in {imap.joint_unit} "
                f"and every one is inside them in {other}: set [joints] unit = \"{other}\"")
    for j in range(robot.n_joints):
        out = beyond[:, j]
        if out.any():
            i = int(np.argmax(out))
            q = camp.q_deg[i, j]
            raw = q / JOINT_UNITS[imap.joint_unit]
            raise InputError(source.path, f"{raw:g} {imap.joint_unit} = {q:g} deg is outside joint {j + 1}'s range "
                             f"[{lo[j]:g}, {hi[j]:g}] deg of the robot ({Path(robot.path).name}){hint}",
                             source.lines[i], imap.joint_columns[j])


# ------------------------------------------------------------------ install (atomic)
# what a nominal-consistency refusal most likely needs changed, and where in the map, by the
# cause the check found (InputError.hypothesis, see pipeline.robot.campaign.frame)
_MAP_FIXES = {"frame": ("position", "frame", "[position] frame in the map"),
              "radians": ("joints", "unit", "[joints] unit in the map"),
              "metres": ("position", "unit", "[position] unit in the map"),
              "swap": ("joints", "columns", "the order of [joints] columns in the map"),
              "sign": ("joints", "columns", "the joint columns of the map (a joint's sign)"),
              "coupling": ("joints", "columns", "the map's [joints]")}


def _map_fix(hypothesis: str):
    for key, fix in _MAP_FIXES.items():
        if hypothesis == key or (key in ("swap", "sign", "coupling") and hypothesis.startswith(key)):
            return fix
    return None


def _robot_location(exc: InputError, tmpdir: Path, robot_path):
    """Where in the user's robot file the key that an error names in the imported robot.toml is."""
    if not isinstance(exc.line, int):
        return None, None
    try:
        copied = (tmpdir / "robot.toml").read_text(encoding="utf-8").splitlines()
        original = Path(robot_path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None, None
    if exc.line > len(copied):
        return None, None
    m = re.match(r"^\s*([A-Za-z0-9_]+)\s*=", copied[exc.line - 1])
    if not m or is_urdf(robot_path):
        return None, None
    nth = sum(1 for ln in copied[: exc.line] if re.match(r"^\s*\[\[\s*joint\s*\]\]", ln))
    count, inside = 0, nth == 0
    for k, ln in enumerate(original.splitlines(), 1):
        if re.match(r"^\s*\[\[\s*joint\s*\]\]", ln):
            count += 1
            inside = count == nth
        elif re.match(r"^\s*\[", ln):
            inside = nth == 0 and ln.strip().startswith("[tool]") if m.group(1) == "xyz_mm" else nth == 0
        km = re.match(r"^(\s*)" + re.escape(m.group(1)) + r"\s*=", ln)
        if inside and km:
            return k, len(km.group(1)) + 1
    return None, None


def _in_urdf_terms(message: str, robot_path, tip, base, tool_mm, tool_fit) -> str:
    """A message about the imported robot.toml said in the terms of the URDF the user gave.

    ``robot.toml`` becomes the URDF's name; a wrong tool's suggestion (``tool_fit``, the SMR in the
    flange frame {N} that fits, mm) is given in the ``--tip`` link's frame, the frame ``--tool-mm`` is
    read in, as the option to type.
    """
    name = Path(robot_path).name
    if tool_fit is not None:
        _, info = robot_from_urdf(robot_path, tip, base, tool_mm, checks=0)
        R, t = info["tip_in_flange"]
        local = R.T @ (np.asarray(tool_fit, float) - t)
        given = np.zeros(3) if tool_mm is None else np.asarray(tool_mm, float)
        said = f"--tool-mm {' '.join(f'{v:g}' for v in given)}" if tool_mm is not None else "its origin (no --tool-mm)"
        typed = " ".join(f"{v:.1f}" for v in local)
        message = re.sub(r"a wrong tool: with the SMR at \[[^\]]*\] mm in the flange frame, \d+ mm from \[tool\] "
                         r"xyz_mm of robot\.toml,",
                         f"a wrong tool: with the SMR at [{typed.replace(' ', ', ')}] mm in link '{tip}''s frame "
                         f"(--tool-mm {typed}), {np.linalg.norm(local - given):.0f} mm from {said},", message)
    message = message.replace("zero offsets (theta_offset_deg) of robot.toml", f"joint zeros of {name}")
    message = re.sub(r"say so with \[coupling\] .*? in robot\.toml, or ", "say so with ", message)
    return message.replace("robot.toml", f"{name} (--tip {tip})", 1).replace("robot.toml", name)


def translate(exc: InputError, tmpdir: Path, camp: Campaign, imap: ImportMap, source: Source, robot_path,
              robot_where=(None, None), urdf=None) -> InputError:
    """An error ``ingest_robot`` found in the temporary campaign, named where the user can fix it.

    A row's problem is named at the source's line and column; a refusal of the whole campaign
    by the nominal-consistency check at the map line its likely cause points to (frame, unit,
    joint columns); a robot problem in the robot file given (at ``robot_where`` for a URDF).
    ``urdf``: ``(tip, base, tool_mm)`` of a URDF robot, whose messages are then said in its terms
    (:func:`_in_urdf_terms`).
    """
    p = Path(exc.path)
    if p.parent.resolve() != Path(tmpdir).resolve():
        return exc
    name = p.name
    if urdf is not None and is_urdf(robot_path):
        said = _in_urdf_terms(exc.message, robot_path, *urdf, getattr(exc, "tool_mm", None))
        if said != exc.message:
            hyp, kind, tool = (getattr(exc, k, None) for k in ("hypothesis", "kind", "tool_mm"))
            exc = InputError(exc.path, said, exc.line, exc.column)
            exc.hypothesis, exc.kind, exc.tool_mm = hyp, kind, tool
    if name in ("poses.csv", "tracker.csv"):
        fix = _map_fix(getattr(exc, "hypothesis", "") or "")
        if fix is not None:
            section, key, what = fix
            line, col = imap.where.key(section, key)
            return InputError(imap.path, f"{exc.message} (nominal check of the imported campaign; change {what})",
                              line, col)
        if isinstance(exc.line, int) and exc.line >= 2 and exc.line - 2 < len(source.lines):
            col = camp.columns.get(str(exc.column), exc.column) if exc.column is not None else None
            return InputError(source.path, f"{exc.message} (in the imported {name})", source.lines[exc.line - 2], col)
        line, col = imap.where.key("joints", "columns")
        return InputError(imap.path, f"{exc.message} (in the imported {name})", line, col)
    if name == "campaign.toml":
        line, col = imap.where.key("position", "frame")
        return InputError(imap.path, f"{exc.message} (in the imported campaign.toml)", line, col)
    if is_urdf(robot_path):
        return InputError(robot_path, exc.message if urdf is not None else f"{exc.message} (in the imported robot.toml)",
                          *robot_where)
    line, col = _robot_location(exc, Path(tmpdir), robot_path)
    return InputError(robot_path, f"{exc.message} (in the imported robot.toml)", line, col)


def install_campaign(out_dir, files: dict, validate) -> None:
    """Write ``files`` into ``out_dir`` only if ``validate(tmpdir)`` passes; nothing half-written.

    The folder is built in a temporary sibling, validated, then renamed into place (new
    folder) or its files renamed one by one over the old ones (existing folder). On any
    error the temporary folder (and any parent folder made for it) is removed.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(out, "--out exists and is not a folder")
    made = []
    parent = out.absolute().parent
    for d in reversed([parent, *parent.parents]):
        if not d.exists():
            d.mkdir()
            made.append(d)
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.import-", dir=parent))
        for name, text in files.items():
            with open(tmp / name, "w", encoding="utf-8", newline="") as fh:
                fh.write(text)
        validate(tmp)
        if not out.exists():
            os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp makes 0700; a campaign is an ordinary folder
            os.rename(tmp, out)
            tmp = None
        else:
            for name in files:
                os.replace(tmp / name, out / name)
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
            tmp = None
        for d in reversed(made):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


# ------------------------------------------------------------------------ the command
def _sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def is_urdf(path) -> bool:
    path = Path(path)
    if path.suffix.lower() in (".urdf", ".xml"):
        return True
    if path.suffix.lower() == ".toml":
        return False
    with contextlib.suppress(OSError):
        with open(path, "rb") as fh:
            return fh.read(256).lstrip().startswith((b"<?xml", b"<robot"))
    return False


def load_import_robot(robot_path, tip=None, base=None, tool_mm=None, ur_model=None):
    """The robot of an import: ``robot.toml`` as parsed, derived from a URDF (``tip`` needed), or a
    UR's own ``calibration.conf`` with ``ur_model`` (:mod:`pipeline.robot.campaign.ur`).

    Returns the Robot, the text of the campaign's robot.toml and a provenance line.
    """
    from .ur import UR_DH, calibration_header, is_calibration_conf, parse_calibration_conf, robot_from_calibration

    name = Path(robot_path).name
    if not Path(robot_path).exists():
        raise InputError(robot_path, "robot file not found (a robot.toml, or a URDF with --tip LINK)")
    if ur_model is not None or is_calibration_conf(robot_path):
        if ur_model is None:
            raise InputError(robot_path, f"a UR calibration.conf needs --ur-model ({', '.join(UR_DH)}): its deltas "
                             "are against that model's published DH", None, None)
        if tip or base:
            raise InputError(robot_path, "--tip and --base name links of a URDF; a calibration.conf is a UR's own "
                             "kinematics (give the SMR with --tool-mm X Y Z in the tool flange frame)")
        deltas = parse_calibration_conf(read_text_input(robot_path, "UR calibration.conf"), str(robot_path))
        robot = robot_from_calibration(deltas, ur_model, tool_mm if tool_mm is not None else (0.0, 0.0, 0.0),
                                       str(robot_path))
        sha = _sha(robot_path)
        return robot, calibration_header(name, sha, ur_model, deltas) + "\n" + robot.to_toml(), \
            f"# robot: {name} (sha256 {sha}), UR calibration.conf of a {ur_model.upper()}"
    if is_urdf(robot_path):
        if not tip:
            raise InputError(robot_path, "a URDF robot needs --tip LINK: the link whose origin is the SMR "
                             "(or the flange link, with --tool-mm X Y Z in its frame)")
        robot, info = robot_from_urdf(robot_path, tip, base, tool_mm)
        tool = "" if tool_mm is None else f" + tool_mm [{', '.join(_fmt(v, 9) for v in tool_mm)}]"
        head = [f"# Nominal kinematics derived by `jointcal import` from {name} (sha256 {_sha(robot_path)}):",
                f"# chain {', '.join(info['chain'])}; base frame '{info['base']}'; SMR at link '{tip}'{tool}.",
                "# Classic DH plus beta (contract section 2), taken at q = 0 from the URDF's joint axes;",
                f"# checked: the SMR agrees with pinocchio's URDF model to < {FK_TOLERANCE_MM:g} mm at "
                f"{info['checks']} random configurations.",
                "# Masses and centres of mass (link frame {i}) from the URDF's inertias; limits from its <limit>s."]
        return robot, "\n".join(head) + "\n" + robot.to_toml(), f"# robot: {name} (sha256 {_sha(robot_path)}), tip " \
            f"'{tip}'{', base ' + repr(base) if base else ''}{tool}"
    if tip or base:
        raise InputError(robot_path, "--tip and --base name links of a URDF; this robot is a robot.toml (its [tool] "
                         "is the SMR in the flange frame)")
    text = read_text_input(robot_path, "robot.toml")
    robot = parse_robot(text, str(robot_path))
    tool = ""
    if tool_mm is not None:
        robot = replace(robot, tool_xyz_mm=tuple(float(v) for v in tool_mm))
        tool = f" with [tool] xyz_mm = [{', '.join(_fmt(v, 9) for v in tool_mm)}] from --tool-mm"
    head = f"# Nominal kinematics copied by `jointcal import` from {name} (sha256 {_sha(robot_path)}){tool}.\n"
    return robot, head + robot.to_toml(), f"# robot: {name} (sha256 {_sha(robot_path)}){tool}"


def check_joint_count(imap: ImportMap, robot, robot_path) -> None:
    """The map's [joints] columns must be one per joint of the robot; refused naming both counts."""
    n, m = robot.n_joints, len(imap.joint_columns)
    extra = [c for c in imap.columns if c.startswith("dir") and int(c[3:]) > n]
    if m != n:
        line, col = imap.where.key("joints", "columns")
        raise InputError(imap.path, f"[joints] columns lists {m} joint columns; the robot ({Path(robot_path).name}) "
                         f"has {n} joints: list one source column per joint, from the base", line, col)
    if extra:
        line, col = imap.where.key("columns", extra[0])
        raise InputError(imap.path, f"[columns] {extra[0]} names joint {extra[0][3:]}; the robot "
                         f"({Path(robot_path).name}) has {n} joints", line, col)


def import_campaign(source_path, map_path, robot_path, out_dir, tip=None, base=None, tool_mm=None,
                    ur_model=None) -> dict:
    """Read, check and install a campaign folder (contract section 6). Returns a summary.

    Nothing is written unless everything passes, including ``ingest_robot`` on the result.
    """
    map_text = read_text_input(map_path, "map")
    imap = parse_map(map_text, str(map_path))
    robot, robot_text, robot_line = load_import_robot(robot_path, tip, base, tool_mm, ur_model)
    check_joint_count(imap, robot, robot_path)
    notes = []
    reversed1 = is_urdf(robot_path) and bool(robot.coupling)     # a URDF robot's own coupling: joint 1 about -z
    if reversed1:
        notes.append("joint 1 turns about -z in the URDF: its angle is taken as -q1 (a [coupling] row)")
    if imap.coupling and reversed1:
        # the map's coupling gives the URDF's angles from the recorded ones, the URDF's sign the kinematics' from
        # the URDF's: C = C_sign @ C_map
        old_lines = "\n".join(robot.coupling_lines())
        C = robot.coupling_matrix @ replace(robot, coupling=imap.coupling).coupling_matrix
        rows = tuple((j, tuple(float(c) for c in C[j])) for j in range(robot.n_joints)
                     if not np.array_equal(C[j], np.eye(robot.n_joints)[j]))
        robot = replace(robot, coupling=rows)
        robot_text = (robot_text.replace(old_lines, "\n".join(robot.coupling_lines())) if rows
                      else robot_text.replace("\n\n" + old_lines, ""))      # the two undo each other
    elif imap.coupling:
        if robot.coupling and robot.coupling != imap.coupling:
            line, col = imap.where.key("joints", "coupling")
            raise InputError(imap.path, f"[joints] coupling differs from the [coupling] of {Path(robot_path).name}: "
                             "state it once", line, col)
        if not robot.coupling:
            robot = replace(robot, coupling=imap.coupling)
            robot_text = robot_text.rstrip("\n") + "\n\n" + "\n".join(robot.coupling_lines()) + "\n"
    source = read_source_file(source_path, imap)
    prov = [f"# source: {Path(source_path).name} (sha256 {source.sha256})",
            f"# map: {Path(map_path).name} (sha256 {_sha(map_path)})", robot_line]
    camp = build_campaign(source, imap, robot, robot_text, prov)
    # the checks see the angles the kinematics take (coupled joints combined); poses.csv keeps the recorded ones
    seen = replace(camp, q_deg=robot.kinematic_angles(camp.q_deg)) if robot.coupling else camp
    check_limits(seen, imap, robot, source)
    rms = check_units(seen, imap, robot, source)
    oriented = None
    if imap.orientation and rms <= MAX_RMS_MM:
        # (positions that do not fit the robot are refused below, with their likely cause, first)
        robot, robot_text, oriented = check_orientation(seen, imap, robot, robot_text, source)
        camp.files["robot.toml"] = robot_text
    robot_where = (None, None)
    if is_urdf(robot_path):
        robot_where = tag_line(Path(robot_path).read_text(encoding="utf-8"), "link", tip)

    def validate(tmp):
        try:
            ingest_robot(tmp)
        except InputError as exc:
            raise translate(exc, Path(tmp), camp, imap, source, robot_path, robot_where,
                            (tip, base, tool_mm) if is_urdf(robot_path) else None) from None

    install_campaign(out_dir, camp.files, validate)
    n_s = int((camp.sets == "sample").sum())
    return {"n": len(camp.sets), "sample": n_s, "target": len(camp.sets) - n_s, "frame": imap.frame,
            "nominal_rms_mm": rms, "orientation": oriented, "warnings": mass_warnings(robot, robot_path),
            "notes": notes}


def mass_warnings(robot, robot_path) -> list[str]:
    """What the robot's masses leave out, for the console: a URDF without ``<inertial>`` on the arm's
    links gives every mass 0 (no gravity torque: compliance can be neither fitted nor revealed by any
    poses); some links without one, those joints' links."""
    if not is_urdf(robot_path):
        return []
    name = Path(robot_path).name
    massless = [i + 1 for i, j in enumerate(robot.joints) if j.mass_kg <= 0.0]
    if len(massless) == robot.n_joints:
        return [f"{name} has no <inertial> on the arm's links: every mass is 0, so every gravity torque is 0 and "
                "compliance can be neither fitted nor revealed by any choice of poses (only a payload would load the "
                "joints); give the links' <inertial> (mass, origin) in the URDF and import again, or mass_kg and "
                "com_mm in the campaign's robot.toml"]
    if massless:
        return [f"{name} gives no mass (no <inertial>) to the links of joint {', '.join(map(str, massless))}: the "
                "gravity torques leave them out"]
    return []
