"""The simulated cameras' compiled z-buffer against pybullet's own ray casts: the robot at random configurations, the
demo's table and bins, the operator's forearm, and the room behind them."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from replanner.model.robot import RobotModel
from replanner.perception.camera import CameraModel, pose_from_config
from replanner.sim.bodies import capsule_pose, create_capsule, set_pose
from replanner.sim.camera import PyBulletDepthCamera
from replanner.sim.config import load_cell_config
from replanner.sim.scene import PyBulletScene
from replanner.world.scene import scene_from_config


def _ray_depth(scene: PyBulletScene, cam: PyBulletDepthCamera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """pybullet's ray test through pixel centres (u, v): the depth along the optical axis [m], NaN for no hit."""
    c, T = cam.camera, cam.T_base_camera
    rays = np.stack([(u - c.cx) / c.fx, (v - c.cy) / c.fy, np.ones(len(u))], axis=1)  # z = 1
    start = np.repeat(T[:3, 3][None], len(u), axis=0)
    end = rays * cam.far @ T[:3, :3].T + T[:3, 3]
    hits = pb.rayTestBatch(start.tolist(), end.tolist(), physicsClientId=scene.client)
    return np.array([h[2] * cam.far if h[0] >= 0 else np.nan for h in hits])


def test_the_z_buffer_sees_what_pybullets_rays_hit():
    cfg = load_cell_config("demo")
    robot = RobotModel.from_config(cfg.robot)
    scene = PyBulletScene(robot, draw_collision=True)
    try:
        for name, shape, pose in scene_from_config(cfg):
            scene.add(name, shape, pose)
        forearm = create_capsule(scene.client, 0.05, 0.35)
        rng = np.random.default_rng(5)
        agree, total, missing = 0, 0, 0
        for sensor in cfg.perception.sensors:
            model = CameraModel.from_config(sensor)
            cam = PyBulletDepthCamera(scene.client, model, pose_from_config(sensor.pose), meshes=scene.meshes())
            for _ in range(4):
                scene.set_q(robot.random_q(rng))
                tip = rng.uniform((0.3, -0.4, 0.1), (0.7, 0.4, 0.5))
                set_pose(scene.client, forearm, capsule_pose(tip, rng.normal(size=3), 0.35))
                depth = cam.depth()
                assert depth.shape == (model.height, model.width) and depth.dtype == np.float32
                px = rng.choice(model.width * model.height, 1500, replace=False)
                v, u = np.divmod(px, model.width)
                truth, seen = _ray_depth(scene, cam, u, v), depth[v, u]
                both = np.isfinite(truth) & np.isfinite(seen)
                missing += int((np.isfinite(truth) != np.isfinite(seen)).sum())
                agree += int((np.abs(truth - seen)[both] < 0.002).sum())
                total += len(px)
        # pixels on a silhouette may hit either side (a hull's facets against pybullet's margins): a few
        assert agree >= 0.97 * total, (agree, total)
        assert missing <= 0.005 * total, (missing, total)
    finally:
        scene.close()
