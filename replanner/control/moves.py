"""The commands the controller sends the robot: trajectories from start times, brakes, slow-downs and resumes."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

import numpy as np

from ..trajectory import Trajectory, TrajectoryError, TrajectoryGenerator
from .liveness import STANDING, record_gap
from .timeline import Timeline

log = logging.getLogger(__name__)

LATE_START = 0.1  # [s] a motion from rest this far behind its stamp on the measured arm was started late
FOLLOWING = 0.01  # [rad] the measured arm this close to the path is following it
SPLICE_DEFER = 0.25  # [s] a slow-down waits this long at most for a splice to land (a brake never waits)


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
        lead: float = 0.0,
    ):
        self.timeline = Timeline(q0)
        self.gen, self._execute, self.clock, self.latency = generator, execute, clock, latency
        self.lead = max(lead, latency)  # a motion from rest: no hurry, and it must reach the robot before it starts
        self.log_event = log_event
        self.sent = 0  # trajectories sent so far (the latency account times decision -> command)
        self._splice: object | None = None  # the last splice sent (a slow-down before it lands slows it instead)

    def send(self, traj: Trajectory, start: float) -> None:
        """Run `traj` from `start` [clock s] on, replacing what would run from then."""
        self.timeline.add(traj, start, self.clock())
        self._execute(traj, start)
        self.sent += 1

    def send_planned(self, traj: Trajectory, land: float | None = None) -> float:
        """Run `traj` from `land` (a splice) or, one from rest, once it has had time to reach the robot; returns its
        start [clock s]."""
        start = self.clock() + self.lead if land is None else land
        self.send(traj, start)
        if land is not None:
            self._splice = traj
        return start

    def resync(self, q, now: float, qd=None):
        """The measured arm `q` [rad] well behind a motion from rest that should be under way, moving as the motion
        does there (`qd` [rad/s], if given: a robot that stopped on its own is not late): the robot got it late and
        started it on arrival, so the record is moved to when it started (every brake, slow-down and splice is then
        computed from where the arm is, not from where it would be). Returns q."""
        seg = self.timeline.active(now)
        if q is None or seg is None or self.timeline.later(now):
            return q
        start, traj = seg
        t = now - start
        if not (LATE_START < t < min(traj.duration, 1.0)) or np.abs(traj.state_at(0.0)[1]).max() > 1e-6:
            return q
        ts = np.arange(0.0, t, 0.005)
        gap = np.linalg.norm(traj.evaluate(ts, order=0)[0] - q, axis=1)
        ts = np.linspace(max(ts[np.argmin(gap)] - 0.005, 0.0), ts[np.argmin(gap)] + 0.005, 21)  # then finer
        gap = np.linalg.norm(traj.evaluate(ts, order=0)[0] - q, axis=1)
        k = int(np.argmin(gap))
        if qd is not None:
            v = traj.state_at(ts[k])[1]
            if np.abs(np.asarray(qd) - v).max() > 0.1 + 0.25 * np.abs(v).max():  # [rad/s]: stopped, not late
                return q
        if t - ts[k] > LATE_START and gap[k] < FOLLOWING:
            self.timeline.shift(traj, start + t - ts[k])
            self.log_event("resync", late=round(t - ts[k], 3))
        return q

    def settle(self, js, tolerance: float) -> str | None:
        """Before a plan from rest: the measured arm `js` standing away from where the record has it (the robot
        stopped on its own: a refused trajectory, a protective stop) makes the record hold it where it stands, so the
        plan starts there. Returns why no plan can start yet (the arm still moves, off the record by more than
        `tolerance` [rad]), else None."""
        off = record_gap(js, self.timeline).max()
        if off <= FOLLOWING:
            return None
        if np.abs(js.velocity).max() < STANDING:
            self.timeline.hold(js.position, js.stamp)
            self.log_event("settled", off=round(float(off), 4))
            return None
        if off > tolerance:
            return f"the arm still moves, {off:.3f} rad from where it was told to be: send the goal once it stands"
        return None

    def speed_factor(self) -> float | None:
        """The share of its nominal speed the running motion is timed at, or None at rest."""
        run = self._running()
        if run is None:
            return None
        traj = run[1]
        return float((traj.limits.velocity / traj.nominal.velocity).min())

    def _running(self) -> tuple[float, Trajectory, float] | None:
        """(start, trajectory, time into it when a change decided now starts), or None at rest."""
        now = self.clock()
        seg = self.timeline.active(now + self.latency)  # a motion sent to start by then (a swerve) is the one to change
        if seg is None or now - seg[0] >= seg[1].duration:
            return None
        start, traj = seg
        return start, traj, min(now - start + self.latency, traj.duration)

    def brake(self) -> Trajectory | None:
        """The shortest jerk-limited stop along the running curve; None if the arm is at rest. A motion sent but
        not started yet (a resume, a plan from rest) is called off: replaced at its start by a stop at its start."""
        run = self._running()
        if run is None:
            later = self.timeline.later(self.clock())
            if later:
                start, traj = later[0]
                self.send(self.gen.brake(traj, 0.0), start)
                self.log_event("brake", duration=0.0)
            return None
        start, traj, t = run
        stop = self.gen.brake(traj, t)
        self.send(stop, start + t)
        self.log_event("brake", duration=stop.duration)
        return stop

    def _pending_splice(self) -> tuple[float, Trajectory] | None:
        """(land, trajectory) of the last splice sent if it is all that is still to start, within SPLICE_DEFER [s]."""
        later = self.timeline.later(self.clock() + self.latency)
        if len(later) != 1 or later[0][1] is not self._splice or not isinstance(self._splice, Trajectory):
            return None
        land, traj = later[0]
        return (land, traj) if land - self.clock() - self.latency <= SPLICE_DEFER else None

    def slow_down(self, factor: float) -> None:
        """Go on along the same curve at `factor` <= 1 of the nominal speed (1: back to it). With a splice about to
        land, the splice is slowed from where it lands: slowing the motion before it would call it off."""
        run = self._running()
        if factor > 1.0 or run is None:
            return
        if (pending := self._pending_splice()) is not None:
            land, spliced = pending
            try:
                slow = self.gen.slow_down(spliced, 0.0, factor)
            except TrajectoryError as err:
                log.warning("cannot slow the splice down: %s", err)
            else:
                self.send(slow, land)
                self._splice = slow
                return
        start, traj, t = run
        try:
            slow = self.gen.slow_down(traj, t, factor)
        except TrajectoryError as err:
            log.warning("cannot slow down: %s", err)
            return
        self.send(slow, start + t)

    def retime(self, factor: float) -> float | None:
        """Re-time the motion to `factor` of its nominal speed: down at once, up in 20 % steps (no back and forth
        for every small change). Returns the factor it had if it changed, else None."""
        current = self.speed_factor()
        if current is None or not (factor < current - 0.02 or (current < 0.999 and factor > 1.2 * current + 0.02)):
            return None
        if factor > current and self.timeline.later(self.clock()):
            return None  # a splice on its way brings its own speed: a retime now would call it off
        self.slow_down(min(factor, 1.0))
        return current

    def swerve(self, detours: Callable[[Trajectory, float], Iterable[tuple[np.ndarray, np.ndarray]]]) -> bool:
        """Splice the first of `detours(trajectory, t)` whose own segments are collision-free onto the running
        motion at t (when a change decided now starts), at the limits it runs at; False when none fits (nothing
        sent). Each detour is (path from the state at t, its own segments)."""
        run, checker = self._running(), self.gen.checker
        if run is None or checker is None or not isinstance(run[1], Trajectory) or self.timeline.later(self.clock()):
            return False  # at rest, or a splice is on its way (a swerve now would call it off)
        start, traj, t = run
        lim = self.gen.robot.limits
        vs = min(float(np.min(traj.limits.velocity / lim.velocity)), 1.0)
        acc = min(float(np.min(traj.limits.acceleration / lim.acceleration)), 1.0)
        for path, own in detours(traj, t):
            if not checker.path_valid(own):
                continue
            try:
                # onto the detour before its first shifted point: a later merge would cut the swerve out
                new = self.gen.splice(traj, t, path, vs, acc, merge_within=float(np.linalg.norm(path[1] - path[0])))
            except TrajectoryError:
                continue
            new.nominal = traj.nominal  # a slowed motion stays slowed: the next speed-up goes back to the goal's limits
            self.send(new, start + t)
            self._splice = new
            return True
        return False

    def escape(self) -> float | None:
        """From rest where no plan can start: move a little along its own curve, back the way it came or on, to the
        nearest configuration clear of everything. The configurations still touching get ever farther from what
        they touch (out, never in); the rest are checked as any path. Returns the arc [rad] (negative: on), or None."""
        seg = self.timeline.active(self.clock())
        checker = self.gen.checker
        if seg is None or checker is None or self.timeline.moving(self.clock()):
            return None
        curve, s_now = seg[1].curve, seg[1].s_at(seg[1].duration)
        for arc in (0.05, 0.1, 0.2, 0.35, 0.6):  # [rad]: the shortest move that leaves the collision behind
            for s_to in (s_now - arc, s_now + arc):
                if not 0.0 <= s_to <= curve.length:
                    continue
                pts = curve.eval(np.linspace(s_now, s_to, 16))
                free = checker.is_valid_batch(pts)
                first = int(np.argmax(free)) if free.any() else None
                if first is None or not checker.path_valid(pts[first:]):
                    continue
                gaps = [checker.clearance(q, max_distance=0.1).distance for q in pts[: first + 1]]
                if np.all(np.diff(gaps) >= -1e-6):
                    self.send_planned(self.gen.time(pts))
                    return arc if s_to < s_now else -arc
        return None

    def resume(self) -> None:
        """From a brake's stop on to the end of its curve, at the nominal limits."""
        seg = self.timeline.active(self.clock())
        if seg is None:
            return
        rest = self.gen.resume(seg[1])
        if rest.duration > 0:
            self.send_planned(rest)
