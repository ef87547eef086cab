"""Frame maths, one home: rotation vectors, orientation errors and their angles, the rotation angle
between frames, the rigid (Kabsch) fit of point sets and the chordal mean of rotations.

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


def chordal_mean(R) -> np.ndarray:
    """The chordal L2 mean of rotations ``R`` (n, 3, 3): the rotation (3, 3) nearest their arithmetic
    mean (SVD, the determinant made +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(R).mean(axis=0))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
