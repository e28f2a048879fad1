"""The simulated cell behind `replanner sim`: the arm under pybullet physics, a scripted operator, ground truth.

The arm follows its commanded trajectories with pybullet's joint motors and reports measured joint states. The
operator's forearm (a capsule) enters the workspace, lingers and leaves, seeded; often it reaches to where the
arm will be a moment later. Obstacles do not push the arm: contacts are measured, not simulated, so a collision
is counted rather than hidden by a deflected arm. Ground truth (contacts, clearance, the obstacle on the planned
path, parts placed) goes out as events. The sim takes plain inputs and calls plain outputs: the entry point wires
them to Zenoh.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

import numpy as np
import pybullet as pb

from ..control.timeline import Timeline
from ..errors import InvalidInputError, ReplannerError
from ..model.robot import RobotModel
from ..trajectory import SampledTrajectory
from ..transport import messages as m
from .bodies import pose_list
from .cell import Cell, ShadowWorld
from .config import CellConfig
from .gripper import SuctionGripper
from .operator import OPERATOR_HZ, Operator
from .truth import GroundTruth

log = logging.getLogger(__name__)

BODIES_HZ = 60.0  # the cameras' view of the cell
REPORT_HZ = 10.0  # clearance events: the least clearance since the last one
MAX_BURST = 50  # steps run back to back when the loop fell behind, between answers to calls


class SimBusyError(ReplannerError):
    """Too many calls wait for the physics loop; try again."""


def _drop(_) -> None:
    pass


class PhysicsSim:
    """The cell: robot, static scene (from the config's `scene:`), part, operator, ground truth, in one loop.

    The loop steps pybullet at `sim.physics_hz` in real time (wall clock); on each step, at their own rates, it
    reports joint states, measures contacts and clearance, checks the path and moves the operator. pybullet is
    used from the loop's thread only: `gripper` and `state` run there through `submit`.

    Args:
        cfg: the cell's config; `sim:` holds rates, noise, the operator's script and the pick-and-place task.
        seed: seeds the operator's script.
        gui: open pybullet's window.
        operator: run the operator's script (default: `sim.operator.enabled`).
        publish_joint_state: called with each measured joint state (a CDR JointState) at `sim.joint_state_hz`.
        publish_truth: called with each ground-truth event, a JSON object as text (`stamp` [s], `kind`, fields).
        publish_bodies: called at BODIES_HZ with JSON text: `stamp`, `q` [rad] and the forearm's and the part's
            poses ([x, y, z, qx, qy, qz, qw], null while away) of one instant, for the simulated cameras.
    """

    def __init__(
        self,
        cfg: CellConfig,
        *,
        seed: int = 0,
        gui: bool = False,
        operator: bool | None = None,
        publish_joint_state: Callable[[bytes], None] = _drop,
        publish_truth: Callable[[str], None] = _drop,
        publish_bodies: Callable[[str], None] = _drop,
    ):
        self.cfg, self.seed = cfg, seed
        self.sc = sc = cfg.sim
        self.publish_joint_state = publish_joint_state
        self.publish_truth = publish_truth
        self.publish_bodies = publish_bodies
        self.robot = RobotModel.from_config(cfg.robot)
        self.cell = Cell(cfg, self.robot, gui=gui)
        q0 = self.robot.home
        self.timeline = Timeline(q0)
        self.suction = SuctionGripper(self.cell, sc.task, self.event)
        self.op_on = sc.operator.enabled if operator is None else operator
        self.shadow = ShadowWorld(self.robot, sc.operator)
        self.operator = Operator(
            sc.operator,
            np.random.default_rng(seed),
            time.time(),
            cell=self.cell,
            shadow=self.shadow,
            timeline=self.timeline,
            event=self.event,
        )
        self.truth = GroundTruth(self.cell, self.shadow, self.timeline, self.event)
        hz = sc.physics_hz
        self.every = {  # physics steps between each activity
            "js": max(1, round(hz / sc.joint_state_hz)),
            "truth": max(1, round(hz / sc.truth_rate_hz)),
            "path": max(1, round(hz / sc.path_check_hz)),
            "bodies": max(1, round(hz / BODIES_HZ)),
            "operator": max(1, round(hz / OPERATOR_HZ)),
            "report": max(1, round(hz / REPORT_HZ)),
        }
        self._calls: queue.Queue = queue.Queue(maxsize=64)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._window = math.inf  # least clearance since the last report [m]
        self.q = q0.copy()
        self.qd = np.zeros_like(q0)
        self.steps = 0
        self.rejected = 0
        self.dropped = 0.0  # [s] of backlog walked without physics on a busy machine
        self.late = 0  # trajectories from rest that arrived after their start
        self.t = time.time()  # the last physics step's time [s]
        self._t0, self._k = self.t, 0  # step k runs at _t0 + k / physics_hz
        self._rtf_mark: tuple[float, int] | None = None

    # ------------------------------------------------------------------ running
    def start(self) -> PhysicsSim:
        self.event("start", seed=self.seed, operator=self.op_on, physics_hz=self.sc.physics_hz)
        self._t0, self._k = time.time(), 0
        self._thread = threading.Thread(target=self._loop, name="physics", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        self.event("stop", steps=self.steps)
        while not self._calls.empty():
            self._calls.get_nowait()[0].cancel()
        self.shadow.close()
        self.cell.close()

    def event(self, kind: str, stamp: float | None = None, **data) -> None:
        """Publish a ground-truth event stamped `stamp` [s, wall clock] (now if None)."""
        msg = {"stamp": time.time() if stamp is None else stamp, "kind": kind, **data}
        self.publish_truth(json.dumps(msg))

    # ------------------------------------------------------------------ inputs
    def on_trajectory(self, payload: bytes) -> None:
        """A trajectory message (CDR) from the controller; thread-safe. Invalid ones are counted and logged."""
        try:
            start, traj = SampledTrajectory.from_message(payload, self.robot.joint_names)
        except InvalidInputError as err:
            self.rejected += 1
            log.warning("trajectory rejected: %s", err)
            return
        self.add_trajectory(start, traj)

    def stop_along(self, reason: str) -> None:
        """The robot's own stop (the service is lost): brake along the path it is on (thread-safe)."""
        if self.timeline.stop_along(self.t, self.robot.limits.acceleration) is not None:
            log.warning("braking along the path: %s", reason)
            self.event("robot_stop", reason=reason)

    def add_trajectory(self, start: float, traj: SampledTrajectory) -> None:
        """Follow `traj` from `start` [s, wall clock] on, replacing what would run from then; one from rest that
        arrives after its start starts when it arrives (thread-safe)."""
        late = self.timeline.receive(traj, start, self.t, tolerance=None)  # tracking lags: no jump test here
        if late > 0.0 and np.abs(traj.state_at(0.0)[1]).max() < 1e-6:
            self.late += 1
            log.warning("a trajectory from rest arrived %.0f ms after its start: started on arrival", late * 1e3)

    def submit(self, fn: Callable, *args) -> Future:
        """Run `fn(*args)` in the loop's thread between steps; never blocks (raises SimBusyError when full).

        The future's done-callbacks run in the loop's thread: they must not block either.
        """
        fut: Future = Future()
        try:
            self._calls.put_nowait((fut, fn, args))
        except queue.Full:
            raise SimBusyError("the simulator is busy; try again") from None
        return fut

    def gripper(self, request: dict) -> dict:
        """The suction gripper: `{"command": "grasp" | "release"}` (loop thread: use `submit`)."""
        return self.suction.command(request)

    def state(self) -> dict:
        """The part, the operator's presence and the arm's measured position [rad] (loop thread: use `submit`)."""
        return {**self.suction.report(), "operator": self.operator.present, "position": self.q.tolist()}

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        dt = 1.0 / self.sc.physics_hz
        while not self._stop.is_set():
            self.advance(time.time())
            self._run_calls()
            delay = self._t0 + self._k * dt - time.time()
            if delay > 0:
                time.sleep(delay)

    def advance(self, now: float) -> None:
        """Run the steps due by `now` [s]: under physics up to MAX_BURST of them; a longer backlog (a busy machine)
        is walked kinematically along the command (loop thread)."""
        dt = 1.0 / self.sc.physics_hz
        due = int((now - self._t0) / dt)
        burst = 0
        while self._k <= due and burst < MAX_BURST:  # fell behind: catch up, but keep answering calls
            self._tick(self._k, self._t0 + self._k * dt)
            self._k += 1
            burst += 1
        if self._k <= due:
            self._skip(self._k, due + 1)
            self.dropped += (due + 1 - self._k) * dt
            self._k = due + 1

    def _skip(self, k0: int, k1: int) -> None:
        # a real robot's controller keeps following its command while the sim computes nothing: the arm goes on
        # along it (a frozen arm jumped after the backlog and overshot into the bins), contacts measured on the way
        dt, every = 1.0 / self.sc.physics_hz, self.every
        for k in range(k0, k1):
            t = self._t0 + k * dt
            if self.op_on and k % every["operator"] == 0:
                self.operator.operate(t)  # the operator keeps its pace too
            if k % every["truth"] == 0 or k == k1 - 1:
                self.t = t
                self.cell.set_state(*self.timeline.state(t))
                self.suction.follow_tip()
                self._measure(t)
            if self.op_on and k % every["path"] == 0:
                self.truth.check_path(t, self.operator.pose(), self.operator.count)  # reactions are timed from it

    def _measure(self, t: float) -> None:
        g = self.suction
        c = self.truth.measure(t, holding=g.holding, part_in=g.part_in, operator=self.operator.present)
        self._window = min(self._window, c)

    def _tick(self, k: int, t: float) -> None:
        """Physics step `k`, at `t` [s], and whatever is due on it."""
        self.t = t
        every, op_on = self.every, self.op_on
        self._step(t, operate=op_on and k % every["operator"] == 0)
        if k % every["js"] == 0:
            self._publish_js(t)
        if k % every["truth"] == 0:
            self._measure(t)
        if op_on and k % every["path"] == 0:
            self.truth.check_path(t, self.operator.pose(), self.operator.count)
        if k % every["bodies"] == 0:
            self._publish_bodies(t)
        if k % every["report"] == 0:
            w = self._window
            # real-time factor: physics seconds stepped per wall second (a busy machine drops steps)
            wall, steps = time.time(), self.steps
            mark_wall, mark_steps = self._rtf_mark or (wall, steps)
            rtf = (steps - mark_steps) / self.sc.physics_hz / (wall - mark_wall) if wall > mark_wall else None
            self._rtf_mark = (wall, steps)
            self.event(
                "clearance",
                t,
                clearance=None if w == math.inf else round(w, 4),
                operator=self.operator.present,
                on_path=self.truth.on_path,
                rtf=None if rtf is None else round(rtf, 3),
                dropped=round(self.dropped, 3),
                late=self.late,
            )
            self._window = math.inf
        self.steps += 1

    def _step(self, t: float, operate: bool = False) -> None:
        cell = self.cell
        q_d, qd_d = self.timeline.state(t)
        n = len(cell.joint_ids)
        pb.setJointMotorControlArray(
            cell.body,
            cell.joint_ids,
            pb.POSITION_CONTROL,
            targetPositions=q_d.tolist(),
            targetVelocities=qd_d.tolist(),
            positionGains=[0.3] * n,
            velocityGains=[1.0] * n,
            forces=cell.forces,
            physicsClientId=cell.client,
        )
        if operate:
            self.operator.operate(t)
        pb.stepSimulation(physicsClientId=cell.client)
        self.suction.follow_tip()

    def _publish_js(self, t: float) -> None:
        self.q, self.qd = self.cell.joint_states()
        self.publish_joint_state(m.encode_joint_state(t, self.robot.joint_names, self.q, self.qd))

    def _publish_bodies(self, t: float) -> None:
        # the arm too: cameras render one instant, or a carried part trails the hand into the map
        q, _ = self.cell.joint_states()
        msg = {
            "stamp": t,
            "q": q.tolist(),
            "operator": pose_list(self.operator.pose()),
            "part": pose_list(self.suction.pose),
        }
        self.publish_bodies(json.dumps(msg))

    def _run_calls(self) -> None:
        while True:
            try:
                fut, fn, args = self._calls.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn(*args))
            except Exception as err:
                fut.set_exception(err)
