"""Rigid transforms as 4x4 homogeneous matrices. Quaternions are (x, y, z, w), as in ROS and pybullet."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InvalidInputError


def rpy_to_matrix(rpy: Sequence[float]) -> np.ndarray:
    """Rotation matrix of URDF roll-pitch-yaw [rad] (fixed axes X, then Y, then Z)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def quat_to_matrix(quat_xyzw: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w); it is normalised first."""
    q = np.asarray(quat_xyzw, dtype=float)
    n = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(n) or n < 1e-9:
        raise InvalidInputError(f"quaternion must be 4 finite numbers (x, y, z, w) with norm > 0, got {q.tolist()}")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix."""
    m = np.asarray(R, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


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
    """Rotation angle [rad] of rotation matrices (..., 3, 3)."""
    tr = np.trace(R, axis1=-2, axis2=-1)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
