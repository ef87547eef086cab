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
3. beyond the joint ranges the model was fitted on (:func:`extrapolation_covariance`): a joint's angle
   error there is not determined by any measurement (a joint map fades to 0 at the edge: a guess), and is
   taken as unknown with a standard deviation that grows from 0 at the edge, one sampled width beyond it
   (:data:`EXTRAPOLATION_WIDTHS`), to the unexplained scatter of (2) expressed as that joint's angle (its
   lever arm to the SMR) together with the spread of the model's own angle error of that joint over its
   sample poses (:func:`joint_angle_spread`: what a joint map or backlash does inside the range), and
   stays there.

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
    from scipy import special  # chi2.ppf(p, nu) is 2 gammaincinv(nu / 2, p); scipy.stats costs 2 s to import

    lam = np.clip(np.linalg.eigvalsh(np.asarray(S, float)), 0.0, None)
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


def extrapolation_covariance(q_deg, sampled: dict, Jq, unexplained, spread_rad=None, Jturn=None) -> np.ndarray:
    """What a pose beyond the sampled joint ranges adds (3 x 3 per pose, mm^2; 0 inside them).

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
    """
    q = np.asarray(q_deg, float)
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    width = np.maximum(hi - lo, 1e-6)
    beyond = np.maximum(np.maximum(lo - q, q - hi), 0.0)
    grow = np.minimum(beyond / (EXTRAPOLATION_WIDTHS * width), 1.0)                 # (n, N)
    scale = float(np.sqrt(max(np.trace(np.asarray(unexplained, float)), 0.0) / 3.0))
    lever = np.linalg.norm(Jq, axis=1)                                               # (n, N) mm/rad
    spread = np.zeros(q.shape[1]) if spread_rad is None else np.asarray(spread_rad, float)
    sigma = grow * np.sqrt((scale / np.maximum(lever, 1e-9)) ** 2 + spread ** 2)     # rad
    cols = (Jq if Jturn is None else Jturn) * sigma[:, None, :]
    return np.einsum("nkj,nlj->nkl", cols, cols)


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
            "method": ("u95_mm = coverage_factor x the 95 % radius of a 3-D Gaussian error whose covariance is the "
                       "parameters' covariance propagated to the pose + the unexplained scatter of the "
                       f"{n_folds}-fold cross-validation + beyond the sampled joint ranges an unknown joint angle "
                       "error (docs/uncertainty.md); coverage_factor: the 0.95 quantile of the cross-validated "
                       "residuals over their own Gaussian radius")}
    if cv_orientation is not None and "tool_ex" in model.names_:
        Jo = orientation_jacobian(model, sample, mv)
        at_o = prediction_covariance(Jo, cov_mv) * (n / max(train, 1.0))
        Uo = unexplained_covariance(cv_orientation, at_o)
        ro = np.linalg.norm(np.asarray(cv_orientation, float), axis=1)
        bo = radius95(at_o + Uo)
        pred["unexplained_orientation_mrad2"] = Uo.tolist()
        pred["unexplained_orientation_rms_arcsec"] = float(np.sqrt(max(np.trace(Uo), 0.0))) * ARCSEC_PER_MRAD_EXACT
        pred["orientation_coverage_factor"] = float(np.quantile(ro / np.where(bo > 0, bo, np.inf), P95)) if n else 1.0
        pred["method_orientation"] = ("u95_arcsec: the same for the probe frame's orientation (its rows of the "
                                      "prediction Jacobian, the cross-validation's orientation errors, the joints' "
                                      "unknown angle errors beyond the sampled ranges turning the frame)")
    groups = [g["parameters"] for g in (model.identifiability_ or {}).get("redundant_groups", [])]
    Pen = np.asarray(getattr(model, "penalty_", np.zeros((0, len(model.names_)))), float)
    penalised = [nm for nm, on in zip(model.names_, np.abs(Pen).sum(axis=0) > 0) if on]
    return {"uncertainty": unc, "correlations": correlated_pairs(model.names_, cov_rep, groups=groups),
            "prediction": pred, "penalised": penalised}


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
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(U)) and np.isfinite(factor) and np.all(np.isfinite(spread))):
        return None
    out = {"covariance": cov, "unexplained": U, "factor": factor, "spread_rad": spread if spread.size else None}
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
    Se = extrapolation_covariance(data.q_deg, sampled, joint_jacobian(model, data), stated["unexplained"],
                                  stated.get("spread_rad"))
    S = Sp + stated["unexplained"][None] + Se
    tr = lambda M: np.sqrt(np.clip(np.einsum("nkk->n", M), 0.0, None))  # noqa: E731
    out = {"u95_mm": stated["factor"] * radius95(S), "parameters_mm": tr(Sp),
           "unexplained_mm": np.full(data.n, float(np.sqrt(max(np.trace(stated["unexplained"]), 0.0)))),
           "extrapolation_mm": tr(Se)}
    if "unexplained_orientation" in stated and "tool_ex" in model.names_:
        So = prediction_covariance(orientation_jacobian(model, data, mv), cov_mv)
        So = So + stated["unexplained_orientation"][None] + extrapolation_covariance(
            data.q_deg, sampled, joint_jacobian(model, data), stated["unexplained"], stated.get("spread_rad"),
            Jturn=joint_jacobian(model, data, turn=True))
        out["u95_arcsec"] = stated["factor_orientation"] * radius95(So) * ARCSEC_PER_MRAD_EXACT
    return out


def coverage(error_mm, u95_mm) -> float:
    """Share of points whose error is within their ``u95_mm``."""
    e, u = np.asarray(error_mm, float), np.asarray(u95_mm, float)
    return float(np.mean(e <= u)) if e.size else float("nan")
