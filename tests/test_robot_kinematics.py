"""pinocchio kinematics against a plain numpy implementation of Eq. 2 and finite differences."""

import numpy as np
import pytest

from conftest import ROOT

from pipeline.robot.arm.kinematics import (build_error_model, build_model, gravity_torques, load_robot, parse_robot,
                            positions, positions_and_jacobians)

KR210 = "raw/robot/kr210/robot.toml"


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _T(R=np.eye(3), p=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def fk_numpy(robot, q_deg):
    """Eq. 2: T_i = Rz(q_i + off_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i); SMR = T_1..T_6 [tool, 1] (mm)."""
    T = np.eye(4)
    for q, j in zip(q_deg, robot.joints):
        T = T @ _T(_rot("z", np.deg2rad(q + j.theta_offset_deg))) @ _T(p=(0, 0, j.d_mm)) @ _T(p=(j.a_mm, 0, 0)) \
            @ _T(_rot("x", np.deg2rad(j.alpha_deg))) @ _T(_rot("y", np.deg2rad(j.beta_deg)))
    return (T @ np.r_[robot.tool_xyz_mm, 1.0])[:3]


def random_robot_toml(rng):
    lines = ['name = "random"', "", "[tool]", f"xyz_mm = [{', '.join(f'{v:.3f}' for v in rng.uniform(-150, 150, 3))}]"]
    for _ in range(6):
        lo = rng.uniform(-150, 0)
        lines += ["", "[[joint]]", f"a_mm = {rng.uniform(-600, 600):.3f}", f"alpha_deg = {rng.choice([-90, 0, 90]) + rng.uniform(-3, 3):.3f}",
                  f"d_mm = {rng.uniform(-400, 800):.3f}", f"theta_offset_deg = {rng.uniform(-180, 180):.3f}",
                  f"beta_deg = {rng.uniform(-2, 2):.3f}", f"lower_deg = {lo:.3f}", f"upper_deg = {lo + rng.uniform(20, 200):.3f}",
                  f"mass_kg = {rng.uniform(5, 200):.3f}",
                  f"com_mm = [{', '.join(f'{v:.3f}' for v in rng.uniform(-200, 200, 3))}]"]
    return "\n".join(lines) + "\n"


def robots():
    rng = np.random.default_rng(7)
    return [load_robot(KR210), parse_robot(random_robot_toml(rng), "random1.toml"),
            parse_robot(random_robot_toml(rng), "random2.toml")]


@pytest.mark.parametrize("robot", robots(), ids=["kr210", "random1", "random2"])
def test_fk_matches_eq2(robot):
    rng = np.random.default_rng(1)
    Q = rng.uniform(robot.lower_deg, robot.upper_deg, (20, 6))
    P = positions(build_model(robot), np.deg2rad(Q))
    ref = np.array([fk_numpy(robot, q) for q in Q])
    assert np.abs(P - ref).max() < 1e-8


@pytest.mark.parametrize("robot", robots(), ids=["kr210", "random1", "random2"])
def test_error_model_at_zero_is_the_arm_and_jacobian_matches_finite_differences(robot):
    model, idx = build_error_model(robot)
    rng = np.random.default_rng(2)
    Q = np.zeros((5, idx.nq))
    Q[:, idx.joints] = np.deg2rad(rng.uniform(robot.lower_deg, robot.upper_deg, (5, 6)))
    Q[:, idx.links.ravel()] = rng.normal(0, 1e-3, (5, 36))   # small error twists (m, rad)
    P, J = positions_and_jacobians(model, Q)
    Q0 = Q.copy()
    Q0[:, idx.links.ravel()] = 0
    ref = np.array([fk_numpy(robot, np.rad2deg(q[idx.joints])) for q in Q0])
    assert np.abs(positions(model, Q0) - ref).max() < 1e-8
    h = 1e-7
    for k in range(idx.nq):
        dq = np.zeros(idx.nq)
        dq[k] = h
        fd = (positions(model, Q + dq) - positions(model, Q - dq)) / (2 * h)
        assert np.abs(fd - J[:, :, k]).max() < 1e-4 * max(1.0, np.abs(J[:, :, k]).max())


def test_gravity_torque_matches_finite_difference_of_potential_energy():
    robot = load_robot(KR210)
    model = build_model(robot)
    import pinocchio as pin

    data = model.createData()
    q = np.deg2rad((robot.lower_deg + robot.upper_deg) / 2 + 3.0)
    tau = gravity_torques(robot, np.rad2deg(q)[None], 0.0, model)[0]

    def potential(qq):
        return pin.computePotentialEnergy(model, data, qq)

    h = 1e-6
    fd = np.array([(potential(q + h * e) - potential(q - h * e)) / (2 * h) for e in np.eye(6)])
    assert np.allclose(tau, fd, atol=1e-3 * np.abs(tau).max())
    # payload at the SMR adds m g dz/dq
    tau_p = gravity_torques(robot, np.rad2deg(q)[None], 100.0, model)[0]
    J = positions_and_jacobians(model, q[None])[1][0] / 1000.0
    assert np.allclose(tau_p - tau, 100.0 * 9.81 * J[2], atol=1e-6 * np.abs(tau_p).max())


def test_batched_kinematics_are_pinocchios():
    """Issue 32: the error model's placements and frame Jacobians (3 rows, and 6 for a 6-DoF probe), computed
    for every pose at once (kinematics.batch_placements, what positions(), placements(),
    positions_and_jacobians() and pose_jacobians() use), equal
    pinocchio's own forwardKinematics / getFrameJacobian(LOCAL_WORLD_ALIGNED) to rounding, for every
    error joint moved (arm, link, base and tool errors) on a 6- and a 7-joint arm."""
    import pinocchio as pin

    from pipeline.robot.arm.kinematics import batch_placements, build_error_model, load_robot

    for path in (ROOT / "raw" / "robot" / "kr210" / "robot.toml", ROOT / "raw" / "real" / "ur10-ipa" / "robot.toml",
                 ROOT / "raw" / "arms" / "panda.toml"):
        robot = load_robot(path)
        model, idx = build_error_model(robot)
        rng = np.random.default_rng(3)
        Q = rng.normal(0.0, 2e-3, (40, model.nq))
        Q[:, idx.joints] = rng.uniform(-3.0, 3.0, (40, idx.joints.size))
        for frame in ("smr", "flange"):
            R, p, J = batch_placements(model, Q, frame, jacobian=True)
            data, fid = model.createData(), model.getFrameId(frame)
            for k, q in enumerate(Q):
                pin.computeJointJacobians(model, data, q)
                M = pin.updateFramePlacement(model, data, fid)
                np.testing.assert_allclose(p[k], M.translation, rtol=0, atol=1e-13)
                np.testing.assert_allclose(R[k], M.rotation, rtol=0, atol=1e-13)
                np.testing.assert_allclose(J[k], pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3],
                                           rtol=0, atol=1e-13)
            # the 6-row Jacobian of a 6-DoF probe (what pose_jacobians() uses): angular rows too
            R6, p6, J6 = batch_placements(model, Q, frame, jacobian=True, angular=True)
            np.testing.assert_array_equal(J6[:, :3], J)
            for k, q in enumerate(Q):
                pin.computeJointJacobians(model, data, q)
                pin.updateFramePlacement(model, data, fid)
                np.testing.assert_allclose(J6[k], pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED),
                                           rtol=0, atol=1e-13)


