"""Robot description (contract section 2, ``robot.toml``) and its pinocchio models.

Link transform of joint i (contract, Eq. 2 of the second paper)::

    T_i = Rz(q_i + theta_offset_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i) . Ry(beta_i)

and the SMR position is ``T_1 ... T_N . [tool.xyz_mm, 1]`` (N joints, 4 to 7). Writing
``L_i = Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)`` the chain is

    Rz(off_1) Rz(q_1) L_1 Rz(off_2) Rz(q_2) L_2 ... Rz(off_N) Rz(q_N) L_N Trans(tool)

so a pinocchio revolute-Z joint i placed at ``L_{i-1} Rz(off_i)`` (``Rz(off_1)`` for
the first) reproduces it exactly; the MDH link frame {i} is an operational frame at ``L_i``
on joint i, the SMR a frame at ``L_N Trans(tool)``.

Two models are built from one description:

* :func:`build_model` - the plain N-joint arm with link inertias (``mass_kg``, ``com_mm``
  in link frame {i}) for kinematics and gravity torques;
* :func:`build_error_model` - the same chain with *error joints* inserted: a 6-dof base
  error (PX PY PZ RX RY RZ) before joint 1, a 6-dof error after every link frame {i}
  (the error transfer matrix E_i of Eq. 7-8 of the paper, realised as an exact rigid
  transform) and a 3-dof tool offset before the SMR. Every robot effect is linear in its
  parameters through these coordinates ("channels"), so one forward-kinematics call gives
  the predicted SMR position and one frame Jacobian gives the derivative with respect to
  every channel. pinocchio works in metres and radians; files and reports use mm and deg.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from ...core.errors import InputError, parse_toml
from ...core.files import read_text_input

JOINT_FIELDS = ("a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg", "lower_deg", "upper_deg")
GRAVITY_FIELDS = ("mass_kg", "com_mm")
#: joint counts a robot may have (contract section 2: one ``[[joint]]`` table per joint, 4 to 7)
MIN_JOINTS, MAX_JOINTS = 4, 7
#: the papers' robots (KR210, UR10): the six-joint chain the paper-2 methods are written for
PAPER_JOINTS = 6
G = 9.81
TWIST = ("dx", "dy", "dz", "ex", "ey", "ez")


@dataclass(frozen=True)
class Joint:
    """One ``[[joint]]`` table: lengths in mm, angles in deg, mass in kg."""

    a_mm: float
    alpha_deg: float
    d_mm: float
    theta_offset_deg: float
    beta_deg: float
    lower_deg: float
    upper_deg: float
    mass_kg: float = 0.0
    com_mm: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Robot:
    """Nominal robot of a campaign (``robot.toml``)."""

    name: str
    joints: tuple
    tool_xyz_mm: tuple
    path: str = "<robot>"
    ur_model: str = ""     # a UR imported from its calibration.conf: the model whose published DH it is against
    #: orientation of the probe frame (a 6-DoF probe) in the flange frame, URDF's rpy in deg:
    #: R = Rz(yaw) Ry(pitch) Rx(roll) (``[tool] rpy_deg``; 0, 0, 0 when not given)
    tool_rpy_deg: tuple = (0.0, 0.0, 0.0)
    #: coupled joints (``[coupling]``): rows ``(j, (c_1 .. c_N))`` saying that joint j's angle (0-based j)
    #: is ``sum_k c_k q_k`` of the recorded (controller's) angles q, e.g. a FANUC's J2/J3 interaction;
    #: every other joint's angle is its recorded one. Empty: none.
    coupling: tuple = ()

    @property
    def coupling_matrix(self) -> np.ndarray:
        """C (N, N): the joint angles the kinematics take = C @ the recorded angles (identity without coupling)."""
        C = np.eye(self.n_joints)
        for j, row in self.coupling:
            C[j] = np.asarray(row, float)
        return C

    def kinematic_angles(self, q_recorded_deg) -> np.ndarray:
        """The angles the kinematics take (n, N) deg from the recorded (controller's) angles (n, N) deg."""
        q = np.asarray(q_recorded_deg, float)
        return q if not self.coupling else q @ self.coupling_matrix.T

    def recorded_angles(self, q_kinematic_deg) -> np.ndarray:
        """The controller's angles (n, N) deg that give the kinematic angles (n, N) deg (C's inverse)."""
        q = np.asarray(q_kinematic_deg, float)
        return q if not self.coupling else np.linalg.solve(self.coupling_matrix, q.T).T

    def coupling_lines(self) -> list[str]:
        """The ``[coupling]`` section of robot.toml (no lines without coupling)."""
        if not self.coupling:
            return []
        out = ["[coupling]   # the joint's angle = this combination of the recorded angles"]
        for j, row in self.coupling:
            terms = ", ".join(f"q{k + 1} = {_num(c)}" for k, c in enumerate(row) if c != 0.0)
            out.append(f"q{j + 1} = {{ {terms} }}")
        return out

    @property
    def n_joints(self) -> int:
        """N, the number of joints (4 to 7)."""
        return len(self.joints)

    @property
    def lower_deg(self) -> np.ndarray:
        return np.array([j.lower_deg for j in self.joints])

    @property
    def upper_deg(self) -> np.ndarray:
        return np.array([j.upper_deg for j in self.joints])

    def replace_joint(self, i: int, **changes) -> "Robot":
        """A copy with joint ``i`` (0-based) changed; for perturbed (true) robots."""
        joints = list(self.joints)
        joints[i] = Joint(**{**joints[i].__dict__, **changes})
        return replace(self, joints=tuple(joints))

    @property
    def tool_rotation(self) -> np.ndarray:
        """The probe frame's rotation in the flange frame, shape (3, 3) (identity without ``rpy_deg``)."""
        return pin.rpy.rpyToMatrix(*np.deg2rad(np.asarray(self.tool_rpy_deg, float)))

    def to_toml(self) -> str:
        lines = [f'name = "{self.name}"'] + ([f'ur_model = "{self.ur_model}"'] if self.ur_model else [])
        lines += ["", "[tool]", f"xyz_mm = [{', '.join(_num(v) for v in self.tool_xyz_mm)}]"]
        if any(float(v) != 0.0 for v in self.tool_rpy_deg):
            lines.append(f"rpy_deg = [{', '.join(_num(v) for v in self.tool_rpy_deg)}]")
        if self.coupling:
            lines += ["", *self.coupling_lines()]
        for j in self.joints:
            lines += ["", "[[joint]]"]
            for f in JOINT_FIELDS + ("mass_kg",):
                lines.append(f"{f} = {_num(getattr(j, f))}")
            lines.append(f"com_mm = [{', '.join(_num(v) for v in j.com_mm)}]")
        return "\n".join(lines) + "\n"


def _num(v) -> str:
    v = float(v)
    return str(int(v)) + ".0" if v == int(v) else repr(v)


# ------------------------------------------------------------------------------ loading
def _table_lines(text: str, header: str) -> list[int]:
    return [text.count("\n", 0, m.start()) + 1
            for m in re.finditer(r"^[ \t]*\[\[[ \t]*" + re.escape(header) + r"\s*\]\]", text, flags=re.MULTILINE)]


def _key_line(text: str, start_line: int, key: str):
    lines = text.splitlines()
    for k in range(start_line - 1, len(lines)):
        if k > start_line - 1 and lines[k].lstrip().startswith("["):
            break
        m = re.match(r"^\s*" + re.escape(key) + r"\s*=", lines[k])
        if m:
            return k + 1, len(lines[k]) - len(lines[k].lstrip()) + 1
    return start_line, 1


def parse_robot(text: str, path="<robot.toml>") -> Robot:
    """Parse ``robot.toml`` text; every problem is an InputError with line and column."""
    doc = parse_toml(text, path)
    tables = doc.get("joint")
    starts = _table_lines(text, "joint")
    if not isinstance(tables, list) or not MIN_JOINTS <= len(tables) <= MAX_JOINTS:
        n = len(tables) if isinstance(tables, list) else 0
        line = starts[-1] if starts else 1
        raise InputError(path, f"found {n} [[joint]] tables; expected {MIN_JOINTS} to {MAX_JOINTS}, one per joint "
                         "from the base", line, 1)
    joints = []
    for i, t in enumerate(tables):
        start = starts[i] if i < len(starts) else 1
        for f in JOINT_FIELDS:
            if f not in t:
                close = difflib.get_close_matches(f, [k for k in t if k not in JOINT_FIELDS + GRAVITY_FIELDS], n=1)
                hint = f" (found '{close[0]}': misspelled?)" if close else ""
                raise InputError(path, f"joint {i + 1}: missing field '{f}'{hint}", start, 1)
        for f in t:
            if f not in JOINT_FIELDS + GRAVITY_FIELDS:
                line, col = _key_line(text, start, f)
                raise InputError(path, f"joint {i + 1}: unknown field '{f}' (known: {', '.join(JOINT_FIELDS + GRAVITY_FIELDS)})",
                                 line, col)
        vals = {}
        for f in JOINT_FIELDS + ("mass_kg",):
            if f not in t:
                continue
            v = t[f]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                line, col = _key_line(text, start, f)
                raise InputError(path, f"joint {i + 1}: '{f}' must be a finite number, got {v!r}", line, col)
            vals[f] = float(v)
        com = t.get("com_mm", [0.0, 0.0, 0.0])
        if (not isinstance(com, list) or len(com) != 3
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in com)):
            line, col = _key_line(text, start, "com_mm")
            raise InputError(path, f"joint {i + 1}: com_mm must be [x, y, z] in mm", line, col)
        if vals.get("mass_kg", 0.0) < 0:
            line, col = _key_line(text, start, "mass_kg")
            raise InputError(path, f"joint {i + 1}: mass_kg must not be negative", line, col)
        if vals["lower_deg"] >= vals["upper_deg"]:
            line, col = _key_line(text, start, "upper_deg")
            raise InputError(path, f"joint {i + 1}: upper_deg must be above lower_deg", line, col)
        joints.append(Joint(com_mm=tuple(float(c) for c in com), **vals))
    lengths = np.array([[j.a_mm, j.d_mm] for j in joints])
    if np.abs(lengths).max() < 10.0:
        raise InputError(path, "all link lengths are below 10: a_mm/d_mm look like metres; the contract says mm",
                         starts[0], 1)
    angles = np.array([[j.alpha_deg, j.beta_deg, j.theta_offset_deg] for j in joints])
    if np.any(np.isclose(np.abs(angles), np.pi / 2, atol=1e-3)) or np.any(np.isclose(np.abs(angles), np.pi, atol=1e-3)):
        k = int(np.argmax(np.isclose(np.abs(angles), np.pi / 2, atol=1e-3).any(axis=1)
                          | np.isclose(np.abs(angles), np.pi, atol=1e-3).any(axis=1)))
        raise InputError(path, f"joint {k + 1}: an angle of about pi/2 or pi looks like radians; the contract says deg",
                         starts[k], 1)
    spans = np.array([j.upper_deg - j.lower_deg for j in joints])
    if np.all(spans <= 2 * np.pi + 1e-9):
        raise InputError(path, "every joint range spans less than 6.3: lower_deg/upper_deg look like radians; "
                         "the contract says deg", starts[0], 1)
    tool = doc.get("tool", {}).get("xyz_mm") if isinstance(doc.get("tool"), dict) else None
    if (not isinstance(tool, list) or len(tool) != 3
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in tool)):
        line = next((k + 1 for k, s in enumerate(text.splitlines()) if re.match(r"^\s*\[tool\]", s)), 1)
        raise InputError(path, "missing or bad [tool] xyz_mm = [x, y, z] (SMR in the flange frame, mm)", line, 1)
    rpy = doc["tool"].get("rpy_deg", [0.0, 0.0, 0.0])
    if (not isinstance(rpy, list) or len(rpy) != 3
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in rpy)):
        line, col = _key_line(text, next((k + 1 for k, s in enumerate(text.splitlines())
                                          if re.match(r"^\s*\[tool\]", s)), 1), "rpy_deg")
        raise InputError(path, "bad [tool] rpy_deg = [roll, pitch, yaw] (the probe frame in the flange frame, deg, "
                         "R = Rz(yaw) Ry(pitch) Rx(roll))", line, col)
    name = str(doc.get("name", Path(str(path)).parent.name or "robot"))
    coupling = parse_coupling(doc.get("coupling"), len(joints), path, text)
    return Robot(name, tuple(joints), tuple(float(c) for c in tool), str(path), str(doc.get("ur_model", "")),
                 tuple(float(c) for c in rpy), coupling)


