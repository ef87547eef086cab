"""A URDF's arm as the contract's robot (``robot.toml``, classic DH plus beta).

The contract's link transform (section 2) is

    T_i = Rz(q_i + theta_offset_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i) . Ry(beta_i)

i.e. classic Denavit-Hartenberg: frame {i-1}'s z axis is joint i's axis, x_i lies on the
common normal of the axes of joints i and i+1. :func:`robot_from_urdf` reads the URDF with
pinocchio (fixed joints are composed into the links they hang from), walks the chain of
revolute joints from the base link to the tip link, and derives the parameters from the
joint axes at q = 0:

* frame {0} is the base link's frame; its z axis must be joint 1's axis, through its origin -
  otherwise the arm cannot be written without a base transform and the import is refused
  (``--base`` names another link of the fixed base, e.g. UR's ``base``). A joint 1 turning about
  -z (ROS-Industrial's KUKA descriptions: ``joint_a1`` has axis ``0 0 -1``) is the same arm with
  joint 1's angle counted the other way: a turn q about -z is a turn -q about +z, so the robot gets
  the ``[coupling]`` row ``q1 = { q1 = -1.0 }`` (its kinematics take -q1 of the recorded, the
  URDF's, angle) and joint 1's limits as that angle's, [-upper, -lower];
* for skew axes x_i is the unit common normal, a_i its length, d_i the distance along
  z_{i-1}; for intersecting axes x_i = +-(z_{i-1} x z_i), a_i = 0; for parallel axes the
  common normal through O_{i-1} is taken (d_i = 0, the offset moves on to d_{i+1});
* of the two directions of x_i the one nearer x_{i-1} is kept (a_i changes sign instead), so
  theta_offset is 0 wherever the geometry allows - UR's published DH comes out as published;
* frame {N} (N the chain's revolute joints, 4 to 7; fixed joints folded in, a prismatic or
  continuous joint refused, naming it) has z along joint N's axis with its origin where the
  tip link's origin projects onto it (d_N) and x along the tip link's x axis when the tip's z
  is joint N's axis; ``[tool] xyz_mm`` is the tip link's origin (or ``tool_mm`` given in the
  tip link's frame) in frame {N};
* beta_i = 0 (nominal parallel axes are exactly parallel; beta is for the identified errors);
* mass and centre of mass of link i: the URDF inertias of everything rigidly attached to
  joint i (pinocchio lumps fixed links), centre expressed in DH frame {i}; joint limits from
  the URDF in degrees.

The result is checked: the derived robot's SMR position must agree with pinocchio's URDF
model to < 1e-6 mm at 64 random configurations (the URDF's angles recorded, the robot's
``[coupling]`` applied), else the import is refused.
"""

from __future__ import annotations

import difflib
import os
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from ...core.errors import InputError
from ...core.files import read_text_input
from ..arm.kinematics import MAX_JOINTS, MIN_JOINTS, Joint, Robot, build_model, positions

FK_TOLERANCE_MM = 1e-6
FK_CHECKS = 64
_REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
_EPS = 1e-9


def tag_line(text: str, tag: str, name: str | None = None) -> tuple[int | None, int | None]:
    """Line and column of the element ``<tag name="name" ...>`` (or the first ``<tag``) in URDF text.

    A joint is also named inside ``<transmission>``; its definition (with ``type=``) is preferred.
    """
    pat = r"<\s*" + re.escape(tag) + (r"\b[^>]*\bname\s*=\s*[\"']" + re.escape(name) + r"[\"'][^>]*>" if name else r"\b")
    found = list(re.finditer(pat, text))
    if not found:
        return None, None
    m = next((f for f in found if re.search(r"\btype\s*=", f.group(0))), found[0])
    line = text.count("\n", 0, m.start()) + 1
    col = m.start() - (text.rfind("\n", 0, m.start()) + 1) + 1
    return line, col


def _fail(path, text, message, tag="robot", name=None):
    line, col = tag_line(text, tag, name)
    if line is None:
        line, col = tag_line(text, "robot")
    raise InputError(path, message, line, col)


def _read_urdf(path):
    """Text, the parsed XML root and pinocchio's model of a URDF (errors located)."""
    text = read_text_input(path, "URDF")
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as exc:
        line, col = exc.position
        raise InputError(path, f"not valid XML: {str(exc).split(':')[0]}", line, col + 1) from None
    if root.tag != "robot":
        raise InputError(path, f"not a URDF: the root element is <{root.tag}>, expected <robot>", 1, 1)
    # urdfdom writes its complaints to file descriptor 2 itself: catch them for the one error line
    with tempfile.TemporaryFile(mode="w+b") as err:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            model = pin.buildModelFromUrdf(str(path))
            problem = None
        except (RuntimeError, ValueError) as exc:
            model, problem = None, " ".join(str(exc).split())
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        said = [ln.strip() for ln in err.read().decode("utf-8", "replace").splitlines()
                if ln.strip().startswith("Error:")]
    if model is None:
        detail = "; ".join(s.removeprefix("Error:").strip() for s in said[:2]) or problem
        named = re.search(r"(joint|link) \[([^\]]+)\]", detail)
        _fail(path, text, f"pinocchio cannot read this URDF: {detail[:300]}", *(named.groups() if named else ("robot",)))
    return text, root, model


