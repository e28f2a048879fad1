"""The commands the controller sends the robot: trajectories from start times, brakes, slow-downs and resumes."""

from __future__ import annotations

import logging
from collections.abc import Callable

from ..trajectory import Trajectory, TrajectoryError, TrajectoryGenerator
from .timeline import Timeline

log = logging.getLogger(__name__)


class Moves:
    """Sends trajectories and keeps the same timeline the robot follows.

    Args:
        q0: rest configuration [rad] before the first trajectory.
        generator: brakes, slows and resumes along the running curve.
        execute: execute(trajectory, start [clock s]) sends it to the robot.
        clock: the controller's clock [s].
        latency: [s] between deciding a change and the robot starting it.
        log_event: log_event(what, **details) records what was sent.
    """

    def __init__(
        self,
        q0,
        generator: TrajectoryGenerator,
        execute: Callable[[Trajectory, float], None],
        clock: Callable[[], float],
        latency: float,
        log_event: Callable[..., None],
    ):
        self.timeline = Timeline(q0)
        self.gen, self._execute, self.clock, self.latency = generator, execute, clock, latency
        self.log_event = log_event

    def send(self, traj: Trajectory, start: float) -> None:
        """Run `traj` from `start` [clock s] on, replacing what would run from then."""
        self.timeline.add(traj, start)
        self._execute(traj, start)

    def _running(self) -> tuple[float, Trajectory, float] | None:
        """(start, trajectory, time into it when a change decided now starts), or None at rest."""
        now = self.clock()
        seg = self.timeline.active(now)
        if seg is None or now - seg[0] >= seg[1].duration:
            return None
        start, traj = seg
        return start, traj, min(now - start + self.latency, traj.duration)

    def brake(self) -> Trajectory | None:
        """The shortest jerk-limited stop along the running curve; None if the arm is at rest."""
        run = self._running()
        if run is None:
            return None
        start, traj, t = run
        stop = self.gen.brake(traj, t)
        self.send(stop, start + t)
        self.log_event("brake", duration=stop.duration)
        return stop

    def slow_down(self, factor: float) -> None:
        """Go on along the same curve at `factor` of the nominal speed (while a new path is planned)."""
        run = self._running()
        if factor >= 1.0 or run is None:
            return
        start, traj, t = run
        try:
            slow = self.gen.slow_down(traj, t, factor)
        except TrajectoryError as err:
            log.warning("cannot slow down: %s", err)
            return
        self.send(slow, start + t)

    def resume(self) -> None:
        """From a brake's stop on to the end of its curve, at the nominal limits."""
        seg = self.timeline.active(self.clock())
        if seg is None:
            return
        rest = self.gen.resume(seg[1])
        if rest.duration > 0:
            self.send(rest, self.clock() + self.latency)
