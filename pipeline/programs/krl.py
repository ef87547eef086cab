"""KUKA KRL: a ``.src``, the ``.dat`` of the same name beside it and the controller's ``$config.dat``
(contract section 11).

Read: ``DECL E6POS/POS/E6AXIS/AXIS/FRAME/FDAT`` data (in either file), and in the ``.src`` the motions
``PTP``, ``LIN``, ``CIRC`` (and the spline single motions ``SPTP``, ``SLIN``, ``SCIRC``) to a declared
name or an inline aggregate (``{X 1,Y 2,...}``, ``{E6POS: ...}``, ``{AXIS: A1 ...}``); the tool and base
from ``$TOOL = {...}`` / ``$BASE = {...}``, ``BAS(#TOOL, n)`` / ``BAS(#BASE, n)``, ``$TOOL = TOOL_DATA[n]``,
``$BASE = BASE_DATA[n]`` and ``FDAT_ACT = FPn`` (``TOOL_NO``, ``BASE_NO``). Tool 0 is the flange and
base 0 the robot's base frame; any other number is ``TOOL_DATA``/``BASE_DATA`` of the controller's
``$config.dat``: read from it when it lies beside the ``.src`` (or in the ``--program`` folder), else
``--tool`` / ``--base``. The payload: ``$LOAD = {M ...}``, ``$LOAD.M = ...``, ``$LOAD = LOAD_DATA[n]``,
and the ``LOAD_DATA[n]`` a tool change (``BAS(#TOOL, n)``, ``FDAT_ACT``, ``STOOL2``) activates, from a
given ``$config.dat`` (``M -1``, the controller's default load, states no mass). ``S`` names the
branch of a ``PTP`` (bit 0 rear, bit 1 elbow up, bit 2 flip; ignored for ``LIN``/``CIRC`` as the
controller does), ``T`` the sign of each joint. A UTF-8 byte-order mark is not read (``text``).

Left as given and named: geometric operators (``XP1 : {X 10}``), ``PTP_REL``/``LIN_REL``, ``$POS_ACT``
and other system variables, indexed arrays, partial aggregates (``{X 10, Y 20}``), targets under
``IPO_FRAME #TCP`` (a stationary tool), names declared nowhere or without a value, names declared in
``$config.dat`` (``XHOME``: shared by every program, never rewritten; the file is read, not written),
the segments of spline blocks (``SPLINE``/``PTP_SPLINE`` ... ``ENDSPLINE``) and asynchronous motions
(``ASYPTP`` ...). KSS 8 inline forms (``SPTP XP1 WITH $TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO)``)
take the tool and base of their FDAT. Refused (file:line): unbalanced braces, a ``DEF`` without
``END``, a ``DEFDAT`` without ``ENDDAT``, a ``SPLINE`` without ``ENDSPLINE``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from . import conventions as cv
from .model import CARTESIAN, CONFIG, JOINT, PREVIOUS, Frame, Program, Target
from .text import NUMBER, Number, balanced, read_source, split_top, strip_comment

DECL_RE = re.compile(r"^(\s*(?:DECL\s+)?(?:GLOBAL\s+)?)(E6POS|POS|E6AXIS|AXIS|FRAME|FDAT)\s+([A-Za-z_$][\w$]*)\s*(=\s*|$)",
                     re.IGNORECASE)
#: the controller's numbered frames and loads in $config.dat: ``TOOL_DATA[1]={X ...}``, ``LOAD_DATA[1]={M 60,...}``
NUMBERED_RE = re.compile(r"^\s*(?:DECL\s+(?:FRAME|LOAD)\s+)?(TOOL_DATA|BASE_DATA|LOAD_DATA)\s*\[\s*(\d+)\s*\]\s*=\s*",
                         re.IGNORECASE)
CONFIG_DAT = "$config.dat"
MOTION_RE = re.compile(r"^\s*(PTP_REL|LIN_REL|SPTP_REL|SLIN_REL|PTP|LIN|CIRC|SPTP|SLIN|SCIRC)\b(.*)$", re.IGNORECASE)
UNSUPPORTED_RE = re.compile(r"^\s*(SPLINE|PTP_SPLINE|SPL|ASYPTP|ASYLIN|ASYCIRC|ASYCONT)\b", re.IGNORECASE)
POSE_KEYS = ("X", "Y", "Z", "A", "B", "C")
JOINT_KEYS = ("A1", "A2", "A3", "A4", "A5", "A6")
ITEM_RE = re.compile(r"^\s*([A-Za-z_$][\w$]*(?:\[\])?)\s+(.*?)\s*$")


def dat_of(src: Path) -> Path | None:
    """The ``.dat`` beside a ``.src`` (same name, any case of the extension), or None."""
    for cand in src.parent.glob(src.stem + ".*"):
        if cand.suffix.lower() == ".dat" and cand.stem == src.stem:
            return cand
    return None


def _aggregate(text: str, start: int, path: str, line: int):
    """Parse an aggregate ``{...}`` beginning at ``text[start]``: (end, items, type prefix).

    items: KEY -> (value text, absolute start, absolute end)."""
    depth, k, inside = 0, start, False
    while k < len(text):
        ch = text[k]
        if ch == '"':
            inside = not inside
        elif not inside and ch == "{":
            depth += 1
        elif not inside and ch == "}":
            depth -= 1
            if depth == 0:
                break
        elif ch == "\n" and depth:
            raise InputError(path, "unbalanced braces: the aggregate is not closed on its line", line, None)
        k += 1
    if depth:
        raise InputError(path, "unbalanced braces: the aggregate is not closed", line, None)
    body_start = start + 1
    body = text[body_start:k]
    prefix = ""
    m = re.match(r"\s*([A-Za-z_][\w]*)\s*:", body)
    if m:
        prefix = m.group(1).upper()
        body_start += m.end()
        body = body[m.end():]
    items = {}
    if body.strip():
        for off, part in split_top(body):
            mi = ITEM_RE.match(part)
            if not mi:
                raise InputError(path, f"broken aggregate item '{part.strip()}' (expected NAME value)", line, None)
            key, val = mi.group(1).upper(), mi.group(2)
            vstart = body_start + off + part.index(val, mi.start(2)) if val else body_start + off
            items[key] = (val, vstart, vstart + len(val))
    return k + 1, items, prefix


def _numbers(items, keys, fidx):
    out = []
    for key in keys:
        val, a, b = items[key]
        if not re.fullmatch(NUMBER, val):
            return None
        out.append(Number(fidx, a, b, val))
    return out


def _st(items):
    def val(key):
        if key not in items:
            return None
        v = items[key][0].strip()
        m = re.fullmatch(r"'B([01]+)'", v, re.IGNORECASE)
        if m:
            return int(m.group(1), 2)
        return int(float(v)) if re.fullmatch(NUMBER, v) else None
    return val("S"), val("T")


def config_of(src: Path) -> Path | None:
    """The controller's ``$config.dat`` beside a ``.src`` (any case), or None."""
    for cand in src.parent.iterdir():
        if cand.name.lower() == CONFIG_DAT and cand.is_file():
            return cand
    return None


