r"""ABB RAPID: a program's modules, ``.mod``, ``.prg``, ``.sys``, ``.modx`` (contract section 11).

The modules of a program are read together, as the controller loads them into one task: a target,
tool, work object or load declared in any of them is known in all (``LOCAL`` ones are not told
apart: decision). A module is split into statements as the controller does: a statement runs to its
``;`` over any number of lines; ``MODULE``, ``PROC``/``FUNC``/``TRAP`` headers (their parameter
lists over several lines too), ``IF ... THEN``, ``WHILE ... DO``, ``FOR ... DO``, ``TEST``/``CASE``,
labels and the ``END...`` words are statements of their own; ``!`` starts a comment; the ``%%%``
header of old ``.prg``/``.sys`` files is not read. Keywords are case-insensitive.

Read: ``CONST``/``PERS``/``VAR`` (``LOCAL``, ``TASK``) declarations of ``robtarget``, ``jointtarget``,
``tooldata``, ``wobjdata`` and ``loaddata``; the motions ``MoveJ``, ``MoveL``, ``MoveC``
(Cartesian) and ``MoveAbsJ`` (joint), and the instructions that move like them to a ToPoint given
first (``TriggJ``/``TriggL``/``TriggC``, ``MoveJDO``/``MoveLDO``/``MoveCDO``, ``...AO``, ``...GO``,
``...Sync``, ``ArcL``/``ArcC`` and their ``Start``/``End`` forms, ``SpotL``/``SpotJ``, ``CapL``/``CapC``,
``DispL``/``DispC``, ``PaintL``/``PaintC``), to a declared name or an inline literal, with their tool
(the standard instructions: the argument after Speed and Zone; the others: the first argument that
is a declared tool, else the last positional one) and ``\WObj``; ``ConfJ``; ``GripLoad``.
A J-type move goes to the branch its ``cf1 cf4 cf6 cfx`` name (``ConfJ \Off``: the branch of the
point before, nearest its joints); linear and circular moves keep the branch of the point before.
Tool ``tool0`` is the flange and work object ``wobj0`` (or no ``\WObj``) the robot's base frame; a
tool or work object declared in a module is used as declared (``uframe . oframe``); one that is not:
``--tool`` / ``--base``. The payload of a motion is its tool's load mass plus the ``GripLoad`` in
force (the one before it in the text: decision), or ``\TLoad``'s mass; with ``tool0`` and no
``GripLoad`` the program states none.

A call of any other name (``moveToHome;``, a procedure of the program or of another module) is a
call, passed through. Left as given and named: ``Offs``, ``RelTool``, ``CRobT``, ``CalcRobT`` and any
other function at the motion, ``*`` (a point stored in the instruction), indexed arrays, a name
declared in none of the modules or declared without a value (a parameter, a ``VAR`` set at run
time), ``\Corr``, a stationary tool (``robhold`` FALSE) or a moving work object, a Cartesian target that sets an
external axis (a track or a positioner: ``eax_a`` .. ``eax_f`` not 9E9), and the motions not
read (``SearchL``, ``SearchC``, ``MoveExtJ``, ...). Refused (file:line): a statement without its
``;``, unbalanced brackets, a robtarget or jointtarget with the wrong number of values, ``MODULE``
without ``ENDMODULE``.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import InputError
from ..core.files import read_bytes_input
from . import conventions as cv
from .model import CARTESIAN, CONFIG, JOINT, PREVIOUS, Frame, Program, Target
from .text import NUMBER, Number, Source, balanced, decode_program, read_source, split_top

DECL_RE = re.compile(r"(?:(?:LOCAL|TASK)\s+)*(CONST|PERS|VAR)\s+(robtarget|jointtarget|tooldata|wobjdata|loaddata)\s+"
                     r"([A-Za-z_]\w*)\s*(\{[^}]*\})?\s*(?::=\s*(.*))?$", re.IGNORECASE | re.DOTALL)
#: motions read: instruction -> (kind, points before the speed, J-type, standard argument order)
_ONE = ("TriggL", "MoveLDO", "MoveLAO", "MoveLGO", "MoveLSync", "TriggLIOs", "ArcL", "ArcLStart", "ArcLEnd", "ArcL1",
        "ArcL2", "SpotL", "SpotML", "CapL", "DispL", "PaintL")
_ONE_J = ("TriggJ", "MoveJDO", "MoveJAO", "MoveJGO", "MoveJSync", "TriggJIOs", "SpotJ", "SpotMJ")
_TWO = ("TriggC", "MoveCDO", "MoveCAO", "MoveCGO", "MoveCSync", "ArcC", "ArcCStart", "ArcCEnd", "ArcC1", "ArcC2", "CapC",
        "DispC", "PaintC")
MOTIONS = {"MOVEJ": (CARTESIAN, 1, True, True), "MOVEL": (CARTESIAN, 1, False, True),
           "MOVEC": (CARTESIAN, 2, False, True), "MOVEABSJ": (JOINT, 1, False, True),
           **{w.upper(): (CARTESIAN, 1, False, False) for w in _ONE},
           **{w.upper(): (CARTESIAN, 1, True, False) for w in _ONE_J},
           **{w.upper(): (CARTESIAN, 2, False, False) for w in _TWO}}
#: motion instructions that are not read: named and left as given
NOT_READ = {w.upper() for w in ("SearchL", "SearchC", "SearchJ", "SearchExtJ", "MoveExtJ", "ArcMoveExtJ", "ContactL",
                                "PathRecMoveBwd", "PathRecMoveFwd", "StepBwdPath", "MoveLStart", "CSSDeactMoveL")}
HEADER_LINE = re.compile(r"(?:(?:LOCAL|SYSMODULE)\s+)*(MODULE|PROC|FUNC|TRAP|RECORD|ALIAS)\b|(TEST|ERROR)\b", re.IGNORECASE)
HEADER_WORD = re.compile(r"(ENDMODULE|ENDPROC|ENDFUNC|ENDTRAP|ENDRECORD|ENDIF|ENDWHILE|ENDFOR|ENDTEST|ELSE|BACKWARD|"
                         r"UNDO)\b(?!\s*IF)", re.IGNORECASE)
UNTIL_WORD = {"IF": "THEN", "ELSEIF": "THEN", "WHILE": "DO", "FOR": "DO"}
ENDS_A_STATEMENT = re.compile(r"(ENDMODULE|ENDPROC|ENDFUNC|ENDTRAP|ENDIF|ENDWHILE|ENDFOR|ENDTEST|PROC|FUNC|TRAP|MODULE|"
                              r"ELSE|ELSEIF)\b", re.IGNORECASE)
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
    extax = _nums(g[3], 6, "robtarget extax", path, line)
    cf = [int(float(c.text)) for c in conf]
    return trans + rot, cv.abb_cfx_flags(cf[3]), (cf[0], cf[1], cf[2]), _external_axes(extax)


#: An external axis value at or above this is RAPID's "not used" (9E9)
EXTAX_UNUSED = 8.9e9


def _external_axes(extax) -> str:
    """Words on the external axes a robtarget sets (``eax_a = 1200``), '' when none (all 9E9)."""
    used = [(letter, float(x.text)) for letter, x in zip("abcdef", extax) if abs(float(x.text)) < EXTAX_UNUSED]
    return ", ".join(f"eax_{a} = {v:g}" for a, v in used)


def _extax_reason(extax: str) -> str:
    """Why a Cartesian target that sets external axes is left as given."""
    return (f"it sets an external axis ({extax}): a track carrying the robot or a positioner carrying the work "
            "moves with it, and where that puts the target relative to the robot is not in the model")


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


def _mass(v, what, path, line) -> float:
    """The mass (kg) of a loaddata literal ``[mass,[cog],[aom],ix,iy,iz]`` (parsed by :func:`_nested`)."""
    try:
        return float(v[0])
    except (ValueError, TypeError, IndexError):
        raise InputError(path, f"{what}: expected [mass,[x,y,z],[q1,q2,q3,q4],ix,iy,iz]", line, None) from None


def _tooldata(lit, path, line, name):
    """The tool's frame and its load mass (kg, None when the tool holds none: robhold FALSE)."""
    g = _nested(lit, path, line)
    if not isinstance(g, list) or len(g) < 2 or not isinstance(g[1], list):
        raise InputError(path, f"tooldata {name}: expected [robhold,[[x,y,z],[q1,q2,q3,q4]],[load]]", line, None)
    if str(g[0]).upper() != "TRUE":
        return Frame(None, f"tool {name} is a stationary tool (robhold FALSE)", name, moving=True), None
    mass = _mass(g[2], f"tooldata {name} tload", path, line) if len(g) > 2 and isinstance(g[2], list) else None
    return Frame(_pose_list(g[1], f"tooldata {name} tframe", path, line), "", name), mass


