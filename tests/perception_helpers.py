"""A perception set-up over a real pybullet scene: the robot, a table, cameras from the config."""

from __future__ import annotations

import copy

import numpy as np
import yaml

from replanner.bench.scenes import add_table
from replanner.config import parse_config
from replanner.model.robot import RobotModel
from replanner.perception import CameraModel, CloudFrame, Perception, pose_from_config
from replanner.sim.camera import PyBulletDepthCamera
from replanner.sim.scene import PyBulletScene
from replanner.world.scene import World
from tests.conftest import CONFIGS


def config_dict(width: int = 320, height: int = 240, **perception) -> dict:
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    for s in data["perception"]["sensors"]:
        s["width"], s["height"] = width, height
    data["perception"].update(perception)
    return data


class Rig:
    """Robot, world (with a table), its pybullet twin, one simulated camera per configured sensor, perception."""

    def __init__(self, data: dict | None = None, robot: RobotModel | None = None):
        self.cfg = parse_config(copy.deepcopy(data or config_dict()), base_dir=CONFIGS)
        self.robot = robot or RobotModel.from_config(self.cfg.robot)
        self.world = World(self.robot)
        add_table(self.world)
        self.sim = PyBulletScene(self.robot)
        for o in self.world.objects.values():
            self.sim.add(o.name, o.shape, o.pose)
        self.cameras = {
            s.name: PyBulletDepthCamera(self.sim.client, CameraModel.from_config(s), pose_from_config(s.pose))
            for s in self.cfg.perception.sensors
        }
        self.perception = Perception(self.cfg.perception, self.robot, self.world)
        self.q = self.robot.home.copy()
        self.sim.set_q(self.q)
        self.stamp = 0.0

    def set_q(self, q) -> None:
        self.q = np.asarray(q, dtype=float)
        self.sim.set_q(self.q)

    def frame(self, sensor: str = "front", **kw):
        self.stamp += 1.0 / 30
        self.perception.add_joint_state(self.stamp, self.q)
        cloud = self.cameras[sensor].cloud()
        return self.perception.integrate(CloudFrame(sensor, self.stamp, cloud, organized=True, **kw))

    def voxels_in(self, center, size) -> int:
        """Occupied voxels whose centre lies in the axis-aligned box."""
        occ = self.world.occupancy
        if occ is None or not len(occ):
            return 0
        c = occ.centers
        lo, hi = np.asarray(center) - np.asarray(size) / 2, np.asarray(center) + np.asarray(size) / 2
        return int(np.all((c >= lo) & (c <= hi), axis=1).sum())

    def close(self) -> None:
        self.sim.close()
