"""Robot error models: one generic nonlinear least-squares fit over a sum of effects.

:class:`RobotErrorModel` is the estimator. Given effects (``pipeline.robot.arm.effects``) it
predicts the SMR position as the forward kinematics of the error model (``pipeline.robot``)
at ``Q0 + sum_p x_p basis_p`` and fits ``x`` to tracker positions by

* ``solver="gauss-newton"``: iterated least squares, Eq. 6 of the paper
  ``Delta X = (J^T J)^-1 J^T Delta P`` repeated at the updated parameters (MDH stage),
* ``solver="lm"``: the paper's improved Levenberg-Marquardt (:mod:`pipeline.robot.model.lm`),
* ``solver="scipy"``: ``scipy.optimize.least_squares`` (cross-check).

Identifiability: the Jacobian at the start is scaled to unit columns and decomposed
(SVD: rank, condition number; QR with column pivoting: which parameters to keep). With
``identifiability=True`` the parameters determined too weakly to hold away from the fitted poses
are fixed at 0 and reported by name (:data:`WEAK_TOL`). What the measurements cannot see at all
(combinations of parameters that move the measured point alike: with one SMR, the last joint's
frame and the tool offset) is not settled by fixing some of them: the fit is the one nearest the
nominal robot, every parameter counted in units of its typical size
(:meth:`pipeline.robot.arm.effects.RobotEffect.typical_sizes`, :func:`physical_subspace`); the fit's
``identifiability_["redundant_groups"]`` says, group by group, what was held and why
(docs/physical-redundancy.md).

The MDH calibration stage (:func:`calibrate_mdh`) is this estimator with the ``geometry``
effect on the ``sample`` poses.
"""

from __future__ import annotations

import re
import time

import numpy as np
import scipy.linalg

from . import lm  # the solvers as lm.improved_lm: looked up at call time (tests wrap them)
from .budget import model_over_budget
from ..arm.effects import REFERENCE_TEMPERATURE_C, Base, Geometry, RobotData, RobotEffect
from ..arm.kinematics import (Robot, batch_frames, build_error_model, placements, pose_jacobians, positions,
                               positions_and_jacobians)
from .lm import GAIN_REL_CONVERGED, implausible_parameters

RANK_TOL = 1e-7   # singular value / largest singular value of the column-scaled Jacobian (numerical rank)
#: A parameter is identified only when the poses determine it well enough for the model to hold on
#: poses the fit did not see. Its determination is the distance of its (unit) Jacobian column from
#: the span of the other identified parameters' columns, relative to the largest singular value: the
#: inverse of its standard error in these units, i.e. how well it is told apart from all the others
#: together. Parameters below WEAK_TOL are left at nominal one at a time, the least determined first,
#: until every one left is above (condition number of the identified set ~1 / WEAK_TOL or better).
#: Measured: on both real UR10 series the parameters fall into two groups, 3e-5..1.6e-4 (the rotation
#: of joint 6 and the wrist-5 twist/length, with an SMR 0.4 mm off joint 6's axis) and 5e-3 and above;
#: on a series in a small part of the workspace (ISO 9283 cubes) the tool length and the base sit at
#: 2.7e-4 of each other and, fitted, the tool took 8 mm and the model was 3x worse on another series;
#: the simulated KR210 campaign (100 poses, orientation within +-10 deg) has its least determined
#: parameter at 1.0e-3 and needs it. Condition numbers up to ~2,000 are kept.
WEAK_TOL = 5e-4
#: Relative singular value below which a fixed parameter is called redundant (an exact combination
#: of the kept ones) rather than weakly determined.
EXACT_TOL = 1e-9
#: A rotation parameter whose Jacobian column is shorter than this times the median rotation's (it
#: moves the measured point a hundred times less than a typical rotation: an axis the SMR sits on or
#: near, like the UR10's probe 0.4 mm off joint 6's axis) is not identified. Measured:
#: at 1e-3 the rotations about joint 6's axis still came out at 1e5 arcsec on the real series.
SHORT_LEVER = 1e-2
#: A 6-DoF campaign's position and orientation residuals are weighed by variance components: the weight
#: of the orientation rows (mm per mrad) is the ratio of the two components' RMS residuals (per axis)
#: of the fit, refitted until it changes by less than VCE_RTOL (at most VCE_MAX_ITER fits); it starts
#: from the stated uncertainties (sigma_mm / sigma_arcsec) when given, else from START_WEIGHT_MM_PER_MRAD.
VCE_RTOL = 0.01
VCE_MAX_ITER = 8
START_WEIGHT_MM_PER_MRAD = 1.0
ARCSEC_PER_MRAD = 206.264806


