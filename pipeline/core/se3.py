"""Frame maths, one home: rotation vectors, orientation errors and their angles, the rotation angle
between frames, the rigid (Kabsch) fit of point sets and the chordal mean of rotations, and the
arcsec-per-mrad constant.

Each function keeps the arithmetic of the copies it replaces (outputs are compared byte for byte, see
tests/data/make-all.sha256). pinocchio's ``log3`` is the same rotation vector as scipy's
``as_rotvec`` only to rounding (it is not batched and takes another branch near pi), so the rotation
vectors stay scipy's.
"""

from __future__ import annotations

import numpy as np

#: arcsec per mrad as the fit writes it (six digits: the value every fit and its JSON have used)
ARCSEC_PER_MRAD = 206.264806
#: arcsec per rad, exact (180 / pi x 3600)
ARCSEC_PER_RAD = 180.0 / np.pi * 3600.0
#: arcsec per mrad, exact (the uncertainty's propagation keeps every digit)
ARCSEC_PER_MRAD_EXACT = ARCSEC_PER_RAD / 1000.0


def rotation_vectors(R) -> np.ndarray:
    """Rotation vectors (rad) of rotation matrices, shape (n, 3, 3) -> (n, 3)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def orientation_errors(R_pred, R_meas) -> np.ndarray:
    """Orientation error of each pose: the rotation vector (mrad, base frame) of ``R_pred R_meas^T``,
    the turn that takes the measured probe frame onto the predicted one (predicted - measured, as
    positions are), shape (n, 3); its norm is the angle between the two frames.

    Parameters
    ----------
    R_pred, R_meas : ndarray, shape (n, 3, 3)
        Predicted and measured rotations.
    """
    return rotation_vectors(np.einsum("nij,nkj->nik", R_pred, R_meas)) * 1000.0


def angle_arcsec(e_mrad) -> np.ndarray:
    """Angle (arcsec) of orientation errors ``e_mrad`` (n, 3) mrad, shape (n,)."""
    return np.linalg.norm(np.asarray(e_mrad, float), axis=-1) * ARCSEC_PER_MRAD


def rotation_angle(Ra, Rb) -> np.ndarray:
    """Rotation angle (rad) of ``Ra^T Rb``, batched over leading axes: Ra, Rb (..., 3, 3) -> (...)."""
    c = (np.einsum("...ji,...ji->...", Ra, Rb) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def rotation_angle_deg(R) -> float:
    """Angle (deg) of the rotation ``R`` (3, 3) about its axis, in [0, 180] (from its trace)."""
    c = (np.trace(np.asarray(R, float)) - 1.0) / 2.0
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))


def chordal_mean(R) -> np.ndarray:
    """The chordal L2 mean of rotations ``R`` (n, 3, 3): the rotation (3, 3) nearest (Frobenius) their
    arithmetic mean (SVD, the determinant made +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float).mean(axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def kabsch_rotation(H) -> tuple[np.ndarray, np.ndarray]:
    """The proper rotation R (3, 3) taking centred points ``a`` onto centred points ``b`` best, from their
    cross-covariance ``H = a^T b`` (3, 3) (Kabsch: SVD, the determinant's sign fixed), and H's singular
    values (3,) (the second near 0: the points are collinear and R is not determined)."""
    U, S, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    return Vt.T @ D @ U.T, S


def rigid_fit(src, dst, weights=None):
    """Best rigid transform (rotation and translation, no scale) of ``src`` onto ``dst``.

    Minimises ``sum_i w_i |R src_i + t - dst_i|^2`` (Kabsch / Umeyama without scale, SVD with
    the determinant sign fixed so that ``R`` is a proper rotation: :func:`kabsch_rotation`).

    Parameters
    ----------
    src : array_like, shape (n, 3)
        Points to be moved, e.g. mm in the tracker's frame. n >= 3, not all on one line.
    dst : array_like, shape (n, 3)
        Where they should land, same unit, e.g. nominal SMR positions in the base frame (mm).
    weights : array_like, shape (n,), optional
        Non-negative weight of each pair (default all 1).

    Returns
    -------
    R : ndarray, shape (3, 3)
        Rotation, ``det(R) = +1``.
    t : ndarray, shape (3,)
        Translation, unit of the points; ``dst ~= src @ R.T + t``.

    Raises
    ------
    ValueError
        Shapes differ, fewer than 3 pairs, non-finite values, or the points are (nearly)
        collinear so that the rotation is not determined.
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise ValueError(f"rigid_fit needs two (n, 3) arrays of the same shape, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"rigid_fit needs at least 3 point pairs, got {len(src)}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("rigid_fit: non-finite coordinates")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, float)
    if w.shape != (len(src),) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError("rigid_fit: weights must be (n,) finite, non-negative and not all zero")
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    a, b = src - cs, dst - cd
    R, S = kabsch_rotation((a * w[:, None]).T @ b)
    scale = max(S[0], np.finfo(float).tiny)
    if S[1] <= 1e-12 * scale:
        raise ValueError("rigid_fit: the points are (nearly) collinear; the rotation is not determined")
    t = cd - R @ cs
    return R, t
