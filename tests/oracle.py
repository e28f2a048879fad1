"""pybullet as the independent oracle: the same URDF loaded by pybullet, its own kinematics and collision engine."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from replanner.model.robot import RobotModel
from replanner.sim.scene import PyBulletScene

# pybullet inflates every convex hull it builds from a URDF mesh by a 1 mm collision margin, so its distances
# are ~1 mm per hull smaller than the hulls' true distance (test_oracle_margin measures it).
HULL_MARGIN = 0.001


class PyBulletOracle(PyBulletScene):
    """The robot loaded by pybullet from the same URDF (no floor or walls), with pybullet's own FK and distances."""

    def __init__(self, robot: RobotModel):
        super().__init__(robot, room=False)
        self.cid = self.client
        self.link_id = dict(self.link_index)
        self.link_id[pb.getBodyInfo(self.body, physicsClientId=self.cid)[0].decode()] = -1
        self.obstacles = self.objects

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
