"""The pool of feasible poses ``jointcal plan`` chooses from (contract section 9), read and checked,
and the plan written as the start of a ``poses.csv``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..core.files import read_text_input
from ..core.tables import SeenIds, csv_rows, fields_problem, find_joint_columns


@dataclass
class Pool:
    """Poses the robot can reach and the tracker can see.

    Attributes
    ----------
    point_id : ndarray of str, shape (n,)
    q_deg : ndarray, shape (n, N), deg
    payload_kg : ndarray, shape (n,), kg (0 when the file has no payload_kg)
    has_payload : bool
    """

    point_id: np.ndarray
    q_deg: np.ndarray
    payload_kg: np.ndarray
    has_payload: bool


def parse_pool(text: str, n_joints: int, lower_deg, upper_deg, path="<pool>") -> Pool:
    """Read a pool CSV (``point_id, q1 … qN``, optional ``payload_kg``); bad input raises InputError
    naming the line (the header is line 1) and the column."""
    header, header_line, rows = csv_rows(text)
    if header is None or header_line != 1:
        raise InputError(path, "empty file: a pool needs a header point_id, q1 … qN and one row per pose", 1, None)
    joints = find_joint_columns(header, n_joints)
    qcols = sorted(joints.q)
    if "point_id" not in header:
        raise InputError(path, "no point_id column (a pool has point_id, q1 … qN, optional payload_kg)", 1, "point_id")
    if len(qcols) != n_joints or not joints.in_order:
        found = f"q1 … q{len(qcols)}" if joints.in_order else ", ".join(f"q{k}" for k in qcols)
        raise InputError(path, f"the pool has {len(qcols)} joint columns ({found or 'none'}) but the robot has "
                         f"{n_joints} joints (q1 … q{n_joints})", 1,
                         f"q{n_joints + 1}" if len(qcols) > n_joints else f"q{len(qcols) + 1}")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise InputError(path, f"column {dup[0]!r} appears twice in the header", 1, dup[0])
    col = {c: k for k, c in enumerate(header)}
    has_payload = "payload_kg" in col
    ids, Q, pay, seen = [], [], [], SeenIds()
    lower, upper = np.asarray(lower_deg, float), np.asarray(upper_deg, float)
    for ln, row in rows:
        ragged = fields_problem(header, row)
        if ragged:
            raise InputError(path, ragged, ln, None)
        pid = row[col["point_id"]].strip()
        if not pid:
            raise InputError(path, "empty point_id", ln, "point_id")
        first = seen.earlier(pid, ln)
        if first is not None:
            raise InputError(path, f"point_id {pid!r} already on line {first}", ln, "point_id")
        q = []
        for j in range(1, n_joints + 1):
            name = f"q{j}"
            v = _number(row[col[name]], path, ln, name, "deg")
            if not lower[j - 1] - 1e-9 <= v <= upper[j - 1] + 1e-9:
                raise InputError(path, f"{name} = {v:g} deg is outside joint {j}'s range [{lower[j - 1]:g}, "
                                 f"{upper[j - 1]:g}] deg of the robot (angles in degrees?)", ln, name)
            q.append(v)
        p = _number(row[col["payload_kg"]], path, ln, "payload_kg", "kg") if has_payload else 0.0
        if p < 0:
            raise InputError(path, f"payload_kg = {p:g} is negative", ln, "payload_kg")
        ids.append(pid)
        Q.append(q)
        pay.append(p)
    if not ids:
        raise InputError(path, "no pose in the pool (only a header)", 2, None)
    return Pool(np.array(ids, dtype=object), np.array(Q, float), np.array(pay, float), has_payload)


def _number(text, path, line, column, unit):
    try:
        v = float(text)
    except ValueError:
        raise InputError(path, f"{column} must be a number ({unit}), found {text.strip()!r}", line, column) from None
    if not np.isfinite(v):
        raise InputError(path, f"{column} must be a finite number ({unit}), found {text.strip()!r}", line, column)
    return v


def read_pool(path, robot) -> Pool:
    """:func:`parse_pool` of a file, for ``robot``'s joint count and ranges (a coupled joint's range is the
    arm's angle's, not the recorded one's: not checked per value)."""
    text = read_text_input(path, "pool")
    lo, hi = robot.lower_deg.copy(), robot.upper_deg.copy()
    for j, _ in getattr(robot, "coupling", ()):
        lo[j], hi[j] = -np.inf, np.inf
    return parse_pool(text, len(robot.joints), lo, hi, str(path))


def format_plan_csv(point_id, q_deg, payload_kg=None, directions=None) -> str:
    """The plan in visiting order: ``point_id, q1 … qN`` (full precision, deg), ``payload_kg`` when
    given, ``dir1 … dirN`` when the plan needs approach directions, and ``set`` = ``sample`` (poses
    to identify the model on: the file is ready to become a campaign's poses.csv)."""
    q = np.asarray(q_deg, float)
    nj = q.shape[1]
    head = ["point_id"] + [f"q{j}" for j in range(1, nj + 1)]
    if payload_kg is not None:
        head.append("payload_kg")
    if directions is not None:
        head += [f"dir{j}" for j in range(1, nj + 1)]
    head.append("set")
    out = [",".join(head)]
    for k, pid in enumerate(point_id):
        cells = [str(pid)] + [repr(float(v)) for v in q[k]]
        if payload_kg is not None:
            cells.append(repr(float(payload_kg[k])))
        if directions is not None:
            cells += [str(int(v)) for v in directions[k]]
        cells.append("sample")
        out.append(",".join(cells))
    return "\n".join(out) + "\n"
