"""How sure a fitted robot model is (contract section 14): each parameter's standard uncertainty,
the pairs that trade with each other, and each predicted point's 95 % radius ``u95_mm``.

**Parameters.** The fit moves the parameters ``x`` in the span of its fitted directions ``B``
(``x = B z``, :meth:`pipeline.robot.model.estimator.RobotErrorModel.fit`: the identified parameters,
redundant combinations held nearest the nominal robot by :func:`~pipeline.robot.model.identify.physical_subspace`,
parameters left at nominal outside it). At the solution, with ``A = [J B; Pen B]`` (the Jacobian of the
position residuals in the fitted directions, and the effects' penalty rows), the least-squares
covariance is

    Cov(x) = s^2 B (A^T A)^-1 B^T,   s^2 = ||r||^2 / (3 n - dof),   dof = trace of the hat matrix

(``r`` the sample poses' position residuals; ``dof`` the fitted directions, less what the penalties
hold). What this states, and what it does not:

* a parameter left at nominal (weakly determined, or one the SMR does not feel) has no uncertainty in
  the model (it is not fitted): ``uncertainty`` is null, ``why_fixed`` says why;
* a parameter in a group the measurements cannot tell apart (docs/physical-redundancy.md: with one SMR,
  the last joint's frame and the tool offset) is stated as the representative nearest the nominal
  robot: ``B`` has no part along the unseen combinations, so they carry no variance. The combination
  itself is not measured at all (its real value is unknown, and no prediction depends on it):
  ``identification.redundant`` names it. The parameter's ``uncertainty`` is that of what the
  measurements see of it.

**Points.** A pose's predicted position has three independent parts of error (3 x 3 covariance, mm^2):

1. the parameters' covariance propagated to the pose: ``J_x Cov(x) J_x^T`` (``J_x`` the model's position
   Jacobian at the pose, 3 rows; orientation rows, when a model has them, would be rows 4-6 of the same
   propagation, :func:`prediction_covariance`);
2. the scatter the model leaves unexplained, from its 5-fold cross-validation on the sample poses:
   the covariance of the held-out residuals less the part (1) accounts for (at the folds' size), floored
   at 0 (:func:`unexplained_covariance`). It holds the tracker's noise, the robot's repeatability and
   every effect the model lacks;
3. beyond the joint ranges the model was fitted on (:func:`extrapolation_covariance`): what the model does
   there is settled by no measurement (a joint map fades to 0 at the edge; the fit's trade-offs hold in
   the region they were made in). The fit learns how much it errs there from its own sample poses
   (:func:`region_split_errors`: each joint, refitted below its 60th percentile and judged above, and the
   mirror, by one linearised Gauss-Newton step at the solution): each joint's error beyond its range, a
   level at the edge plus a growth with the distance (:func:`extrapolation_growth`), is stated in the fit
   JSON and added, of every direction alike, for a pose that far beyond; several joints' errors combine by
   the norm their pair splits hold (:func:`region_pair_errors`, :func:`extrapolation_combination`: refitted
   inside two joints' cuts at once, judged beyond both). A fit JSON without it keeps
   the older guess: an unknown angle error growing from 0 at the edge, one sampled width beyond it
   (:data:`EXTRAPOLATION_WIDTHS`), to the unexplained scatter of (2) expressed as that joint's angle
   together with the spread of the model's own angle error of that joint over its sample poses
   (:func:`joint_angle_spread`).

The 95 % radius of a 3-D error of covariance ``S`` is the 0.95 quantile of ``|e|``, ``e ~ N(0, S)``:
``|e|^2`` is a weighted sum of chi-square(1) variables (weights: eigenvalues of ``S``), taken as a
scaled chi-square with the same mean and variance (Welch-Satterthwaite; exact for an isotropic and for
a one-axis error, :func:`radius95`). Real residuals are not Gaussian (a few large ones), so the radius
is then calibrated on the cross-validation's own held-out residuals: ``coverage_factor`` is the 0.95
quantile of ``|r_i| / radius95(S_i)`` over them (1 for Gaussian errors) and ``u95_mm = coverage_factor
radius95(S)``. Nothing of the target poses enters: the check on them (``coverage_95``) is honest.
"""

from __future__ import annotations

import re

import numpy as np

from ...core.se3 import ARCSEC_PER_MRAD_EXACT, ARCSEC_PER_RAD

#: The probability of the stated radius
P95 = 0.95
#: Pairs of parameters correlated beyond this are listed (contract section 14)
CORRELATION_LIMIT = 0.9
#: Beyond a joint's sampled range, its unknown angle error grows linearly from 0 at the edge to the
#: whole unexplained scatter (as that joint's angle) at this many sampled widths beyond it
#: (:func:`extrapolation_covariance`); further, it stays there.
EXTRAPOLATION_WIDTHS = 1.0
#: Region splits (:func:`region_split_errors`): each joint's sample poses below this quantile of its angle
#: are refitted on and those above judged, and the mirror (above the ``1 -`` quantile, judged below)
SPLIT_QUANTILE = 0.6
#: Fewest judged poses a joint's splits need for its growth to be learned (:func:`extrapolation_growth`);
#: a joint with fewer keeps the one-width guess (:data:`EXTRAPOLATION_WIDTHS`)
SPLIT_MIN_POSES = 12
#: At most this many judged poses a joint (evenly spaced) are used to learn its error beyond the range
#: (:func:`extrapolation_growth`): more change the 95 % quantile by little and cost time (docs/speed.md)
GROWTH_MAX_POSES = 1000
#: Beyond a joint's sampled range its learned error (:func:`extrapolation_growth`) rises from 0 at the edge
#: to its whole size at this many degrees beyond it, and stays there: on the real UR10's region splits
#: the error beyond a split is already whole a few degrees past it and then about flat with the distance
#: (docs/uncertainty.md)
EXTRAPOLATION_RAMP_DEG = 1.0
#: Singular values of the column-scaled fitted Jacobian below this (relative) are left out of the
#: covariance (directions the fit could not move: none, normally)
COVARIANCE_RCOND = 1e-12


def model_jacobian(model, data, columns=None) -> np.ndarray:
    """Position Jacobian of a fitted model at its solution, shape (n, 3, p), mm per internal unit.

    Parameters
    ----------
    model : RobotErrorModel (fitted or rebuilt from JSON)
    data : RobotData, n poses
    columns : ndarray, shape (p,), bool, optional
        Only those parameters' columns: (n, 3, k).
    """
    _, J = model.design(data).predict_and_jacobian(model.coef_, columns)
    return J


def moving(cov) -> np.ndarray:
    """The parameters a covariance (p, p) holds, (p,) bool: a parameter left at nominal has an exactly zero
    row and column, and adds nothing to ``J C J^T`` (its Jacobian columns need not be made)."""
    return np.any(np.asarray(cov) != 0.0, axis=0)


