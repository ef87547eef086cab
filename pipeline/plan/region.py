"""Choosing the poses that make a model hold in a region it has not seen (issue 52, "Measure where you
work"): ``jointcal plan --model FIT.json --region ...``.

The model at hand was fitted on some poses (its campaign, measured). The user will work in a *region*
(a program's poses, a targets file, another campaign's poses) and can measure a second campaign there,
from a *pool* of poses the robot reaches in it, with its own tracker frame. The poses to measure are
those that most lower the model's prediction variance over the region (V-optimality, the "I-optimal"
design of the linearised model restricted to the region):

* The unknowns are the spec's parameters with its joint maps' knots laid over the joint ranges of the
  measured poses, the pool and the region together (a fit of the two campaigns lays them so), held by
  the maps' own smoothness and level priors (their penalty rows, as for ``m + n`` poses) and by the
  information of the poses already measured.
* The new campaign has its own tracker frame: six more unknowns (the base frame's, on its rows only),
  never shared with the measured campaign.
* The region's error is judged as ``jointcal predict --register`` judges it: after its own rigid
  re-registration. So the region's rows are projected off their own rigid-frame columns before they make
  the weight ``W = mean_r A_r^T A_r``; the criterion is ``trace(W M^-1)`` (mean prediction variance over the
  region, scaled units), M the information of the measured poses, the priors and the chosen poses.
* Greedy: each step adds the pool pose that lowers ``trace(W M^-1)`` most, every candidate's gain from
  rank-k (Woodbury) updates of ``A_i M^-1 A_i^T`` and ``A_i M^-1 W M^-1 A_i^T``: O(pool x p x k) a step.

Only joint values (and payloads) are seen, never a measurement; the Jacobian is the fit's own at the
nominal robot, as :mod:`pipeline.plan.design` uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.se3 import ARCSEC_PER_MRAD
from ..robot.arm.effects import RobotData
from ..robot.model.estimate import effects_estimator
from .design import RIDGE, _scaled_blocks, concat_data, distinct_rows, pose_rows, with_probe

#: the parameters of the base frame
FRAME_PREFIX = "base_"
#: prior precision of the new campaign's frame (scaled units: about one pose's worth), so that the criterion
#: is defined before its poses determine it
FRAME_PRIOR = 1.0
#: the criterion's rank-k updates are recomputed from scratch every this many additions (rounding)
REFRESH_EVERY = 10


@dataclass
class RegionPlan:
    """The poses chosen for a region.

    Attributes
    ----------
    chosen : ndarray of int, shape (n,): rows of the pool, in the order chosen (most useful first)
    curve : list of dict: ``{"k", "region_rms_mm"}`` the predicted RMS error the parameters' scatter leaves
        on the region (mm, for the stated noise) after the first k chosen poses
    region_rms_mm_before : float: the same with no pose of the region measured (mm)
    region_rms_mm : float: after all the chosen poses (mm)
    n_params : int: unknowns (the model's, with the maps' knots over the region, and the new frame's six)
    """

    chosen: np.ndarray
    curve: list
    region_rms_mm_before: float
    region_rms_mm: float
    n_params: int


def unprepared(effects) -> list:
    """The effects with any joint map range a fit fixed removed, so that they are laid again over the poses
    the plan sees (a fitted model's maps stop at the range it sampled)."""
    out = []
    for e in effects:
        if e.name == "joint_map" and e.params.get("range_deg") is not None:
            e = type(e)(**{k: v for k, v in e.params.items() if k != "range_deg"})
        out.append(e)
    return out


def frame_blocks(P_mm, k: int, weight) -> np.ndarray:
    """Scaled blocks (n, k, 6) of a rigid tracker frame at the nominal positions ``P_mm`` (n, 3) mm: a shift
    (mm) and a small turn (rad) move a position by ``t + w x p``; with orientation rows (k = 6, weighed
    ``weight`` mm per mrad) the turn moves the orientation too. Each column scaled to unit RMS per pose."""
    P = np.asarray(P_mm, float)
    n = len(P)
    out = np.zeros((n, k, 6))
    out[:, :3, :3] = np.eye(3)
    px, py, pz = P[:, 0], P[:, 1], P[:, 2]
    z = np.zeros(n)
    # w x p = -[p]x w
    out[:, :3, 3:] = -np.stack([np.stack([z, -pz, py], 1), np.stack([pz, z, -px], 1), np.stack([-py, px, z], 1)], 1)
    if k == 6:
        out[:, 3:, 3:] = np.eye(3) * (1e-3 * weight)          # 1 rad = 1000 mrad
    norms = np.linalg.norm(out.reshape(-1, 6), axis=0) / np.sqrt(max(n, 1))
    return out / np.where(norms > 0, norms, 1.0)


def region_weight(A_region, F_region) -> np.ndarray:
    """``W = mean_r A_r^T A_r`` of the region's scaled position blocks after their own rigid registration.

    Parameters
    ----------
    A_region : ndarray, shape (R, 3, q): the region's scaled position rows (mm per scaled unit)
    F_region : ndarray, shape (R, 3, 6): the region's rigid-frame blocks (:func:`frame_blocks`), projected off
        the region's rows (``predict --register`` re-estimates the region's frame, so an error the frame
        absorbs does not count)
    """
    R, k, q = A_region.shape
    X = A_region.reshape(R * k, q)
    F = F_region.reshape(R * k, -1)
    X = X - F @ np.linalg.lstsq(F, X, rcond=None)[0]
    return X.T @ X / max(R, 1)


class _VCriterion:
    """``trace(W M^-1)`` with, for every candidate block A_i (k x q), ``G_i = A_i M^-1 A_i^T`` and
    ``Q_i = A_i M^-1 W M^-1 A_i^T`` kept up to date under additions (rank-k Woodbury updates)."""

    def __init__(self, A, M0, W):
        self.A, self.W = A, W
        self.I = np.eye(A.shape[1])
        self.refresh(M0)

    def refresh(self, M) -> None:
        """Recompute every kept quantity from the information matrix M (the updates' rounding does not add up)."""
        self.Minv = np.linalg.inv(M)
        self.Minv = 0.5 * (self.Minv + self.Minv.T)
        B = self.A @ self.Minv
        self.G = np.einsum("nkp,nlp->nkl", B, self.A)
        self.Q = np.einsum("nkp,nlp->nkl", B @ self.W, B)
        self.value = float(np.sum(self.W * self.Minv))

    def gains(self) -> np.ndarray:
        """How much adding each candidate lowers ``trace(W M^-1)``: ``trace((I + G_i)^-1 Q_i)``."""
        return np.einsum("nkk->n", np.linalg.solve(self.I + self.G, self.Q))

    def add(self, i: int) -> None:
        a = self.A[i]
        U = self.Minv @ a.T                                   # (q, k)
        C = np.linalg.inv(self.I + a @ U)
        R = self.A @ U                                        # (n, k, k)
        S = self.A @ (self.Minv @ (self.W @ U))               # a_i Minv W U
        UWU = U.T @ self.W @ U
        cross = np.einsum("nka,ab,nlb->nkl", R, C, S)
        self.Q = (self.Q - cross - np.transpose(cross, (0, 2, 1))
                  + np.einsum("nka,ab,nlb->nkl", R, C @ UWU @ C, R))
        self.G = self.G - np.einsum("nka,ab,nlb->nkl", R, C, R)
        self.value -= float(np.trace(C @ UWU))
        self.Minv = self.Minv - U @ C @ U.T


def plan_region(robot, effects, measured: RobotData, pool: RobotData, region: RobotData | None, n: int,
                noise_mm: float = 0.05, noise_arcsec: float | None = None, say=None) -> RegionPlan:
    """Choose ``n`` poses of ``pool`` (a new campaign, its own tracker frame) that most lower the model's
    prediction variance over ``region`` (V-optimal; see the module's text).

    Parameters
    ----------
    robot : Robot (N joints)
    effects : list of RobotEffect: the model's (its joint maps laid again over every pose seen here)
    measured : RobotData: the poses the model was fitted on (joint values only are read)
    pool : RobotData: candidate poses of the new campaign
    region : RobotData or None: the poses where the model must hold (None: the pool's own poses)
    n : int: poses to choose (at most the pool's distinct poses)
    noise_mm : float: measurement noise (mm, 1 sigma per coordinate) of the predicted errors
    noise_arcsec : float, optional: a 6-DoF probe's orientation noise (arcsec, 1 sigma per axis): the
        chosen poses' orientation rows count too (weighed by the ratio of the noises); None: positions only
    """
    say = say or (lambda msg: None)
    weight = None if noise_arcsec is None else noise_mm / (noise_arcsec / ARCSEC_PER_MRAD)
    m, P = measured.n, pool.n
    Rn = P if region is None else region.n
    union = concat_data(measured, pool) if region is None else concat_data(concat_data(measured, pool), region)
    if weight is not None:
        union = with_probe(union, weight)
    est = effects_estimator(robot, unprepared(effects))
    est.orientation_weight = weight
    d, P_mm, J2, Pen, _, ident = est.identification(union)
    keep = np.asarray(ident["keep"], bool)
    names = [nm for nm, k in zip(d.names, keep) if k]
    J2 = pose_rows(J2, union.n)
    A_all, norms = _scaled_blocks(J2, keep, union.n)
    q = A_all.shape[2]
    frame = np.array([i for i, nm in enumerate(names) if nm.startswith(FRAME_PREFIX)], int)
    # the new campaign's blocks: the model's columns and its own tracker frame's six (zero on every other
    # campaign), held by a prior of one pose's worth until its poses determine it
    F = frame_blocks(P_mm[m:m + P], A_all.shape[1], weight)
    nf = F.shape[2]
    Ap = np.concatenate([A_all[m:m + P], F], axis=2)
    M0 = RIDGE * np.eye(q + nf)
    M0[q:, q:] += FRAME_PRIOR * np.eye(nf)
    if Pen.shape[0]:
        Pk = Pen[:, keep] / norms * np.sqrt((m + n) / union.n)
        M0[:q, :q] += Pk.T @ Pk
    Am = A_all[:m]
    M0[:q, :q] += np.einsum("nkp,nkq->pq", Am, Am)
    W = np.zeros((q + nf, q + nf))
    r0 = m if region is None else m + P           # the region's rows: the pool's own, or its own after the pool's
    W[:q, :q] = region_weight(A_all[r0:r0 + Rn, :3, :], frame_blocks(P_mm[r0:r0 + Rn], 3, None))
    # candidates: distinct pool poses (point ids of another campaign may equal the measured one's)
    cand = distinct_rows(np.hstack([pool.q_deg, pool.payload_kg[:, None]]))
    n = min(n, int(cand.sum()))
    say(f"region: {Rn} poses; pool: {P} poses ({int(cand.sum())} distinct); {q} parameters of the model with "
        f"its joint maps over every pose seen, and the new campaign's {nf}-parameter frame")
    crit = _VCriterion(Ap, M0, W)
    before = crit.value
    chosen, curve = [], []
    for step in range(1, n + 1):
        g = np.where(cand, crit.gains(), -np.inf)
        i = int(np.argmax(g))
        crit.add(i)
        cand[i] = False
        chosen.append(i)
        if step % REFRESH_EVERY == 0:
            crit.refresh(M0 + np.einsum("nkp,nkq->pq", Ap[chosen], Ap[chosen]))
        curve.append({"k": step, "region_rms_mm": float(noise_mm * np.sqrt(max(crit.value, 0.0)))})
        if step % 25 == 0:
            say(f"{step} poses: predicted {curve[-1]['region_rms_mm']:.4f} mm RMS over the region")
    return RegionPlan(np.asarray(chosen, int), curve, float(noise_mm * np.sqrt(max(before, 0.0))),
                      curve[-1]["region_rms_mm"] if curve else float(noise_mm * np.sqrt(max(before, 0.0))),
                      q + nf)
