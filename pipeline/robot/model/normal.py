"""Column-scaled normal equations, one home: how a step, a fold's solution or a pseudo-inverse is solved.

A normal-equations matrix ``A`` (k, k) (``J^T J`` plus any penalty rows' ``P^T P``) is scaled to a unit
diagonal (:func:`column_scale`) and solved

* by its Cholesky factor where it is well-conditioned (:func:`well_conditioned_cholesky`,
  :data:`CHOLESKY_RCOND`): every direction is kept, as the eigen-solution would keep it;
* otherwise in its eigen-directions, those below ``rtol`` of the largest left out: the minimum-norm
  solution (:func:`eigen_directions`, :func:`min_norm_solve`, :func:`pseudo_inverse`), or, for a
  damped Gauss-Newton step, in its singular directions (:func:`singular_directions`).

The cut-offs are named arguments: the fit's steps leave out eigenvalues below :data:`EIGEN_RTOL` of
the largest, its damped loop singular values below :data:`SINGULAR_RTOL` of the largest, and the
diagnosis's linear candidates (:mod:`pipeline.diagnosis.linear`) eigenvalues below its weaker
``EIG_TOL`` (``WEAK_TOL ** 2``). The scaling's floor is a named argument too (``floor``).

The normal equations of a sparse Jacobian (:func:`gram`) and the singular values of a tall one by blocks
of rows (:func:`scaled_svd`) are here too, with the sizes beyond which a fit uses them
(:data:`GRAM_MIN_K`, :data:`DENSE_SVD_MAX`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

#: A column-scaled normal-equations matrix whose reciprocal condition number (LAPACK's 1-norm estimate after
#: its Cholesky factor) is above this is solved by that factor: its eigenvalues then all lie far above the
#: 1e-12 of the largest below which an eigen-solution leaves a direction out, and both give the same step.
CHOLESKY_RCOND = 1e-7
#: Eigenvalues of a scaled normal-equations matrix below this fraction of the largest are left out of the
#: fit's minimum-norm steps (rounding: 1e-12 in eigenvalues is 1e-6 in singular values)
EIGEN_RTOL = 1e-12
#: Singular values (square roots of the eigenvalues) below this fraction of the largest are left out of the
#: damped Gauss-Newton loop's steps (the dense SVD's cut-off, kept for the normal equations' loop alike)
SINGULAR_RTOL = 1e-12
#: A fit with more directions to solve for than this (a joint map's grid values) is solved on its
#: normal equations, built from the sparse Jacobian (:func:`gram`), and its unseen directions found
#: from them (:func:`~pipeline.robot.model.identify.physical_subspace` with ``gram``): the dense SVD of a
#: (3 n) x k Jacobian each iteration was most of a large fit's time (docs/speed.md). Smaller fits
#: (geometry, base, tool, compliance, backlash: at most a few dozen directions) keep the dense SVD.
GRAM_MIN_K = 64
#: A fit in the leading singular directions (``reduction="svd"``) whose Jacobian has more entries than this
#: (64 MB) is iterated on its normal equations too (docs/speed.md); smaller ones (the paper's KR210 stage)
#: keep the dense SVD. Read at call time as ``normal.DENSE_SVD_MAX`` (tests lower it).
DENSE_SVD_MAX = 8_000_000


def column_scale(diag, floor: float | None = None) -> np.ndarray:
    """The column scale (k,) of a normal-equations matrix of diagonal ``diag`` (k,): ``sqrt(diag)``, a zero
    (or negative) diagonal scaled by 1 (``floor`` None), or ``sqrt(max(diag, floor))``."""
    if floor is not None:
        return np.sqrt(np.maximum(diag, floor))
    sc = np.sqrt(np.maximum(diag, 0.0))
    return np.where(sc > 0, sc, 1.0)


def well_conditioned_cholesky(As, rcond: float = CHOLESKY_RCOND):
    """The Cholesky factor of the symmetric matrix ``As`` (k, k) (as ``scipy.linalg.cho_factor`` gives it)
    where it is positive definite with a reciprocal condition number above ``rcond``; else None
    (a rank-deficient or nearly singular matrix: solved in its eigen-directions)."""
    from scipy.linalg import lapack

    if As.shape[0] == 0 or not np.all(np.isfinite(As)):
        return None
    try:
        factor = scipy.linalg.cho_factor(As, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    rc, info = lapack.dpocon(factor[0], float(np.abs(As).sum(axis=0).max()), uplo="L")
    return factor if info == 0 and rc > rcond else None


def cholesky_solve(factor, b) -> np.ndarray:
    """The solution of ``A y = b`` (b (k,) or (k, m)) by a Cholesky ``factor`` of A (``scipy.linalg.cho_factor``'s)."""
    return scipy.linalg.cho_solve(factor, b, check_finite=False)


def damped_cholesky(As, lam: float):
    """The Cholesky factor (lower) of the damped ``As + lam I`` (k, k): a Levenberg step of the fit's loop."""
    return scipy.linalg.cho_factor(As + lam * np.eye(As.shape[0]), lower=True, check_finite=False)


def levenberg_cholesky(A0, mu: float):
    """The Cholesky factor (scipy's default, upper) of ``A0 + mu I`` (k, k), the diagonal raised in place of a
    copy: the improved L-M's matrix, factorised once for its three steps (:mod:`pipeline.robot.model.lm`)."""
    A = A0.copy()
    A[np.diag_indices_from(A)] += mu
    return scipy.linalg.cho_factor(A, check_finite=False)


def largest_eigenvalue(As) -> float:
    """The largest eigenvalue of the symmetric matrix ``As`` (k, k)."""
    return float(scipy.linalg.eigh(As, eigvals_only=True, subset_by_index=[As.shape[0] - 1] * 2, check_finite=False)[0])


def eigen_directions(As, rtol: float = EIGEN_RTOL, floor: float = 0.0):
    """The eigenvalues (r,) and eigenvectors (k, r) of the symmetric ``As`` (k, k) kept: those above ``rtol``
    times the largest (or times ``floor``, if larger)."""
    ev, V = np.linalg.eigh(As)
    use = ev > rtol * max(float(ev[-1]), floor) if ev.size else np.zeros(0, bool)
    return ev[use], V[:, use]


def min_norm_solve(As, bs, rtol: float = EIGEN_RTOL, floor: float = 0.0, cholesky: bool = True) -> tuple:
    """The minimum-norm solution y (k,) of the scaled normal equations ``As y = bs``, its gain ``bs^T y``
    and the number of directions kept: by the Cholesky factor where well-conditioned (``cholesky``), else
    in the eigen-directions above ``rtol`` (:func:`eigen_directions`)."""
    factor = well_conditioned_cholesky(As) if cholesky else None
    if factor is not None:
        y = cholesky_solve(factor, bs)
        return y, float(bs @ y), int(As.shape[0])
    ev, V = eigen_directions(As, rtol, floor)
    t = V.T @ bs
    return V @ (t / ev), float(t @ (t / ev)), int(ev.size)


def pseudo_inverse(As, rtol: float = EIGEN_RTOL, floor: float = 0.0) -> np.ndarray:
    """The pseudo-inverse (k, k) of the symmetric ``As`` (k, k) in its eigen-directions above ``rtol``."""
    ev, V = eigen_directions(As, rtol, floor)
    return (V / ev) @ V.T


def singular_directions(As, rtol: float | None = SINGULAR_RTOL):
    """The singular values (r,) and right singular vectors Vt (r, k) of a column-scaled Jacobian from its
    normal equations ``As`` (k, k) (largest first), those at or below ``rtol`` times the largest left out
    (``rtol`` None: all k)."""
    w, V = np.linalg.eigh(As)
    sv, Vt = np.sqrt(np.maximum(w[::-1], 0.0)), V[:, ::-1].T
    if rtol is None:
        return sv, Vt
    r = int(np.sum(sv > rtol * sv[0])) if sv.size else 0
    return sv[:r], Vt[:r]


def scaled_min_norm_step(A, b, with_rank: bool = False) -> tuple:
    """The minimum-norm solution dz of the normal equations ``A dz = -b`` (A (k, k) symmetric positive
    semi-definite, b (k,)), solved column-scaled by its eigen-directions, those below :data:`EIGEN_RTOL` of
    the largest left out (by its Cholesky factor where every direction is kept: :func:`well_conditioned_cholesky`);
    and the step's gain ``b^T A^+ b``, the change ``||dF||^2`` the linear model predicts (and, ``with_rank``,
    the number of directions kept)."""
    sc = column_scale(np.diag(A))
    y, gain, rank = min_norm_solve(A / np.outer(sc, sc), b / sc)
    return (-y / sc, gain, rank) if with_rank else (-y / sc, gain)


def scaled_svd(J, norms, zero=None) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (k,) and right singular vectors Vt (k, p) of J (m, p; dense or sparse) with its columns
    divided by ``norms`` (p,) and the ``zero`` (p,) ones set to 0, without the left ones (m, k): the SVD of the
    triangular factor R of a QR (blocked LAPACK), the U of a large 6-DoF campaign's J being far larger than J.

    R is built from row blocks of at most :data:`DENSE_SVD_MAX` entries: each block's rows below the R so
    far are factored together (a tall-skinny QR), so no copy of the whole J is made. A J of one block (every
    fixture) is factored in one QR."""
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
        qr, _, _, _ = dgeqrf(A, lwork=max(1, 64 * p), overwrite_a=1)   # with a work size: blocked LAPACK
        R = np.triu(qr[:min(A.shape[0], p)])
        del A, qr, blk
    _, sv, Vt = np.linalg.svd(R, full_matrices=False)
    return sv, Vt


def gram(J, r=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``J^T J`` (p, p) and ``J^T r`` (p,) of a sparse Jacobian J (3 n, p) and residual r (3 n,), its dense
    columns (the kinematic parameters: every pose) by BLAS and its sparse ones (joint-map values) sparse."""
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