#: an assignment statement of the .src: a variable or one of its fields on the left of a single '='
ASSIGNED_RE = re.compile(r"^\s*([A-Za-z_]\w*)(?:\s*\.\s*\w+)*\s*=(?!=)")


#: words followed by '(' that are no call of a routine (control flow, operators, built-in functions whose
#: parameters are all :IN)
NOT_CALLS = {"IF", "WHILE", "UNTIL", "FOR", "WAIT", "SWITCH", "CASE", "AND", "OR", "NOT", "EXOR", "RETURN",
             "ELSE", "TO", "STEP", "SIN", "COS", "TAN", "ASIN", "ACOS", "ATAN2", "SQRT", "ABS", "INV_POS",
             "FORWARD", "INVERSE", "VARSTATE", "STRLEN", "B_AND", "B_OR", "B_NOT", "B_EXOR"}
ROUTINE_RE = re.compile(r"^\s*(?:GLOBAL\s+)?(?:DEF|DEFFCT\s+\w+|EXT|EXTFCT\s+\w+)\s+([A-Za-z_]\w*)\s*\(([^)]*)\)",
                        re.IGNORECASE)


def _modes(text: str) -> dict:
    """Per routine DEF'd in the file (upper-case name): True for each parameter declared ``:IN``."""
    out = {}
    for raw in text.splitlines():
        m = ROUTINE_RE.match(strip_comment(raw, ";"))
        if m and m.group(2).strip():
            out[m.group(1).upper()] = [bool(re.search(r":\s*IN\b", a, re.IGNORECASE)) for a in m.group(2).split(",")]
    return out


