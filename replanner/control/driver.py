"""Robot drivers. `KinematicDriver` follows trajectories exactly (like ros2_control's mock hardware)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..trajectory import Trajectory
from .timeline import Timeline

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointState:
    """Measured joint positions [rad] and velocities [rad/s] at `stamp` [s, the controller's clock]."""

    stamp: float
    position: np.ndarray
    velocity: np.ndarray


class KinematicDriver:
    """Follows the trajectories it is sent exactly and reports joint states at `rate_hz`.

    Args:
        q0: initial configuration [rad].
        rate_hz: joint-state rate.
        on_state: called with each JointState (from the driver's thread; must not block).
        clock: time source [s], shared with the controller.
        wait: wait(seconds) between states; default: a real wait (a test passes one that moves its own clock).
        acceleration: [rad/s^2] per joint the robot's own stops may use (after a stall, or when told to stop).
        stall_after: a gap between two steps this long [s] is a stall (see `stall_check`); None: never (a robot
            simulated in the controller's own process is only starved, not stalled).
    """

    def __init__(
        self,
        q0,
        rate_hz: float = 200.0,
        on_state: Callable[[JointState], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], object] | None = None,
        acceleration=None,
        stall_after: float | None = None,
    ):
        self.timeline = Timeline(q0)
        self.rate_hz = float(rate_hz)
        self.clock = clock
        self._subscribers: list[Callable[[JointState], None]] = [on_state] if on_state else []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wait = wait or self._stop.wait
        self.silent = False  # tests stop the stream to exercise the controller's watchdog
        if stall_after is not None and acceleration is None:
            raise ValueError("a driver that stops after a stall needs the acceleration it may stop with")
        self.acceleration, self.stalls, self.stall_after = acceleration, 0, stall_after

    def subscribe(self, callback: Callable[[JointState], None]) -> None:
        self._subscribers.append(callback)

    def execute(self, traj: Trajectory, start_time: float) -> None:
        """Run `traj` from `start_time` [clock s] on, replacing whatever would run from then."""
        self.timeline.add(traj, start_time, self.clock())

    def state(self, t: float | None = None) -> JointState:
        t = self.clock() if t is None else t
        q, qd = self.timeline.state(t)
        return JointState(t, q, qd)

    def start(self) -> KinematicDriver:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="kinematic-driver", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def stall_check(self, last: float, now: float) -> bool:
        """After a stall (no step for `stall_after` [s]: the process was stopped or starved) the robot does not
        catch up with its queue in one step: it goes on from where it was, and brakes along its path."""
        gap = now - last
        if self.stall_after is None or gap <= self.stall_after:
            return False
        self.timeline.delay(last, gap)
        self.timeline.stop_along(now, self.acceleration)
        self.stalls += 1
        log.warning("the robot stalled for %.3f s: it went on from where it was and braked along its path", gap)
        return True

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = last = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            self.stall_check(last, now)
            last = now
            if not self.silent:
                js = self.state()
                for cb in list(self._subscribers):
                    try:
                        cb(js)
                    except Exception:  # a subscriber's bug must not stop the robot's state stream
                        log.exception("joint-state subscriber failed")
            next_t += period
            delay = next_t - self.clock()
            if delay > 0:
                self._wait(delay)
            else:
                next_t = self.clock()  # fell behind: do not burst
