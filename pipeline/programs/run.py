"""``jointcal correct --program``: a robot program filtered through a fitted robot model (contract section 11).

:func:`filter_with_model` is the whole job between reading the program and writing its files: each
motion's payload (:func:`pipeline.programs.filtering.payloads`), the filter
(:func:`pipeline.programs.filtering.filter_program`), the new texts of the program's files
(:func:`pipeline.programs.text.rewrite`) and the counts the report gives. The command
(``pipeline.cli.deploy``) reads the program, writes the files and the JSON report, and prints.
:func:`played_poses` is ``jointcal simulate measure --program``'s: the poses the nominal controller
commands for the program's motions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.units import REFERENCE_TEMPERATURE_C
from ..correct.robot import OUTSIDE, ModelKinematics
from ..correct.run import outside_region, outside_summary, outside_where
from ..robot.model.rigid import assumptions, model_payload
from .filtering import PAYLOAD_EFFECTS, Filtered, filter_program, payloads, play
from .model import Program
from .text import rewrite


@dataclass
class FilteredProgram:
    """What :func:`filter_with_model` returns.

    Attributes
    ----------
    filtered : Filtered
        The changes, one report row per motion (``status``, ``max_correction_arcsec`` arcsec, ``move_mm``
        mm, ``payload_kg`` kg, ``payload_source``, ...) and the conflicts.
    texts : list of str
        The new text of each of the program's files, in ``program.sources`` order.
    counts : dict
        Motions per status.
    largest_arcsec : float, arcsec
        The largest joint correction of a filtered motion (0 when none).
    moved_mm : float, mm
        The largest move of a filtered target (0 when none).
    payloads : dict
        ``(payload_kg, source) -> [rows]``: the motions by the payload they were corrected at, in order.
    assumed : str
        What the model assumes of the robot, in words.
    outside : list
        Per motion (``filtered.rows`` order), where a target left as given outside the calibrated region lies and
        its stated u95, or None (:func:`pipeline.correct.run.outside_region`).
    """

    filtered: Filtered
    texts: list
    counts: dict
    largest_arcsec: float
    moved_mm: float
    payloads: dict
    assumed: str
    outside: list = field(default_factory=list)

    def report(self, written, seconds: float, notes=(), payload_kg=None, closed=()) -> list[str]:
        """The console's lines: motions filtered and left as given (each named at its file and line; one outside
        the calibrated region with its joint, how far beyond and its u95_mm, after a line on all of them), the
        largest joint correction (arcsec) and target move (mm), the program's notes, what was assumed and
        the payload of each motion with where it comes from.

        ``written`` the files written; ``seconds`` the time the filter took; ``notes`` the program's
        (:attr:`Program.notes`); ``payload_kg`` the --payload given (kg); ``closed`` the joints run closed loop.
        """
        res, rows, counts = self.filtered, self.filtered.rows, self.counts
        lines = [f"{', '.join(map(str, written))}: {len(rows)} targets in {seconds:.1f} s: "
                 f"{counts.get('ok', 0)} filtered (largest joint correction {self.largest_arcsec:.1f} arcsec, "
                 f"largest target move {self.moved_mm:.3f} mm), {len(res.changes)} numbers changed; left as given: "
                 + (", ".join(f"{v} {k}" for k, v in sorted(counts.items()) if k != "ok") or "none")]
        where = self.outside or [None] * len(rows)
        summary = outside_summary(where)
        if summary:
            lines.append(f"  {summary} (each named below, with how far beyond and its u95_mm)")
        lines += [f"  {r['file']}:{r['line']}: {r['name']} ({r['kind']}) left as given: {r['reason']}"
                  + (f"; {outside_where(w, angle=False)}" if w is not None else "")   # the reason names the joint
                  for r, w in zip(rows, where) if r["status"] not in ("ok", "same_target")]
        lines += [f"  {r['file']}:{r['line']}: {r['name']} ({r['kind']}) used again: {r['reason']}"
                  for r in res.conflicts]
        lines += [f"  {note}" for note in (*notes, *res.notes)]
        if payload_kg is not None and any(r["payload_source"].startswith("program:") for r in rows):
            lines.append(f"  --payload {payload_kg:g} kg is used where the program states no payload; where it "
                         "states one, the program's")
        lines.append(f"  {self.assumed}"
                     + (f"; closed loop on their encoders: joints {' '.join(map(str, closed))}" if closed else "")
                     + "; payload: " + "; ".join(f"{v:g} kg ({src}; {len(rs)} target{'s' if len(rs) > 1 else ''}, "
                                                 f"from {rs[0]['file']}:{rs[0]['line']})"
                                                 for (v, src), rs in self.payloads.items()))
        return lines


def filter_with_model(program: Program, doc: dict, loaded: tuple, tool=None, base=None, payload_kg=None,
                      max_correction_deg: float = 0.5) -> FilteredProgram:
    """Filter a program's motion targets through a fitted robot model.

    Parameters
    ----------
    program : Program
        As :func:`pipeline.programs.io.read_program` read it.
    doc : dict
        The fit JSON (``payloads_kg``, ``joint_angles``).
    loaded : tuple
        ``(robot, effects, model, sampled, frame)`` of :func:`pipeline.robot.model.predict.load_model_document`.
    tool, base : sequence of float, optional
        ``--tool`` / ``--base``: mm and the format's rotation, where the program defines none.
    payload_kg : float, kg, optional
        ``--payload``: where the program states no payload (else the model's one payload).
    max_correction_deg : float, deg
        A motion needing a larger correction of any joint is left as given.

    Returns
    -------
    FilteredProgram
    """
    robot, effects, model, sampled, frame = loaded
    # the program's own payload, else --payload, else the model's one payload (as for a --targets row)
    dependent = tuple(sorted({e.name for e in effects} & set(PAYLOAD_EFFECTS)))
    kg, source = payloads(program, payload_kg, model_payload(doc.get("payloads_kg")), dependent)
    kin = ModelKinematics(robot, model)
    res = filter_program(program, robot, kin, sampled, tool, base, kg, max_correction_deg, source)
    texts = rewrite(program.sources, res.changes)
    counts = {}
    for r in res.rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    ok = [r for r in res.rows if r["status"] == "ok"]
    largest = max((r["max_correction_arcsec"] for r in ok), default=0.0)
    moved = max((r["move_mm"] for r in ok), default=0.0)
    used = {}
    for r in res.rows:
        used.setdefault((r["payload_kg"], r["payload_source"]), []).append(r)
    outside = _outside(program, robot, kin, doc, sampled, tool, base, kg, res.rows) if counts.get(OUTSIDE) else []
    return FilteredProgram(res, texts, counts, largest, moved, used, assumptions(doc, len(robot.joints)), outside)


def _outside(program, robot, kin, doc, sampled, tool, base, kg, rows) -> list:
    """Per motion, where a target the filter left as given outside the calibrated region lies and its stated u95
    (:func:`pipeline.correct.run.outside_region`), None for every other motion: the console names them.

    The motions are played again (:func:`pipeline.programs.filtering.play`) for their joints (deg), each u95 taken
    as ``correct_commands`` takes a row left as given: at the played joints, with the directions of the played
    sequence, the motion's payload ``kg`` (kg, None: 0) and the reference temperature."""
    from ..robot.arm.kinematics import directions_from_sequence
    from ..robot.model.uncertainty import load_prediction, u95

    played = play(program, robot, tool, base)
    idx = [k for k in range(len(rows)) if not played.reason[k]]
    far = [k for k in idx if rows[k]["status"] == OUTSIDE]
    if not far:
        return []
    q = played.q_deg[idx]
    dirs = directions_from_sequence(q, start_deg=(robot.lower_deg + robot.upper_deg) / 2)
    pos = {k: i for i, k in enumerate(idx)}
    at = [pos[k] for k in far]
    payload = np.zeros(len(rows)) if kg is None else np.broadcast_to(np.asarray(kg, float), (len(rows),))
    stated = load_prediction(doc, kin.model)
    u = None
    if stated is not None:
        data = kin.data(q[at], dirs[at], payload[far], np.full(len(far), REFERENCE_TEMPERATURE_C))
        u = u95(kin.model, data, stated, sampled)["u95_mm"]
    where = outside_region(q[at], sampled, u)
    out = [None] * len(rows)
    for k, w in zip(far, where):
        out[k] = w
    return out


@dataclass
class PlayedPoses:
    """What :func:`played_poses` returns for the m of a program's n motions the controller could play.

    Attributes
    ----------
    point_id : ndarray of str, shape (m,)
        The target's name (``#2``, ``#3`` added for a target visited again).
    q_deg : ndarray, shape (m, N), deg
        The commanded joints.
    payload_kg : ndarray, shape (m,), kg
        The program's own payload, else the one given.
    not_played : list of (Target, str)
        Each motion the controller could not play, and why, in program order.
    """

    point_id: np.ndarray
    q_deg: np.ndarray
    payload_kg: np.ndarray
    not_played: list


def played_poses(program: Program, robot, tool=None, base=None, payload_kg=None) -> PlayedPoses:
    """The commanded poses of a program as the nominal controller plays it (:func:`pipeline.programs.filtering.play`).

    Parameters
    ----------
    program : Program
    robot : Robot
    tool, base : sequence of float, optional
        ``--tool`` / ``--base``: mm and the format's rotation, where the program defines none.
    payload_kg : float, kg, optional
        Where the program states no payload (default 0).

    Returns
    -------
    PlayedPoses
    """
    played = play(program, robot, tool, base)
    keep = [k for k, r in enumerate(played.reason) if not r]
    names, seen = [], {}
    for k in keep:
        nm = program.targets[k].name
        seen[nm] = seen.get(nm, 0) + 1
        names.append(nm if seen[nm] == 1 else f"{nm}#{seen[nm]}")
    kg, _ = payloads(program, 0.0 if payload_kg is None else payload_kg)     # the program's own, else the given
    not_played = [(program.targets[k], r) for k, r in enumerate(played.reason) if r]
    return PlayedPoses(np.array(names), played.q_deg[keep], kg[keep], not_played)
