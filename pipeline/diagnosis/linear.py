"""Robot diagnosis around one shared baseline fit: every candidate is a linear correction to it.

The spec's model is fitted once on every sample pose (Gauss-Newton, :mod:`pipeline.calibrate`).
At that solution the residuals ``r`` (n, 3) mm and the Jacobian of the SMR positions with respect
to every parameter of the baseline and of every candidate are computed once (pinocchio frame
Jacobians of the error model, chained with each effect's channel basis). A model "baseline +
candidate" refitted on the training poses of a fold is then one linear least-squares step from
the shared solution - exact to first order in the (small) parameter changes - so a candidate
costs a few small normal-equation solves per fold instead of five nonlinear fits.

Two sets of folds:

* **random** folds by pose (the held-out poses are neighbours of the fitted ones): the gain and
  the paired test of the drop in squared held-out residual, pose by pose;
* **region** folds: the sample poses cut into blocks of joint space (k-means on the joint angles
  scaled to their sampled ranges), each held out in turn: a term that only interpolates between
  neighbouring poses does not lower the error there.

And a look at the candidate's fit on every sample pose: its largest predicted change anywhere in
the sampled joint box (random configurations), its parameters against a real robot's bounds, and
whether its contribution is cancelled by the model's other terms.
"""

from __future__ import annotations

import numpy as np

# configurations drawn in the sampled joint box (the robot's error budget, shared with every fit)
from ..robot.model.budget import N_BOX, box_configurations  # noqa: F401 (re-exported)
from ..robot.model import normal
from ..core.se3 import orientation_errors
from ..robot.model.design import Design
from ..robot.model.identify import WEAK_TOL, penalty_rows
from ..robot.model.weighting import start_weight
from ..robot.model.estimate import fit_effects
from ..robot.arm.kinematics import pose_jacobians, positions_and_jacobians

#: Region folds: number of blocks of joint space and k-means iterations.
N_REGIONS = 5
KMEANS_ITER = 30
#: A refit may not change the predicted position anywhere in the sampled joint box by more than this
#: many times the larger of the largest error measured (nominal model) and its own largest change on
#: the sample poses: random configurations there reach further and turn the wrist more than the
#: sampled poses (a real tool offset: 3x), while a pair of harmonics cancelling each other on the
#: sampled poses sent a home pose 18.9 mm off against a measured 2.2 mm (8.6x).
BOX_FACTOR = 5.0
#: Directions of a fold's normal equations weaker than this (eigenvalue relative to the largest, of
#: the column-scaled Gram matrix) are left out: the identifiability limit of the full fit
#: (WEAK_TOL on singular values) applied to the smaller training set of a fold. Without it, a
#: region held out from 80 poses of a small box saw 48 mm of extrapolation from a base error.
EIG_TOL = WEAK_TOL ** 2


