"""What the robot was told to run: trajectories from absolute start times, each replacing the rest of earlier ones."""

from __future__ import annotations

import threading
from typing import Protocol

import numpy as np


class Timed(Protocol):
    """Anything with a duration [s] and a state at a time: a Trajectory or a SampledTrajectory."""

    @property
    def duration(self) -> float: ...

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


class Timeline:
    """Trajectories, each from an absolute start time [clock s]; one added at `start` replaces what would run then.

    Used on both sides of the wire: the robot follows its timeline, the controller keeps the same account of what
    it sent. Only the newest `keep` segments are kept: time runs forward, older ones can no longer be active.

    Args:
        q0: the rest configuration [rad] before the first trajectory.
    """

    def __init__(self, q0, keep: int = 8):
        self._segments: list[tuple[float, Timed]] = []
        self._rest = np.asarray(q0, dtype=float).copy()
        self._keep = keep
        self._lock = threading.Lock()

    def add(self, traj: Timed, start: float) -> None:
        """Run `traj` from `start` on; whatever was to start at or after `start` is dropped."""
        with self._lock:
            kept = [(t, tr) for t, tr in self._segments if t < start]
            self._segments = [*kept, (float(start), traj)][-self._keep :]

    def receive(self, traj: Timed, start: float, now: float) -> float:
        """The robot's side: run `traj` from `start`, or from `now` if it arrives late to a robot at rest and starts
        at rest (as a driver starts a trajectory stamped in the past: a jump would be worse). Returns the delay [s]."""
        late = now - start
        if late > 0.0 and not self.moving(now) and np.abs(traj.state_at(0.0)[1]).max() < 1e-6:
            self.add(traj, now)
            return late
        self.add(traj, start)
        return 0.0

    def shift(self, traj: Timed, start: float) -> None:
        """`traj` runs from `start` after all (a robot that got it late started it then); later segments stay."""
        with self._lock:
            moved = [((start if tr is traj else s), tr) for s, tr in self._segments]
            self._segments = sorted(moved, key=lambda seg: seg[0])

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
