"""The model room: a robot from its URDF (joints, limits, kinematics, collision bodies), collision shapes and rigid
transforms. Everything else stands on it."""

from .geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from .robot import JointLimits, RobotModel
from .transforms import (
    check_transform,
    invert_transform,
    make_transform,
    matrix_to_quat,
    quat_to_matrix,
    rotation_angle,
    rpy_to_matrix,
)
from .urdf import CollisionBody

__all__ = [
    "Box",
    "CollisionBody",
    "ConvexHull",
    "Cylinder",
    "JointLimits",
    "Mesh",
    "RobotModel",
    "Shape",
    "Sphere",
    "check_transform",
    "invert_transform",
    "make_transform",
    "matrix_to_quat",
    "quat_to_matrix",
    "rotation_angle",
    "rpy_to_matrix",
]
