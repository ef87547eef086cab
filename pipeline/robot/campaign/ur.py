"""A Universal Robots ``calibration.conf`` as the nominal robot (contract section 6).

A UR is calibrated at the factory: its controller's kinematics are UR's published classic DH of
the model plus the deltas of the robot's own ``calibration.conf`` (``[mounting]``: ``delta_theta``,
``delta_a``, ``delta_d``, ``delta_alpha``, six values each, rad and m):
``T_i = Rz(q_i + theta_i + delta_theta_i) Tz(d_i + delta_d_i) Tx(a_i + delta_a_i) Rx(alpha_i + delta_alpha_i)``.
On the nearly parallel joints 2-4 the file's ``d`` reaches hundreds of metres (the common normal of
two axes a fraction of a milliradian apart lies far away). The robot.toml keeps the same joint axes
and flange exactly but writes joints 2 and 3 with ``d = 0`` and the tilt in ``alpha`` and ``beta``
(the contract's ``Ry(beta)``), so every link frame stays on the arm and a fit on top of it is as
well conditioned as on UR's table; the masses keep their place on the links (each centre of mass
is carried from the published link frame into the robot's), so gravity torques are the real arm's.

The published tables (``UR_DH``) are UR's "DH parameters for calculations of kinematics and
dynamics" (universal-robots.com); masses and centres of mass where that page gives them.
"""

from __future__ import annotations

import re

import numpy as np

from ...core.errors import InputError
from ..arm.kinematics import Joint, Robot

_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)
#: model -> (a [m], d [m]) of joints 1..6; theta 0 and alpha (pi/2, 0, 0, pi/2, -pi/2, 0) for all
UR_DH = {
    "ur3": ((0, -0.24365, -0.21325, 0, 0, 0), (0.1519, 0, 0, 0.11235, 0.08535, 0.0819)),
    "ur5": ((0, -0.425, -0.39225, 0, 0, 0), (0.089159, 0, 0, 0.10915, 0.09465, 0.0823)),
    "ur10": ((0, -0.612, -0.5723, 0, 0, 0), (0.1273, 0, 0, 0.163941, 0.1157, 0.0922)),
    "ur3e": ((0, -0.24355, -0.2132, 0, 0, 0), (0.15185, 0, 0, 0.13105, 0.08535, 0.0921)),
    "ur5e": ((0, -0.425, -0.3922, 0, 0, 0), (0.1625, 0, 0, 0.1333, 0.0997, 0.0996)),
    "ur10e": ((0, -0.6127, -0.57155, 0, 0, 0), (0.1807, 0, 0, 0.17415, 0.11985, 0.11655)),
    "ur16e": ((0, -0.4784, -0.36, 0, 0, 0), (0.1807, 0, 0, 0.17415, 0.11985, 0.11655)),
    "ur20": ((0, -0.862, -0.7287, 0, 0, 0), (0.2363, 0, 0, 0.201, 0.1593, 0.1543)),
    "ur30": ((0, -0.637, -0.5037, 0, 0, 0), (0.2363, 0, 0, 0.201, 0.1593, 0.1543)),
}
#: model -> (masses [kg], centres of mass [m] in the published link frames {i}), where UR publishes them
UR_MASS = {
    "ur10": ((7.1, 12.7, 4.27, 2.0, 2.0, 0.365),
             ((0.021, 0, 0.027), (0.38, 0, 0.158), (0.24, 0, 0.068), (0, 0.007, 0.018), (0, 0.007, 0.018),
              (0, 0, -0.026))),
    "ur3e": ((1.98, 3.4445, 1.437, 0.871, 0.805, 0.261),
             ((0, -0.02, 0), (0.13, 0, 0.1157), (0.05, 0, 0.0238), (0, 0, 0.01), (0, 0, 0.01), (0, 0, -0.02))),
    "ur5e": ((3.761, 8.058, 2.846, 1.37, 1.3, 0.365),
             ((0, -0.02561, 0.00193), (0.2125, 0, 0.11336), (0.15, 0, 0.0265), (0, -0.0018, 0.01634),
              (0, 0.0018, 0.01634), (0, 0, -0.001159))),
    "ur20": ((16.343, 29.632, 7.879, 3.054, 3.126, 0.846),
             ((0, -0.061, 0.0062), (0.5226, 0, 0.2098), (0.3234, 0, 0.0604), (0, -0.0026, 0.0393),
              (0, 0.0024, 0.0379), (0, -0.0003, -0.0318))),
}
KEYS = ("delta_theta", "delta_a", "delta_d", "delta_alpha")


def published_dh(model: str) -> dict:
    """UR's published classic DH of ``model``: ``theta, a, d, alpha`` arrays (6,), rad and m."""
    a, d = UR_DH[model]
    return {"theta": np.zeros(6), "a": np.array(a, float), "d": np.array(d, float), "alpha": np.array(_ALPHA)}


