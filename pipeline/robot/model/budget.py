"""The robot's own error budget: how far a joint's angle error may vary and still be physical.

One yardstick, used by diagnosis (is a candidate plausible?) and by every fit (is the fitted model
plausible?): the largest error measured on the sample poses under the nominal kinematics (mm),
divided by each joint's lever arm to the SMR (median over the sample poses, mm per rad). A joint
angle error that varies by more than that anywhere in the sampled joint box (random configurations
uniform in each joint's sampled range, :func:`box_configurations`) would move the point further
than anything the robot was measured to do: two terms cancelling each other on the sampled poses
(1,740 arcsec joint maps of a UR5's wrist), not a property of the robot.
"""

from __future__ import annotations

import numpy as np

#: Configurations drawn in the sampled joint box to look for wild predictions.
N_BOX = 400


def box_configurations(q_deg, n: int = N_BOX, seed: int = 0) -> np.ndarray:
    """Random joint configurations, uniform in each joint's sampled range, shape (n, N) deg."""
    q = np.asarray(q_deg, float)
    rng = np.random.default_rng(seed)
    return q.min(axis=0) + rng.random((n, q.shape[1])) * np.ptp(q, axis=0)


def error_scale(measured_mm, nominal_mm) -> float:
    """The largest error measured (mm): |measured - nominal| over the sample poses, (n, 3) mm each."""
    return float(np.max(np.linalg.norm(np.asarray(measured_mm, float) - np.asarray(nominal_mm, float), axis=1)))


def lever_arms(Jext, joint_channels) -> np.ndarray:
    """Each joint's lever arm to the SMR, mm per rad: the median over the poses of the norm of the
    position Jacobian's joint column. ``Jext`` (n, 3, nv) mm per channel unit; ``joint_channels``
    (N,) the joints' channel indices."""
    return np.median(np.linalg.norm(np.asarray(Jext)[:, :, joint_channels], axis=1), axis=0)


def angle_budget(scale_mm: float, lever_mm_per_rad) -> np.ndarray:
    """Each joint's angle error budget (rad), shape (N,)."""
    return scale_mm / np.maximum(np.asarray(lever_mm_per_rad, float), 1e-9)


def angle_variation(dQ_joints) -> np.ndarray:
    """How much each joint's angle error varies about its mean (rad), shape (N,), from the angle
    errors (m, N) rad at the box configurations: a constant error is the joint's offset."""
    d = np.asarray(dQ_joints, float)
    if d.size == 0:
        return np.zeros(d.shape[1] if d.ndim == 2 else 0)
    return np.abs(d - d.mean(axis=0)).max(axis=0)


def over_budget(dq, budget) -> list[dict]:
    """The joints whose angle error varies beyond their budget, as ``{name, value, unit, bound}``
    (arcsec; the format of :func:`pipeline.robot.model.lm.implausible_parameters`), worst first."""
    dq, budget = np.asarray(dq, float), np.asarray(budget, float)
    over = np.flatnonzero(dq > budget)
    out = [{"name": f"joint {j + 1}'s angle error variation in the sampled joint box",
            "value": float(np.degrees(dq[j]) * 3600), "unit": "arcsec (robot's error budget)",
            "bound": float(np.degrees(budget[j]) * 3600), "excess": float(dq[j] / budget[j])} for j in over]
    out.sort(key=lambda q: -q["excess"])
    return [{k: v for k, v in q.items() if k != "excess"} for q in out]


def model_over_budget(robot, design_class, effects, coef_by_name: dict, data, Jext, joint_channels,
                      nominal_mm) -> list[dict]:
    """:func:`over_budget` for a fitted model: the angle errors its effects put on the joints at the
    box configurations of ``data``'s sampled joint ranges.

    Parameters
    ----------
    design_class : the model's design (``pipeline.robot.model.design.Design``), passed in to keep this
        module free of the estimator.
    effects : list of RobotEffect (prepared)
    coef_by_name : dict parameter name -> internal value
    data : RobotData (sample poses)
    Jext : ndarray, shape (n, 3, nv): channel Jacobian at the sample poses
    nominal_mm : ndarray, shape (n, 3): the nominal model's positions of the sample poses
    """
    from dataclasses import replace

    angle = [e for e in effects if getattr(e, "on_joint_angle", False)]
    if not angle or data.measured_mm is None or data.n == 0:
        return []
    qb = box_configurations(data.q_deg)
    n, nj = qb.shape
    rng = np.random.default_rng(1)
    box = replace(data, q_deg=qb, dir=rng.choice([-1, 1], size=(n, nj)),
                  payload_kg=np.full(n, float(np.median(data.payload_kg))),
                  temperature_c=np.full(n, float(np.median(data.temperature_c))),
                  torque_nm=np.zeros((n, nj)), measured_mm=None, point_id=np.array([], dtype=object))
    if any(e.name == "compliance" for e in angle):
        from ..arm.kinematics import gravity_torques

        box = replace(box, torque_nm=gravity_torques(robot, qb, box.payload_kg))
    d = design_class(robot, angle, box)
    x = np.array([coef_by_name.get(nm, 0.0) for nm in d.names])
    dQ = d.configurations(x) - d.Q0
    dq = angle_variation(dQ[:, d.idx.joints])
    budget = angle_budget(error_scale(data.measured_mm, nominal_mm), lever_arms(Jext, joint_channels))
    return over_budget(dq, budget)