def _wobjdata(lit, path, line, name):
    g = _nested(lit, path, line)
    if not isinstance(g, list) or len(g) != 5:
        raise InputError(path, f"wobjdata {name}: expected [robhold,ufprog,ufmec,uframe,oframe]", line, None)
    if str(g[0]).upper() != "FALSE" or str(g[1]).upper() != "TRUE" or str(g[2]).strip('"').strip():
        return Frame(None, f"work object {name} moves (robhold TRUE, ufprog FALSE or a mechanical unit)", name,
                     moving=True)
    U = _pose_list(g[3], f"wobjdata {name} uframe", path, line)
    O = _pose_list(g[4], f"wobjdata {name} oframe", path, line)
    return Frame(U @ O, "", name)


def _mask_header(text: str, masked: str) -> str:
    """Blank the ``%%%`` ... ``%%%`` header of old ``.prg`` / ``.sys`` files (VERSION, LANGUAGE)."""
    m = re.match(r"\s*%%%[^\n]*\n.*?%%%[^\n]*", masked, re.DOTALL)
    if not m:
        return masked
    return re.sub(r"[^\r\n]", " ", masked[:m.end()]) + masked[m.end():]


def _scan_to(masked: str, k: int, stop) -> int:
    """First position at or after ``k`` where ``stop(j)`` holds at bracket depth 0 (len at the end)."""
    depth = 0
    for j in range(k, len(masked)):
        ch = masked[j]
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif depth <= 0 and stop(j):
            return j
    return len(masked)