def parameter_covariance(model, data) -> dict:
    """Covariance of a fitted model's parameters from its Jacobian at the solution (module docstring).

    Parameters
    ----------
    model : RobotErrorModel
        Fitted on ``data`` (``basis_``, ``penalty_``: its fitted directions and penalty rows).
    data : RobotData
        The sample poses it was fitted on (``measured_mm`` (n, 3), mm).

    Returns
    -------
    dict: ``covariance`` (p, p) internal units, ``sigma_mm`` (s, per coordinate, mm), ``dof`` (fitted
    degrees of freedom), ``n_obs`` (3 n).
    """
    from .normal import DENSE_SVD_MAX, gram, scaled_svd

    d = model.design(data)
    B = np.asarray(model.basis_, float)
    Pen = np.asarray(getattr(model, "penalty_", np.zeros((0, d.p))), float)
    PB = Pen @ B
    n_obs = (6 if d.oriented else 3) * data.n
    if n_obs * d.p <= DENSE_SVD_MAX:
        if d.oriented:
            # a 6-DoF fit: its residual rows are the positions and the weighted orientations (variance
            # components make both of one variance per row), and so is its covariance's
            r, J2 = d.residual_and_jacobian(model.coef_)
        else:
            P, J = d.predict_and_jacobian(model.coef_)
            J2 = J.reshape(-1, d.p)
            r = (P - np.asarray(data.measured_mm, float)).ravel()
        A = np.vstack([J2 @ B, PB])
        c = np.linalg.norm(A, axis=0)
        c = np.where(c > 0, c, 1.0)
        U, sv, Vt = np.linalg.svd(A / c, full_matrices=False)
        live = sv > COVARIANCE_RCOND * (sv[0] if sv.size else 1.0)
        U, sv, Vt = U[:, live], sv[live], Vt[live]
        dof = float(np.sum(U[:n_obs] ** 2))
    else:
        # a large campaign: the same sv and V from the sparse Jacobian, block of rows by block (no dense J or
        # U: docs/speed.md), and the data rows' share of each direction as 1 less the penalty rows' (U's
        # columns are unit vectors)
        if d.oriented:
            _, r, Js = d.residual_and_sparse_jacobian(model.coef_)
        else:
            P, Js = d.predict_and_sparse_jacobian(model.coef_)
            r = (P - np.asarray(data.measured_mm, float)).ravel()
        H, _ = gram(Js)
        c = np.sqrt(np.maximum(np.einsum("pk,pk->k", B, H @ B) + np.sum(PB ** 2, axis=0), 0.0))
        c = np.where(c > 0, c, 1.0)
        sv, Vt = scaled_svd(_Rows(Js.tocsr(), B, PB), c)
        live = sv > COVARIANCE_RCOND * (sv[0] if sv.size else 1.0)
        sv, Vt = sv[live], Vt[live]
        dof = float(np.sum(1.0 - np.sum(((PB / c) @ Vt.T / sv) ** 2, axis=0)))
    s2 = float(r @ r) / max(n_obs - dof, 1.0)
    Hinv = (Vt.T / sv ** 2) @ Vt / np.outer(c, c)
    cov = s2 * (B @ Hinv @ B.T)
    cov = 0.5 * (cov + cov.T)
    return {"covariance": cov, "sigma_mm": float(np.sqrt(s2)), "dof": dof, "n_obs": int(n_obs)}


class _Rows:
    """The rows of ``[J B; Pen B]`` (J sparse (m, p), B (p, k), Pen B (m_p, k)) as :func:`scaled_svd` reads
    them: a slice of rows at a time, dense."""

    def __init__(self, J, B, PB):
        self.J, self.B, self.PB = J, B, PB
        self.shape = (J.shape[0] + PB.shape[0], B.shape[1])

    def __getitem__(self, rows: slice) -> np.ndarray:
        m = self.J.shape[0]
        a, b = rows.start or 0, min(rows.stop, self.shape[0])
        top = np.asarray(self.J[a:min(b, m)] @ self.B) if a < m else np.zeros((0, self.shape[1]))
        return np.vstack([top, self.PB[max(a - m, 0):max(b - m, 0)]])


def orientation_jacobian(model, data, columns=None) -> np.ndarray:
    """The probe frame's turn (base frame) with respect to the parameters at the solution, shape (n, 3, p),
    mrad per internal unit (a 6-DoF probe's orientation, contract section 13); ``columns`` as
    :func:`model_jacobian`'s."""
    _, _, J = model.design(data).pose_and_jacobian(model.coef_, columns)
    return J[:, 3:]


def prediction_variance(J, cov) -> np.ndarray:
    """Trace of the propagated covariance per pose: ``trace(J_i C J_i^T)``, shape (n,).

    Parameters
    ----------
    J : ndarray, shape (n, m, p)
        Prediction Jacobian (m rows a pose: 3 position rows, mm per parameter unit).
    cov : ndarray, shape (p, p)
        Parameter covariance in the same parameter units.
    """
    J = np.asarray(J, float)
    if not len(J):
        return np.zeros(0)
    return np.concatenate([np.einsum("nkq,nkq->n", JC, Jc) for Jc, JC in _times_cov(J, cov)])


def prediction_covariance(J, cov) -> np.ndarray:
    """The parameters' covariance propagated to each pose: ``J_i C J_i^T``, shape (n, m, m).

    Parameters
    ----------
    J : ndarray, shape (n, m, p)
        Prediction Jacobian (rows 1-3 position, mm per unit; rows 4-6, when given, orientation).
    cov : ndarray, shape (p, p)
    """
    J = np.asarray(J, float)
    if not len(J):
        return np.zeros((0, J.shape[1], J.shape[1]))
    return np.concatenate([np.matmul(JC, Jc.transpose(0, 2, 1)) for Jc, JC in _times_cov(J, cov)])


#: poses a block of :func:`_times_cov`: a large campaign's products are not made at once (docs/speed.md)
_BLOCK = 2048


def _times_cov(J, cov):
    """``(J_i, J_i C)`` by blocks of poses: ``J C`` as one matrix product a block. numpy's einsum of the
    three operands ``J, C, J`` sums over both parameter indices at once, (m p)^2 products a pose (far slower:
    docs/speed.md)."""
    J = np.asarray(J, float)
    n, m, p = J.shape
    cov = np.asarray(cov, float)
    for a in range(0, n, _BLOCK):
        Jc = J[a:a + _BLOCK]
        yield Jc, (Jc.reshape(-1, p) @ cov).reshape(Jc.shape)


def radius95(S, p: float = P95) -> np.ndarray:
    """Radius holding a zero-mean Gaussian 3-D error of covariance ``S`` with probability ``p``.

    ``|e|^2`` is the sum of the eigenvalues of ``S`` times chi-square(1) variables; it is taken as
    ``a chi2(nu)`` with its mean and variance (Welch-Satterthwaite): exact for an isotropic error
    (chi2(3)) and for an error along one axis (chi2(1)).

    Parameters
    ----------
    S : ndarray, shape (n, 3, 3), mm^2

    Returns
    -------
    ndarray, shape (n,), mm
    """
    return _radius95_of(np.linalg.eigvalsh(np.asarray(S, float)), p)


def _radius95_of(lam, p: float = P95) -> np.ndarray:
    """:func:`radius95` from the covariances' eigenvalues ``lam`` (n, 3), mm^2 (``S + c I`` has ``lam + c``)."""
    from scipy import special  # chi2.ppf(p, nu) is 2 gammaincinv(nu / 2, p); scipy.stats costs 2 s to import

    lam = np.clip(np.asarray(lam, float), 0.0, None)
    s1, s2 = lam.sum(axis=-1), (lam ** 2).sum(axis=-1)
    ok = s2 > 0
    a = np.where(ok, s2 / np.where(ok, s1, 1.0), 0.0)
    nu = np.where(ok, s1 ** 2 / np.where(ok, s2, 1.0), 1.0)
    return np.sqrt(a * 2.0 * special.gammaincinv(nu / 2.0, p))


