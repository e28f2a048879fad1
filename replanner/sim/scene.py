"""A pybullet world mirroring a replanner robot and its static objects (the simulator's ground truth)."""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as pb

from ..model.geometry import Box, Cylinder, Shape, Sphere
from ..model.robot import RobotModel
from ..model.transforms import make_transform, matrix_to_quat
from .raster import PyBulletMeshes


def room_geometry() -> list[tuple[str, Shape, np.ndarray]]:
    """Floor 0.75 m below the table top and walls 3 m away: what the cameras see behind everything."""
    return [
        ("floor", Box(size=(10.0, 10.0, 0.1)), make_transform((0.0, 0.0, FLOOR_Z - 0.05))),
        ("wall_back", Box(size=(0.1, 10.0, 4.0)), make_transform((-3.0, 0.0, 1.0))),
        ("wall_left", Box(size=(10.0, 0.1, 4.0)), make_transform((0.0, -3.0, 1.0))),
    ]


FLOOR_Z = -0.75  # the table top is at z = 0 in the base frame


def collision_drawn(urdf: Path) -> Path:
    """A copy of the URDF whose links are drawn with their collision geometry (written once to the temp dir).

    A depth camera drawing the panda's collision meshes renders much faster than with its visual meshes (many times
    the triangles); the silhouettes differ by millimetres, and the collision meshes are what the service checks anyway.
    """
    urdf = Path(urdf).resolve()
    tag = hashlib.sha1(f"{urdf}:{urdf.stat().st_mtime_ns}".encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / "replanner-urdf" / f"{urdf.stem}-{tag}.urdf"
    if out.exists():
        return out
    tree = ET.parse(urdf)
    for link in tree.getroot().iter("link"):
        for v in link.findall("visual"):
            link.remove(v)
        for c in link.findall("collision"):
            v = copy.deepcopy(c)
            v.tag = "visual"
            link.append(v)
    for mesh in tree.getroot().iter("mesh"):  # the copy lives elsewhere: every mesh by its absolute path
        name = mesh.get("filename", "")
        name = name[len("package://") :] if name.startswith("package://") else name
        mesh.set("filename", name if os.path.isabs(name) else str(urdf.parent / name))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tree.write(tmp)
    os.replace(tmp, out)  # two processes writing at once both leave a whole file
    return out


class PyBulletScene:
    """The robot at the origin (fixed base) on a table-height base, a floor and two walls, and primitive bodies.

    The floor and walls give depth cameras a background, as in a lab; they lie outside the perception workspace.
    """

    def __init__(
        self,
        robot: RobotModel,
        client: int | None = None,
        room: bool = True,
        self_collision: bool = False,
        draw_collision: bool = False,
    ):
        """draw_collision: cameras see the robot's collision geometry (faster to render) instead of its visual."""
        self.robot = robot
        self.client = pb.connect(pb.DIRECT) if client is None else client
        self._owns_client = client is None
        flags = pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT if self_collision else 0
        urdf = collision_drawn(robot.urdf_path) if draw_collision else robot.urdf_path
        self.body = pb.loadURDF(str(urdf), useFixedBase=True, flags=flags, physicsClientId=self.client)
        self.joint_index: dict[str, int] = {}
        self.link_index: dict[str, int] = {}
        for j in range(pb.getNumJoints(self.body, physicsClientId=self.client)):
            info = pb.getJointInfo(self.body, j, physicsClientId=self.client)
            self.joint_index[info[1].decode()] = j
            self.link_index[info[12].decode()] = j
        for name, value in robot.passive_joint_positions.items():
            pb.resetJointState(self.body, self.joint_index[name], value, physicsClientId=self.client)
        self.objects: dict[str, int] = {}
        self.room: dict[str, int] = {}
        self._meshes: PyBulletMeshes | None = None
        if room:
            for name, shape, pose in room_geometry():
                self.room[name] = self._create(shape, pose)

    def meshes(self) -> PyBulletMeshes:
        """What a depth camera sees of this world, for the compiled z-buffer (`raster.py`)."""
        if self._meshes is None:
            self._meshes = PyBulletMeshes(self.client, self.robot, self.body)
        return self._meshes

    def close(self) -> None:
        if self._owns_client:
            pb.disconnect(self.client)

    def set_q(self, q) -> None:
        for name, value in zip(self.robot.joint_names, q):
            pb.resetJointState(self.body, self.joint_index[name], float(value), physicsClientId=self.client)

    def add(self, name: str, shape: Shape, pose: np.ndarray) -> int:
        body = self._create(shape, pose)
        self.objects[name] = body
        return body

    def _create(self, shape: Shape, pose: np.ndarray) -> int:
        c = self.client
        if isinstance(shape, Box):
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[s / 2 for s in shape.size], physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[s / 2 for s in shape.size], physicsClientId=c)
        elif isinstance(shape, Sphere):
            col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=shape.radius, physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=shape.radius, physicsClientId=c)
        elif isinstance(shape, Cylinder):
            col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=shape.radius, height=shape.length, physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=shape.radius, length=shape.length, physicsClientId=c)
        else:
            raise TypeError(f"the simulator has no {type(shape).__name__} yet")
        return pb.createMultiBody(
            0,
            col,
            vis,
            basePosition=pose[:3, 3].tolist(),
            baseOrientation=matrix_to_quat(pose[:3, :3]).tolist(),
            physicsClientId=c,
        )

    def contacts(
        self, q, ignore: set[frozenset[str]] = frozenset(), depth: float = 0.0
    ) -> list[tuple[str, str, float]]:
        """Penetrations deeper than `depth` [m] between the robot and anything (itself with self_collision=True).

        `ignore` holds pairs of names (robot link names, object names) that may touch.
        """
        self.set_q(q)
        c = self.client
        pb.performCollisionDetection(physicsClientId=c)
        link_name = {v: k for k, v in self.link_index.items()}
        link_name[-1] = self.robot.base_link
        body_name = {v: k for k, v in {**self.objects, **self.room}.items()}
        out = []
        for pt in pb.getContactPoints(bodyA=self.body, physicsClientId=c):
            if pt[8] >= -depth:
                continue
            a = link_name.get(pt[3], str(pt[3]))
            b = link_name.get(pt[4], str(pt[4])) if pt[2] == self.body else body_name.get(pt[2], str(pt[2]))
            if frozenset((a, b)) not in ignore:
                out.append((a, b, pt[8]))
        return out

    def move(self, name: str, pose: np.ndarray) -> None:
        pb.resetBasePositionAndOrientation(
            self.objects[name], pose[:3, 3].tolist(), matrix_to_quat(pose[:3, :3]).tolist(), physicsClientId=self.client
        )

    def remove(self, name: str) -> None:
        pb.removeBody(self.objects.pop(name), physicsClientId=self.client)
