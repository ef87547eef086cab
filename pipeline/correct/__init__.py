"""Putting a fitted model on the robot, part 1: corrected commands (contract section 8, ``jointcal correct``).

A layer above the robot and encoder models: it uses them and is used only by the command line.
"""