def _passed(text: str) -> dict:
    """Variables the .src passes to a call (bare or a field: ``f(goal)``, ``EKI_GetReal(c, t, goal.X)``): a
    KRL parameter is :OUT (by reference) unless the routine declares it :IN, so the call may write it.

    Returns
    -------
    dict
        upper-case name -> (line, callee) of its first such call.
    """
    modes, out = _modes(text), {}
    for k, raw in enumerate(text.splitlines(), 1):
        code = strip_comment(raw, ";")
        if ROUTINE_RE.match(code) or re.match(r"^\s*(?:DECL\b|GLOBAL\b|&)", code, re.IGNORECASE):
            continue
        for m in re.finditer(r"(?<![\w$.])([A-Za-z_]\w*)\s*\(", code):
            callee = m.group(1)
            if callee.upper() in NOT_CALLS:
                continue
            depth, args, start = 0, [], m.end()
            for i in range(m.end(), len(code)):
                c = code[i]
                if c in "([{":
                    depth += 1
                elif c in ")]}":
                    if depth == 0:
                        args.append(code[start:i])
                        break
                    depth -= 1
                elif c == "," and depth == 0:
                    args.append(code[start:i])
                    start = i + 1
            ins = modes.get(callee.upper(), [])
            for j, a in enumerate(args):
                ma = re.fullmatch(r"\s*([A-Za-z_]\w*)(?:\s*\.\s*\w+)*\s*", a)
                if ma and not (j < len(ins) and ins[j]):
                    out.setdefault(ma.group(1).upper(), (k, callee))
    return out


class _Data:
    def __init__(self):
        self.decls = {}
        self.numbered = {}             # ("TOOL_DATA", n) -> (items, file index, line)
        self.config = None             # file index of $config.dat, when read
        self.assigned = {}             # NAME -> first .src line that assigns it (or a field of it)
        self.passed = {}               # NAME -> (line, callee): passed to a call that may write it

    def scan(self, src, fidx, only_global=False):
        text = src.text
        pos = 0
        for line, raw in enumerate(text.splitlines(keepends=True), 1):
            code = strip_comment(raw, ";") if ";" in raw else raw
            if only_global and not re.match(r"^\s*(?:DECL\s+)?GLOBAL\b", code, re.IGNORECASE):
                pos += len(raw)
                continue
            mn = NUMBERED_RE.match(code)
            if mn and code.find("{", mn.end()) >= 0 and balanced(code):
                _, items, _ = _aggregate(text, pos + code.find("{", mn.end()), src.path, line)
                self.numbered[(mn.group(1).upper(), int(mn.group(2)))] = (items, fidx, line)
            m = DECL_RE.match(code)
            if m and not m.group(4).startswith("="):
                if not code[m.end():].strip():
                    self.decls[m.group(3).upper()] = (m.group(2).upper(), fidx, None, None, line, m.group(3))
                pos += len(raw)
                continue
            if m:
                brace = code.find("{", m.end())
                if brace < 0 or code[m.end():brace].strip():
                    raise InputError(src.path, f"DECL {m.group(2)} {m.group(3)}: the value must be an aggregate {{...}}",
                                     line, None)
                if not balanced(code):
                    raise InputError(src.path, "unbalanced braces", line, None)
                _, items, _ = _aggregate(text, pos + brace, src.path, line)
                self.decls[m.group(3).upper()] = (m.group(2).upper(), fidx, pos + brace, items, line, m.group(3))
            pos += len(raw)


def _target_of(items, prefix, fidx, decl_type=""):
    """(kind, numbers, flags, turn) of an aggregate, or a reason it is partial."""
    keys = set(items)
    if decl_type in ("E6AXIS", "AXIS") or prefix in ("AXIS", "E6AXIS") or (keys & set(JOINT_KEYS) and not keys & {"X", "Y", "Z"}):
        if not set(JOINT_KEYS) <= keys:
            return None, "a partial joint aggregate (the controller fills the missing axes at run time)"
        nums = _numbers(items, JOINT_KEYS, fidx)
        return (JOINT, nums, None, None) if nums else (None, "joint values that are not numbers")
    if not set(POSE_KEYS) <= keys:
        return None, "a partial aggregate (the controller fills the missing fields from the current position)"
    nums = _numbers(items, POSE_KEYS, fidx)
    if nums is None:
        return None, "pose fields that are not numbers"
    S, T = _st(items)
    flags = cv.kuka_status_flags(S) if S is not None else None
    return CARTESIAN, nums, flags, T


