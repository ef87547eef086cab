"""A campaign split by region (issue 52): fit on the poses below a joint's percentile, judge on those above.

A model judged on its own held-out poses is judged where it was fitted: the held-out poses are drawn
from the same joint ranges. Split by region instead, the poses it is judged on lie beyond what it saw
in one joint: how far its effects carry over. :func:`region_split` reassigns a campaign's sets (pure);
:func:`write_region_split` writes the split as an imported campaign (``robot.toml``, ``poses.csv``,
``tracker.csv``, ``campaign.toml``) that ``jointcal fit`` and ``predict`` read as any other: its
held-out error is the error above the split.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from ...core.errors import InputError

#: the percentile of a joint's sample angles below which the split's model is fitted (issue 52: 60)
PERCENTILE = 60.0


def region_split(poses: pd.DataFrame, joint: int, percentile: float = PERCENTILE) -> tuple[pd.DataFrame, float]:
    """A campaign's poses with their sets reassigned by joint ``joint``'s angle.

    The threshold is the ``percentile`` of the joint's angles over the campaign's sample poses. Sample
    poses at or below it stay ``sample`` (fitted); every sample or target pose above it becomes
    ``target`` (judged, never fitted); target poses below it and ``repeat`` poses are left out (they
    would judge the model where it was fitted).

    Parameters
    ----------
    poses : DataFrame
        An imported campaign's ``poses.csv``: ``point_id``, ``set``, ``q1`` .. ``qN`` (deg), and any other
        column (kept as it is).
    joint : int
        1-based joint number.
    percentile : float
        In (0, 100).

    Returns
    -------
    (DataFrame, float)
        The kept poses in their original order with the new ``set``, and the threshold (deg).
    """
    col = f"q{joint}"
    if col not in poses:
        raise ValueError(f"no joint {joint}: the poses have no column {col}")
    if not 0.0 < percentile < 100.0:
        raise ValueError(f"percentile {percentile} is not between 0 and 100")
    q = poses[col].to_numpy(float)
    sample = (poses["set"] == "sample").to_numpy()
    if not sample.any():
        raise ValueError("no sample poses to take the percentile of")
    threshold = float(np.percentile(q[sample], percentile))
    above = q > threshold
    keep = (sample & ~above) | (above & poses["set"].isin(("sample", "target")).to_numpy())
    out = poses[keep].copy()
    out["set"] = np.where(above[keep], "target", "sample")
    return out.reset_index(drop=True), threshold


def write_region_split(campaign, joint: int, out, percentile: float = PERCENTILE) -> dict:
    """Write ``campaign``'s region split (:func:`region_split`) as an imported campaign in ``out``.

    The folder is written whole or not at all (a temporary folder beside it, then renamed).

    Parameters
    ----------
    campaign : path of an imported campaign (``robot.toml``, ``poses.csv``, ``tracker.csv``)
    joint : int, 1-based
    out : path of the folder to write (replaced when it exists)
    percentile : float, in (0, 100)

    Returns
    -------
    dict ``{"joint", "percentile", "threshold_deg", "n_sample", "n_target"}``
    """
    src = Path(campaign)
    for name in ("robot.toml", "poses.csv", "tracker.csv"):
        if not (src / name).exists():
            raise InputError(src / name, "not found: give a campaign jointcal import wrote (--out)")
    poses = pd.read_csv(src / "poses.csv", dtype={"point_id": str}, keep_default_na=False)
    try:
        split, threshold = region_split(poses, joint, percentile)
    except ValueError as exc:
        raise InputError(src / "poses.csv", str(exc), 1) from None
    n_sample = int((split["set"] == "sample").sum())
    n_target = int((split["set"] == "target").sum())
    if not n_sample or not n_target:
        raise InputError(src / "poses.csv", f"joint {joint}'s {percentile:g}th percentile leaves {n_sample} sample "
                                            f"and {n_target} target poses: nothing to fit or nothing to judge", 1)
    tracker = pd.read_csv(src / "tracker.csv", dtype={"point_id": str}, keep_default_na=False)
    tracker = tracker[tracker["point_id"].isin(set(split["point_id"]))]
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        shutil.copy(src / "robot.toml", tmp / "robot.toml")
        head = (f"# Region split of {src} (jointcal robot region-split): sample = its sample poses with q{joint} <= "
                f"{threshold:.6f} deg (the {percentile:g}th percentile of its sample poses), target = every pose above.\n")
        body = (src / "campaign.toml").read_text(encoding="utf-8") if (src / "campaign.toml").exists() else ""
        (tmp / "campaign.toml").write_text(head + body, encoding="utf-8")
        # the original text of each kept row, in order (no number is re-printed)
        for name, frame in (("poses.csv", split), ("tracker.csv", tracker)):
            lines = (src / name).read_text(encoding="utf-8").splitlines()
            header, rows = lines[0], lines[1:]
            at = header.split(",").index("point_id")
            by_id = {r.split(",")[at]: r for r in rows if r.strip()}
            sets = dict(zip(frame["point_id"], frame["set"])) if name == "poses.csv" else None
            kept = []
            for pid in frame["point_id"]:
                row = by_id[pid]
                if sets is not None:
                    f = row.split(",")
                    f[header.split(",").index("set")] = sets[pid]
                    row = ",".join(f)
                kept.append(row)
            (tmp / name).write_text("\n".join([header, *kept]) + "\n", encoding="utf-8")
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o777 & ~mask)       # mkdtemp makes 0700; a campaign is an ordinary folder
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(tmp)
        raise
    return {"joint": joint, "percentile": percentile, "threshold_deg": threshold, "n_sample": n_sample,
            "n_target": n_target}
