"""ABB RAPID: a ``.mod`` module (contract section 11).

Read: ``CONST``/``PERS``/``VAR`` (``LOCAL``, ``TASK``) declarations of ``robtarget``, ``jointtarget``,
``tooldata`` and ``wobjdata``; the motions ``MoveJ``, ``MoveL``, ``MoveC`` (Cartesian) and ``MoveAbsJ``
(joint) to a declared name or an inline literal, with their tool argument and ``\\WObj``; ``ConfJ``.
A ``MoveJ`` goes to the branch its ``cf1 cf4 cf6 cfx`` name (``ConfJ \\Off``: the branch of the point
before, nearest its joints); ``MoveL`` and ``MoveC`` keep the branch of the point before. Tool
``tool0`` is the flange and work object ``wobj0`` (or no ``\\WObj``) the robot's base frame; a tool or
work object declared in the module is used as declared (``uframe . oframe``); one that is not: ``--tool``
/ ``--base``. Keywords are case-insensitive; ``!`` starts a comment.

Left as given and named: ``Offs``, ``RelTool``, ``CRobT``, ``CalcRobT`` and any other function at
the motion, ``*`` (a point stored in the instruction), indexed arrays, ``\\Corr``, a stationary tool
(``robhold`` FALSE) or a moving work object. Refused (file:line): a statement without its ``;``,
unbalanced brackets, a robtarget or jointtarget with the wrong number of values, a name nobody
declared, ``MODULE`` without ``ENDMODULE``, and motion instructions not read here (``MoveJDO``,
``SearchL``, ...).
"""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import InputError
from . import conventions as cv
from .model import CARTESIAN, CONFIG, JOINT, PREVIOUS, Frame, Program, Target
from .text import NUMBER, Number, balanced, read_source, split_top

DECL_RE = re.compile(r"(?:(?:LOCAL|TASK)\s+)*(CONST|PERS|VAR)\s+(robtarget|jointtarget|tooldata|wobjdata)\s+"
                     r"([A-Za-z_]\w*)\s*(\{[^}]*\})?\s*(?::=\s*(.*))?$", re.IGNORECASE | re.DOTALL)
MOTION_RE = re.compile(r"(MoveJ|MoveL|MoveC|MoveAbsJ)\b(.*)$", re.IGNORECASE | re.DOTALL)
OTHER_MOTION_RE = re.compile(r"(Move\w+|Search\w+|Trigg[JLC]\w*|Arc[LC]\w*|Cap[LC]\w*)\b", re.IGNORECASE)
STATEMENT_START = re.compile(r"(?:LOCAL\s+|TASK\s+)*(CONST|PERS|VAR|Move\w+|ConfJ|ConfL|Search\w+)\b", re.IGNORECASE)


def _mask(text: str) -> str:
    """The text with comments and string contents blanked (same length: offsets stay)."""
    out, k, n = list(text), 0, len(text)
    inside = False
    while k < n:
        ch = text[k]
        if inside:
            if ch == '"':
                inside = False
            elif ch not in "\r\n":
                out[k] = " "
        elif ch == '"':
            inside = True
        elif ch == "!":
            while k < n and text[k] not in "\r\n":
                out[k] = " "
                k += 1
            continue
        k += 1
    return "".join(out)


def _groups(lit: str, at: int, fidx: int, path: str, line: int):
    """Numbers of a literal ``[[..],[..],...]``: list of groups, each a list of Number or text items."""
    s = lit.strip()
    lead = at + lit.index(s) if s else at
    if not (s.startswith("[") and s.endswith("]")) or not balanced(s):
        raise InputError(path, f"broken literal '{s[:40]}' (expected [[...],[...]])", line, None)
    groups = []
    for off, part in split_top(s[1:-1]):
        p = part.strip()
        pstart = lead + 1 + off + part.index(p) if p else lead + 1 + off
        if p.startswith("[") and p.endswith("]"):
            items = []
            for o2, item in split_top(p[1:-1]):
                it = item.strip()
                istart = pstart + 1 + o2 + (item.index(it) if it else 0)
                items.append(Number(fidx, istart, istart + len(it), it) if re.fullmatch(NUMBER, it) else it)
            groups.append(items)
        else:
            groups.append(p)
    return groups


def _nums(group, count, what, path, line):
    if not isinstance(group, list) or len(group) != count or not all(isinstance(x, Number) for x in group):
        raise InputError(path, f"{what}: expected {count} numbers", line, None)
    return group


def _robtarget(lit, at, fidx, path, line):
    g = _groups(lit, at, fidx, path, line)
    if len(g) != 4:
        raise InputError(path, "a robtarget is [[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a..eax_f]]", line, None)
    trans = _nums(g[0], 3, "robtarget trans [x,y,z]", path, line)
    rot = _nums(g[1], 4, "robtarget rot [q1,q2,q3,q4]", path, line)
    conf = _nums(g[2], 4, "robtarget robconf [cf1,cf4,cf6,cfx]", path, line)
    _nums(g[3], 6, "robtarget extax", path, line)
    cf = [int(float(c.text)) for c in conf]
    return trans + rot, cv.abb_cfx_flags(cf[3]), (cf[0], cf[1], cf[2])


