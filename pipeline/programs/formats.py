"""The four formats' numbers as joints and poses (units and conventions of contract section 11).

=========  ==========================  ===============================================  ======================
format     joint target numbers        Cartesian target numbers                         turn data
=========  ==========================  ===============================================  ======================
krl        A1..A6 deg                  X, Y, Z mm, A, B, C deg (Rz(A) Ry(B) Rx(C))       T (int)
rapid      j1..j6 deg                  x, y, z mm, q1..q4 (q1 = w)                       (cf1, cf4, cf6)
fanuc      J1..J6 deg                  X, Y, Z mm, W, P, R deg (Rz(R) Ry(P) Rx(W))       (t1, t2, t3)
ur         q1..q6 rad                  x, y, z m, rx, ry, rz rad (rotation vector)       none
=========  ==========================  ===============================================  ======================
"""

from __future__ import annotations

import numpy as np

from . import conventions as cv


def joints_deg(fmt: str, values) -> np.ndarray:
    """Joint values (deg) of a joint target's numbers."""
    v = np.asarray(values, float)
    return np.rad2deg(v) if fmt == "ur" else v


def joint_values(fmt: str, q_deg) -> np.ndarray:
    """A joint target's numbers of joint values (deg)."""
    q = np.asarray(q_deg, float)
    return np.deg2rad(q) if fmt == "ur" else q


def pose(fmt: str, values) -> np.ndarray:
    """4 x 4 pose (mm) of a Cartesian target's numbers."""
    v = [float(x) for x in values]
    if fmt == "krl":
        return cv.homogeneous(cv.kuka_matrix(*v[3:6]), v[:3])
    if fmt == "fanuc":
        return cv.homogeneous(cv.fanuc_matrix(*v[3:6]), v[:3])
    if fmt == "rapid":
        return cv.homogeneous(cv.abb_matrix(*v[3:7]), v[:3])
    if fmt == "ur":
        return cv.homogeneous(cv.ur_matrix(*v[3:6]), np.array(v[:3]) * 1000.0)
    raise ValueError(fmt)


def pose_values(fmt: str, T, near) -> np.ndarray:
    """A Cartesian target's numbers of a 4 x 4 pose (mm), the rotation written nearest ``near`` (the
    numbers as given: the same Euler solution, quaternion hemisphere, rotation-vector branch)."""
    T = np.asarray(T, float)
    near = [float(x) for x in near]
    if fmt == "krl":
        return np.array([*T[:3, 3], *cv.kuka_abc(T[:3, :3], near[3:6])])
    if fmt == "fanuc":
        return np.array([*T[:3, 3], *cv.fanuc_wpr(T[:3, :3], near[3:6])])
    if fmt == "rapid":
        # the norm of the quaternion as written (rounded; the controller normalises): kept, so that an
        # unchanged rotation spells the same
        return np.array([*T[:3, 3], *(np.array(cv.abb_quaternion(T[:3, :3], near[3:7])) * np.linalg.norm(near[3:7]))])
    if fmt == "ur":
        return np.array([*(T[:3, 3] / 1000.0), *cv.ur_rotvec(T[:3, :3], near[3:6])])
    raise ValueError(fmt)


def frame_pose(fmt: str, values) -> np.ndarray:
    """A ``--tool`` / ``--base`` value (6 numbers: X Y Z mm and the format's rotation: KUKA A B C,
    FANUC W P R deg, UR rotation vector rad; RAPID: 7 numbers x y z q1 q2 q3 q4) as a 4 x 4 pose (mm)."""
    v = [float(x) for x in values]
    if fmt == "ur":
        return cv.homogeneous(cv.ur_matrix(*v[3:6]), v[:3])
    return pose(fmt, v)


def frame_arity(fmt: str) -> int:
    return 7 if fmt == "rapid" else 6


def turn_ok(fmt: str, turn, q_deg) -> bool:
    """Whether joint values (deg) have the turn / quadrant data a target names (None: any)."""
    if turn is None:
        return True
    if fmt == "krl":
        return cv.kuka_turn(q_deg) == (int(turn) & 63)
    if fmt == "rapid":
        return cv.abb_quadrants(q_deg) == tuple(turn)
    if fmt == "fanuc":
        return cv.fanuc_turns(q_deg) == tuple(turn)
    return True
