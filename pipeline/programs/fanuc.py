"""FANUC TP, ASCII ``.ls`` (contract section 11).

Read: the ``/MN`` motion lines ``J``, ``L`` and ``C`` (with its continuation line ``:  P[j] ...``) to
``P[n]`` and the group-1 data of their ``/POS`` entries: Cartesian ``X Y Z W P R`` with
``CONFIG : 'F|N U|D T|B, t1, t2, t3'`` (t1, t2, t3 the turns of joints 1, 4 and 6: decision; the word is
the pendant's language's: German ``KONFIG``), or joint
``J1 .. J6`` (the robot.toml's joint angles: no J2/J3 interaction is applied: decision). Group 1 is
the robot (decision); an entry of other groups only (a positioner, a rail) is named and left as
given, and the other groups of an entry are never rewritten. A ``J`` move
goes to the branch its CONFIG names; ``L`` and ``C`` keep the branch of the point before. ``UF : 0``
is the robot's base frame and ``UT : 0`` the faceplate (FANUC's mechanical interface frame, no tool:
:mod:`pipeline.programs.flanges`); another user frame, and every other ``UT`` (a tool number, not in
the program), is ``--base`` / ``--tool``. New numbers are right-aligned in their field as the TP writes them.

Left as given and named: ``PR[n]`` targets, ``P[R[n]]``, a ``P[n]`` without a ``/POS`` entry, the
``Offset``, ``Tool_Offset`` (German ``WKZ_Offset``), ``VOFFSET`` and ``INC`` options, ``COORD``
(coordinated motion: the point is in a frame a positioner moves), a Remote TCP point (``RX .. RR``: a
stationary tool), a point never taught (``X = ********``). An instruction whose line number is left
out (``:J P[1] 100% FINE ;``) is read as a numbered one; ``/MN`` lines of other forms (``------ ;``)
are kept. The payload is a controller schedule
(``PAYLOAD[n]``), never in the program: ``--payload``. Refused (file:line): a file without ``/PROG``
or ``/END``, a numbered ``/MN`` line without its ``;``, a ``/POS`` entry without its ``};``.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import InputError
from . import conventions as cv
from .model import CARTESIAN, CONFIG, JOINT, PREVIOUS, Frame, Program, Target
from .text import NUMBER, Number, read_source

MN_LINE = re.compile(r"^\s*\d*\s*:(.*);\s*$")          # the line number may be left out (':J P[1] ... ;')
MOTION = re.compile(r"^\s*([JLC])\s+(P|PR)\[\s*(R\[)?\s*(\d+)\s*(?::[^\]]*)?\]", re.IGNORECASE)
CIRC_FIRST = re.compile(r"^\s*\d+\s*:\s*C\s+P\[[^\]]*\]\s*$", re.IGNORECASE)
CIRC_SECOND = re.compile(r"^\s*:\s*(P|PR)\[\s*(\d+)\s*(?::[^\]]*)?\](.*);\s*$", re.IGNORECASE)
OFFSET_OPT = re.compile(r"\b(Offset|Tool_Offset|WKZ_Offset|VOFFSET|INC)\b", re.IGNORECASE)
#: coordinated motion: the point is in a frame the leader group (a positioner) moves
COORD_OPT = re.compile(r"\bCOORD\b", re.IGNORECASE)
#: group 1's configuration ``CONFIG : 'N U T, 0, 0, 0'``, whatever word the pendant's language gives it
CONFIG_FIELD = re.compile(r"[^\s,:']+\s*:\s*'([^']*)'")
POS_HEAD = re.compile(r"^\s*P\[\s*(\d+)\s*(?::\s*\"[^\"]*\")?\s*\]\s*\{\s*$")
FIELD = re.compile(r"\b(X|Y|Z|W|P|R|J[1-6])\s*=(\s*)(" + NUMBER + r")\s*(mm|deg)")
#: a point taught with Remote TCP (the tool stands still, the robot carries the part): RX .. RR
REMOTE_FIELD = re.compile(r"\bR[XYZWPR]\s*=\s*" + NUMBER + r"\s*(mm|deg)")


class _Pos:
    def __init__(self):
        self.entries = {}

    def parse(self, src, lines, offsets, start):
        k = start
        while k < len(lines):
            raw = lines[k]
            if raw.strip().upper().startswith("/END"):
                return k
            m = POS_HEAD.match(raw.rstrip("\r\n"))
            if not m:
                if raw.strip():
                    raise InputError(src.path, f"not a /POS entry: '{raw.strip()[:40]}' (expected P[n]{{)", k + 1, None)
                k += 1
                continue
            head = k
            body = []
            k += 1
            while k < len(lines) and not lines[k].strip().startswith("};"):
                if POS_HEAD.match(lines[k].rstrip("\r\n")) or lines[k].strip().upper().startswith("/END"):
                    break
                body.append(k)
                k += 1
            if k >= len(lines) or not lines[k].strip().startswith("};"):
                raise InputError(src.path, f"P[{m.group(1)}]: the /POS entry has no '}};'", head + 1, None)
            self.entries[int(m.group(1))] = self._entry(src, lines, offsets, head, body)
            k += 1
        raise InputError(src.path, "no /END", len(lines), None)

    @staticmethod
    def _entry(src, lines, offsets, head, body):
        gp1, groups = [], []
        in_gp1 = False
        for i in body:
            s = lines[i]
            mg = re.match(r"^\s*GP(\d+)\s*:", s)
            if mg:
                groups.append(int(mg.group(1)))
            if re.match(r"^\s*GP1\s*:", s):
                in_gp1 = True
                continue
            if mg:
                in_gp1 = False
            if in_gp1:
                gp1.append(i)
        info = {"line": head + 1, "uf": None, "ut": None, "config": None, "fields": {}, "groups": groups,
                "remote": False, "untaught": False}
        for i in gp1:
            s = lines[i]
            m = re.search(r"\bUF\s*:\s*(\d+)", s)
            if m:
                info["uf"] = int(m.group(1))
            m = re.search(r"\bUT\s*:\s*(\d+)", s)
            if m:
                info["ut"] = int(m.group(1))
            # the configuration is the one quoted field of group 1; its word is the pendant's language
            # (CONFIG; a controller set to German writes KONFIG)
            m = CONFIG_FIELD.search(s)
            if m:
                info["config"] = (m.group(1), i + 1)
            if REMOTE_FIELD.search(s):
                info["remote"] = True
            if re.search(r"\b(X|J1)\s*=\s*\*+", s):
                info["untaught"] = True      # the pendant writes ******** for a position never recorded
            for f in FIELD.finditer(s):
                lead = len(f.group(2))
                a = offsets[i] + f.start(3)
                info["fields"][f.group(1).upper()] = Number(0, a - lead, a + len(f.group(3)), f.group(3), lead)
        return info


def read(path) -> Program:
    """Read a FANUC ``.ls``; InputError (file:line) on broken syntax."""
    src = read_source(path)
    lines = src.text.splitlines(keepends=True)
    offsets = np.cumsum([0] + [len(x) for x in lines]).tolist()
    first = next((i for i, s in enumerate(lines) if s.strip()), None)
    if first is None or not lines[first].strip().upper().startswith("/PROG"):
        raise InputError(src.path, "not a FANUC TP program: the first line must be /PROG name", (first or 0) + 1, None)
    mn = next((i for i, s in enumerate(lines) if s.strip().upper().startswith("/MN")), None)
    if mn is None:
        raise InputError(src.path, "no /MN section", len(lines), None)
    pos_at = next((i for i, s in enumerate(lines) if s.strip().upper().startswith("/POS")), None)
    end_at = next((i for i, s in enumerate(lines) if s.strip().upper().startswith("/END")), None)
    if end_at is None:
        raise InputError(src.path, "no /END", len(lines), None)
    pos = _Pos()
    if pos_at is not None:
        pos.parse(src, lines, offsets, pos_at + 1)
    motions, payloads = [], []
    k = mn + 1
    stop = pos_at if pos_at is not None else end_at
    while k < stop:
        raw = lines[k].rstrip("\r\n")
        if not raw.strip():
            k += 1
            continue
        if re.match(r"^\s*\d+\s*:", raw) and not raw.rstrip().endswith(";") and not CIRC_FIRST.match(raw):
            # a long instruction the TP wrote on several lines: continuation lines start with ':'
            j = k + 1
            while j < stop and re.match(r"^\s*:", lines[j]) and not lines[j - 1].rstrip().endswith(";"):
                j += 1
            if j == k + 1 or not lines[j - 1].rstrip().endswith(";"):
                raise InputError(src.path, f"not an /MN instruction line: '{raw.strip()[:40]}' (expected 'n: ... ;'); "
                                 "an instruction without its ';'", k + 1, None)
            raw = raw + " " + " ".join(re.sub(r"^\s*:", "", x.rstrip("\r\n")) for x in lines[k + 1:j])
            m = MN_LINE.match(raw)
            mm = MOTION.match(m.group(1))
            if mm:
                motions.append((k + 1, mm.group(1).upper(), mm.group(2), mm.group(3), int(mm.group(4)),
                                m.group(1)[mm.end():]))
            k = j
            continue
        if CIRC_FIRST.match(raw):
            if k + 1 >= stop or not CIRC_SECOND.match(lines[k + 1].rstrip("\r\n")):
                raise InputError(src.path, "C (circular) needs its second line ':  P[j] speed term ;'", k + 2, None)
            m1 = MOTION.match(raw.split(":", 1)[1])
            m2 = CIRC_SECOND.match(lines[k + 1].rstrip("\r\n"))
            motions.append((k + 1, "C", m1.group(2), m1.group(3), int(m1.group(4)), m2.group(3)))
            motions.append((k + 2, "C", m2.group(1), None, int(m2.group(2)), m2.group(3)))
            k += 2
            continue
        m = MN_LINE.match(raw)
        if not m:
            if re.match(r"^\s*\d+\s*:", raw):
                raise InputError(src.path, f"not an /MN instruction line: '{raw.strip()[:40]}' (expected 'n: ... ;'); "
                                 "an instruction without its ';'", k + 1, None)
            k += 1                       # a line of another form ('------ ;', ':' lines without their ';'): kept
            continue
        if re.match(r"^\s*PAYLOAD\s*\[", m.group(1), re.IGNORECASE):
            payloads.append((k + 1, m.group(1).strip()))
        mm = MOTION.match(m.group(1))
        if mm:
            motions.append((k + 1, mm.group(1).upper(), mm.group(2), mm.group(3), int(mm.group(4)),
                            m.group(1)[mm.end():]))
        k += 1
    targets = []
    for line, word, reg, indirect, n, opts in motions:
        branch = CONFIG if word == "J" else PREVIOUS
        if reg.upper() == "PR":
            targets.append(Target(src.path, line, f"PR[{n}]", CARTESIAN, branch,
                                  runtime="a position register PR[] (its value is set at run time)"))
            continue
        if indirect:
            targets.append(Target(src.path, line, f"P[R[{n}]]", CARTESIAN, branch,
                                  runtime="an indirect point P[R[]] (chosen at run time)"))
            continue
        name = f"P[{n}]"
        e = pos.entries.get(n)
        if e is None:
            targets.append(Target(src.path, line, name, CARTESIAN, branch, runtime=f"{name} has no /POS entry (its "
                                  "value is not in the program)"))
            continue
        f = e["fields"]
        if 1 not in e["groups"] and e["groups"]:
            targets.append(Target(src.path, line, name, JOINT, branch, runtime="moves group "
                                  f"{', '.join(map(str, e['groups']))} only, not the robot (group 1)"))
            continue
        mo = OFFSET_OPT.search(opts)
        if e["untaught"]:
            targets.append(Target(src.path, line, name, CARTESIAN, branch, runtime=f"{name} is not taught (its /POS "
                                  "values are '********': the controller has no position for it)"))
            continue
        if e["remote"]:
            targets.append(Target(src.path, line, name, CARTESIAN, branch,
                                  runtime=f"{name} is a Remote TCP point (RX .. RR: the tool stands still, the robot "
                                  "carries the part: a stationary tool)"))
            continue
        if all(j in f for j in ("J1", "J2", "J3", "J4", "J5", "J6")):
            t = Target(src.path, line, name, JOINT, branch, [f[j] for j in ("J1", "J2", "J3", "J4", "J5", "J6")],
                       decl=(0, n))
        elif all(c in f for c in "XYZWPR"):
            flags = turn = None
            if e["config"] is not None:
                cfg, cline = e["config"]
                parts = [p.strip() for p in cfg.split(",")]
                try:
                    flags = cv.fanuc_letter_flags(parts[0])
                    turn = tuple(int(p) for p in parts[1:4]) if len(parts) >= 4 else None
                except ValueError as exc:
                    raise InputError(src.path, f"{name}: CONFIG '{cfg}': {exc}", cline, None) from None
            t = Target(src.path, line, name, CARTESIAN, branch, [f[c] for c in "XYZWPR"], flags, turn, decl=(0, n))
            uf, ut = e["uf"], e["ut"]
            t.base = Frame(np.eye(4), "", "UF 0") if uf == 0 else Frame(
                None, f"user frame UF : {uf} is UFRAME[{uf}] of the controller, not in the program", f"UFRAME[{uf}]")
            # UT : 0 is the faceplate itself (no tool: pipeline.programs.flanges gives its frame on the robot)
            t.tool = Frame(np.eye(4), "", "UT 0") if ut == 0 else Frame(
                None, f"tool UT : {ut} is UTOOL[{ut}] of the controller, not in the program", f"UTOOL[{ut}]")
        else:
            raise InputError(src.path, f"{name}: group 1 has neither X, Y, Z, W, P, R nor J1 .. J6", e["line"], None)
        if mo:
            t.runtime = f"the {mo.group(1)} option (an offset applied at run time)"
        elif COORD_OPT.search(opts) and t.kind == CARTESIAN:
            t.runtime = ("COORD: coordinated motion, the point is in a frame the leader group (a positioner) "
                         "moves: the robot's joints depend on the positioner's axes too")
        before = [pl for pl in payloads if pl[0] < line]
        t.extra["payload"] = (None, f"{before[-1][1]} at line {before[-1][0]}: a payload schedule of the controller, "
                              "not in the program") if before else (None, "a FANUC program states no payload")
        targets.append(t)
    return Program("fanuc", [src], targets)