def parse_coupling(table, n: int, path, text: str, section: str = "coupling") -> tuple:
    """``[coupling]`` (``q3 = { q2 = 1.0, q3 = 1.0 }``: joint 3's angle is q2 + q3 of the recorded angles) as
    :attr:`Robot.coupling`; None or empty: no coupling. Problems are located InputErrors."""
    if table is None:
        return ()
    start = next((k + 1 for k, s in enumerate(text.splitlines()) if re.match(r"^\s*\[" + section + r"\]", s)), 1)
    if not isinstance(table, dict):
        raise InputError(path, f"[{section}] must be a table: q3 = {{ q2 = 1.0, q3 = 1.0 }} (joint 3's angle is q2 + q3 "
                         "of the recorded angles)", start, 1)
    rows = []
    for key, terms in table.items():
        line, col = _key_line(text, start, key)
        m = re.fullmatch(r"q(\d+)", key)
        if not m or not 1 <= int(m.group(1)) <= n:
            raise InputError(path, f"[{section}] '{key}' is not a joint q1..q{n}", line, col)
        if not isinstance(terms, dict) or not terms:
            raise InputError(path, f"[{section}] {key} must be {{ q2 = 1.0, q3 = 1.0 }}: the recorded angles it sums, "
                             "each with its factor", line, col)
        row = [0.0] * n
        for k, c in terms.items():
            mk = re.fullmatch(r"q(\d+)", str(k))
            if not mk or not 1 <= int(mk.group(1)) <= n or isinstance(c, bool) or not isinstance(c, (int, float)) \
                    or not np.isfinite(c):
                raise InputError(path, f"[{section}] {key}: '{k} = {c!r}' must be a recorded joint q1..q{n} with a "
                                 "finite factor", line, col)
            row[int(mk.group(1)) - 1] = float(c)
        rows.append((int(m.group(1)) - 1, tuple(row)))
    rows.sort()
    C = np.eye(n)
    for j, row in rows:
        C[j] = row
    if abs(np.linalg.det(C)) < 1e-9:
        raise InputError(path, f"[{section}] makes the joint angles depend on each other so that the recorded angles "
                         "cannot be recovered from them (a singular combination)", start, 1)
    return tuple(rows)