def rotation_vectors(R) -> np.ndarray:
    """Rotation vectors (rad) of rotation matrices, shape (n, 3, 3) -> (n, 3)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def orientation_errors(R_pred, R_meas) -> np.ndarray:
    """Orientation error of each pose: the rotation vector (mrad, base frame) of ``R_pred R_meas^T``,
    the turn that takes the measured probe frame onto the predicted one (predicted - measured, as
    positions are), shape (n, 3); its norm is the angle between the two frames."""
    return rotation_vectors(np.einsum("nij,nkj->nik", R_pred, R_meas)) * 1000.0


def angle_arcsec(e_mrad) -> np.ndarray:
    """Angle (arcsec) of orientation errors (n, 3) mrad."""
    return np.linalg.norm(np.asarray(e_mrad, float), axis=-1) * ARCSEC_PER_MRAD


#: Gauss-Newton has converged when a full step would change the residuals by ||dF||^2 <= GN_PHI (mm^2),
#: the improved L-M's phi (pipeline.robot.model.lm)
GN_PHI = 1e-5


#: A column-scaled normal-equations matrix whose reciprocal condition number (LAPACK's 1-norm estimate after
#: its Cholesky factor) is above this is solved by that factor: its eigenvalues then all lie far above the
#: 1e-12 of the largest below which an eigen-solution leaves a direction out, and both give the same step.
CHOLESKY_RCOND = 1e-7


def well_conditioned_cholesky(As):
    """The Cholesky factor of the symmetric matrix ``As`` (k, k) (as ``scipy.linalg.cho_factor`` gives it)
    where it is positive definite with a reciprocal condition number above :data:`CHOLESKY_RCOND`; else None
    (a rank-deficient or nearly singular matrix: solved in its eigen-directions)."""
    from scipy.linalg import lapack

    if As.shape[0] == 0 or not np.all(np.isfinite(As)):
        return None
    try:
        factor = scipy.linalg.cho_factor(As, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    rcond, info = lapack.dpocon(factor[0], float(np.abs(As).sum(axis=0).max()), uplo="L")
    return factor if info == 0 and rcond > CHOLESKY_RCOND else None


def _largest_eigenvalue(As) -> float:
    return float(scipy.linalg.eigh(As, eigvals_only=True, subset_by_index=[As.shape[0] - 1] * 2, check_finite=False)[0])


def scaled_min_norm_step(A, b, with_rank: bool = False) -> tuple:
    """The minimum-norm solution dz of the normal equations ``A dz = -b`` (A (k, k) symmetric positive
    semi-definite, b (k,)), solved column-scaled by its eigen-directions, those below 1e-12 of the largest
    left out (by its Cholesky factor where every direction is kept: :func:`well_conditioned_cholesky`); and
    the step's gain ``b^T A^+ b``, the change ``||dF||^2`` the linear model predicts (and, ``with_rank``, the
    number of directions kept)."""
    sc = np.sqrt(np.maximum(np.diag(A), 0.0))
    sc = np.where(sc > 0, sc, 1.0)
    As, bs = A / np.outer(sc, sc), b / sc
    factor = well_conditioned_cholesky(As)
    if factor is not None:
        y = scipy.linalg.cho_solve(factor, bs, check_finite=False)
        return (-y / sc, float(bs @ y), int(A.shape[0])) if with_rank else (-y / sc, float(bs @ y))
    ev, V = np.linalg.eigh(As)
    use = ev > 1e-12 * max(float(ev[-1]), 0.0) if ev.size else np.zeros(0, bool)
    t = V[:, use].T @ bs
    if with_rank:
        return -(V[:, use] @ (t / ev[use])) / sc, float(t @ (t / ev[use])), int(use.sum())
    return -(V[:, use] @ (t / ev[use])) / sc, float(t @ (t / ev[use]))


def vce_next(log_w: float, h: float, before) -> float:
    """The next weight of the variance components' iteration (mm per mrad).

    The plain step takes the ratio the fit at ``w`` gave: ``w exp(h)``, with ``h = log(w_new / w)``.
    It converges linearly (each step a fixed fraction of the one before), so from the second step on the
    root of ``h`` is sought by the secant through this iteration and ``before`` (its ``(log w, h)``):
    taken when it lies on the plain step's side and at most four times as far, else the plain step.
    Where it ends is decided by the same test (:data:`VCE_RTOL` on ``h``), not by the step."""
    plain = log_w + h
    if before is not None and h != before[1]:
        step = -h * (log_w - before[0]) / (h - before[1])
        if step * h > 0 and abs(step) <= 4.0 * abs(h):
            return float(np.exp(log_w + step))
    return float(np.exp(plain))


def start_weight(data) -> tuple[float, str]:
    """The first orientation weight (mm per mrad) of a 6-DoF fit and where it came from."""
    sp, so = getattr(data, "sigma_mm", None), getattr(data, "sigma_arcsec", None)
    if sp is not None and so is not None and np.isfinite(sp).any() and np.isfinite(so).any():
        a, b = float(np.nanmedian(sp)), float(np.nanmedian(so)) / ARCSEC_PER_MRAD
        if a > 0 and b > 0:
            return a / b, "the stated uncertainties (median sigma_mm / sigma_arcsec)"
    return START_WEIGHT_MM_PER_MRAD, f"{START_WEIGHT_MM_PER_MRAD:g} mm per mrad"


class Design:
    """The effects' channels on one data set (pure, built once per data set).

    Attributes
    ----------
    Q0 : ndarray, shape (n, nq)
        Error-model configuration with all parameters at 0 (joint angles in rad).
    names, units : parameter names and (unit, factor internal -> reported)
    sizes : ndarray, shape (p,), each parameter's typical size in internal units
        (:meth:`pipeline.robot.arm.effects.RobotEffect.typical_sizes`)
    """

    def __init__(self, robot: Robot, effects: list[RobotEffect], data: RobotData, model_and_index=None):
        self.robot = robot
        self.model, self.idx = model_and_index or build_error_model(robot)
        self.data = data
        n = data.n
        self.Q0 = np.zeros((n, self.idx.nq))
        self.Q0[:, self.idx.joints] = np.deg2rad(data.q_deg)
        names, units, sizes, p_idx, c_idx, rows, vals = [], [], [], [], [], [], []
        for e in effects:
            offset = len(names)
            names += e.parameter_names(robot)
            units += e.units(robot)
            sizes += list(e.typical_sizes(robot))
            for k, chans in enumerate(e.basis(robot, self.idx, data)):
                for c, v in chans:
                    p_idx.append(offset + k)
                    c_idx.append(int(c))
                    v = np.broadcast_to(np.asarray(v, float), (n,))
                    nz = np.flatnonzero(v)
                    rows.append(nz)
                    vals.append(v[nz])
        self.names = names
        self.units = units
        #: typical size of each parameter (internal units): the yardstick of "nearest the nominal robot"
        self.sizes = np.array([z / f for z, (_, f) in zip(sizes, units)], float)
        self.p = len(names)
        self.p_idx = np.asarray(p_idx, int)
        self.c_idx = np.asarray(c_idx, int)
        # each entry's channel values, kept without their zeros (a joint map's value moves only the poses
        # near its knot: 7 % of a 12,000-pose flexible model's (pose, entry) pairs): entry e's poses are
        # rows[ptr[e]:ptr[e + 1]] (increasing), its values vals[...] (issue 32: building them dense took
        # 0.4 s and 63 MB a design)
        self._ptr = np.concatenate([[0], np.cumsum([r.size for r in rows])]).astype(np.int64)
        self._rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        self._vals = np.concatenate(vals) if vals else np.zeros(0)
        self._ent = np.repeat(np.arange(len(rows)), np.diff(self._ptr))
        # the entries of each configuration channel and of each parameter, in entry order: sums over
        # them are taken in that order (as np.add.at did), never by a dense selection matrix
        self._by_channel = _groups(self.c_idx)
        self._by_param = _groups(self.p_idx)
        # each channel's nonzeros in entry order (a pose's terms are summed in entry order, from 0)
        self._channel_nz = []
        for c, entries in self._by_channel:
            at = np.concatenate([np.arange(self._ptr[e], self._ptr[e + 1]) for e in entries])
            self._channel_nz.append((c, self._rows[at], self._vals[at], self._ent[at]))
        self._nonzero = None
        self._coo = self._coo6 = None
        # the last residual-and-Jacobian evaluation, (key, result), on a design an estimator keeps for more than
        # one fit (``keep_last``): a fit's last iteration is at its solution, where the variance components'
        # linearisation and the wild search's steps evaluate again
        self._last = None
        self.keep_last = False

    def _once(self, kind: str, x, compute):
        """``compute()``, or what it gave for the same ``kind``, parameters x and weight last time (the one
        evaluation kept). Callers do not write into the arrays returned."""
        if not self.keep_last:
            return compute()
        key = (kind, float(self.weight or 0.0), np.asarray(x, float).tobytes())
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        out = compute()
        self._last = (key, out)
        return out

    def _column(self, e: int) -> np.ndarray:
        """Entry ``e``'s channel values at every pose (n,), zeros included."""
        v = np.zeros(self.data.n)
        a, b = self._ptr[e], self._ptr[e + 1]
        v[self._rows[a:b]] = self._vals[a:b]
        return v

    def _pose_major(self):
        """The nonzero (pose, entry) pairs, pose-major and entries increasing within a pose, and their values."""
        if self._nonzero is None:
            # the entries are stored entry by entry, poses increasing: a stable sort by pose keeps the
            # entries increasing within a pose (radix on small pose numbers)
            rows = self._rows.astype(np.int16) if self.data.n < 2 ** 15 else self._rows
            order = np.argsort(rows, kind="stable")
            self._nonzero = (self._rows[order], self._ent[order], self._vals[order])
        return self._nonzero

    def configurations(self, x) -> np.ndarray:
        """Error-model configurations (n, nq) at the parameters ``x`` (p,), internal units."""
        xe = np.asarray(x, float)[self.p_idx]
        n = self.Q0.shape[0]
        dQ = np.zeros((self.Q0.shape[1], n))
        for c, rows, vals, ent in self._channel_nz:
            # sequential sums (bincount adds in input order): each pose's terms in entry order, as before
            dQ[c] = np.bincount(rows, weights=vals * xe[ent], minlength=n)
        return self.Q0 + dQ.T

    #: weight of the orientation rows of the residual (mm per mrad), None: positions only
    weight = None

    @property
    def oriented(self) -> bool:
        """Whether the residual has orientation rows (a 6-DoF campaign fitted on its orientations)."""
        return self.weight is not None and getattr(self.data, "measured_R", None) is not None

    def predict(self, x) -> np.ndarray:
        """SMR positions (n, 3) mm."""
        return positions(self.model, self.configurations(x))

    def predict_pose(self, x):
        """Probe frames: rotations (n, 3, 3) and positions (n, 3) mm."""
        return placements(self.model, self.configurations(x), "smr")

    def predict_and_jacobian(self, x, columns=None):
        """Positions (n, 3) mm and Jacobian (n, 3, p) mm per internal unit (``columns``: only those
        parameters', :meth:`parameter_jacobian`)."""
        P, Jext = positions_and_jacobians(self.model, self.configurations(x))
        return P, self.parameter_jacobian(Jext, columns)

    def parameter_jacobian(self, Jext, columns=None) -> np.ndarray:
        """The parameters' Jacobian (n, m, p) from the configuration channels' (n, m, nq) (any rows m:
        position mm, or position and orientation), each parameter's entries summed in order.

        ``columns`` (p,) bool: only those parameters' columns, (n, m, k), the same values (a 6-DoF
        baseline's fixed parameters are a third of its 863: 100 MB of 43,000 rows, issue 32)."""
        Jext = np.asarray(Jext, float)
        where = np.arange(self.p) if columns is None else np.cumsum(columns) - 1
        keep = np.ones(self.p, bool) if columns is None else np.asarray(columns, bool)
        J = np.zeros((Jext.shape[0], Jext.shape[1], int(keep.sum())))
        for k, entries in self._by_param:
            if not keep[k]:
                continue
            col = Jext[:, :, self.c_idx[entries[0]]] * self._column(entries[0])[:, None]
            for e in entries[1:]:
                col = col + Jext[:, :, self.c_idx[e]] * self._column(e)[:, None]
            J[:, :, where[k]] = col
        return J

    def predict_and_sparse_jacobian(self, x):
        """Positions (n, 3) mm and the Jacobian as a sparse matrix (3 n, p) (CSC; rows x, y, z of each
        pose), mm per internal unit: what :meth:`predict_and_jacobian` gives, without its zeros (a joint
        map's value moves only the poses near its knot). By column: what the normal equations read."""
        P, Jext = positions_and_jacobians(self.model, self.configurations(x))
        ii, ee, vv = self._pose_major()           # (pose, entry), pose-major
        vals = Jext[ii, :, self.c_idx[ee]] * vv[:, None]          # (nnz, 3)
        if self._coo is None:
            self._coo = _pose_csc_structure(ii, self.p_idx[ee], self.data.n, self.p)
        return P, _pose_csc(vals, self._coo)

    def pose_and_jacobian(self, x, columns=None):
        """Rotations (n, 3, 3), positions (n, 3) mm and Jacobian (n, 6, p): rows x, y, z in mm and the
        probe frame's turn about x, y, z (base frame) in mrad, per internal unit (``columns``: only those
        parameters', :meth:`parameter_jacobian`)."""
        R, P, Jext = pose_jacobians(self.model, self.configurations(x), "smr")
        Jext[:, 3:] *= 1000.0
        return R, P, self.parameter_jacobian(Jext, columns)

    def residual_and_sparse_jacobian(self, x):
        """A 6-DoF design's positions (n, 3) mm, :meth:`residual` and its Jacobian as a sparse matrix
        (6 n, p) (CSC; rows as the residual's: every pose's x, y, z, then every pose's weighted turn)."""
        return self._once("sparse6", x, lambda: self._residual_and_sparse_jacobian(x))

    def _residual_and_sparse_jacobian(self, x):
        R, P, Jext = pose_jacobians(self.model, self.configurations(x), "smr")
        Jext[:, 3:] *= 1000.0 * self.weight
        ii, ee, vv = self._pose_major()
        n = self.data.n
        vals = Jext[ii, :, self.c_idx[ee]] * vv[:, None]          # (nnz, 6)
        data = np.concatenate([vals[:, :3].ravel(), vals[:, 3:].ravel()])
        del vals
        if self._coo6 is None:
            # the entries' rows and columns are the same at every x: the layout is built once
            self._coo6 = _pose6_csc_structure(ii, self.p_idx[ee], n, self.p)
        J = _csc(data, self._coo6)
        F = np.concatenate([(P - self.data.measured_mm).ravel(),
                            self.weight * orientation_errors(R, self.data.measured_R).ravel()])
        return P, F, J

    def residual(self, x) -> np.ndarray:
        """Residual vector of the fit (predicted - measured): the positions (3 n, mm) and, for a 6-DoF
        fit, the orientation errors times :attr:`weight` (3 n, mm-equivalent)."""
        if not self.oriented:
            return (self.predict(x) - self.data.measured_mm).ravel()
        R, P = self.predict_pose(x)
        return np.concatenate([(P - self.data.measured_mm).ravel(),
                               self.weight * orientation_errors(R, self.data.measured_R).ravel()])

    def residual_and_jacobian(self, x):
        """:meth:`residual` and its Jacobian (rows as the residual's, p columns)."""
        return self._once("dense", x, lambda: self._residual_and_jacobian(x))

    def _residual_and_jacobian(self, x):
        if not self.oriented:
            P, J = self.predict_and_jacobian(x)
            return (P - self.data.measured_mm).ravel(), J.reshape(-1, self.p)
        R, P, J = self.pose_and_jacobian(x)
        F = np.concatenate([(P - self.data.measured_mm).ravel(),
                            self.weight * orientation_errors(R, self.data.measured_R).ravel()])
        return F, np.vstack([J[:, :3].reshape(-1, self.p), self.weight * J[:, 3:].reshape(-1, self.p)])

    def jacobian_rows(self, x):
        """The identification Jacobian (rows of :meth:`residual`), with the nominal positions (n, 3) mm."""
        if not self.oriented:
            P, J = self.predict_and_jacobian(x)
            return P, J.reshape(-1, self.p)
        _, P, J = self.pose_and_jacobian(x)
        return P, np.vstack([J[:, :3].reshape(-1, self.p), self.weight * J[:, 3:].reshape(-1, self.p)])



def _by_column(keys, cols, p):
    """Entries (``keys``, ``cols``) sorted by column, keys increasing within a column: the order, where each
    run of one (key, column) starts, the sorted keys and columns (issue 32: a stable sort, radix on small
    column numbers, when the keys already increase in entry order)."""
    keys, cols = np.asarray(keys, np.int64), np.asarray(cols, np.int64)
    order = np.argsort(cols.astype(np.int16) if p < 2 ** 15 else cols, kind="stable")
    k, c = keys[order], cols[order]
    if np.any((k[1:] < k[:-1]) & (c[1:] == c[:-1])):
        order = np.lexsort((keys, cols))
        k, c = keys[order], cols[order]
    new = np.ones(k.size, bool)
    new[1:] = (k[1:] != k[:-1]) | (c[1:] != c[:-1])
    return order, np.flatnonzero(new), k, c


def _csc_structure(rows, cols, m, p):
    """The CSC layout of a sparse matrix (m, p) whose entries (``rows``, ``cols``) keep their places from call
    to call (a design's Jacobian): the order taking the entries to it, where each stored value starts
    (None: no duplicates; duplicates are summed), its row indices and column pointers (built once, not by
    a COO conversion each iteration)."""
    order, start, r, c = _by_column(rows, cols, p)
    indptr = np.searchsorted(c[start], np.arange(p + 1)).astype(np.int64)
    return order, (start if start.size < r.size else None), r[start].astype(np.int32), indptr, (m, p)