def statements(src, masked):
    """A module's statements as the controller reads them: (start, end, masked text, line).

    A statement ends at its ``;`` (over any number of lines); headers and block words are statements
    of their own (module docstring). InputError (file:line) for a statement without its ``;``
    and for unbalanced brackets.
    """
    out, k, n = [], 0, len(masked)
    word = re.compile(r"[A-Za-z_]\w*")
    while True:
        m = re.compile(r"\S").search(masked, k)
        if not m:
            return out
        k = m.start()
        line = src.line_of(k)
        w = word.match(masked, k)
        up = w.group(0).upper() if w else ""
        if w and HEADER_LINE.match(masked, k):
            j = _scan_to(masked, k, lambda j: masked[j] == "\n")               # to the end of its line
        elif w and HEADER_WORD.fullmatch(up):
            j = w.end()
        elif up in UNTIL_WORD:
            until = UNTIL_WORD[up]
            j = _scan_to(masked, w.end(), lambda j: masked[j] == ";" or (
                masked[j - 1:j].isspace() or masked[j - 1] in ")]}") and re.match(until + r"\b", masked[j:j + 6], re.I))
            if j < n and masked[j] != ";":
                j += len(until)
            elif j < n:
                j += 1
        elif up in ("CASE", "DEFAULT") or (w and re.match(r"\s*:(?!=)", masked[w.end():w.end() + 3]) and up not in
                                           ("CONST", "PERS", "VAR")):
            j = _scan_to(masked, k, lambda j: masked[j] == ":" and masked[j + 1:j + 2] != "=") + 1
        else:
            j = _scan_to(masked, k, lambda j: masked[j] == ";")
            stmt = masked[k:j]
            nxt = re.search(r"\n[ \t]*(?:" + ENDS_A_STATEMENT.pattern + r"|(?:CONST|PERS|VAR|ConfJ|ConfL|"
                            + "|".join(MOTIONS) + r")\b)", stmt, re.IGNORECASE)
            if j >= n or nxt:
                semi = masked.find(";", k)
                if semi >= 0 and not balanced(masked[k:semi]) and (not nxt or semi < k + nxt.start()):
                    # its ';' is there, but a bracket opened before it is not closed: the scan at depth 0 ran on
                    raise InputError(src.path, "unbalanced brackets: a '[' or '(' of the statement is not closed "
                                     "before its ';'", line, None)
                raise InputError(src.path, "statement without its ';'", line, None)
            if not balanced(stmt):
                raise InputError(src.path, "unbalanced brackets", line, None)
            out.append((k, j, stmt, line))
            k = j + 1
            continue
        if not balanced(masked[k:j]):
            raise InputError(src.path, "unbalanced brackets", line, None)
        out.append((k, j, masked[k:j], line))
        k = max(j, k + 1)


