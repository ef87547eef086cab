"""Do the stated parameter uncertainties hold? A check on virtual cells whose truth is known (issue 33).

For each seed a virtual cell (:func:`pipeline.robot.cell.simulate.make_cell`, the KR210 cell's
geometry errors drawn from the seed, its tracker registered as a cell set-up does) is measured at
``n_poses`` poses drawn in its test region, with the tracker's noise only (no transmission error,
compliance, backlash or jitter: the effects ``geometry + base + tool`` can represent, so that the
stated uncertainty is the whole story). The model is fitted twice on the same poses: on the noise-free
positions (the truth as the model represents it: the same parameters left at nominal, the same
representative of what the measurements cannot see, docs/physical-redundancy.md) and on the measured
ones. Each fitted parameter's standardised error ``(fitted - truth) / uncertainty`` is then N(0, 1) if
the stated uncertainty is right: about 68.3 % within 1 and 95 % within 1.96.
"""

from __future__ import annotations

import numpy as np

from ...core.units import REFERENCE_TEMPERATURE_C
from ..arm.effects import Base, Geometry, RobotData, Tool
from ..arm.kinematics import Robot, positions
from ..model.estimate import fit_effects
from ..model.uncertainty import parameter_covariance
from .simulate import ROBOT_FIXTURE, draw_poses, make_cell, rng_for

#: random stream of the poses and the noise of this check (the cell's own streams are not reused)
STREAM = 33


def geometry_only_config(seed: int) -> dict:
    """The KR210 cell's configuration with only its geometry errors and tracker noise."""
    n = len(ROBOT_FIXTURE["transmission_arcsec"])
    return {**ROBOT_FIXTURE, "seed": int(seed), "transmission_arcsec": [0.0] * n,
            "compliance_arcsec_per_knm": [0.0] * n, "backlash_arcsec": [0.0] * n, "jitter_arcsec": 0.0}


def standardised_errors(robot: Robot, seed: int, n_poses: int = 100) -> dict:
    """One virtual cell: each fitted parameter's ``(fitted - truth) / uncertainty``.

    Parameters
    ----------
    robot : Robot (6 joints: the KR210 cell)
    seed : int
        The cell's truth, poses and noise.
    n_poses : int

    Returns
    -------
    dict: ``z`` (m,) for the m parameters with an uncertainty, ``names`` (m,), ``mahalanobis2`` (the
    squared Mahalanobis distance of the error under the stated covariance) and ``rank`` (its degrees of
    freedom), ``sigma_mm`` (the fit's residual scale per coordinate) and ``noise_mm`` (the cell's tracker noise).
    """
    config = geometry_only_config(seed)
    cell = make_cell(robot, config)
    rng = rng_for(seed, STREAM)
    q = draw_poses(robot, n_poses, rng, config["box_mm"], config["orientation_deg"])
    n = len(q)
    true = positions(cell.model_true, np.deg2rad(q)) @ cell.frame_R.T + cell.frame_t
    measured = true + rng.normal(0.0, config["tracker_sigma_mm"], true.shape)

    def data(xyz):
        return RobotData(q, np.ones((n, robot.n_joints), int), np.zeros(n), np.full(n, REFERENCE_TEMPERATURE_C),
                         np.zeros((n, robot.n_joints)), robot.lower_deg, robot.upper_deg, xyz)

    effects = [Geometry(), Base(), Tool()]
    truth = fit_effects(robot, effects, data(true))
    fitted = fit_effects(robot, effects, data(measured))
    pc = parameter_covariance(fitted, data(measured))
    sd = np.sqrt(np.clip(np.diag(pc["covariance"]), 0.0, None))
    live = sd > 0
    z = (fitted.coef_ - truth.coef_)[live] / sd[live]
    # the whole statement at once: the squared Mahalanobis distance of the error under the stated
    # covariance (correlation matrix: every parameter in units of its own sigma), chi2(rank) if right
    C = pc["covariance"][np.ix_(live, live)] / np.outer(sd[live], sd[live])
    w, V = np.linalg.eigh(C)
    keep = w > 1e-9 * w.max()
    y = V[:, keep].T @ z
    return {"z": z, "names": [m for m, k in zip(fitted.names_, live) if k],
            "mahalanobis2": float(np.sum(y ** 2 / w[keep])), "rank": int(keep.sum()),
            "sigma_mm": pc["sigma_mm"], "noise_mm": float(config["tracker_sigma_mm"])}


def parameter_coverage(robot: Robot, seeds, n_poses: int = 100) -> dict:
    """:func:`standardised_errors` over seeds: how often the truth is within 1 and 1.96 stated sigma.

    Returns
    -------
    dict: ``seeds``, ``n`` (parameter values checked), ``within_1_sigma`` (expected 0.683),
    ``within_1_96_sigma`` (expected 0.95), ``rms_z`` (expected 1), ``per_seed`` (share within 1.96 sigma),
    ``mahalanobis2`` and ``mahalanobis_dof``: the sum over the seeds of the squared Mahalanobis distance
    of the fitted parameters from the truth under the stated covariance and of its degrees of freedom
    (chi-square with those degrees of freedom if the covariance is right; the parameters of one cell are
    correlated, so this is the sharper test of the statement as a whole).
    """
    zs, per, d2, dof = [], [], 0.0, 0
    for s in seeds:
        one = standardised_errors(robot, int(s), n_poses)
        zs.append(one["z"])
        per.append(float(np.mean(np.abs(one["z"]) < 1.96)))
        d2 += one["mahalanobis2"]
        dof += one["rank"]
    z = np.concatenate(zs) if zs else np.zeros(0)
    return {"seeds": [int(s) for s in seeds], "n": int(z.size), "n_poses": int(n_poses),
            "within_1_sigma": float(np.mean(np.abs(z) < 1.0)), "within_1_96_sigma": float(np.mean(np.abs(z) < 1.96)),
            "rms_z": float(np.sqrt(np.mean(z ** 2))), "per_seed": per,
            "mahalanobis2": d2, "mahalanobis_dof": int(dof)}