def _pose_csc_structure(ii, cols, n, p):
    """The CSC layout of a positions' Jacobian (3 n, p) whose nonzeros t (pose ``ii[t]``, column ``cols[t]``,
    pose-major) each fill the rows 3 ii + 0, 1, 2: the order taking the nonzeros to it (by column, poses
    increasing), where each run of nonzeros of one (pose, column) starts (None: no run longer than one),
    row indices and column pointers. Sorted as nonzeros, not as rows (a third of the work)."""
    order, first, i, c = _by_column(ii, cols, p)
    rows = (3 * i[first][:, None] + np.arange(3)).ravel().astype(np.int32)
    indptr = 3 * np.searchsorted(c[first], np.arange(p + 1)).astype(np.int64)
    return order, (first if first.size < i.size else None), rows, indptr, (3 * n, p)


def _pose6_csc_structure(ii, cols, n, p):
    """The :func:`_csc_structure` of a 6-DoF Jacobian (6 n, p) whose nonzeros t (pose ``ii[t]``, column
    ``cols[t]``, pose-major) each fill the rows 3 ii + 0, 1, 2 (positions) and 3 n + 3 ii + 0, 1, 2 (turns),
    the values laid out as ``[vals[:, :3].ravel(), vals[:, 3:].ravel()]``: the same layout, sorted as
    nonzeros rather than as its six times as many entries (issue 32: 0.4 s a design on 7,000 poses), also
    where a (pose, column) has several nonzeros (a run, summed: the loop's designs, 0.27 s each the general
    way)."""
    ii, cols = np.asarray(ii, np.int64), np.asarray(cols, np.int64)
    order, first, i, c = _by_column(ii, cols, p)
    nnz = ii.size
    ptr = np.searchsorted(c, np.arange(p + 1)).astype(np.int64)      # each column's nonzeros, sorted
    m = np.diff(ptr)[c]                                               # its column's count, per sorted nonzero
    # a run of L nonzeros of one (pose, column) (a joint map's and a compliance's on one joint, ...): its
    # entries of one row side by side, in their order (as the general layout sorts them, stably), summed
    starts = np.zeros(nnz, bool)
    starts[first] = True
    run = np.cumsum(starts) - 1                                       # each sorted nonzero's run
    length = np.diff(np.append(first, nnz))[run]
    lo = first[run] - ptr[c]                                          # the run's first nonzero in its column
    j = np.arange(nnz) - first[run]                                   # and this nonzero's place in the run
    a = np.arange(3)
    pos = ((6 * ptr[c] + 3 * lo + j)[:, None] + a * length[:, None]).ravel()   # where its position rows go
    turn = pos + 3 * np.repeat(m, 3)                                # and its turns', after the column's positions
    src = (3 * order[:, None] + a).ravel()                          # its position values in the layout
    row = (3 * i[:, None] + a).ravel()
    perm = np.empty(6 * nnz, np.int64)
    rows = np.empty(6 * nnz, np.int32)
    perm[pos], perm[turn] = src, 3 * nnz + src
    rows[pos], rows[turn] = row, 3 * n + row
    if first.size == nnz:
        return perm, None, rows, 6 * ptr, (6 * n, p)
    f = first
    uptr = np.searchsorted(c[f], np.arange(p + 1)).astype(np.int64)  # each column's runs
    # where each run's stored values start, in the layout's order: a column's runs' position rows (run by
    # run, x y z), then the same runs' turns; placed there directly (a sort of them took 0.23 s on 7,000 poses)
    pos_start = ((6 * ptr[c[f]] + 3 * lo[f])[:, None] + a * length[f][:, None]).ravel()
    at = (3 * uptr[c[f]] + 3 * np.arange(f.size))[:, None] + a
    start = np.empty(2 * pos_start.size, np.int64)
    start[at.ravel()] = pos_start
    start[(at + 3 * (uptr[c[f] + 1] - uptr[c[f]])[:, None]).ravel()] = pos_start + 3 * np.repeat(m[f], 3)
    return perm, start, rows[start], 6 * uptr, (6 * n, p)


def _pose_csc(vals, structure):
    """The sparse matrix (CSC) of the nonzeros' values ``vals`` (nnz, 3) on a :func:`_pose_csc_structure`
    (a run of one (pose, column) summed in order)."""
    import scipy.sparse

    order, first, rows, indptr, shape = structure
    v = vals[order]
    if first is not None:
        v = np.add.reduceat(v, first, axis=0)
    return scipy.sparse.csc_matrix((v.ravel(), rows, indptr), shape=shape)


def _csc(values, structure):
    """The sparse matrix (CSC) of ``values`` (in the entries' order) on a :func:`_csc_structure`."""
    import scipy.sparse

    order, start, indices, indptr, shape = structure
    data = values[order]
    if start is not None:
        data = np.add.reduceat(data, start)
    return scipy.sparse.csc_matrix((data, indices, indptr), shape=shape)


def _groups(index) -> list[tuple[int, np.ndarray]]:
    """(value, the positions holding it in order) for each distinct value of an int array."""
    index = np.asarray(index, int)
    order = np.argsort(index, kind="stable")
    vals, starts = np.unique(index[order], return_index=True)
    return [(int(v), order[a:b]) for v, a, b in zip(vals, starts, list(starts[1:]) + [index.size])]


#: A fit with more directions to solve for than this (a joint map's grid values) is solved on its
#: normal equations, built from the sparse Jacobian (:func:`gram`), and its unseen directions found
#: from them (:func:`physical_subspace` with ``gram``): the dense SVD of a (3 n) x k Jacobian each
#: iteration cost 45 of predict's 47 s on 11,911 poses (issue 32). Smaller fits (geometry, base, tool,
#: compliance, backlash: at most a few dozen directions) keep the dense SVD.
GRAM_MIN_K = 64
#: A fit in the leading singular directions (``reduction="svd"``) whose Jacobian has more entries than this
#: (64 MB) is iterated on its normal equations too: a Chebyshev swap on 7,144 6-DoF poses took 37 s and 2 GB
#: in dense SVDs (issue 32). Smaller ones (the paper's KR210 stage) keep the dense SVD.
DENSE_SVD_MAX = 8_000_000


def scaled_svd(J, norms, zero=None) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (k,) and right singular vectors Vt (k, p) of J (m, p; dense or sparse) with its columns
    divided by ``norms`` (p,) and the ``zero`` (p,) ones set to 0, without the left ones (m, k): the SVD of the
    triangular factor R of a QR (blocked LAPACK), the U of a 6-DoF campaign's 43,000 x 800 J being another
    275 MB (issue 32).

    R is built from row blocks of at most :data:`DENSE_SVD_MAX` entries: each block's rows below the R so
    far are factored together (a tall-skinny QR), so no copy of the whole J is made. A J of one block (every
    fixture) is factored in one QR, as before."""
    from scipy.linalg.lapack import dgeqrf

    m, p = J.shape
    rows = max(p, DENSE_SVD_MAX // max(p, 1))
    if hasattr(J, "tocsr"):
        J = J.tocsr()
    R = np.zeros((0, p))
    for a in range(0, max(m, 1), rows):
        blk = J[a:a + rows]
        blk = blk.toarray() if hasattr(blk, "toarray") else np.asarray(blk, float)
        A = np.empty((R.shape[0] + blk.shape[0], p), order="F")
        A[:R.shape[0]] = R
        np.divide(blk, norms, out=A[R.shape[0]:])
        if zero is not None:
            A[:, zero] = 0.0
        qr, _, _, _ = dgeqrf(A, lwork=max(1, 64 * p), overwrite_a=1)   # with a work size: blocked (3x faster)
        R = np.triu(qr[:min(A.shape[0], p)])
        del A, qr, blk
    _, sv, Vt = np.linalg.svd(R, full_matrices=False)
    return sv, Vt


def gram(J, r=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``J^T J`` (p, p) and ``J^T r`` (p,) of a sparse Jacobian (3 n, p), its dense columns (the
    kinematic parameters: every pose) by BLAS and its sparse ones (joint-map values) sparse."""
    import scipy.sparse

    J = scipy.sparse.csc_matrix(J)
    nnz = np.diff(J.indptr)
    dense = nnz > 0.25 * J.shape[0]
    di, si = np.flatnonzero(dense), np.flatnonzero(~dense)
    H = np.zeros((J.shape[1], J.shape[1]))
    Jd = J[:, di].toarray()
    Js = J[:, si]
    H[np.ix_(di, di)] = Jd.T @ Jd
    if si.size:
        cross = np.asarray((Js.T @ Jd))
        H[np.ix_(si, di)] = cross
        H[np.ix_(di, si)] = cross.T
        H[np.ix_(si, si)] = (Js.T @ Js).toarray()
    g = None if r is None else np.asarray(J.T @ np.asarray(r, float)).ravel()
    return H, g


