"""How noisy a robot campaign's measurements are: the floor no model can go below.

Two sources, the first that a campaign has:

* ``repeat`` poses (ISO 9283 runs): the same commanded pose reached from the same direction
  several times; the difference of two such measurements (less what the nominal kinematics
  predicts between the angles read) is the measurement's noise (tracker noise and the robot's
  repeatability together);
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
    from .design import Design

    return Design(robot, [], data).predict(np.zeros(0))


def _pairs_noise(robot, data):
    """(3-D RMS noise of one point, mm; number of pairs) from the pairs of ``data``'s poses within
    NEAR_DEG on every joint and approached from the same directions; None below MIN_PAIRS pairs."""
    from scipy.spatial import cKDTree

    q = np.asarray(data.q_deg, float)
    pairs = np.array(sorted(cKDTree(q).query_pairs(NEAR_DEG, p=np.inf)), dtype=int).reshape(-1, 2)
    if len(pairs):
        pairs = pairs[np.all(np.asarray(data.dir)[pairs[:, 0]] == np.asarray(data.dir)[pairs[:, 1]], axis=1)]
    if len(pairs) < MIN_PAIRS:
        return None
    nom = _nominal(robot, data)
    m = np.asarray(data.measured_mm, float)
    d = (m[pairs[:, 0]] - m[pairs[:, 1]]) - (nom[pairs[:, 0]] - nom[pairs[:, 1]])
    # each difference carries the noise of two measurements
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)) / 2.0)), int(len(pairs))


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
    for data, what in ((repeat, "repeat measurements"), (sample, "near-identical sample poses")):
        if data is None or data.n < 2 or data.measured_mm is None:
            continue
        found = _pairs_noise(robot, data)
        if found is not None:
            rms, n = found
            return {"rms": rms, "n": n, "source": f"{n} pairs of {what} (joint angles within {NEAR_DEG:g} deg, "
                                                  "same directions of approach)"}
    return {"rms": None, "n": 0, "source": "the campaign has no repeat poses and no near-identical sample poses"}
