"""Choosing the poses to measure (contract section 9, ``jointcal plan``).

A layer above the robot models: it shares the fit's identification Jacobian and scaling.
"""