def identifiability(J: np.ndarray, names: list[str], tol: float = RANK_TOL, priority=None,
                    weak_tol: float | None = None, units=None, penalised=None) -> dict:
    """Rank, condition number and identifiable parameters of a Jacobian.

    Parameters
    ----------
    J : ndarray, shape (N, p)
        Jacobian of the residuals (mm per internal unit).
    names : list of str, length p
    priority : sequence of int, optional
        Order in which parameters are preferred when some must be fixed (greedy: a
        parameter is kept when it raises the rank of those kept before it). Default:
        QR with column pivoting.

    Returns
    -------
    dict with ``rank``, ``n_params``, ``condition_number`` (of the scaled Jacobian restricted
    to the identifiable parameters), ``condition_number_all``, ``singular_values`` (scaled),
    ``keep`` (bool mask) and ``not_identifiable`` (names fixed at 0).
    """
    sparse = hasattr(J, "tocsc")          # a scipy.sparse Jacobian (Design.predict_and_sparse_jacobian)
    if penalised is not None and np.any(penalised):
        # parameters kept smooth and unique by their effect's penalty (a joint map's hundreds of
        # grid values) are not ranked here; only the rotations the SMR barely feels are left out
        pen = np.asarray(penalised, bool)
        Jr = J.tocsc()[:, np.flatnonzero(~pen)].toarray() if sparse else J[:, ~pen]
        rest = identifiability(Jr, [n for n, q in zip(names, pen) if not q], tol,
                               None if priority is None else [int(np.sum(~pen[:c])) for c in priority if not pen[c]],
                               weak_tol, None if units is None else [u for u, q in zip(units, pen) if not q])
        norms = (np.sqrt(np.asarray(J.multiply(J).sum(axis=0)).ravel()) if sparse else np.linalg.norm(J, axis=0))
        angle = np.array([u[0] == "arcsec" for u in units], bool) if units is not None else np.zeros(len(names), bool)
        ref = norms[angle & ~pen & (norms > 0)]
        short = pen & (norms < SHORT_LEVER * (np.median(ref) if ref.size else norms.max(initial=0.0)))
        keep = np.zeros(J.shape[1], bool)
        keep[~pen] = rest["keep"]
        keep[pen] = ~short[pen]
        zero = np.zeros(J.shape[1], bool)
        zero[~pen] = rest["zero"]
        zero |= short
        reasons = dict(rest["fixed_reasons"])
        for c in np.flatnonzero(short):
            reasons[names[c]] = {"relative_determination": 0.0,
                                 "reason": "moves the measured point less than 1/100 as much as a typical parameter "
                                           "(an axis the SMR sits on or near): not identifiable"}
        return {**rest, "n_params": int(J.shape[1]), "keep": keep, "zero": zero, "fixed_reasons": reasons,
                "not_identifiable": [n for n, k in zip(names, keep) if not k], "penalised": int(pen.sum())}
    if sparse:
        J = J.toarray()
    norms = np.linalg.norm(J, axis=0)
    zero = norms <= 1e-12 * max(norms.max(initial=0.0), 1e-300)
    # a parameter that moves the measured point a hundred times less than a typical one (a rotation
    # about an axis the SMR sits on, 0.4 mm off it) is not identified: scaled to unit norm, its column
    # would turn rounding and noise into coefficients of 1e6 arcsec (SHORT_LEVER)
    angle = np.array([u[0] == "arcsec" for u in units], bool) if units is not None else np.zeros(len(names), bool)
    short = np.zeros_like(zero)
    if (angle & ~zero).any():   # rotations: compared with the other rotations (mm of motion per mrad)
        short = angle & ~zero & (norms < SHORT_LEVER * np.median(norms[angle & ~zero]))
    zero = zero | short
    Js = J / np.where(zero, 1.0, norms)
    Js[:, zero] = 0.0
    if Js.shape[0] > Js.shape[1]:
        # J = Q R with orthonormal Q: every column subset of R has the singular values of the
        # same subset of J, so the rank tests below cost O(p^3) whatever the number of poses
        Js = np.linalg.qr(Js, mode="r")
    s = np.linalg.svd(Js, compute_uv=False)
    rank = int(np.sum(s > tol * s[0])) if s.size else 0
    keep = np.zeros(J.shape[1], bool)
    if priority is None:
        _, _, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
        keep[piv[:rank]] = True
    else:
        kept = []
        for c in priority:
            if zero[c]:
                continue
            trial = Js[:, kept + [c]]
            sv = np.linalg.svd(trial, compute_uv=False)
            if sv[-1] > tol * s[0]:
                kept.append(c)
            if len(kept) == rank:
                break
        keep[kept] = True
    keep &= ~zero
    reasons = {}
    for c in np.flatnonzero(~keep):
        reasons[names[c]] = {"relative_determination": 0.0,
                             "reason": ("moves the measured point less than 1/100 as much as a typical parameter "
                                        "(an axis the SMR sits on or near): not identifiable" if short[c] else
                                        "does not move the measured point at these poses" if zero[c] else
                                        "redundant: a combination of the identified parameters (numerical rank)")}
    s0 = float(s[0]) if s.size else 0.0
    if weak_tol is not None and s0 > 0:
        rank_of = {c: k for k, c in enumerate(priority)} if priority is not None else {}
        while keep.sum() > 1:
            idx = np.flatnonzero(keep)
            A = Js[:, idx]
            try:
                det = 1.0 / np.sqrt(np.diag(np.linalg.inv(A.T @ A))) / s0   # distance from the others' span
            except np.linalg.LinAlgError:
                break
            low = np.flatnonzero(det < weak_tol)
            if not low.size:
                break
            # the least determined first; among (nearly) equal ones, the one of lowest priority
            k = max(low, key=lambda m: (-round(float(np.log10(max(det[m], 1e-300))), 1), rank_of.get(idx[m], idx[m])))
            c = int(idx[k])
            keep[c] = False
            reasons[names[c]] = {"relative_determination": float(det[k]),
                                 "reason": (f"weakly determined: {det[k]:.1e} of the best-determined direction (limit "
                                            f"{weak_tol:g}); fitted, it would trade with the identified parameters and "
                                            "not hold on poses away from these")}
    sk = np.linalg.svd(Js[:, keep], compute_uv=False) if keep.any() else np.array([1.0])
    return {"rank": rank, "n_params": int(J.shape[1]),
            "condition_number": float(sk[0] / sk[-1]),
            # rank-deficient: the smallest singular value is rounding noise, and so would be the ratio
            # (1e17 on one CPU, 3e18 on another): infinite, written as null
            "condition_number_all": float(s[0] / s[-1]) if s.size and s[-1] > tol * s[0] else float("inf"),
            "singular_values": s.tolist(), "keep": keep, "rank_tol": tol, "weak_tol": weak_tol,
            "not_identifiable": [n for n, k in zip(names, keep) if not k],
            "fixed_reasons": reasons, "zero": zero}


def frame_deviations(model, idx, Q, Q0) -> list[dict]:
    """How far the model's frames move and turn from the nominal robot's over the sampled poses, as
    ``{name, value, unit}`` for the plausibility bounds (:data:`pipeline.robot.model.lm.PLAUSIBLE_BOUNDS`).

    Per frame, the largest over the poses of the shift (mm) and the turn (arcsec) of its placement
    relative to the frame before it (the base relative to the world; joint i's link frame relative
    to joint i-1's, joint angle errors included; the SMR relative to the flange), and of the flange
    and the SMR in the base frame (everything before them together). Exact (pinocchio), every effect
    of the model included: what a real robot's frames do, whatever parameters carry it.

    Parameters
    ----------
    model : pin.Model, the error model (:func:`pipeline.robot.arm.kinematics.build_error_model`)
    Q, Q0 : ndarray, shape (n, nq)
        Error-model configurations with the fitted parameters and with none (nominal).
    """
    import pinocchio as pin

    N = idx.joints.size
    names = [f"link{i}" for i in range(1, N + 1)] + ["smr"]
    fids = [model.getFrameId(nm) for nm in names]
    base_joint = int(idx.base[-1]) + 1                      # the last base error joint (pinocchio joint id)
    data = model.createData()

    def frames(Qs):
        """Rotations (n, N + 2, 3, 3) and positions (n, N + 2, 3) m: base, link frames 1..N, SMR."""
        got = batch_frames(model, Qs, names, (base_joint,))
        if got is not None:
            M = [got[base_joint]] + [got[nm] for nm in names]
            return np.stack([m[0] for m in M], axis=1), np.stack([m[1] for m in M], axis=1)
        R = np.empty((len(Qs), N + 2, 3, 3))
        p = np.empty((len(Qs), N + 2, 3))
        for k, q in enumerate(np.asarray(Qs, float)):
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacements(model, data)
            M = [data.oMi[base_joint]] + [data.oMf[f] for f in fids]
            R[k] = [m.rotation for m in M]
            p[k] = [m.translation for m in M]
        return R, p

    def relative(R, p):
        """Each frame relative to the one before it (the base relative to the world)."""
        Rr, pr = R.copy(), p.copy()
        Rr[:, 1:] = np.einsum("nfji,nfjk->nfik", R[:, :-1], R[:, 1:])
        pr[:, 1:] = np.einsum("nfji,nfj->nfi", R[:, :-1], p[:, 1:] - p[:, :-1])
        return Rr, pr

    def angle(Ra, Rb):
        """Rotation angle (rad) of Ra^T Rb, batched."""
        c = (np.einsum("...ji,...ji->...", Ra, Rb) - 1.0) / 2.0
        return np.arccos(np.clip(c, -1.0, 1.0))

    R1, p1 = frames(Q)
    R0, p0 = frames(Q0)
    Rr1, pr1 = relative(R1, p1)
    Rr0, pr0 = relative(R0, p0)
    # E = rel0^-1 rel: shift rel0.R^T (rel.p - rel0.p), turn angle(rel0.R, rel.R)
    shift = np.linalg.norm(np.einsum("nfji,nfj->nfi", Rr0, pr1 - pr0), axis=2).max(axis=0) * 1000.0
    turn = angle(Rr0, Rr1).max(axis=0)
    flange_turn = float(angle(R0[:, N], R1[:, N]).max())
    smr_shift = float(np.linalg.norm(p1[:, -1] - p0[:, -1], axis=1).max()) * 1000.0
    n_frames = N + 2
    arcsec = 180.0 / np.pi * 3600.0
    label = ["the base frame"] + [f"joint {i}'s link frame" for i in range(1, N + 1)] + ["the SMR on the flange"]
    out = []
    for k in range(n_frames):
        out.append({"name": f"{label[k]}: shift from nominal (largest over the sampled poses)",
                    "value": shift[k], "unit": "mm"})
        if k < n_frames - 1:
            out.append({"name": f"{label[k]}: turn from nominal (largest over the sampled poses)",
                        "value": turn[k] * arcsec, "unit": "arcsec"})
    out.append({"name": "the flange: turn from nominal in the base frame (largest over the sampled poses)",
                "value": flange_turn * arcsec, "unit": "arcsec"})
    out.append({"name": "the SMR: distance from its nominal position (largest over the sampled poses)",
                "value": smr_shift, "unit": "mm"})
    return out


def physical_subspace(A: np.ndarray | None, B0: np.ndarray, free, sizes, tol: float = RANK_TOL, gram=None):
    """What the measurements determine, represented nearest the nominal robot (contract section 8).

    The fit moves the parameters ``x`` in the span of ``B0`` (the parameters kept, or the leading
    singular directions): that span decides the predictions. Among the parameters ``free`` to move,
    the directions ``n`` with ``A n = 0`` (relative singular value of the column-scaled ``A`` below
    ``tol``) change no prediction: the measurements cannot see them (with one SMR, the last joint's
    frame against the tool offset; a 7-joint arm's redundant axes). Every parameter is counted in
    units of its typical size (``u = x / sizes``); the span of ``B0`` is replaced by its projection
    orthogonal (in ``u``) to those directions. ``A B`` spans what ``A B0`` spans (the same
    predictions, to first order), and the least-squares solution in it is the one nearest the
    nominal robot: the smallest ``||x / sizes||`` of all the solutions that predict alike.

    Parameters
    ----------
    A : ndarray, shape (m, p)
        Jacobian of the residuals (with any penalty rows) at the nominal parameters.
    B0 : ndarray, shape (p, k)
        The fitted directions (columns), zero outside ``free``.
    free : ndarray of bool, shape (p,)
        Parameters that may move (not fixed at nominal).
    sizes : ndarray, shape (p,)
        Typical size of each parameter (internal units).
    gram : ndarray, shape (p, p), optional
        ``A^T A`` in place of ``A`` (``A`` may then be None): the singular values and right singular
        vectors are those of its eigen-decomposition (a relative singular value resolves down to
        about 1e-8, below ``tol``'s 1e-7; what the measurements cannot see at all comes out near 1e-8
        or below), for fits of hundreds of parameters on thousands of poses (:data:`GRAM_MIN_K`).

    Returns
    -------
    B : ndarray, shape (p, k)
        The directions to fit in (``x = B z``): each column of ``B0`` without its part along the unseen
        directions (in ``u``).
    U : ndarray, shape (p, r)
        The directions the measurements cannot see (``u`` coordinates, orthonormal; 0 outside ``free``).
    """
    p = B0.shape[0]
    cols = np.flatnonzero(free)
    U = np.zeros((p, 0))
    if cols.size and gram is not None:
        G = gram[np.ix_(cols, cols)] * np.outer(sizes[cols], sizes[cols])
        nrm = np.sqrt(np.maximum(np.diag(G), 0.0))
        nrm = np.where(nrm > 0, nrm, 1.0)
        w, V = np.linalg.eigh(G / np.outer(nrm, nrm))
        sv, Vt = np.sqrt(np.maximum(w[::-1], 0.0)), V[:, ::-1].T
    elif cols.size:
        Af = A[:, cols] * sizes[cols]
        nrm = np.linalg.norm(Af, axis=0)
        nrm = np.where(nrm > 0, nrm, 1.0)
        R = np.linalg.qr(Af / nrm, mode="r") if Af.shape[0] > Af.shape[1] else Af / nrm
        _, sv, Vt = np.linalg.svd(R, full_matrices=True)
        sv = np.concatenate([sv, np.zeros(cols.size - sv.size)])
    if cols.size:
        null = Vt[sv <= tol * max(sv[0], 1e-300)].T / nrm[:, None]      # u coordinates, not orthonormal
        if null.shape[1]:
            Q, r, _ = scipy.linalg.qr(null, mode="economic", pivoting=True)
            Q = Q[:, np.abs(np.diag(r)) > 1e-12 * np.abs(r[0, 0])]
            U = np.zeros((p, Q.shape[1]))
            U[cols] = Q
    # each fitted direction without its unseen part: A B = A B0 column by column, so the solver sees the
    # Jacobian it saw before (same steps, same convergence), and x = B z is the representative nearest
    # the nominal robot
    Bu = B0 / sizes[:, None]
    Bu = Bu - U @ (U.T @ Bu)
    Bu[~np.asarray(free, bool)] = 0.0          # a parameter fixed at nominal stays there
    return sizes[:, None] * Bu, U


