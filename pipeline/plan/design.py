"""Choosing the poses to measure (contract section 9): D-optimal and Ds-optimal designs over a pool.

The problem is the fit's own: :meth:`pipeline.robot.model.estimator.RobotErrorModel.identification` of
the estimator ``jointcal fit`` uses for the spec (:func:`pipeline.robot.model.estimate.effects_estimator`)
gives the identification Jacobian at the nominal robot (3 rows a pose, mm per internal unit) and
the parameters the poses can determine (rank, weak determination: the fit's own tolerances). Only
joint values (and payloads) are seen, never a measurement.

* Columns are scaled as the fit scales them (the column norms over the pool, per pose): every
  parameter enters the information matrix with unit weight whatever its unit and lever arm.
* **D-optimality**: the chosen set S maximises ``log det M(S)``, ``M(S) = M0 + sum_{i in S} A_i^T A_i``
  (A_i the pose's scaled 3 x p block; M0 the poses already measured, the effects' own penalty rows
  and a ridge of 1e-9 so that the first choices are defined).
* **Ds-optimality** (``reveal``): the information of the suspected effect's parameters after the
  model's own are adjusted out (the Schur complement): ``log det M_full(S) - log det M_model(S)``.
* Greedy start (each step adds the pose of largest ``log det(I_3 + A_i M^-1 A_i^T)``), then
  Fedorov exchange passes (each chosen pose is swapped for the best pose of the pool while that
  raises the criterion). Every gain is a 3 x 3 determinant from rank-3 (Woodbury) updates of
  ``A_i M^-1 A_i^T`` for all candidates at once: O(pool x p) per candidate exchange.
* Predicted error: with measurement noise sigma (mm, each coordinate) the fitted parameters scatter
  with covariance ``sigma^2 M^-1``, which leaves ``sigma sqrt(mean_i trace(A_i M^-1 A_i^T))`` RMS
  position error over the pool (the error the parameter uncertainty leaves; not the error of
  effects the model lacks, nor the bias of parameters left at nominal).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..robot.arm.effects import RobotData
from ..robot.model.estimate import effects_estimator
from ..robot.model.uncertainty import prediction_covariance
from ..robot.arm.kinematics import Robot, gravity_torques
from ..core.se3 import ARCSEC_PER_MRAD
from ..core.units import REFERENCE_TEMPERATURE_C

#: Ridge added to the information matrix (scaled units: a pose adds about 1 per parameter)
RIDGE = 1e-9
#: Joint values closer than this (deg, every joint) are the same pose
SAME_POSE_DEG = 1e-6
#: Reveal: ``log det M_full - DS_WEIGHT log det M_model`` = (1 - w) D of the larger model + w Ds of the
#: effect: half of each keeps enough distinct poses to fit the larger model, which pure Ds (w = 1) did
#: not (docs/speed.md "Measurements behind the code").
DS_WEIGHT = 0.5
#: Model-robust D-optimality (DuMouchel & Jones 1994, "A simple Bayesian modification of D-optimal
#: designs to reduce dependence on an assumed model"): the design also gathers information on
#: *potential terms* - errors the model lacks - held by a prior: the second paper's error transfer
#: (Chebyshev) terms of this order on every joint, orthogonalised against the model's parameters,
#: scaled like them, with this prior precision (one pose's worth); why plain D-optimality was not
#: enough: docs/speed.md "Measurements behind the code". Order 2 and precision 1 are the method's
#: textbook choice (unit prior on scaled terms); no other was tried.
POTENTIAL_ORDER = 2
POTENTIAL_PRECISION = 1.0
#: A pool pose within this of a measured one (deg, every joint) is that pose again (--campaign never
#: plans it): 0.36 arcsec, far below any robot's repeatability, above the rounding of exported files.
MEASURED_POSE_DEG = 1e-4
#: Exchange passes at most (each pass tries every chosen pose once)
MAX_PASSES = 20
#: poses uniform over the robot's joint ranges on which a parameter the pool cannot identify is checked:
#: not identifiable there either, it is structural (no poses would), not the pool's
BROAD_POSES = 400


def pool_data(robot: Robot, q_deg, payload_kg=None, directions=None) -> RobotData:
    """The model's view of poses that were not measured (joint values and payloads only).

    Parameters
    ----------
    robot : Robot (N joints)
    q_deg : ndarray, shape (n, N), deg
    payload_kg : ndarray, shape (n,), kg, optional (default 0)
    directions : ndarray, shape (n, N), +1/-1, optional (default +1)
    """
    q = np.asarray(q_deg, float)
    n, nj = q.shape
    pay = np.zeros(n) if payload_kg is None else np.asarray(payload_kg, float)
    d = np.ones((n, nj), int) if directions is None else np.asarray(directions, int)
    tau = gravity_torques(robot, q, pay) if n else np.zeros((0, nj))
    return RobotData(q, d, pay, np.full(n, REFERENCE_TEMPERATURE_C), tau, robot.lower_deg, robot.upper_deg, None,
                     np.array([f"p{k}" for k in range(n)], dtype=object))


def concat_data(a: RobotData, b: RobotData) -> RobotData:
    """Rows of ``a`` then rows of ``b`` (no measurements)."""
    return RobotData(np.vstack([a.q_deg, b.q_deg]), np.vstack([a.dir, b.dir]),
                     np.concatenate([a.payload_kg, b.payload_kg]), np.concatenate([a.temperature_c, b.temperature_c]),
                     np.vstack([a.torque_nm, b.torque_nm]), a.lower_deg, a.upper_deg, None,
                     np.concatenate([np.asarray(a.point_id, object), np.asarray(b.point_id, object)]))


class _LogDet:
    """log det of ``M0 + sum A_i^T A_i`` over a set, with ``G_i = A_i M^-1 A_i^T`` kept for every row."""

    def __init__(self, A, M0):
        self.A = A                       # (n, k, q): k = 3 rows per pose (an SMR) or 6 (a 6-DoF probe)
        self.I = np.eye(A.shape[1])
        self.M = M0.copy()
        self.refresh()

    def refresh(self):
        self.Minv = np.linalg.inv(self.M)
        self.Minv = 0.5 * (self.Minv + self.Minv.T)
        B = self.A @ self.Minv
        self.G = np.einsum("nkp,nlp->nkl", B, self.A)
        self.logdet = float(np.linalg.slogdet(self.M)[1])

    def gains(self):
        """log det(M + A_i^T A_i) - log det M for every row."""
        return np.linalg.slogdet(self.I + self.G)[1]

    def _update(self, i, sign):
        a = self.A[i]
        U = self.Minv @ a.T                                   # (q, k)
        C = np.linalg.inv(sign * self.I + a @ U)              # Woodbury core
        W = self.A @ U                                        # (n, 3, 3)
        self.G = self.G - np.einsum("nka,ab,nlb->nkl", W, C, W)
        self.Minv = self.Minv - U @ C @ U.T
        self.M = self.M + sign * a.T @ a
        self.logdet += float(np.linalg.slogdet(self.I + sign * a @ U)[1])

    def add(self, i):
        self._update(i, 1.0)

    def remove(self, i):
        self._update(i, -1.0)

    def swap_gains(self, j):
        """log det(M - A_j^T A_j + A_i^T A_i) - log det M for every row i."""
        a = self.A[j]
        U = self.Minv @ a.T
        S = self.I - a @ U
        C = np.linalg.inv(S)
        W = self.A @ U
        G = self.G + np.einsum("nka,ab,nlb->nkl", W, C, W)
        return np.linalg.slogdet(self.I + G)[1] + float(np.linalg.slogdet(S)[1])


class _Criterion:
    """D (one matrix) or Ds (full minus model's own) criterion over rows of A."""

    def __init__(self, A, M0, sub=None, weight=1.0):
        self.w = weight
        self.full = _LogDet(A, M0)
        self.sub = None if sub is None else _LogDet(A[:, :, sub], M0[np.ix_(sub, sub)])

    def value(self):
        return self.full.logdet - (self.w * self.sub.logdet if self.sub else 0.0)

    def gains(self):
        return self.full.gains() - (self.w * self.sub.gains() if self.sub else 0.0)

    def swap_gains(self, j):
        return self.full.swap_gains(j) - (self.w * self.sub.swap_gains(j) if self.sub else 0.0)

    def add(self, i):
        self.full.add(i)
        if self.sub:
            self.sub.add(i)

    def remove(self, i):
        self.full.remove(i)
        if self.sub:
            self.sub.remove(i)

    def refresh(self):
        self.full.refresh()
        if self.sub:
            self.sub.refresh()


def near_any(q_deg, ref_deg, tol) -> np.ndarray:
    """Mask of the rows of ``q_deg`` (n, N) within ``tol`` deg, every joint, of a row of ``ref_deg`` (m, N)."""
    q, ref = np.asarray(q_deg, float), np.asarray(ref_deg, float)
    out = np.zeros(len(q), bool)
    for k in range(0, len(ref), 256):
        block = ref[k:k + 256]
        out |= (np.abs(q[:, None, :] - block[None, :, :]).max(axis=2) <= tol).any(axis=1)
    return out


def distinct_rows(q_deg, tol=SAME_POSE_DEG) -> np.ndarray:
    """Mask of the first occurrence of every pose (rows equal within ``tol`` deg count once)."""
    q = np.round(np.asarray(q_deg, float) / tol).astype(np.int64)
    _, first = np.unique(q, axis=0, return_index=True)
    mask = np.zeros(len(q), bool)
    mask[first] = True
    return mask


def greedy_exchange(crit: _Criterion, candidates: np.ndarray, k: int, say=None, exchange=True):
    """Greedy start of ``k`` rows among ``candidates`` then Fedorov exchange; returns (chosen, greedy order)."""
    allowed = np.zeros(crit.full.A.shape[0], bool)
    allowed[candidates] = True
    chosen = []
    for step in range(k):
        g = np.where(allowed, crit.gains(), -np.inf)
        i = int(np.argmax(g))
        if not np.isfinite(g[i]):
            break
        crit.add(i)
        allowed[i] = False
        chosen.append(i)
    greedy = list(chosen)
    if not exchange:
        return chosen, greedy
    for it in range(MAX_PASSES):
        crit.refresh()
        swaps = 0
        for pos in range(len(chosen)):
            j = chosen[pos]
            g = np.where(allowed, crit.swap_gains(j), -np.inf)
            i = int(np.argmax(g))
            if np.isfinite(g[i]) and g[i] > 1e-9 * max(1.0, abs(crit.value())):
                crit.remove(j)
                crit.add(i)
                allowed[i], allowed[j] = False, True
                chosen[pos] = i
                swaps += 1
        if say:
            say(f"exchange pass {it + 1}: {swaps} swap(s), criterion {crit.value():.4f}")
        if not swaps:
            break
    crit.refresh()
    return chosen, greedy


def i_exchange(A, M0, W, chosen, candidates, say=None, max_passes=MAX_PASSES):
    """Fedorov exchange on the I-criterion ``trace(W M^-1)`` (the mean prediction variance over the
    pool, W = mean of the pool's A_i^T A_i): each chosen pose is swapped for the pool pose that lowers
    it most, while one does. Every swap's effect on all candidates comes from rank-3 updates.

    Parameters
    ----------
    A : ndarray, shape (n, 3, q)  scaled blocks of the pool
    M0 : ndarray, shape (q, q)    information of what is not chosen (measured poses, penalty, ridge)
    W : ndarray, shape (q, q)
    chosen : list of int          a starting design (e.g. the D-optimal one)
    """
    chosen = list(chosen)
    allowed = np.zeros(len(A), bool)
    allowed[candidates] = True
    allowed[chosen] = False
    eye = np.eye(A.shape[1])

    def state():
        M = M0 + np.einsum("nkp,nkq->pq", A[chosen], A[chosen])
        Minv = np.linalg.inv(M)
        Minv = 0.5 * (Minv + Minv.T)
        H = Minv @ W @ Minv
        return Minv, H, prediction_covariance(A, Minv), prediction_covariance(A, H)

    Minv, H, G, Q = state()
    value = float(np.trace(W @ Minv))
    for it in range(max_passes):
        swaps = 0
        for pos in range(len(chosen)):
            j = chosen[pos]
            a = A[j]
            U = Minv @ a.T                                  # (q, 3)
            C = np.linalg.inv(eye - a @ U)                  # removal: Minv_- = Minv + U C U^T
            R = A @ U                                       # (n, 3, 3): a_i U
            Gm = G + np.einsum("nka,ab,nlb->nkl", R, C, R)  # a_i Minv_- a_i^T
            S = A @ (Minv @ W @ U)                          # a_i Minv W U
            UWU = U.T @ W @ U
            cross = np.einsum("nka,ab,nlb->nkl", R, C, S)
            Qm = Q + cross + np.transpose(cross, (0, 2, 1)) + np.einsum("nka,ab,bc,cd,nld->nkl", R, C, UWU, C, R)
            base = value + float(np.trace(C @ U.T @ W @ U))  # trace(W Minv_-)
            Dinv = np.linalg.inv(eye + Gm)
            new = base - np.einsum("nkl,nlk->n", Dinv, Qm)
            new = np.where(allowed, new, np.inf)
            i = int(np.argmin(new))
            if np.isfinite(new[i]) and new[i] < value * (1 - 1e-9):
                chosen[pos] = i
                allowed[i], allowed[j] = False, True
                Minv, H, G, Q = state()
                value = float(np.trace(W @ Minv))
                swaps += 1
        if say:
            say(f"I-exchange pass {it + 1}: {swaps} swap(s), mean prediction variance {value:.4g}")
        if not swaps:
            break
    return chosen


def path_cost(q_deg, order, start_deg=None, weights=None) -> float:
    """Joint-space path length (deg) of visiting ``q_deg[order]``, each move costing max_j w_j |dq_j|."""
    q = np.asarray(q_deg, float)[list(order)]
    w = np.ones(q.shape[1]) if weights is None else np.asarray(weights, float)
    if start_deg is not None:
        q = np.vstack([np.asarray(start_deg, float)[None], q])
    return float(np.sum(np.max(np.abs(np.diff(q, axis=0)) * w, axis=1))) if len(q) > 1 else 0.0


#: Cost (deg-equivalent) of changing the payload between two poses: a change of end effector or
#: weights takes far longer than any joint motion, so poses of one payload are visited together.
PAYLOAD_CHANGE_DEG = 3600.0


def visiting_order(q_deg, start_deg=None, weights=None, max_passes=50, payload_kg=None) -> np.ndarray:
    """An order that keeps the robot's path short: nearest neighbour, then 2-opt (open path).

    A move's cost is ``max_j w_j |dq_j|`` (deg): joints move together, the one with the longest
    way (weighted by ``w_j``, e.g. 1 / relative speed; default 1) sets the move's time.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    start_deg : ndarray, shape (N,), deg, optional
        Where the robot is before the first pose (the path starts there; else at the first pose chosen
        by nearest neighbour from the middle of the poses).
    payload_kg : ndarray, shape (n,), kg, optional
        A change of payload between two poses costs :data:`PAYLOAD_CHANGE_DEG` more.
    """
    q = np.asarray(q_deg, float)
    n = len(q)
    if n <= 1:
        return np.arange(n)
    w = np.ones(q.shape[1]) if weights is None else np.asarray(weights, float)
    D = np.max(np.abs(q[:, None, :] - q[None, :, :]) * w, axis=2)
    if payload_kg is not None:
        pay = np.asarray(payload_kg, float)
        D = D + PAYLOAD_CHANGE_DEG * (pay[:, None] != pay[None, :])
    s = np.median(q, axis=0) if start_deg is None else np.asarray(start_deg, float)
    d0 = np.max(np.abs(q - s) * w, axis=1)
    # nearest neighbour
    left = np.ones(n, bool)
    cur = int(np.argmin(d0))
    order = [cur]
    left[cur] = False
    for _ in range(n - 1):
        dd = np.where(left, D[cur], np.inf)
        cur = int(np.argmin(dd))
        order.append(cur)
        left[cur] = False
    order = np.array(order)
    # 2-opt on the open path from the start: reverse order[i..k]
    for _ in range(max_passes):
        improved = False
        for i in range(n - 1):
            prev = d0[order] if i == 0 else D[order[i - 1]]       # cost from the point before i
            a = order[i]
            ks = np.arange(i + 1, n)
            b = order[ks]
            before = (d0[a] if i == 0 else D[order[i - 1], a]) + np.where(ks + 1 < n, D[b, order[np.minimum(ks + 1, n - 1)]], 0.0)
            after = prev[ks] + np.where(ks + 1 < n, D[a, order[np.minimum(ks + 1, n - 1)]], 0.0)
            delta = after - before
            m = int(np.argmin(delta))
            if delta[m] < -1e-9:
                k = ks[m]
                order[i:k + 1] = order[i:k + 1][::-1]
                improved = True
        if not improved:
            break
    return order


#: what each criterion maximises, in words (the plan's JSON)
CRITERIA = {
    "D-optimal": "log det of the information matrix of the identifiable parameters (columns scaled as jointcal fit "
                 "scales them)",
    "robust D-optimal": "log det of the information on the identifiable parameters and on potential terms the model "
                        "lacks (Chebyshev error transfer of order 2 on every joint, orthogonal to the model, unit "
                        "prior precision): model-robust D-optimality (DuMouchel & Jones 1994)",
    "I-optimal": "mean prediction variance over the pool (trace of W M^-1), Fedorov exchange from the D-optimal design",
    "Ds-optimal": "log det of the suspected effect's information after the model's own is adjusted out (Schur "
                  "complement), half weight, plus log det of the larger model's information, half weight (enough "
                  "distinct poses to fit it)",
}


@dataclass
class Plan:
    """What :func:`plan_poses` chose and why (JSON-ready through :meth:`summary`)."""

    chosen: np.ndarray                 # indices into the pool, in visiting order
    criterion: str
    criterion_value: float
    parameters: list                   # names of the parameters the design is for (pool-identifiable)
    not_identifiable_on_pool: dict     # name -> reason (the fit's own check on the whole pool)
    identification: dict               # the fit's check on the measured + chosen poses
    predicted_rms_mm: float | None
    noise_mm: float
    curve: list = field(default_factory=list)
    path_deg: float = 0.0
    path_deg_unordered: float = 0.0
    notes: list = field(default_factory=list)
    reveal: dict | None = None
    directions: np.ndarray | None = None
    predicted_u95_mm: float | None = None
    #: of ``not_identifiable_on_pool``, those no poses identify (not on poses over the whole joint ranges)
    structural: list = field(default_factory=list)

    def summary(self) -> dict:
        ident = self.identification
        return {"n": int(len(self.chosen)), "criterion": self.criterion, "criterion_value": self.criterion_value,
                "criterion_note": CRITERIA.get(self.criterion, ""),
                "parameters_identifiable": int(np.sum(ident["keep"])), "n_params": int(ident["n_params"]),
                "not_identified": ident["not_identifiable"],
                "not_identified_reasons": ident["fixed_reasons"],
                "not_identifiable_on_pool": self.not_identifiable_on_pool,
                "not_identifiable_structural": list(self.structural),
                "condition_number": ident["condition_number"],
                "predicted_rms_mm": self.predicted_rms_mm, "noise_mm": self.noise_mm,
                "predicted_rms_note": ("RMS position error over the pool that the fitted parameters' scatter leaves "
                                       "for measurement noise noise_mm (each coordinate), from the identification "
                                       "Jacobian at the nominal robot; it leaves out effects the model lacks"),
                "predicted_u95_mm": self.predicted_u95_mm,
                "predicted_u95_note": ("mean over the pool of the 95 % radius (u95_mm, as jointcal predict states it) "
                                       "of the fitted model's error at a pose: the parameters' scatter and the "
                                       "measurement noise noise_mm, by the same propagation; a fit of the measured "
                                       "campaign states its own u95_mm from its cross-validated scatter, which holds "
                                       "what the model lacks too"),
                "curve": self.curve,
                "curve_note": ("predicted_rms_mm (for noise_mm) of the first k poses a greedy D-optimal choice takes "
                               "from this pool; null where k poses are too few for the parameters"),
                "path_deg": self.path_deg, "path_deg_in_choice_order": self.path_deg_unordered,
                "path_note": "joint-space path from the start, each move costing its largest joint motion (deg)",
                "notes": self.notes, **({"reveal": self.reveal} if self.reveal else {})}


def _scaled_blocks(J2, keep, n_rows):
    """Per-pose scaled blocks (n, 3, q) of the kept columns: the fit's column scaling (norm per pose);
    (n, 6, q) for a 6-DoF probe's rows (:func:`pose_rows`)."""
    Jk = J2[:, keep]
    norms = np.linalg.norm(Jk, axis=0) / np.sqrt(max(n_rows, 1))
    norms = np.where(norms > 0, norms, 1.0)
    return (Jk / norms).reshape(n_rows, -1, Jk.shape[1]), norms


def pose_rows(J2, n_rows):
    """The identification Jacobian with its rows per pose: a 6-DoF fit stacks every pose's position rows
    (3 n) above its orientation rows (3 n); planning takes them pose by pose (x, y, z, then the turn)."""
    if J2.shape[0] == 3 * n_rows:
        return J2
    p = J2.shape[1]
    Jp, Jo = J2[:3 * n_rows].reshape(n_rows, 3, p), J2[3 * n_rows:].reshape(n_rows, 3, p)
    return np.concatenate([Jp, Jo], axis=1).reshape(-1, p)


def with_probe(data: RobotData, weight_mm_per_mrad: float) -> RobotData:
    """Poses to be measured with a 6-DoF probe: the fit's identification then has orientation rows
    (weighed ``weight_mm_per_mrad``, the ratio of the stated noises); the frames are placeholders (the
    Jacobian does not depend on them)."""
    out = data.subset(np.ones(data.n, bool))
    out.measured_R = np.repeat(np.eye(3)[None], data.n, axis=0)
    out.planned_weight = weight_mm_per_mrad
    return out


def potential_blocks(robot: Robot, data: RobotData, A_model) -> np.ndarray:
    """Scaled blocks (n, 3, r) of the potential terms of model-robust D-optimality.

    The Chebyshev error transfer terms of order :data:`POTENTIAL_ORDER` on every joint (the
    fit's own effect and Jacobian), minus their least-squares projection on the model's scaled
    columns ``A_model`` (n, 3, q) over the same poses, each scaled to unit RMS per pose; columns
    that vanish after the projection (the model has them) are dropped.
    """
    from ..robot.model.estimator import RobotErrorModel
    from ..robot.arm.effects import Chebyshev

    nj = len(robot.joints)
    est = RobotErrorModel(robot, [Chebyshev(order=POTENTIAL_ORDER, joints=list(range(1, nj + 1)))],
                          identifiability=False, orientation_weight=getattr(data, "planned_weight", None))
    _, _, Jp, _, _, _ = est.identification(data)
    Jp = pose_rows(Jp, data.n)
    X = A_model.reshape(-1, A_model.shape[2])
    Z = Jp - X @ np.linalg.lstsq(X, Jp, rcond=None)[0]
    nz = np.linalg.norm(Z, axis=0)
    live = nz > 1e-6 * max(nz.max(initial=0.0), 1e-300)
    Z = Z[:, live] / nz[live] * np.sqrt(data.n)
    return Z.reshape(data.n, A_model.shape[1], -1)


def _prediction_rms(A_pool, M, noise_mm) -> tuple[float | None, float | None]:
    """The parameters' scatter on the pool and the 95 % radius it promises, by the propagation
    ``jointcal predict`` states ``u95_mm`` with (:mod:`pipeline.robot.model.uncertainty`).

    Parameters
    ----------
    A_pool : ndarray, shape (n, 3, q): the pool's scaled Jacobian blocks
    M : ndarray, shape (q, q): the information matrix (scaled units); Cov = noise^2 M^-1
    noise_mm : float, mm, standard deviation of each coordinate

    Returns
    -------
    (predicted RMS position error from the parameters' scatter, mm; the mean over the pool of the 95 %
    radius of that error plus the measurement noise itself, mm), each None when not defined.
    """
    from ..robot.model.uncertainty import prediction_variance, radius95

    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None, None
    tr = prediction_variance(A_pool, Minv)
    v = float(noise_mm * np.sqrt(max(np.mean(tr), 0.0)))
    S = noise_mm ** 2 * (prediction_covariance(A_pool, Minv) + np.eye(3))
    u = float(np.mean(radius95(S)))
    return (v if np.isfinite(v) else None), (u if np.isfinite(u) else None)


def plan_poses(robot: Robot, effects, pool: RobotData, n: int, measured: RobotData | None = None,
               reveal=None, noise_mm: float = 0.05, curve_k=None, say=None, exchange=True,
               criterion: str = "robust", noise_arcsec: float | None = None) -> Plan:
    """Choose ``n`` poses of ``pool`` that determine the model best (D) or reveal ``reveal`` (Ds).

    Parameters
    ----------
    robot : Robot (N joints)
    effects : list of RobotEffect (the spec's model)
    pool : RobotData
        Candidate poses (joint values, payloads; directions matter for backlash only).
    n : int
        Poses to choose.
    measured : RobotData, optional
        Poses already measured (``--campaign``): their information is counted, they are never chosen
        again, nor any pool pose equal to one of them.
    reveal : RobotEffect, optional
        The suspected effect: choose the poses that tell it apart from ``effects`` (Ds-optimality
        on the model ``effects + [reveal]``).
    noise_mm : float
        Measurement noise (mm, standard deviation of each coordinate) of the predicted error.
    curve_k : sequence of int, optional
        Numbers of poses of the predicted-error curve (greedy prefixes; default a range around n).
    noise_arcsec : float, optional
        A 6-DoF probe's orientation noise (arcsec, 1 sigma per axis): the poses are chosen for the
        information the orientation adds too (each pose 6 rows, the orientation's weighed by the ratio
        of the two noises); ``predicted_rms_mm`` is still the position's. Default: an SMR (positions).
    criterion : {"robust", "D", "I"}
        ``"D"``: log det of the information matrix. ``"robust"`` (default): log det of the information
        of the parameters and of potential terms the model lacks (:func:`potential_blocks`, DuMouchel &
        Jones' model-robust D-optimality). ``"I"``: from the D-optimal design, exchanges that lower the
        mean prediction variance over the pool (what predicted_rms_mm measures). ``reveal`` is always Ds.

    Returns
    -------
    Plan; ``chosen`` indexes ``pool`` in visiting order.
    """
    say = say or (lambda msg: None)
    m0 = 0 if measured is None else measured.n
    full_effects = list(effects) + ([reveal] if reveal is not None else [])
    union = pool if measured is None else concat_data(measured, pool)
    weight = None
    if noise_arcsec is not None:
        weight = noise_mm / (noise_arcsec / ARCSEC_PER_MRAD)
        union, pool = with_probe(union, weight), with_probe(pool, weight)
        if measured is not None:
            measured = with_probe(measured, weight)
    est = effects_estimator(robot, full_effects)
    est.orientation_weight = weight
    d, _, J2, Pen, penalised, ident_pool = est.identification(union)
    keep = np.asarray(ident_pool["keep"], bool)
    names = list(d.names)
    n_rows = union.n
    J2 = pose_rows(J2, n_rows)
    A_all, norms = _scaled_blocks(J2, keep, n_rows)
    rows = A_all.shape[1]      # measured coordinates per pose: 3 (an SMR) or 6 (a 6-DoF probe)
    q = int(keep.sum())
    M0 = RIDGE * np.eye(q)
    if Pen.shape[0]:
        # the effects' own penalty rows, as they stand for n poses (they scale with the number of poses)
        Pk = Pen[:, keep] / norms * np.sqrt((m0 + n) / n_rows)
        M0 = M0 + Pk.T @ Pk
    M0_base = M0.copy()
    if m0:
        Am = A_all[:m0]
        M0 = M0 + np.einsum("nkp,nkq->pq", Am, Am)
    A = A_all[m0:]
    kept_names = [nm for nm, k in zip(names, keep) if k]
    sub = None
    if reveal is not None:
        own = set(reveal.parameter_names(robot))
        sub = np.array([i for i, nm in enumerate(kept_names) if nm not in own], int)
        if sub.size == q:
            from ..core.errors import InputError
            from .reveal import what_poses_need

            why = "; ".join(f"{nm}: {ident_pool['fixed_reasons'].get(nm, {}).get('reason', 'not identifiable')}"
                            for nm in reveal.parameter_names(robot))
            raise InputError("--reveal", f"no pose of this pool can identify the suspected effect ({why}); the "
                             f"poses need {what_poses_need(reveal)}", 1, 1)
    # candidates: distinct pool poses, none equal to a measured one
    qkey = pool.q_deg if reveal is None or reveal.name != "backlash" else np.hstack([pool.q_deg, pool.dir])
    cand = distinct_rows(np.hstack([qkey, pool.payload_kg[:, None]]))
    if m0:
        cand &= ~near_any(pool.q_deg, measured.q_deg, MEASURED_POSE_DEG)
        pid = set(map(str, measured.point_id))
        cand &= np.array([str(p) not in pid for p in pool.point_id], bool)
    candidates = np.flatnonzero(cand)
    notes = []
    if len(candidates) < n:
        notes.append(f"the pool has only {len(candidates)} distinct poses not yet measured; {len(candidates)} chosen")
        n = len(candidates)
    if rows * (m0 + n) < q:
        notes.append(f"{m0 + n} poses give {rows * (m0 + n)} coordinates for {q} parameters: too few to determine the "
                     f"model (at least {-(-q // rows)} poses)")
    say(f"pool: {pool.n} poses ({len(candidates)} candidates), {q} of {len(names)} parameters identifiable on the pool")
    # greedy prefixes for the curve (D-criterion, a separate run so that the plan's exchange is not limited)
    kmax = len(candidates)
    if curve_k is None:
        lo = max(1, -(-q // rows))
        curve_k = sorted({k for k in np.unique(np.round(np.geomspace(lo, max(lo, min(kmax, max(4 * n, 60))), 12)).astype(int))} | {n})
    curve_k = [int(k) for k in curve_k if 0 < k <= kmax]
    curve = []
    if curve_k:
        c = _Criterion(A, M0)
        allowed = np.zeros(len(A), bool)
        allowed[candidates] = True
        for step in range(1, max(curve_k) + 1):
            g = np.where(allowed, c.gains(), -np.inf)
            i = int(np.argmax(g))
            c.add(i)
            allowed[i] = False
            if step % 25 == 0:
                c.refresh()          # the rank-3 updates' rounding does not accumulate
            if step in curve_k:
                tr = np.einsum("nkk->n", c.full.G[:, :3, :3])     # the position's rows
                rms = noise_mm * float(np.sqrt(max(np.mean(tr), 0.0)))
                ok = rows * (m0 + step) >= q
                curve.append({"k": step, "predicted_rms_mm": rms if ok and np.isfinite(rms) else None})
    if criterion not in ("robust", "D", "I"):
        raise ValueError(f"unknown criterion {criterion!r}")
    if reveal is None and criterion == "robust":
        P_all = potential_blocks(robot, union, A_all)
        Af = np.concatenate([A_all, P_all], axis=2)
        r = P_all.shape[2]
        M0f = np.zeros((q + r, q + r))
        M0f[:q, :q] = M0_base
        M0f[q:, q:] = (RIDGE + POTENTIAL_PRECISION) * np.eye(r)
        if m0:
            M0f = M0f + np.einsum("nkp,nkq->pq", Af[:m0], Af[:m0])
        crit = _Criterion(Af[m0:], M0f)
        say(f"model-robust D-optimal: {q} parameters and {r} potential terms (Chebyshev order {POTENTIAL_ORDER}, "
            f"prior precision {POTENTIAL_PRECISION:g})")
    else:
        crit = _Criterion(A, M0, sub, DS_WEIGHT)
    chosen, _ = greedy_exchange(crit, candidates, n, say, exchange)
    value = float(crit.value())
    name = ("Ds-optimal" if reveal is not None else "robust D-optimal" if criterion == "robust" else "D-optimal")
    if criterion == "I" and reveal is None and exchange and rows * (m0 + len(chosen)) >= q:
        W = np.einsum("nkp,nkq->pq", A, A) / len(A)
        chosen = i_exchange(A, M0, W, chosen, candidates, say)
        M = M0 + np.einsum("nkp,nkq->pq", A[chosen], A[chosen])
        value, name = float(np.trace(W @ np.linalg.inv(M))), "I-optimal"
    chosen = np.asarray(chosen, int)
    # the fit's own identification check on what would be measured
    data_sel = pool.subset(chosen) if measured is None else concat_data(measured, pool.subset(chosen))
    if weight is not None:
        data_sel = with_probe(data_sel, weight)
    est_sel = effects_estimator(robot, full_effects)
    est_sel.orientation_weight = weight
    dsel, _, _, _, _, ident = est_sel.identification(data_sel)
    kept_sel = {nm for nm, k in zip(dsel.names, ident["keep"]) if k}
    Msel = M0 + np.einsum("nkp,nkq->pq", A[chosen], A[chosen])
    idx = np.array([i for i, nm in enumerate(kept_names) if nm in kept_sel], int)
    if reveal is not None:
        idx = np.intersect1d(idx, sub)        # the spec's model's error (the effect is what is being tested)
    pred, u95_pred = (_prediction_rms(A[:, :3, idx], Msel[np.ix_(idx, idx)], noise_mm) if rows * (m0 + n) >= q
                      else (None, None))
    # visiting order
    start = None
    if m0:
        start = measured.q_deg[-1]
    qc = pool.q_deg[chosen]
    order = visiting_order(qc, start, payload_kg=pool.payload_kg[chosen] if np.ptp(pool.payload_kg) > 0 else None)
    not_on_pool = {nm: ident_pool["fixed_reasons"].get(nm, {}).get("reason", "not identifiable")
                   for nm, k in zip(names, keep) if not k}
    plan = Plan(chosen[order], name, value, kept_names,
                not_on_pool, ident, pred, float(noise_mm), curve,
                path_cost(qc, order, start), path_cost(qc, np.arange(len(qc)), start), notes)
    plan.predicted_u95_mm = u95_pred
    if not_on_pool:
        broad_est = effects_estimator(robot, full_effects)      # a fresh one: its effects prepared on other poses
        broad_est.orientation_weight = weight
        plan.structural = structural_parameters(robot, broad_est, union, weight, list(not_on_pool))
    return plan


def structural_parameters(robot: Robot, est, union: RobotData, weight, names: list) -> list:
    """Which of ``names`` (parameters the pool cannot identify) no poses identify: not identifiable on
    :data:`BROAD_POSES` poses uniform over the robot's joint ranges either (seeded; both approach
    directions, the pool's payloads at random), e.g. combinations of others that one SMR never tells
    apart. The rest are the pool's: other poses would identify them."""
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(robot.lower_deg, float), np.asarray(robot.upper_deg, float)
    q = rng.uniform(lo, hi, (BROAD_POSES, len(lo)))
    payloads = np.unique(np.asarray(union.payload_kg, float))
    broad = pool_data(robot, q, payloads[rng.integers(0, len(payloads), BROAD_POSES)],
                      rng.choice([-1, 1], q.shape))
    if weight is not None:
        broad = with_probe(broad, weight)
    d, *_, ident = est.identification(broad)
    keep = dict(zip(d.names, np.asarray(ident["keep"], bool)))
    return [nm for nm in names if nm in keep and not keep[nm]]


def parameter_notes(summary: dict) -> list[str]:
    """The console's lines on the parameters a plan's pool cannot identify, by why: structural (no poses
    would) or the pool's; redundant ones (combinations of others) are fitted by ``jointcal fit`` as its
    share nearest the nominal robot, the others left at nominal."""
    reasons = summary.get("not_identifiable_on_pool") or {}
    structural = set(summary.get("not_identifiable_structural") or ())
    groups = {}
    for nm, why in reasons.items():
        groups.setdefault((nm in structural, str(why).startswith("redundant")), []).append(nm)
    text = {
        (True, True): "combinations of other parameters on any poses (structural, e.g. what one SMR cannot tell "
                      "apart): jointcal fit gives them their share, nearest the nominal robot, and reports their "
                      "values; no poses separate them",
        (True, False): "not identifiable from any poses (structural): left at nominal by jointcal fit",
        (False, True): "combinations of other parameters on the poses of this pool (poses elsewhere in the joint "
                       "ranges would separate them): jointcal fit gives them their share, nearest the nominal robot",
        (False, False): "not identifiable from any poses of this pool (poses elsewhere in the joint ranges would "
                        "identify them): left at nominal by jointcal fit",
    }
    return [f"{text[key]}: {', '.join(groups[key])}" for key in sorted(groups, reverse=True)]