def unexplained_covariance(cv_residuals, parameter_part) -> np.ndarray:
    """The scatter a model leaves unexplained (3 x 3, mm^2): the covariance (about 0) of its
    cross-validated residuals less the mean of what its parameters' uncertainty accounts for at those
    poses, floored at 0 eigenvalue by eigenvalue.

    Parameters
    ----------
    cv_residuals : ndarray, shape (n, 3), mm
        Held-out residuals of the k-fold cross-validation.
    parameter_part : ndarray, shape (n, 3, 3), mm^2
        The parameters' covariance propagated to those poses, at the folds' size.
    """
    r = np.asarray(cv_residuals, float)
    M = r.T @ r / max(len(r), 1) - np.mean(parameter_part, axis=0)
    M = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(M)
    return (V * np.clip(w, 0.0, None)) @ V.T


def beyond_deg(q_deg, sampled: dict) -> np.ndarray:
    """How far each joint of each pose lies from the angles the model sampled, shape (n, N), deg: beyond the joint
    ranges ``sampled`` (``lower_deg`` / ``upper_deg`` (N,), :func:`pipeline.robot.model.predict.sampled_range`),
    or inside one of their ``gaps_deg`` (stretches no sample pose reached) the distance to the nearer sampled
    angle; 0 where the poses were.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    """
    q = np.asarray(q_deg, float)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    out = np.maximum(np.maximum(lo - q, q - hi), 0.0)
    for j, stretches in (sampled.get("gaps_deg") or {}).items():
        col = q[:, int(j) - 1]
        for a, b in stretches:
            out[:, int(j) - 1] = np.maximum(out[:, int(j) - 1], np.maximum(np.minimum(col - a, b - col), 0.0))
    return out


def in_gap(q_deg, sampled: dict) -> list:
    """Per pose and joint, the stretch ``[low, high]`` (deg) of ``sampled``'s ``gaps_deg`` the joint's angle lies in,
    or None (:func:`beyond_deg`); a list (n) of lists (N).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    """
    q = np.atleast_2d(np.asarray(q_deg, float))
    out = [[None] * q.shape[1] for _ in range(q.shape[0])]
    for j, stretches in (sampled.get("gaps_deg") or {}).items():
        for a, b in stretches:
            for k in np.flatnonzero((q[:, int(j) - 1] > a) & (q[:, int(j) - 1] < b)):
                out[k][int(j) - 1] = [float(a), float(b)]
    return out


def extrapolation_covariance(q_deg, sampled: dict, Jq, unexplained, spread_rad=None, Jturn=None,
                             growth=None, norm_p: float = 2.0) -> np.ndarray:
    """What a pose beyond the sampled joint ranges adds (3 x 3 per pose, mm^2; 0 inside them).

    A joint whose error beyond its range the fit learned from its region splits (``growth``,
    :func:`extrapolation_growth`) adds an error of every direction alike whose size (sqrt of the trace) is
    ``level_j min(b_j / EXTRAPOLATION_RAMP_DEG, 1) + slope_j min(b_j, reach_j)`` at ``b_j`` (deg) beyond the
    sampled range;
    the sizes of several joints combine as their ``norm_p``-norm (2: in quadrature; ``inf``: the largest alone; the
    fit learns it from its pair splits, :func:`extrapolation_combination`). A joint without one
    (NaN; every joint of a fit JSON written before them) keeps the guess below.

    Joint ``j`` beyond its range by ``b_j`` (deg) has an unknown angle error of standard deviation
    ``min(b_j / (EXTRAPOLATION_WIDTHS w_j), 1) g_j`` (``w_j`` the sampled width), moving the point along
    the joint's column of the position Jacobian. ``g_j`` holds two things no measurement there settles:
    the unexplained scatter's 1-sigma size (sqrt(trace / 3)) as that joint's angle (divided by its lever
    arm at the pose), and how much the model's own angle error of the joint varies over the poses it
    was fitted on (``spread_rad``: a joint map, harmonic or backlash measured inside the range says
    nothing of its values beyond it; a constant offset, geometry, extrapolates and adds nothing).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
    sampled : dict, ``lower_deg`` / ``upper_deg`` (N,) (:func:`pipeline.robot.model.predict.sampled_range`)
    Jq : ndarray, shape (n, 3, N), mm per rad: the position Jacobian with respect to each joint angle
    unexplained : ndarray, shape (3, 3), mm^2 (:func:`unexplained_covariance`)
    spread_rad : ndarray, shape (N,), rad, optional
        Standard deviation of the model's angle error of each joint over its sample poses
        (:func:`joint_angle_spread`); default 0.
    Jturn : ndarray, shape (n, 3, N), optional
        The probe frame's turn per joint angle (mrad per rad): then the same unknown joint angle errors as
        the probe's orientation covariance (mrad^2) instead of the position's.
    growth : (level, slope, reach), ndarrays of shape (N,), optional
        Each joint's learned error beyond its range (:func:`extrapolation_growth`): mm, mm per deg and deg (the
        probe frame's turn, mrad and mrad per deg, with ``Jturn``); NaN where not learned.
    norm_p : float
        How the learned sizes of several joints combine (:func:`combined_size`): 2 in quadrature, ``inf`` the largest.
    """
    q = np.asarray(q_deg, float)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    width = np.maximum(hi - lo, 1e-6)
    beyond = beyond_deg(q, sampled)
    grow = np.minimum(beyond / (EXTRAPOLATION_WIDTHS * width), 1.0)                 # (n, N)
    level, slope, reach = ((np.full(q.shape[1], np.nan),) * 3 if growth is None
                           else (np.asarray(g, float) for g in growth))
    learned = np.isfinite(level) & np.isfinite(slope) & np.isfinite(reach)
    extra = 0.0
    if learned.any():
        size = learned_sizes(beyond, (level, slope, reach))
        extra = combined_size(size, norm_p)[:, None, None] ** 2 / 3.0 * np.eye(3)    # (n, 3, 3)
        grow = np.where(learned, 0.0, grow)
    scale = float(np.sqrt(max(np.trace(np.asarray(unexplained, float)), 0.0) / 3.0))
    lever = np.linalg.norm(Jq, axis=1)                                               # (n, N) mm/rad
    spread = np.zeros(q.shape[1]) if spread_rad is None else np.asarray(spread_rad, float)
    sigma = grow * np.sqrt((scale / np.maximum(lever, 1e-9)) ** 2 + spread ** 2)     # rad
    cols = (Jq if Jturn is None else Jturn) * sigma[:, None, :]
    return np.einsum("nkj,nlj->nkl", cols, cols) + extra


def combined_size(size, norm_p: float = 2.0) -> np.ndarray:
    """The size of several joints' errors beyond their ranges together (n,): the ``norm_p``-norm of each pose's
    sizes ``size`` (n, N) (1: they add; 2: in quadrature, independent errors; ``inf``: the largest alone)."""
    size = np.asarray(size, float)
    if size.shape[1] == 0:
        return np.zeros(size.shape[0])
    if np.isinf(norm_p):
        return size.max(axis=1)
    return np.sum(size ** norm_p, axis=1) ** (1.0 / norm_p)


def learned_sizes(beyond_deg, growth) -> np.ndarray:
    """Each joint's learned error size (n, N) at ``beyond_deg`` (n, N) deg beyond its range (:func:`extrapolation_growth`:
    ``growth`` (level, slope, reach)); 0 where not learned (NaN)."""
    b = np.asarray(beyond_deg, float)
    level, slope, reach = (np.asarray(g, float) for g in growth)
    learned = np.isfinite(level) & np.isfinite(slope) & np.isfinite(reach)
    return (np.where(learned, level, 0.0) * _ramp(b)
            + np.where(learned, slope, 0.0) * np.minimum(b, np.where(learned, reach, 0.0)))