def unseen_groups(U: np.ndarray, names, units, sizes, tol: float = 1e-9) -> list[dict]:
    """The parameters the measurements cannot tell apart, group by group, in words (the fit JSON).

    Parameters
    ----------
    U : ndarray, shape (p, r)
        Orthonormal directions the measurements cannot see, in units of typical size
        (:func:`physical_subspace`).

    Returns
    -------
    list of dict: per group (parameters linked by an unseen direction; from the projector ``U U^T``,
    so independent of the basis): ``parameters``, ``typical_sizes`` (reported units), ``seen`` and
    ``unseen`` (how many combinations of them the measurements see and do not), ``held`` and ``why``
    (plain words), and ``unseen_directions``: a canonical basis of the unseen combinations (reduced
    row echelon form, reported units: the first parameter of each moves by one typical size).
    """
    if U.shape[1] == 0:
        return []
    P = U @ U.T
    link = np.abs(P) > tol
    p = len(names)
    seen_at, groups = np.full(p, -1), []
    for i in range(p):
        if seen_at[i] >= 0 or P[i, i] <= tol:
            continue
        members, stack = [], [i]
        seen_at[i] = len(groups)
        while stack:
            a = stack.pop()
            members.append(a)
            for b in np.flatnonzero(link[a]):
                if seen_at[b] < 0:
                    seen_at[b] = len(groups)
                    stack.append(b)
        groups.append(sorted(members))
    out = []
    for g in groups:
        g = np.array(g)
        k = int(round(float(np.trace(P[np.ix_(g, g)]))))
        # canonical basis of the unseen combinations: reduced row echelon form of U's rows on the group
        M = U[g].T[np.abs(U[g]).max(axis=0) > tol]                 # (r', n) spanning the group's part
        M = scipy.linalg.orth(M.T).T if M.size else M
        E = _rref(M)[:k]
        dirs = []
        for row in E:
            # at a fixed resolution (1e-6 of the reported unit): the last bits of an SVD differ by machine
            dirs.append({names[c]: round(float(v * sizes[c] * units[c][1]), 6) + 0.0
                         for c, v in zip(g, row) if abs(v) > 1e-9})
        typ = {names[c]: float(sizes[c] * units[c][1]) for c in g}
        out.append({
            "parameters": [names[c] for c in g], "typical_sizes": typ,
            "seen": int(len(g) - k), "unseen": k,
            "held": (f"the {k} combination{'s' if k != 1 else ''} of these {len(g)} parameters that the measurements "
                     f"cannot see {'are' if k != 1 else 'is'} held where the parameters, each counted in units of its "
                     "typical size, are nearest the nominal robot (the smallest sum of squares): what the "
                     "measurements show is carried by the parameters that change least for it"),
            "why": (f"at these poses the {len(g)} parameters move the measured point in only {len(g) - k} independent "
                    f"way{'s' if len(g) - k != 1 else ''}: changed together as in each of the unseen directions, they "
                    "leave every measured position as it is (e.g. with one SMR, the last joint's frame and the tool "
                    "offset), so no measurement can say which of them it is"),
            "unseen_directions": dirs})
    return out


