"""The robot reports: the paper's robot.pdf (report) and a real robot's report (real_report)."""
