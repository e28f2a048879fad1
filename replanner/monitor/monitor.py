"""The monitor: reads the motion from the measured state and runs its checks; the state machine decides.

As in the KineoWorks reactive-planning paper: a fast boolean check of the remaining path while MONITORING,
distances while a replan is pending.
Here the path checks (map, scene) run in every moving state; the close checks (safety distance, stop region)
while a replan is pending, when the arm moves towards something known to be in its way.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..collision.exact import CollisionChecker
from ..sections import ControllerConfig
from ..trajectory import Trajectory, TrajectoryGenerator
from .checks import (
    Check,
    MapPathCheck,
    MotionView,
    SafetyDistanceCheck,
    ScenePathCheck,
    StopRegionCheck,
    Verdict,
)
from .ssm import SpeedSeparationCheck

GRID_STEP = 0.02  # [rad of joint-space arc] between the remaining path's points


@dataclass
class MonitorStats:
    """How often the monitor looked and how long a path check took [ms] (the newest 1,000)."""

    checks: int = 0
    check_ms: deque = field(default_factory=lambda: deque(maxlen=1000))


@dataclass(frozen=True)
class Report:
    """The verdicts of one monitor cycle, in check order; it stops at the first one that is not clear."""

    verdicts: tuple[Verdict, ...]

    @property
    def clear(self) -> bool:
        return all(v.clear for v in self.verdicts)

    @property
    def blocking(self) -> Verdict | None:
        return next((v for v in self.verdicts if not v.clear), None)

    @property
    def speed_factor(self) -> float:
        """The lowest share of its nominal speed any verdict allows (1: no limit)."""
        return min((v.speed_factor for v in self.verdicts if v.speed_factor is not None), default=1.0)


class Monitor:
    """Runs `path_checks` (every moving state) and `close_checks` (replan pending) over the remaining path.

    Args:
        path_checks: e.g. [MapPathCheck, ScenePathCheck]: is the way to the goal free?
        close_checks: e.g. [SafetyDistanceCheck, StopRegionCheck]: must the arm stop now?
    """

    def __init__(self, path_checks: list[Check], close_checks: list[Check] = (), speed_checks: list[Check] = ()):
        self.path_checks = list(path_checks)
        self.close_checks = list(close_checks)
        self.speed_checks = list(speed_checks)
        self.stats = MonitorStats()
        self._grid_cache: dict[tuple, tuple[np.ndarray, np.ndarray, Trajectory]] = {}
        self._speed: tuple[float, Report] | None = None
        self.padding: float | None = None  # the active goal's padding from known objects [m]: set by the controller

    # ------------------------------------------------------------------ the motion as it stands
    def grid(self, traj: Trajectory, to_curve_end: bool) -> tuple[np.ndarray, np.ndarray]:
        """Points of the trajectory's curve every GRID_STEP of arc, to where it stops (or to the curve's end)."""
        key = (id(traj), to_curve_end)
        hit = self._grid_cache.get(key)
        if hit is None or hit[2] is not traj:
            s0 = traj.s_at(0.0)
            s1 = traj.curve.length if to_curve_end else traj.s_at(traj.duration)
            n = max(2, int(math.ceil((s1 - s0) / GRID_STEP)) + 1)
            s = np.linspace(s0, s1, n)
            hit = (s, traj.curve.eval(s), traj)
            if len(self._grid_cache) > 8:
                self._grid_cache.clear()
            self._grid_cache[key] = hit
        return hit[0], hit[1]

    def view(self, timeline, now: float, q: np.ndarray, *, to_curve_end: bool = False, check_gap: float = 0.0):
        """The remaining path from the measured q along what the robot was told to run; None when nothing runs.

        to_curve_end: on to the end of the running curve, not where its trajectory stops (a brake stops early).
        """
        seg = timeline.active(now)
        if seg is None or not isinstance(seg[1], Trajectory):  # at rest where the record was settled: no path
            return None
        start, traj = seg
        s_grid, q_grid = self.grid(traj, to_curve_end)
        s_exp = traj.s_at(now - start)
        window = np.flatnonzero((s_grid >= s_exp - 0.5) & (s_grid <= s_exp + 0.1))
        if not len(window):
            window = np.arange(len(s_grid))
        i = int(window[np.argmin(np.linalg.norm(q_grid[window] - q, axis=1))])
        later = timeline.later(now)
        key: tuple = (traj, to_curve_end)  # the objects, not their ids: an id is reused once its object is gone
        if later:  # a spliced trajectory takes over at its start: each one before it runs only until then
            s_switch = traj.s_at(later[0][0] - start)
            pts = [q[None], q_grid[i + 1 :][s_grid[i + 1 :] < s_switch]]
            for k, (t_k, tr) in enumerate(later):
                s_k, q_k = self.grid(tr, False)
                if k + 1 < len(later):  # a splice queued behind it replaces the rest of it
                    q_k = q_k[s_k < tr.s_at(later[k + 1][0] - t_k)]
                pts += [tr.state_at(0.0)[0][None], q_k]
            key += tuple(tr for _, tr in later)
        else:
            pts = [q[None], q_grid[i + 1 :]]
        progress = float((s_grid[i] - s_grid[0]) / max(s_grid[-1] - s_grid[0], 1e-9))
        return MotionView(now, q, np.vstack(pts), progress, seg, key, check_gap, self.padding)

    # ------------------------------------------------------------------ checks
    def check_path(self, view: MotionView, fresh: bool = False) -> Report:
        """Is the way to the goal free? `fresh`: no remembered verdicts (before a resume)."""
        t0 = time.perf_counter()
        report = self._run(self.path_checks, view, fresh)
        self.stats.checks += 1
        self.stats.check_ms.append((time.perf_counter() - t0) * 1e3)
        return report

    def check_close(self, view: MotionView, path_clear: bool) -> Report:
        """Must the arm stop now? Checks that matter only on a blocked path are skipped on a clear one."""
        checks = [c for c in self.close_checks if not (path_clear and c.only_when_blocked)]
        return self._run(checks, view, False)

    def check_speed(self, view: MotionView, max_age: float = 0.0) -> Report:
        """How fast may the arm go now? Every speed check's verdict (a `speed_factor` each), in order.

        max_age: a report this young [s] is good enough (an arm at rest asking whether it may move again).
        """
        cached = self._speed
        if cached is not None and 0.0 <= view.now - cached[0] < max_age:
            return cached[1]
        report = Report(tuple(check(view, False) for check in self.speed_checks))
        self._speed = (view.now, report)
        return report

    def check_start(self, traj: Trajectory, now: float, q: np.ndarray) -> Report:
        """Would the speed checks let `traj`, not yet sent, start from the arm at `q` now? (Not kept for
        `check_speed`: that one judges the motion that runs.)"""
        _, q_grid = self.grid(traj, False)
        view = MotionView(now, q, np.vstack([q[None], q_grid[1:]]), 0.0, (now, traj), (traj, False), 0.0, self.padding)
        return Report(tuple(check(view, False) for check in self.speed_checks))

    @staticmethod
    def _run(checks: list[Check], view: MotionView, fresh: bool) -> Report:
        out = []
        for check in checks:
            v = check(view, fresh)
            out.append(v)
            if not v.clear:
                break
        return Report(tuple(out))


def build_monitor(
    checker: CollisionChecker,
    generator: TrajectoryGenerator,
    cfg: ControllerConfig,
    allowed_contacts=(),
    reaction_time: Callable[[float], float] | None = None,
    joint_state_age: Callable[[float], float] | None = None,
) -> Monitor:
    """The default checks: map and scene on the path; safety distance and stop region while a replan is pending;
    speed and separation in every moving state when `reaction_time` (T_r at a time [s]) is given.

    The safety distance is kept from what the cameras see with a second checker whose robot is inflated by it.
    """
    safety = CollisionChecker(
        checker.robot,
        checker.world,
        padding=max(cfg.safety_distance, checker.padding),
        map_padding=cfg.safety_distance,
        path_resolution=checker.path_resolution,
        allowed_contacts=allowed_contacts,
        check_limits=False,
    )
    speed = []
    if reaction_time is not None and cfg.speed_separation.enabled:
        age = joint_state_age or (lambda now: 0.0)
        speed.append(SpeedSeparationCheck(checker, generator, cfg.speed_separation, reaction_time, age))
    return Monitor(
        [MapPathCheck(checker), ScenePathCheck(checker)],
        [
            SafetyDistanceCheck(checker, safety, cfg.safety_distance),
            StopRegionCheck(checker, generator, 2.0 / cfg.check_rate_hz, cfg.brake_latency),
        ],
        speed,
    )
