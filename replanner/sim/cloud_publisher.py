"""Simulated depth cameras: pybullet renders the robot at its reported joint states, clouds go out as CDR."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from ..config import ReplannerConfig
from ..errors import ConfigError, InvalidInputError
from ..model.geometry import Box, Shape
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..perception import CameraModel, pose_from_config
from ..transport import messages as m
from .bodies import PARK, create_capsule, pose_from_list, set_pose
from .camera import PyBulletDepthCamera
from .config import CellConfig, NoiseConfig, SimConfig
from .scene import PyBulletScene

log = logging.getLogger(__name__)


class CloudPublisher:
    """Renders organised PointCloud2 clouds of every configured camera and hands them to `publish`.

    The arm is drawn where the latest input says: `on_joint_state` (a CDR JointState) or, with `mirror_sim`,
    `on_bodies` (the physics sim's bodies message: the arm, the operator's forearm and the part of one instant).
    Each frame is stamped with the input it was rendered at.

    Args:
        cfg: full config; its perception.sensors are the cameras (pose, resolution, field of view). A cell's
            config (CellConfig) also gives the depth noise, the forearm and the part; without `sim:`, defaults.
        publish: called from the rendering thread with (sensor name, CDR PointCloud2).
        static: (name, shape, pose) objects present in the simulated room.
        rate_hz: frames per second per camera (rendering holds one core for a while per frame).
        robot: a loaded model of cfg.robot (loaded here if not given).
        mirror_sim: also show the operator and the part where the physics sim says they are (`on_bodies`).
        seed: seeds the depth noise (`sim.noise`).
    """

    def __init__(
        self,
        cfg: ReplannerConfig,
        publish: Callable[[str, bytes], None],
        static=(),
        rate_hz: float = 10.0,
        robot: RobotModel | None = None,
        mirror_sim: bool = False,
        seed: int = 0,
    ):
        if cfg.perception is None or not cfg.perception.sensors:
            raise ConfigError("the config has no perception.sensors: there is no camera to simulate")
        self.robot = robot or RobotModel.from_config(cfg.robot)
        self.publish = publish
        self.rate_hz = float(rate_hz)
        self.scene = PyBulletScene(self.robot)
        for name, shape, pose in static:
            self.scene.add(name, shape, pose)
        meshes = self.scene.meshes()
        self.cameras = [
            (
                s.name,
                PyBulletDepthCamera(
                    self.scene.client, CameraModel.from_config(s), pose_from_config(s.pose), meshes=meshes
                ),
            )
            for s in cfg.perception.sensors
        ]
        self.frames = 0
        sim = cfg.sim if isinstance(cfg, CellConfig) else SimConfig()
        self.noise = sim.noise
        self.rng = np.random.default_rng(seed)
        self.mirror_sim = mirror_sim
        if mirror_sim:
            oc = sim.operator
            self._op = create_capsule(self.scene.client, oc.arm_radius, oc.arm_length)
            self._part = self.scene.add("part", Box(size=tuple(sim.task.part_size)), make_transform(PARK))
        self._js: tuple[float, np.ndarray, tuple | None] | None = None  # stamp, q, (operator, part)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.paused = False  # True: the cameras publish nothing (a test sends its own frames meanwhile)
        self._thread: threading.Thread | None = None

    @property
    def sensors(self) -> list[str]:
        return [name for name, _ in self.cameras]

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
        self._thread = threading.Thread(target=self._loop, name="cloud-publisher", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        with self._lock:
            self.scene.close()

    # ------------------------------------------------------------------ inputs (any thread; never block)
    def on_joint_state(self, payload: bytes) -> None:
        """Draw the arm at this joint state (CDR) from the next frame on; invalid ones are logged."""
        try:
            stamp, q, _ = m.decode_joint_state(payload, self.robot.joint_names)
        except InvalidInputError as err:
            log.warning("joint state ignored: %s", err)
            return
        self._js = (stamp, q, None)

    def on_bodies(self, payload: bytes | str) -> None:
        """Draw the arm, the forearm and the part as the physics sim's bodies message says; invalid ones are logged."""
        try:
            msg = json.loads(payload)
            q = np.asarray(msg["q"], float)
            if q.shape != (self.robot.dof,):
                raise ValueError(f"q has {q.size} values, the robot {self.robot.dof} joints")
            self._js = (float(msg["stamp"]), q, (msg.get("operator"), msg.get("part")))
        except (ValueError, KeyError, TypeError, AttributeError) as err:
            log.warning("sim bodies ignored: %s", err)

    def _apply_bodies(self, bodies) -> None:
        op, part = bodies
        set_pose(self.scene.client, self._op, pose_from_list(op))
        set_pose(self.scene.client, self._part, pose_from_list(part))

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
            if self.paused or js is None or js[0] == last[k]:  # a frame per joint state at most: stamps increase
                continue
            last[k] = js[0]
            name, cam = self.cameras[k]
            with self._lock:
                self.scene.set_q(js[1])
                if js[2] is not None:
                    self._apply_bodies(js[2])
                depth = cam.depth()
            c = cam.camera
            pts = c.depth_to_points(depth_noise(depth, self.noise, self.rng))
            # stamped with the joint state it was rendered at: the self-filter sees the same arm
            self.publish(name, m.encode_cloud(js[0], pts, name, c.width, c.height))
            self.frames += 1


def depth_noise(depth: np.ndarray, nz: NoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """A structured-light camera's depth image (Kinect-like) from an exact one: mixed pixels at depth edges, noise
    growing with range squared, missing returns, stray points."""
    depth = flying_pixels(depth, nz.flying, rng) if nz.flying > 0 else depth.copy()
    if nz.depth_sigma > 0:
        depth += rng.normal(0.0, 1.0, depth.shape).astype(np.float32) * nz.depth_sigma * depth**2
    if nz.dropout > 0:
        depth[rng.random(depth.shape) < nz.dropout] = np.nan
    if nz.outliers > 0:
        stray = rng.random(depth.shape) < nz.outliers
        depth[stray] = rng.uniform(0.3, 4.0, int(stray.sum())).astype(np.float32)
    return depth


def flying_pixels(depth: np.ndarray, share: float, rng: np.random.Generator, jump: float = 0.05) -> np.ndarray:
    """`share` of the pixels at a depth edge (a 4-neighbour more than `jump` x depth away) return a depth drawn
    between theirs and that neighbour's: a real camera's pixel straddling an edge mixes both sides' returns."""
    far = np.full(depth.shape, np.nan, np.float32)  # each pixel's farthest-off neighbour (NaN: none across an edge)
    gap = np.zeros(depth.shape, np.float32)
    with np.errstate(invalid="ignore"):
        for mine, theirs in (
            (np.s_[:, 1:], np.s_[:, :-1]),
            (np.s_[:, :-1], np.s_[:, 1:]),
            (np.s_[1:], np.s_[:-1]),
            (np.s_[:-1], np.s_[1:]),
        ):
            d = np.abs(depth[theirs] - depth[mine])
            wider = (d > jump * np.fmin(depth[mine], depth[theirs])) & (d > gap[mine])
            gap[mine] = np.where(wider, d, gap[mine])
            far[mine] = np.where(wider, depth[theirs], far[mine])
    at = np.flatnonzero(np.isfinite(far))
    at = at[rng.random(len(at)) < share]
    out = depth.copy()
    out.flat[at] += rng.random(len(at)).astype(np.float32) * (far.flat[at] - depth.flat[at])
    return out