#: The combinations of several joints' learned errors :func:`extrapolation_combination` chooses among (the exponent
#: of their norm: 1 they add, 2 in quadrature, ``inf`` the largest alone)
EXTRAPOLATION_NORMS = (1.0, 1.5, 2.0, 3.0, 4.0, 8.0, np.inf)


def extrapolation_combination(pairs: list[dict], S_in, factor: float, growth, key: str = "position_mm") -> float:
    """How the learned errors of several joints beyond their ranges combine, learned from the pair splits
    (:func:`region_pair_errors`): the sharpest norm of :data:`EXTRAPOLATION_NORMS` (the largest exponent) at which
    ``factor radius95(S_in + combined_size^2 / 3 I)`` holds 95 % of the judged errors of the poses that lie beyond
    two or more joints' refitted ranges, each joint's size from ``growth`` (:func:`extrapolation_growth`); 1 (they
    add) when none does. Each joint's own size already holds 95 % of its splits' errors alone; whether the errors
    of several joints add up (quadrature, or more) or one of them makes most of it (the largest) differs from model
    to model, and the pair splits show which.

    Parameters
    ----------
    pairs : list of dict (:func:`region_pair_errors`)
    S_in : ndarray, shape (n, 3, 3): each sample pose's in-range covariance (mm^2, or mrad^2)
    factor : float, the coverage factor of the stated radius
    growth : (level, slope, reach), ndarrays (N,) (:func:`extrapolation_growth`)
    key : ``"position_mm"`` or ``"orientation_mrad"``

    Returns
    -------
    float: the exponent (``inf``: the largest alone); 2 (in quadrature) when the pair splits judged fewer than
    :data:`SPLIT_MIN_POSES` poses beyond two or more joints.
    """
    sizes, errors, idx = [], [], []
    for s in pairs:
        if s.get(key) is None:
            continue
        several = np.sum(np.asarray(s["beyond_deg"]) > 0, axis=1) >= 2
        sizes.append(learned_sizes(np.asarray(s["beyond_deg"])[several], growth))
        errors.append(np.linalg.norm(np.asarray(s[key])[several], axis=1))
        idx.append(np.asarray(s["judged"])[several])
    idx = np.concatenate(idx) if idx else np.zeros(0, int)
    if idx.size < SPLIT_MIN_POSES:
        return 2.0
    size, r = np.concatenate(sizes), np.concatenate(errors)
    S = np.asarray(S_in, float)[idx]
    radius = _radius95_table(P95)
    lam = np.linalg.eigvalsh(S)
    for p in sorted(EXTRAPOLATION_NORMS, reverse=True):
        u = factor * radius(lam + (combined_size(size, p) ** 2 / 3.0)[:, None])
        if np.mean(r <= u) >= P95:
            return float(p)
    return float(min(EXTRAPOLATION_NORMS))


def _ramp(beyond_deg) -> np.ndarray:
    """How much of a joint's learned error beyond its range a pose ``beyond_deg`` (deg) past it has (0 to 1)."""
    return np.minimum(np.asarray(beyond_deg, float) / EXTRAPOLATION_RAMP_DEG, 1.0)


def region_split_errors(model, data, quantile: float = SPLIT_QUANTILE) -> list[dict]:
    """How a fitted model errs beyond the range it was fitted on, learned from its own sample poses.

    For each joint, the model is refitted on the poses whose angle of that joint lies at or below its
    ``quantile`` and judged on the poses above, and the mirror (fitted at or above the ``1 - quantile``,
    judged below). A refit is one Gauss-Newton step from the model's solution in its fitted directions,
    with its penalty rows and orientation weight (:func:`pipeline.robot.model.gauss_newton.steps_without`,
    on the one Jacobian at the solution): the linearised refit on that subset.

    Parameters
    ----------
    model : RobotErrorModel, fitted on ``data`` (``basis_``, ``penalty_``)
    data : RobotData, n poses (``q_deg`` (n, N) deg, ``measured_mm`` (n, 3) mm)
    quantile : float

    Returns
    -------
    list of dict, one a joint and side: ``joint`` (1-based), ``judged`` (m,) the judged poses' indices,
    ``beyond_deg`` (m,) how far each lies beyond the refitted poses' range of that joint (deg, > 0),
    ``position_mm`` (m, 3) their position errors (predicted - measured, mm) and ``orientation_mrad``
    (m, 3) their orientation errors (a 6-DoF fit; else None). Empty when the model has no fitted
    directions or too few poses.
    """
    q = np.asarray(data.q_deg, float)
    cases = []
    for j in range(q.shape[1]):
        lo_cut, hi_cut = np.quantile(q[:, j], [1.0 - quantile, quantile])
        for fitted, up in ((q[:, j] <= hi_cut, True), (q[:, j] >= lo_cut, False)):
            cases.append(((j, up), fitted, ~fitted))
    out = []
    for (j, up), fitted, judged, errors in _split_refits(model, data, cases):
        edge = q[fitted, j].max() if up else q[fitted, j].min()
        out.append({"joint": j + 1, "judged": np.flatnonzero(judged), "beyond_deg": np.abs(q[judged, j] - edge),
                    **errors})
    return out


def region_pair_errors(model, data, quantile: float = SPLIT_QUANTILE) -> list[dict]:
    """How a fitted model errs beyond the range of two joints at once, learned from its own sample poses: for each
    pair of joints and each of their four sides, the model refitted (as :func:`region_split_errors` refits) on the
    poses inside both joints' ``quantile`` cuts and judged on the poses beyond both.

    Parameters
    ----------
    model : RobotErrorModel, fitted on ``data``
    data : RobotData, n poses (``q_deg`` (n, N) deg)
    quantile : float

    Returns
    -------
    list of dict, one a pair and sides: ``joints`` (two, 1-based), ``judged`` (m,) indices, ``beyond_deg`` (m, N)
    how far each judged pose lies beyond the refitted poses' range of every joint (deg, 0 inside), ``position_mm``
    (m, 3) mm and ``orientation_mrad`` (m, 3) mrad or None. Pairs whose sides judged no pose are left out.
    """
    q = np.asarray(data.q_deg, float)
    N = q.shape[1]
    cuts = [np.quantile(q[:, j], [1.0 - quantile, quantile]) for j in range(N)]
    inside = [(q[:, j] <= cuts[j][1], q[:, j] >= cuts[j][0]) for j in range(N)]
    cases = []
    for j in range(N):
        for k in range(j + 1, N):
            for fj in inside[j]:
                for fk in inside[k]:
                    cases.append(({"joints": (j + 1, k + 1)}, fj & fk, ~fj & ~fk))
    out = []
    for case, fitted, judged, errors in _split_refits(model, data, cases):
        lo, hi = q[fitted].min(axis=0), q[fitted].max(axis=0)
        beyond = np.maximum(np.maximum(lo - q[judged], q[judged] - hi), 0.0)
        out.append(dict(case, judged=np.flatnonzero(judged), beyond_deg=beyond, **errors))
    return out


