"""Reading contract CSV tables with located errors.

Every problem is an :class:`~pipeline.core.errors.InputError` naming file, line and column.
Readers collect *all* problems (``jointcal validate`` lists them); stages raise the first.
"""

from __future__ import annotations

import csv
import difflib
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError

# column kinds
STR, INT, FLOAT, SIGN, TIME = "str", "int", "float", "sign", "time"


class Problems(list):
    """A list of InputError; ``raise_first`` raises the earliest by file order."""

    def add(self, path, message, line=None, column=None):
        self.append(InputError(path, message, line, column))

    def raise_first(self):
        if self:
            raise self[0]


class SeenIds:
    """The ids met so far, each with the line it was first met on: the one check that an id (a
    ``point_id``) appears once, row by row (:meth:`earlier`) or over a table (:func:`check_unique_ids`)."""

    def __init__(self):
        self.lines = {}

    def earlier(self, value, line):
        """The line ``value`` was met on before (None the first time; then it is remembered at ``line``)."""
        if value in self.lines:
            return self.lines[value]
        self.lines[value] = line
        return None


def check_unique_ids(path, frame, message: str, column: str = "point_id", problems: Problems | None = None) -> None:
    """The first row of a :func:`read_table` frame whose ``column`` repeats an earlier row's: an InputError
    at its file, line and column, raised (``problems`` None) or collected.

    ``message`` is formatted with ``id`` (the repeated value) and ``first`` (the line it was first on).
    """
    seen = SeenIds()
    for value, line in zip(frame[column].tolist(), frame["_line"].tolist()):
        first = seen.earlier(value, line)
        if first is not None:
            err = InputError(path, message.format(id=value, first=first), int(line), column)
            if problems is None:
                raise err
            problems.append(err)
            return


_JOINT_COLUMN = re.compile(r"(q|dir)(\d+)")


@dataclass(frozen=True)
class JointColumns:
    """The joint columns (``q<k>``, ``dir<k>``) of a table's header against a robot's ``n`` joints.

    Attributes
    ----------
    q : list of int
        ``k`` of every ``q<k>`` column, in header order (a column given twice counts twice).
    extra : list of str
        The ``q<k>`` and ``dir<k>`` columns naming no joint ``1 … n``, in header order.
    missing : list of str
        The columns ``q1 … qn`` the header lacks, in joint order.
    """

    q: list
    extra: list
    missing: list

    @property
    def in_order(self) -> bool:
        """The ``q`` columns are exactly ``q1 … qn`` for ``n = len(q)`` (whatever the robot's count)."""
        return sorted(self.q) == list(range(1, len(self.q) + 1))


def find_joint_columns(header, n: int) -> JointColumns:
    """Which joint columns of ``header`` (stripped column names) are missing or in excess for a robot of
    ``n`` joints: the one finding behind each reader's joint-count check (the poses, the pool, the
    targets; each words its own refusal).

    Examples
    --------
    >>> find_joint_columns(["point_id", "q1", "q2", "q4"], 3)
    JointColumns(q=[1, 2, 4], extra=['q4'], missing=['q3'])
    """
    q, extra = [], []
    for c in header:
        m = _JOINT_COLUMN.fullmatch(c)
        if m is None:
            continue
        k = int(m.group(2))
        if m.group(1) == "q":
            q.append(k)
        if not 1 <= k <= n:
            extra.append(c)
    return JointColumns(q, extra, [f"q{k}" for k in range(1, n + 1) if k not in q])


def _filled(record) -> bool:
    """A CSV record with a field of more than white space (others are blank lines, left out)."""
    return bool(record) and bool("".join(record).strip())


def csv_rows(text: str) -> tuple[list[str] | None, int, list[tuple[int, list[str]]]]:
    """The records of a CSV text with their file lines: the one row reader of the contract tables.

    Parameters
    ----------
    text : str
        The file's text (newlines translated; a leading byte-order mark is dropped).

    Returns
    -------
    header : list of str or None
        The first record that is not blank, its names stripped (None: no such record).
    header_line : int
        Its 1-based line (0 without a header).
    rows : list of (int, list of str)
        Every later record that is not blank (a blank record: no field with more than white
        space), with its 1-based line; fields as written (a field after a comma may start
        with spaces, which are dropped).
    """
    text = text[1:] if text.startswith("\ufeff") else text
    reader = csv.reader(io.StringIO(text), skipinitialspace=True)
    records = [(line, record) for line, record in enumerate(reader, start=1) if _filled(record)]
    if not records:
        return None, 0, []
    (header_line, header), rows = records[0], records[1:]
    return [c.strip() for c in header], header_line, rows


def fields_problem(header, record) -> str:
    """What is wrong with a record that has not one field per column of the header ('' when it has)."""
    return f"{len(record)} fields, the header has {len(header)}" if len(record) != len(header) else ""


def text_table(text: str, path) -> tuple[pd.DataFrame, np.ndarray] | None:
    """Every column of a CSV text as written (str, names stripped), blank rows left out, and each
    row's 1-based file line, shape (n,); None without a header. A row with the wrong number of
    fields raises InputError at its line. The rows :func:`read_table` types, and a table passed
    through as it is (``jointcal correct`` of encoder readings)."""
    header, _, rows = csv_rows(text)
    if header is None:
        return None
    for line, record in rows:
        problem = fields_problem(header, record)
        if problem:
            raise InputError(path, problem, line, None)
    return (pd.DataFrame([r for _, r in rows], columns=header, dtype=str),
            np.array([line for line, _ in rows], int))


