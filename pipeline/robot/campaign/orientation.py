"""A 6-DoF probe's orientation (contract section 13): conventions in, the probe's mounting, the checks.

A tracker's 6-DoF probe (a T-Mac, an optical CMM's target frame) measures the probe frame's
orientation beside its origin. ``tracker.csv`` carries it as a unit quaternion ``qw, qx, qy, qz``
(the probe frame in the frame of the positions); a vendor export carries it in its own convention,
which ``jointcal import`` reads through the map's ``[orientation]``:

* ``kind = "euler"``, ``sequence`` three letters of x, y, z: upper case intrinsic
  (``"XYZ"``: R = Rx(a) Ry(b) Rz(c), each turn about the axes already turned), lower case extrinsic
  (``"xyz"``: R = Rz(c) Ry(b) Rx(a), each turn about the fixed axes, in the order written);
* ``kind = "quaternion"``: four columns w, x, y, z;
* ``kind = "rotvec"``: a rotation vector (axis times angle);
* ``kind = "nest"``: a nest of three SMRs: ``[position]`` is SMR 1 (the probe frame's origin), the six
  columns SMRs 2 and 3 (same unit and frame); the probe frame has x from SMR 1 to SMR 2, z along the
  normal of the three, y = z x x (:func:`nest_frames`).

The probe's mounting on the flange (``robot.toml``'s ``[tool] rpy_deg``) is estimated from the data
as the tracker frame is: with the tracker-to-base rotation from the positions, the rotation M that
best maps every nominal flange frame onto its measured probe frame (``R_meas = R_flange M``), the
chordal mean of ``R_flange^T R_meas`` (:func:`mounting`).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from ...core.se3 import chordal_mean, rotation_angle  # noqa: F401 (chordal_mean: named here for the campaign's callers)

#: every Euler sequence (Tait-Bryan and proper), intrinsic (upper case) then extrinsic (lower case)
SEQUENCES = tuple("".join(p) for p in itertools.product("XYZ", repeat=3) if p[0] != p[1] and p[1] != p[2])
SEQUENCES = SEQUENCES + tuple(s.lower() for s in SEQUENCES)
ORIENTATION_UNITS = ("deg", "rad")
KINDS = ("euler", "quaternion", "rotvec", "nest")
#: the distances between a nest's SMRs may vary by this much (mm) from their median before a pose is
#: refused as a reseated or swapped SMR
NEST_TOL_MM = 0.5
#: A quaternion whose norm is off 1 by more than this is refused (tracker.csv, a quaternion export)
QUATERNION_NORM_TOL = 1e-3
#: A real robot's orientation errors after the best tracker frame and probe mounting stay well below a
#: degree (a UR10's nominal kinematics leave 0.08 deg RMS, a KR210's a few hundredths): the nominal
#: orientation check refuses an RMS beyond this (deg) as a wrong convention, not a robot's error.
MAX_ORIENTATION_RMS_DEG = 1.0
#: A stated convention is refused when another fits at least this many times better (RMS) ...
BETTER_FACTOR = 3.0
#: ... and the stated one is beyond what a robot's errors can be (deg)
STATED_BAD_DEG = 0.5
#: The probe's mounting estimated from the data is used instead of robot.toml's when they differ by
#: more than this (deg): beyond it the fit's small-angle model of the mounting would start far away
MOUNTING_TOL_DEG = 2.0


def nest_frames(p1, p2, p3) -> tuple[np.ndarray, np.ndarray, int]:
    """The probe frames of a nest of three SMRs, and how rigid the nest stayed.

    Parameters
    ----------
    p1, p2, p3 : array_like, shape (n, 3), mm
        SMRs 1, 2 and 3 at every pose (SMR 1 is the frame's origin).

    Returns
    -------
    R : ndarray, shape (n, 3, 3)
        x along SMR 1 -> SMR 2, z along (p2 - p1) x (p3 - p1), y = z x x.
    spread_mm : ndarray, shape (n,), mm
        The largest departure of the three SMR-to-SMR distances from their medians over the poses.
    worst : int
        The pose of the largest spread.
    """
    p1, p2, p3 = (np.asarray(p, float).reshape(-1, 3) for p in (p1, p2, p3))
    a, b = p2 - p1, p3 - p1
    with np.errstate(invalid="ignore", divide="ignore"):      # coincident or collinear SMRs: NaN frames
        x = a / np.linalg.norm(a, axis=1, keepdims=True)
        z = np.cross(a, b)
        z /= np.linalg.norm(z, axis=1, keepdims=True)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=2)
    d = np.column_stack([np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1), np.linalg.norm(p3 - p2, axis=1)])
    spread = np.abs(d - np.median(d, axis=0)).max(axis=1)
    return R, spread, int(np.argmax(spread)) if len(spread) else 0


def quaternions_to_matrices(q_wxyz) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of unit quaternions (n, 4), scalar first (w, x, y, z)."""
    q = np.asarray(q_wxyz, float).reshape(-1, 4)
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()


def matrices_to_quaternions(R) -> np.ndarray:
    """Unit quaternions (n, 4), scalar first, w >= 0, of rotation matrices (n, 3, 3)."""
    q = Rotation.from_matrix(np.asarray(R, float).reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    q[q[:, 0] < 0] *= -1.0
    return q


def euler_to_matrices(angles, sequence: str, unit: str = "deg") -> np.ndarray:
    """Rotation matrices (n, 3, 3) of Euler angles (n, 3) in ``unit`` (see the module docstring)."""
    a = np.asarray(angles, float).reshape(-1, 3)
    return Rotation.from_euler(sequence, a, degrees=(unit == "deg")).as_matrix()


def rotvecs_to_matrices(v, unit: str = "rad") -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors (n, 3) in ``unit``."""
    v = np.asarray(v, float).reshape(-1, 3)
    return Rotation.from_rotvec(np.deg2rad(v) if unit == "deg" else v).as_matrix()


def rpy_deg(R) -> np.ndarray:
    """URDF roll, pitch, yaw (deg) of a rotation (3, 3): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return Rotation.from_matrix(np.asarray(R, float)).as_euler("ZYX", degrees=True)[::-1]


def rpy_matrix(rpy) -> np.ndarray:
    """The rotation (3, 3) of URDF roll, pitch, yaw in deg."""
    return Rotation.from_euler("ZYX", np.asarray(rpy, float)[::-1], degrees=True).as_matrix()


def angles_deg(Ra, Rb) -> np.ndarray:
    """Angle (deg) between rotations Ra and Rb, batched over (..., 3, 3) (:func:`pipeline.core.se3.rotation_angle`)."""
    return np.degrees(rotation_angle(Ra, Rb))


def mounting(R_flange, R_meas_base, rows=None):
    """The probe's mounting on the flange and what it leaves.

    Parameters
    ----------
    R_flange : ndarray, shape (n, 3, 3)
        Nominal flange frames in the base frame.
    R_meas_base : ndarray, shape (n, 3, 3)
        Measured probe frames in the base frame.
    rows : ndarray of bool, shape (n,), optional
        Poses to estimate it on (default every pose).

    Returns
    -------
    M : ndarray, shape (3, 3), the probe frame in the flange frame
    err_deg : ndarray, shape (n,), the angle between each measured and nominal probe frame with M
    """
    R_flange, R_meas_base = np.asarray(R_flange, float), np.asarray(R_meas_base, float)
    rel = np.einsum("nji,njk->nik", R_flange, R_meas_base)
    rows = np.ones(len(rel), bool) if rows is None else np.asarray(rows, bool)
    M = chordal_mean(rel[rows])
    return M, angles_deg(R_flange @ M, R_meas_base)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0


def orientation_hypotheses(read, R_flange, R_tracker_to_base, rows=None) -> list[tuple[str, float, np.ndarray]]:
    """Each reading of the orientation columns with what it leaves after the best mounting.

    Parameters
    ----------
    read : dict label -> ndarray (n, 3, 3)
        The measured probe frames (tracker frame) under each convention tried.
    R_flange : ndarray, shape (n, 3, 3), nominal flange frames (base frame)
    R_tracker_to_base : ndarray, shape (3, 3), from the positions' rigid fit

    Returns
    -------
    list of ``(label, rms_deg, M)``, best first.
    """
    out = []
    for label, R in read.items():
        Rb = np.einsum("ij,njk->nik", R_tracker_to_base, R)
        M, err = mounting(R_flange, Rb, rows)
        out.append((label, rms(err), M))
    return sorted(out, key=lambda h: h[1])