def is_public(dat: Path) -> bool:
    """A data list declared ``DEFDAT name PUBLIC``: its ``DECL GLOBAL`` data are seen by every ``.src``."""
    try:
        text = read_source(dat).text
    except InputError:
        return False
    for raw in text.splitlines():
        code = strip_comment(raw, ";").strip()
        if re.match(r"^DEFDAT\b", code, re.IGNORECASE):
            return bool(re.search(r"\bPUBLIC\s*$", code, re.IGNORECASE))
    return False


def read(path, config=None, shared=()) -> Program:
    """Read a KRL program (``.src``, its ``.dat``, and ``config`` or the ``$config.dat`` beside it);
    ``shared``: the other ``DEFDAT ... PUBLIC`` data lists of the folder, whose ``DECL GLOBAL`` data
    the ``.src`` may use (corrected in the file that declares them). InputError (file:line) on broken
    syntax."""
    src = read_source(path)
    sources = [src]
    dat = dat_of(Path(path))
    config = config or config_of(Path(path))
    data = _Data()
    if config is not None:
        sources.append(read_source(config, writable=False))
        data.config = len(sources) - 1
        data.scan(sources[-1], data.config)
    for other in shared:
        if dat is not None and Path(other).resolve() == dat.resolve():
            continue
        sources.append(read_source(other))
        data.scan(sources[-1], len(sources) - 1, only_global=True)
    if dat is not None:
        sources.append(read_source(dat))
        data.scan(sources[-1], len(sources) - 1)
        codes = [strip_comment(x, ";").strip().upper() for x in sources[-1].text.splitlines()]
        opened = [k for k, c in enumerate(codes, 1) if re.match(r"^DEFDAT\b", c)]
        if opened and not any(re.match(r"^ENDDAT\b", c) for c in codes):
            raise InputError(sources[-1].path, "DEFDAT without ENDDAT", opened[0], None)
    data.scan(src, 0)
    text = src.text
    # a variable the program assigns (g = $POS_ACT, g.X = g.X + 10) holds a run-time value, not its DECL's
    for k, raw in enumerate(text.splitlines(), 1):
        ma = ASSIGNED_RE.match(strip_comment(raw, ";"))
        if ma and not re.match(r"^\s*DECL\b", raw, re.IGNORECASE):
            data.assigned.setdefault(ma.group(1).upper(), k)
    data.passed = _passed(text)
    targets = []
    tool = Frame(None, "the program never sets $TOOL (nor BAS(#TOOL, n), nor FDAT_ACT)", "$TOOL (not set)")
    base = Frame(None, "the program never sets $BASE (nor BAS(#BASE, n), nor FDAT_ACT)", "$BASE (not set)")
    load = (None, "the program never sets $LOAD (nor BAS(#TOOL, n) with LOAD_DATA of a given $config.dat)")
    external = False
    spline, spline_line = None, 0
    depth_def, def_line = 0, None
    pos = 0
    for lineno, raw in enumerate(text.splitlines(keepends=True), 1):
        here = pos
        pos += len(raw)
        code = strip_comment(raw, ";").rstrip("\r\n")
        s = code.strip()
        if not s or s.startswith("&"):
            continue
        if not balanced(code):
            raise InputError(src.path, "unbalanced brackets or braces", lineno, None)
        up = s.upper()
        if re.match(r"^(GLOBAL\s+)?DEF(FCT)?\b", up):
            depth_def += 1
            def_line = lineno
            continue
        if re.match(r"^END(FCT)?\b", up) and not re.match(r"^END(IF|FOR|WHILE|LOOP|SWITCH|FOLD|DAT)\b", up):
            depth_def -= 1
            if depth_def < 0:
                raise InputError(src.path, "END without DEF", lineno, None)
            continue
        mu = UNSUPPORTED_RE.match(s)
        if mu or spline is not None:
            word = mu.group(1).upper() if mu else ""
            if word in ("SPLINE", "PTP_SPLINE"):
                spline, spline_line = word, lineno
            elif re.match(r"^ENDSPLINE\b", up):
                spline = None
            elif mu or MOTION_RE.match(code) or re.match(r"^SPL\b", up):
                how = (f"a segment of a {spline} block (spline blocks are not read)" if spline else
                       f"{s.split()[0]}: a motion statement this filter does not read")
                targets.append(Target(src.path, lineno, f"{s.split()[0]}@{lineno}", CARTESIAN, PREVIOUS, runtime=how))
            continue
        m = re.match(r"^\$LOAD\s*=\s*(.*)$", s, re.IGNORECASE)
        if m:
            load = _load_stmt(m.group(1), text, here + code.index(m.group(1)), src.path, lineno, data)
            continue
        m = re.match(r"^\$LOAD\.M\s*=\s*(" + NUMBER + r")\s*$", s, re.IGNORECASE)
        if m:
            load = (float(m.group(1)), f"$LOAD.M at line {lineno}")
            continue
        m = re.match(r"^\$TOOL\s*=\s*(.*)$", s, re.IGNORECASE)
        if m:
            tool = _frame_stmt(m.group(1), text, here + code.index(m.group(1)), src.path, lineno, "TOOL", data)
            continue
        m = re.match(r"^\$BASE\s*=\s*(.*)$", s, re.IGNORECASE)
        if m:
            base = _frame_stmt(m.group(1), text, here + code.index(m.group(1)), src.path, lineno, "BASE", data)
            continue
        m = re.match(r"^BAS\s*\(\s*#(TOOL|BASE)\s*,\s*(\d+)\s*\)", s, re.IGNORECASE)
        if m:
            fr = _numbered(m.group(1).upper(), int(m.group(2)), data)
            if m.group(1).upper() == "TOOL":
                tool = fr
                load = _load_data(int(m.group(2)), data, f"BAS(#TOOL, {m.group(2)})")
            else:
                base = fr
            continue
        m = re.match(r"^FDAT_ACT\s*=\s*([A-Za-z_][\w]*)\s*$", s, re.IGNORECASE)
        if m:
            d = data.decls.get(m.group(1).upper())
            if d is None or d[0] != "FDAT":
                # declared elsewhere (the controller's $config.dat, e.g. FHOME): its tool and base are unknown
                # here, so a Cartesian motion after it takes --tool / --base or is named; a joint motion is not
                why = f"FDAT_ACT = {m.group(1)}: no DECL FDAT {m.group(1)} in the program or the .dat given"
                tool = Frame(None, why, f"{m.group(1)}.TOOL_NO")
                base = Frame(None, why, f"{m.group(1)}.BASE_NO")
                continue
            items = d[3]
            if "TOOL_NO" in items:
                tool = _numbered("TOOL", int(float(items["TOOL_NO"][0])), data)
                load = _load_data(int(float(items["TOOL_NO"][0])), data, f"FDAT_ACT = {m.group(1)}")
            if "BASE_NO" in items:
                base = _numbered("BASE", int(float(items["BASE_NO"][0])), data)
            external = items.get("IPO_FRAME", ("#BASE",))[0].strip().upper() == "#TCP"
            continue
        m = MOTION_RE.match(code)
        if not m:
            continue
        word = m.group(1).upper()
        rest = m.group(2)
        rest_at = here + m.start(2)
        if word.endswith("_REL"):
            targets.append(Target(src.path, lineno, f"{word}@{lineno}", CARTESIAN, runtime=f"a relative move ({word})",
                                  extra={"payload": load}))
            continue
        with_parts = re.split(r"\bWITH\b", rest, maxsplit=1, flags=re.IGNORECASE)
        rest_main = with_parts[0]
        if len(with_parts) > 1:            # KSS 8 inline forms: $TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO)
            for which, pat in (("TOOL", r"\$TOOL\s*=\s*STOOL2\s*\(\s*([A-Za-z_]\w*)\s*\)"),
                               ("BASE", r"\$BASE\s*=\s*SBASE\s*\(\s*([A-Za-z_]\w*)\s*\.\s*BASE_NO\s*\)")):
                mw = re.search(pat, with_parts[1], re.IGNORECASE)
                if not mw:
                    continue
                d = data.decls.get(mw.group(1).upper())
                key = f"{which}_NO"
                if d is None or d[0] != "FDAT" or key not in d[3]:
                    raise InputError(src.path, f"{word} ... WITH: no DECL FDAT {mw.group(1)} with {key} in the .src or "
                                     ".dat", lineno, None)
                fr = _numbered(which, int(float(d[3][key][0])), data)
                if which == "TOOL":
                    tool = fr
                    load = _load_data(int(float(d[3][key][0])), data, f"{word} ... WITH $TOOL = STOOL2({mw.group(1)})")
                else:
                    base = fr
        rest_main = re.sub(r"\s+(C_PTP|C_DIS|C_VEL|C_ORI|C_SPL)(\s+C_\w+)*\s*$", "", rest_main, flags=re.IGNORECASE)
        parts = split_top(rest_main)
        if word in ("CIRC", "SCIRC"):
            if len(parts) < 2:
                raise InputError(src.path, f"{word} needs an auxiliary point and a target", lineno, None)
            parts = parts[:2]
        else:
            parts = parts[:1]
        for off, expr in parts:
            t = _motion_target(expr, rest_at + off, text, data, src.path, lineno, word)
            t.tool, t.base = tool, base
            t.extra["payload"] = load
            if external and t.kind == CARTESIAN and not t.runtime:
                t.runtime = "IPO_FRAME #TCP: a stationary tool (the roles of $TOOL and $BASE are swapped)"
            targets.append(t)
    if depth_def > 0:
        raise InputError(src.path, f"DEF at line {def_line} has no END", def_line, None)
    if spline is not None:
        raise InputError(src.path, f"{spline} without ENDSPLINE", spline_line, None)
    return Program("krl", sources, targets)