def _split_refits(model, data, cases):
    """The linearised refits of :func:`region_split_errors` and :func:`region_pair_errors`: for each case
    ``(label, fitted, judged)`` (boolean masks (n,) of the poses refitted on and judged) with at least one judged
    pose and :data:`SPLIT_MIN_POSES` fitted ones, yields ``(label, fitted, judged, errors)``, ``errors`` the judged
    poses' ``position_mm`` (m, 3) and ``orientation_mrad`` (m, 3, or None)."""
    from .gauss_newton import steps_without
    from .normal import scaled_min_norm_step

    B = getattr(model, "basis_", None)
    if B is None or np.asarray(B).shape[1] == 0 or data.n < 2 * SPLIT_MIN_POSES:
        return
    B = np.asarray(B, float)
    Pen = np.asarray(getattr(model, "penalty_", np.zeros((0, B.shape[0]))), float)
    d = model.design(data)
    d.keep_last = True                    # the Jacobian at the solution: made once for every split
    sparse = model.solves_on_normal_equations(data)
    x = np.asarray(model.coef_, float)
    n = data.n
    # the residual and Jacobian at the solution (the one the steps use): each refit's residuals are their linear
    # change, as the step is the linearised refit
    if not sparse:
        F0, J0 = d.residual_and_jacobian(x)
    elif d.oriented:
        _, F0, J0 = d.residual_and_sparse_jacobian(x)
    else:
        P0, J0 = d.predict_and_sparse_jacobian(x)
        F0 = (P0 - np.asarray(data.measured_mm, float)).ravel()
    if not sparse:
        # a small model (the dense Jacobian, a few dozen directions): each split's normal equations are the whole
        # campaign's less its judged rows', solved as steps_without solves them (one home: normal.py)
        JB = J0 @ B
        PB = Pen @ B
        H_all, g_all = JB.T @ JB + PB.T @ PB, JB.T @ F0 + PB.T @ (Pen @ x)
    try:
        for label, fitted, judged in cases:
            if not judged.any() or fitted.sum() < SPLIT_MIN_POSES:
                continue
            rows = np.repeat(fitted, 3)
            if d.oriented:
                rows = np.concatenate([rows, rows])
            # only the judged poses' rows of the refit's residuals are needed
            at = np.flatnonzero(np.repeat(judged, 3))
            if d.oriented:
                at = np.concatenate([at, 3 * n + at])
            if sparse:
                xs, _ = steps_without(d, B, Pen, x, rows.astype(float), sparse, data.measured_mm, max_steps=1)
                F = F0[at] + J0[at] @ (xs - x)
            else:
                if 2 * rows.sum() < rows.size:     # fewer rows refitted on than left out: their own normal equations
                    Jc, Fc = JB[rows], F0[rows]
                    dz, _ = scaled_min_norm_step(Jc.T @ Jc + PB.T @ PB, Jc.T @ Fc + PB.T @ (Pen @ x))
                else:
                    Jc, Fc = JB[~rows], F0[~rows]
                    dz, _ = scaled_min_norm_step(H_all - Jc.T @ Jc, g_all - Jc.T @ Fc)
                F = F0[at] + JB[at] @ dz
            m = int(judged.sum())
            yield label, fitted, judged, {
                "position_mm": F[:3 * m].reshape(m, 3),
                "orientation_mrad": (F[3 * m:].reshape(m, 3) / d.weight) if d.oriented else None}
    finally:
        d.keep_last, d._last = False, None


def extrapolation_growth(splits: list[dict], S_in, factor: float, widths, key: str = "position_mm") -> tuple:
    """Each joint's error beyond its sampled range, learned from the region splits: a size at the edge and
    a growth with the distance as far as the splits judged, ``size(b) = level_j min(b / EXTRAPOLATION_RAMP_DEG, 1)
    + slope_j min(b, reach_j)`` (``reach_j`` the farthest judged pose: beyond it nothing was measured and the
    size stays what it was there).

    A judged pose ``b`` (deg) beyond the refitted poses' range of joint ``j`` is given the covariance it
    would have inside the range (``S_in``: the parameters' part and the unexplained scatter) plus an error
    of every direction alike of that size. Its shape (how much of it is the level, how much the growth:
    :data:`EXTRAPOLATION_SHAPES` of the size one sampled width ``w_j`` beyond) is the one under which the
    judged errors are likeliest (3-D Gaussian); its amplitude the smallest at which ``factor radius95(S_in +
    size^2 / 3 I)`` holds 95 % of the judged errors of both splits of that joint (bisection: coverage grows
    with it). A size of 0: the model holds beyond its range as it holds inside (geometry extrapolates).

    Parameters
    ----------
    splits : list of dict (:func:`region_split_errors`)
    S_in : ndarray, shape (n, 3, 3): each sample pose's in-range covariance (mm^2, or mrad^2)
    factor : float, the coverage factor of the stated radius
    widths : ndarray, shape (N,), deg: each joint's sampled width
    key : ``"position_mm"`` or ``"orientation_mrad"``

    Returns
    -------
    (level, slope, reach): ndarrays, shape (N,), mm, mm per deg (mrad, mrad per deg) and deg; NaN where a
    joint's splits judged fewer than :data:`SPLIT_MIN_POSES` poses.
    """
    widths = np.asarray(widths, float)
    N = widths.size
    lam_all, V_all = np.linalg.eigh(np.asarray(S_in, float)) if len(splits) else (np.zeros((0, 3)), None)
    level, slope, reach = np.full(N, np.nan), np.full(N, np.nan), np.full(N, np.nan)
    for j in range(N):
        parts = [s for s in splits if s["joint"] == j + 1 and s.get(key) is not None]
        idx = np.concatenate([s["judged"] for s in parts]) if parts else np.zeros(0, int)
        if idx.size < SPLIT_MIN_POSES:
            continue
        b = np.concatenate([s["beyond_deg"] for s in parts])
        e = np.concatenate([s[key] for s in parts])
        farthest = float(b.max())
        if idx.size > GROWTH_MAX_POSES:
            # a large campaign: evenly spaced judged poses of both splits (the 95 % quantile to about 0.7 %)
            keep = np.linspace(0, idx.size - 1, GROWTH_MAX_POSES).round().astype(int)
            idx, b, e = idx[keep], b[keep], e[keep]
        r = np.linalg.norm(e, axis=1)
        lam = lam_all[idx]
        # the judged errors in the eigen-axes of their in-range covariance: their likelihood at any extra size
        z2 = np.einsum("nk,nkl->nl", e, V_all[idx]) ** 2
        w = max(float(widths[j]), 1e-6)
        best = None
        for t in EXTRAPOLATION_SHAPES:
            shape = (1.0 - t) * _ramp(b) + t * b / w
            a = _least_amplitude(r / factor, lam, shape)
            var = np.maximum(lam + ((a * shape) ** 2 / 3.0)[:, None], 1e-300)
            loglik = -0.5 * float(np.sum(np.log(var) + z2 / var))
            if best is None or loglik > best[0]:
                best = (loglik, a, t)
        _, a, t = best
        level[j], slope[j], reach[j] = a * (1.0 - t), a * t / w, farthest
    return level, slope, reach


#: The shapes :func:`extrapolation_growth` chooses among: the share of a joint's error one sampled width beyond
#: its range that grew with the distance (0: all of it there at the edge, 1: growing from 0 at the edge)
EXTRAPOLATION_SHAPES = (0.0, 0.25, 0.5, 0.75, 1.0)


def _least_amplitude(r, lam, shape, p: float = P95) -> float:
    """The least amplitude ``a >= 0`` at which ``radius95`` of the covariances of eigenvalues ``lam + (a shape)^2 / 3``
    ((n, 3), mm^2) holds the share ``p`` of the errors ``r`` (n,): each pose's own least amplitude (``|r_i|`` on
    its radius, found by bisection for every pose at once; 0 where its radius holds it already), and their ``p``
    quantile. The radius's chi-square quantile is read from a table over its degrees of freedom (1 to 3)."""
    r, lam, shape = np.asarray(r, float), np.asarray(lam, float), np.asarray(shape, float)
    radius = _radius95_table(p)
    need = (radius(lam) < r) & (shape > 0)
    a_i = np.zeros(r.size)
    if need.any():
        rr, ll, sh = r[need], lam[need], shape[need]
        lo, hi = np.zeros(rr.size), np.sqrt(3.0) * rr / sh           # at hi the extra error alone is |r| in size
        for _ in range(20):                            # to 1e-6 of the bracket
            mid = 0.5 * (lo + hi)
            ok = radius(ll + ((mid * sh) ** 2 / 3.0)[:, None]) >= rr
            lo, hi = np.where(ok, lo, mid), np.where(ok, mid, hi)
        a_i[need] = hi
    a_i[(radius(lam) < r) & (shape <= 0)] = np.inf
    k = int(np.ceil(p * r.size)) - 1                   # the least a covering at least p of the poses
    return float(np.sort(a_i)[max(k, 0)]) if r.size else 0.0


