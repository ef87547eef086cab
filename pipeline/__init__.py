"""jointcal: calibration of robot joints and robots.

A model is a list of physical effects (:mod:`pipeline.effects`); the two papers
reproduced here are two model specifications in ``specs/``.
"""

__version__ = "0.1.0"
