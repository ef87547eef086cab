"""The nominal controller and the filter (contract section 11).

:func:`play` is the robot's controller with its nominal kinematics: each motion of a program, in
visiting order, becomes commanded joint values - a joint target as it is, a Cartesian target (TCP
pose in the program's base frame) through inverse kinematics on its branch: the branch flags its
configuration data name, or, for a linear move (and every UR move, and a joint move without
configuration monitoring), the branch of the point before; among the turns of that branch, the one
the target's turn data name (KUKA ``T``, ABB ``cf1 cf4 cf6``, FANUC turns), else the one nearest the
joints of the point before (a URScript ``get_inverse_kin(pose, qnear)`` with a known ``qnear``: the
branch and the solution nearest ``qnear``, as the controller does). The robot starts at the middle of its joint ranges (decision). A tool
is given in the vendor's flange frame (FANUC's faceplate, KUKA's ``$FLANGE``, ABB's ``tool0``, UR's
tool flange: :mod:`pipeline.programs.flanges`), whatever frame the robot's kinematics end at; a target
with no solution that a half-turn of the tool would reach is named as such.

:func:`filter_program` corrects those commands with the whole fitted model
(:func:`pipeline.correct.robot.correct_commands`, as ``jointcal correct --targets``) and writes
back, for a Cartesian target, the nominal forward kinematics of the corrected joints in the
target's own tool and base frame (its configuration data unchanged); for a joint target the
corrected joints. Left as given and named: targets computed at run time, without a solution on
their branch or within the joint ranges, whose correction the model refuses (outside the sampled
range, too large), or whose branch or turn the correction would change.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from . import formats as fm
from . import ik
from .conventions import invert
from .flanges import HALF_TURNS, vendor_flange
from .model import CARTESIAN, CONFIG, JOINT, Program

OK = "ok"
#: effects whose error depends on the payload (the gravity torque includes it)
PAYLOAD_EFFECTS = ("compliance",)


#: a correction below this (arcsec, largest joint; 1e-9 deg) is none: the target is left as written
UNCHANGED_ARCSEC = 3.6e-6
#: a target whose numbers, rounded to the decimals they are written with, land it farther than this fraction
#: of its correction and this many mm from the corrected target is named ``rounded_away``, left as given
ROUNDED_AWAY = 0.5
ROUNDED_AWAY_MM = 0.001


def payloads(program: Program, given: float | None = None, model_kg: float | None = None,
             dependent: tuple = ()) -> tuple[np.ndarray, list]:
    """The payload of each motion (kg) and where it comes from (contract section 11).

    The program's own where its language states it (RAPID tooldata load, GripLoad, ``\\TLoad``;
    URScript ``set_payload``; KRL ``$LOAD`` / ``LOAD_DATA[n]`` of a given ``$config.dat``); else
    ``given`` (``--payload``); else ``model_kg``, the one payload the model was fitted at; else, for a
    model with no payload-dependent effect, 0 kg (it does not matter).

    Parameters
    ----------
    given : float, kg, optional
    model_kg : float, kg, optional
    dependent : tuple of str
        The model's payload-dependent effects (:data:`PAYLOAD_EFFECTS` it has).

    Returns
    -------
    kg : ndarray, shape (n,), kg
        One per motion of ``program.targets``.
    source : list of str, (n,)

    Raises InputError (file:line, naming ``--payload``) for a motion whose payload nobody knows on a
    model with a payload-dependent effect.
    """
    n = len(program.targets)
    kg, source = np.zeros(n), [""] * n
    for k, t in enumerate(program.targets):
        stated, why = t.extra.get("payload", (None, "the program states no payload"))
        if stated is not None:
            kg[k], source[k] = stated, f"program: {why}"
        elif given is not None:
            kg[k], source[k] = given, "--payload"
        elif model_kg is not None:
            kg[k], source[k] = model_kg, f"the model's payload (fitted at {model_kg:g} kg only)"
        elif dependent and not t.runtime:
            raise InputError(t.file, f"{t.name}: {why}, and the model's {', '.join(dependent)} depends on the payload "
                             "(fitted at several): give --payload KG", t.line, None)
        elif dependent:
            kg[k], source[k] = 0.0, "none known (the target is left as given)"
        else:
            kg[k], source[k] = 0.0, "none stated (the model has no payload-dependent effect)"
    return kg, source


@dataclass
class Played:
    """The nominal controller's commands for a program's motions (n motions, N joints)."""

    q_deg: np.ndarray               # (n, N) deg, NaN where not played
    reason: list                    # (n,) '' or why the motion has no commanded joints
    tool: list                      # (n,) 4 x 4 or None
    base: list                      # (n,) 4 x 4 or None
    notes: list = field(default_factory=list)


def _frame(t, which: str, given, slots: dict, fmt: str):
    fr = getattr(t, which)
    if fr.pose is not None:
        return fr.pose
    if given is None:
        raise InputError(t.file, f"Cartesian target {t.name}: {fr.why or 'no ' + which + ' frame'}; the program does "
                         f"not define its {which} frame, so give it with --{which}", t.line, None)
    first = slots.setdefault(which, (fr.key, t.file, t.line))
    if first[0] != fr.key:                # named and left as given: --tool / --base stands for one frame
        return (f"it uses {which} {fr.key} ({fr.why or 'not defined in the program'}), and --{which} stands for "
                f"{first[0]} (first used at {first[1]}:{first[2]})")
    return fm.frame_pose(fmt, given)


def play(program: Program, robot, tool=None, base=None) -> Played:
    """The nominal controller: commanded joints (deg) of every motion (see the module docstring).

    Parameters
    ----------
    program : Program
    robot : pipeline.robot.arm.kinematics.Robot
        The nominal robot (six joints).
    tool, base : sequence of float, optional
        ``--tool`` / ``--base`` in the format's convention (:func:`pipeline.programs.formats.frame_pose`).

    Raises InputError (file:line) for a Cartesian target whose tool or base frame nobody gave; a
    target in a second undefined frame, when ``--tool`` / ``--base`` already stands for another, is
    left as given (its reason says so).
    """
    if robot.n_joints != 6:
        raise InputError(robot.path, f"program filtering needs a six-joint arm; this robot has {robot.n_joints}", 1, 1)
    fmt = program.format
    chain = ik.chain_of(robot)
    targets = program.targets
    n = len(targets)
    q = np.full((n, 6), np.nan)
    reason = [""] * n
    tools, bases = [None] * n, [None] * n
    slots: dict = {}
    start = (robot.lower_deg + robot.upper_deg) / 2
    # pass 1: frames, flange poses and the branch each Cartesian target is wanted on (flags propagate)
    prev_flags = ik.arm_flags(chain, start[None])[0]
    joint_k = [k for k, t in enumerate(targets) if t.kind == JOINT and not t.runtime]
    # a joint target holds the controller's angles: coupled joints (robot.toml [coupling], a FANUC's J2/J3)
    # are combined into the angles the kinematics take
    joint_q = {k: robot.kinematic_angles(np.asarray(fm.joints_deg(fmt, targets[k].values), float)[None])[0]
               for k in joint_k}
    joint_flags = dict(zip(joint_k, ik.arm_flags(chain, np.array([joint_q[k] for k in joint_k])))) if joint_k else {}
    # the vendor's flange frame (FANUC's faceplate, KUKA's $FLANGE, ABB's tool0, UR's tool flange) in the last
    # link frame {N}: a program's tool is given in it, the kinematics end at {N}
    flange = vendor_flange(robot, fmt)
    notes = [flange.note] if flange.note and any(t.kind == CARTESIAN and not t.runtime for t in targets) else []
    want, T_fl, cart, T_target, near = {}, {}, [], {}, {}
    for k, t in enumerate(targets):
        if t.runtime:
            reason[k] = t.runtime
            continue
        if t.kind == JOINT:
            qj = joint_q[k]
            q[k] = qj
            prev_flags = joint_flags[k]
            continue
        tool_T = _frame(t, "tool", tool, slots, fmt)
        base_T = _frame(t, "base", base, slots, fmt)
        if isinstance(tool_T, str) or isinstance(base_T, str):
            reason[k] = tool_T if isinstance(tool_T, str) else base_T
            continue
        tool_T = flange.pose @ tool_T            # the TCP in {N}
        tools[k], bases[k] = tool_T, base_T
        T_target[k] = base_T @ fm.pose(fmt, t.values)
        T_fl[k] = T_target[k] @ invert(tool_T)
        w = np.array(t.flags, bool) if (t.branch == CONFIG and t.flags is not None) else prev_flags
        if t.extra.get("qnear_deg") is not None:
            # URScript get_inverse_kin(pose, qnear): the solution nearest qnear (the controller's angles)
            near[k] = robot.kinematic_angles(np.asarray(t.extra["qnear_deg"], float)[None])[0]
            w = ik.arm_flags(chain, near[k][None])[0]
        want[k] = w
        prev_flags = w
        cart.append(k)
    sols = {}
    if cart:
        found = ik.solve_branch(chain, np.array([T_fl[k] for k in cart]), np.array([want[k] for k in cart]))
        sols = dict(zip(cart, found))
    # pass 2: the turn, in visiting order
    prev = start.copy()
    lo, hi = robot.lower_deg, robot.upper_deg
    for k, t in enumerate(targets):
        if reason[k]:
            continue
        if t.kind == JOINT:
            out = (q[k] < lo - 1e-9) | (q[k] > hi + 1e-9)
            if out.any():
                j = int(np.argmax(out))
                reason[k] = (f"joint {j + 1} at {q[k, j]:.4f} deg is beyond the robot's joint range "
                             f"({lo[j]:g} to {hi[j]:g} deg)")
                q[k] = np.nan
                continue
            prev = q[k]
            continue
        s = sols.get(k, np.zeros((0, 6)))
        flags = "".join(n for n, f in zip(("rear ", "down ", "flip"), want[k]) if f).strip() or "front, up, no flip"
        if not len(s):
            reason[k] = (f"no inverse-kinematics solution on its branch ({flags})"
                         + _half_turn(chain, T_target[k], tools[k], flange, want[k]))
            continue
        cands = np.rad2deg(ik.expand_turns(chain, s))
        if not len(cands):
            reason[k] = (f"its branch ({flags}) has no solution within the joint ranges"
                         + _half_turn(chain, T_target[k], tools[k], flange, want[k]))
            continue
        if t.branch == CONFIG and t.turn is not None:
            # a turn names the signs of the controller's angles (a URDF's -z joint 1: [coupling] q1 = -q1)
            okt = np.array([fm.turn_ok(fmt, t.turn, c) for c in robot.recorded_angles(cands)])
            if not okt.any():
                reason[k] = f"no solution on its branch ({flags}) has the turn it names ({t.turn})"
                continue
            cands = cands[okt]
        best = cands[np.argmin(np.abs(cands - near.get(k, prev)).max(axis=1))]
        q[k] = best
        prev = best
    return Played(q, reason, tools, bases, notes)


def _half_turn(chain, T_target, tool_T, flange, want) -> str:
    """Why a Cartesian target has no solution when it is a half-turn of its tool: ``''``, or the words
    naming the axis of the vendor's flange frame about which the tool turned by 180 deg reaches it on its
    branch within the joint ranges (the frame of a URDF's link taken for the vendor's flange, say).

    ``T_target`` (4, 4) mm the TCP in the robot's base frame; ``tool_T`` (4, 4) mm the TCP in {N};
    ``flange`` the :class:`~pipeline.programs.flanges.VendorFlange`; ``want`` (3,) bool the branch flags."""
    tcp = invert(flange.pose) @ tool_T                   # the TCP in the vendor's flange frame
    for axis, H in HALF_TURNS.items():
        T = T_target @ invert(flange.pose @ H @ tcp)
        s = ik.solve_branch(chain, T[None], np.asarray(want, bool)[None])[0]
        if len(s) and len(ik.expand_turns(chain, s)):
            return (f"; it has one with its tool turned half a turn (180 deg) about the {axis} axis of {flange.name}"
                    ": the tool frame (the program's tool, --tool) is a half-turn off the vendor's flange frame "
                    "(a frame read off another convention, a URDF link's?)")
    return ""


@dataclass
class Filtered:
    """Result of :func:`filter_program`: the changed numbers and one report row per motion."""

    changes: dict                   # (file index, start, end) -> new text
    rows: list                      # dicts: file, line, name, kind, status, reason, max_correction_arcsec, move_mm
    texts: list = field(default_factory=list)
    conflicts: list = field(default_factory=list)   # rows of a declared target used again under another frame or load
    notes: list = field(default_factory=list)       # the controller's notes (a vendor flange taken as {N})


def filter_program(program: Program, robot, kin, sampled=None, tool=None, base=None, payload_kg=None,
                   max_correction_deg: float = 0.5, payload_source=None) -> Filtered:
    """Filter a program's targets through a fitted model (see the module docstring).

    Parameters
    ----------
    kin : pipeline.correct.robot.ModelKinematics
        The fitted model.
    sampled : dict, optional
        Joint ranges the model was fitted on (``{"lower_deg": [6], "upper_deg": [6]}``).
    tool, base : sequence of float, optional
        ``--tool`` / ``--base`` (format's convention).
    payload_kg : float or ndarray of shape (n motions,), kg, optional
        Mass the robot carries at each motion (:func:`payloads`; None: what ``correct_commands``
        assumes for a row without a payload).
    payload_source : list of str, optional
        Where each motion's payload comes from (for the report).
    max_correction_deg : float, deg
    """
    from ..correct.robot import correct_commands
    from ..robot.arm.kinematics import directions_from_sequence

    fmt = program.format
    chain = ik.chain_of(robot)
    played = play(program, robot, tool, base)
    targets = program.targets
    n = len(targets)
    rows = []
    idx = [k for k in range(n) if not played.reason[k]]
    q0 = played.q_deg[idx]
    status = {k: played.reason[k] for k in range(n) if played.reason[k]}
    q1 = {}
    if idx:
        start = (robot.lower_deg + robot.upper_deg) / 2
        dirs = directions_from_sequence(q0, start_deg=start)
        payload = None if payload_kg is None else np.broadcast_to(np.asarray(payload_kg, float), (n,))[idx]
        res = correct_commands(kin, q0, None, dirs, payload, None, sampled, max_correction_deg)
        for r, k in enumerate(idx):
            if res.status[r] != "ok":
                status[k] = f"{res.status[r]}: {res.reason[r]}"
            q1[k] = res.q_deg[r]
    changes = {}
    seen = {}
    conflicts = []
    done = sorted(q1)
    if done:
        both = np.concatenate([played.q_deg[done], np.array([q1[k] for k in done])])
        fl = ik.arm_flags(chain, both)
        F_all = ik.flange(chain, np.deg2rad(both))
        flags_a = dict(zip(done, fl[:len(done)]))
        flags_b = dict(zip(done, fl[len(done):]))
        fl_a = dict(zip(done, F_all[:len(done)]))
        fl_b = dict(zip(done, F_all[len(done):]))
    smr = np.append(np.asarray(robot.tool_xyz_mm, float), 1.0)
    for k, t in enumerate(targets):
        row = {"file": t.file, "line": t.line, "name": t.name, "kind": t.kind, "status": OK, "reason": "",
               "max_correction_arcsec": 0.0, "move_mm": 0.0}
        if payload_kg is not None:
            row["payload_kg"] = float(np.broadcast_to(np.asarray(payload_kg, float), (n,))[k])
            row["payload_source"] = payload_source[k] if payload_source else ""
        rows.append(row)
        q_played = None if np.isnan(played.q_deg[k]).any() else played.q_deg[k]
        use = (played.tool[k], played.base[k], row.get("payload_kg"), q_played)
        if t.decl and t.decl in seen:
            first, used = seen[t.decl]
            row["status"] = "same_target"
            row["reason"] = f"the declaration {t.name} was filtered at its first use, line {first}"
            differ = _uses_differ(used, use)
            if differ:
                # one set of numbers cannot serve two frames or loads: it is filtered for the first
                # use, and this use is named (the report and the console) so the user can split it
                row["reason"] += (f", under another {' and '.join(differ)} than here: its numbers serve line "
                                  f"{first} only (give this motion its own target)")
                conflicts.append(row)
            continue
        if t.decl and not t.runtime:
            seen[t.decl] = (t.line, use)
        if k in status:
            row["status"] = _status_word(status[k], t)
            row["reason"] = status[k]
            continue
        qa, qb = played.q_deg[k], q1[k]
        dq = np.abs(qb - qa).max() * 3600.0
        if dq < UNCHANGED_ARCSEC:
            # no correction (an identity model): the target stays as written, whatever rounding its
            # respelling from the pose would add (a rotation vector near a half-turn, Euler angles at a lock)
            row["max_correction_arcsec"] = float(dq)
            continue
        if t.kind == CARTESIAN:
            fa, fb = flags_a[k], flags_b[k]
            if tuple(fa) != tuple(fb) or (t.branch == CONFIG
                                          and not fm.turn_ok(fmt, t.turn, robot.recorded_angles(qb[None])[0])):
                row["status"] = "branch_change"
                row["reason"] = "the corrected joints are on another branch or turn than the target names"
                continue
            Fb = fl_b[k]
            new_pose = invert(played.base[k]) @ Fb @ played.tool[k]
            old = t.values
            new = fm.pose_values(fmt, new_pose, old)
            move = float(np.linalg.norm(new_pose[:3, 3] - fm.pose(fmt, old)[:3, 3]))
        else:
            new = fm.joint_values(fmt, robot.recorded_angles(np.asarray(qb, float)[None])[0])  # the controller's
            move = float(np.linalg.norm((fl_b[k] @ smr - fl_a[k] @ smr)[:3]))
        spelled, written = {}, []
        for num, v in zip(t.numbers, new):
            s = num.respell(float(v))
            if s is not None:
                spelled[(num.file, num.start, num.end)] = s
            written.append(float(s) if s is not None else num.value)
        # the numbers keep their decimals: where the rounding undoes most of the correction (a KRL
        # {A1 0, A2 -90, ...} with no decimals), the target is named, not reported filtered
        if t.kind == CARTESIAN:
            miss = float(np.linalg.norm(fm.pose(fmt, written)[:3, 3] - new_pose[:3, 3]))
        else:
            qw = robot.kinematic_angles(np.asarray(fm.joints_deg(fmt, written), float)[None])
            miss = float(np.linalg.norm((ik.flange(chain, np.deg2rad(qw))[0] @ smr - fl_b[k] @ smr)[:3]))
        if miss > ROUNDED_AWAY * move and miss > ROUNDED_AWAY_MM:
            row["status"] = "rounded_away"
            row["reason"] = (f"its numbers, written with their decimals, cannot carry the correction: rounded, the "
                             f"target would land {miss:.3f} mm from the corrected one (the correction moves it "
                             f"{move:.3f} mm); write it with more decimals")
            continue
        changes.update(spelled)
        row["max_correction_arcsec"] = float(dq)
        row["move_mm"] = move
    return Filtered(changes, rows, conflicts=conflicts, notes=list(played.notes))


def _uses_differ(a, b) -> list:
    """What differs between two uses ``(tool 4 x 4 or None, base 4 x 4 or None, payload kg or None,
    commanded joints (N,) deg or None)`` of one declared target: ``tool frame`` / ``base frame`` (an entry
    of the 4 x 4 apart by more than 1e-6: mm, or rotation), ``payload``, ``arm solution`` (the nominal
    controller's joints apart by more than 1e-3 deg: another branch or turn, e.g. two URScript
    ``get_inverse_kin`` of one pose with the ``qnear`` of two solutions)."""
    out = []
    for word, fa, fb in (("tool", a[0], b[0]), ("base", a[1], b[1])):
        if fa is not None and fb is not None and not np.allclose(fa, fb, rtol=0.0, atol=1e-6):
            out.append(f"{word} frame")
    if a[2] is not None and b[2] is not None and abs(a[2] - b[2]) > 1e-9:
        out.append(f"payload ({a[2]:g} kg there, {b[2]:g} kg here)")
    if len(a) > 3 and a[3] is not None and b[3] is not None and np.abs(np.asarray(a[3]) - b[3]).max() > 1e-3:
        out.append("arm solution (branch or turn)")
    return out


def _status_word(reason: str, t) -> str:
    if t.runtime:
        return "run_time"
    for w in ("outside_sampled_range", "correction_too_large", "no_solution"):
        if reason.startswith(w):
            return w
    if "joint range" in reason:
        return "beyond_joint_range"
    if reason.startswith("it uses "):
        return "frame_unknown"
    return "no_ik_solution"
