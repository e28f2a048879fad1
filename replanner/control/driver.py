"""Robot drivers. `KinematicDriver` follows trajectories exactly (like ros2_control's mock hardware)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..trajectory.generator import Trajectory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointState:
    """Measured joint positions [rad] and velocities [rad/s] at `stamp` [s, the controller's clock]."""

    stamp: float
    position: np.ndarray
    velocity: np.ndarray


class Timeline:
    """Trajectories, each from an absolute start time; a later one replaces what remains of the earlier ones."""

    def __init__(self, q0: np.ndarray):
        self._segments: list[tuple[float, Trajectory]] = []
        self._rest = np.asarray(q0, dtype=float).copy()
        self._lock = threading.Lock()

    def add(self, traj: Trajectory, start: float) -> None:
        with self._lock:
            self._segments = [(t, tr) for t, tr in self._segments if t < start]
            self._segments.append((float(start), traj))

    def active(self, t: float) -> tuple[float, Trajectory] | None:
        """(start, trajectory) running at time t, or None before the first one."""
        with self._lock:
            seg = None
            for start, traj in self._segments:
                if start <= t:
                    seg = (start, traj)
            return seg

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        seg = self.active(t)
        if seg is None:
            return self._rest.copy(), np.zeros_like(self._rest)
        q, qd, _ = seg[1].state_at(t - seg[0])
        return q, qd


class KinematicDriver:
    """Follows the trajectories it is sent exactly and reports joint states at `rate_hz`.

    Args:
        q0: initial configuration [rad].
        rate_hz: joint-state rate.
        on_state: called with each JointState (from the driver's thread; must not block).
        clock: time source [s], shared with the controller.
    """

    def __init__(
        self,
        q0,
        rate_hz: float = 200.0,
        on_state: Callable[[JointState], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.timeline = Timeline(q0)
        self.rate_hz = float(rate_hz)
        self.clock = clock
        self._subscribers: list[Callable[[JointState], None]] = [on_state] if on_state else []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.silent = False  # tests stop the stream to exercise the controller's watchdog

    def subscribe(self, callback: Callable[[JointState], None]) -> None:
        self._subscribers.append(callback)

    def execute(self, traj: Trajectory, start_time: float) -> None:
        """Run `traj` from `start_time` [clock s] on, replacing whatever would run from then."""
        self.timeline.add(traj, start_time)

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

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = self.clock()
        while not self._stop.is_set():
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
                self._stop.wait(delay)
            else:
                next_t = self.clock()  # fell behind: do not burst


class SampledTrajectory:
    """A trajectory given as points (time, q, qd, qdd), e.g. a received JointTrajectory; quintic Hermite between.

    Position, velocity and acceleration are continuous and exact at the points; between points sampled every
    10 ms from a jerk-limited trajectory, positions differ from it by about 1e-5 rad.
    """

    def __init__(self, times, q, qd, qdd):
        self.times = np.asarray(times, dtype=float)
        self.q, self.qd, self.qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        if len(self.times) < 1 or self.q.shape != self.qd.shape or self.q.shape != self.qdd.shape:
            raise ValueError("times, q, qd and qdd must describe the same points")

    @classmethod
    def from_message(cls, data: bytes, joint_names) -> tuple[float, SampledTrajectory]:
        """(start [s], trajectory) of a JointTrajectory CDR message; raises InvalidInputError."""
        from ..transport.messages import decode_trajectory

        start, t, q, qd, qdd = decode_trajectory(data, joint_names)
        return start, cls(t, q, qd, qdd)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ts = self.times
        if t <= ts[0] or len(ts) == 1:
            return self.q[0].copy(), self.qd[0].copy(), self.qdd[0].copy()
        if t >= ts[-1]:
            return self.q[-1].copy(), np.zeros_like(self.q[-1]), np.zeros_like(self.q[-1])
        i = int(np.searchsorted(ts, t, side="right") - 1)
        h = ts[i + 1] - ts[i]
        u = (t - ts[i]) / h
        p0, v0, a0 = self.q[i], self.qd[i] * h, self.qdd[i] * h * h
        p1, v1, a1 = self.q[i + 1], self.qd[i + 1] * h, self.qdd[i + 1] * h * h
        c = [p0, v0, a0 / 2]
        d, e, f = p1 - p0 - v0 - a0 / 2, v1 - v0 - a0, a1 - a0
        c += [10 * d - 4 * e + f / 2, -15 * d + 7 * e - f, 6 * d - 3 * e + f / 2]
        q = sum(ck * u**k for k, ck in enumerate(c))
        qd = sum(k * ck * u ** (k - 1) for k, ck in enumerate(c) if k) / h
        qdd = sum(k * (k - 1) * ck * u ** (k - 2) for k, ck in enumerate(c) if k > 1) / (h * h)
        return q, qd, qdd
