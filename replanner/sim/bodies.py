"""Bodies the cell moves by hand: the operator's forearm (a capsule) and poses set, parked and sent as lists."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
from scipy.spatial.transform import Rotation

from ..model.transforms import make_transform, matrix_to_quat

PARK = (0.0, 0.0, -5.0)  # where absent bodies wait: under the floor, out of every camera's view
CONTACT_DEPTH = 0.001  # pybullet reports distances up to its 1 mm collision margin short: deeper counts


def capsule_pose(tip: np.ndarray, direction: np.ndarray, length: float) -> np.ndarray:
    """Pose of a capsule (axis z) whose far end is at `tip` [m], pointing along `direction`."""
    d = direction / np.linalg.norm(direction)
    axis = np.cross((0.0, 0.0, 1.0), d)
    s = float(np.linalg.norm(axis))
    angle = math.atan2(s, float(d[2]))
    # straight up or down the cross product has no axis: turn about x (by pi when pointing down)
    rotvec = axis / s * angle if s >= 1e-9 else np.array([0.0 if d[2] > 0 else math.pi, 0.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = tip - d * (length / 2)
    return T


def create_capsule(client: int, radius: float, length: float) -> int:
    """A massless capsule body [m], parked."""
    col = pb.createCollisionShape(pb.GEOM_CAPSULE, radius=radius, height=length, physicsClientId=client)
    vis = pb.createVisualShape(pb.GEOM_CAPSULE, radius=radius, length=length, physicsClientId=client)
    return pb.createMultiBody(0, col, vis, basePosition=PARK, physicsClientId=client)


def set_pose(client: int, body: int, T: np.ndarray | None) -> None:
    """Put `body` at `T` (base frame), or park it if None."""
    if T is None:
        pb.resetBasePositionAndOrientation(body, PARK, (0, 0, 0, 1), physicsClientId=client)
    else:
        pb.resetBasePositionAndOrientation(
            body, T[:3, 3].tolist(), matrix_to_quat(T[:3, :3]).tolist(), physicsClientId=client
        )


def pose_list(T: np.ndarray | None) -> list[float] | None:
    """[x, y, z, qx, qy, qz, qw] of a pose (None stays None): poses in JSON messages."""
    return None if T is None else [*T[:3, 3].tolist(), *matrix_to_quat(T[:3, :3]).tolist()]


def pose_from_list(p) -> np.ndarray | None:
    return None if p is None else make_transform(p[:3], p[3:])
