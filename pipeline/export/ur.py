"""``jointcal export --format ur``: Universal Robots' convention (contract section 8).

Two files from the fitted rigid chain (:func:`pipeline.export.chain.folded_chain`):

* ``calibration.conf``-style ``[mounting]`` with ``delta_theta``, ``delta_a``, ``delta_d``, ``delta_alpha``
  (one value per joint, rad and m): the fitted chain's standard (classic) DH parameters minus the
  nominal robot's, the DH being ``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` from UR's base
  frame {0} (z along joint 1) to the flange frame {N} (z along the last joint). Where consecutive axes
  are nearly parallel (UR's joints 2-4) the common normal lies far away and ``d`` reaches hundreds of
  metres, as in UR's own controller files: exact, but no physical length.
* the ROS driver's kinematics YAML (``kinematics:`` with ``shoulder``, ``upper_arm``, ``forearm``,
  ``wrist_1``, ``wrist_2``, ``wrist_3``; ``x, y, z, roll, pitch, yaw``, m and rad, URDF's
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``): joint i's origin in joint i-1's frame. The same chain with sane
  origins: every joint frame sits where the model's own (MDH) frames are - the job ``ur_calibration``
  of the ROS driver does by moving the DH frames back along the nearly parallel axes.

What neither holds is said in both (as comments): the base transform from the model's base frame to
UR's frame {0} (the DH form needs z along joint 1; the YAML's ``shoulder`` carries it) and the SMR in
the flange frame (UR's TCP setting).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

UR_NAMES = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
#: below this |z_{i-1} x z_i| two axes are taken as exactly parallel (d = 0 by convention)
PARALLEL_TOL = 1e-12


def _num(v) -> str:
    v = float(v)
    return "0.0" if v == 0.0 else repr(v)


def axes_at_zero(chain: dict) -> tuple[list[pin.SE3], pin.SE3]:
    """Joint frames (z = axis) in the model's base frame at zero command, and the flange frame."""
    frames, M = [], pin.SE3.Identity()
    for o in chain["origins"]:
        M = M * o
        frames.append(M)
    return frames, M * chain["flange"]


def standard_dh(chain: dict, reference: dict | None = None) -> dict:
    """Classic DH parameters of a folded chain (m, rad) and the transforms it leaves out.

    Frame {0}: z along joint 1, origin the point of joint 1's axis nearest the base origin, x the
    base x made perpendicular. Frame {i} (i < N): z along joint i+1, x along the common normal of
    axes i and i+1 (sign: closest to ``reference``'s x_i, or to x_{i-1}). Frame {N}: z along joint
    N, origin the flange's foot on it, x the flange's x made perpendicular.

    Returns
    -------
    dict ``theta, d, a, alpha`` (N,), ``base`` (SE3, model base <- {0}), ``tool`` (SE3, {N} <- flange),
    ``x`` (list of x axes, for ``reference``).
    """
    frames, flange = axes_at_zero(chain)
    n = len(frames)
    z = [F.rotation[:, 2].copy() for F in frames]
    p = [F.translation.copy() for F in frames]
    # frame {0}
    z0 = z[0]
    o0 = p[0] - (p[0] @ z0) * z0          # the foot of the base origin on joint 1's axis
    x0 = np.array([1.0, 0.0, 0.0]) - z0[0] * z0
    if np.linalg.norm(x0) < 1e-6:
        x0 = np.array([0.0, 1.0, 0.0]) - z0[1] * z0
    x0 /= np.linalg.norm(x0)
    o, x, zz = [o0], [x0], [z0]
    theta, d, a, alpha = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(1, n + 1):
        zp, op, xp = zz[-1], o[-1], x[-1]
        if i < n:
            zi, pi = z[i], p[i]
            cn = np.cross(zp, zi)
            ref = reference["x"][i] if reference is not None else xp
            if np.linalg.norm(cn) > PARALLEL_TOL:
                xi = cn / np.linalg.norm(cn)
                if xi @ ref < 0:
                    xi = -xi
                s, ai, t = np.linalg.solve(np.column_stack([zp, xi, -zi]), pi - op)
                oi = pi + t * zi
                di = s
            else:
                perp = (pi - op) - ((pi - op) @ zp) * zp
                if np.linalg.norm(perp) > 1e-12:
                    xi = perp / np.linalg.norm(perp)
                    if xi @ ref < 0:
                        xi = -xi
                else:
                    xi = xp
                ai = float(perp @ xi)
                di = 0.0
                oi = op + ai * xi
                # axis i+1 passes through oi (parallel axes): move oi onto it exactly
                oi = pi + ((oi - pi) @ zi) * zi
        else:
            zi = zp
            fo, fx = flange.translation, flange.rotation[:, 0]
            oi = op + ((fo - op) @ zp) * zp
            xi = fx - (fx @ zi) * zi
            xi /= np.linalg.norm(xi)
            di, ai = float((oi - op) @ zp), 0.0
        theta[i - 1] = np.arctan2(np.cross(xp, xi) @ zp, xp @ xi)
        alpha[i - 1] = np.arctan2(np.cross(zp, zi) @ xi, zp @ zi)
        d[i - 1], a[i - 1] = di, ai
        o.append(oi), x.append(xi), zz.append(zi)
    base = pin.SE3(np.column_stack([x[0], np.cross(zz[0], x[0]), zz[0]]), o[0])
    last = pin.SE3(np.column_stack([x[-1], np.cross(zz[-1], x[-1]), zz[-1]]), o[-1])
    return {"theta": theta, "d": d, "a": a, "alpha": alpha, "base": base, "tool": last.actInv(flange), "x": x}


