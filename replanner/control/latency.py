"""How late the controller is: a sliding-window account of the reaction chain, on the controller's clock [s].

    sensor stamp ─▶ map integrated ─▶ path checked ─▶ command out          (and each joint state's age)

`reaction` (sensor stamp → the first check that saw that map) plus the command latency is what the
speed-and-separation monitor takes as T_r, at a high percentile: when the machine is slow, it grows.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

STAGES = (
    "sensor_to_map",
    "map_to_check",
    "check_to_command",
    "reaction",
    "joint_state_age",
    "check_gap",
    "plan_overrun",
    "replan_plan",
    "rest_answer",
)
LEAD_PERCENTILE = 90.0  # of plan overruns a replan's landing time allows for
MAX_EXTRA_LEAD = 0.25  # [s] beyond the configured margin: later than that, braking is the better answer


class Window:
    """Samples of one quantity [s] over the last `seconds` (at most `cap` of them)."""

    def __init__(self, seconds: float, cap: int = 4000):
        self.seconds = seconds
        self._times: deque[float] = deque(maxlen=cap)
        self._values: deque[float] = deque(maxlen=cap)

    def add(self, now: float, value: float) -> None:
        if math.isfinite(value):
            self._times.append(now)
            self._values.append(max(0.0, value))

    def values(self, now: float) -> np.ndarray:
        while self._times and self._times[0] < now - self.seconds:
            self._times.popleft()
            self._values.popleft()
        return np.fromiter(self._values, dtype=float, count=len(self._values))

    def summary(self, now: float) -> dict:
        """{"median", "p99", "max", "n"} in s over the window (None without samples)."""
        v = self.values(now)
        if not len(v):
            return {"median": None, "p99": None, "max": None, "n": 0}
        return {
            "median": float(np.median(v)),
            "p99": float(np.percentile(v, 99)),
            "max": float(v.max()),
            "n": int(len(v)),
        }


class LatencyAccount:
    """The reaction chain's stages, each over a sliding window; thread-safe (maps arrive on another thread).

    Args:
        window: [s] of history the figures are taken over.
        percentile: the one `reaction_time` reports (a high one: the tail is what collides, not the median).
        floor: [s] the measured part of T_r is at least this (few samples yet, or none).
        extra: [s] added to T_r beyond what is measured: a camera's frame period (what appears just after a frame
            is seen a period later) and the latency of a brake command.
    """

    def __init__(self, window: float = 10.0, percentile: float = 99.0, floor: float = 0.05, extra: float = 0.0):
        self.window, self.percentile, self.floor, self.extra = window, percentile, floor, extra
        self.stages = {name: Window(window) for name in STAGES}
        self._lock = threading.Lock()
        self._unchecked: list[tuple[float, float]] = []  # (sensor stamp, integrated) of maps not yet checked
        self._newest_sensor: float | None = None  # the sensor stamp the last check saw
        self._cache: tuple[float, float] | None = None
        self._age_cache: tuple[float, float] | None = None

    def map_integrated(self, now: float, sensor_stamp: float | None) -> None:
        if sensor_stamp is None:
            return
        with self._lock:
            self.stages["sensor_to_map"].add(now, now - sensor_stamp)
            self._unchecked.append((sensor_stamp, now))

    def checked(self, now: float, gap: float, watching: bool = True) -> None:
        """A monitor check finished at `now`; it saw every map integrated before it started.

        watching: False when nothing moves and nothing was looked at (maps waiting then are no reaction samples).
        """
        with self._lock:
            maps, self._unchecked = self._unchecked, []
            if not watching:
                return
            for stamp, integrated in maps:
                self.stages["map_to_check"].add(now, now - integrated)
                self.stages["reaction"].add(now, now - stamp)
            if maps:
                self._newest_sensor = max(s for s, _ in maps)
            self.stages["check_gap"].add(now, gap)

    def command_sent(self, now: float, decided: float) -> None:
        with self._lock:
            self.stages["check_to_command"].add(now, now - decided)

    def joint_state(self, now: float, stamp: float) -> None:
        with self._lock:
            self.stages["joint_state_age"].add(now, now - stamp)

    def plan_answered(self, now: float, asked: float, deadline: float, took: float | None = None) -> None:
        """A replan's answer arrived at `now`, asked at `asked` with a planning budget of `deadline` [s]; `took` [s]:
        its plan's own time (search, shortcutting, FCL's re-check; None: no plan came back)."""
        with self._lock:
            self.stages["plan_overrun"].add(now, now - asked - deadline)
            if took is not None:
                self.stages["replan_plan"].add(now, took)

    def answered_at_rest(self, now: float, asked: float) -> None:
        """A plan from rest, asked at `asked`, answered at `now`: its path runs about then."""
        with self._lock:
            self.stages["rest_answer"].add(now, now - asked)

    def rest_answer(self, now: float, default: float) -> float:
        """[s] from asking a plan from rest to its answer: the `percentile` of the window, `default` without any."""
        with self._lock:
            took = self.stages["rest_answer"].values(now)
        return float(np.percentile(took, self.percentile)) if len(took) else default

    def landing_margin(self, now: float, margin: float) -> float:
        """[s] after a replan's deadline its landing time lies: `margin`, or more when answers have been arriving
        later than that (a busy machine), so the next one lands in time instead of failing as late."""
        with self._lock:
            o = self.stages["plan_overrun"].values(now)
        late = float(np.percentile(o, LEAD_PERCENTILE)) + 0.01 if len(o) else 0.0
        return min(max(margin, late), margin + MAX_EXTRA_LEAD)

    def reaction_time(self, now: float) -> float:
        """T_r [s]: the `percentile` of frame stamp → checked plus that of check → command (at least `floor`),
        plus `extra`. Refreshed at most every 50 ms: a percentile over thousands of samples is not free."""
        cached = self._cache
        if cached is not None and 0.0 <= now - cached[0] < 0.05:
            return cached[1]
        with self._lock:
            r = self.stages["reaction"].values(now)
            c = self.stages["check_to_command"].values(now)
        measured = (float(np.percentile(r, self.percentile)) if len(r) else 0.0) + (
            float(np.percentile(c, self.percentile)) if len(c) else 0.0
        )
        value = max(measured, self.floor) + self.extra
        self._cache = (now, value)
        return value

    def joint_state_age(self, now: float) -> float:
        """The `percentile` of joint-state ages [s] (refreshed at most every 50 ms, as `reaction_time`)."""
        cached = self._age_cache
        if cached is not None and 0.0 <= now - cached[0] < 0.05:
            return cached[1]
        with self._lock:
            a = self.stages["joint_state_age"].values(now)
        value = float(np.percentile(a, self.percentile)) if len(a) else 0.0
        self._age_cache = (now, value)
        return value

    def report(self, now: float) -> dict:
        """Every stage's median, p99, max and count over the window [s]; T_r as the monitor uses it."""
        with self._lock:
            out = {name: w.summary(now) for name, w in self.stages.items()}
        out["window_s"] = self.window
        out["reaction_time_s"] = self.reaction_time(now)
        return out