def load_robot(path) -> Robot:
    """Read ``robot.toml`` (raises InputError naming file, line and column)."""
    text = read_text_input(path, "robot.toml (a robot campaign needs the nominal kinematics)")
    return parse_robot(text, str(path))


# ------------------------------------------------------------------------------- models
def link_placement(joint: Joint) -> pin.SE3:
    """``L_i = Tz(d) Tx(a) Rx(alpha) Ry(beta)`` in metres."""
    rx = pin.utils.rotate("x", np.deg2rad(joint.alpha_deg))
    ry = pin.utils.rotate("y", np.deg2rad(joint.beta_deg))
    return pin.SE3(rx @ ry, np.array([joint.a_mm, 0.0, joint.d_mm]) / 1000.0)


def _rz(deg) -> pin.SE3:
    return pin.SE3(pin.utils.rotate("z", np.deg2rad(deg)), np.zeros(3))


def _link_inertia(joint: Joint) -> pin.Inertia:
    # mass at com (link frame {i}) with a small rotational inertia; gravity needs mass and com only
    c = np.asarray(joint.com_mm, float) / 1000.0
    m = joint.mass_kg
    return pin.Inertia(m, c, np.eye(3) * max(m, 1e-9) * 0.01)


def build_model(robot: Robot) -> pin.Model:
    """The plain arm: N revolute-Z joints, link inertias, frames ``link1..linkN``, ``flange``, ``smr``.

    The body of joint i carries its link's mass; ``com_mm`` is given in link frame {i}
    (the frame after ``T_i``), i.e. at ``L_i . com`` in the joint frame.
    """
    model = pin.Model()
    model.name = robot.name
    parent = 0
    prev_L = pin.SE3.Identity()
    for i, j in enumerate(robot.joints):
        placement = prev_L * _rz(j.theta_offset_deg)
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"q{i + 1}",
                             np.array([1e4]), np.array([1e2]),
                             np.array([np.deg2rad(j.lower_deg)]), np.array([np.deg2rad(j.upper_deg)]))
        L = link_placement(j)
        model.appendBodyToJoint(jid, L.act(_link_inertia(j)), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"link{i + 1}", jid, 0, L, pin.FrameType.OP_FRAME))
        parent, prev_L = jid, L
    model.addFrame(pin.Frame("flange", parent, 0, prev_L, pin.FrameType.OP_FRAME))
    tool = pin.SE3(robot.tool_rotation, np.asarray(robot.tool_xyz_mm, float) / 1000.0)
    model.addFrame(pin.Frame("smr", parent, 0, prev_L * tool, pin.FrameType.OP_FRAME))
    model.gravity = pin.Motion(np.array([0.0, 0.0, -G, 0.0, 0.0, 0.0]))
    return model


