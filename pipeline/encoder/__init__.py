"""The encoder side (paper 1): one joint module measured against a polygon and an autocollimator.

ingest -> harmonic -> aliasing -> selection -> model / evaluate -> compensate -> report;
``simulate`` writes the synthetic campaigns. Registers the encoder effects (here, and only here).
"""

from ..core.effect import REGISTRY
from .effects import EFFECTS

REGISTRY.register(*EFFECTS)