def is_calibration_conf(path) -> bool:
    """Whether a robot file is a UR ``calibration.conf`` (by name or by its ``[mounting]`` deltas)."""
    from pathlib import Path

    p = Path(path)
    if p.suffix.lower() == ".conf":
        return True
    try:
        head = p.read_bytes()[:4096].decode("latin-1")
    except OSError:
        return False
    return "[mounting]" in head and "delta_theta" in head


def parse_calibration_conf(text: str, path="<calibration.conf>") -> dict:
    """The ``[mounting]`` deltas of a ``calibration.conf``: ``delta_theta`` ... ``delta_alpha`` (6,), rad and m.

    Other sections and keys are not read. InputError (file:line:column) for a missing section or
    key, a list that is not six finite numbers, or a key given twice.
    """
    section, found, lines = None, {}, text.splitlines()
    for k, raw in enumerate(lines, 1):
        s = raw.split("#")[0].split(";")[0].strip() if not raw.lstrip().startswith("[") else raw.strip()
        if not s:
            continue
        m = re.fullmatch(r"\[\s*([^\]]+?)\s*\]", s)
        if m:
            section = m.group(1).lower()
            continue
        if section != "mounting" or "=" not in s:
            continue
        key, value = (t.strip() for t in s.split("=", 1))
        if key not in KEYS:
            continue
        col = raw.index(value) + 1 if value in raw else 1
        if key in found:
            raise InputError(path, f"[mounting] {key} is given twice (first at line {found[key][1]})", k, col)
        body = value.strip()
        if not (body.startswith("[") and body.endswith("]")):
            raise InputError(path, f"[mounting] {key}: expected [v1, v2, v3, v4, v5, v6] (rad and m)", k, col)
        try:
            v = np.array([float(x) for x in body[1:-1].split(",")], float)
        except ValueError:
            raise InputError(path, f"[mounting] {key}: not six numbers ({body[:60]})", k, col) from None
        if v.shape != (6,) or not np.isfinite(v).all():
            raise InputError(path, f"[mounting] {key}: expected six finite numbers, got {len(v)}", k, col)
        found[key] = (v, k)
    missing = [key for key in KEYS if key not in found]
    if missing:
        where = next((k for k, raw in enumerate(lines, 1) if raw.strip().lower() == "[mounting]"), 1)
        raise InputError(path, f"no {', '.join(missing)} in a [mounting] section (a UR calibration.conf has "
                         "delta_theta, delta_a, delta_d and delta_alpha)", where, 1)
    return {key: found[key][0] for key in KEYS}


def _frames(theta, d, a, alpha) -> list:
    """Link frames {1..6} at q = 0 of a classic DH chain: 4 x 4 each (m)."""
    out, M = [], np.eye(4)
    for t, dd, aa, al in zip(theta, d, a, alpha):
        ct, st, ca, sa = np.cos(t), np.sin(t), np.cos(al), np.sin(al)
        M = M @ np.array([[ct, -st * ca, st * sa, aa * ct], [st, ct * ca, -ct * sa, aa * st],
                          [0, sa, ca, dd], [0, 0, 0, 1.0]])
        out.append(M)
    return out


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _tr(x, y, z):
    M = np.eye(4)
    M[:3, 3] = (x, y, z)
    return M


def _link(theta, d, a, alpha, beta=0.0):
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)``, 4 x 4 (m)."""
    return _rz(theta) @ _tr(0, 0, d) @ _tr(a, 0, 0) @ _rx(alpha) @ _ry(beta)


def _parallel_row(A, p, u, theta_near):
    """A row with ``d = 0`` from frame A (4 x 4) to the joint axis through p along u (base frame): the
    origin where the axis meets A's x-y plane, the tilt in ``alpha`` and ``beta`` (Hayati's form for
    nearly parallel axes). Returns (theta, a, alpha, beta)."""
    Ai = np.linalg.inv(A)
    pl = Ai[:3, :3] @ p + Ai[:3, 3]
    ul = Ai[:3, :3] @ u
    o = pl - (pl[2] / ul[2]) * ul                   # on the axis, z = 0 in A
    a = float(np.hypot(o[0], o[1]))
    theta = float(np.arctan2(o[1], o[0]))
    alt = float(np.arctan2(-o[1], -o[0]))
    if abs(np.angle(np.exp(1j * (alt - theta_near)))) < abs(np.angle(np.exp(1j * (theta - theta_near)))):
        theta, a = alt, -a                          # the sign of a that keeps theta near UR's
    w = _rz(theta)[:3, :3].T @ ul
    beta = float(np.arcsin(np.clip(w[0], -1.0, 1.0)))
    alpha = float(np.arctan2(-w[1], w[2]))
    return theta, a, alpha, beta


def _dh_row(A, B):
    """The classic DH row from frame A to frame B (both 4 x 4), B's x axis on the common normal."""
    M = np.linalg.solve(A, B)
    theta = float(np.arctan2(M[1, 0], M[0, 0]))
    a = float(M[0, 3] * np.cos(theta) + M[1, 3] * np.sin(theta))
    return theta, float(M[2, 3]), a, float(np.arctan2(M[2, 1], M[2, 2]))