def test_batched_frames_are_pinocchios():
    """Issue 32: every link frame, the SMR and a joint's placement along the chain, computed for every pose
    in one walk (kinematics.batch_frames, what the frames' plausibility check uses), equal pinocchio's
    forwardKinematics / updateFramePlacements to rounding, on a 6- and a 7-joint arm; a frame off the
    chain is not guessed (None: pinocchio's loop)."""
    import pinocchio as pin

    from pipeline.robot.arm.kinematics import batch_frames, build_error_model, load_robot

    for path in (ROOT / "raw" / "robot" / "kr210" / "robot.toml", ROOT / "raw" / "arms" / "panda.toml"):
        robot = load_robot(path)
        model, idx = build_error_model(robot)
        rng = np.random.default_rng(5)
        Q = rng.normal(0.0, 2e-3, (30, model.nq))
        Q[:, idx.joints] = rng.uniform(-3.0, 3.0, (30, idx.joints.size))
        names = [f"link{i}" for i in range(1, idx.joints.size + 1)] + ["smr"]
        base_joint = int(idx.base[-1]) + 1
        got = batch_frames(model, Q, names, (base_joint,))
        assert got is not None and set(got) == set(names) | {base_joint}
        data = model.createData()
        for k, q in enumerate(Q):
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacements(model, data)
            for nm in names:
                M = data.oMf[model.getFrameId(nm)]
                np.testing.assert_allclose(got[nm][0][k], M.rotation, rtol=0, atol=1e-13)
                np.testing.assert_allclose(got[nm][1][k], M.translation, rtol=0, atol=1e-13)
            np.testing.assert_allclose(got[base_joint][0][k], data.oMi[base_joint].rotation, rtol=0, atol=1e-13)
            np.testing.assert_allclose(got[base_joint][1][k], data.oMi[base_joint].translation, rtol=0, atol=1e-13)
        # the flange hangs off the same joint as the SMR; a frame on another branch would be refused
        assert batch_frames(model, Q, ["flange"], ()) is not None