def _jointtarget(lit, at, fidx, path, line):
    g = _groups(lit, at, fidx, path, line)
    if len(g) != 2:
        raise InputError(path, "a jointtarget is [[rax_1..rax_6],[eax_a..eax_f]]", line, None)
    _nums(g[1], 6, "jointtarget extax", path, line)
    return _nums(g[0], 6, "jointtarget robax", path, line)


def _nested(s: str, path: str, line: int):
    """A literal as nested lists of strings (``[TRUE,[[1,2,3],[1,0,0,0]]]`` -> ['TRUE', [['1','2','3'], [...]]])."""
    s = s.strip()
    if not s.startswith("["):
        return s
    if not s.endswith("]") or not balanced(s):
        raise InputError(path, f"broken literal '{s[:40]}'", line, None)
    return [_nested(p, path, line) for _, p in split_top(s[1:-1])]


def _pose_list(v, what, path, line):
    try:
        t = [float(x) for x in v[0]]
        q = [float(x) for x in v[1]]
        if len(t) != 3 or len(q) != 4:
            raise ValueError
    except (ValueError, TypeError, IndexError):
        raise InputError(path, f"{what}: expected [[x,y,z],[q1,q2,q3,q4]]", line, None) from None
    return cv.homogeneous(cv.abb_matrix(*q), t)


def _tooldata(lit, path, line, name):
    g = _nested(lit, path, line)
    if not isinstance(g, list) or len(g) < 2 or not isinstance(g[1], list):
        raise InputError(path, f"tooldata {name}: expected [robhold,[[x,y,z],[q1,q2,q3,q4]],[load]]", line, None)
    if str(g[0]).upper() != "TRUE":
        return Frame(None, f"tool {name} is a stationary tool (robhold FALSE)", name)
    return Frame(_pose_list(g[1], f"tooldata {name} tframe", path, line), "", name)


def _wobjdata(lit, path, line, name):
    g = _nested(lit, path, line)
    if not isinstance(g, list) or len(g) != 5:
        raise InputError(path, f"wobjdata {name}: expected [robhold,ufprog,ufmec,uframe,oframe]", line, None)
    if str(g[0]).upper() != "FALSE" or str(g[1]).upper() != "TRUE" or str(g[2]).strip('"').strip():
        return Frame(None, f"work object {name} moves (robhold TRUE, ufprog FALSE or a mechanical unit)", name)
    U = _pose_list(g[3], f"wobjdata {name} uframe", path, line)
    O = _pose_list(g[4], f"wobjdata {name} oframe", path, line)
    return Frame(U @ O, "", name)


def _statements(src, masked):
    """Statements of interest: (start, end, text) from a statement keyword to its ``;``."""
    out = []
    for m in re.finditer(r"(?m)^[ \t]*", masked):
        k = m.end()
        if not STATEMENT_START.match(masked, k):
            continue
        depth, j = 0, k
        while j < len(masked):
            ch = masked[j]
            if ch in "([{":
                depth += 1
            elif ch in ")]}":
                depth -= 1
            elif ch == ";" and depth == 0:
                break
            j += 1
        line = src.line_of(k)
        stmt = masked[k:j]
        nxt = re.search(r"\n[ \t]*(?:LOCAL\s+|TASK\s+)*(CONST|PERS|VAR|Move\w+|ConfJ|ConfL|ENDPROC|ENDMODULE|PROC|ENDFUNC)\b",
                        stmt, re.IGNORECASE)
        if j >= len(masked) or nxt:
            raise InputError(src.path, "statement without its ';'", line, None)
        if not balanced(stmt):
            raise InputError(src.path, "unbalanced brackets", line, None)
        out.append((k, j, stmt, line))
    return out


