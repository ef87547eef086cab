"""The robot side (paper 2): any serial arm of 4–7 joints measured with a laser tracker.

By task, lowest layer first: ``arm`` (kinematics, effects) -> ``campaign`` (ingest, importer,
frame, urdf) -> ``model`` (calibrate, lm, chebyshev, estimate, fit, predict ...) -> ``paper``
(chain, mapping, closedloop, evaluate) -> ``cell`` (simulate, measure, execute, stages) -> ``reporting``.
Registers the robot effects (here, and only here).
"""

from ..core.effect import REGISTRY
from .arm.effects import EFFECTS

REGISTRY.register(*EFFECTS)