#: an assignment statement: a variable or one of its fields on the left of ':='
ASSIGNED_RE = re.compile(r"^\s*([A-Za-z_]\w*)(?:\s*\.\s*\w+)*\s*:=")


class _Declared:
    """What the modules declare, by upper-case name."""

    def __init__(self):
        self.targets, self.procs, self.loads = {}, set(), {}
        self.assigned = {}               # NAME -> (file, line) of the first statement assigning it (or a field)
        self.tools = {"TOOL0": (Frame(np.eye(4), "", "tool0"), 0.0)}
        self.wobjs = {"WOBJ0": Frame(np.eye(4), "", "wobj0")}

    def scan(self, src, fidx, stmts, masked):
        text = src.text                  # tool and work object data: strings matter (ufmec)
        for k, j, stmt, line in stmts:
            mp = re.match(r"(?:LOCAL\s+)?(?:PROC|TRAP)\s+([A-Za-z_]\w*)|(?:LOCAL\s+)?FUNC\s+\w+\s+([A-Za-z_]\w*)", stmt,
                          re.IGNORECASE)
            if mp:
                self.procs.add((mp.group(1) or mp.group(2)).upper())
                continue
            ma = ASSIGNED_RE.match(stmt)
            if ma:                       # jp := CJointT(); p.trans.x := ...: a run-time value, not the DECL's
                self.assigned.setdefault(ma.group(1).upper(), (src.path, line))
                continue
            m = DECL_RE.match(stmt)
            if not m:
                continue
            kind, typ, name, dims, value = m.group(1), m.group(2).lower(), m.group(3), m.group(4), m.group(5)
            key = name.upper()
            if value is None or dims:
                how = "an array" if dims else "declared without a value (set at run time)"
                if typ in ("robtarget", "jointtarget"):
                    self.targets.setdefault(key, (typ, None, line, name, how, src.path))
                elif typ == "tooldata":
                    self.tools.setdefault(key, (Frame(None, f"tool {name} is {how}", name), None))
                elif typ == "wobjdata":
                    self.wobjs.setdefault(key, Frame(None, f"work object {name} is {how}", name))
                continue
            at = k + m.start(5)
            lit = text[at:j]
            if typ in ("robtarget", "jointtarget"):
                lit = masked[at:j]       # comments between the lines of a literal blanked
            if typ == "robtarget":
                self.targets[key] = (typ, _robtarget(lit, at, fidx, src.path, line), line, name, kind.upper(), src.path)
            elif typ == "jointtarget":
                self.targets[key] = (typ, _jointtarget(lit, at, fidx, src.path, line), line, name, kind.upper(),
                                     src.path)
            elif typ == "tooldata":
                self.tools[key] = _tooldata(lit, src.path, line, name)
            elif typ == "wobjdata":
                self.wobjs[key] = _wobjdata(lit, src.path, line, name)
            else:
                self.loads[key] = (_mass(_nested(lit, src.path, line), f"loaddata {name}", src.path, line), name)


