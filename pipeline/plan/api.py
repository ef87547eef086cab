"""``jointcal plan`` as one library call: a pool, a spec's effects (and a campaign already measured,
a suspected effect) in, the plan's CSV text and JSON-ready summary out."""

from __future__ import annotations

import numpy as np

from ..robot.arm.kinematics import directions_from_sequence
from .design import plan_poses, pool_data
from .pool import Pool, format_plan_csv
from .reveal import doubled_for_backlash, reveal_text, what_poses_need


def plan_from_pool(robot, effects, pool: Pool, n: int, measured=None, reveal=None, noise_mm: float = 0.05,
                   say=None, criterion: str = "robust", noise_arcsec: float | None = None) -> tuple[str, dict]:
    """Choose ``n`` poses of ``pool``; returns (plan CSV text, summary dict).

    Parameters
    ----------
    robot : Robot (N joints)
    effects : list of RobotEffect (the spec's model)
    pool : Pool (joint values deg, payloads kg)
    n : int
    measured : RobotData, optional
        The campaign's poses already measured, in visiting order.
    reveal : RobotEffect, optional
    noise_mm : float
        Measurement noise, mm (standard deviation of each coordinate).
    criterion : {"robust", "D", "I"}
        See :func:`pipeline.plan.design.plan_poses`.
    noise_arcsec : float, optional
        A 6-DoF probe's orientation noise (arcsec per axis): poses chosen for the orientation's
        information too (see :func:`pipeline.plan.design.plan_poses`); None: an SMR.
    """
    backlash = reveal is not None and reveal.name == "backlash"
    # the pool holds the controller's angles: coupled joints (robot.toml [coupling]) are combined into the
    # arm's for the model, and the plan is written back in the controller's
    pool_q = robot.kinematic_angles(pool.q_deg)
    if backlash:
        q, pay, dirs, back = doubled_for_backlash(pool_q, pool.payload_kg, reveal.joints(robot))
        data = pool_data(robot, q, pay, dirs)
        data.point_id = np.array([f"{pool.point_id[b]}{'@dir+' if k < pool.q_deg.shape[0] else '@dir-'}"
                                  for k, b in enumerate(back)], dtype=object)
    else:
        data = pool_data(robot, pool_q, pool.payload_kg)
        data.point_id = np.asarray(pool.point_id, object)
    plan = plan_poses(robot, effects, data, n, measured=measured, reveal=reveal, noise_mm=noise_mm, say=say,
                      criterion=criterion, noise_arcsec=noise_arcsec)
    chosen = plan.chosen
    summary = plan.summary()
    ids = data.point_id[chosen]
    q = data.q_deg[chosen]
    directions = None
    if backlash:
        start = measured.q_deg[-1] if measured is not None else (robot.lower_deg + robot.upper_deg) / 2
        directions = directions_from_sequence(q, start_deg=start)
        for j in reveal.joints(robot):
            directions[:, j - 1] = data.dir[chosen, j - 1]
    if reveal is not None:
        sel = data.subset(chosen)
        if directions is not None:
            sel.dir = directions
        ok, why = reveal.can_reveal(sel)
        summary["reveal"] = {"effect": reveal_text(reveal), "revealable": bool(ok), "why_not": why,
                             "needs": what_poses_need(reveal),
                             "parameters": reveal.parameter_names(robot)}
        if not ok:
            summary["notes"].append(f"even the best poses of this pool cannot reveal it: {why}; the poses need "
                                    f"{what_poses_need(reveal)}")
    if measured is not None:
        summary["campaign_poses"] = int(measured.n)
    summary["point_ids"] = [str(p) for p in ids]
    text = format_plan_csv(ids, robot.recorded_angles(q),
                           pool.payload_kg[chosen % pool.q_deg.shape[0]] if pool.has_payload else None, directions)
    return text, summary


def plan_for_region(robot, effects, pool: Pool, region_q_deg, n: int, measured, noise_mm: float = 0.05,
                    say=None, noise_arcsec: float | None = None, region_payload_kg=None) -> tuple[str, dict]:
    """Choose ``n`` poses of ``pool`` to measure as a new campaign (its own tracker frame) so that the model
    fitted on ``measured`` holds over a region (V-optimal: :func:`pipeline.plan.region.plan_region`);
    returns (plan CSV text, summary dict).

    Parameters
    ----------
    robot : Robot (N joints)
    effects : list of RobotEffect: the model's (a fitted model's joint maps are laid again over every pose)
    pool : Pool (joint values deg, payloads kg): the poses the new campaign can measure
    region_q_deg : ndarray, shape (R, N), deg, or None: the controller's joint values where the model must hold
        (None: the pool's own poses)
    n : int
    measured : RobotData: the poses the model was fitted on (joint values are read, never a measurement)
    noise_mm : float: measurement noise, mm (1 sigma per coordinate)
    noise_arcsec : float, optional: a 6-DoF probe's orientation noise (arcsec per axis); None: an SMR
    region_payload_kg : ndarray, shape (R,), kg, optional (default 0)
    """
    from .design import path_cost, visiting_order
    from .region import plan_region

    pool_q = robot.kinematic_angles(pool.q_deg)
    data = pool_data(robot, pool_q, pool.payload_kg)
    data.point_id = np.asarray(pool.point_id, object)
    region = None
    if region_q_deg is not None:
        region = pool_data(robot, robot.kinematic_angles(np.asarray(region_q_deg, float)), region_payload_kg)
    done = pool_data(robot, measured.q_deg, measured.payload_kg)
    plan = plan_region(robot, effects, done, data, region, n, noise_mm, noise_arcsec, say)
    chosen = plan.chosen
    qc = data.q_deg[chosen]
    pay = pool.payload_kg[chosen] if np.ptp(pool.payload_kg) > 0 else None
    order = visiting_order(qc, payload_kg=pay)
    notes = []
    if len(chosen) < n:
        notes.append(f"the pool has only {len(chosen)} distinct poses; {len(chosen)} chosen")
    summary = {"n": int(len(chosen)), "criterion": "V-optimal over the region",
               "parameters_identifiable": int(plan.n_params), "n_params": int(plan.n_params),
               "predicted_rms_mm": plan.region_rms_mm, "noise_mm": float(noise_mm),
               "region": {"n": int(pool.q_deg.shape[0] if region is None else region.n), "predicted_rms_mm_before": plan.region_rms_mm_before,
                          "predicted_rms_mm": plan.region_rms_mm},
               "model_poses": int(measured.n), "curve": plan.curve,
               "path_deg": path_cost(qc, order), "notes": notes,
               "point_ids": [str(p) for p in data.point_id[chosen[order]]]}
    text = format_plan_csv(data.point_id[chosen[order]], robot.recorded_angles(qc[order]),
                           pool.payload_kg[chosen[order]] if pool.has_payload else None)
    return text, summary
