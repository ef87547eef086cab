"""Every vendor convention of the program formats in one place (contract section 11).

Rotations (each tested against an independent formula, scipy's ``Rotation``, in
``tests/test_programs_conventions.py``):

* KUKA ``A, B, C`` (deg): ``R = Rz(A) . Ry(B) . Rx(C)``;
* FANUC ``W, P, R`` (deg): ``R = Rz(R) . Ry(P) . Rx(W)`` (the same matrix as KUKA's with the triple reversed);
* ABB quaternion ``[q1, q2, q3, q4]``: ``q1 = w`` (scalar first), normalised when read;
* UR ``p[x, y, z, rx, ry, rz]``: metres and a rotation vector (axis times angle, rad).

Configuration data, from the arm's three branch flags (:func:`pipeline.programs.ik.arm_flags`:
``rear`` - the wrist point behind joint 1's axis; ``down`` - elbow down, the wrist point below the
line through the axes of joints 2 and 3; ``flip`` - joint 5 negative, counted from the wrist
singularity) and the joint values:

* KUKA ``S`` = rear + 2 * (not down) + 4 * flip (bits 3 and up are kept, never read); ``T`` bit i
  (i = 0..5) set when joint i + 1 is negative;
* ABB ``cf1, cf4, cf6`` = floor(q / 90 deg) of joints 1, 4, 6; ``cfx`` = 4 * rear + 2 * down + flip;
* FANUC ``CONFIG : 'F|N U|D T|B, t1, t2, t3'``: N = flip, D = down, B = rear; turns t1, t2, t3 of
  joints 1, 4 and 6 (RoboDK's reading; decision, see docs/programs.md), the turn k of an angle q being
  the k with q in (-180 + 360 k, 180 + 360 k].

Pure functions of numbers; no file, no robot.
"""

from __future__ import annotations

import math

import numpy as np


# ------------------------------------------------------------------------------ rotations
def rot_x(deg: float) -> np.ndarray:
    """Rotation about x by ``deg`` degrees, shape (3, 3)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    """Rotation about y by ``deg`` degrees, shape (3, 3)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(deg: float) -> np.ndarray:
    """Rotation about z by ``deg`` degrees, shape (3, 3)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(R, p_mm) -> np.ndarray:
    """4 x 4 pose from a rotation (3, 3) and a position (3,) mm."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p_mm
    return T