def read(path) -> Program:
    """Read one RAPID module (:func:`read_modules` of it)."""
    return read_modules([path])


def _opaque(path) -> Source | None:
    """A module of a folder that is not RAPID text (an encrypted module: binary bytes, or an encoded blob
    without ``MODULE``): its bytes as a :class:`Source` the readers skip, copied as given; else None."""
    data = read_bytes_input(path, "program file", "a program file, not a folder")
    try:
        src = decode_program(data, str(path))
    except InputError:
        return Source(str(path), data.decode("latin-1"))
    return None if re.search(r"(?im)^\s*(?:(?:LOCAL|SYSMODULE)\s+)*MODULE\b", _mask(src.text)) else src


def read_modules(paths) -> Program:
    """Read a RAPID program's modules together; InputError (file:line) on broken syntax.

    Of several modules (a folder), one that is not RAPID text (:func:`_opaque`: an encrypted module the
    controller decodes) is named in ``Program.notes`` and copied byte for byte; its data is not read.
    One module alone is read as text (a binary file: InputError).
    """
    opaque = [_opaque(p) for p in paths] if len(paths) > 1 else [None] * len(paths)
    sources = [o if o is not None else read_source(p) for p, o in zip(paths, opaque)]
    notes = [f"{o.path}: not readable RAPID text (an encrypted module?), copied as given" for o in opaque if o]
    masks, all_stmts = [], []
    decl = _Declared()
    for fidx, src in enumerate(sources):
        if opaque[fidx] is not None:
            masks.append("")
            all_stmts.append([])
            continue
        masked = _mask_header(src.text, _mask(src.text))
        mo = re.search(r"(?im)^\s*MODULE\b", masked)
        if mo and not re.search(r"(?im)^\s*ENDMODULE\b", masked):
            raise InputError(src.path, "MODULE without ENDMODULE", src.line_of(mo.start()), None)
        stmts = statements(src, masked)
        masks.append(masked)
        all_stmts.append(stmts)
        decl.scan(src, fidx, stmts, masked)
    targets = []
    for fidx, (src, stmts, masked) in enumerate(zip(sources, all_stmts, masks)):
        targets += _motions(src, fidx, stmts, decl, masked)
    used = {t.decl for t in targets if t.decl}
    for typ, data, dline, name, how, dpath in decl.targets.values():      # declared, and no motion read goes there
        if data is None:
            continue
        first = data[0] if typ == "jointtarget" else data[0][0]
        if (first.file, first.start) not in used:
            targets.append(Target(dpath, dline, name, JOINT if typ == "jointtarget" else CARTESIAN, PREVIOUS,
                                  runtime="declared, but no motion the filter reads goes to it (an argument of a "
                                  "call, Offs or RelTool, or a motion not read): left as given"))
    return Program("rapid", sources, targets, notes)


