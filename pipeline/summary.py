"""``results/summary.json`` (contract section 5) from the stages' results."""

from __future__ import annotations


def build_summary(encoder_models: dict, robot: dict | None, real: dict | None = None) -> dict:
    """Assemble the summary.

    Parameters
    ----------
    encoder_models : dict module -> model result (``jointcal fit`` JSON)
    robot : dict or None
        ``results/robot/table2.json``: ``before``, ``kinematic``, ``feedback`` statistics
        (min/max/mean/std in mm) and ``max_reduction_pct``.
    """
    out = {"encoder": {}}
    for module in sorted(encoder_models):
        m = encoder_models[module]
        out["encoder"][module] = {"orders": sorted(m["orders"]), "p2p_before_arcsec": m["p2p_before_arcsec"],
                                  "p2p_after_arcsec": m["p2p_after_arcsec"], "reduction_pct": m["reduction_pct"]}
    if robot is not None:
        keys = ("min_mm", "max_mm", "mean_mm", "std_mm")
        out["robot"] = {stage: {k: robot[stage][k] for k in keys} for stage in ("before", "kinematic", "feedback")}
        out["robot"]["max_reduction_pct"] = robot["max_reduction_pct"]
        for extra in ("beyond_paper",):
            if extra in robot:
                out["robot"][extra] = robot[extra]
    if real is not None:
        out["real"] = {"ur10-ipa": real}
    return out
