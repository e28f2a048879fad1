"""The world room: robot model, collision shapes, transforms, occupancy map, the World and the collision checker."""

from .collision import OCTREE, BodyPoses, Clearance, CollisionChecker, Contact, ContactKind, PathCheck
from .geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from .occupancy import OccupancyMap
from .robot import CollisionBody, JointLimits, RobotModel
from .scene import Attachment, World, WorldObject, WorldSnapshot
from .transforms import (
    check_transform,
    invert_transform,
    make_transform,
    matrix_to_quat,
    quat_to_matrix,
    rotation_angle,
    rpy_to_matrix,
)

__all__ = [
    "OCTREE",
    "Attachment",
    "BodyPoses",
    "Box",
    "Clearance",
    "CollisionBody",
    "CollisionChecker",
    "Contact",
    "ContactKind",
    "ConvexHull",
    "Cylinder",
    "JointLimits",
    "Mesh",
    "OccupancyMap",
    "PathCheck",
    "RobotModel",
    "Shape",
    "Sphere",
    "World",
    "WorldObject",
    "WorldSnapshot",
    "check_transform",
    "invert_transform",
    "make_transform",
    "matrix_to_quat",
    "quat_to_matrix",
    "rotation_angle",
    "rpy_to_matrix",
]
