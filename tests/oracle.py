"""pybullet as the independent oracle: the same URDF loaded by pybullet, its own kinematics and collision engine."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from replanner.geometry import Box, Cylinder, Sphere
from replanner.robot import RobotModel
from replanner.transforms import matrix_to_quat

# pybullet inflates every convex hull it builds from a URDF mesh by a 1 mm collision margin, so its distances
# are ~1 mm per hull smaller than the hulls' true distance (test_oracle_margin measures it).
HULL_MARGIN = 0.001


class PyBulletOracle:
    """A DIRECT pybullet client with the robot loaded at the origin, its passive joints set like the model's."""

    def __init__(self, robot: RobotModel):
        self.robot = robot
        self.cid = pb.connect(pb.DIRECT)
        self.body = pb.loadURDF(str(robot.urdf_path), useFixedBase=True, physicsClientId=self.cid)
        self.link_id: dict[str, int] = {}
        self.joint_id: dict[str, int] = {}
        root = pb.getBodyInfo(self.body, physicsClientId=self.cid)[0].decode()
        self.link_id[root] = -1
        for j in range(pb.getNumJoints(self.body, physicsClientId=self.cid)):
            info = pb.getJointInfo(self.body, j, physicsClientId=self.cid)
            self.joint_id[info[1].decode()] = j
            self.link_id[info[12].decode()] = j
        for name, value in robot.passive_joint_positions.items():
            pb.resetJointState(self.body, self.joint_id[name], value, physicsClientId=self.cid)
        self.obstacles: dict[str, int] = {}

    def close(self) -> None:
        pb.disconnect(self.cid)

    def set_q(self, q) -> None:
        for name, value in zip(self.robot.joint_names, q):
            pb.resetJointState(self.body, self.joint_id[name], float(value), physicsClientId=self.cid)

    def link_pose(self, link: str) -> np.ndarray:
        """URDF link frame in the world (pybullet's worldLinkFrame, not the inertial frame)."""
        T = np.eye(4)
        i = self.link_id[link]
        if i == -1:  # the base reports its centre of mass: undo the inertial offset
            com_pos, com_quat = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.cid)
            info = pb.getDynamicsInfo(self.body, -1, physicsClientId=self.cid)
            inv_pos, inv_quat = pb.invertTransform(info[3], info[4])
            pos, quat = pb.multiplyTransforms(com_pos, com_quat, inv_pos, inv_quat)
        else:
            st = pb.getLinkState(self.body, i, computeForwardKinematics=True, physicsClientId=self.cid)
            pos, quat = st[4], st[5]
        T[:3, :3] = np.array(pb.getMatrixFromQuaternion(quat)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def add(self, name: str, shape, pose: np.ndarray) -> int:
        if isinstance(shape, Box):
            col = pb.createCollisionShape(
                pb.GEOM_BOX, halfExtents=[s / 2 for s in shape.size], physicsClientId=self.cid
            )
        elif isinstance(shape, Sphere):
            col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=shape.radius, physicsClientId=self.cid)
        elif isinstance(shape, Cylinder):
            col = pb.createCollisionShape(
                pb.GEOM_CYLINDER, radius=shape.radius, height=shape.length, physicsClientId=self.cid
            )
        else:
            raise TypeError(type(shape))
        body = pb.createMultiBody(
            0,
            col,
            basePosition=pose[:3, 3].tolist(),
            baseOrientation=matrix_to_quat(pose[:3, :3]).tolist(),
            physicsClientId=self.cid,
        )
        self.obstacles[name] = body
        return body

    def move(self, name: str, pose: np.ndarray) -> None:
        pb.resetBasePositionAndOrientation(
            self.obstacles[name], pose[:3, 3].tolist(), matrix_to_quat(pose[:3, :3]).tolist(), physicsClientId=self.cid
        )

    def remove_all(self) -> None:
        for body in self.obstacles.values():
            pb.removeBody(body, physicsClientId=self.cid)
        self.obstacles.clear()

    def min_world_distance(self, cutoff: float, allowed: set[tuple[str, str]] = frozenset()) -> float:
        """Smallest signed distance [m] between robot links and obstacles (cutoff if none is closer)."""
        best = cutoff
        names = {v: k for k, v in self.link_id.items()}
        for oname, ob in self.obstacles.items():
            for c in pb.getClosestPoints(self.body, ob, cutoff, physicsClientId=self.cid):
                if (names[c[3]], oname) in allowed:
                    continue
                best = min(best, c[8])
        return best

    def min_self_distance(
        self, link_pairs: list[tuple[str, str]], cutoff: float
    ) -> tuple[float, tuple[str, str] | None]:
        best, who = cutoff, None
        for a, b in link_pairs:
            for c in pb.getClosestPoints(
                self.body, self.body, cutoff, self.link_id[a], self.link_id[b], physicsClientId=self.cid
            ):
                if c[8] < best:
                    best, who = c[8], (a, b)
        return best, who

    def distance_between(self, body_a: int, body_b: int, cutoff: float = 1.0) -> float:
        pts = pb.getClosestPoints(body_a, body_b, cutoff, physicsClientId=self.cid)
        return min((c[8] for c in pts), default=cutoff)
