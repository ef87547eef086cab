"""Evaluation of the robot stages (the second paper's Section 3, Table 2, Figures 6-11).

* ``before``: the campaign's target points as measured with the nominal commands.
* ``kinematic``: open loop with commands from the calibrated MDH model (inverse correction
  so that the calibrated model reaches the nominal pose of the target).
* ``feedback``: Chebyshev model + joint mapping (Eqs. 22-24) + grating closed loop on
  joints 1-3 (Eq. 26); joints 4-6 stay open loop and keep their backlash.

The commands are executed by the virtual cell (rebuilt from its seed, never from the truth
file) or, for a real robot, measured again and passed as a tracker file whose point_ids
are ``<point_id>@kinematic`` / ``<point_id>@feedback`` (targets) and
``<point_id>@feedback`` (repeat rows, closed loop).

ISO 9283 multi-directional pose accuracy variation at each pose P_j:
``vAP = max over approach pairs (h, k) of || barycentre_h - barycentre_k ||`` (mm).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..model.estimate import error_stats


PAPER_TABLE2 = {"before": {"min_mm": 0.10, "max_mm": 0.76, "mean_mm": 0.42, "std_mm": 0.16},
                "kinematic": {"min_mm": 0.03, "max_mm": 0.42, "mean_mm": 0.24, "std_mm": 0.08},
                "feedback": {"min_mm": 0.03, "max_mm": 0.19, "mean_mm": 0.10, "std_mm": 0.04},
                "max_reduction_pct": 75.0}


def table2(before, kinematic, feedback) -> dict:
    out = {"before": error_stats(before), "kinematic": error_stats(kinematic), "feedback": error_stats(feedback)}
    out["max_reduction_pct"] = 100.0 * (1.0 - out["feedback"]["max_mm"] / out["before"]["max_mm"])
    out["max_reduction_vs_kinematic_pct"] = 100.0 * (1.0 - out["feedback"]["max_mm"] / out["kinematic"]["max_mm"])
    out["paper"] = PAPER_TABLE2
    return out


def vap(labels_pose, labels_approach, xyz_mm) -> dict:
    """ISO 9283 multi-directional pose accuracy variation per pose (mm) and repeatability RP."""
    df = pd.DataFrame({"pose": labels_pose, "approach": labels_approach})
    xyz = np.asarray(xyz_mm, float)
    out = {}
    for pose, g in df.groupby("pose", sort=True):
        bary, rp = {}, {}
        for a, h in g.groupby("approach", sort=True):
            p = xyz[h.index.to_numpy()]
            c = p.mean(axis=0)
            bary[a] = c
            d = np.linalg.norm(p - c, axis=1)
            rp[a] = float(d.mean() + 3 * d.std(ddof=1)) if len(d) > 1 else 0.0
        keys = sorted(bary)
        v = max((np.linalg.norm(bary[a] - bary[b]) for i, a in enumerate(keys) for b in keys[i + 1:]), default=0.0)
        out[pose] = {"vAP_mm": float(v), "RP_mm": rp, "barycentres_mm": {k: bary[k].tolist() for k in keys}}
    return out