def region_folds(q_deg, k: int = N_REGIONS, seed: int = 0) -> np.ndarray:
    """Block of joint space of each pose: k-means (k-means++ start, seeded) on the joint angles
    scaled to [0, 1] over their sampled ranges.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg

    Returns
    -------
    ndarray of int, shape (n,): 0..k-1 (empty blocks are dropped and renumbered)
    """
    q = np.asarray(q_deg, float)
    span = np.ptp(q, axis=0)
    X = (q[:, span > 1e-9] - q[:, span > 1e-9].min(axis=0)) / span[span > 1e-9]
    n = len(X)
    k = max(1, min(k, n))
    rng = np.random.default_rng(seed)
    centres = [X[rng.integers(n)]]
    for _ in range(1, k):
        d2 = np.min(((X[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        centres.append(X[rng.choice(n, p=d2 / d2.sum())] if d2.sum() > 0 else X[rng.integers(n)])
    C = np.array(centres)
    lab = np.zeros(n, int)
    for _ in range(KMEANS_ITER):
        lab = np.argmin(((X[:, None, :] - C[None]) ** 2).sum(-1), axis=1)
        newC = np.array([X[lab == c].mean(axis=0) if np.any(lab == c) else C[c] for c in range(k)])
        if np.allclose(newC, C):
            break
        C = newC
    _, lab = np.unique(lab, return_inverse=True)
    return lab


def channel_jacobian(design: Design, x) -> np.ndarray:
    """Positions' Jacobian (n, 3, nv) with respect to every channel of the error model at ``x``; for a
    6-DoF design (``design.oriented``) (n, 6, nv), the probe frame's turn in mrad times the design's
    orientation weight (mm-equivalent) below the positions."""
    if design.oriented:
        _, _, Jext = pose_jacobians(design.model, design.configurations(x))
        Jext[:, 3:] *= 1000.0 * design.weight
        return Jext
    _, Jext = positions_and_jacobians(design.model, design.configurations(x))
    return Jext


def effect_columns(robot, effect, data, Jext, idx_model) -> tuple[np.ndarray, list, list]:
    """Jacobian (3n, k) of the SMR positions with respect to ``effect``'s parameters (internal units),
    chained from the channel Jacobian ``Jext`` (n, 3, nv) (6n rows from a 6-DoF one, (n, 6, nv));
    and its names and units."""
    d = Design(robot, [effect], data, idx_model)
    if d.p == 0:
        return np.zeros((Jext.shape[1] * data.n, 0)), [], []
    J = d.parameter_jacobian(Jext)
    return J.reshape(-1, d.p), d.names, d.units


class Block:
    """Columns of one effect in the linear problem: Jacobian (3n, k), penalty rows (m, k) or None.

    ``dense=False`` (a candidate's block): once its columns are found sparse (:meth:`sparse`), only the sparse
    copy is kept and :attr:`J` is made from it when asked for (the same values). A diagnosis keeps every
    candidate's block; a joint map's dense columns on a 6-DoF campaign of 7,144 poses are 25 MB each, two
    nonzeros a row (issue 32)."""

    def __init__(self, J, pen=None, names=(), units=(), dense: bool = True):
        self._J = J
        self._dense = dense
        self.pen = pen if pen is not None and pen.size else None
        self.names, self.units = list(names), list(units)
        self._sparse, self._sparse_known, self._full = None, False, None
        self._shape = J.shape

    @property
    def J(self) -> np.ndarray:
        """The columns, dense (3n or 6n, k)."""
        return self._J if self._J is not None else self._sparse.toarray()

    @property
    def k(self) -> int:
        return self._shape[1]

    def sparse(self):
        """The columns as a sparse matrix (CSR) when fewer than :data:`SPARSE_DENSITY` of them are nonzero (a
        joint map's: each pose moves two knots of a joint), else None."""
        if not self._sparse_known:
            self._sparse_known = True
            J = self._J
            if J.size and np.count_nonzero(J) < SPARSE_DENSITY * J.size:
                import scipy.sparse

                self._sparse = scipy.sparse.csr_matrix(J)
                if not self._dense:
                    self._J = None
        return self._sparse

    def columns(self):
        """The columns to multiply with: :meth:`sparse` when they are sparse, else the dense J."""
        sp = self.sparse()
        return self._J if sp is None else sp


#: A candidate's columns sparser than this (fraction nonzero) are multiplied as a sparse matrix.
SPARSE_DENSITY = 0.1


def _tdot(A, B) -> np.ndarray:
    """A^T B as a dense array, A and B dense or sparse (rows alike)."""
    if hasattr(A, "tocsr"):
        out = A.T @ B
    elif hasattr(B, "tocsr"):
        out = (B.T @ A).T
    else:
        return A.T @ B
    return out.toarray() if hasattr(out, "toarray") else np.asarray(out)


def _count_nonzero(A) -> np.ndarray:
    """Nonzero rows of each column (k,), A dense or sparse."""
    if hasattr(A, "tocsr"):
        A = A.tocsr()
        return np.bincount(A.indices[A.data != 0], minlength=A.shape[1])
    return np.count_nonzero(A, axis=0)


def _train_products(J: np.ndarray, r: np.ndarray, train: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J[train].T @ J[train]`` (k, k) and ``J[train].T @ r[train]`` (k,) of J (m, k), r (m,), train (m,) bool.

    A J beyond :data:`pipeline.robot.model.normal.DENSE_SVD_MAX` entries is summed over blocks of rows of
    that size, so that the training rows (four fifths of a 6-DoF baseline's 43,000 x 800: 220 MB) are never
    copied at once (issue 32); a smaller one (every fixture) in one product, as before."""
    if J.size <= normal.DENSE_SVD_MAX:
        Jb = J[train]
        return Jb.T @ Jb, Jb.T @ r[train]
    rows = max(1, normal.DENSE_SVD_MAX // max(J.shape[1], 1))
    G, g = np.zeros((J.shape[1], J.shape[1])), np.zeros(J.shape[1])
    for a in range(0, J.shape[0], rows):
        t = train[a:a + rows]
        Jb = J[a:a + rows][t]
        G += Jb.T @ Jb
        g += Jb.T @ r[a:a + rows][t]
    return G, g


class LinearProblem:
    """The baseline fitted once; models with extra blocks solved linearly, fold by fold.

    Parameters
    ----------
    robot : Robot
    base_effects : list of RobotEffect
    data : RobotData (sample poses, measured_mm set)
    folds : dict name -> ndarray of int, shape (n,) (e.g. ``{"random": ..., "region": ...}``)
    """

    def __init__(self, robot, base_effects, data, folds: dict, weight=None):
        self.robot, self.data, self.folds = robot, data, folds
        n = data.n
        #: rows per pose: 3 (positions) or 6 (a 6-DoF campaign: positions and weighted orientations)
        self.dim = 6 if data.has_orientation else 3
        #: weight of the orientation rows (mm per mrad; None: positions only)
        self.weight = None
        if base_effects:
            self.model = fit_effects(robot, base_effects, data, orientation_weight=weight if self.dim == 6 else None)
            d = self.model.design(data)
            self.weight = d.weight if d.oriented else None
            self.idx_model = (d.model, d.idx)
            self.coef = self.model.coef_
            keep = ~np.isin(d.names, self.model.fixed_)
            # the fixed parameters' columns are never made (a 6-DoF baseline's J is 43,000 x 573 of its 863
            # parameters: 196 MB, not 296 MB, and no copy)
            if d.oriented:
                R_pred, pred, Jall = d.pose_and_jacobian(self.coef, keep)
                Jall[:, 3:] *= d.weight
            else:
                pred, Jall = d.predict_and_jacobian(self.coef, keep)
            J = Jall.reshape(-1, int(keep.sum()))
            del Jall
            pen = _penalty(robot, self.model.effects_, n, d.p)
            self.base = Block(J, pen[:, keep] if pen is not None else None,
                              [m for m, k in zip(d.names, keep) if k], [u for u, k in zip(d.units, keep) if k])
            self.base_design = d
        else:
            self.model = None
            d = Design(robot, [], data)
            if self.dim == 6:
                d.weight = self.weight = weight or start_weight(data)[0]
            self.idx_model = (d.model, d.idx)
            self.coef = np.zeros(0)
            if d.oriented:
                R_pred, pred = d.predict_pose(self.coef)
            else:
                pred = d.predict(self.coef)
            self.base = Block(np.zeros((self.dim * n, 0)))
            self.base_design = d
        r = np.asarray(data.measured_mm, float) - pred
        if self.dim == 6:
            # measured - predicted, as the positions: the turn from the predicted probe frame to the measured
            r = np.hstack([r, -self.weight * orientation_errors(R_pred, data.measured_R)])
        self.r = r.ravel()
        self.Jext = channel_jacobian(self.base_design, self.coef)
        self._gram = {}
        #: the baseline's J^T J and J^T r over every row (:meth:`_solve`), once
        self._base_all = None
        #: block pairs' products over every row and over each fold's held-out rows (:meth:`_gram_of`), under
        #: the blocks' ids; the blocks themselves, so that an id is never reused while its products are kept
        self._pairs, self._keep = {}, {}

    # ------------------------------------------------------------------ columns
    def block(self, effect) -> Block:
        """The candidate's columns at the shared solution (effect made ready on the sample poses)."""
        e = effect.prepared(self.robot, self.data)
        J, names, units = effect_columns(self.robot, e, self.data, self.Jext, self.idx_model)
        pen = e.penalty(self.robot, self.data.n)
        return Block(J, pen, names, units, dense=False)

    # ------------------------------------------------------------------ solves
    def _rows(self, mask):
        return np.repeat(mask, self.dim)

    def _solve(self, blocks, rows):
        """Least squares of r on the blocks' columns over ``rows`` (+ penalties); coefficients."""
        if rows.all() and len(blocks) == 2 and blocks[0] is self.base and self.base.k:
            # every row, the baseline and one candidate: the products computed once (:meth:`_products`)
            if self._base_all is None:
                self._base_all = (self.base.J.T @ self.base.J, self.base.J.T @ self.r)
            Gbb, gb = self._base_all
            Gbc, Gcc, gc, _ = self._products(blocks[1])
            G = np.block([[Gbb, Gbc], [Gbc.T, Gcc]])
            g = np.concatenate([gb, gc])
            return self._solve_normal(blocks, G, g)
        X = np.hstack([b.J[rows] for b in blocks]) if blocks else np.zeros((int(rows.sum()), 0))
        if X.shape[1] == 0:
            return np.zeros(0)
        G = X.T @ X
        g = X.T @ self.r[rows]
        return self._solve_normal(blocks, G, g)

    def _solve_normal(self, blocks, G, g):
        """The penalised, scaled, minimum-norm solution of the normal equations G (k, k), g (k,)."""
        off = 0
        for b in blocks:
            if b.pen is not None:
                G[off:off + b.k, off:off + b.k] += b.pen.T @ b.pen
            off += b.k
        s = normal.column_scale(np.diag(G), floor=1e-300)
        Gs = G / s[:, None] / s[None, :]
        # minimum-norm solution of the scaled normal equations (redundant columns stay at 0), at the weaker
        # cut-off EIG_TOL
        z, _, _ = normal.min_norm_solve(Gs, g / s, rtol=EIG_TOL, floor=1e-300, cholesky=False)
        return z / s

    def _base_fold(self, folds, f):
        """The baseline's normal equations on the training rows of fold ``f``, solved once:
        (training rows, pseudo-inverse of the scaled Gram matrix, scale, J^T r)."""
        key = (folds, int(f))
        if key not in self._gram:
            train = ~self._rows(self.folds[folds] == f)
            G, gb = _train_products(self.base.J, self.r, train)
            if self.base.pen is not None:
                G += self.base.pen.T @ self.base.pen
            s = normal.column_scale(np.diag(G), floor=1e-300)
            Ginv = normal.pseudo_inverse(G / s[:, None] / s[None, :], rtol=EIG_TOL, floor=1e-300) / s[:, None] / s[None, :]
            self._gram[key] = (train, Ginv, gb)
        return self._gram[key]

    def _products(self, c):
        """A candidate block's products with the baseline's columns, its own and the residual over every row
        (J_b^T J_c (kb, kc), J_c^T J_c (kc, kc), J_c^T r (kc,)) and its nonzero rows per column (kc,), once."""
        if c._full is None:
            Jc = c.columns()
            c._full = (_tdot(self.base.J, Jc), _tdot(Jc, Jc), _tdot(Jc, self.r), _count_nonzero(Jc))
        return c._full

    def cv(self, blocks, folds: str):
        """Held-out residuals (n, 3) of the model "baseline + blocks" under the fold set ``folds`` ((n, 6) on a
        6-DoF campaign: positions mm, then the orientation's mrad times :attr:`weight`).

        With one extra block the baseline's part is eliminated (Schur complement on the baseline's
        normal equations, solved once per fold), so a candidate costs products with its own columns.
        """
        ids = self.folds[folds]
        out = np.empty_like(self.r)
        if len(blocks) == 1 and self.base.k:
            c = blocks[0]
            Gbc_all, Gcc_all, gc_all, nnz_all = self._products(c)
            Jc = c.columns()
            for f in np.unique(ids):
                train, Ginv, gb = self._base_fold(folds, f)
                test = np.flatnonzero(~train)
                # the training rows' products are all rows' (computed once per candidate, for both fold
                # sets) less the held-out rows' (a fifth): no copy of the training rows (issue 32)
                Jbt, Jct, rt = self.base.J[test], Jc[test], self.r[test]
                Gbc = Gbc_all - _tdot(Jbt, Jct)
                Gcc = Gcc_all - _tdot(Jct, Jct)
                gcr = gc_all - _tdot(Jct, rt)
                # a column the training rows never reach is exactly zero there (not rounding noise)
                unseen = nnz_all == _count_nonzero(Jct)
                if unseen.any():
                    Gbc[:, unseen] = 0.0
                    Gcc[unseen, :] = 0.0
                    Gcc[:, unseen] = 0.0
                    gcr[unseen] = 0.0
                S = Gcc - Gbc.T @ Ginv @ Gbc
                if c.pen is not None:
                    S += c.pen.T @ c.pen
                rhs = gcr - Gbc.T @ (Ginv @ gb)
                # scaled by the candidate's own column norms: a direction of it that the baseline
                # nearly explains (outside fraction below sqrt(EIG_TOL)) is left out, as in a full fit
                own = np.maximum(np.diag(Gcc), 0.0) + (np.sum(c.pen ** 2, axis=0) if c.pen is not None else 0.0)
                sc = normal.column_scale(own, floor=1e-300)
                dc = normal.min_norm_solve(S / sc[:, None] / sc[None, :], rhs / sc, rtol=EIG_TOL, floor=1e-300,
                                           cholesky=False)[0] / sc
                db = Ginv @ (gb - Gbc @ dc)
                out[test] = rt - Jbt @ db - Jct @ dc
            return out.reshape(-1, self.dim)
        blocks = [b for b in (self.base, *blocks) if b.k]
        if not blocks:
            return self.r.reshape(-1, self.dim).copy()
        G_all, g_all, nnz_all, _ = self._gram_of(blocks, None)
        for f in np.unique(ids):
            test = np.flatnonzero(self._rows(ids == f))
            # the training rows' normal equations are every row's (each pair of blocks multiplied once, for
            # every model and fold set that has the pair) less the held-out rows' (each pair once per fold):
            # a re-test given the effects accepted so far multiplies only the new block's pairs
            G_t, g_t, nnz_t, cols = self._gram_of(blocks, (folds, int(f), test))
            G, g = G_all - G_t, g_all - g_t
            # a column the training rows never reach is exactly zero there (not rounding noise)
            unseen = nnz_all == nnz_t
            if unseen.any():
                G[unseen, :] = 0.0
                G[:, unseen] = 0.0
                g[unseen] = 0.0
            delta = self._solve_normal(blocks, G, g)
            pred, off = np.zeros(test.size), 0
            for b, A in zip(blocks, cols):
                pred += A @ delta[off:off + b.k]
                off += b.k
            out[test] = self.r[test] - pred
        return out.reshape(-1, self.dim)

    def _gram_of(self, blocks, fold):
        """J^T J (k, k), J^T r (k,) and each column's nonzero rows (k,) of the blocks' columns side by side,
        over every row (``fold`` None) or over a fold's held-out rows (``fold`` = (fold set, fold, rows)), and the
        blocks' columns on those rows. Each block pair's product is kept (under the blocks' ids, the blocks kept
        with them); the held-out rows' columns are not (a 6-DoF baseline's are a fifth of 43,000 x 800)."""
        tag = None if fold is None else fold[:2]
        rows = None if fold is None else fold[2]
        for b in blocks:
            self._keep[id(b)] = b
        cols = [b.columns() if rows is None else b.columns()[rows] for b in blocks]
        r = self.r if rows is None else self.r[rows]
        sizes = [b.k for b in blocks]
        off = np.concatenate([[0], np.cumsum(sizes)])
        G = np.empty((off[-1], off[-1]))
        g = np.empty(off[-1])
        nnz = np.empty(off[-1], dtype=np.int64)
        for i, (a, A) in enumerate(zip(blocks, cols)):
            key = (tag, id(a))
            if key not in self._pairs:
                self._pairs[key] = (_tdot(A, r), _count_nonzero(A))
            g[off[i]:off[i + 1]], nnz[off[i]:off[i + 1]] = self._pairs[key]
            for j in range(i, len(blocks)):
                key = (tag, id(a), id(blocks[j]))
                if key not in self._pairs:
                    self._pairs[key] = _tdot(A, cols[j])
                G[off[i]:off[i + 1], off[j]:off[j + 1]] = self._pairs[key]
                if j != i:
                    G[off[j]:off[j + 1], off[i]:off[i + 1]] = self._pairs[key].T
        return G, g, nnz, cols

    def fit_all(self, blocks):
        """Coefficients of every block (base first) fitted on all sample poses, and the change
        of the predicted positions (n, 3) each block makes."""
        blocks = [self.base, *blocks]
        rows = np.ones(self.r.size, bool)
        delta = self._solve(blocks, rows)
        parts, off = [], 0
        for b in blocks:
            parts.append(delta[off:off + b.k])
            off += b.k
        contrib = [(b.J @ p).reshape(-1, self.dim)[:, :3] for b, p in zip(blocks, parts)]
        return parts, contrib


def _penalty(robot, effects, n_poses, p):
    """The effects' penalty rows (:func:`pipeline.robot.model.identify.penalty_rows`), None when none."""
    rows, _ = penalty_rows(robot, effects, n_poses, p)
    return rows if len(rows) else None
