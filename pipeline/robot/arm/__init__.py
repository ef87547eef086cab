"""The arm itself: its kinematics (robot.toml, pinocchio, any serial arm of 4-7 joints) and the
catalogue of error effects a model is made of; the lowest layer, imports nothing else of the robot."""