def invert(T) -> np.ndarray:
    """Inverse of a 4 x 4 rigid pose."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _wrap_near(angle_deg: float, near_deg: float) -> float:
    return angle_deg + 360.0 * round((near_deg - angle_deg) / 360.0)


def zyx_matrix(a_deg: float, b_deg: float, c_deg: float) -> np.ndarray:
    """``Rz(a) . Ry(b) . Rx(c)``."""
    return rot_z(a_deg) @ rot_y(b_deg) @ rot_x(c_deg)


def zyx_angles(R, near=None) -> tuple[float, float, float]:
    """``(a, b, c)`` deg with ``Rz(a) Ry(b) Rx(c) = R``; of the two solutions, the one nearest ``near``
    (each angle taken within 360 deg of the near one), else the one with ``|b| <= 90``."""
    R = np.asarray(R, float)
    b = math.degrees(math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0])))
    if math.hypot(R[0, 0], R[1, 0]) < 1e-9:               # gimbal lock (b within 6e-8 deg of +-90)
        # only a - c (b = +90) or a + c (b = -90) is defined: keep the near c (a program's own split of
        # the two, so an unchanged rotation keeps its numbers), else put everything on a
        d = math.degrees(math.atan2(-R[0, 1], R[1, 1]))
        if near is not None:
            c = float(near[2])
            a = d + c if b > 0 else d - c
            return tuple(float(_wrap_near(v, float(n))) for v, n in zip((a, b, c), near))
        a, c = d, 0.0
    else:
        a = math.degrees(math.atan2(R[1, 0], R[0, 0]))
        c = math.degrees(math.atan2(R[2, 1], R[2, 2]))
    sols = [(a, b, c), (a + 180.0, 180.0 - b, c + 180.0)]
    if near is None:
        return tuple(float(_wrap_near(v, 0.0)) for v in sols[0])
    near = [float(v) for v in near]
    best = None
    for s in sols:
        w = tuple(_wrap_near(v, n) for v, n in zip(s, near))
        d = sum((v - n) ** 2 for v, n in zip(w, near))
        if best is None or d < best[0]:
            best = (d, w)
    return best[1]


def kuka_matrix(a: float, b: float, c: float) -> np.ndarray:
    """KUKA ``A, B, C`` (deg): ``Rz(A) Ry(B) Rx(C)``."""
    return zyx_matrix(a, b, c)


def kuka_abc(R, near=None) -> tuple[float, float, float]:
    """KUKA ``(A, B, C)`` deg of a rotation, nearest ``near`` (an ``(A, B, C)``)."""
    return zyx_angles(R, near)


def fanuc_matrix(w: float, p: float, r: float) -> np.ndarray:
    """FANUC ``W, P, R`` (deg): ``Rz(R) Ry(P) Rx(W)``."""
    return zyx_matrix(r, p, w)


def fanuc_wpr(R, near=None) -> tuple[float, float, float]:
    """FANUC ``(W, P, R)`` deg of a rotation, nearest ``near`` (a ``(W, P, R)``)."""
    r, p, w = zyx_angles(R, None if near is None else (near[2], near[1], near[0]))
    return w, p, r


def abb_matrix(q1: float, q2: float, q3: float, q4: float) -> np.ndarray:
    """ABB quaternion ``[q1, q2, q3, q4]`` with ``q1 = w``: the rotation (normalised first)."""
    q = np.array([q1, q2, q3, q4], float)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def abb_quaternion(R, near=None) -> tuple[float, float, float, float]:
    """ABB ``(q1, q2, q3, q4)`` (``q1 = w``) of a rotation, in the hemisphere of ``near``
    (default ``q1 >= 0``)."""
    R = np.asarray(R, float)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q) / np.linalg.norm(q)
    ref = np.array([1.0, 0.0, 0.0, 0.0]) if near is None else np.asarray(near, float)
    if q @ ref < 0:
        q = -q
    return tuple(float(v) for v in q)


def ur_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """UR rotation vector (rad): the rotation by its length about its direction (Rodrigues)."""
    v = np.array([rx, ry, rz], float)
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def ur_rotvec(R, near=None) -> tuple[float, float, float]:
    """UR rotation vector (rad) of a rotation; of the equivalent vectors (angle + 2 pi k, or the
    opposite axis), the one nearest ``near`` (default the one of angle <= pi)."""
    w, x, y, z = abb_quaternion(R)
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-15:
        base = np.zeros(3)
        axis = None
    else:
        th = 2.0 * math.atan2(s, w)
        axis = np.array([x, y, z]) / s
        base = axis * th
    if near is None or axis is None:
        return tuple(float(v) for v in base)
    near = np.asarray(near, float)
    th = float(np.linalg.norm(base))
    cands = [axis * (th + 2 * math.pi * k) for k in (-1, 0, 1)] + [-axis * (2 * math.pi - th + 2 * math.pi * k)
                                                                   for k in (-1, 0, 1)]
    best = min(cands, key=lambda c: float(np.sum((c - near) ** 2)))
    return tuple(float(v) for v in best)


# ------------------------------------------------------------------------ configuration data
def kuka_status(rear: bool, down: bool, flip: bool) -> int:
    """KUKA ``S`` bits 0-2: rear (1), elbow up (2), flip (4)."""
    return int(rear) + 2 * int(not down) + 4 * int(flip)


def kuka_status_flags(S: int) -> tuple[bool, bool, bool]:
    """``(rear, down, flip)`` of a KUKA ``S`` (bits 3 and up ignored)."""
    return bool(S & 1), not bool(S & 2), bool(S & 4)


def kuka_turn(q_deg) -> int:
    """KUKA ``T``: bit i set when joint i + 1 (i = 0..5) is negative."""
    return sum(1 << i for i, v in enumerate(np.asarray(q_deg, float)[:6]) if v < 0)


def abb_quadrants(q_deg) -> tuple[int, int, int]:
    """ABB ``cf1, cf4, cf6``: floor(q / 90 deg) of joints 1, 4 and 6."""
    q = np.asarray(q_deg, float)
    return int(math.floor(q[0] / 90.0)), int(math.floor(q[3] / 90.0)), int(math.floor(q[5] / 90.0))


def abb_cfx(rear: bool, down: bool, flip: bool) -> int:
    """ABB ``cfx`` of a six-axis arm: 4 * rear + 2 * (wrist behind the lower arm: elbow down) + flip."""
    return 4 * int(rear) + 2 * int(down) + int(flip)


def abb_cfx_flags(cfx: int) -> tuple[bool, bool, bool]:
    """``(rear, down, flip)`` of an ABB ``cfx`` (0..7)."""
    return bool(cfx & 4), bool(cfx & 2), bool(cfx & 1)


def fanuc_letters(rear: bool, down: bool, flip: bool) -> str:
    """FANUC configuration letters ``'F|N U|D T|B'``: N = flip, D = elbow down, B = rear."""
    return f"{'N' if flip else 'F'} {'D' if down else 'U'} {'B' if rear else 'T'}"


def fanuc_letter_flags(letters: str) -> tuple[bool, bool, bool]:
    """``(rear, down, flip)`` of FANUC letters such as ``'N U T'`` (any order, any spacing);
    ValueError when a letter pair is missing or repeated."""
    found = {}
    for ch in letters.upper().replace(",", " ").split():
        for c in ch:
            for key, (no, yes) in {"flip": ("F", "N"), "down": ("U", "D"), "rear": ("T", "B")}.items():
                if c in (no, yes):
                    if key in found:
                        raise ValueError(f"'{letters}' names {key} twice")
                    found[key] = c == yes
            if c not in "FNUDTB":
                raise ValueError(f"'{c}' is not a FANUC configuration letter (F/N, U/D, T/B)")
    if len(found) != 3:
        raise ValueError(f"'{letters}' needs one of F/N, one of U/D and one of T/B")
    return found["rear"], found["down"], found["flip"]


def fanuc_turn(q_deg: float) -> int:
    """FANUC turn number k of an angle: q in (-180 + 360 k, 180 + 360 k]."""
    return int(math.ceil((float(q_deg) - 180.0) / 360.0))


def fanuc_turns(q_deg) -> tuple[int, int, int]:
    """FANUC turns t1, t2, t3: of joints 1, 4 and 6 (decision, docs/programs.md)."""
    q = np.asarray(q_deg, float)
    return fanuc_turn(q[0]), fanuc_turn(q[3]), fanuc_turn(q[5])
