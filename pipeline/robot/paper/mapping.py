"""Joint mapping (the second paper, Eqs. 22-24) and model-based inverse correction.

Eq. 22: the predicted position error of a target is written as the effect of small angle
errors of the front three joints, ``Delta P_e = dP_t/dtheta . Delta theta`` (3 x 3, from the
nominal SMR position Jacobian of pinocchio); Eq. 23 solves it by least squares and Eq. 24
corrects the commands ``theta_i' = theta_i - Delta theta_i`` (i = 1, 2, 3).

:func:`inverse_commands` is the kinematic stage's counterpart: the commands with which a
calibrated (MDH) model puts the SMR at the nominal pose of the target (position and
orientation; Newton iterations on the error model's 6 x 6 frame Jacobian).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..arm.kinematics import Robot, build_model, pose_jacobians


def joint_mapping(robot: Robot, q_deg, dP_mm, joints=(1, 2, 3), model=None):
    """Angle corrections of ``joints`` that cancel a position error (Eqs. 22-24).

    Parameters
    ----------
    q_deg : ndarray, shape (n, 6), deg
        Commanded (nominal) joint angles of the targets.
    dP_mm : ndarray, shape (n, 3), mm
        Predicted position error (model - nominal) at the targets.

    Returns
    -------
    dtheta_deg : ndarray, shape (n, len(joints)), deg (Eq. 23)
    q_corrected_deg : ndarray, shape (n, 6), deg (Eq. 24 applied to ``joints``)
    """
    model = model or build_model(robot)
    q_deg = np.atleast_2d(np.asarray(q_deg, float))
    cols = [j - 1 for j in joints]
    _, _, J = pose_jacobians(model, np.deg2rad(q_deg), "smr")
    Jp = J[:, :3, cols]                               # mm per rad
    dtheta = np.empty((len(q_deg), len(cols)))
    for k in range(len(q_deg)):
        dtheta[k] = np.linalg.lstsq(Jp[k], dP_mm[k], rcond=None)[0]
    dtheta_deg = np.rad2deg(dtheta)
    qc = q_deg.copy()
    qc[:, cols] -= dtheta_deg
    return dtheta_deg, qc


def inverse_commands(fitted, robot: Robot, data, iters: int = 4):
    """Commands (n, 6) deg for which ``fitted`` (a RobotErrorModel) reaches the nominal poses.

    Parameters
    ----------
    fitted : RobotErrorModel
        Calibrated model (e.g. MDH geometry).
    data : RobotData
        Targets; ``q_deg`` are the nominal commands.
    """
    plain = build_model(robot)
    R0, P0, _ = pose_jacobians(plain, np.deg2rad(data.q_deg), "smr")
    q = data.q_deg.copy()
    for _ in range(iters):
        d = fitted.design(type(data)(q, data.dir, data.payload_kg, data.temperature_c, data.torque_nm,
                                     data.lower_deg, data.upper_deg))
        Q = d.configurations(fitted.coef_)
        R, P, J = pose_jacobians(d.model, Q, "smr")
        Jq = J[:, :, d.idx.joints]
        for k in range(len(q)):
            dp = (P0[k] - P[k])                          # mm
            dr = pin.log3(R0[k] @ R[k].T)                # rad, world frame
            step = np.linalg.solve(Jq[k] * np.array([1, 1, 1, 1000, 1000, 1000])[:, None],
                                   np.concatenate([dp, dr * 1000]))
            q[k] += np.rad2deg(step)
    return q
