"""Simulated depth cameras on Zenoh: pybullet renders the robot at its reported joint states, clouds go out as CDR."""

from __future__ import annotations

import json
import logging
import threading
import time

import numpy as np

from ..errors import ConfigError, InvalidInputError
from ..perception import CameraModel, pose_from_config
from ..transport import messages as m
from ..transport.keys import Keys
from ..world.geometry import Box, Shape
from ..world.robot import RobotModel
from ..world.transforms import make_transform
from .camera import PyBulletDepthCamera
from .config import CellConfig
from .scene import PyBulletScene

log = logging.getLogger(__name__)


class CloudPublisher:
    """Publishes organised PointCloud2 clouds of every configured camera on `<root>/clouds/<sensor>`.

    Args:
        cfg: full config; its perception.sensors are the cameras (pose, resolution, field of view).
        session: an open Zenoh session (not closed here).
        static: (name, shape, pose) objects present in the simulated room.
        rate_hz: frames per second per camera (rendering 320x240 takes ~40 ms on one core).
        robot: a loaded model of cfg.robot (loaded here if not given).
        mirror_sim: also show the operator and the part where `replanner sim` says they are (`sim/bodies`).
        seed: seeds the depth noise (`sim.noise`).
    """

    def __init__(
        self,
        cfg: CellConfig,
        session,
        static=(),
        rate_hz: float = 10.0,
        robot: RobotModel | None = None,
        mirror_sim: bool = False,
        seed: int = 0,
    ):
        if cfg.perception is None or not cfg.perception.sensors:
            raise ConfigError("the config has no perception.sensors: there is no camera to simulate")
        self.robot = robot or RobotModel.from_config(cfg.robot)
        self.keys = Keys(self.robot.name, cfg.transport.namespace)
        self.session = session
        self.rate_hz = float(rate_hz)
        self.scene = PyBulletScene(self.robot)
        for name, shape, pose in static:
            self.scene.add(name, shape, pose)
        self.cameras = [
            (s.name, PyBulletDepthCamera(self.scene.client, CameraModel.from_config(s), pose_from_config(s.pose)))
            for s in cfg.perception.sensors
        ]
        self.frames = 0
        self.noise = cfg.sim.noise
        self.rng = np.random.default_rng(seed)
        self.mirror_sim = mirror_sim
        if mirror_sim:
            from .physics import create_capsule

            oc = cfg.sim.operator
            self._op = create_capsule(self.scene.client, oc.arm_radius, oc.arm_length)
            self._part = self.scene.add("part", Box(size=tuple(cfg.sim.task.part_size)), make_transform((0, 0, -5.0)))
        self._js: tuple[float, np.ndarray, tuple | None] | None = None  # stamp, q, (operator, part)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ obstacles only the cameras see
    def add_obstacle(self, name: str, shape: Shape, pose: np.ndarray) -> None:
        with self._lock:
            self.scene.add(name, shape, pose)

    def move_obstacle(self, name: str, pose: np.ndarray) -> None:
        with self._lock:
            self.scene.move(name, pose)

    def remove_obstacle(self, name: str) -> None:
        with self._lock:
            self.scene.remove(name)

    # ------------------------------------------------------------------ running
    def start(self) -> CloudPublisher:
        self._pubs = {name: self.session.declare_publisher(self.keys.cloud(name)) for name, _ in self.cameras}
        self._sub = None
        self._sub_bodies = None
        if not self.mirror_sim:  # mirroring: the arm comes with the bodies, all of one instant
            self._sub = self.session.declare_subscriber(self.keys.joint_states, self._on_joint_state)
        else:
            from .physics import sim_keys

            self._sub_bodies = self.session.declare_subscriber(sim_keys(self.keys)["bodies"], self._on_bodies)
        self._thread = threading.Thread(target=self._loop, name="cloud-publisher", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        for sub in (self._sub, self._sub_bodies):
            if sub is not None:
                sub.undeclare()
        for p in self._pubs.values():
            p.undeclare()
        with self._lock:
            self.scene.close()

    def _on_joint_state(self, sample) -> None:
        try:
            stamp, q, _ = m.decode_joint_state(sample.payload.to_bytes(), self.robot.joint_names)
        except InvalidInputError as err:
            log.warning("joint state ignored: %s", err)
            return
        self._js = (stamp, q, None)

    def _on_bodies(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
            q = np.asarray(msg["q"], float)
            if q.shape != (self.robot.dof,):
                raise ValueError(f"q has {q.size} values, the robot {self.robot.dof} joints")
            self._js = (float(msg["stamp"]), q, (msg.get("operator"), msg.get("part")))
        except (ValueError, KeyError, TypeError, AttributeError) as err:
            log.warning("sim bodies ignored: %s", err)

    def _apply_bodies(self, bodies) -> None:
        from .physics import pose_from_list, set_pose

        op, part = bodies
        set_pose(self.scene.client, self._op, pose_from_list(op))
        set_pose(self.scene.client, self._part, pose_from_list(part))

    def _depth_noise(self, depth: np.ndarray) -> np.ndarray:
        """Kinect-like: range-dependent noise, missing returns, stray points."""
        nz = self.noise
        if nz.depth_sigma > 0:
            depth = depth + self.rng.normal(0.0, 1.0, depth.shape).astype(np.float32) * nz.depth_sigma * depth**2
        if nz.dropout > 0:
            depth[self.rng.random(depth.shape) < nz.dropout] = np.nan
        if nz.outliers > 0:
            stray = self.rng.random(depth.shape) < nz.outliers
            depth[stray] = self.rng.uniform(0.3, 4.0, int(stray.sum())).astype(np.float32)
        return depth

    def _loop(self) -> None:
        period = 1.0 / self.rate_hz
        now = time.monotonic()
        # cameras take turns, evenly spread over a period: a frame is out one render after its stamp, not n
        due = [now + k * period / len(self.cameras) for k in range(len(self.cameras))]
        last: list[float | None] = [None] * len(self.cameras)
        while not self._stop.is_set():
            k = int(np.argmin(due))
            delay = due[k] - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                break
            due[k] = max(due[k] + period, time.monotonic())
            js = self._js
            if js is None or js[0] == last[k]:  # a frame per joint state at most: a camera's stamps must increase
                continue
            last[k] = js[0]
            name, cam = self.cameras[k]
            with self._lock:
                self.scene.set_q(js[1])
                if js[2] is not None:
                    self._apply_bodies(js[2])
                depth = cam.depth()
            c = cam.camera
            pts = c.depth_to_points(self._depth_noise(depth))
            # stamped with the joint state it was rendered at: the self-filter sees the same arm
            self._pubs[name].put(m.encode_cloud(js[0], pts, name, c.width, c.height))
            self.frames += 1
