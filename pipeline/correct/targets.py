"""The targets file of ``jointcal correct`` (contract section 8): read and checked, every problem located.

One row per point, in visiting order: ``point_id, q1 … qN`` (deg), optionally ``x_mm, y_mm, z_mm``
(the point to reach, robot base frame), ``payload_kg``, ``dir1 … dirN``, ``temperature_c``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..core.tables import FLOAT, SIGN, STR, check_unique_ids, csv_header, find_joint_columns, read_table
from ..core.units import REFERENCE_TEMPERATURE_C

#: A point to reach this far (mm) from the nominal kinematics of its own joint values is not the same
#: pose: another frame, metres, or a row out of step (a real robot's errors are a few mm at most).
MAX_TARGET_OFFSET_MM = 25.0


@dataclass
class Targets:
    """A program's points as arrays (n rows, N joints); see :func:`read_targets`."""

    point_id: np.ndarray      # (n,) str
    q_deg: np.ndarray         # (n, N) deg
    target_mm: np.ndarray     # (n, 3) mm, NaN rows: the nominal kinematics' position
    dirs: np.ndarray | None   # (n, N) +1/-1, or None: from the visiting order
    payload_kg: np.ndarray    # (n,) kg (``default_payload_kg`` where the row gives none)
    temperature_c: np.ndarray  # (n,) degC
    lines: np.ndarray         # (n,) 1-based file lines
    payload_given: np.ndarray = None  # (n,) bool: the row gives its payload_kg
    target_R: np.ndarray | None = None  # (n, 3, 3) the probe / tool frame to reach (qw..qz), NaN rows: the program's