def _rref(M: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Reduced row echelon form of M (rows: a basis of a subspace), pivoting by column order."""
    A = np.array(M, float)
    r = 0
    rows, cols = A.shape
    for c in range(cols):
        if r >= rows:
            break
        piv = r + int(np.argmax(np.abs(A[r:, c])))
        if abs(A[piv, c]) <= tol:
            continue
        A[[r, piv]] = A[[piv, r]]
        A[r] /= A[r, c]
        for i in range(rows):
            if i != r:
                A[i] -= A[i, c] * A[r]
        r += 1
    A[np.abs(A) < 1e-12] = 0.0
    return A[:r]


class RobotErrorModel:
    """Estimator of a robot error model made of effects (scikit-learn style).

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
    solver : {"gauss-newton", "lm", "scipy"}
    identifiability : bool
        Fix parameters beyond the numerical rank at 0 (and report them).
    lm_options : dict, optional
        Constants of the improved L-M (see :func:`pipeline.robot.model.lm.improved_lm`).
    max_iter : int
        Gauss-Newton iterations at most.
    weak_tol : float or None
        Parameters whose determination (distance of their scaled Jacobian column from the span
        of the other kept ones, relative to the largest singular value) is below it stay at
        nominal, the least determined first (see :data:`WEAK_TOL`); None keeps every parameter
        of the numerical rank. Only with ``reduction="fix"``.
    rank_tol : float
        Relative singular value (column-scaled Jacobian) below which a direction counts as
        not identifiable.
    start : dict, optional
        Parameter name -> value (internal units) to start the solver from (the solution of a model
        nested in this one, :func:`pipeline.robot.model.estimate.fit_effects`); default: nominal (0).
    orientation : bool
        On a campaign with a 6-DoF probe's orientations (``RobotData.measured_R``), fit them too
        (contract section 13); False fits the positions alone.
    orientation_weight : float or None
        Weight of the orientation rows, mm per mrad; None: estimated by variance components
        (:data:`VCE_RTOL`), stated in ``weighting_``.
    weight_start : float or None
        Where the variance components start (mm per mrad) when ``orientation_weight`` is None: the
        weight a fit of the same model on nearly the same poses ended with; default: the stated
        uncertainties, else :data:`START_WEIGHT_MM_PER_MRAD` (:func:`start_weight`).
    reduction : {"fix", "svd"}
        What to do with the directions that are not identifiable: ``"fix"`` fixes the
        parameters beyond the rank at 0 (named, QR with pivoting / priority); ``"svd"``
        solves in the span of the leading right singular vectors of the column-scaled
        Jacobian (truncated SVD: the minimum-norm solution; no parameter is singled out).
    checks : bool
        Check the fitted model against what a real robot can be (``plausible_``, ``implausible_``: the
        parameters' bounds, its frames' deviations, the error budget). A fit used only for its
        predictions (a cross-validation fold, the wild-point detector's flexible model) skips them
        (``plausible_`` is then None).

    Attributes (after fit)
    ----------------------
    coef_ : ndarray, shape (p,), internal units (mm, mrad, ...)
    names_, units_ : parameter names, (unit, factor internal -> reported)
    identifiability_ : dict (see :func:`identifiability`)
    cost_ : float, 0.5 ||F||^2 at the solution, mm^2
    rms_mm_ : float, RMS of the 3-D position residual norms of the fitted poses
    orientation_rms_arcsec_ : float or None, RMS of the orientation errors (angles) of the fitted poses
    weighting_ : dict or None, how positions and orientations were weighed (6-DoF fits)
    dof_ : float, the effective number of parameters (trace of the hat matrix of the last Gauss-Newton
        linearisation, penalties included; Gauss-Newton only): a fit with ``dof_`` near its number of
        residuals (3 a pose) interpolates them
    n_iter_, seconds_ : iterations and wall time of the solver
    solver_result_ : LMResult or None
    """

    def __init__(self, robot: Robot, effects, solver: str = "gauss-newton", identifiability: bool = True,
                 lm_options: dict | None = None, max_iter: int = 100, rank_tol: float = RANK_TOL,
                 reduction: str = "fix", weak_tol: float | None = WEAK_TOL, start: dict | None = None,
                 checks: bool = True, orientation: bool = True, orientation_weight: float | None = None,
                 weight_start: float | None = None):
        self.robot = robot
        self.checks = checks
        self.start = start
        self.orientation = orientation
        self.orientation_weight = orientation_weight
        self.weight_start = weight_start
        self.effects = effects
        self.solver = solver
        self.identifiability = identifiability
        self.lm_options = lm_options
        self.max_iter = max_iter
        self.rank_tol = rank_tol
        self.reduction = reduction
        self.weak_tol = weak_tol

    @staticmethod
    def _priority(names):
        """Order of the parameters in the rank and weak-determination passes of :func:`identifiability`:
        joint offsets, then link lengths and twists, then d and beta (MDH practice); other effects in
        their order. It decides which parameters are left at nominal when they are weakly determined
        (the predictions), never how what the measurements cannot see is represented: redundant
        parameters stay free and the fit is the one nearest the nominal robot (:func:`physical_subspace`)."""
        order = {"dtheta": 0, "da": 1, "dalpha": 2, "dd": 3, "dbeta": 4}

        def key(k):
            m = re.match(r"^(dtheta|dd|da|dalpha|dbeta)(\d)$", names[k])
            return (order[m.group(1)], int(m.group(2))) if m else (5, k)
        return sorted(range(len(names)), key=key)

    def design(self, data: RobotData) -> Design:
        memo = getattr(self, "_designs", None)
        if memo is not None and id(data) in memo and memo[id(data)][0] is data:
            # within one variance-components fit: the same poses, the same effects, another weight
            d = memo[id(data)][1]
        else:
            d = Design(self.robot, list(getattr(self, "effects_", self.effects)), data,
                       getattr(self, "_model_and_index", None))
            if memo is not None:
                memo[id(data)] = (data, d)
                d.keep_last = True
        if self.orientation and getattr(data, "measured_R", None) is not None:
            d.weight = getattr(self, "_weight", None) or self.orientation_weight or start_weight(data)[0]
        return d

    def identification(self, data: RobotData, sparse: bool = False):
        """The identification problem of ``data`` at the nominal parameters, as :meth:`fit` sees it.

        Prepares the effects on ``data`` (``effects_``), and returns ``(design, P, J, Pen, penalised,
        ident)``: the :class:`Design`, nominal SMR positions P (n, 3) mm, the identification Jacobian
        J (3 n, p) mm per internal unit (rows x, y, z of each pose), the effects' penalty rows Pen
        (m, p), which parameters are penalised (p,) bool, and :func:`identifiability`'s verdict
        (rank, condition number, the parameters kept and why the others are fixed) with this
        estimator's rank and weak-determination tolerances. It needs joint values only (no
        measurement): ``jointcal plan`` chooses poses on the same problem. With ``sparse`` J is a
        scipy.sparse matrix (CSC), for fits of many parameters (:data:`GRAM_MIN_K`).
        """
        self.effects_ = [e.prepared(self.robot, data) for e in self.effects]
        d = self.design(data)
        self._model_and_index = (d.model, d.idx)
        x = np.zeros(d.p)
        if sparse and d.oriented:
            P, _, J2 = d.residual_and_sparse_jacobian(x)
        elif sparse:
            P, J2 = d.predict_and_sparse_jacobian(x)
        else:
            P, J2 = d.jacobian_rows(x)
        # penalty rows of the effects that have one (smooth many-parameter effects), (m, p)
        blocks, penalised = [], np.zeros(d.p, bool)
        k = 0
        for e in self.effects_:
            n_e = len(e.parameter_names(self.robot))
            pen = e.penalty(self.robot, data.n)
            if pen is not None:
                row = np.zeros((pen.shape[0], d.p))
                row[:, k:k + n_e] = pen
                blocks.append(row)
                penalised[k:k + n_e] = True
            k += n_e
        Pen = np.vstack(blocks) if blocks else np.zeros((0, d.p))
        ident = identifiability(J2, d.names, tol=self.rank_tol, priority=self._priority(d.names), units=d.units,
                                weak_tol=self.weak_tol if self.identifiability and self.reduction == "fix" else None,
                                penalised=penalised)
        ident["rank_exact"] = int(np.sum(np.asarray(ident["singular_values"]) > 1e-10 * ident["singular_values"][0]))
        return d, P, J2, Pen, penalised, ident

    def _large(self, data: RobotData) -> bool:
        """Solved on normal equations: with the default reduction (parameters kept or fixed by name), more
        parameters than :data:`GRAM_MIN_K` and some of them penalised (a joint map's grid values); in the leading
        singular directions (``reduction="svd"``, a Chebyshev model's), a Jacobian of more entries than
        :data:`DENSE_SVD_MAX`."""
        if not (self.identifiability and self.solver == "gauss-newton"):
            return False
        effects = [e.prepared(self.robot, data) for e in self.effects]
        p = sum(len(e.parameter_names(self.robot)) for e in effects)
        if self.reduction == "fix":
            return p > GRAM_MIN_K and any(e.penalty(self.robot, 1) is not None for e in effects)
        return self.reduction == "svd" and (6 if data.has_orientation else 3) * data.n * p > DENSE_SVD_MAX

    def fit(self, data: RobotData) -> "RobotErrorModel":
        """Fit on ``data``'s measured positions (and orientations, a 6-DoF campaign); returns self.

        A 6-DoF fit without a stated ``orientation_weight`` weighs the two by variance components:
        fitted at a weight, the weight becomes the ratio of the RMS position residual (mm, per axis)
        to the RMS orientation residual (mrad, per axis), and the model is fitted again, until the
        weight changes by less than :data:`VCE_RTOL`. Each next weight is where the iteration ends on the fit
        linearised at its solution (:meth:`_vce_linear`), so a campaign usually needs two fits. Where it starts
        does not decide where it ends."""
        t0 = time.perf_counter()
        self._weight = None
        self.weighting_ = None
        # a caller that goes on with the same poses (the wild search's refit steps and predictions) keeps
        # the fit's design: its sparse layouts are not built again
        retain = getattr(self, "_retain_designs", False)
        if getattr(data, "measured_R", None) is None:
            if retain:
                self._designs = {}
            return self._fit_once(data, t0)
        if not self.orientation:
            # positions alone; a 6-DoF probe's mounting on the flange then comes from the orientations
            # with every other parameter as the positions put it (the rotation nearest all of them)
            self._fit_once(data, t0)
            self._register_mounting(data)
            self.weighting_ = {"method": "positions only",
                               "rule": "fitted on the positions alone; the probe frame's turn on the flange (tool_ex, "
                                       "tool_ey, tool_ez) is then the mean rotation from the predicted to the measured "
                                       "probe frames, every other parameter as the positions put it"}
            self.seconds_ = time.perf_counter() - t0
            return self
        if self.orientation_weight:
            w, source = float(self.orientation_weight), "stated (orientation_weight)"
        elif getattr(self, "weight_start", None):
            w, source = float(self.weight_start), "the weight of a fit of the same model on nearly the same poses"
        else:
            w, source = start_weight(data)
        history = []
        before = None          # (log w, log(w_new / w)) of the iteration before
        # every iteration fits the same poses with the same effects at another weight: one design serves them
        # all (its sparse layouts are built once; the weight is applied where the residual is evaluated)
        self._designs = {}
        try:
            for it in range(1, VCE_MAX_ITER + 1):
                self._weight = w
                self._fit_once(data, t0)
                d = self.design(data)
                R, P = d.predict_pose(self.coef_)
                sp = float(np.sqrt(np.mean((P - data.measured_mm) ** 2)))
                so = float(np.sqrt(np.mean(orientation_errors(R, data.measured_R) ** 2)))
                history.append(w)
                if self.orientation_weight or so <= 0 or sp <= 0:
                    break
                w_new = sp / so
                h = float(np.log(w_new / w))
                if abs(h) < VCE_RTOL:
                    break
                # the next weight: where the fit, linearised at this solution, ends the iteration (the
                # position and orientation rows' normal equations apart: a (k, k) solve a trial weight);
                # the plain or secant step where the linear problem cannot say
                guess = self._vce_linear(data, w)
                w = guess if guess is not None else vce_next(np.log(w), h, before)
                before = (float(np.log(history[-1])), h)
        finally:
            if not retain:
                self._designs = None
        self.weighting_ = {
            "method": "stated" if self.orientation_weight else "variance components",
            "rule": ("the orientation rows (mrad) weigh orientation_weight_mm_per_mrad mm each: the ratio of the "
                     "fit's RMS position residual per axis (mm) to its RMS orientation residual per axis (mrad), "
                     f"refitted until it changes by less than {VCE_RTOL:.0%}"),
            "started_from": source, "iterations": len(history),
            "orientation_weight_mm_per_mrad": float(self._weight),
            "position_sigma_mm": sp, "orientation_sigma_arcsec": so * ARCSEC_PER_MRAD}
        self.seconds_ = time.perf_counter() - t0
        return self

    def _vce_linear(self, data: RobotData, w: float) -> float | None:
        """The weight (mm per mrad) where the variance components' iteration ends on the fit linearised at
        its solution (fitted at weight ``w``), to :data:`VCE_RTOL` / 10 on ``h``; None where the linear problem
        cannot say.

        In the fit's directions B (``basis_``) and with its penalty rows, the position and orientation rows
        enter the normal equations apart: at a trial weight v the linear fit is
        ``(Hp + v^2 Ho + Pen^T Pen) dz = -(gp + v^2 go + Pen^T Pen x)`` and its RMS residuals follow from the
        same sums, so each trial costs a (k, k) solve, not a fit. The fit at the weight found decides (the
        iteration's test is on that fit's residuals, as for every weight)."""
        d = self.design(data)
        x = np.asarray(self.coef_, float)
        B, Pen = self.basis_, self.penalty_
        if B is None or B.shape[1] == 0 or w <= 0:
            return None
        n3 = 3 * data.n
        if self._large(data):
            _, F, J = d.residual_and_sparse_jacobian(x)
            J = J.tocsr()
            Hp, gp = gram(J[:n3].tocsc(), F[:n3])
            Ho, go = gram(J[n3:].tocsc(), F[n3:])
        else:
            F, J = d.residual_and_jacobian(x)
            Hp, gp = J[:n3].T @ J[:n3], J[:n3].T @ F[:n3]
            Ho, go = J[n3:].T @ J[n3:], J[n3:].T @ F[n3:]
        # the orientation rows unweighted (mrad)
        Ho, go, Fo, Fp = Ho / w ** 2, go / w ** 2, F[n3:] / w, F[:n3]
        Hp, Ho, gp, go = B.T @ Hp @ B, B.T @ Ho @ B, B.T @ gp, B.T @ go
        PB = Pen @ B
        PtP, pz = PB.T @ PB, PB.T @ (Pen @ x)
        fp2, fo2 = float(Fp @ Fp), float(Fo @ Fo)
        v, before = float(w), None
        for _ in range(4 * VCE_MAX_ITER):
            dz, _ = scaled_min_norm_step(Hp + v * v * Ho + PtP, gp + v * v * go + pz)
            sp2 = (fp2 + 2.0 * float(gp @ dz) + float(dz @ Hp @ dz)) / n3
            so2 = (fo2 + 2.0 * float(go @ dz) + float(dz @ Ho @ dz)) / n3
            if not (np.isfinite(sp2) and np.isfinite(so2) and sp2 > 0 and so2 > 0):
                return None
            h = 0.5 * float(np.log(sp2 / so2)) - float(np.log(v))
            if abs(h) < VCE_RTOL / 10:
                return v
            v, before = vce_next(np.log(v), h, before), (float(np.log(v)), h)
        return None

    def _register_mounting(self, data: RobotData) -> None:
        """Set the probe frame's turn on the flange (the tool's orientation parameters) to the chordal
        mean of the rotations from the predicted to the measured probe frames."""
        from scipy.spatial.transform import Rotation

        names = ["tool_ex", "tool_ey", "tool_ez"]
        if not all(n in self.names_ for n in names):
            return
        cols = [self.names_.index(n) for n in names]
        coef = self.coef_.copy()
        coef[cols] = 0.0
        R, _ = self.design(data).predict_pose(coef)
        rel = np.einsum("nji,njk->nik", R, data.measured_R)
        U, _, Vt = np.linalg.svd(rel.mean(axis=0))
        M = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
        coef[cols] = Rotation.from_matrix(M).as_euler("XYZ") * 1000.0    # the joints RX RY RZ, mrad
        self.coef_ = coef
        self.fixed_ = [n for n in self.fixed_ if n not in names]
        reasons = self.identifiability_.get("fixed_reasons", {})
        for n in names:
            reasons.pop(n, None)
        self.identifiability_["not_identifiable"] = [n for n in self.identifiability_.get("not_identifiable", [])
                                                     if n not in names]
        Rp, _ = self.design(data).predict_pose(self.coef_)
        self.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(orientation_errors(Rp, data.measured_R))
                                                             ** 2)))

    def _fit_once(self, data: RobotData, t0) -> "RobotErrorModel":
        large = self._large(data)
        d, P, J2, Pen, penalised, ident = self.identification(data, sparse=large)
        meas = np.asarray(data.measured_mm, float)
        F0 = d.residual(np.zeros(d.p)) if d.oriented else (P - meas).ravel()
        if large:
            H0, g0 = gram(J2, F0)
            norms = np.sqrt(np.maximum(np.diag(H0), 0.0))
        else:
            norms = np.linalg.norm(J2, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        if self.identifiability and self.reduction == "svd":
            if large:
                # the same sv and V as the dense SVD's, without its U
                sv2, Vt = scaled_svd(J2, norms, ident["zero"])
            else:
                Js2 = J2 / norms
                Js2[:, ident["zero"]] = 0.0          # parameters that barely move the point stay at 0
                _, sv2, Vt = np.linalg.svd(Js2, full_matrices=False)
            r = min(ident["rank"], int(np.sum(sv2 > self.rank_tol * sv2[0])) if sv2.size else 0)
            B = Vt[:r].T / norms[:, None]          # (p, r): x = B z
            ident["not_identifiable"] = [n for n, z in zip(d.names, ident["zero"]) if z]
            # no other parameter is singled out: weak directions are left out
            ident["fixed_reasons"] = {n: v for n, v in ident["fixed_reasons"].items() if n in ident["not_identifiable"]}
            ident["directions_left_out"] = int(d.p - ident["rank"])
        else:
            keep = ident["keep"] if self.identifiability else np.ones(d.p, bool)
            B = np.eye(d.p)[:, keep]
        # what the measurements cannot see stays physical (contract section 8): the span of B decides
        # the predictions; within the parameters free to move, the directions that change no prediction
        # are held where the model is nearest the nominal robot, every parameter counted in units of its
        # typical size (physical_subspace). A parameter called redundant (an exact combination of the
        # kept ones) is free: it takes its share of what it cannot be told apart from.
        if self.identifiability and self.reduction == "fix":
            redundant = np.array([ident["fixed_reasons"].get(n, {}).get("reason", "").startswith("redundant")
                                  for n in d.names], bool)
            movable = ident["keep"] | redundant
        elif self.identifiability:
            movable = ~ident["zero"]
        else:
            movable = np.ones(d.p, bool)
        if large:
            B, U = physical_subspace(None, B, movable, d.sizes, gram=H0 + Pen.T @ Pen)
        else:
            B, U = physical_subspace(np.vstack([J2, Pen]), B, movable, d.sizes)
        moves = (np.abs(B).max(axis=1, initial=0.0) > 0) | (np.abs(U).max(axis=1, initial=0.0) > 0)
        groups = unseen_groups(U, d.names, d.units, d.sizes)
        in_group = {n for g in groups for n in g["parameters"]}
        reasons = {n: r for n, r in ident["fixed_reasons"].items()
                   if n not in in_group and not (n in d.names and moves[d.names.index(n)])}
        ident["fixed_reasons"] = reasons
        ident["not_identifiable"] = [n for n in d.names if n in reasons]
        ident["redundant_groups"] = groups
        #: directions of the parameters (internal units, columns) no measurement of the fit can see
        self.unseen_ = d.sizes[:, None] * U
        #: the fitted directions (x = B z, (p, k)) and the effects' penalty rows (m, p): the fit's
        #: covariance (pipeline.robot.model.uncertainty) lives in their span
        self.basis_, self.penalty_ = B, Pen

        def full(z):
            return B @ z

        PB = Pen @ B

        def fun(z):
            return np.concatenate([d.residual(full(z)), PB @ z])

        def fun_and_jac(z):
            F_, J_ = d.residual_and_jacobian(full(z))
            return np.concatenate([F_, PB @ z]), np.vstack([J_ @ B, PB])

        PtP = PB.T @ PB
        rows = np.flatnonzero(np.abs(B).max(axis=1, initial=0.0) > 0)     # the parameters that move
        Br = B[rows]

        def normal_equations(z, Fd=None, H=None, g=None):
            """F, and the normal equations of the fitted directions: Jf^T Jf (k, k) and Jf^T F (k,)."""
            if H is None:
                if d.oriented:
                    _, Fd, J_ = d.residual_and_sparse_jacobian(full(z))
                else:
                    P_, J_ = d.predict_and_sparse_jacobian(full(z))
                    Fd = (P_ - meas).ravel()
                H, g = gram(J_, Fd)
            F_ = np.concatenate([Fd, PB @ z])
            return F_, Br.T @ H[np.ix_(rows, rows)] @ Br + PtP, Br.T @ g[rows] + PtP @ z

        free = np.arange(B.shape[1])
        result = None
        z0 = np.zeros(free.size)
        if self.start:
            x0 = np.array([float(self.start.get(nm, 0.0)) for nm in d.names])
            # the start's part in the fitted directions, counted in typical sizes
            z0 = np.linalg.lstsq(B / d.sizes[:, None], x0 / d.sizes, rcond=None)[0] if B.shape[1] else z0
        if self.solver == "gauss-newton":
            # Gauss-Newton (Eq. 6 iterated) on the column-scaled Jacobian (minimum-norm steps from
            # its SVD), with Levenberg damping only when a full step does not lower the cost: the
            # damping grows tenfold until a step does (from 1e-3 of the largest curvature) and falls
            # tenfold after each success, to 0 (a plain Gauss-Newton step again). Converged when a
            # full Gauss-Newton step would change the residuals by ||dF||^2 <= GN_PHI (or a
            # GAIN_REL_CONVERGED fraction of ||F||^2): the improved L-M's test (pipeline.robot.model.lm).
            # Step halving alone stopped at its iteration limit on a real UR10, worse than the start.
            xf = z0.copy()
            if large:
                # the same iteration on the normal equations (GRAM_MIN_K): Jf^T Jf = V diag(sv^2) V^T
                # gives the SVD's sv and V, and U^T F = diag(1/sv) V^T Jf^T F
                F, Gf, gF = normal_equations(xf) if self.start else normal_equations(xf, F0, H0, g0)
                Jf = None
            elif self.start:
                F, Jf = fun_and_jac(xf)
            elif d.oriented:
                F, Jf = np.concatenate([F0, np.zeros(PB.shape[0])]), np.vstack([J2 @ B, PB])
            else:
                F, Jf = np.concatenate([(P - meas).ravel(), np.zeros(PB.shape[0])]), np.vstack([J2 @ B, PB])
            cost = 0.5 * float(F @ F)
            scale = np.zeros(free.size)
            # a start from a nested model's solution counts as having left nominal
            lam, moved, converged, it = 0.0, bool(self.start), False, 0
            dof, hat = float("nan"), None
            reason = f"iteration limit ({self.max_iter}) reached"
            for it in range(1, self.max_iter + 1):
                if not (np.all(np.isfinite(F)) and np.all(np.isfinite(Gf if large else Jf))):
                    reason = "non-finite residual or Jacobian"
                    break
                factor = top = None
                if large:
                    scale = np.maximum(scale, np.sqrt(np.maximum(np.diag(Gf), 0.0)))
                    sc = np.where(scale > 0, scale, 1.0)
                    As, gs = Gf / np.outer(sc, sc), gF / sc
                    factor = well_conditioned_cholesky(As)
                    if factor is not None:
                        # every direction kept (as the eigen-solution would keep them): solved by the factor,
                        # the largest curvature (the damping's scale) found only when a step needs damping
                        y = scipy.linalg.cho_solve(factor, gs, check_finite=False)
                        gain = float(gs @ y)
                    else:
                        w, V = np.linalg.eigh(As)
                        sv, Vt = np.sqrt(np.maximum(w[::-1], 0.0)), V[:, ::-1].T
                        r = int(np.sum(sv > 1e-12 * sv[0])) if sv.size else 0
                        sv, Vt = sv[:r], Vt[:r]
                        c = (Vt @ gs) / sv
                        gain = float(c @ c)
                        top = float(sv[0] ** 2) if sv.size else 0.0
                    # the last iteration's: its hat matrix trace is dof_ (below)
                    hat = (Gf, sc, factor) + ((None, None) if factor is not None else (Vt, sv))
                else:
                    scale = np.maximum(scale, np.linalg.norm(Jf, axis=0))
                    sc = np.where(scale > 0, scale, 1.0)
                    U, sv, Vt = np.linalg.svd(Jf / sc, full_matrices=False)
                    r = int(np.sum(sv > 1e-12 * sv[0])) if sv.size else 0
                    U, sv, Vt = U[:, :r], sv[:r], Vt[:r]
                    c = U.T @ F
                    nd = F.size - PB.shape[0]
                    dof = float(np.sum(U[:nd] ** 2))
                    gain = float(c @ c)
                    top = float(sv[0] ** 2) if sv.size else 0.0
                stationary = gain <= max(GN_PHI, GAIN_REL_CONVERGED * 2.0 * cost)
                if gain <= 1e-12 * 2.0 * cost:  # the linear model predicts no decrease beyond rounding
                    converged = moved or cost == 0.0
                    reason = (f"a Gauss-Newton step would change F by ||dF||^2 = {gain:.2g} mm^2 (rounding)"
                              if converged else "the start is already stationary (never left it)")
                    break
                for _ in range(16):
                    if factor is None:
                        step = -(Vt.T @ (sv / (sv**2 + lam) * c)) / sc
                    elif lam == 0.0:
                        step = -y / sc
                    else:
                        damped = scipy.linalg.cho_factor(As + lam * np.eye(As.shape[0]), lower=True, check_finite=False)
                        step = -scipy.linalg.cho_solve(damped, gs, check_finite=False) / sc
                    F_try = fun(xf + step)
                    cost_try = 0.5 * float(F_try @ F_try)
                    if np.isfinite(cost_try) and cost_try < cost:
                        break
                    top = top if top is not None else _largest_eigenvalue(As)
                    lam = max(10.0 * lam, 1e-3 * top)
                else:
                    converged = moved and stationary
                    reason = (f"no damped step lowers the cost; a Gauss-Newton step would change F by ||dF||^2 = "
                              f"{gain:.2g} mm^2" + (f" <= {GN_PHI:g}" if stationary else " (not stationary)"))
                    break
                if lam > 0.0:
                    top = top if top is not None else _largest_eigenvalue(As)
                lam = lam / 10.0 if lam > 0.0 and lam > 1e-9 * top else 0.0
                xf = xf + step
                moved = True
                if large:
                    F, Gf, gF = normal_equations(xf)
                else:
                    F, Jf = fun_and_jac(xf)
                cost = 0.5 * float(F @ F)
            self.n_iter_ = it
            self.converged_, self.convergence_ = bool(converged), reason
            if large and hat is not None:
                # the hat matrix's trace: the data rows' share of each direction (penalty rows excluded)
                Gh, sch, fh, Vth, svh = hat
                Gd = (Gh - PtP) / np.outer(sch, sch)
                dof = (float(np.trace(scipy.linalg.cho_solve(fh, Gd, check_finite=False))) if fh is not None
                       else float(np.sum(np.sum((Vth @ Gd) * Vth, axis=1) / svh ** 2)))
            self.dof_ = dof
        elif self.solver == "lm":
            result = lm.improved_lm(fun, None, z0, fun_and_jac=fun_and_jac, **(self.lm_options or {}))
            xf, cost, self.n_iter_ = result.x, result.cost, result.n_iter
            self.converged_, self.convergence_ = bool(result.converged), result.reason
        elif self.solver == "scipy":
            result = lm.scipy_least_squares(fun, lambda xf: fun_and_jac(xf)[1], z0)
            xf, cost, self.n_iter_ = result.x, result.cost, result.n_iter
            self.converged_, self.convergence_ = bool(result.converged), result.reason
        else:
            raise ValueError(f"unknown solver {self.solver!r}")
        self.coef_ = full(xf)
        self.names_ = d.names
        self.units_ = d.units
        self.identifiability_ = ident
        self.fixed_ = ident["not_identifiable"]
        self.cost_ = cost
        if d.oriented:
            R_, P_ = d.predict_pose(self.coef_)
            resid = P_ - meas
            self.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(orientation_errors(R_, data.measured_R))
                                                                 ** 2)))
        else:
            resid = (d.predict(self.coef_) - meas)
            self.orientation_rms_arcsec_ = None
        self.rms_mm_ = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
        self.solver_result_ = result
        self._judge(d, data)
        self.seconds_ = time.perf_counter() - t0
        return self

    def _judge(self, d, data: RobotData) -> None:
        """Whether a real robot can have the fitted parameters (``implausible_``, ``plausible_``; None
        without ``checks``), on the design ``d`` of the poses ``data`` it was fitted on."""
        if not self.checks:
            self.implausible_, self.plausible_ = [], None
            return
        # every fit checks itself: converged_ / convergence_ (set by the solver branch above) and
        # whether a real robot can have the fitted parameters (pipeline.robot.model.lm.PLAUSIBLE_BOUNDS)
        params, checked, k = self.parameters(), [], 0
        for e in self.effects_:
            n = len(e.parameter_names(self.robot))
            checked += e.checked_values(self.robot, params[k:k + n], data.q_deg)
            k += n
        # the frames judged by how far they move and turn (contract section 8: physical deviations, not
        # a parameter that carried a direction the measurements cannot see)
        checked += frame_deviations(d.model, d.idx, d.configurations(self.coef_), d.Q0)
        # and whether a joint's angle error varies beyond the robot's own error budget in the sampled
        # joint box (the yardstick diagnosis uses: pipeline.robot.model.budget)
        self.implausible_ = implausible_parameters(checked) + self._over_budget(d, data)
        self.plausible_ = not self.implausible_

    def _over_budget(self, d, data) -> list[dict]:
        """Joints whose fitted angle error varies beyond the robot's error budget (:mod:`.budget`)."""
        if not any(getattr(e, "on_joint_angle", False) for e in self.effects_) or data.measured_mm is None:
            return []
        nominal, Jext = positions_and_jacobians(d.model, d.Q0)
        return model_over_budget(self.robot, Design, self.effects_, dict(zip(d.names, self.coef_)), data, Jext,
                                 d.idx.joints, nominal)

    def predict(self, data: RobotData) -> np.ndarray:
        """Model SMR positions, shape (n, 3), mm."""
        return self.design(data).predict(self.coef_)

    def predict_pose(self, data: RobotData):
        """Model probe frames: rotations (n, 3, 3) and positions (n, 3) mm."""
        return self.design(data).predict_pose(self.coef_)

    def stepped_without(self, data: RobotData, keep, max_steps: int = 10) -> "RobotErrorModel":
        """This model refitted on the poses ``keep`` of ``data`` (the poses it was fitted on) by
        Gauss-Newton steps from its solution, in its fitted directions: a new model (this one is not
        changed).

        Each step solves the normal equations of the kept poses, in the fitted directions (``basis_``) with
        the effects' penalty rows, at the fit's orientation weight; the steps end when one would change the
        residuals by ``||dF||^2 <= 1e-5 mm^2`` (that step taken; the improved L-M's test) or by rounding.
        Leaving out a few poses of thousands moves the solution by little: two steps, each one Jacobian,
        instead of a new design, identification and iteration. The identification stays the fit's: the
        directions it could not see on all poses are not fitted on fewer.

        Parameters
        ----------
        data : RobotData
            The poses the model was fitted on, n of them.
        keep : ndarray of bool, shape (n,)
            The poses the steps are fitted on.
        """
        import copy

        import scipy.sparse

        keep = np.asarray(keep, bool)
        out = copy.copy(self)
        B, Pen = self.basis_, self.penalty_
        if B is None or B.shape[1] == 0 or keep.all():
            return out
        d = self.design(data)
        x = np.asarray(self.coef_, float)
        rows = np.repeat(keep, 3).astype(float)
        if d.oriented:
            rows = np.concatenate([rows, rows])
        PB = Pen @ B
        PtP = PB.T @ PB
        # a fit of many parameters steps on its sparse Jacobian (its layout already built), a small one on the
        # dense Jacobian it was fitted with
        sparse = self._large(data)
        for _ in range(max_steps):
            if not sparse:
                F, J = d.residual_and_jacobian(x)
                J = J * rows[:, None]
                H, g = J.T @ J, J.T @ (F * rows)
            else:
                if d.oriented:
                    _, F, J = d.residual_and_sparse_jacobian(x)
                else:
                    P, J = d.predict_and_sparse_jacobian(x)
                    F = (P - np.asarray(data.measured_mm, float)).ravel()
                # the poses left out weigh 0 (their rows zeroed: no row slicing of the CSC matrix)
                J = scipy.sparse.csc_matrix((J.data * rows[J.indices], J.indices, J.indptr), shape=J.shape)
                H, g = gram(J, F * rows)
            dz, gain, rank = scaled_min_norm_step(B.T @ H @ B + PtP, B.T @ g + PB.T @ (Pen @ x), with_rank=True)
            out.step_rank_ = rank
            cost2 = float((F * rows) @ F) + float((Pen @ x) @ (Pen @ x))
            if not np.isfinite(gain) or gain <= 1e-12 * cost2:
                break
            x = x + B @ dz
            if gain <= GN_PHI:
                break
        out.coef_ = x
        return out

    def determined_without(self, data: RobotData, keep) -> "RobotErrorModel | None":
        """:meth:`stepped_without`, or None where the steps cannot stand for a fit on the poses ``keep``: the
        model has no fitted directions to step in, or the kept poses do not determine every one of them."""
        if getattr(self, "basis_", None) is None:
            return None
        out = self.stepped_without(data, keep)
        return out if getattr(out, "step_rank_", self.basis_.shape[1]) >= self.basis_.shape[1] else None

    def refitted_without(self, data: RobotData, keep, kept: RobotData) -> "RobotErrorModel | None":
        """This model (fitted on ``data``) taken to the poses ``keep`` of it (``kept``, the same poses as
        ``data.subset(keep)``) by :meth:`stepped_without`, and judged there as a fit on ``kept`` is: its RMS
        residuals, its variance components and its plausibility. A new model; None where the steps cannot
        stand for a fit on ``kept``: the kept poses do not determine every fitted direction, or (a 6-DoF fit
        weighed by variance components) the weight the kept poses give differs from the fit's by
        :data:`VCE_RTOL` or more. The identification stays the fit's (it needs joint values only)."""
        keep = np.asarray(keep, bool)
        if keep.all():
            return self
        out = self.determined_without(data, keep)
        if out is None:
            return None
        d = out.design(kept)
        meas = np.asarray(kept.measured_mm, float)
        if d.oriented:
            R, P = d.predict_pose(out.coef_)
            ori = orientation_errors(R, kept.measured_R)
            out.orientation_rms_arcsec_ = float(np.sqrt(np.mean(angle_arcsec(ori) ** 2)))
            if out.weighting_ and out.weighting_.get("method") == "variance components":
                sp, so = float(np.sqrt(np.mean((P - meas) ** 2))), float(np.sqrt(np.mean(ori ** 2)))
                if not (sp > 0 and so > 0) or abs(float(np.log(sp / so / out._weight))) >= VCE_RTOL:
                    return None
                out.weighting_ = dict(out.weighting_, position_sigma_mm=sp, orientation_sigma_arcsec=so * ARCSEC_PER_MRAD)
        else:
            P = d.predict(out.coef_)
        out.rms_mm_ = float(np.sqrt(np.mean(np.sum((P - meas) ** 2, axis=1))))
        out._judge(d, kept)
        return out

    def predict_error(self, data: RobotData) -> np.ndarray:
        """Predicted position error (model - nominal), shape (n, 3), mm (the paper's Delta P_e)."""
        d = self.design(data)
        return d.predict(self.coef_) - d.predict(np.zeros(d.p))

    def parameters(self) -> list[dict]:
        """Fitted parameters in reported units."""
        fixed = set(self.fixed_)
        return [{"name": n, "value": float(v * f), "unit": u, "fixed": n in fixed}
                for n, v, (u, f) in zip(self.names_, self.coef_, self.units_)]

    @classmethod
    def from_parameters(cls, robot, effects, parameters: list[dict]) -> "RobotErrorModel":
        """Rebuild a fitted model from :meth:`parameters` (e.g. read from JSON)."""
        m = cls(robot, effects)
        m.effects_ = list(effects)       # as fitted (their spec lines carry any fit-time state)
        d = m.design(_empty_data(robot))
        by = {p["name"]: p for p in parameters}
        m.names_, m.units_ = d.names, d.units
        m.coef_ = np.array([by[n]["value"] / f for n, (u, f) in zip(d.names, d.units)])
        m.fixed_ = [p["name"] for p in parameters if p.get("fixed")]
        m.unseen_ = np.zeros((len(d.names), 0))
        return m

    def undetermined(self) -> np.ndarray:
        """Directions of the parameters (internal units, shape (p, m)) the measurements of the fit did
        not determine: the combinations no measurement could see (:attr:`unseen_`) and every parameter
        left at nominal (:attr:`fixed_`). ``jointcal correct`` holds the flange orientation only where
        none of them turns it."""
        U = getattr(self, "unseen_", None)
        U = np.zeros((len(self.names_), 0)) if U is None else np.asarray(U, float)
        if "orientation_weight_mm_per_mrad" in (getattr(self, "weighting_", None) or {}):
            # fitted on a 6-DoF probe's orientations: the probe frame's orientation is a measurement, and
            # what no measurement could see leaves it as it is; a parameter left at nominal as weakly
            # determined moves it only as the identified ones already do over the sampled poses. The
            # whole orientation is determined (contract section 13: orientation_held = all).
            return np.zeros((len(self.names_), 0))
        fixed = [k for k, n in enumerate(self.names_) if n in set(self.fixed_)]
        E = np.zeros((len(self.names_), len(fixed)))
        E[fixed, np.arange(len(fixed))] = 1.0
        return np.hstack([U, E])


def _empty_data(robot):
    z = np.zeros((1, robot.n_joints))
    return RobotData(z + (robot.lower_deg + robot.upper_deg) / 2, np.ones((1, robot.n_joints), int), np.zeros(1),
                     np.full(1, REFERENCE_TEMPERATURE_C),
                     z, robot.lower_deg, robot.upper_deg)


def calibrate_mdh(robot: Robot, data: RobotData, effects=None) -> tuple[RobotErrorModel, dict]:
    """MDH kinematic calibration (Eqs. 3-6) with identifiability analysis.

    Returns the fitted model and a JSON-ready report: parameters (arcsec, mm), rank,
    condition number, parameters not identifiable (fixed at 0), residual RMS before/after.
    """
    effects = effects or [Geometry(), Base()]
    model = RobotErrorModel(robot, effects, solver="gauss-newton", identifiability=True).fit(data)
    nominal = model.design(data).predict(np.zeros(len(model.coef_)))
    before = np.linalg.norm(data.measured_mm - nominal, axis=1)
    after = np.linalg.norm(data.measured_mm - model.predict(data), axis=1)
    ident = model.identifiability_
    report = {"effects": [e.name for e in effects], "n_poses": int(data.n), "solver": "gauss-newton (Eq. 6 iterated)",
              "iterations": model.n_iter_, "seconds": model.seconds_,
              "rank": ident["rank"], "n_params": ident["n_params"],
              "condition_number": ident["condition_number"],
              "condition_number_all": ident["condition_number_all"],
              "not_identifiable": ident["not_identifiable"],
              "redundant": ident.get("redundant_groups", []),
              "rms_before_mm": float(np.sqrt(np.mean(before**2))), "rms_after_mm": float(np.sqrt(np.mean(after**2))),
              "max_before_mm": float(before.max()), "max_after_mm": float(after.max()),
              "parameters": model.parameters()}
    return model, report
