"""A thread-safe history of measured joint states, looked up by time."""

from __future__ import annotations

import bisect
import threading
from collections import deque

import numpy as np

from ..errors import InvalidInputError


class JointStateBuffer:
    """The last `maxlen` joint states (stamp [s], q [rad]) in time order."""

    def __init__(self, dof: int, maxlen: int = 2000):
        self.dof = dof
        self._stamps: deque[float] = deque(maxlen=maxlen)
        self._qs: deque[np.ndarray] = deque(maxlen=maxlen)
        self._lock = threading.Lock()

    def add(self, stamp: float, q) -> None:
        a = np.array(q, dtype=np.float64)
        if a.shape != (self.dof,) or not np.all(np.isfinite(a)):
            raise InvalidInputError(f"joint state must be {self.dof} finite values, got shape {a.shape}")
        if not np.isfinite(stamp):
            raise InvalidInputError(f"joint state stamp must be finite, got {stamp}")
        with self._lock:
            if self._stamps and stamp < self._stamps[-1]:
                raise InvalidInputError(
                    f"joint state stamp {stamp:.6f} is older than the last one {self._stamps[-1]:.6f}"
                )
            self._stamps.append(float(stamp))
            self._qs.append(a)

    def nearest(self, stamp: float) -> tuple[float, np.ndarray] | None:
        """(stamp, q) of the state closest in time to `stamp`, or None if empty."""
        with self._lock:
            if not self._stamps:
                return None
            stamps = list(self._stamps)
            i = bisect.bisect_left(stamps, stamp)
            best = min((j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - stamp))
            return stamps[best], self._qs[best]

    def latest(self) -> tuple[float, np.ndarray] | None:
        with self._lock:
            return (self._stamps[-1], self._qs[-1]) if self._stamps else None

    def __len__(self) -> int:
        return len(self._stamps)
