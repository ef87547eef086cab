"""The robot side (paper 2): a six-axis robot measured with a laser tracker.

kinematics (robot.toml, pinocchio) -> ingest / importer -> calibrate (MDH) -> chebyshev (improved
L-M, ``lm``) -> mapping -> closedloop -> evaluate -> report; ``fit`` and ``predict`` for a spec's
whole model; ``simulate`` writes the virtual cell's campaigns. Registers the robot effects (here,
and only here).
"""

from ..core.effect import REGISTRY
from .effects import EFFECTS

REGISTRY.register(*EFFECTS)