def _numbered(which: str, n: int, data=None) -> Frame:
    """Tool or base number n: 0 is the flange / the robot's base; n is TOOL_DATA[n] / BASE_DATA[n] of a
    given $config.dat, else unknown (``--tool`` / ``--base``)."""
    if n == 0:
        return Frame(np.eye(4), "", f"{which} 0")
    name = "TOOL_DATA" if which == "TOOL" else "BASE_DATA"
    got = data.numbered.get((name, n)) if data is not None else None
    if got is not None and set(POSE_KEYS) <= set(got[0]) and all(re.fullmatch(NUMBER, got[0][k][0].strip())
                                                                  for k in POSE_KEYS):
        v = [float(got[0][k][0]) for k in POSE_KEYS]
        return Frame(cv.homogeneous(cv.kuka_matrix(*v[3:]), v[:3]), "", f"{name}[{n}]")
    return Frame(None, f"{which.lower()} {n} is {name}[{n}] of the controller's $config.dat, not in the program",
                 f"{name}[{n}]")


def _load_data(n: int, data, how: str):
    """(kg, where from) of LOAD_DATA[n] of a given $config.dat; (None, why) when unknown (M -1: the
    controller's default load, not a stated mass)."""
    got = data.numbered.get(("LOAD_DATA", n))
    if got is None:
        return None, f"{how}: LOAD_DATA[{n}] is in the controller's $config.dat, which was not given"
    m = got[0].get("M")
    if m is None or not re.fullmatch(NUMBER, m[0].strip()) or float(m[0]) < 0:
        return None, f"{how}: LOAD_DATA[{n}] of $config.dat (line {got[2]}) states no mass (M -1 is the default load)"
    return float(m[0]), f"LOAD_DATA[{n}] of $config.dat ({how})"


