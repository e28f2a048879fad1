"""`replanner robot --kinematic`: a robot that follows the trajectory stream exactly and publishes joint states."""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time

import zenoh

from replanner.config import ReplannerConfig
from replanner.control import JointState, KinematicDriver
from replanner.errors import InvalidInputError
from replanner.model.robot import RobotModel
from replanner.trajectory import SampledTrajectory
from replanner.transport import messages as m
from replanner.transport.keys import Keys
from replanner.transport.refusals import Refusals, access_control_on
from replanner.transport.watch import ServiceWatch

log = logging.getLogger(__name__)


class KinematicRobotNode:
    def __init__(self, cfg: ReplannerConfig, session: zenoh.Session, q0=None, clock=time.time):
        self.robot = RobotModel.from_config(cfg.robot)
        self.keys = Keys(self.robot.name, cfg.transport.namespace)
        self.session = session
        self.cfg = cfg
        self.driver = KinematicDriver(
            self.robot.home if q0 is None else q0,
            rate_hz=cfg.controller.driver_rate_hz,
            clock=clock,
            acceleration=self.robot.limits.acceleration,
            stall_after=cfg.controller.robot_stall_after,
        )
        self.rejected = 0
        self.stops = 0  # stops of its own: the service was lost, or its trajectory could not be followed
        self.watch: ServiceWatch | None = None

    def start(self) -> KinematicRobotNode:
        self.pub = self.session.declare_publisher(self.keys.joint_states)
        self.driver.subscribe(self._publish)
        self.sub = self.session.declare_subscriber(self.keys.trajectory, self._on_trajectory)
        self.driver.start()
        self.watch = ServiceWatch(self.session, self.keys, self.cfg.controller.robot_watchdog, self._service_lost)
        return self

    def stop(self) -> None:
        if self.watch is not None:
            self.watch.close()
        self.sub.undeclare()
        self.driver.stop()

    def _service_lost(self, reason: str) -> None:
        """No one watches the path any more: brake along it."""
        if self.driver.timeline.stop_along(self.driver.clock(), self.robot.limits.acceleration) is not None:
            self.stops += 1
            log.warning("braking along the path: the service is lost (%s)", reason)

    def _publish(self, js: JointState) -> None:
        self.pub.put(m.encode_joint_state(js.stamp, self.robot.joint_names, js.position, js.velocity))

    def _on_trajectory(self, sample) -> None:
        try:
            start, traj = SampledTrajectory.from_message(sample.payload.to_bytes(), self.robot.joint_names)
        except InvalidInputError as err:
            self.rejected += 1
            log.warning("trajectory rejected: %s", err)
            return
        try:
            late = self.driver.timeline.receive(traj, start, self.driver.clock())
        except InvalidInputError as err:
            self.rejected += 1
            # the sender no longer wants the motion running: going on with it to its end would be following no one
            stop = self.driver.timeline.stop_along(self.driver.clock(), self.robot.limits.acceleration)
            log.warning("trajectory rejected: %s%s", err, "; braking along the path" if stop is not None else "")
            self.stops += stop is not None
            return
        if late > 0.0:
            log.warning(
                "a trajectory runs %.0f ms after its stamp (the motion from rest it belongs to came late)", late * 1e3
            )


def run(cfg: ReplannerConfig, conf: zenoh.Config, q0=None) -> None:
    from replanner.transport.session import open_session

    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    refusals = Refusals.capture() if access_control_on(conf) else None
    session = open_session(conf)
    try:
        node = KinematicRobotNode(cfg, session, q0).start()
        print(f"replanner: kinematic {node.robot.name} on {node.keys.root} (Ctrl-C stops)", file=sys.stderr, flush=True)
        done.wait()
        node.stop()
        if refusals is not None:
            log.warning(
                "refused %d messages by access control; %d trajectories rejected", refusals.total, node.rejected
            )
    finally:
        session.close()