def _radius95_table(p: float = P95):
    """:func:`_radius95_of` with the chi-square quantile interpolated from a table over 1 to 3 degrees of freedom
    (relative error below 1e-7): the bisection of :func:`_least_amplitude` evaluates it many times."""
    from scipy import special

    nus = np.linspace(1.0, 3.0, 401)
    table = 2.0 * special.gammaincinv(nus / 2.0, p)

    def radius(lam):
        lam = np.clip(lam, 0.0, None)
        s1, s2 = lam.sum(axis=-1), (lam ** 2).sum(axis=-1)
        ok = s2 > 0
        a = np.where(ok, s2 / np.where(ok, s1, 1.0), 0.0)
        nu = np.where(ok, s1 ** 2 / np.where(ok, s2, 1.0), 1.0)
        return np.sqrt(a * np.interp(nu, nus, table))

    return radius


def joint_angle_spread(model, data) -> np.ndarray:
    """Standard deviation over ``data``'s poses of each joint's angle error in a fitted model (every
    effect on the joint's angle: joint maps, harmonics, compliance, backlash), shape (N,), rad."""
    d = model.design(data)
    dq = (d.configurations(model.coef_) - d.Q0)[:, d.idx.joints]
    return dq.std(axis=0) if len(dq) > 1 else np.zeros(dq.shape[1])


def joint_jacobian(model, data, turn: bool = False) -> np.ndarray:
    """Position Jacobian of a fitted model with respect to each joint's angle, shape (n, 3, N), mm/rad;
    with ``turn`` the probe frame's turn instead (mrad/rad)."""
    from ..arm.kinematics import pose_jacobians, positions_and_jacobians

    d = model.design(data)
    if turn:
        _, _, Jext = pose_jacobians(d.model, d.configurations(model.coef_), "smr")
        return Jext[:, 3:, d.idx.joints] * 1000.0
    _, Jext = positions_and_jacobians(d.model, d.configurations(model.coef_))
    return Jext[:, :, d.idx.joints]


# ------------------------------------------------------------------ the fit's statement
def correlated_pairs(names, cov, limit: float = CORRELATION_LIMIT, groups=()) -> list[dict]:
    """Pairs of parameters whose correlation exceeds ``limit`` in magnitude, strongest first.

    Parameters
    ----------
    names : list of str, length p
    cov : ndarray, shape (p, p) (parameters without variance are left out)
    groups : sequence of sequences of names
        The groups the measurements cannot tell apart (the fit's ``identification.redundant``): a pair
        inside one is marked ``"redundant": true`` (they move together because the fit holds the unseen
        combination nearest the nominal robot, not because the data tie them).

    Returns
    -------
    list of ``{"a", "b", "value", "redundant"}`` (value rounded to 1e-6)
    """
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    live = np.flatnonzero(sd > 1e-12 * max(sd.max(initial=0.0), 1e-300))
    if live.size < 2:
        return []
    C = cov[np.ix_(live, live)] / np.outer(sd[live], sd[live])
    i, j = np.triu_indices(live.size, 1)
    v = C[i, j]
    hit = np.abs(v) > limit
    group_of = {nm: k for k, g in enumerate(groups) for nm in g}
    out = [{"a": names[live[a]], "b": names[live[b]], "value": round(float(x), 6) + 0.0,
            "redundant": group_of.get(names[live[a]], -1) == group_of.get(names[live[b]], -2)}
           for a, b, x in zip(i[hit], j[hit], v[hit])]
    out.sort(key=lambda e: (-abs(e["value"]), e["a"], e["b"]))
    return out


_MEANING = [
    (r"^dtheta(\d+)$", "joint {0}'s zero offset (the angle it reads at its zero)"),
    # robot.toml's link transform (contract section 2), whether written by hand or imported from a URDF or a
    # calibration.conf: classic DH plus a tilt beta, T_i = Rz(q_i + theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)
    (r"^dd(\d+)$", "the offset along joint {0}'s axis (robot.toml's d_mm of joint {0}: DH d)"),
    (r"^da(\d+)$", "link {0}'s length along its common normal (robot.toml's a_mm of joint {0}: DH a)"),
    (r"^dalpha(\d+)$", "the twist from joint {0}'s axis to the next joint's, about the link's x (robot.toml's "
                       "alpha_deg of joint {0}: DH alpha)"),
    (r"^dbeta(\d+)$", "the tilt from joint {0}'s axis to the next joint's, about the link's y (robot.toml's "
                      "beta_deg of joint {0}: the beta of DH + beta, for nearly parallel axes)"),
    (r"^base_d([xyz])$", "the base frame's offset along {0} (where the tracker sees the robot)"),
    (r"^base_e([xyz])$", "the base frame's rotation about {0}"),
    (r"^tool_d([xyz])$", "the SMR's offset on the flange along {0}"),
    (r"^map(\d+)_(\d+)$", "knot {1} of joint {0}'s angle error map"),
    (r"^compliance(\d+)$", "joint {0}'s compliance (angle per torque)"),
    (r"^half_backlash(\d+)$", "half of joint {0}'s backlash"),
    (r"^([AB])(\d+)_joint(\d+)$", "the order-{1} harmonic ({0}) of joint {2}'s angle error"),
    (r"^expansion_ppm_per_K$", "the arm's thermal expansion"),
    (r"^(gamma|lambda)_(\d+)_(\w+)_(\d+)$", "a Chebyshev coefficient of link {3}'s error transfer"),
]


def meaning(name: str) -> str:
    """What a parameter is, physically (plain words; '' when not known)."""
    for pat, text in _MEANING:
        m = re.match(pat, name)
        if m:
            return text.format(*m.groups())
    return ""


def largest_relative(parameters: list[dict], k: int = 3, skip=()) -> list[dict]:
    """The ``k`` fitted parameters of largest relative uncertainty (uncertainty / |value|).

    Parameters
    ----------
    parameters : list of dict with ``name``, ``value``, ``unit``, ``uncertainty`` (None when fixed)
    skip : names left out (the knots of a smooth map, held by their effect's penalty: one knot is not
        a physical quantity of its own)

    Returns
    -------
    list of ``{name, value, uncertainty, unit, relative, meaning}``, largest first
    """
    rows = []
    skip = set(skip)
    for p in parameters:
        u = p.get("uncertainty")
        if p["name"] in skip or u is None or not np.isfinite(u) or u <= 0:
            continue
        rel = u / abs(p["value"]) if p["value"] != 0 else float("inf")
        rows.append({"name": p["name"], "value": p["value"], "uncertainty": u, "unit": p["unit"], "relative": rel,
                     "meaning": meaning(p["name"])})
    # largest first, counted to 6 digits: a pair the data cannot tell apart (a joint's zero offset and the
    # base's turn about the same axis: dd1 and base_dz) has the same relative uncertainty but for rounding,
    # which reaches the 8th digit on a real series (0.905366221 / 0.905366203), and is named in the order of
    # its names, not of its last digits
    rows.sort(key=lambda r: (-float(f"{r['relative']:.6g}"), r["name"]))
    return rows[:k]


