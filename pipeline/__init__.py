"""jointcal: calibration of robot joints and robots.

A model is a list of physical effects (:mod:`pipeline.core.effect`); the two papers
reproduced here are two model specifications in ``specs/``.

Layers (each uses only those below it; ``.importlinter`` holds the contract):

* :mod:`pipeline.cli` - the ``jointcal`` command: reads files, calls the library, writes results;
* :mod:`pipeline.fleet` - the per-unit pipeline over many campaigns, and the fleet's statistics;
* :mod:`pipeline.diagnosis` - which physical effect a model lacks (encoder and robot adapters);
* :mod:`pipeline.encoder` | :mod:`pipeline.robot` - the two domains, independent of each other:
  a joint module (paper 1) and a robot with a laser tracker (paper 2);
* :mod:`pipeline.core` - errors, files, tables, specs, the effect base class and registry, plots.
"""

__version__ = "0.1.0"
