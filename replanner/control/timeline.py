"""What the robot was told to run: trajectories from absolute start times, each replacing the rest of earlier ones."""

from __future__ import annotations

import threading
from typing import Protocol

import numpy as np

from ..errors import InvalidInputError

JUMP_TOLERANCE = 0.02  # [rad] a received trajectory starts this close to where the robot is told to be
HISTORY = 2.0  # [s] a segment is forgotten this long after it ended (a late joint state asks about the past)
MIN_STOP = 0.05  # [s] the shortest stop along the path


class Timed(Protocol):
    """Anything with a duration [s] and a state at a time: a Trajectory or a SampledTrajectory."""

    @property
    def duration(self) -> float: ...

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


class Timeline:
    """Trajectories, each from an absolute start time [clock s]; one added at `start` replaces what would run then.

    Used on both sides of the wire: the robot follows its timeline, the controller keeps the same account of what
    it sent. A segment is forgotten once `keep` others are held and it ended HISTORY before now: never one that runs
    or is still to run, however many splices are queued behind it.

    Args:
        q0: the rest configuration [rad] before the first trajectory.
    """

    def __init__(self, q0, keep: int = 8):
        self._segments: list[tuple[float, Timed]] = []
        self._rest = np.asarray(q0, dtype=float).copy()
        self._keep = keep
        self._lock = threading.Lock()
        self.lag = 0.0  # [s] the last motion from rest started this late (the robot's side; see `receive`)

    def add(self, traj: Timed, start: float, now: float | None = None) -> None:
        """Run `traj` from `start` on; whatever was to start at or after `start` is dropped. `now` [clock s] (default:
        `start`, no later than it) says which segments ended long enough ago to be forgotten."""
        with self._lock:
            segs = [(t, tr) for t, tr in self._segments if t < start]
            segs.append((float(start), traj))
            past = (start if now is None else min(now, start)) - HISTORY
            while len(segs) > self._keep and segs[1][0] <= past:
                segs.pop(0)
            self._segments = segs

    def receive(self, traj: Timed, start: float, now: float, tolerance: float | None = JUMP_TOLERANCE) -> float:
        """The robot's side: run `traj` from `start`, or from `now` if it arrives late to a robot at rest and starts
        at rest (as a driver starts a trajectory stamped in the past: a jump would be worse). A motion from rest
        started late leaves the robot that far behind the sender's account, so a later trajectory that starts where
        the robot will be that much later runs that much later (a brake or splice computed on the sender's account
        joins the motion where it is, instead of being refused). Returns the delay [s] it runs with.

        Raises InvalidInputError for a trajectory that does not start where the robot is told to be then (by more
        than `tolerance` [rad]; None: not checked, e.g. a robot whose measured state lags what it was told)."""
        late = now - start
        q0, v0, _ = traj.state_at(0.0)
        starts_at_rest = np.abs(v0).max() < 1e-6
        from_rest = late > 0.0 and starts_at_rest and not self.moving(now)
        shifts = [now - start] if from_rest else ([0.0, self.lag] if self.lag > 0.0 else [0.0])
        gaps = [np.abs(q0 - self.state(start + d)[0]) for d in shifts]
        k = int(np.argmin([g.max() for g in gaps]))
        if tolerance is not None and gaps[k].max() > tolerance:
            gap = gaps[0]
            j = int(np.argmax(gap))
            raise InvalidInputError(
                f"the trajectory starts {gap[j]:.3f} rad away from where joint {j + 1} is at its start: following "
                f"it would jump (more than {tolerance} rad); plan from the measured joint states"
            )
        if starts_at_rest and not self.moving(start + shifts[k]):
            self.lag = shifts[k]  # a new motion from rest: as late as it starts
        self.add(traj, start + shifts[k], now)
        return shifts[k]

    def hold(self, q, t: float) -> None:
        """Stand at `q` [rad] from `t` on (what runs from then is dropped)."""
        self.add(_Rest(q), t)

    def stop_along(self, now: float, acceleration) -> float | None:
        """Brake along the path running at `now` (the robot's own stop: the service is gone, or the robot stalled)
        with at most `acceleration` [rad/s^2] per joint from slowing down; drops whatever was to come. Returns when
        the arm will stand [clock s], None if it is not moving."""
        seg = self.active(now)
        if seg is None or not self.moving(now):
            self.add(_Rest(self.state(now)[0]), now)  # nothing queued runs either
            return None
        start, traj = seg
        t0 = now - start
        qd = traj.state_at(t0)[1]
        # the slowing adds k' qd (k' peaks at 1.5 / D) to the path's own k^2 qdd: with D = 4 |qd| / a the sum stays
        # within 1.1 a even where the path itself brakes at its limit (within a where it does not)
        D = max(MIN_STOP, 4.0 * float(np.max(np.abs(qd) / np.asarray(acceleration, dtype=float))))
        self.add(Slowed(traj, t0, D), start, now)
        return now + D

    def shift(self, traj: Timed, start: float) -> None:
        """`traj` runs from `start` after all (a robot that got it late started it then); later segments stay."""
        with self._lock:
            moved = [((start if tr is traj else s), tr) for s, tr in self._segments]
            self._segments = sorted(moved, key=lambda seg: seg[0])

    def delay(self, since: float, by: float) -> None:
        """Everything from `since` on runs `by` [s] later (the robot stood still meanwhile)."""
        with self._lock:
            seg = None
            for s, tr in self._segments:
                if s <= since:
                    seg = (s, tr)
            active = seg[1] if seg is not None else None
            self._segments = [((s + by) if s > since or tr is active else s, tr) for s, tr in self._segments]
            self._segments.sort(key=lambda x: x[0])

    def segments(self) -> list[tuple[float, Timed]]:
        """(start, trajectory) pairs in start order."""
        with self._lock:
            return list(self._segments)

    def active(self, t: float) -> tuple[float, Timed] | None:
        """(start, trajectory) running at time t, or None before the first one."""
        with self._lock:
            seg = None
            for start, traj in self._segments:
                if start <= t:
                    seg = (start, traj)
            return seg

    def later(self, t: float) -> list[tuple[float, Timed]]:
        """Segments that start after t (a splice or a brake already sent, not yet running)."""
        with self._lock:
            return [(s, tr) for s, tr in self._segments if s > t]

    def moving(self, t: float) -> bool:
        """True while the segment active at t has not ended."""
        seg = self.active(t)
        return seg is not None and t - seg[0] < seg[1].duration

    def busy(self, t: float) -> bool:
        """Moving at t, or something is still to start after t."""
        return self.moving(t) or bool(self.later(t))

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) commanded at time t."""
        seg = self.active(t)
        if seg is None:
            return self._rest.copy(), np.zeros_like(self._rest)
        q, qd, _ = seg[1].state_at(t - seg[0])
        return q, qd


class Slowed:
    """`traj` from its time `t0` on, slowed to a stop along its own path within `D` [s]: its clock runs at the rate
    k(u) = 1 - 3u^2 + 2u^3, u = (t - t0) / D (C1: the acceleration stays continuous), so the arm covers D / 2 of
    the trajectory's time and stands."""

    def __init__(self, traj: Timed, t0: float, D: float):
        self.traj, self.t0, self.D = traj, float(t0), float(D)

    @property
    def duration(self) -> float:
        return self.t0 + self.D

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if t <= self.t0:
            return self.traj.state_at(t)
        u = min((t - self.t0) / self.D, 1.0)
        tau = self.t0 + self.D * (u - u**3 + u**4 / 2)
        k, dk = 1 - 3 * u * u + 2 * u**3, (-6 * u + 6 * u * u) / self.D
        q, qd, qdd = self.traj.state_at(tau)
        return q, qd * k, qdd * k * k + qd * dk


class _Rest:
    """Standing at q."""

    duration = 0.0

    def __init__(self, q):
        self.q = np.asarray(q, dtype=float)

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.q.copy(), np.zeros_like(self.q), np.zeros_like(self.q)