def describe_relative(rows: list[dict]) -> str:
    """One console line of :func:`largest_relative`."""
    parts = []
    for r in rows:
        what = f" ({r['meaning']})" if r["meaning"] else ""
        verdict = ("not told apart from 0" if r["relative"] > 0.5 else "determined to within "
                   f"{100 * r['relative']:.0f} %")
        parts.append(f"{r['name']}{what} {r['value']:.4g} +- {r['uncertainty']:.2g} {r['unit']}: {verdict}")
    return "; ".join(parts)


def describe_beyond(pred: dict) -> str:
    """In words, what a fit JSON's ``prediction_uncertainty`` (``pred``) adds beyond the sampled joint ranges:
    each learned joint's 1-sigma size at the farthest its region splits judged, largest first ('' when
    none was learned)."""
    level, slope, reach = (pred.get(k) for k in ("extrapolation_mm", "extrapolation_mm_per_deg",
                                                 "extrapolation_reach_deg"))
    if not (isinstance(level, list) and isinstance(slope, list) and isinstance(reach, list)):
        return ""
    sizes = [(l + s * r, j + 1, r) for j, (l, s, r) in enumerate(zip(level, slope, reach))
             if l is not None and s is not None and r is not None]
    if not sizes:
        return ""
    sizes.sort(key=lambda x: (-x[0], x[1]))
    return ("beyond a joint's sampled range its own region splits add (1 sigma, every direction alike) "
            + ", ".join(f"joint {j} {v:.3f} mm ({r:.0f} deg beyond)" for v, j, r in sizes))


def uncertainty_document(model, sample, cv_residuals, n_folds: int, cv_orientation=None) -> dict:
    """What the fit JSON says of its uncertainty, and what ``predict`` and ``correct`` need for ``u95_mm``.

    Parameters
    ----------
    model : RobotErrorModel, fitted on ``sample``
    sample : RobotData (n poses, ``measured_mm`` (n, 3) mm)
    cv_residuals : ndarray, shape (n, 3), mm: the k-fold cross-validation's held-out residuals on ``sample``
    n_folds : int
    cv_orientation : ndarray, shape (n, 3), mrad, optional
        A 6-DoF fit's held-out orientation errors: then the same statement for the orientation
        (``u95_arcsec``): its unexplained covariance (mrad^2) and its own coverage factor.

    Returns
    -------
    dict: ``uncertainty`` (p,) per parameter in reported units (None when left at nominal),
    ``correlations`` (:func:`correlated_pairs`, reported names) and ``prediction`` (JSON-ready: the
    covariance of the parameters that move, reported units; the unexplained covariance mm^2; the
    coverage factor and how it was found).
    """
    pc = parameter_covariance(model, sample)
    cov = pc["covariance"]
    f = np.array([u[1] for u in model.units_], float)
    cov_rep = cov * np.outer(f, f)
    sd = np.sqrt(np.clip(np.diag(cov_rep), 0.0, None))
    fixed = set(model.fixed_)
    unc = [None if n in fixed else float(s) for n, s in zip(model.names_, sd)]
    mv = moving(cov)
    cov_mv = cov[np.ix_(mv, mv)]
    J = model_jacobian(model, sample, mv)
    n = sample.n
    train = n * (n_folds - 1) / n_folds
    at_cv = prediction_covariance(J, cov_mv) * (n / max(train, 1.0))
    U = unexplained_covariance(cv_residuals, at_cv)
    S_cv = at_cv + U
    r_cv = np.linalg.norm(np.asarray(cv_residuals, float), axis=1)
    base = radius95(S_cv)
    factor = float(np.quantile(r_cv / np.where(base > 0, base, np.inf), P95)) if n else 1.0
    # how its error grows beyond the range it saw, learned from its own region splits (extrapolation_growth)
    splits = region_split_errors(model, sample)
    N = np.asarray(sample.q_deg).shape[1]
    widths = np.ptp(np.asarray(sample.q_deg, float), axis=0)
    level, slope, reach = extrapolation_growth(splits, S_cv, factor, widths)
    # how the joints' sizes combine for a pose beyond several ranges, learned from the pair splits
    pairs = region_pair_errors(model, sample) if np.isfinite(level).sum() >= 2 else []
    norm_p = extrapolation_combination(pairs, S_cv, factor, (level, slope, reach))
    judged = [int(sum(s["judged"].size for s in splits if s["joint"] == j + 1)) for j in range(N)]
    live = [k for k in range(len(model.names_)) if sd[k] > 0]
    pred = {"parameters": [model.names_[k] for k in live],
            "covariance": cov_rep[np.ix_(live, live)].tolist(),
            "sigma_mm": pc["sigma_mm"], "dof": pc["dof"], "n_obs": pc["n_obs"],
            "unexplained_mm2": U.tolist(),
            "unexplained_rms_mm": float(np.sqrt(max(np.trace(U), 0.0))),
            "coverage_factor": factor,
            "n_cv": int(n),
            "extrapolation_widths": EXTRAPOLATION_WIDTHS,
            # how much each joint's angle error in the model varies over the sample poses (arcsec): beyond the
            # sampled range it is not known (extrapolation_covariance)
            "joint_angle_spread_arcsec": (joint_angle_spread(model, sample) * ARCSEC_PER_RAD).tolist(),
            # learned from the region splits: the size of the error beyond each joint's sampled range (None: too
            # few judged poses, the one-width guess instead)
            "extrapolation_split_quantile": SPLIT_QUANTILE,
            "extrapolation_judged_poses": judged,
            "extrapolation_ramp_deg": EXTRAPOLATION_RAMP_DEG,
            "extrapolation_mm": _json_rates(level),
            "extrapolation_mm_per_deg": _json_rates(slope),
            "extrapolation_reach_deg": _json_rates(reach),
            # the norm the joints' sizes combine by (2: quadrature; None: the largest alone), learned from the pairs
            "extrapolation_combination_p": _json_norm(norm_p),
            "extrapolation_pair_judged_poses": int(sum(np.sum(np.sum(s["beyond_deg"] > 0, axis=1) >= 2)
                                                       for s in pairs)),
            "method": ("u95_mm = coverage_factor x the 95 % radius of a 3-D Gaussian error whose covariance is the "
                       "parameters' covariance propagated to the pose + the unexplained scatter of the "
                       f"{n_folds}-fold cross-validation + beyond the sampled joint ranges an error growing with "
                       "the distance beyond them to the size the fit's own region splits show (each joint: refitted "
                       f"below its {SPLIT_QUANTILE:g} quantile, judged above, and the mirror; several joints' sizes "
                       "combined by the norm under which the pair splits' judged errors are held; docs/uncertainty.md); "
                       "coverage_factor: the 0.95 quantile of the cross-validated residuals over their own Gaussian "
                       "radius")}
    if cv_orientation is not None and "tool_ex" in model.names_:
        Jo = orientation_jacobian(model, sample, mv)
        at_o = prediction_covariance(Jo, cov_mv) * (n / max(train, 1.0))
        Uo = unexplained_covariance(cv_orientation, at_o)
        ro = np.linalg.norm(np.asarray(cv_orientation, float), axis=1)
        bo = radius95(at_o + Uo)
        pred["unexplained_orientation_mrad2"] = Uo.tolist()
        pred["unexplained_orientation_rms_arcsec"] = float(np.sqrt(max(np.trace(Uo), 0.0))) * ARCSEC_PER_MRAD_EXACT
        pred["orientation_coverage_factor"] = float(np.quantile(ro / np.where(bo > 0, bo, np.inf), P95)) if n else 1.0
        level_o, slope_o, reach_o = extrapolation_growth(splits, at_o + Uo, pred["orientation_coverage_factor"],
                                                         widths, "orientation_mrad")
        pred["extrapolation_combination_p_orientation"] = _json_norm(extrapolation_combination(
            pairs, at_o + Uo, pred["orientation_coverage_factor"], (level_o, slope_o, reach_o), "orientation_mrad"))
        pred["extrapolation_arcsec"] = _json_rates(level_o * ARCSEC_PER_MRAD_EXACT)
        pred["extrapolation_arcsec_per_deg"] = _json_rates(slope_o * ARCSEC_PER_MRAD_EXACT)
        pred["method_orientation"] = ("u95_arcsec: the same for the probe frame's orientation (its rows of the "
                                      "prediction Jacobian, the cross-validation's orientation errors, the joints' "
                                      "unknown angle errors beyond the sampled ranges turning the frame)")
    groups = [g["parameters"] for g in (model.identifiability_ or {}).get("redundant_groups", [])]
    Pen = np.asarray(getattr(model, "penalty_", np.zeros((0, len(model.names_)))), float)
    penalised = [nm for nm, on in zip(model.names_, np.abs(Pen).sum(axis=0) > 0) if on]
    return {"uncertainty": unc, "correlations": correlated_pairs(model.names_, cov_rep, groups=groups),
            "prediction": pred, "penalised": penalised}