def robot_from_calibration(deltas: dict, model: str, tool_mm=(0.0, 0.0, 0.0), path="<calibration.conf>") -> Robot:
    """The robot's own calibrated kinematics as a contract :class:`Robot` (lengths mm, angles deg).

    The joint axes and the flange of UR's calibrated classic DH at q = 0 are kept exactly; joints 2
    and 3, whose axes are nearly parallel to the one before, are written with ``d = 0`` and the tilt
    in ``alpha`` and ``beta`` (the contract's link transform allows it), so that no link frame lies
    hundreds of metres away; joint 4's row follows from them, joints 1, 5, 6 are UR's rows. The
    flange frame is UR's frame {6}. The forward kinematics equals the calibrated DH's (checked).

    Parameters
    ----------
    deltas : dict
        :func:`parse_calibration_conf` of the robot's file (rad and m).
    model : str
        ``ur3`` ... ``ur30`` (:data:`UR_DH`).
    tool_mm : sequence of 3 float, mm
        The SMR in the flange frame (UR's tool flange frame {6}).
    """
    if model not in UR_DH:
        raise InputError(path, f"unknown UR model '{model}' (one of {', '.join(UR_DH)})", None, None)
    nom = published_dh(model)
    cal = {k: nom[k] + deltas["delta_" + k] for k in ("theta", "a", "d", "alpha")}
    masses, coms = UR_MASS.get(model, ((0.0,) * 6, ((0.0, 0.0, 0.0),) * 6))
    F_nom = _frames(nom["theta"], nom["d"], nom["a"], nom["alpha"])
    F_cal = _frames(cal["theta"], cal["d"], cal["a"], cal["alpha"])
    rows, frames, A = [], [], np.eye(4)
    for i in range(6):
        if i in (1, 2):                             # the next axis nearly parallel to this one
            theta, a, alpha, beta = _parallel_row(A, F_cal[i][:3, 3], F_cal[i][:3, 2], nom["theta"][i])
            row = (theta, 0.0, a, alpha, beta)
        elif i == 3:
            row = (*_dh_row(A, F_cal[i]), 0.0)
        else:
            row = (cal["theta"][i], cal["d"][i], cal["a"][i], cal["alpha"][i], 0.0)
        A = A @ _link(*row)
        rows.append(row)
        frames.append(A)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (8, 6))
    for qq in q:                                    # the same arm as the file's classic DH, flange included
        M, N = np.eye(4), np.eye(4)
        for k in range(6):
            M = M @ _link(rows[k][0] + qq[k], *rows[k][1:])
            N = N @ _link(cal["theta"][k] + qq[k], cal["d"][k], cal["a"][k], cal["alpha"][k])
        if np.abs(M - N).max() > 1e-9:
            raise InputError(path, "the calibration's kinematics could not be written without its far link frames "
                             f"(a difference of {np.abs(M - N).max():.3g} m): are these the deltas of a {model.upper()}?",
                             None, None)
    joints = []
    for i, (theta, d, a, alpha, beta) in enumerate(rows):
        c = np.linalg.solve(frames[i], F_nom[i] @ np.r_[np.asarray(coms[i], float), 1.0])[:3]
        joints.append(Joint(a_mm=float(a * 1000.0), alpha_deg=float(np.rad2deg(alpha)), d_mm=float(d * 1000.0),
                            theta_offset_deg=float(np.rad2deg(theta)), beta_deg=float(np.rad2deg(beta)),
                            lower_deg=-360.0, upper_deg=360.0, mass_kg=float(masses[i]),
                            com_mm=tuple(float(x) for x in c * 1000.0)))
    return Robot(model, tuple(joints), tuple(float(v) for v in tool_mm), str(path), ur_model=model)


def calibration_header(path, sha: str, model: str, deltas: dict) -> str:
    """Comment lines of a robot.toml made from a calibration.conf."""
    big = float(np.abs(deltas["delta_d"]).max())
    return "\n".join([
        f"# Nominal kinematics derived by `jointcal import` from the UR calibration.conf {path} (sha256 {sha}):",
        f"# UR's published classic DH of the {model.upper()} plus the file's [mounting] deltas, as the robot's",
        "# controller uses them: T_i = Rz(q_i + theta_i + delta_theta_i) Tz(d_i + delta_d_i) Tx(a_i + delta_a_i)",
        f"# Rx(alpha_i + delta_alpha_i); the largest |delta_d| is {big:.6g} m (nearly parallel axes): the same axes",
        "# and flange are written here with d = 0 and beta on joints 2 and 3 (forward kinematics equal to < 1 nm).",
        "# Masses and centres of mass: UR's published ones carried into the calibrated link frames"
        + ("" if model in UR_MASS else " (none published here for this model: 0)") + ".",
        f'# ur_model = "{model}": `jointcal export --format ur` writes deltas against the published table.'])