@dataclass(frozen=True)
class ErrorModelIndex:
    """Positions of the channels in the error model's configuration vector (nq = nv = 7 N + 12; 54 for six joints)."""

    joints: np.ndarray        # (N,) main joints q1..qN
    links: np.ndarray         # (N, 6) link i error twist dx dy dz ex ey ez
    base: np.ndarray          # (6,) base error twist
    tool: np.ndarray          # (3,) tool offset dx dy dz
    nq: int
    tool_rot: np.ndarray = None   # (3,) the probe frame's turn ex ey ez (about its own axes, at its origin)


def build_error_model(robot: Robot) -> tuple[pin.Model, ErrorModelIndex]:
    """The arm with error joints (see module docstring); no inertias (kinematics only)."""
    model = pin.Model()
    model.name = robot.name + "_errors"
    kinds = [pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ, pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ]
    big = np.array([1e3])

    def add(parent, jm, placement, name):
        jid = model.addJoint(parent, jm(), placement, name, big, big, -big, big)
        model.appendBodyToJoint(jid, pin.Inertia.Zero(), pin.SE3.Identity())
        return jid

    parent = 0
    base = []
    for k, kind in enumerate(kinds):
        parent = add(parent, kind, pin.SE3.Identity(), f"base_{TWIST[k]}")
        base.append(parent)
    joints, links = [], []
    placement = pin.SE3.Identity()
    for i, j in enumerate(robot.joints):
        parent = add(parent, pin.JointModelRZ, placement * _rz(j.theta_offset_deg), f"q{i + 1}")
        joints.append(parent)
        row = []
        for k, kind in enumerate(kinds):
            parent = add(parent, kind, link_placement(j) if k == 0 else pin.SE3.Identity(), f"link{i + 1}_{TWIST[k]}")
            row.append(parent)
        links.append(row)
        model.addFrame(pin.Frame(f"link{i + 1}", parent, 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
        placement = pin.SE3.Identity()
    model.addFrame(pin.Frame("flange", parent, 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    tool = []
    for k, kind in enumerate(kinds[:3]):
        parent = add(parent, kind, pin.SE3.Identity(), f"tool_{TWIST[k]}")
        tool.append(parent)
    # the probe frame's turn on the flange (a 6-DoF probe's orientation): three rotations about the
    # probe's own axes at its origin, so that they turn the probe frame and move no measured point
    tool_rot = []
    placement = pin.SE3(robot.tool_rotation, np.asarray(robot.tool_xyz_mm, float) / 1000.0)
    for k, kind in enumerate(kinds[3:]):
        parent = add(parent, kind, placement if k == 0 else pin.SE3.Identity(), f"tool_{TWIST[3 + k]}")
        tool_rot.append(parent)
    model.addFrame(pin.Frame("smr", parent, 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    # every joint is 1-dof: configuration index = joint id - 1
    idx = ErrorModelIndex(np.array(joints) - 1, np.array(links) - 1, np.array(base) - 1, np.array(tool) - 1, model.nq,
                          np.array(tool_rot) - 1)
    return model, idx


# ------------------------------------------------------------------------ batch helpers
def frame_id(model: pin.Model, name: str) -> int:
    return model.getFrameId(name)


#: the 1-dof joints the batched kinematics (:func:`batch_placements`) evaluates: (revolute?, axis)
_AXIS_JOINTS = {"JointModelRX": (True, 0), "JointModelRY": (True, 1), "JointModelRZ": (True, 2),
                "JointModelPX": (False, 0), "JointModelPY": (False, 1), "JointModelPZ": (False, 2)}


def _chain(model: pin.Model, frame: str):
    """The joints from the root to ``frame``'s parent joint, as (joint id, revolute, axis, placement R,
    placement p, q index); None when one of them is not a 1-dof axis joint (then pinocchio's loop)."""
    key = ("_jointcal_chain", frame)
    cache = getattr(model, "_jointcal_cache", None)
    if cache is None:
        cache = {}
        try:
            model._jointcal_cache = cache
        except AttributeError:        # a model that takes no attributes: no cache
            pass
    if key in cache:
        return cache[key]
    fr = model.frames[model.getFrameId(frame)]
    j = int(fr.parentJoint if hasattr(fr, "parentJoint") else fr.parent)
    path = []
    while j > 0:
        path.append(j)
        j = int(model.parents[j])
    out = []
    for j in reversed(path):
        jm = model.joints[j]
        kind = _AXIS_JOINTS.get(jm.shortname())
        if kind is None:
            out = None
            break
        M = model.jointPlacements[j]
        R, p = np.array(M.rotation), np.array(M.translation)
        out.append((j, kind[0], kind[1], None if np.array_equal(R, np.eye(3)) else R,
                    None if not p.any() else p, int(jm.idx_q), int(jm.idx_v)))
    result = None if out is None else (out, np.array(fr.placement.rotation), np.array(fr.placement.translation))
    cache[key] = result
    return result


def _moved(p, cols, v):
    """The origin p (3, n) moved by v (3,) in the frame of the columns ``cols`` (three (3, n))."""
    for k in range(3):
        if v[k] != 0.0:
            p = p + cols[k] * v[k]
    return p


def _turned(cols, M):
    """The columns (three (3, n)) of the frame turned by M (3, 3)."""
    return [sum(cols[i] * M[i, k] for i in range(3) if M[i, k] != 0.0) for k in range(3)]


def _origin(n):
    """The root frame for n configurations: the rotation as its three columns and the origin, each (3, n)
    (x, y, z rows); the numpy kinematics are a few axpys a joint on them."""
    return [np.repeat(np.eye(3)[:, k:k + 1], n, axis=1) for k in range(3)], np.zeros((3, n))


def _walk(steps, Q):
    """The numpy kinematics of a :func:`_chain`'s joints for every configuration Q (n, nq): after each joint,
    (joint id, revolute, axis, v index, the frame's three columns (3, n), its origin (3, n) m)."""
    Q = np.asarray(Q, float)
    n = len(Q)
    cols, p = _origin(n)
    for j, revolute, a, Rj, pj, iq, iv in steps:
        if pj is not None:
            p = _moved(p, cols, pj)
        if Rj is not None:
            cols = _turned(cols, Rj)
        q = Q[:, iq]
        if revolute:
            b, c = (a + 1) % 3, (a + 2) % 3
            if np.any(q):
                cq, sq = np.cos(q), np.sin(q)
                cols = list(cols)
                cols[b], cols[c] = cq * cols[b] + sq * cols[c], cq * cols[c] - sq * cols[b]
        elif np.any(q):
            p = p + cols[a] * q
        yield j, revolute, a, iv, cols, p


def batch_placements(model: pin.Model, Q: np.ndarray, frame: str = "smr", jacobian: bool = False,
                     angular: bool = False):
    """``frame``'s placement for every configuration at once (numpy, no loop over the poses), and with
    ``jacobian`` its positional frame Jacobian (world-aligned), for models whose joints from the root to
    the frame are 1-dof axis joints (the error model's, :func:`build_error_model`). The same numbers as
    pinocchio's ``forwardKinematics`` / ``getFrameJacobian(LOCAL_WORLD_ALIGNED)`` to rounding (tested),
    faster than its loop over the poses (docs/speed.md "Measurements behind the code"). None for any other model.

    Parameters
    ----------
    Q : ndarray, shape (n, nq), rad (and m for prismatic joints)

    Returns
    -------
    R : ndarray, shape (n, 3, 3); p : ndarray, shape (n, 3), m; J : ndarray, shape (n, 3, nv), m per unit
    of each coordinate (only with ``jacobian``; shape (n, 6, nv) with ``angular``: rows 3-5 the angular
    velocity, rad per unit, pinocchio's 6-row ``LOCAL_WORLD_ALIGNED`` Jacobian), or None
    """
    chain = _chain(model, frame)
    if chain is None:
        return None
    joints, Rf, pf = chain
    Q = np.asarray(Q, float)
    n = len(Q)
    cols, p = _origin(n)
    axes = []
    for j, revolute, a, iv, cols, p in _walk(joints, Q):
        if jacobian:
            axes.append((iv, revolute, cols[a], p))
    pw = _moved(p, cols, pf)
    cols = _turned(cols, Rf)
    Rw = np.stack(cols, axis=0).transpose(2, 1, 0)          # (n, 3, 3): [pose, row, column]
    if not jacobian:
        return Rw, pw.T, None
    Jt = np.zeros((model.nv, 6 if angular else 3, n))
    for iv, revolute, w, o in axes:
        if revolute:
            d = pw - o
            Jt[iv, 0] = w[1] * d[2] - w[2] * d[1]
            Jt[iv, 1] = w[2] * d[0] - w[0] * d[2]
            Jt[iv, 2] = w[0] * d[1] - w[1] * d[0]
            if angular:
                Jt[iv, 3:] = w
        else:
            Jt[iv, :3] = w
    return Rw, pw.T, Jt.transpose(2, 1, 0)


def batch_frames(model: pin.Model, Q: np.ndarray, frames: list, joints: tuple = (), last: str = "smr"):
    """The placements of several frames (and joints) on the chain from the root to ``last``, for every
    configuration at once: one walk of :func:`batch_placements`' numpy kinematics instead of pinocchio's
    loop over the poses (docs/speed.md "Measurements behind the code"). None when the chain is not all 1-dof
    axis joints or a frame is not on it.

    Parameters
    ----------
    Q : ndarray, shape (n, nq), rad (and m for prismatic joints)
    frames : list of str
        Frames on the chain to ``last``.
    joints : tuple of int
        Pinocchio joint ids on that chain whose placements (``data.oMi``) are wanted too.

    Returns
    -------
    dict name-or-joint-id -> (R (n, 3, 3), p (n, 3) m), or None
    """
    chain = _chain(model, last)
    if chain is None:
        return None
    steps = chain[0]
    on = {j for j, *_ in steps}
    want = {}
    for name in frames:
        fr = model.frames[model.getFrameId(name)]
        parent = int(fr.parentJoint if hasattr(fr, "parentJoint") else fr.parent)
        if parent not in on:
            return None
        want.setdefault(parent, []).append((name, np.array(fr.placement.rotation), np.array(fr.placement.translation)))
    if any(int(j) not in on for j in joints):
        return None

    def placed(cols, p):
        return np.stack(cols, axis=0).transpose(2, 1, 0), p.T.copy()

    out = {}
    for j, revolute, a, iv, cols, p in _walk(steps, Q):
        if j in joints:
            out[j] = placed(cols, p)
        for name, Rf, pf in want.get(j, ()):
            out[name] = placed(_turned(cols, Rf), _moved(p, cols, pf))
    return out


def positions(model: pin.Model, Q: np.ndarray, frame: str = "smr") -> np.ndarray:
    """Position of ``frame`` for every configuration.

    Parameters
    ----------
    Q : ndarray, shape (n, nq), rad (and m for prismatic error joints)

    Returns
    -------
    ndarray, shape (n, 3), mm
    """
    batch = batch_placements(model, Q, frame)
    if batch is not None:
        return batch[1] * 1000.0
    data = model.createData()
    fid = model.getFrameId(frame)
    out = np.empty((len(Q), 3))
    for k, q in enumerate(np.asarray(Q, float)):
        pin.forwardKinematics(model, data, q)
        out[k] = pin.updateFramePlacement(model, data, fid).translation
    return out * 1000.0


def placements(model: pin.Model, Q: np.ndarray, frame: str = "flange") -> tuple[np.ndarray, np.ndarray]:
    """Rotation (n, 3, 3) and translation (n, 3) mm of ``frame``."""
    batch = batch_placements(model, Q, frame)
    if batch is not None:
        return batch[0], batch[1] * 1000.0
    data = model.createData()
    fid = model.getFrameId(frame)
    R = np.empty((len(Q), 3, 3))
    p = np.empty((len(Q), 3))
    for k, q in enumerate(np.asarray(Q, float)):
        pin.forwardKinematics(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        R[k] = M.rotation
        p[k] = M.translation
    return R, p * 1000.0


def positions_and_jacobians(model: pin.Model, Q: np.ndarray, frame: str = "smr") -> tuple[np.ndarray, np.ndarray]:
    """Position and positional frame Jacobian (world-aligned) of ``frame``.

    Returns
    -------
    P : ndarray, shape (n, 3), mm
    J : ndarray, shape (n, 3, nv), mm per unit of each coordinate (rad or m)
    """
    batch = batch_placements(model, Q, frame, jacobian=True)
    if batch is not None:
        return batch[1] * 1000.0, batch[2] * 1000.0
    data = model.createData()
    fid = model.getFrameId(frame)
    n = len(Q)
    P = np.empty((n, 3))
    J = np.empty((n, 3, model.nv))
    for k, q in enumerate(np.asarray(Q, float)):
        pin.computeJointJacobians(model, data, q)
        P[k] = pin.updateFramePlacement(model, data, fid).translation
        J[k] = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
    return P * 1000.0, J * 1000.0


def pose_jacobians(model: pin.Model, Q: np.ndarray, frame: str = "smr"):
    """Placement and 6-row world-aligned Jacobian (linear mm, angular rad) of ``frame``."""
    batch = batch_placements(model, Q, frame, jacobian=True, angular=True)
    if batch is not None:
        R, P, J = batch
        J[:, :3] *= 1000.0
        return R, P * 1000.0, J
    data = model.createData()
    fid = model.getFrameId(frame)
    n = len(Q)
    R = np.empty((n, 3, 3))
    P = np.empty((n, 3))
    J = np.empty((n, 6, model.nv))
    for k, q in enumerate(np.asarray(Q, float)):
        pin.computeJointJacobians(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        R[k], P[k] = M.rotation, M.translation
        J[k] = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
    J[:, :3] *= 1000.0
    return R, P * 1000.0, J


def gravity_torques(robot: Robot, q_deg: np.ndarray, payload_kg=None, model: pin.Model | None = None) -> np.ndarray:
    """Joint torques that hold the arm (and a payload at the SMR point) against gravity.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    payload_kg : ndarray, shape (n,), kg, optional
        Mass carried at the flange, lumped at the SMR point.

    Returns
    -------
    ndarray, shape (n, N), N m (positive: the torque the motor must apply in +q_i)
    """
    model = model or build_model(robot)
    data = model.createData()
    fid = model.getFrameId("smr")
    q = np.deg2rad(np.atleast_2d(np.asarray(q_deg, float)))
    payload = np.zeros(len(q)) if payload_kg is None else np.broadcast_to(np.asarray(payload_kg, float), (len(q),))
    out = np.empty((len(q), model.nv))
    for k in range(len(q)):
        tau = pin.computeGeneralizedGravity(model, data, q[k]).copy()
        if payload[k] != 0.0:
            pin.computeJointJacobians(model, data, q[k])
            Jz = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[2]
            tau += payload[k] * G * Jz
        out[k] = tau
    return out


def inverse_kinematics(model: pin.Model, R_target, p_target_mm, q0_rad, frame="smr", iters=50, tol=1e-12):
    """Joint angles (rad) that put ``frame`` at the target pose (damped Newton on log6).

    Parameters
    ----------
    model : pin.Model
        The plain arm (N joints).
    R_target : ndarray, shape (3, 3)
    p_target_mm : ndarray, shape (3,), mm
    q0_rad : ndarray, shape (N,), rad, start
    """
    data = model.createData()
    fid = model.getFrameId(frame)
    target = pin.SE3(np.asarray(R_target, float), np.asarray(p_target_mm, float) / 1000.0)
    q = np.array(q0_rad, float)
    for _ in range(iters):
        pin.forwardKinematics(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        err = pin.log6(M.actInv(target)).vector
        if err @ err < tol:
            break
        J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
        q = q + np.linalg.solve(J.T @ J + 1e-12 * np.eye(model.nv), J.T @ err)
    return q


def directions_from_sequence(q_deg, start_deg=None, start_dir=None):
    """Sign of each joint's last motion along a visiting sequence (carry the sign when unchanged).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg, in visiting order
    start_deg : ndarray, shape (N,), optional
        Where the robot was before the first pose (first pose gets +1 when absent).
    """
    q = np.atleast_2d(np.asarray(q_deg, float))
    n, N = q.shape
    prev_d = np.ones(N, int) if start_dir is None else np.broadcast_to(np.asarray(start_dir, int), (N,))
    if n == 0:
        return np.empty(q.shape, int)
    # each pose's move from the one before (the first from start_deg; none without it), +1 / -1 / 0 (no
    # move, or not a number), and a 0 carries the last sign before it (start_dir before the first): one
    # pass for every pose at once, not a loop over the poses
    before = np.vstack([q[:1] if start_deg is None else np.asarray(start_deg, float)[None], q[:-1]])
    diff = q - before
    step = (diff > 0).astype(int) - (diff < 0).astype(int)
    at = np.where(step != 0, np.arange(n)[:, None], -1)
    last = np.maximum.accumulate(at, axis=0)
    return np.where(last >= 0, np.take_along_axis(step, np.maximum(last, 0), axis=0), prev_d[None, :])
