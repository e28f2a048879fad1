"""Rigid transforms as 4x4 homogeneous matrices. Quaternions are (x, y, z, w), as in ROS, pybullet and scipy."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InvalidInputError

_AS_ROTATION = {"assume_valid": True}  # else scipy projects every matrix onto SO(3) with an SVD (10x slower)


def rpy_to_matrix(rpy: Sequence[float]) -> np.ndarray:
    """Rotation matrix of URDF roll-pitch-yaw [rad] (fixed axes X, then Y, then Z)."""
    a = np.asarray(rpy, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"rpy must be 3 finite angles (roll, pitch, yaw) [rad], got {np.asarray(rpy).tolist()}")
    return Rotation.from_euler("xyz", a).as_matrix()  # lower case: extrinsic axes, as URDF


def quat_to_matrix(quat_xyzw: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w); it is normalised first."""
    q = np.asarray(quat_xyzw, dtype=float)
    n = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(n) or n < 1e-9:
        raise InvalidInputError(f"quaternion must be 4 finite numbers (x, y, z, w) with norm > 0, got {q.tolist()}")
    return Rotation.from_quat(q / n).as_matrix()


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix."""
    m = np.asarray(R, dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise InvalidInputError(f"rotation matrix must be a finite 3x3 array, got shape {m.shape}")
    return Rotation.from_matrix(m, **_AS_ROTATION).as_quat(canonical=True)


def make_transform(position: Sequence[float] = (0.0, 0.0, 0.0), quat_xyzw: Sequence[float] | None = None) -> np.ndarray:
    """4x4 transform from a position [m] and a quaternion (x, y, z, w); identity rotation if None."""
    p = np.asarray(position, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"position must be 3 finite numbers [m], got {np.asarray(position).tolist()}")
    T = np.eye(4)
    T[:3, 3] = p
    if quat_xyzw is not None:
        T[:3, :3] = quat_to_matrix(quat_xyzw)
    return T


def check_transform(T: np.ndarray, name: str = "transform", tol: float = 1e-6) -> np.ndarray:
    """Return T as a float 4x4 array, or raise if it is not a finite rigid transform."""
    a = np.asarray(T, dtype=float)
    if a.shape != (4, 4):
        raise InvalidInputError(f"{name} must be a 4x4 homogeneous matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} contains NaN or inf")
    R = a[:3, :3]
    if (
        np.abs(R @ R.T - np.eye(3)).max() > tol
        or abs(np.linalg.det(R) - 1.0) > tol
        or np.abs(a[3] - [0, 0, 0, 1]).max() > tol
    ):
        raise InvalidInputError(
            f"{name} is not a rigid transform: its 3x3 block must be a rotation (orthonormal, det +1) "
            "and its last row [0, 0, 0, 1]"
        )
    return a


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (or a stack of them, shape (..., 4, 4))."""
    R = T[..., :3, :3]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] in [0, pi] of rotation matrices (..., 3, 3)."""
    m = np.asarray(R, dtype=float)
    if m.shape[-2:] != (3, 3):
        raise InvalidInputError(f"rotation matrices must have shape (..., 3, 3), got {m.shape}")
    angle = Rotation.from_matrix(m.reshape(-1, 3, 3), **_AS_ROTATION).magnitude()
    return angle.reshape(m.shape[:-2])[()]
