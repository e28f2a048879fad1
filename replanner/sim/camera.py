"""Depth images and organised point clouds of a pybullet world: by a compiled z-buffer over its meshes
(`raster.py`), or by pybullet's own software renderer."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from ..errors import InvalidInputError
from ..perception.camera import CameraModel
from .raster import PyBulletMeshes, render_depth


class PyBulletDepthCamera:
    """A pinhole depth camera in a pybullet world.

    Args:
        client: pybullet client id.
        camera: intrinsics (square pixels, centred principal point: what pybullet's projection supports).
        T_base_camera: optical-frame pose (x right, y down, z forward) in the world/base frame.
        near, far: clipping planes [m]; nothing beyond `far` returns (NaN), like a real sensor's range.
        meshes: the world's meshes (`PyBulletScene.meshes`): drawn by the compiled z-buffer, exact at every pixel;
            None: pybullet's tiny renderer (its depth, interpolated linearly across the image, is off by up to
            centimetres on large surfaces, and a frame costs several times as much).
    """

    def __init__(
        self,
        client: int,
        camera: CameraModel,
        T_base_camera: np.ndarray,
        near: float = 0.05,
        far: float = 6.0,
        meshes: PyBulletMeshes | None = None,
    ):
        if (
            abs(camera.fx - camera.fy) > 1e-6 * camera.fx
            or abs(camera.cx - (camera.width / 2 - 0.5)) > 1e-6
            or abs(camera.cy - (camera.height / 2 - 0.5)) > 1e-6
        ):
            raise InvalidInputError(
                "pybullet renders only square pixels with a centred principal point (use fov_y_deg)"
            )
        self.client = client
        self.camera = camera
        self.near, self.far = near, far
        self.meshes = meshes
        self._proj = pb.computeProjectionMatrixFOV(
            camera.fov_y_deg, camera.width / camera.height, near, far, physicsClientId=client
        )
        self.set_pose(T_base_camera)

    def set_pose(self, T_base_camera: np.ndarray) -> None:
        self.T_base_camera = np.asarray(T_base_camera, dtype=float)
        eye = self.T_base_camera[:3, 3]
        z, y = self.T_base_camera[:3, 2], self.T_base_camera[:3, 1]
        self._view = pb.computeViewMatrix(eye.tolist(), (eye + z).tolist(), (-y).tolist(), physicsClientId=self.client)

    def depth(self) -> np.ndarray:
        """(H, W) float32 depth along the optical axis [m]; NaN where nothing is within `far`."""
        if self.meshes is not None:
            return render_depth(self.meshes.posed(), self.camera, self.T_base_camera, self.near, self.far)
        cam = self.camera
        _, _, _, buf, _ = pb.getCameraImage(
            cam.width,
            cam.height,
            self._view,
            self._proj,
            renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client,
        )
        d = np.asarray(buf, dtype=np.float64).reshape(cam.height, cam.width)
        z = self.far * self.near / (self.far - (self.far - self.near) * d)
        z[d >= 1.0 - 1e-7] = np.nan
        return z.astype(np.float32)

    def cloud(self) -> np.ndarray:
        """Organised (H*W, 3) float32 cloud in the optical frame; NaN rows where there was no return."""
        return self.camera.depth_to_points(self.depth())
