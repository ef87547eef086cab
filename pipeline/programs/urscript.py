"""Universal Robots URScript ``.script`` / ``.urscript`` (contract section 11).

A statement is a logical line: a line, continued on the next ones while a bracket or parenthesis is
open. Read: ``movej``, ``movel``, ``movep`` (one target) and ``movec`` (via point and target), to an
inline ``p[x, y, z, rx, ry, rz]`` (m and rotation vector, rad: Cartesian) or ``[q1 .. q6]`` (rad: joint),
to a variable assigned once (``global P1 = p[...]``, ``Q1 = [...]``), or to
``get_inverse_kin(pose, qnear=...)`` of one; the TCP from ``set_tcp(p[...])`` (or a variable assigned
once); the payload from ``set_payload(m, ...)``, ``set_payload_mass(m)`` and ``set_target_payload(m, ...)``
(kg; from that statement on, in the text's order: decision). UR has no configuration data: every
Cartesian target goes to the solution nearest the joints of the point before (decision), but for
``get_inverse_kin(pose, qnear)`` with a known ``qnear`` (a literal joint list or a variable assigned once,
as PolyScope writes every waypoint: ``movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q))``), which
goes to the solution nearest ``qnear``, as the controller does; ``qnear`` is not rewritten. A
``get_inverse_kin`` with its own ``tcp=`` is left as given. Poses are in the robot's base frame (``--base`` is
not used for UR); without ``set_tcp`` the TCP is ``--tool`` (mm and a rotation vector, rad). ``#``
starts a comment.

Left as given and named: poses built at run time (``pose_trans``, ``pose_add``,
``get_actual_tcp_pose()``, a variable assigned more than once or nowhere, e.g. a function's
parameter), and motions streamed at run time (``servoj``, ``servoc``, ``servol``, ``speedj``,
``speedl``, ``movecs``). Every other statement (calls of functions of any name, threads, URCap
code) passes through. Refused (file:line): unbalanced brackets or parentheses, a
``def``/``if``/``while``/``for``/``thread`` block without its ``end``.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import InputError
from . import conventions as cv
from .model import CARTESIAN, JOINT, PREVIOUS, Frame, Program, Target
from .text import NUMBER, Number, balanced, read_source, split_top, strip_comment

MOVE_RE = re.compile(r"\b(movej|movel|movep|movec)\s*\(")
STREAMED_RE = re.compile(r"\b(servoj|servoc|speedj|speedl|movecs|servol)\s*\(")
PAYLOAD_RE = re.compile(r"\b(set_payload|set_payload_mass|set_target_payload)\s*\(")
ASSIGN_RE = re.compile(r"^\s*(?:global\s+|local\s+)?([A-Za-z_]\w*)\s*=(?!=)\s*(.*?)\s*$")
OPEN_RE = re.compile(r"^\s*(def|thread|if|while|for)\b.*:\s*$", re.S)  # a header may run over lines


def _list(expr: str, at: int, path: str, line: int):
    """Numbers of ``p[...]`` / ``[...]``: (is_pose, [Number]) or None when not a literal of numbers."""
    e = expr.strip()
    lead = at + (expr.index(e) if e else 0)
    m = re.fullmatch(r"(p?)\[(.*)\]", e, re.DOTALL)
    if not m:
        return None
    body_at = lead + len(m.group(1)) + 1
    nums = []
    for off, part in split_top(m.group(2)):
        p = part.strip()
        if not re.fullmatch(NUMBER, p):
            return None
        a = body_at + off + part.index(p)
        nums.append(Number(0, a, a + len(p), p))
    if len(nums) != 6:
        raise InputError(path, f"a {'pose p' if m.group(1) else 'joint list '}[...] needs 6 numbers, not {len(nums)}",
                         line, None)
    return bool(m.group(1)), nums


def _args(code: str, open_at: int):
    depth = 0
    for k in range(open_at, len(code)):
        if code[k] == "(":
            depth += 1
        elif code[k] == ")":
            depth -= 1
            if depth == 0:
                return code[open_at + 1:k], open_at + 1
    return None, None


def logical_lines(text: str):
    """A script's statements: (first line index, start, end, code) with comments blanked (offsets kept);
    a line continues on the next while a bracket or parenthesis is open."""
    lines = text.splitlines(keepends=True)
    masked = []
    for raw in lines:
        body = raw.rstrip("\r\n")
        code = strip_comment(body, "#")
        masked.append(code + " " * (len(body) - len(code)) + raw[len(body):])
    out, first, start, depth, pos, inside = [], 0, 0, 0, 0, False
    for i, raw in enumerate(masked):
        if depth == 0:
            first, start = i, pos
        for ch in raw:
            if ch == '"':
                inside = not inside
            elif not inside and ch in "([":
                depth += 1
            elif not inside and ch in ")]":
                depth -= 1
        inside = False
        pos += len(raw)
        if depth <= 0:
            out.append((first, start, pos, "".join(masked[first:i + 1]).rstrip("\r\n")))
            depth = 0
    if depth > 0:
        out.append((first, start, pos, "".join(masked[first:]).rstrip("\r\n")))
    return out


def read(path) -> Program:
    """Read a URScript program; InputError (file:line) on broken syntax."""
    src = read_source(path)
    stmts = logical_lines(src.text)
    assigned = {}
    depth, opened = 0, []
    for i, start, _, code in stmts:
        if not balanced(code):
            raise InputError(src.path, "unbalanced brackets or parentheses", i + 1, None)
        s = code.strip()
        if OPEN_RE.match(code):
            depth += 1
            opened.append(i + 1)
        elif re.fullmatch(r"end", s):
            depth -= 1
            if depth < 0:
                raise InputError(src.path, "'end' without a block to end", i + 1, None)
            opened.pop()
        m = ASSIGN_RE.match(code)
        if m and not s.startswith(("if ", "while ", "elif ")):
            assigned.setdefault(m.group(1), []).append((start + m.start(2), m.group(2), i + 1))
    if depth:
        raise InputError(src.path, "block without its 'end'", opened[-1], None)

    def lookup(name, line):
        if name not in assigned:
            return None, f"{name} is assigned nowhere in the script (a parameter, or set at run time)"
        if len(assigned[name]) > 1:
            return None, f"{name} is assigned {len(assigned[name])} times (its value is known at run time only)"
        at, expr, aline = assigned[name][0]
        lit = _list(expr, at, src.path, aline)
        if lit is None:
            return None, f"{name} = {expr.strip()} is computed at run time"
        return lit, (name, at)

    tool = Frame(None, "the script sets no TCP (set_tcp) before it", "TCP (no set_tcp)")
    base = Frame(np.eye(4), "", "base")
    payload = (None, "the script sets no payload (set_payload) before it")
    targets = []
    for i, start, _, code in stmts:
        line = i + 1
        for mo in STREAMED_RE.finditer(code):
            targets.append(Target(src.path, line, f"{mo.group(1)}@{line}", JOINT if mo.group(1).endswith("j") else
                                  CARTESIAN, PREVIOUS, runtime=f"{mo.group(1)}: a motion streamed at run time"))
        mp = PAYLOAD_RE.search(code)
        if mp:
            args, _ = _args(code, mp.end() - 1)
            first = split_top(args or "")[0][1].strip()
            if re.fullmatch(NUMBER, first):
                payload = (float(first), f"{mp.group(1)} at line {line}")
            else:
                payload = (None, f"{mp.group(1)}({first}) at line {line} is computed at run time")
            continue
        mt = re.search(r"\bset_tcp\s*\(", code)
        if mt:
            args, at = _args(code, mt.end() - 1)
            first = split_top(args)[0][1]
            lit = _list(first, 0, src.path, line)
            if lit is None and re.fullmatch(r"\s*[A-Za-z_]\w*\s*", first):
                lit, _ = lookup(first.strip(), line)
            if lit is None or not lit[0]:
                tool = Frame(None, f"set_tcp({first.strip()}) is computed at run time", f"set_tcp at line {line}")
            else:
                v = [float(n.text) for n in lit[1]]
                tool = Frame(cv.homogeneous(cv.ur_matrix(*v[3:]), np.array(v[:3]) * 1000.0), "", f"set_tcp@{line}")
            continue
        for m in MOVE_RE.finditer(code):
            args, at = _args(code, m.end() - 1)
            parts = split_top(args)
            n_pts = 2 if m.group(1) == "movec" else 1
            for off, expr in parts[:n_pts]:
                t = _target(m.group(1), expr, start + at + off, src.path, line, lookup)
                t.tool, t.base = tool, base
                t.extra["payload"] = payload
                targets.append(t)
    return Program("ur", [src], targets)


def _target(word, expr, at, path, line, lookup) -> Target:
    e = expr.strip()
    mg = re.fullmatch(r"get_inverse_kin\s*\((.*)\)", e, re.DOTALL)
    qnear = None
    if mg:
        args = split_top(mg.group(1))
        inner = args[0]
        at = at + expr.index(mg.group(1)) + inner[0]
        expr = inner[1]
        e = expr.strip()
        # the controller returns the solution nearest qnear (the second argument, or qnear=): a literal joint
        # list or a variable assigned once; computed at run time it is not known (the point before stands)
        rest = [a.strip() for _, a in args[1:]]
        named = {a.split("=", 1)[0].strip(): a.split("=", 1)[1] for a in rest if re.match(r"^\w+\s*=(?!=)", a)}
        if "tcp" in named:
            return Target(path, line, e[:40], CARTESIAN, PREVIOUS,
                          runtime=f"get_inverse_kin with its own tcp ({named['tcp'].strip()[:40]})")
        qexpr = named.get("qnear", rest[0] if rest and not re.match(r"^\w+\s*=(?!=)", rest[0]) else None)
        if qexpr is not None:
            lit = _list(qexpr, 0, path, line)
            if lit is None and re.fullmatch(r"\s*[A-Za-z_]\w*\s*", qexpr):
                lit, _ = lookup(qexpr.strip(), line)
            if lit is not None and not lit[0]:
                qnear = np.rad2deg([float(n.text) for n in lit[1]])
    t = _plain_target(word, expr, at, path, line, lookup)
    if qnear is not None and t.kind == CARTESIAN and not t.runtime:
        t.extra["qnear_deg"] = qnear
    return t


def _plain_target(word, expr, at, path, line, lookup) -> Target:
    e = expr.strip()
    lit = _list(expr, at, path, line)
    name = f"<inline>@{line}"
    decl = (0, at)
    if lit is None:
        if re.fullmatch(r"[A-Za-z_]\w*", e):
            lit, info = lookup(e, line)
            if lit is None:
                return Target(path, line, e, CARTESIAN, PREVIOUS, runtime=info)
            name, decl = info[0], (0, info[1])
        else:
            return Target(path, line, e[:40], CARTESIAN, PREVIOUS, runtime=f"a pose computed at run time ({e[:60]})")
    is_pose, nums = lit
    if not is_pose and word != "movej":
        return Target(path, line, name, JOINT, PREVIOUS, nums, decl=decl)
    return Target(path, line, name, CARTESIAN if is_pose else JOINT, PREVIOUS, nums, decl=decl)
