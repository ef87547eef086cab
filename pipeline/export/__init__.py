"""Putting a fitted model on the robot, part 2: exports a robot or its drives take (contract section 8,
``jointcal export``: URDF, Universal Robots' calibration, per-joint compensation tables).

A layer above the robot and encoder models: it uses them and is used only by the command line.
"""
