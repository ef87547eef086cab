"""How noisy a robot campaign's measurements are: the floor no model can go below.

Two sources, the first that a campaign has:

* ``repeat`` poses (ISO 9283 runs): the same commanded pose reached from the same direction
  several times; the scatter of the measured points about their mean is the measurement's noise
  (tracker noise and the robot's repeatability together);
* near-identical sample poses: pairs whose joint angles differ by at most :data:`NEAR_DEG` on
  every joint (and approached from the same directions); the difference of their measured points
  less the difference the nominal kinematics predicts is the noise of two measurements.

Used by diagnosis to say "the model explains the data down to their noise" only when it does.
"""

from __future__ import annotations

import numpy as np

#: Two poses are "near-identical" when every joint angle differs by at most this (deg): at a 1 m
#: lever arm 0.01 deg moves the point 0.17 mm, of which the nominal kinematics predicts all but a
#: model error's slope times it (a few micrometres).
NEAR_DEG = 0.01
#: Fewest repeated pairs (or repeat degrees of freedom) for an estimate.
MIN_PAIRS = 3


def _nominal(robot, data):
    from .calibrate import Design

    return Design(robot, [], data).predict(np.zeros(0))


def noise_estimate(robot, sample, repeat=None) -> dict:
    """The measurement noise as the 3-D RMS of one point's error (mm).

    Parameters
    ----------
    robot : Robot
    sample : RobotData
        Sample poses (joint angles q_deg (n, N) deg, measured_mm (n, 3) mm).
    repeat : RobotData, optional
        The campaign's ``repeat`` poses.

    Returns
    -------
    dict: ``rms`` (mm, or None when the campaign has neither source), ``n`` (repeated measurements
    or pairs used) and ``source`` (in words).
    """
    if repeat is not None and repeat.n >= 2 and repeat.measured_mm is not None:
        key = np.hstack([np.round(np.asarray(repeat.q_deg, float), 6), np.asarray(repeat.dir, float)])
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        inv = np.asarray(inv).reshape(-1)
        x = np.asarray(repeat.measured_mm, float)
        dof = int(np.sum(counts - 1))
        if dof >= MIN_PAIRS:
            means = np.zeros((counts.size, 3))
            np.add.at(means, inv, x)
            means /= counts[:, None]
            ss = float(np.sum((x - means[inv]) ** 2))
            return {"rms": float(np.sqrt(ss / dof)), "n": int(repeat.n),
                    "source": f"scatter of {repeat.n} repeat measurements of {int(np.sum(counts > 1))} poses"}
    if sample is not None and sample.n >= 2 and sample.measured_mm is not None:
        from scipy.spatial import cKDTree

        q = np.asarray(sample.q_deg, float)
        pairs = np.array(sorted(cKDTree(q).query_pairs(NEAR_DEG, p=np.inf)), dtype=int).reshape(-1, 2)
        if len(pairs):
            same = np.all(np.asarray(sample.dir)[pairs[:, 0]] == np.asarray(sample.dir)[pairs[:, 1]], axis=1)
            pairs = pairs[same]
        if len(pairs) >= MIN_PAIRS:
            nom = _nominal(robot, sample)
            m = np.asarray(sample.measured_mm, float)
            d = (m[pairs[:, 0]] - m[pairs[:, 1]]) - (nom[pairs[:, 0]] - nom[pairs[:, 1]])
            return {"rms": float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)) / 2.0)), "n": int(len(pairs)),
                    "source": f"{len(pairs)} pairs of near-identical sample poses (within {NEAR_DEG:g} deg)"}
    return {"rms": None, "n": 0, "source": "the campaign has no repeat poses and no near-identical sample poses"}
