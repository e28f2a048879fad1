"""Forward kinematics and Jacobians against pybullet, the independent oracle."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from replanner.errors import InvalidInputError
from replanner.model.transforms import rotation_angle
from tests.oracle import PyBulletOracle


def test_fk_matches_pybullet_on_1000_random_configurations(profile):
    cfg, robot = profile
    oracle = PyBulletOracle(robot)
    rng = np.random.default_rng(2)
    Q = robot.random_q(rng, 1000)
    T = robot.fk(Q)  # one batched call for all 1000
    worst_pos = worst_rot = 0.0
    for n, q in enumerate(Q):
        oracle.set_q(q)
        ref = np.stack([oracle.link_pose(link) for link in robot.link_names])
        worst_pos = max(worst_pos, float(np.abs(ref[:, :3, 3] - T[n, :, :3, 3]).max()))
        rel = np.swapaxes(ref[:, :3, :3], -1, -2) @ T[n, :, :3, :3]
        worst_rot = max(worst_rot, float(rotation_angle(rel).max()))
    oracle.close()
    print(f"{robot.name}: worst FK error {worst_pos:.2e} m, {worst_rot:.2e} rad over 1000 configurations")
    assert worst_pos <= 1e-6
    assert worst_rot <= 1e-6


def test_batched_fk_equals_one_at_a_time(panda):
    Q = panda.random_q(np.random.default_rng(0), 7)
    batched = panda.fk(Q)
    for n, q in enumerate(Q):
        np.testing.assert_allclose(panda.fk(q), batched[n], atol=1e-12)
    assert panda.fk(Q.reshape(7, 1, 7)).shape == (7, 1, len(panda.link_names), 4, 4)


def test_jacobian_matches_finite_differences(profile):
    _, robot = profile
    rng = np.random.default_rng(3)
    point = np.array([0.01, -0.02, 0.05])
    eps = 1e-6
    for q in robot.random_q(rng, 20):
        J = robot.jacobian(q, robot.tip_link, point)
        for j in range(robot.dof):
            dq = np.zeros(robot.dof)
            dq[j] = eps
            Tp, Tm = robot.link_pose(q + dq, robot.tip_link), robot.link_pose(q - dq, robot.tip_link)
            v = ((Tp[:3, :3] @ point + Tp[:3, 3]) - (Tm[:3, :3] @ point + Tm[:3, 3])) / (2 * eps)
            dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * eps) @ robot.link_pose(q, robot.tip_link)[:3, :3].T
            w = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
            np.testing.assert_allclose(J[:3, j], v, atol=1e-6)
            np.testing.assert_allclose(J[3:, j], w, atol=1e-6)


def test_jacobian_matches_pybullet(panda):
    oracle = PyBulletOracle(panda)
    movable = [
        j
        for j in range(pb.getNumJoints(oracle.body, physicsClientId=oracle.cid))
        if pb.getJointInfo(oracle.body, j, physicsClientId=oracle.cid)[2] != pb.JOINT_FIXED
    ]
    names = [pb.getJointInfo(oracle.body, j, physicsClientId=oracle.cid)[1].decode() for j in movable]
    cols = [names.index(n) for n in panda.joint_names]
    rng = np.random.default_rng(4)
    for q in panda.random_q(rng, 25):
        oracle.set_q(q)
        full = [panda.passive_joint_positions.get(n, 0.0) for n in names]
        for n, v in zip(panda.joint_names, q):
            full[names.index(n)] = float(v)
        # pybullet 3.2.7 takes the point in the URDF link frame (measured; its docs say centre of mass)
        point = [0.02, -0.01, 0.1]
        lin, ang = pb.calculateJacobian(
            oracle.body,
            oracle.link_id["panda_hand"],
            point,
            full,
            [0.0] * len(full),
            [0.0] * len(full),
            physicsClientId=oracle.cid,
        )
        J = panda.jacobian(q, "panda_hand", point)
        np.testing.assert_allclose(J[:3], np.array(lin)[:, cols], atol=1e-6)
        np.testing.assert_allclose(J[3:], np.array(ang)[:, cols], atol=1e-6)
    oracle.close()


@pytest.mark.parametrize("bad", [[0.0] * 6, [0.0] * 8, [np.nan] + [0.0] * 6, "abc"])
def test_bad_configurations_are_rejected_with_the_joint_names(panda, bad):
    with pytest.raises(InvalidInputError) as err:
        panda.fk(bad)
    assert "panda_joint1" in str(err.value) or "NaN" in str(err.value)


def test_limits_come_from_urdf_and_config(panda, panda_cfg):
    assert panda.limits.lower[0] == pytest.approx(-2.9671)
    assert panda.limits.upper[3] == pytest.approx(0.0)
    np.testing.assert_allclose(panda.limits.jerk, panda_cfg.robot.jerk_limits)
    with pytest.raises(ValueError):
        panda.limits.velocity[0] = 1.0  # read-only