def read(path) -> Program:
    """Read a RAPID module; InputError (file:line) on broken syntax."""
    src = read_source(path)
    text = src.text
    masked = _mask(text)
    if re.search(r"(?im)^\s*MODULE\b", masked) and not re.search(r"(?im)^\s*ENDMODULE\b", masked):
        raise InputError(src.path, "MODULE without ENDMODULE", src.line_of(re.search(r"(?im)^\s*MODULE\b", masked).start()),
                         None)
    decls, tools, wobjs = {}, {"TOOL0": Frame(np.eye(4), "", "tool0")}, {"WOBJ0": Frame(np.eye(4), "", "wobj0")}
    stmts = _statements(src, masked)
    for k, j, stmt, line in stmts:
        m = DECL_RE.match(stmt)
        if not m:
            continue
        kind, typ, name, dims, value = m.group(1), m.group(2).lower(), m.group(3), m.group(4), m.group(5)
        if value is None or dims:
            decls[name.upper()] = (typ, None, line, name, "an array or a declaration without a value")
            continue
        at = k + m.start(5)
        lit = text[at:j]
        if typ == "robtarget":
            decls[name.upper()] = (typ, _robtarget(lit, at, 0, src.path, line), line, name, kind.upper())
        elif typ == "jointtarget":
            decls[name.upper()] = (typ, _jointtarget(lit, at, 0, src.path, line), line, name, kind.upper())
        elif typ == "tooldata":
            tools[name.upper()] = _tooldata(lit, src.path, line, name)
        else:
            wobjs[name.upper()] = _wobjdata(lit, src.path, line, name)
    targets = []
    conf_j = True
    for k, j, stmt, line in stmts:
        s = stmt.strip()
        mc = re.match(r"ConfJ\s*\\(On|Off)", s, re.IGNORECASE)
        if mc:
            conf_j = mc.group(1).lower() == "on"
            continue
        if re.match(r"ConfL\b", s, re.IGNORECASE) or DECL_RE.match(stmt):
            continue
        m = MOTION_RE.match(s)
        if not m or not re.match(r"\s|\\|$", m.group(2) or " "):
            mo = OTHER_MOTION_RE.match(s)
            if mo:
                raise InputError(src.path, f"unknown motion instruction '{mo.group(1)}' (MoveJ, MoveL, MoveC and "
                                 "MoveAbsJ are read)", line, None)
            continue
        word = m.group(1)
        args_at = k + (len(stmt) - len(stmt.lstrip())) + m.start(2)
        args = text[args_at:j]
        parts = split_top(args)
        if parts and parts[0][1].strip().lower() == "\\conc":
            parts = parts[1:]
        wobj = None
        for _, p in parts:
            mw = re.search(r"\\WObj\s*:=\s*([A-Za-z_]\w*)", p, re.IGNORECASE)
            if mw:
                wobj = mw.group(1)
        n_points = 2 if word.lower() == "movec" else 1
        if len(parts) < n_points + 3:
            raise InputError(src.path, f"{word}: expected {'CirPoint, ' if n_points == 2 else ''}ToPoint, Speed, Zone, "
                             "Tool", line, None)
        tool_name = re.split(r"\\", parts[n_points + 2][1])[0].strip()
        tool = tools.get(tool_name.upper(), Frame(None, f"tool {tool_name} is not declared in the module", tool_name))
        base = wobjs.get((wobj or "wobj0").upper(),
                         Frame(None, f"work object {wobj} is not declared in the module", wobj or "wobj0"))
        corr = re.search(r"\\Corr\b", args, re.IGNORECASE)
        for off, expr in parts[:n_points]:
            e = re.split(r"\\", expr)[0]
            t = _motion_target(word, e, args_at + off, text, decls, src.path, line, conf_j)
            t.tool, t.base = tool, base
            if corr and not t.runtime:
                t.runtime = "\\Corr: a path correction added at run time"
            targets.append(t)
    return Program("rapid", [src], targets)


def _motion_target(word, expr, at, text, decls, path, line, conf_j) -> Target:
    w = word.lower()
    joint = w == "moveabsj"
    branch = CONFIG if (w == "movej" and conf_j) else PREVIOUS
    kind = JOINT if joint else CARTESIAN
    e = expr.strip()
    lead = at + (expr.index(e) if e else 0)
    if not e:
        raise InputError(path, f"{word} without a target", line, None)
    if e.startswith("["):
        name = f"<inline>@{line}"
        if joint:
            return Target(path, line, name, JOINT, branch, _jointtarget(e, lead, 0, path, line), decl=(0, lead))
        nums, flags, turn = _robtarget(e, lead, 0, path, line)
        return Target(path, line, name, CARTESIAN, branch, nums, flags, turn, decl=(0, lead))
    if e == "*":
        return Target(path, line, "*", kind, branch, runtime="a point stored in the instruction (*)")
    if not re.fullmatch(r"[A-Za-z_]\w*", e):
        return Target(path, line, e, kind, branch, runtime=f"a target computed at run time ({e})")
    d = decls.get(e.upper())
    if d is None:
        raise InputError(path, f"{word} {e}: no robtarget or jointtarget {e} declared in the module", line, None)
    typ, data, dline, name, how = d
    if data is None:
        return Target(path, line, name, kind, branch, runtime=f"{name} is {how}")
    if joint != (typ == "jointtarget"):
        raise InputError(path, f"{word} {e}: {e} is a {typ}", line, None)
    if joint:
        return Target(path, line, name, JOINT, branch, data, decl=(0, data[0].start))
    nums, flags, turn = data
    return Target(path, line, name, CARTESIAN, branch, nums, flags, turn, decl=(0, nums[0].start),
                  extra={"pers": how == "PERS"})
