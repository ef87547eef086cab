"""The corrected program as CSV text (contract section 8): same inputs, same bytes."""

from __future__ import annotations

import io

import numpy as np


def corrected_csv(point_id, res, dirs=None, payload_kg=None, temperature_c=None) -> str:
    """CSV text: ``point_id, q1 … qN`` (deg, 9 decimals: 4e-6 arcsec), ``dq1_arcsec … dqN_arcsec``,
    ``x_mm, y_mm, z_mm`` (nominal kinematics of the corrected commands), ``model_residual_um``,
    ``u95_mm`` (when the model states its uncertainty: the 95 % radius about the model's prediction at
    the commands written, contract section 14),
    ``orientation_held`` (the flange rotation directions kept as the program has them: ``all``,
    ``none``, ``all but about (ux uy uz)``, ``about (hx hy hz) only``, axes in the base frame; '' for
    a row left as given), ``status``, ``reason``, and the conditions the correction assumed (``dir1 … dirN``,
    ``payload_kg``, ``temperature_c``), so that the file can be run (``jointcal simulate measure``).

    Parameters
    ----------
    point_id : ndarray of str, shape (n,)
    res : pipeline.correct.robot.Correction
    """
    import pandas as pd

    n, nj = res.q_deg.shape
    out = pd.DataFrame({"point_id": np.asarray(point_id, str)})
    for j in range(nj):
        out[f"q{j + 1}"] = [f"{v:.9f}" for v in res.q_deg[:, j]]
    for j in range(nj):
        out[f"dq{j + 1}_arcsec"] = [f"{v:.6f}" for v in res.dq_arcsec[:, j]]
    for k, c in enumerate(("x_mm", "y_mm", "z_mm")):
        out[c] = [f"{v:.6f}" for v in res.xyz_mm[:, k]]
    out["model_residual_um"] = [f"{v:.6f}" for v in res.residual_um]
    if getattr(res, "u95_mm", None) is not None:
        out["u95_mm"] = [f"{v:.6f}" for v in res.u95_mm]
    if getattr(res, "u95_arcsec", None) is not None:
        out["u95_arcsec"] = [f"{v:.3f}" for v in res.u95_arcsec]
    if getattr(res, "orientation_held", None) is not None:
        out["orientation_held"] = res.orientation_held
    out["status"] = res.status
    out["reason"] = res.reason
    if dirs is not None:
        for j in range(nj):
            out[f"dir{j + 1}"] = np.asarray(dirs, int)[:, j]
    if payload_kg is not None:
        out["payload_kg"] = [f"{v:g}" for v in payload_kg]
    if temperature_c is not None:
        out["temperature_c"] = [f"{v:g}" for v in temperature_c]
    buf = io.StringIO()
    out.to_csv(buf, index=False, lineterminator="\n")
    return buf.getvalue()