def _body_frame(path, text, root, model, name, option):
    links = [ln.get("name") for ln in root.iter("link")]
    if name not in links:
        close = difflib.get_close_matches(name, links, n=3)
        hint = f" (close: {', '.join(close)})" if close else f" (links: {', '.join(links[:12])}{'...' if len(links) > 12 else ''})"
        joint_names = [j.get("name") for j in root.iter("joint")]
        if name in joint_names:
            child = next(j.find("child") for j in root.iter("joint") if j.get("name") == name)
            hint = f": '{name}' is a joint; {option} names a link, e.g. its child '{child.get('link')}'"
        _fail(path, text, f"no link '{name}' in the URDF for {option}{hint}")
    fid = next((k for k, f in enumerate(model.frames) if f.name == name and f.type == pin.FrameType.BODY), None)
    if fid is None:
        _fail(path, text, f"pinocchio's model of the URDF has no body frame '{name}'", "link", name)
    return fid


def _chain(path, text, model, tip_fid, base_fid):
    """Joint ids from the base to the tip (N revolute joints, 4 to 7) and their local axes."""
    jid = model.frames[tip_fid].parentJoint
    chain = []
    while jid != 0:
        chain.append(jid)
        jid = model.parents[jid]
    chain.reverse()
    if model.frames[base_fid].parentJoint != 0:
        name = model.frames[base_fid].name
        _fail(path, text, f"--base link '{name}' moves with joint '{model.names[model.frames[base_fid].parentJoint]}'; "
              "the base must be a link of the fixed base, before joint 1", "link", name)
    axes = []
    for j in chain:
        jm = model.joints[j]
        kind = jm.shortname()
        if kind in _REVOLUTE:
            axes.append(np.array(_REVOLUTE[kind]))
        elif kind == "JointModelRevoluteUnaligned":
            axes.append(np.asarray(jm.extract().axis, float).copy())
        else:
            what = ("a continuous joint" if "Unbounded" in kind or "RUB" in kind
                    else "a prismatic joint" if "Prismatic" in kind or kind.startswith("JointModelP")
                    else f"a {kind.replace('JointModel', '')} joint")
            _fail(path, text, f"joint '{model.names[j]}' on the chain to the tip is {what}; the contract's robot has "
                  f"{MIN_JOINTS} to {MAX_JOINTS} revolute joints with limits", "joint", model.names[j])
    if not MIN_JOINTS <= len(chain) <= MAX_JOINTS:
        names = ", ".join(model.names[j] for j in chain) or "none"
        _fail(path, text, f"the chain from the base to the tip has {len(chain)} revolute joints ({names}); "
              f"the contract's robot has {MIN_JOINTS} to {MAX_JOINTS}")
    return chain, axes


def _angle(u, v, axis) -> float:
    """Signed angle (rad) turning u into v about axis."""
    return float(np.arctan2(np.cross(u, v) @ axis, u @ v))


def _dh(points, dirs, tip_p, tip_R):
    """Classic DH parameters from the N joint axes (points, unit directions; base frame, mm).

    Returns a list of N dicts (a, alpha, d, theta in mm / rad) and the frames {0..N}
    (origin, x, z) at q = 0.
    """
    O, x, z = np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    frames = [(O, x, z)]
    params = []
    n_joints = len(points)
    for i in range(n_joints):
        if i < n_joints - 1:
            zn, pn = dirs[i + 1], points[i + 1]
            c = np.cross(z, zn)
            s = np.linalg.norm(c)
            if s > _EPS:
                w = O - pn
                b, dd, e = z @ zn, z @ w, zn @ w
                den = 1.0 - b * b
                t = (b * e - dd) / den
                u = (e - b * dd) / den
                c1, c2 = O + t * z, pn + u * zn
                n = c2 - c1
                a = float(np.linalg.norm(n))
                if a > 1e-9:
                    xn = n / a
                else:
                    xn, a = c / s, 0.0
                d = float(t)
            else:
                w = pn - O
                perp = w - (w @ z) * z
                a = float(np.linalg.norm(perp))
                d = 0.0
                xn = perp / a if a > 1e-9 else x.copy()
                if a <= 1e-9:
                    a = 0.0
        else:
            zn = z
            d = float((tip_p - O) @ z)
            a = 0.0
            tz, tx = tip_R[:, 2], tip_R[:, 0]
            if abs(abs(tz @ z) - 1.0) < 1e-9:
                xn = tx - (tx @ z) * z
                xn /= np.linalg.norm(xn)
            else:
                xn = x.copy()
        if xn @ x < -1e-6:
            xn, a = -xn, -a
        theta = _angle(x, xn, z)
        alpha = _angle(z, zn, xn)
        On = O + d * z + a * xn
        params.append({"a": a, "alpha": alpha, "d": d, "theta": theta})
        O, x, z = On, xn, zn
        frames.append((O, x, z))
    return params, frames