def _motions(src, fidx, stmts, decl, masked) -> list:
    text = masked
    targets = []
    conf_j = True
    grip = None                          # (kg, name) of the GripLoad in force
    for k, j, stmt, line in stmts:
        s = stmt.strip()
        lead = k + (len(stmt) - len(stmt.lstrip()))
        mi = re.match(r"IF\b", s, re.IGNORECASE)
        if mi:                           # a compact IF: IF cond instruction;
            inner = [mm for mm in re.finditer(r"(?<![\w.])([A-Za-z_]\w*)\b", s) if mm.group(1).upper() in MOTIONS
                     or mm.group(1).upper() in NOT_READ]
            if not inner:
                continue
            lead += inner[0].start()
            s = s[inner[0].start():]
        w = re.match(r"([A-Za-z_]\w*)", s)
        if not w:
            continue
        up = w.group(1).upper()
        if up == "CONFJ":
            mc = re.match(r"ConfJ\s*\\(On|Off)", s, re.IGNORECASE)
            if mc:
                conf_j = mc.group(1).lower() == "on"
            continue
        if up == "GRIPLOAD":
            name = s[len("GripLoad"):].strip()
            key = name.upper()
            if key == "LOAD0":
                grip = (0.0, "load0")
            elif key in decl.loads:
                grip = decl.loads[key]
            else:
                grip = (None, name)
            continue
        if up in decl.procs and up not in MOTIONS:
            continue
        if up in NOT_READ:
            targets.append(Target(src.path, line, f"{w.group(1)}@{line}", CARTESIAN, PREVIOUS,
                                  runtime=f"{w.group(1)}: a motion instruction this filter does not read"))
            continue
        if up not in MOTIONS:
            continue                     # another instruction or a call of a procedure: passed through
        kind, n_points, jtype, standard = MOTIONS[up]
        word = w.group(1)
        rest = s[w.end():]
        if rest and not re.match(r"\s|\\", rest):
            continue
        args_at = lead + w.end()
        args = text[args_at:j]
        parts = split_top(args)
        while parts and re.match(r"\s*\\(Conc|WObj|ID)\b", parts[0][1], re.IGNORECASE) and ":=" not in parts[0][1]:
            parts = parts[1:]
        wobj = tl = None
        for _, part in parts:
            mw = re.search(r"\\WObj\s*:=\s*([A-Za-z_]\w*)", part, re.IGNORECASE)
            if mw:
                wobj = mw.group(1)
            mt = re.search(r"\\TLoad\s*:=\s*([A-Za-z_]\w*)", part, re.IGNORECASE)
            if mt:
                tl = mt.group(1)
        if len(parts) < n_points + (3 if standard else 1):
            targets.append(Target(src.path, line, f"{word}@{line}", kind, PREVIOUS,
                                  runtime=f"{word}: fewer arguments than a ToPoint, Speed, Zone and Tool"))
            continue
        tool_name, tool, mass = _tool_of(parts, n_points, standard, decl)
        base = decl.wobjs.get((wobj or "wobj0").upper(),
                              Frame(None, f"work object {wobj} is not declared in the program's modules",
                                    wobj or "wobj0"))
        # a tool or work object the program assigns (wobj.oframe := ...): its frame is the run time's
        tool = _assigned_frame(tool, tool_name, "tool", decl)
        base = _assigned_frame(base, wobj or "wobj0", "work object", decl)
        payload = _payload(tool_name, mass, grip, tl, decl)
        corr = re.search(r"\\Corr\b", args, re.IGNORECASE)
        branch = CONFIG if (jtype and conf_j) else PREVIOUS
        for off, expr in parts[:n_points]:
            e = _before_switch(expr)
            t = _motion_target(word, kind, branch, e, args_at + off, fidx, decl, src.path, line)
            t.tool, t.base = tool, base
            t.extra["payload"] = payload
            moving = [f.why for f in (tool, base) if f.moving]
            if moving and not t.runtime and kind == CARTESIAN:
                t.runtime = moving[0]
            if corr and not t.runtime:
                t.runtime = "\\Corr: a path correction added at run time"
            targets.append(t)
    return targets


def _before_switch(expr: str) -> str:
    """``expr`` up to its first optional argument (``p10\\ID:=1`` -> ``p10``) outside parentheses and brackets:
    ``Offs(CRobT(\\Tool:=tool0), 0, 0, 10)`` is kept whole."""
    depth = 0
    for k, ch in enumerate(expr):
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "\\" and depth == 0:
            return expr[:k]
    return expr


def _assigned_frame(frame, name, what, decl):
    """``frame``, or a moving Frame naming where the program assigns ``name`` (or a field of it)."""
    at = decl.assigned.get(name.upper()) if name else None
    if at is None:
        return frame
    return Frame(None, f"{what} {name} is assigned by the program ({at[0]}:{at[1]}): its frame is the run time's, "
                 "not its declaration's", name, moving=True)


