"""The effect Jacobian: an error model's configurations, predictions and Jacobians on one data set.

:class:`Design` holds the effects' channels on the poses of a data set (each parameter's entries: which
configuration channel it moves, by how much at each pose, without the zeros) and evaluates the residual
of a fit and its Jacobian, dense or sparse (CSC, laid out once per design: :func:`pose_csc_structure`,
:func:`pose6_csc_structure`).
"""

from __future__ import annotations

import numpy as np

from ...core.se3 import orientation_errors
from ..arm.effects import RobotData, RobotEffect
from ..arm.kinematics import (Robot, build_error_model, placements, pose_jacobians, positions,
                              positions_and_jacobians)


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
        mounting = getattr(data, "mounting_offset", None)
        if mounting is not None:
            # poses of a campaign with a probe mounting of its own (pipeline.robot.model.campaigns)
            self.Q0[:, self.idx.tool] = mounting[:, :3]
            self.Q0[:, self.idx.tool_rot] = mounting[:, 3:]
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
        # near its knot): entry e's poses are rows[ptr[e]:ptr[e + 1]] (increasing), its values vals[...]
        # (why not dense: docs/speed.md, "The fitting core's measurements")
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
        baseline's fixed parameters need no column)."""
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
            self._coo = pose_csc_structure(ii, self.p_idx[ee], self.data.n, self.p)
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
            self._coo6 = pose6_csc_structure(ii, self.p_idx[ee], n, self.p)
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
    run of one (key, column) starts, the sorted keys and columns (a stable sort, radix on small column
    numbers, when the keys already increase in entry order)."""
    keys, cols = np.asarray(keys, np.int64), np.asarray(cols, np.int64)
    order = np.argsort(cols.astype(np.int16) if p < 2 ** 15 else cols, kind="stable")
    k, c = keys[order], cols[order]
    if np.any((k[1:] < k[:-1]) & (c[1:] == c[:-1])):
        order = np.lexsort((keys, cols))
        k, c = keys[order], cols[order]
    new = np.ones(k.size, bool)
    new[1:] = (k[1:] != k[:-1]) | (c[1:] != c[:-1])
    return order, np.flatnonzero(new), k, c


def csc_structure(rows, cols, m, p):
    """The CSC layout of a sparse matrix (m, p) whose entries (``rows``, ``cols``) keep their places from call
    to call (a design's Jacobian): the order taking the entries to it, where each stored value starts
    (None: no duplicates; duplicates are summed), its row indices and column pointers (built once, not by
    a COO conversion each iteration)."""
    order, start, r, c = _by_column(rows, cols, p)
    indptr = np.searchsorted(c[start], np.arange(p + 1)).astype(np.int64)
    return order, (start if start.size < r.size else None), r[start].astype(np.int32), indptr, (m, p)


def pose_csc_structure(ii, cols, n, p):
    """The CSC layout of a positions' Jacobian (3 n, p) whose nonzeros t (pose ``ii[t]``, column ``cols[t]``,
    pose-major) each fill the rows 3 ii + 0, 1, 2: the order taking the nonzeros to it (by column, poses
    increasing), where each run of nonzeros of one (pose, column) starts (None: no run longer than one),
    row indices and column pointers. Sorted as nonzeros, not as rows (a third of the work)."""
    order, first, i, c = _by_column(ii, cols, p)
    rows = (3 * i[first][:, None] + np.arange(3)).ravel().astype(np.int32)
    indptr = 3 * np.searchsorted(c[first], np.arange(p + 1)).astype(np.int64)
    return order, (first if first.size < i.size else None), rows, indptr, (3 * n, p)


def pose6_csc_structure(ii, cols, n, p):
    """The :func:`csc_structure` of a 6-DoF Jacobian (6 n, p) whose nonzeros t (pose ``ii[t]``, column
    ``cols[t]``, pose-major) each fill the rows 3 ii + 0, 1, 2 (positions) and 3 n + 3 ii + 0, 1, 2 (turns),
    the values laid out as ``[vals[:, :3].ravel(), vals[:, 3:].ravel()]``: the same layout, sorted as
    nonzeros rather than as its six times as many entries, also where a (pose, column) has several
    nonzeros (a run, summed: the loop's designs). Its measured cost: docs/speed.md."""
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
    # run, x y z), then the same runs' turns; placed there directly (not sorted again)
    pos_start = ((6 * ptr[c[f]] + 3 * lo[f])[:, None] + a * length[f][:, None]).ravel()
    at = (3 * uptr[c[f]] + 3 * np.arange(f.size))[:, None] + a
    start = np.empty(2 * pos_start.size, np.int64)
    start[at.ravel()] = pos_start
    start[(at + 3 * (uptr[c[f] + 1] - uptr[c[f]])[:, None]).ravel()] = pos_start + 3 * np.repeat(m[f], 3)
    return perm, start, rows[start], 6 * uptr, (6 * n, p)


def _pose_csc(vals, structure):
    """The sparse matrix (CSC) of the nonzeros' values ``vals`` (nnz, 3) on a :func:`pose_csc_structure`
    (a run of one (pose, column) summed in order)."""
    import scipy.sparse

    order, first, rows, indptr, shape = structure
    v = vals[order]
    if first is not None:
        v = np.add.reduceat(v, first, axis=0)
    return scipy.sparse.csc_matrix((v.ravel(), rows, indptr), shape=shape)


def _csc(values, structure):
    """The sparse matrix (CSC) of ``values`` (in the entries' order) on a :func:`csc_structure`."""
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
