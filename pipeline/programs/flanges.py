"""Each program format's flange frame (the TCP of a null tool) on any robot, from URDF or robot.toml.

A program's Cartesian target is its TCP, and a TCP is given in the controller's own flange frame:
FANUC's faceplate (``UT : 0``), KUKA's ``$FLANGE`` (``TOOL_DATA`` of the null frame), ABB's ``tool0``,
UR's tool flange (``set_tcp(p[0, 0, 0, 0, 0, 0])``). A robot's kinematics (robot.toml, or a URDF
imported into one) end at the frame {N} of its last joint, whose x axis is wherever the DH
convention put it and whose z axis may point into the wrist (a URDF joint about ``-x``). The vendor's
flange frame is a fixed turn of {N}, found here the way each vendor defines it: by its orientation in
the robot's base frame at the controller's zero (every joint of the controller at 0; coupled joints
through robot.toml's ``[coupling]``), where each of these arms points its flange straight ahead:

========  =====================  ==========================================================  ==============
format    the vendor's frame     at the controller's zero (axes in the robot's base frame)   out of the flange
========  =====================  ==========================================================  ==============
fanuc     faceplate (UT : 0)     x up (+z), y = -y, z ahead (+x)  (W, P, R = 180, -90, 0)    z
krl       $FLANGE (null tool)    x ahead (+x), y = +y, z up (+z)  (A, B, C = 0, 0, 0)        x
rapid     tool0                  x down (-z), y = +y, z ahead (+x) (q = [0.7071, 0, 0.7071, 0])  z
ur        tool flange            x = +x, y up (+z), z = -y  (UR's published DH frame {6})    z
========  =====================  ==========================================================  ==============

The frames are those of ROS-Industrial's descriptions, whose link frames at joint zero are the
base's: FANUC's ``tool0`` (``flange`` turned by rpy (pi, -pi/2, 0)) is the faceplate; KUKA's
``flange`` is ``$FLANGE``; ABB's ``tool0`` (``link_6`` turned by rpy (0, pi/2, 0)) is ``tool0``; UR's
``tool0`` is the tool flange (docs/your-robot.md). The origin is that of {N}, on the last joint's
axis (the flange face of a robot.toml whose last ``d_mm`` reaches it; a URDF's ``--tip`` link origin).

A robot whose flange at the controller's zero does not lie along the vendor's "out of the flange"
axis, or lies behind the base along it (its joint zeros or its base frame are not the controller's),
gets no turn, and a note says so.

Pure functions of a robot's numbers; no file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import ik

#: the vendor's name of its flange frame, per program format
NAMES = {"fanuc": "FANUC's faceplate (UT : 0)", "krl": "KUKA's $FLANGE", "rapid": "ABB's tool0",
         "ur": "UR's tool flange"}

#: each vendor's flange frame at the controller's zero, columns x, y, z in the robot's base frame,
#: and which of its axes points out of the flange
AT_ZERO = {
    "fanuc": (np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]), 2),
    "krl": (np.eye(3), 0),
    "rapid": (np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]), 2),
    "ur": (np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]), 2),
}

#: the last joint's axis at the controller's zero is the vendor's "out of the flange" axis within this (rad)
ALIGN_RAD = 1e-6


@dataclass(frozen=True)
class VendorFlange:
    """The vendor's flange frame in the robot's last link frame {N}.

    Attributes
    ----------
    pose : ndarray, shape (4, 4), mm
        The vendor flange frame in {N} (a pure rotation; the identity when none applies).
    name : str
        The vendor's name of it (:data:`NAMES`).
    note : str
        Empty, or why no turn was applied (the robot's zero is not the controller's).
    """

    pose: np.ndarray
    name: str
    note: str = ""

    @property
    def turn_deg(self) -> float:
        """The angle (deg) by which the vendor's flange frame is turned from {N}."""
        c = (np.trace(self.pose[:3, :3]) - 1.0) / 2.0
        return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def vendor_flange(robot, fmt: str) -> VendorFlange:
    """The flange frame of format ``fmt`` on ``robot`` (see the module docstring).

    Parameters
    ----------
    robot : pipeline.robot.arm.kinematics.Robot
        A six-joint arm; its joint angles are the controller's through its coupling.
    fmt : str
        ``fanuc``, ``krl``, ``rapid`` or ``ur``.

    Returns
    -------
    VendorFlange
    """
    R0, out = AT_ZERO[fmt]
    chain = ik.chain_of(robot)
    q0 = np.asarray(robot.kinematic_angles(np.zeros((1, robot.n_joints))), float)
    FN = ik.flange(chain, np.deg2rad(q0))[0]
    RN = FN[:3, :3]
    axis = R0[:, out]
    z = RN[:, 2]
    why = ""
    if abs(float(z @ axis)) < np.cos(ALIGN_RAD):
        why = (f"this robot's last joint turns about ({z[0]:.3f}, {z[1]:.3f}, {z[2]:.3f}) in its base frame, not "
               f"about ({axis[0]:g}, {axis[1]:g}, {axis[2]:g}) as the vendor's arms do")
    elif float(FN[:3, 3] @ axis) <= 0.0:
        why = (f"this robot's flange is behind its base, at ({FN[0, 3]:.1f}, {FN[1, 3]:.1f}, {FN[2, 3]:.1f}) mm, "
               f"not out along ({axis[0]:g}, {axis[1]:g}, {axis[2]:g}) as the vendor's arms' is")
    if why:
        note = (f"{NAMES[fmt]} is taken as the last joint's frame: at the controller's zero (every joint 0) {why} "
                "(its joint zeros or its base frame are not the controller's): check a target, and give --tool "
                "relative to that frame")
        return VendorFlange(np.eye(4), NAMES[fmt], note)
    T = np.eye(4)
    T[:3, :3] = RN.T @ R0
    # exact quarter and half turns stay exact (a URDF's frames, a DH alpha of 90 deg)
    T[:3, :3] = np.where(np.abs(T[:3, :3]) < 1e-12, 0.0, T[:3, :3])
    return VendorFlange(T, NAMES[fmt])


#: half-turns tried when a Cartesian target has no solution on its branch: about the vendor flange's x, y, z
HALF_TURNS = {"x": np.diag([1.0, -1.0, -1.0, 1.0]), "y": np.diag([-1.0, 1.0, -1.0, 1.0]),
              "z": np.diag([-1.0, -1.0, 1.0, 1.0])}