def _json_rates(g) -> list:
    """Rates (N,) as JSON: a number each, None where not learned (NaN)."""
    return [float(v) if np.isfinite(v) else None for v in np.asarray(g, float)]


def _json_norm(p: float):
    """A combination's exponent as JSON: a number, None for the largest alone (``inf``)."""
    return None if np.isinf(p) else float(p)


def _norm(block: dict, key: str) -> float:
    """A fit JSON's combination exponent (:func:`_json_norm`): ``inf`` for None, 2 (quadrature) when absent."""
    if key not in block:
        return 2.0
    v = block[key]
    return np.inf if v is None else float(v)


def _rates(block: dict, key: str, scale: float = 1.0):
    """A fit JSON's rates (:func:`_json_rates`) as an array (N,) (NaN where None), or None when absent."""
    v = block.get(key)
    if not isinstance(v, list):
        return None
    return np.array([np.nan if x is None else float(x) for x in v], float) / scale


def _growth(block: dict, level_key: str, slope_key: str, scale: float = 1.0):
    """A fit JSON's learned error beyond the ranges as ``(level, slope, reach)`` arrays (N,), or None when absent."""
    level, slope = _rates(block, level_key, scale), _rates(block, slope_key, scale)
    reach = _rates(block, "extrapolation_reach_deg")
    if level is None or slope is None or reach is None or not level.shape == slope.shape == reach.shape:
        return None
    return level, slope, reach


def load_prediction(doc: dict, model):
    """The fit JSON's ``prediction_uncertainty`` as arrays for :func:`u95`, or None (a JSON written before it).

    Returns
    -------
    dict: ``covariance`` (p, p) internal units over ``model.names_``, ``unexplained`` (3, 3) mm^2,
    ``factor``.
    """
    block = doc.get("prediction_uncertainty") if isinstance(doc, dict) else None
    if not isinstance(block, dict):
        return None
    try:
        index = {nm: k for k, nm in enumerate(model.names_)}
        idx = np.array([index[nm] for nm in block["parameters"]], int)
        C = np.asarray(block["covariance"], float).reshape(idx.size, idx.size)
        f = np.array([model.units_[k][1] for k in idx], float)
        cov = np.zeros((len(model.names_), len(model.names_)))
        cov[np.ix_(idx, idx)] = C / np.outer(f, f)
        U = np.asarray(block["unexplained_mm2"], float).reshape(3, 3)
        factor = float(block["coverage_factor"])
        spread = np.asarray(block.get("joint_angle_spread_arcsec", np.zeros(0)), float) / ARCSEC_PER_RAD
        Uo = (np.asarray(block["unexplained_orientation_mrad2"], float).reshape(3, 3)
              if "unexplained_orientation_mrad2" in block else None)
        factor_o = float(block.get("orientation_coverage_factor", 1.0))
        growth = _growth(block, "extrapolation_mm", "extrapolation_mm_per_deg")
        growth_o = _growth(block, "extrapolation_arcsec", "extrapolation_arcsec_per_deg", ARCSEC_PER_MRAD_EXACT)
        norm_p, norm_p_o = _norm(block, "extrapolation_combination_p"), _norm(block, "extrapolation_combination_p_orientation")
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(U)) and np.isfinite(factor) and np.all(np.isfinite(spread))):
        return None
    out = {"covariance": cov, "unexplained": U, "factor": factor, "spread_rad": spread if spread.size else None,
           "growth": growth, "growth_orientation": growth_o, "norm_p": norm_p, "norm_p_orientation": norm_p_o}
    if Uo is not None and np.all(np.isfinite(Uo)) and np.isfinite(factor_o):
        out.update(unexplained_orientation=Uo, factor_orientation=factor_o)
    return out


def u95(model, data, stated: dict, sampled: dict) -> dict:
    """Each pose's 95 % radius (mm) and its parts, for a fitted model with its stated uncertainty.

    Parameters
    ----------
    model : RobotErrorModel
    data : RobotData, n poses
    stated : dict (:func:`load_prediction`)
    sampled : dict, the joint ranges the model was fitted on

    Returns
    -------
    dict of (n,) arrays, mm: ``u95_mm``, and the 1-sigma 3-D sizes sqrt(trace) of the parts
    ``parameters_mm``, ``unexplained_mm``, ``extrapolation_mm``.
    """
    mv = moving(stated["covariance"])
    cov_mv = np.asarray(stated["covariance"])[np.ix_(mv, mv)]
    Sp = prediction_covariance(model_jacobian(model, data, mv), cov_mv)
    Jq = joint_jacobian(model, data)
    Se = extrapolation_covariance(data.q_deg, sampled, Jq, stated["unexplained"], stated.get("spread_rad"),
                                  growth=stated.get("growth"), norm_p=stated.get("norm_p", 2.0))
    S = Sp + stated["unexplained"][None] + Se
    tr = lambda M: np.sqrt(np.clip(np.einsum("nkk->n", M), 0.0, None))  # noqa: E731
    out = {"u95_mm": stated["factor"] * radius95(S), "parameters_mm": tr(Sp),
           "unexplained_mm": np.full(data.n, float(np.sqrt(max(np.trace(stated["unexplained"]), 0.0)))),
           "extrapolation_mm": tr(Se)}
    if "unexplained_orientation" in stated and "tool_ex" in model.names_:
        So = prediction_covariance(orientation_jacobian(model, data, mv), cov_mv)
        So = So + stated["unexplained_orientation"][None] + extrapolation_covariance(
            data.q_deg, sampled, Jq, stated["unexplained"], stated.get("spread_rad"),
            Jturn=joint_jacobian(model, data, turn=True), growth=stated.get("growth_orientation"),
            norm_p=stated.get("norm_p_orientation", 2.0))
        out["u95_arcsec"] = stated["factor_orientation"] * radius95(So) * ARCSEC_PER_MRAD_EXACT
    return out


def coverage(error_mm, u95_mm) -> float:
    """Share of points whose error is within their ``u95_mm``."""
    e, u = np.asarray(error_mm, float), np.asarray(u95_mm, float)
    return float(np.mean(e <= u)) if e.size else float("nan")
