"""The controller on a kinematic robot, with cameras rendered by pybullet: try it without a physics simulator.

The kinematic driver thread, a camera thread (the perception pipeline integrates, the controller hears of the new
map) and the controller thread share this process; pybullet renders the cameras in a child process, as real
cameras are other devices (pybullet holds the interpreter while it renders: tens of ms in which no thread of the
controller could run).
Obstacles added here exist only in pybullet: the controller learns of them through the cameras.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import threading
import time

import numpy as np
import pybullet as pb

from ..config import ReplannerConfig
from ..control import KinematicDriver
from ..model.geometry import Shape
from ..model.robot import RobotModel
from ..perception import CameraModel, CloudFrame, CloudRejected, pose_from_config
from ..stack import build_stack
from .camera import PyBulletDepthCamera
from .scene import PyBulletScene

log = logging.getLogger(__name__)
START_TIMEOUT = 120.0  # [s] for the renderer and the first frames: a liveness guard that fails loudly, not a decision


class KinematicSim:
    """Robot, world, perception, controller and simulated cameras wired together.

    Args:
        cfg: full config (robot, collision, perception with sensors, planning, controller).
        static: (name, shape, pose) objects known to the world and present in the simulation.
        camera_rate: frames per second per camera (rendering holds the GIL: keep images small in-process).
    """

    def __init__(
        self,
        cfg: ReplannerConfig,
        static=(),
        *,
        robot: RobotModel | None = None,
        camera_rate: float = 10.0,
        seed: int | None = None,
    ):
        self.cfg = cfg
        robot = robot or RobotModel.from_config(cfg.robot)
        self.driver = KinematicDriver(robot.home, rate_hz=cfg.controller.driver_rate_hz)
        self.stack = build_stack(cfg, robot=robot, static=static, seed=seed, execute=self.driver.execute)
        st = self.stack
        self.robot, self.world, self.checker, self.planner, self.gen = (
            st.robot,
            st.world,
            st.checker,
            st.planner,
            st.generator,
        )
        self.perception, self.controller = st.perception, st.controller
        self.driver.subscribe(st.on_joint_state)
        self._pb_lock = threading.Lock()
        self.scene = PyBulletScene(self.robot)  # the ground truth benches measure with (the renderer has its own)
        for name, shape, pose in static:
            self.scene.add(name, shape, pose)
        self.sensors = [s.name for s in cfg.perception.sensors] if self.perception is not None else []
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._send_lock = threading.Lock()
        self._renderer = ctx.Process(target=_render, args=(child, cfg, list(static)), name="cameras", daemon=True)
        self.camera_rate = camera_rate
        self.cameras_on = True
        self.map_updates: list[tuple[float, int]] = []  # (time, occupied voxels)
        self.frame_hooks: list = []  # called with the time after each integrated frame (benches measure here)
        self._unseen = set(self.sensors)  # cameras whose first frame is not in the map yet
        self._all_seen = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def _tell(self, *msg) -> None:
        with self._send_lock:
            self._conn.send(msg)

    # ------------------------------------------------------------------ obstacles only the cameras see
    def add_obstacle(self, name: str, shape: Shape, pose: np.ndarray) -> None:
        with self._pb_lock:
            self.scene.add(name, shape, pose)
        self._tell("add", name, shape, pose)

    def move_obstacle(self, name: str, pose: np.ndarray) -> None:
        with self._pb_lock:
            self.scene.move(name, pose)
        self._tell("move", name, pose)

    def remove_obstacle(self, name: str) -> None:
        with self._pb_lock:
            self.scene.remove(name)
        self._tell("remove", name)

    def closest_points(self, q, name: str, max_distance: float) -> list:
        """Ground truth: pybullet's closest points between the arm at q and obstacle `name`, within `max_distance` [m]
        (pybullet's tuples: the distance at [8])."""
        with self._pb_lock:
            self.scene.set_q(q)
            return pb.getClosestPoints(
                self.scene.body, self.scene.objects[name], max_distance, physicsClientId=self.scene.client
            )

    # ------------------------------------------------------------------ running
    def start(self) -> KinematicSim:
        self.driver.start()
        self.controller.start()
        if self.sensors:
            self._renderer.start()
            if not self._conn.poll(START_TIMEOUT):
                raise RuntimeError(f"the camera renderer did not start within {START_TIMEOUT:.0f} s")
            self._conn.recv()  # ready
            t = threading.Thread(target=self._camera_loop, name="cameras", daemon=True)
            t.start()
            self._threads.append(t)
        # every camera in the map before goals come: the controller refuses goals while one is silent
        if self.sensors and not self._all_seen.wait(START_TIMEOUT):
            raise RuntimeError(
                f"cameras {sorted(self._unseen)} sent no frame into the map within {START_TIMEOUT:.0f} s of starting "
                "(a first start compiles the perception kernels: see that numba's cache directory is writable)"
            )
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=3.0)
        if self._renderer.is_alive():
            self._tell("stop")
            self._renderer.join(timeout=5.0)
            if self._renderer.is_alive():
                self._renderer.kill()
        self.stack.close()
        self.driver.stop()
        with self._pb_lock:
            self.scene.close()

    def _camera_loop(self) -> None:
        period = 1.0 / self.camera_rate
        next_t = time.monotonic()
        while not self._stop.is_set():
            if self.cameras_on:
                js = self.driver.state()
                self._tell("render", js.position)
                for name, cloud in self._conn.recv():  # every camera, rendered at that joint state
                    try:
                        self.perception.integrate(
                            CloudFrame(name, js.stamp, cloud, organized=True)
                        )  # tells the controller
                    except CloudRejected as err:
                        log.warning("cloud rejected: %s", err)
                        continue
                    now = time.monotonic()
                    self.map_updates.append((now, len(self.world.occupancy)))
                    self._unseen.discard(name)
                    if not self._unseen:
                        self._all_seen.set()
                    for hook in list(self.frame_hooks):
                        hook(now)
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_t = time.monotonic()


def _render(conn, cfg: ReplannerConfig, static) -> None:
    """The cameras' process: the robot and the objects in pybullet; renders every camera when asked."""
    robot = RobotModel.from_config(cfg.robot)
    scene = PyBulletScene(robot)
    for name, shape, pose in static:
        scene.add(name, shape, pose)
    meshes = scene.meshes()
    cams = [
        (s.name, PyBulletDepthCamera(scene.client, CameraModel.from_config(s), pose_from_config(s.pose), meshes=meshes))
        for s in cfg.perception.sensors
    ]
    conn.send("ready")
    while True:
        try:
            op, *args = conn.recv()
        except EOFError:
            break
        if op == "stop":
            break
        if op == "render":
            scene.set_q(args[0])
            conn.send([(name, cam.cloud()) for name, cam in cams])
        else:
            getattr(scene, op)(*args)  # add, move, remove
    scene.close()