def _load_stmt(expr, text, at, path, line, data):
    e = expr.strip()
    m = re.match(r"^LOAD_DATA\s*\[\s*(\d+)\s*\]$", e, re.IGNORECASE)
    if m:
        return _load_data(int(m.group(1)), data, f"$LOAD at line {line}")
    if e.startswith("{"):
        _, items, _ = _aggregate(text, at + expr.index("{"), path, line)
        if "M" in items and re.fullmatch(NUMBER, items["M"][0].strip()) and float(items["M"][0]) >= 0:
            return float(items["M"][0]), f"$LOAD at line {line}"
    return None, f"$LOAD = {e} at line {line} states no mass the filter can read"


def _frame_stmt(expr, text, at, path, line, which, data=None):
    e = expr.strip()
    m = re.match(r"^(TOOL_DATA|BASE_DATA)\s*\[\s*(\d+)\s*\]$", e, re.IGNORECASE)
    if m:
        return _numbered(which, int(m.group(2)), data)
    if e.upper() == "$NULLFRAME":
        return Frame(np.eye(4), "", "$NULLFRAME")
    if e.startswith("{"):
        _, items, _ = _aggregate(text, at + expr.index("{"), path, line)
        if not set(POSE_KEYS) <= set(items):
            return Frame(None, f"${which} is set from a partial frame", f"${which} at line {line}")
        v = [float(items[k][0]) for k in POSE_KEYS]
        return Frame(cv.homogeneous(cv.kuka_matrix(*v[3:]), v[:3]), "", f"${which} at line {line}")
    return Frame(None, f"${which} = {e} is computed at run time", f"${which} = {e}")


