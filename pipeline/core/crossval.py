"""Held-out residuals of a cross-validated model: what the encoder and robot fits report
(``cv_rms``) and what diagnosis compares models by."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class CVResult:
    """Held-out residuals of one model.

    Attributes
    ----------
    residuals : ndarray, shape (n, d)
        Held-out residual of every point (d = 1 for an encoder, 3 for a robot), in the
        measurement's unit.
    blocks : ndarray, shape (n,), int
        Independent block of each point (run for an encoder, pose for a robot).
    extra : dict
        What the domain keeps beside the residuals (the encoder: each fold's fitted model).
    """

    residuals: np.ndarray
    blocks: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def rms(self) -> float:
        r = np.asarray(self.residuals, float)
        return float(np.sqrt(np.mean(np.sum(r.reshape(r.shape[0], -1) ** 2, axis=1))))


def fold_ids(n: int, k: int = 5, seed: int = 0) -> np.ndarray:
    """Fold of each of ``n`` poses (n,) int: a seeded permutation cut into ``k`` nearly equal parts (every
    cross-validation by pose: ``jointcal fit``'s, diagnosis's, the weighting's position guard)."""
    perm = np.random.default_rng(seed).permutation(n)
    folds = np.empty(n, int)
    folds[perm] = np.arange(n) % k
    return folds
