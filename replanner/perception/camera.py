"""Pinhole depth cameras: intrinsics in the optical frame (x right, y down, z forward) and their poses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..model.transforms import make_transform
from ..sections import PoseConfig, SensorConfig


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_base_camera of an optical frame at `eye` whose z axis points at `target` and whose image top is `up`."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) < 1e-9:
        raise InvalidInputError("look_at: target must differ from eye")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:  # looking straight along `up`: any perpendicular will do
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye
    return T


def pose_from_config(pose: PoseConfig) -> np.ndarray:
    if pose.look_at is not None:
        return look_at(pose.position, pose.look_at)
    return make_transform(pose.position, pose.quat_xyzw)


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics [px]; pixel (u, v) has its centre at integer coordinates."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_deg: float) -> CameraModel:
        f = (height / 2) / np.tan(np.deg2rad(fov_y_deg) / 2)
        return cls(width, height, f, f, width / 2 - 0.5, height / 2 - 0.5)

    @classmethod
    def from_config(cls, cfg: SensorConfig) -> CameraModel:
        if cfg.fov_y_deg is not None:
            return cls.from_fov(cfg.width, cfg.height, cfg.fov_y_deg)
        fx = cfg.fx if cfg.fx is not None else cfg.fy
        fy = cfg.fy if cfg.fy is not None else cfg.fx
        cx = cfg.cx if cfg.cx is not None else cfg.width / 2 - 0.5
        cy = cfg.cy if cfg.cy is not None else cfg.height / 2 - 0.5
        return cls(cfg.width, cfg.height, fx, fy, cx, cy)

    @property
    def fov_y_deg(self) -> float:
        return float(np.rad2deg(2 * np.arctan((self.height / 2) / self.fy)))

    def rays(self) -> np.ndarray:
        """(H, W, 3) float32 directions with z = 1 through every pixel centre."""
        u = (np.arange(self.width) - self.cx) / self.fx
        v = (np.arange(self.height) - self.cy) / self.fy
        r = np.empty((self.height, self.width, 3), np.float32)
        r[..., 0] = u[None, :]
        r[..., 1] = v[:, None]
        r[..., 2] = 1.0
        return r

    def depth_to_points(self, depth: np.ndarray) -> np.ndarray:
        """Organised cloud (H*W, 3) float32 in the optical frame from a depth image [m] (NaN where no return)."""
        d = np.asarray(depth, dtype=np.float32)
        if d.shape != (self.height, self.width):
            raise InvalidInputError(f"depth image must be {self.height}x{self.width}, got {d.shape}")
        return (self.rays() * d[..., None]).reshape(-1, 3)

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel (u, v) int arrays and a mask of points in front of the camera and inside the image."""
        z = points_cam[:, 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        u = np.rint(points_cam[:, 0] / zs * self.fx + self.cx).astype(np.int64)
        v = np.rint(points_cam[:, 1] / zs * self.fy + self.cy).astype(np.int64)
        inside = front & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
        return u, v, inside

    def render_depth(self, points_cam: np.ndarray) -> np.ndarray:
        """Depth image (H, W) [m] of a cloud by z-buffer (nearest point per pixel, NaN elsewhere)."""
        u, v, inside = self.project(points_cam)
        depth = np.full(self.height * self.width, np.inf, np.float32)
        np.minimum.at(depth, v[inside] * self.width + u[inside], points_cam[inside, 2].astype(np.float32))
        depth[np.isinf(depth)] = np.nan
        return depth.reshape(self.height, self.width)
