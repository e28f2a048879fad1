"""The cell's two pybullet worlds: the live one (the arm under motors, the scene, the part, the operator's forearm)
and a shadow one where the arm is put at commanded configurations to ask what the coming motion will meet."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from ..model.geometry import Box
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..world.scene import scene_from_config
from .bodies import CONTACT_DEPTH, PARK, create_capsule, set_pose
from .config import CellConfig, OperatorConfig
from .scene import PyBulletScene


class Cell:
    """The live world: the robot at home, the config's `scene:`, the part (parked) and the forearm (parked).

    Nothing pushes the arm: its collisions with the other bodies are filtered out, so contacts are measured
    (ground truth) rather than simulated and a collision is counted rather than hidden by a deflected arm.

    Args:
        cfg: the cell's config; `sim.physics_hz` sets pybullet's time step.
        robot: a loaded model of cfg.robot.
        gui: open pybullet's window.
    """

    def __init__(self, cfg: CellConfig, robot: RobotModel, *, gui: bool = False):
        self.robot = robot
        self.client = pb.connect(pb.GUI if gui else pb.DIRECT)
        c = self.client
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setTimeStep(1.0 / cfg.sim.physics_hz, physicsClientId=c)
        self.scene = PyBulletScene(robot, c)
        self.static: dict[str, int] = {}
        for name, shape, pose in scene_from_config(cfg):
            self.static[name] = self.scene.add(name, shape, pose)
        self.body = self.scene.body
        self.joint_ids = [self.scene.joint_index[n] for n in robot.joint_names]
        forces = [pb.getJointInfo(self.body, j, physicsClientId=c)[10] for j in self.joint_ids]
        self.forces = [f if f > 0 else 100.0 for f in forces]  # motor force limits [N m]; URDFs without one get 100
        self.link_name = {v: k for k, v in self.scene.link_index.items()}
        self.link_name[-1] = robot.base_link
        self.tip_index = self.scene.link_index[robot.tip_link]
        self.allowed = {(a, b) for a, b in cfg.collision.allowed_contacts}
        self.scene.set_q(robot.home)
        self.part_shape = Box(size=tuple(cfg.sim.task.part_size))
        self.part = self.scene.add("part", self.part_shape, make_transform(PARK))
        oc = cfg.sim.operator
        self.forearm = create_capsule(c, oc.arm_radius, oc.arm_length)
        for other in [*self.static.values(), self.part, self.forearm, *self.scene.room.values()]:
            for link in [-1, *self.scene.link_index.values()]:
                pb.setCollisionFilterPair(self.body, other, link, -1, 0, physicsClientId=c)

    def joint_states(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured joint positions [rad] and velocities [rad/s]."""
        states = pb.getJointStates(self.body, self.joint_ids, physicsClientId=self.client)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Put the arm at `q` [rad] moving at `qd` [rad/s], without physics."""
        for j, value, rate in zip(self.joint_ids, q, qd):
            pb.resetJointState(self.body, j, float(value), float(rate), physicsClientId=self.client)

    def tip_pose(self) -> np.ndarray:
        ls = pb.getLinkState(self.body, self.tip_index, computeForwardKinematics=1, physicsClientId=self.client)
        return make_transform(ls[4], ls[5])

    def close(self) -> None:
        pb.disconnect(self.client)


class ShadowWorld:
    """The robot alone (no room) and a forearm, in a pybullet world of their own: questions about the future.

    Each query sets the configuration (and the forearm) it asks about: nothing carries over between queries.
    """

    def __init__(self, robot: RobotModel, oc: OperatorConfig):
        self.scene = PyBulletScene(robot, room=False)
        self.client, self.body = self.scene.client, self.scene.body
        self.forearm = create_capsule(self.client, oc.arm_radius, oc.arm_length)

    def has_link(self, name: str) -> bool:
        return name in self.scene.link_index

    def place_forearm(self, T: np.ndarray | None) -> None:
        set_pose(self.client, self.forearm, T)

    def within(self, q: np.ndarray, distance: float) -> bool:
        """The robot at `q` [rad] comes within `distance` [m] of the forearm."""
        self.scene.set_q(q)
        return bool(pb.getClosestPoints(self.body, self.forearm, distance, physicsClientId=self.client))

    def penetrates(self, q: np.ndarray) -> bool:
        """The robot at `q` [rad] and the forearm overlap (deeper than pybullet's margin)."""
        self.scene.set_q(q)
        pts = pb.getClosestPoints(self.body, self.forearm, 0.0, physicsClientId=self.client)
        return any(p[8] < -CONTACT_DEPTH for p in pts)

    def link_point(self, q: np.ndarray, link: str) -> np.ndarray:
        """Where `link`'s frame is [m, base frame] with the robot at `q` [rad]."""
        self.scene.set_q(q)
        ls = pb.getLinkState(
            self.body, self.scene.link_index[link], computeForwardKinematics=1, physicsClientId=self.client
        )
        return np.array(ls[4])

    def close(self) -> None:
        self.scene.close()
