"""Stage ``compensate``: compensation table and correction of readings.

The joint reads true angle + error(true angle). A corrected angle is
``reading - error(theta)``; since the error is arcseconds, evaluating it at the reading
instead of the (unknown) true angle changes it by less than error * d(error)/d(theta),
far below a milliarcsecond for these models; one fixed-point step removes even that.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .effects import ARCSEC_PER_DEG


def compensation_table(model, step_deg: float = 0.1) -> pd.DataFrame:
    """Error and correction on a grid of joint angles.

    Parameters
    ----------
    model : EncoderModel
        Fitted model (harmonic terms and constant).
    step_deg : float, deg
        Grid step; 360 must be a whole number of steps.

    Returns
    -------
    DataFrame with ``theta_deg`` (deg), ``error_arcsec`` and ``correction_arcsec`` (= -error).
    """
    n = 360.0 / step_deg
    if step_deg <= 0 or abs(n - round(n)) > 1e-9:
        raise ValueError(f"step {step_deg} deg does not divide 360 deg into whole steps")
    theta = np.arange(int(round(n))) * step_deg
    err = model.predict_theta(theta)
    return pd.DataFrame({"theta_deg": theta, "error_arcsec": err, "correction_arcsec": -err})


def correct_readings(model, reading_deg) -> tuple[np.ndarray, np.ndarray]:
    """Corrected angles (deg) and the applied correction (arcsec) for raw joint readings (deg)."""
    reading = np.asarray(reading_deg, float)
    theta = np.mod(reading, 360.0)
    err = model.predict_theta(theta)
    err = model.predict_theta(np.mod(reading - err / ARCSEC_PER_DEG, 360.0))  # one fixed-point step
    return reading - err / ARCSEC_PER_DEG, -err