def read_targets(path, n_joints: int, nominal_xyz=None, default_payload_kg: float = 0.0) -> Targets:
    """Read and check a targets file; the first problem raises an InputError (file, line, column).

    Parameters
    ----------
    n_joints : int
        Joints of the model's robot (N).
    nominal_xyz : callable, optional
        ``q_deg (n, N) -> (n, 3) mm``: the nominal SMR position, to refuse points that are not the
        pose's (beyond :data:`MAX_TARGET_OFFSET_MM`).
    default_payload_kg : float, kg
        Payload of a row without ``payload_kg`` (``jointcal correct``: the payload the model was
        fitted at, when it was one).
    """
    qcols = [f"q{j}" for j in range(1, n_joints + 1)]
    optional = {"x_mm": FLOAT, "y_mm": FLOAT, "z_mm": FLOAT, "payload_kg": FLOAT, "temperature_c": FLOAT,
                "qw": FLOAT, "qx": FLOAT, "qy": FLOAT, "qz": FLOAT,
                **{f"dir{j}": SIGN for j in range(1, n_joints + 1)}}
    frame = read_table(path, {"point_id": STR, **{c: FLOAT for c in qcols}}, optional)
    header = csv_header(path)
    extra = [c for c in find_joint_columns(header, n_joints).extra if c.startswith("q") and int(c[1:]) > n_joints]
    if extra:
        raise InputError(path, f"column '{extra[0]}': the model's robot has {n_joints} joints (q1 … q{n_joints})",
                         1, extra[0])
    lines = frame["_line"].to_numpy(int)
    check_unique_ids(path, frame, "point_id '{id}' appears twice; ids must be unique")
    xyz_cols = [c for c in ("x_mm", "y_mm", "z_mm") if c in frame]
    if xyz_cols and len(xyz_cols) < 3:
        missing = [c for c in ("x_mm", "y_mm", "z_mm") if c not in frame]
        raise InputError(path, f"'{xyz_cols[0]}' given without '{missing[0]}': the point to reach needs x_mm, y_mm "
                         "and z_mm (or none of them)", 1, xyz_cols[0])
    n = len(frame)
    target = np.full((n, 3), np.nan)
    if xyz_cols:
        target = frame[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        part = np.isnan(target).any(axis=1) & ~np.isnan(target).all(axis=1)
        if part.any():
            k = int(np.argmax(part))
            col = ("x_mm", "y_mm", "z_mm")[int(np.argmax(np.isnan(target[k])))]
            raise InputError(path, "the point to reach is given in part: fill x_mm, y_mm and z_mm, or leave all "
                             "three empty for the nominal kinematics' position", lines[k], col)
    dir_cols = [f"dir{j}" for j in range(1, n_joints + 1)]
    dirs = None
    have = [c for c in dir_cols if c in frame]
    if have:
        if len(have) < n_joints:
            missing = [c for c in dir_cols if c not in frame][0]
            raise InputError(path, f"'{have[0]}' given without '{missing}': give every joint's direction "
                             "(dir1 … dirN) or none (then they follow from the visiting order)", 1, have[0])
        d = frame[dir_cols].to_numpy(float)
        if np.isnan(d).any():
            k, j = np.argwhere(np.isnan(d))[0]
            raise InputError(path, "empty direction: give +1 or -1", lines[k], dir_cols[j])
        dirs = d.astype(int)
    given = frame["payload_kg"].notna().to_numpy(bool) if "payload_kg" in frame else np.zeros(n, bool)
    payload = (frame["payload_kg"].fillna(default_payload_kg).to_numpy(float) if "payload_kg" in frame
               else np.full(n, float(default_payload_kg)))
    if (payload < 0).any():
        k = int(np.argmax(payload < 0))
        raise InputError(path, f"payload_kg {payload[k]:g} is negative", lines[k], "payload_kg")
    temp = (frame["temperature_c"].fillna(REFERENCE_TEMPERATURE_C).to_numpy(float) if "temperature_c" in frame
            else np.full(n, REFERENCE_TEMPERATURE_C))
    q = frame[qcols].to_numpy(float)
    if nominal_xyz is not None and xyz_cols:
        given = ~np.isnan(target).any(axis=1)
        if given.any():
            off = np.full(n, 0.0)
            off[given] = np.linalg.norm(target[given] - nominal_xyz(q[given]), axis=1)
            if off.max() > MAX_TARGET_OFFSET_MM:
                k = int(np.argmax(off > MAX_TARGET_OFFSET_MM))   # the first such row
                raise InputError(path, f"the point to reach is {off[k]:.1f} mm from where the nominal kinematics "
                                 f"put q1 … q{n_joints} (more than a robot's errors, {MAX_TARGET_OFFSET_MM:g} mm): "
                                 "x_mm/y_mm/z_mm must be that pose's point in the robot base frame, in mm (not "
                                 "metres, not the tracker's frame), and q in degrees", lines[k], "x_mm")
    return Targets(frame["point_id"].astype(str).to_numpy(), q, target, dirs, payload, temp, lines, given,
                   _orientations(path, frame, lines))


QUATERNION = ("qw", "qx", "qy", "qz")


def _orientations(path, frame, lines):
    """The frames to reach (n, 3, 3) from qw..qz (a unit quaternion, scalar first, base frame), NaN where a
    row gives none; None when the file has no such columns."""
    have = [c for c in QUATERNION if c in frame]
    if not have:
        return None
    missing = [c for c in QUATERNION if c not in frame]
    if missing:
        raise InputError(path, f"'{have[0]}' given without '{missing[0]}': the orientation to reach needs qw, qx, "
                         "qy and qz (a unit quaternion, scalar first) or none of them", 1, have[0])
    qv = frame[list(QUATERNION)].to_numpy(float)
    part = np.isnan(qv).any(axis=1) & ~np.isnan(qv).all(axis=1)
    if part.any():
        k = int(np.argmax(part))
        raise InputError(path, "the orientation to reach is given in part: fill qw, qx, qy and qz, or leave all four "
                         "empty for the program's own", lines[k], QUATERNION[int(np.argmax(np.isnan(qv[k])))])
    given = ~np.isnan(qv).any(axis=1)
    norm = np.linalg.norm(np.where(given[:, None], qv, 1.0), axis=1)
    bad = given & ~(np.abs(norm - 1.0) <= 1e-3)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(path, f"the quaternion (qw, qx, qy, qz) has norm {norm[k]:.6g}, not 1: give a unit "
                         "quaternion, scalar first", lines[k], "qw")
    from scipy.spatial.transform import Rotation

    R = np.full((len(qv), 3, 3), np.nan)
    if given.any():
        u = qv[given] / norm[given, None]
        R[given] = Rotation.from_quat(u[:, [1, 2, 3, 0]]).as_matrix()
    return R
