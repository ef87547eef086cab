"""A row that cannot be corrected at the elbow or the shoulder singularity says so (issue 53's smaller
points: a singularity is named, not only "the model does not reach the point")."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.correct.robot import singularity
from pipeline.robot.campaign.urdf import robot_from_urdf

URDF = Path(__file__).parent / "data" / "urdf" / "abb_like.urdf"


def test_the_elbow_singularity_is_named():
    """The ABB-like arm (tests/data/urdf/abb_like.urdf: forearm 1590 mm, 200 mm above joint 3's axis) is
    stretched out at joint 3 = -90 + atan(200 / 1590) deg = -82.83 deg: within 2 deg the elbow is named,
    farther away, and on the wrist's own singularity, not."""
    robot, _ = robot_from_urdf(URDF, "link_6")
    stretched = -90.0 + np.rad2deg(np.arctan2(200.0, 1590.0))
    q = np.array([20.0, 10.0, stretched + 0.7, 30.0, 40.0, 10.0])
    words = singularity(robot, q)
    assert words.startswith("the elbow singularity: at joint 3 = ") and "stretched out" in words, words
    assert "0.700 deg off the line" in words, words
    assert singularity(robot, q + [0, 0, 5.0, 0, 0, 0]) == ""
    assert singularity(robot, np.array([20.0, 10.0, stretched + 3.0, 30.0, 0.0, 10.0])).startswith("the wrist")


def test_the_elbow_rule_is_a_spherical_wrists():
    """The elbow rule is for arms whose wrist axes meet (FANUC, KUKA, ABB); a UR10's do not (its singular poses
    are named by the rank rule below)."""
    from conftest import ROOT
    from pipeline.robot.arm.kinematics import load_robot

    robot = load_robot(ROOT / "raw/real/ur10-ipa/robot.toml")
    for q3 in np.linspace(-30.0, 30.0, 13):
        assert not singularity(robot, np.array([0.0, -90.0, q3, -90.0, 45.0, 0.0])).startswith("the elbow")


def test_the_shoulder_singularity_is_named():
    """The ABB-like arm with its wrist point over joint 1's axis (seen on the simulated ABB cell: a program
    target 2.4 mm from it, refused as "the model does not reach the point") is named; 100 mm away, not."""
    import math

    robot, _ = robot_from_urdf(URDF, "link_6")
    # joint 2 leaning forward by t2, the forearm folded back so that the wrist point comes over joint 1's
    # axis: 320 + 1280 sin(t2) + (forearm reach) x = 0 along x, found numerically
    from pipeline.programs import ik

    chain = ik.chain_of(robot)

    def reach(q3):
        return ik.frames(chain, np.deg2rad([[30.0, 29.5, q3, -89.0, -18.0, -14.0]]))[0, 4, 0, 3]

    lo, hi = -170.0, -120.0
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if reach(lo) * reach(mid) > 0 else (lo, mid)
    q = np.array([30.0, 29.5, (lo + hi) / 2, -89.0, -18.0, -14.0])
    words = singularity(robot, q)
    assert words.startswith("the shoulder singularity: the wrist point is 0.0 mm from joint 1's axis"), words
    q3_away = q[2] + math.degrees(100.0 / 1590.0)
    assert singularity(robot, np.array([30.0, 29.5, q3_away, -89.0, -18.0, -14.0])) == ""


def test_a_ur10s_singular_pose_is_named_by_the_rank_its_joints_lose():
    """A UR10's wrist axes do not meet, so neither the wrist (joints 4 and 6 on one line) nor the elbow rule
    applies; yet at joint 5 = 0 with the arm straight up (results/real/C_corrected.csv's first row, refused as
    "does not reach the point ... after 0 iterations") its joints move the flange in fewer than six directions:
    the words say so and name the parallel joints. A pose with every joint away from it: no words."""
    from conftest import ROOT
    from pipeline.robot.arm.kinematics import load_robot

    robot = load_robot(ROOT / "raw/real/ur10-ipa/robot.toml")
    words = singularity(robot, np.array([-180.0, -90.0, 0.0, -90.0, 0.0, 0.0]))
    assert words.startswith("at or near a singular pose: the joints move the flange in only "), words
    assert "joints 2, 3, 4 and 6" in words, words
    assert singularity(robot, np.array([-234.1, -154.4, 97.4, -116.3, 56.9, -3.8])) == ""