def csv_header(path) -> list[str]:
    """The header of a CSV file (names stripped; the file is read up to it); [] when it cannot be
    read or has none (the table's reader then says why)."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            first = next((r for r in csv.reader(fh, skipinitialspace=True) if _filled(r)), None)
    except (OSError, UnicodeDecodeError, csv.Error):
        return []
    return [c.strip() for c in first] if first else []


def read_table(path, required: dict, optional: dict | None = None, problems: Problems | None = None):
    """Read a CSV whose columns have declared kinds.

    Parameters
    ----------
    path : path-like
    required : dict column -> kind
    optional : dict column -> kind
    problems : Problems, optional
        Collector; when None the first problem is raised.

    Returns
    -------
    pandas.DataFrame or None
        Typed columns plus ``_line`` (1-based line of the row in the file, header = 1);
        None when the file could not be read at all.
    """
    own = problems is None
    problems = Problems() if own else problems
    optional = optional or {}
    path = Path(path)
    start = len(problems)
    try:
        table = text_table(path.read_text(encoding="utf-8"), path)
    except (UnicodeDecodeError, csv.Error) as exc:
        problems.add(path, f"not a readable CSV file ({' '.join(str(exc).split())})", None, None)
    except InputError as exc:           # a row with the wrong number of fields
        problems.append(exc)
    else:
        if table is None:
            problems.add(path, "file is empty; expected a header line with columns " + ", ".join(required), 1, None)
        else:
            frame = _check_columns(path, *table, required, optional, problems)
            if frame is not None and len(problems) == start:
                if own:
                    problems.raise_first()
                return frame
    if own:
        problems.raise_first()
    return None


def _check_columns(path, raw, lines, required, optional, problems):
    known = {**required, **optional}
    for col in required:
        if col not in raw.columns:
            close = difflib.get_close_matches(col, [c for c in raw.columns if c not in known], n=1)
            hint = f" (found '{close[0]}': misspelled?)" if close else ""
            problems.add(path, f"missing required column '{col}'{hint}", 1, col)
    dup = raw.columns[raw.columns.duplicated()]
    for col in dup:
        problems.add(path, f"column '{col}' appears twice in the header", 1, col)
    if problems and any(p.path == str(path) and p.line == 1 for p in problems):
        return None
    if len(raw) == 0:
        problems.add(path, "header only, no data rows", 1, None)
        return None
    out = pd.DataFrame({"_line": lines})
    for col, kind in known.items():
        if col not in raw.columns:
            continue
        out[col] = _convert(path, raw[col], lines, col, kind, problems, optional=col in optional)
    return out


def _convert(path, series, lines, col, kind, problems, optional):
    text = series.str.strip()
    blank = text == ""
    if kind == STR:
        if not optional and blank.any():
            i = int(np.argmax(blank.to_numpy()))
            problems.add(path, f"empty value; '{col}' is required", int(lines[i]), col)
        return text
    if kind == TIME:
        values = pd.to_datetime(text.where(~blank), errors="coerce", utc=True, format="ISO8601")
        bad = values.isna() & ~blank
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            problems.add(path, f"'{series.iloc[i]}' is not an ISO-8601 time", int(lines[i]), col)
        return values
    values = pd.to_numeric(text.where(~blank), errors="coerce")
    bad_text = values.isna() & ~blank
    if bad_text.any():
        i = int(np.argmax(bad_text.to_numpy()))
        low = series.iloc[i].strip().lower()
        what = "NaN" if low in ("nan", "-nan", "+nan") else f"'{series.iloc[i]}' is not a number"
        problems.add(path, f"{what}; expected a finite {'integer' if kind in (INT, SIGN) else 'number'}", int(lines[i]), col)
    arr = values.to_numpy(dtype=float)
    nonfinite = ~np.isfinite(arr) & ~values.isna().to_numpy()
    if nonfinite.any():
        i = int(np.argmax(nonfinite))
        problems.add(path, f"'{series.iloc[i]}' is not finite; expected a finite number", int(lines[i]), col)
    if blank.any() and not optional:
        i = int(np.argmax(blank.to_numpy()))
        problems.add(path, f"empty value; '{col}' is required", int(lines[i]), col)
    if kind in (INT, SIGN):
        ok = np.isfinite(arr)
        finite = np.where(ok, arr, 0.0)  # inf - round(inf) would warn on stderr beside the one error line
        frac = ok & (np.abs(finite - np.round(finite)) > 1e-9)
        if frac.any():
            i = int(np.argmax(frac))
            problems.add(path, f"'{series.iloc[i]}' is not an integer", int(lines[i]), col)
        if kind == SIGN:
            badsign = ok & ~np.isin(arr, (-1.0, 1.0))
            if badsign.any():
                i = int(np.argmax(badsign))
                problems.add(path, f"'{series.iloc[i]}' must be +1 or -1", int(lines[i]), col)
    return arr