def dh_transform(theta, d, a, alpha) -> pin.SE3:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha)``."""
    return (pin.SE3(pin.utils.rotate("z", theta), np.array([0.0, 0.0, d]))
            * pin.SE3(pin.utils.rotate("x", alpha), np.array([a, 0.0, 0.0])))


def dh_positions(dh: dict, smr: pin.SE3, q_deg) -> np.ndarray:
    """SMR positions (n, 3) mm of ``base . prod DH_i(q_i) . tool . smr`` (a check of the DH form)."""
    out = []
    for q in np.deg2rad(np.atleast_2d(q_deg)):
        M = dh["base"]
        for i, qi in enumerate(q):
            M = M * dh_transform(dh["theta"][i] + qi, dh["d"][i], dh["a"][i], dh["alpha"][i])
        out.append((M * dh["tool"] * smr).translation * 1000.0)
    return np.array(out)


def _pose_line(M: pin.SE3) -> str:
    rpy = pin.rpy.matrixToRpy(M.rotation)
    return (f"x {_num(M.translation[0])} y {_num(M.translation[1])} z {_num(M.translation[2])} "
            f"roll {_num(rpy[0])} pitch {_num(rpy[1])} yaw {_num(rpy[2])}")


def calibration_conf(fitted: dict, nominal: dict, smr: pin.SE3, comments: list[str]) -> str:
    """``calibration.conf``-style text: ``[mounting]`` deltas (fitted - nominal DH, rad and m).

    Read back by :func:`pipeline.robot.campaign.ur.parse_calibration_conf` (the one reader of a
    ``calibration.conf``, as ``jointcal import`` reads a UR's own)."""
    dtheta = np.angle(np.exp(1j * (fitted["theta"] - nominal["theta"])))
    lines = [f"# {c}" for c in comments]
    lines += ["# Standard DH: T_i = Rz(theta_i + delta_theta_i + q_i) Tz(d_i + delta_d_i) Tx(a_i + delta_a_i) "
              "Rx(alpha_i + delta_alpha_i); rad and m; deltas against the nominal robot's DH below.",
              "# nominal theta = [" + ", ".join(_num(v) for v in nominal["theta"]) + "]",
              "# nominal a     = [" + ", ".join(_num(v) for v in nominal["a"]) + "]",
              "# nominal d     = [" + ", ".join(_num(v) for v in nominal["d"]) + "]",
              "# nominal alpha = [" + ", ".join(_num(v) for v in nominal["alpha"]) + "]",
              "# Not in the DH form (set them in the cell: base frame / mounting, and TCP):",
              "# base frame <- DH frame {0}: " + _pose_line(fitted["base"]),
              "# TCP (SMR) in the flange frame {N}: " + _pose_line(fitted["tool"] * smr), ""]
    lines.append("[mounting]")
    for key, v in (("delta_theta", dtheta), ("delta_a", fitted["a"] - nominal["a"]),
                   ("delta_d", fitted["d"] - nominal["d"]), ("delta_alpha", fitted["alpha"] - nominal["alpha"])):
        lines.append(f"{key} = [" + ", ".join(_num(x) for x in v) + "]")
    return "\n".join(lines) + "\n"


def yaml_origins(chain: dict) -> list[pin.SE3]:
    """Joint i's origin in joint i-1's frame (joint 1: in the model's base frame): the folded chain's."""
    return list(chain["origins"])


def kinematics_yaml(chain: dict, comments: list[str], names=UR_NAMES) -> str:
    """The ROS driver's kinematics YAML (``kinematics:`` with ``x, y, z, roll, pitch, yaw`` per joint).

    ``tool0`` is the last joint's frame after its rotation, as UR's description has it; the flange
    (the model's) and the SMR in that frame are written as comments and as ``jointcal_flange`` /
    ``jointcal_smr`` entries beside ``kinematics``.
    """
    n = len(chain["origins"])
    names = list(names) + [f"joint_{k}" for k in range(len(names) + 1, n + 1)]
    lines = [f"# {c}" for c in comments] + ["kinematics:"]
    for name, M in zip(names, chain["origins"]):
        rpy = pin.rpy.matrixToRpy(M.rotation)
        lines += [f"  {name}:"] + [f"    {k}: {_num(v)}" for k, v in zip(("x", "y", "z"), M.translation)] + \
                 [f"    {k}: {_num(v)}" for k, v in zip(("roll", "pitch", "yaw"), rpy)]
    for name, M in (("jointcal_flange", chain["flange"]), ("jointcal_smr", chain["smr"])):
        rpy = pin.rpy.matrixToRpy(M.rotation)
        lines += [f"{name}:"] + [f"  {k}: {_num(v)}" for k, v in zip(("x", "y", "z"), M.translation)] + \
                 [f"  {k}: {_num(v)}" for k, v in zip(("roll", "pitch", "yaw"), rpy)]
    return "\n".join(lines) + "\n"


def yaml_positions(text: str, q_deg) -> np.ndarray:
    """SMR positions (n, 3) mm of a kinematics YAML written by :func:`kinematics_yaml` (a check)."""
    import yaml

    doc = yaml.safe_load(text)

    def se3(e):
        return pin.SE3(pin.rpy.rpyToMatrix(e["roll"], e["pitch"], e["yaw"]), np.array([e["x"], e["y"], e["z"]]))

    origins = [se3(v) for v in doc["kinematics"].values()]
    tail = se3(doc["jointcal_flange"]) * se3(doc["jointcal_smr"])
    out = []
    for q in np.deg2rad(np.atleast_2d(q_deg)):
        M = pin.SE3.Identity()
        for o, qi in zip(origins, q):
            M = M * o * pin.SE3(pin.utils.rotate("z", qi), np.zeros(3))
        out.append((M * tail).translation * 1000.0)
    return np.array(out)


def published_reference(robot, effects, parameters, folded) -> dict | None:
    """UR's published DH of the robot's model as :func:`standard_dh` gives it (``x`` axes included, for
    the fitted chain's sign choices), or None for a robot not imported from a calibration.conf.

    ``folded`` is :func:`pipeline.export.chain.folded_chain`; ``parameters`` the fit's (set to zero here).
    """
    if not getattr(robot, "ur_model", ""):
        return None
    from ..robot.campaign.ur import KEYS, robot_from_calibration
    from ..robot.model.estimator import RobotErrorModel

    pub = robot_from_calibration({k: np.zeros(6) for k in KEYS}, robot.ur_model, robot.tool_xyz_mm)
    zero = RobotErrorModel.from_parameters(pub, effects, [dict(p, value=0.0) for p in parameters])
    return standard_dh(folded(pub, zero))
