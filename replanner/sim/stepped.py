"""The controller, a kinematic robot and pybullet cameras on one clock this object advances: the same run on any
machine, however fast or busy it is (what the controller's tests drive)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..config import ReplannerConfig
from ..control import JointState, Timeline
from ..errors import InvalidInputError
from ..model.geometry import Shape
from ..model.robot import RobotModel
from ..perception import CameraModel, CloudFrame, CloudRejected, pose_from_config
from ..stack import build_stack
from .camera import PyBulletDepthCamera
from .scene import PyBulletScene


class SteppedSim:
    """Nothing runs by itself: `step()` moves simulated time on by `dt`; the robot follows what it was told, joint
    states and (at `camera_rate`) clouds reach the controller, plan answers due by then are handed over, and the
    controller takes one step. Planning takes `plan_delay` of simulated time (it runs in the stepping thread).

    Args:
        cfg: full config; the controller plans "inline" (see build_stack).
        static: (name, shape, pose) objects known to the world and present in pybullet.
        robot: an already loaded model of cfg.robot.
        dt: [s] of simulated time per step; joint states come every step.
        camera_rate: frames per second of each camera, in simulated time.
        plan_delay: [s] of simulated time between a plan's request and its answer.
        camera_latency: [s] between a frame's exposure and its arrival at perception (a sensor pipeline's delay).
        refuses_jumps: the robot refuses a trajectory that would make it jump and brakes along its path, as
            `replanner robot` does (else it follows whatever it is sent).
    """

    def __init__(
        self,
        cfg: ReplannerConfig,
        static=(),
        *,
        robot: RobotModel | None = None,
        seed: int = 0,
        dt: float = 0.005,
        camera_rate: float = 10.0,
        plan_delay: float = 0.05,
        camera_latency: float = 0.0,
        refuses_jumps: bool = False,
    ):
        robot = robot or RobotModel.from_config(cfg.robot)
        self.t, self.dt = 0.0, float(dt)
        self.timeline = Timeline(robot.home, keep=100_000)  # what the robot follows, its whole history for tests
        self.refused = 0  # trajectories the robot refused (refuses_jumps)
        execute = self._receive if refuses_jumps else self.timeline.add
        self.stack = build_stack(
            cfg, robot=robot, static=static, seed=seed, execute=execute, plan_in="inline", clock=self.clock
        )
        st = self.stack
        st.worker.delay = plan_delay
        self.robot, self.world, self.checker, self.planner, self.gen = (
            st.robot,
            st.world,
            st.checker,
            st.planner,
            st.generator,
        )
        self.perception, self.controller = st.perception, st.controller
        self.scene = PyBulletScene(robot)
        for name, shape, pose in static:
            self.scene.add(name, shape, pose)
        self.cameras = []
        if self.perception is not None:
            for s in cfg.perception.sensors:
                cam = PyBulletDepthCamera(
                    self.scene.client,
                    CameraModel.from_config(s),
                    pose_from_config(s.pose),
                    meshes=self.scene.meshes(),
                )
                self.cameras.append((s.name, cam))
        self.camera_period = 1.0 / camera_rate
        self.camera_latency = camera_latency
        self._next_frame = 0.0
        self._frames: list[tuple[float, CloudFrame]] = []  # (arrival time, frame) in flight
        self.cameras_on = True  # False: the cameras fall silent (tests of the controller's watchdog)
        self.joint_states_on = True  # False: the robot falls silent
        self.rejected: list[str] = []  # frames perception refused
        self.controller.start(thread=False)
        self.step()

    def clock(self) -> float:
        return self.t

    def state(self) -> JointState:
        q, qd = self.timeline.state(self.t)
        return JointState(self.t, q, qd)

    # ------------------------------------------------------------------ obstacles only the cameras see
    def add_obstacle(self, name: str, shape: Shape, pose: np.ndarray) -> None:
        self.scene.add(name, shape, pose)

    def move_obstacle(self, name: str, pose: np.ndarray) -> None:
        self.scene.move(name, pose)

    def remove_obstacle(self, name: str) -> None:
        self.scene.remove(name)

    # ------------------------------------------------------------------ time
    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.t = round(self.t + self.dt, 9)  # a clock without drift: steps add up exactly
            js = self.state()
            if self.joint_states_on:
                self.stack.on_joint_state(js)
            if self.cameras and self.cameras_on and self.t + 1e-9 >= self._next_frame:
                self._next_frame = self.t + self.camera_period
                self.scene.set_q(js.position)
                for name, cam in self.cameras:
                    frame = CloudFrame(name, self.t, cam.cloud(), organized=True)
                    self._frames.append((self.t + self.camera_latency, frame))
            while self._frames and self._frames[0][0] <= self.t + 1e-9:
                try:
                    self.perception.integrate(self._frames.pop(0)[1])
                except CloudRejected as err:  # e.g. no joint state near the frame: the controller hears nothing
                    self.rejected.append(str(err))
            self.stack.worker.deliver()
            self.controller.step()

    def _receive(self, traj, start: float) -> None:
        try:
            self.timeline.receive(traj, start, self.t)
        except InvalidInputError:
            self.refused += 1
            self.timeline.stop_along(self.t, self.robot.limits.acceleration)

    def run_for(self, seconds: float) -> None:
        self.step(max(1, int(math.ceil(seconds / self.dt - 1e-9))))

    def run_until(self, done: Callable[[], bool], within: float, what: str = "the condition") -> float:
        """Step until `done()`; returns the simulated time it took; raises AssertionError after `within` [s]."""
        t0 = self.t
        while not done():
            if self.t - t0 > within:
                edges = [(r.dest, r.reason) for r in self.controller.transitions[-6:]]
                raise AssertionError(f"{what} did not happen within {within} s of simulated time; last: {edges}")
            self.step()
        return self.t - t0

    def close(self) -> None:
        self.stack.close()
        self.scene.close()