def _clean(v, nd=9) -> float:
    v = round(float(v), nd)
    return 0.0 if v == 0 else v


def _sanitize(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "robot"


def robot_from_urdf(path, tip: str, base: str | None = None, tool_mm=None, checks: int = FK_CHECKS):
    """The contract's :class:`Robot` for the arm of a URDF, checked against pinocchio's model.

    Parameters
    ----------
    path : path-like
        The URDF.
    tip : str
        Link whose origin is the SMR (``tool_mm`` None) or to which ``tool_mm`` is relative.
    base : str, optional
        Link of the fixed base whose frame is the robot's base frame {0} (default: the root).
    tool_mm : sequence of 3 floats, optional
        SMR position in the tip link's frame (mm); default its origin.

    Returns
    -------
    robot : Robot
    info : dict
        ``chain`` (joint names), ``base``, ``tip``, ``fk_max_error_mm`` (the check), ``checks``,
        ``tip_in_flange`` (R (3, 3), t (3,) mm: the tip link's frame in the flange frame {N}, a point p
        of the tip's frame at ``R p + t``), ``joint1_reversed`` (True: joint 1 turns about -z of the base
        frame in the URDF; the robot's ``[coupling]`` takes -q1).
    """
    text, root, model = _read_urdf(path)
    tip_fid = _body_frame(path, text, root, model, tip, "--tip")
    if base is None:
        base_fid = next(k for k, f in enumerate(model.frames) if f.type == pin.FrameType.BODY and f.parentJoint == 0)
    else:
        base_fid = _body_frame(path, text, root, model, base, "--base")
    chain, axes = _chain(path, text, model, tip_fid, base_fid)
    data = model.createData()
    q0 = pin.neutral(model)
    pin.forwardKinematics(model, data, q0)
    pin.updateFramePlacements(model, data)
    oMb = data.oMf[base_fid].copy()
    Rb, pb = oMb.rotation, oMb.translation * 1000.0
    points = [Rb.T @ (data.oMi[j].translation * 1000.0 - pb) for j in chain]
    dirs = []
    for j, ax in zip(chain, axes):
        v = Rb.T @ (data.oMi[j].rotation @ ax)
        dirs.append(v / np.linalg.norm(v))
    oMt = data.oMf[tip_fid]
    tool_local = np.zeros(3) if tool_mm is None else np.asarray(tool_mm, float)
    tip_R = Rb.T @ oMt.rotation
    tip_p = Rb.T @ (oMt.translation * 1000.0 - pb)
    smr = tip_p + tip_R @ tool_local
    base_name = model.frames[base_fid].name
    j1 = model.names[chain[0]]
    up = np.array([0.0, 0.0, 1.0])
    # joint 1 about -z through the origin: the same arm, its angle counted the other way ([coupling] q1 = -q1)
    reversed1 = bool(np.linalg.norm(dirs[0] + up) <= 1e-9 and np.linalg.norm(points[0][:2]) <= 1e-6)
    if reversed1:
        dirs[0] = up.copy()
    if np.linalg.norm(dirs[0] - up) > 1e-9 or np.linalg.norm(points[0][:2]) > 1e-6:
        cands = []
        for k, f in enumerate(model.frames):
            if f.type != pin.FrameType.BODY or f.parentJoint != 0:
                continue
            M = data.oMf[k]
            d = M.rotation.T @ (data.oMi[chain[0]].rotation @ axes[0])
            p = M.rotation.T @ (data.oMi[chain[0]].translation - M.translation) * 1000.0
            if min(np.linalg.norm(d - up), np.linalg.norm(d + up)) <= 1e-9 and np.linalg.norm(p[:2]) <= 1e-6:
                cands.append(f.name)
        hint = f"; links that would do: {', '.join(cands)}" if cands else ""
        what = ("turns about ({:.4g}, {:.4g}, {:.4g})".format(*dirs[0]) if np.linalg.norm(dirs[0] - [0, 0, 1]) > 1e-9
                else "has its axis off the origin by ({:.4g}, {:.4g}) mm".format(*points[0][:2]))
        _fail(path, text, f"joint 1 '{j1}' {what} in the base frame '{base_name}': the contract's base frame has z "
              f"along joint 1's axis, through its origin; pass --base LINK{hint}", "joint", j1)
    params, frames = _dh(points, dirs, tip_p, tip_R)
    # link frames {i} at q = 0 as 4x4 (base frame, mm)
    Ts = []
    for O, x, z in frames:
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, O
        Ts.append(T)
    TN = Ts[len(chain)]
    tool = TN[:3, :3].T @ (smr - TN[:3, 3])
    joints = []
    for i, (j, p) in enumerate(zip(chain, params)):
        inertia = model.inertias[j]
        mass = float(inertia.mass)
        com_world = Rb.T @ (data.oMi[j].act(inertia.lever) * 1000.0 - pb)
        Ti = Ts[i + 1]
        com = Ti[:3, :3].T @ (com_world - Ti[:3, 3]) if mass > 0 else np.zeros(3)
        iq = model.joints[j].idx_q
        lo, hi = float(model.lowerPositionLimit[iq]), float(model.upperPositionLimit[iq])
        lo_deg = max(np.rad2deg(lo), -360.0) if np.isfinite(lo) else -360.0
        hi_deg = min(np.rad2deg(hi), 360.0) if np.isfinite(hi) else 360.0
        if not lo_deg < hi_deg:
            _fail(path, text, f"joint '{model.names[j]}' has no range (lower {lo:g} >= upper {hi:g} rad); "
                  "give it <limit lower=... upper=...>", "joint", model.names[j])
        if i == 0 and reversed1:
            lo_deg, hi_deg = -hi_deg, -lo_deg     # the limits are of the angle the kinematics take, -q1
        joints.append(Joint(a_mm=_clean(p["a"]), alpha_deg=_clean(np.rad2deg(p["alpha"])), d_mm=_clean(p["d"]),
                            theta_offset_deg=_clean(np.rad2deg(p["theta"])), beta_deg=0.0,
                            lower_deg=_clean(lo_deg), upper_deg=_clean(hi_deg), mass_kg=_clean(mass),
                            com_mm=tuple(_clean(c, 6) for c in com)))
    coupling = ((0, (-1.0,) + (0.0,) * (len(chain) - 1)),) if reversed1 else ()
    robot = Robot(_sanitize(root.get("name") or Path(str(path)).stem), tuple(joints),
                  tuple(_clean(c) for c in tool), str(path), coupling=coupling)
    err = fk_agreement(robot, model, chain, base_fid, tip_fid, tool_local, checks)
    # the tip link's frame in the flange frame {N}: a point p in the tip's frame is R p + t in {N}
    tip_in_flange = (TN[:3, :3].T @ tip_R, TN[:3, :3].T @ (tip_p - TN[:3, 3]))
    info = {"chain": [model.names[j] for j in chain], "base": base_name, "tip": tip, "fk_max_error_mm": err,
            "checks": checks, "tip_in_flange": tip_in_flange, "joint1_reversed": reversed1}
    if not err < FK_TOLERANCE_MM:
        _fail(path, text, f"the DH parameters derived from the URDF disagree with pinocchio's URDF model by up to "
              f"{err:.3g} mm at random configurations (tolerance {FK_TOLERANCE_MM:g} mm); refused", "joint", j1)
    return robot, info


def fk_agreement(robot: Robot, model, chain, base_fid, tip_fid, tool_local_mm, n=FK_CHECKS, seed=0) -> float:
    """Largest distance (mm) between the robot's SMR and the URDF's at ``n`` random configurations.

    The URDF is given the recorded angles, the robot's kinematics the angles its ``[coupling]`` makes
    of them (a joint 1 about -z in the URDF: -q1)."""
    rng = np.random.default_rng(seed)
    Q = rng.uniform(np.deg2rad(robot.lower_deg), np.deg2rad(robot.upper_deg), size=(n, robot.n_joints))
    mine = positions(build_model(robot), Q, "smr")
    Q = robot.recorded_angles(Q)          # (the coupling is linear: radians as degrees)
    data = model.createData()
    theirs = np.empty((n, 3))
    tool = np.asarray(tool_local_mm, float) / 1000.0
    for k in range(n):
        q = pin.neutral(model)
        for i, j in enumerate(chain):
            q[model.joints[j].idx_q] = Q[k, i]
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        bMt = data.oMf[base_fid].actInv(data.oMf[tip_fid])
        theirs[k] = bMt.act(tool) * 1000.0
    return float(np.abs(mine - theirs).max()) if n else 0.0