def _tool_of(parts, n_points, standard, decl):
    """(name, Frame, load kg or None) of a motion's tool argument."""
    names = [re.split(r"\\", p)[0].strip() for _, p in parts[n_points:]]
    names = [x for x in names if x]
    if standard:
        name = names[2] if len(names) > 2 else ""
    else:
        found = [x for x in names if x.upper() in decl.tools]
        name = found[0] if found else (names[-1] if names else "")
    fr, mass = decl.tools.get(name.upper(), (Frame(None, f"tool {name} is not declared in the program's modules",
                                                   name), None))
    return name, fr, mass


def _payload(tool_name, mass, grip, tload, decl):
    """(kg, where from) of a motion's payload as the program states it; (None, why) when it states none."""
    if tload:
        d = decl.loads.get(tload.upper())
        if d is not None:
            return d[0], f"\\TLoad:={d[1]}"
        return None, f"\\TLoad:={tload} is not declared in the program's modules"
    gkg, gname = grip if grip is not None else (0.0, "")
    if tool_name.upper() == "TOOL0" and not gname:
        return None, "tool0 and no GripLoad: the program states no payload"
    if mass is None or gkg is None:
        return None, f"the load of {gname if gkg is None else tool_name} is not declared in the program's modules"
    where = f"tooldata {tool_name}" + (f" + GripLoad {gname}" if gname and gname.upper() != "LOAD0" else "")
    return mass + gkg, where


def _motion_target(word, kind, branch, expr, at, fidx, decl, path, line) -> Target:
    joint = kind == JOINT
    text_e = expr.strip()
    lead = at + (expr.index(text_e) if text_e else 0)
    e = text_e
    if not e:
        raise InputError(path, f"{word} without a target", line, None)
    if e.startswith("["):
        name = f"<inline>@{line}"
        g = _groups(e, lead, fidx, path, line)
        if any(not isinstance(x, list) or not all(isinstance(i, Number) for i in x) for x in g):
            # [joints, [9E9, ...]]: an aggregate of the program's variables, its value is the run time's
            return Target(path, line, name, kind, branch, runtime=f"a target built at run time from variables ({e[:60]})")
        if joint:
            return Target(path, line, name, JOINT, branch, _jointtarget(e, lead, fidx, path, line), decl=(fidx, lead))
        nums, flags, turn, extax = _robtarget(e, lead, fidx, path, line)
        if extax:
            return Target(path, line, name, kind, branch, runtime=_extax_reason(extax))
        return Target(path, line, name, CARTESIAN, branch, nums, flags, turn, decl=(fidx, lead))
    if e == "*":
        return Target(path, line, "*", kind, branch, runtime="a point stored in the instruction (*)")
    if not re.fullmatch(r"[A-Za-z_]\w*", e):
        return Target(path, line, e, kind, branch, runtime=f"a target computed at run time ({e})")
    if e.upper() in decl.assigned:
        apath, aline = decl.assigned[e.upper()]
        return Target(path, line, e, kind, branch, runtime=f"{e} is assigned by the program ({apath}:{aline}): its "
                      "value is the run time's, not its declaration's")
    d = decl.targets.get(e.upper())
    if d is None:
        return Target(path, line, e, kind, branch, runtime=f"{e} is declared in none of the program's modules (a "
                      "parameter, or a module not given)")
    typ, data, dline, name, how, dpath = d
    if data is None:
        return Target(path, line, name, kind, branch, runtime=f"{name} is {how}")
    if joint != (typ == "jointtarget"):
        return Target(path, line, name, kind, branch, runtime=f"{word} {e}: {e} is a {typ} ({dpath}:{dline})")
    if joint:
        return Target(path, line, name, JOINT, branch, data, decl=(data[0].file, data[0].start))
    nums, flags, turn, extax = data
    if extax:      # its declaration is this motion's (not "declared, and no motion goes there")
        return Target(path, line, name, kind, branch, runtime=_extax_reason(extax), decl=(nums[0].file, nums[0].start))
    return Target(path, line, name, CARTESIAN, branch, nums, flags, turn, decl=(nums[0].file, nums[0].start),
                  extra={"pers": how == "PERS"})