def _motion_target(expr, at, text, data, path, line, word) -> Target:
    branch = CONFIG if word in ("PTP", "SPTP") else PREVIOUS
    e = expr.strip()
    lead = at + (len(expr) - len(expr.lstrip()))
    if not e:
        raise InputError(path, f"{word} without a target", line, None)
    if e.startswith("{"):
        end, items, prefix = _aggregate(text, lead, path, line)
        if text[end:at + len(expr)].strip():
            return Target(path, line, f"<inline>@{line}", CARTESIAN, branch,
                          runtime=f"a target computed at run time ({e})")
        kind, *rest = _target_of(items, prefix, 0)
        if kind is None:
            return Target(path, line, f"<inline>@{line}", CARTESIAN, branch, runtime=rest[0])
        nums, flags, turn = rest
        return Target(path, line, f"<inline>@{line}", kind, branch, nums, flags, turn, decl=(0, lead))
    if ":" in e:
        return Target(path, line, e, CARTESIAN, branch, runtime=f"a geometric operator ({e}) computed at run time")
    if not re.fullmatch(r"[A-Za-z_$][\w$]*", e):
        return Target(path, line, e, CARTESIAN, branch, runtime=f"a target computed at run time ({e})")
    if e.startswith("$"):
        if e.upper().startswith("$AXIS"):
            # $AXIS_ACT, $AXIS_HOME, $AXIS_RET...: an E6AXIS, joint angles the controller holds
            return Target(path, line, e, JOINT, branch, runtime=f"the system variable {e} (joint angles the controller holds)")
        return Target(path, line, e, CARTESIAN, branch, runtime=f"the system variable {e} (the robot's current position)")
    if e.upper() in data.assigned:
        return Target(path, line, e, CARTESIAN, branch,
                      runtime=f"{e} is assigned by the program (line {data.assigned[e.upper()]}): its value is the run "
                              "time's, not its declaration's")
    if e.upper() in data.passed:
        at_line, callee = data.passed[e.upper()]
        return Target(path, line, e, CARTESIAN, branch,
                      runtime=f"{e} is passed to {callee}() (line {at_line}), which may write it (a KRL parameter is "
                              ":OUT unless declared :IN): its value is the run time's, not its declaration's")
    d = data.decls.get(e.upper())
    if d is None:
        return Target(path, line, e, CARTESIAN, branch,
                      runtime=f"{e} is declared outside the program (not in the .src or its .dat; e.g. $config.dat)")
    dtype, fidx, brace, items, dline, name = d
    if items is None:
        return Target(path, line, name, CARTESIAN, branch, runtime=f"{name} is declared without a value (line {dline})")
    if fidx == data.config:
        return Target(path, line, name, CARTESIAN, branch, runtime=f"{name} is declared in the controller's $config.dat "
                      "(shared by every program; not rewritten)")
    if dtype in ("FDAT", "FRAME"):
        if dtype == "FDAT":
            raise InputError(path, f"{word} {e}: {e} is FDAT data, not a position", line, None)
    kind, *rest = _target_of(items, "", fidx, dtype)
    if kind is None:
        return Target(path, line, name, CARTESIAN, branch, runtime=rest[0], decl=(fidx, brace))
    nums, flags, turn = rest
    return Target(path, line, name, kind, branch, nums, flags, turn, decl=(fidx, brace))
