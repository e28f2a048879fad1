"""The monitor's checks: each looks at the motion as it stands and returns a typed verdict; none decides anything."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..collision.exact import CollisionChecker, Contact
from ..collision.paddings import Paddings
from ..trajectory import Trajectory, TrajectoryGenerator


@dataclass(frozen=True, eq=False)
class MotionView:
    """The motion as one monitor cycle sees it.

    now: controller clock [s]; q: measured configuration [rad]; path: waypoints (M, dof) of what the arm still
    has to travel, starting at q; progress: share of the running trajectory's curve done, 0 to 1; segment:
    (start [s], trajectory) running now; key: names the trajectories the path was read from (same key, same
    curve); check_gap: how late the next check may come [s]; padding: the goal's padding from known objects [m]
    (None: the checker's).
    """

    now: float
    q: np.ndarray
    path: np.ndarray
    progress: float
    segment: tuple[float, Trajectory]
    key: tuple
    check_gap: float = 0.0
    padding: float | None = None


class Verdict(NamedTuple):
    """What one check found: `clear`, or why not (a contact, the clearance [m] where it was measured); a speed
    check also says the share of the nominal speed the arm may keep (`speed_factor`, 0: stop)."""

    check: str
    clear: bool
    reason: str = ""
    contact: Contact | None = None
    clearance: float | None = None
    speed_factor: float | None = None


class Check(ABC):
    """One look at the motion. `fresh` asks for a full look, no cached knowledge (e.g. before a resume)."""

    name: str = "check"
    only_when_blocked: bool = False  # a close check that matters only while the path is blocked

    @abstractmethod
    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict: ...

    def clear(self) -> Verdict:
        return Verdict(self.name, True)


class MapPathCheck(Check):
    """The remaining path against the occupancy map (where people show up): every cycle, boolean, no distances.

    A path clear of one map is clear of the next if it is clear of what the next added (voxels that left cannot
    block): when the map follows the one the path was last found clear of, only its new voxels are checked.
    """

    name = "map"

    def __init__(self, checker: CollisionChecker):
        self.checker = checker
        self._clear_of: tuple | None = None  # (path key, map) the path was last found clear of
        self._blocked: tuple | None = None  # (path key, verdict) of the last path found blocked

    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict:
        occ = self.checker.world.snapshot().occupancy
        memo = self._clear_of
        if len(view.path) < 2:
            clear = True
        elif not fresh and memo is not None and memo[0] == view.key and memo[1] is occ:
            clear = True
        elif not fresh and memo is not None and memo[0] == view.key and _follows(occ, memo[1]):
            added = occ.added_map
            clear = added is None or self.checker.path_valid(view.path, octree_only=True, occupancy=added)
        else:
            clear = self.checker.path_valid(view.path, octree_only=True)
        self._clear_of = (view.key, occ) if clear else None
        if clear:
            return self.clear()
        if self._blocked is not None and self._blocked[0] == view.key:
            return self._blocked[1]  # the same path still blocked: where was said when it first was
        found = self.checker.check_path(view.path, robot_pairs=False)
        where = f" ({found.contact})" if found.contact is not None else ""
        verdict = Verdict(self.name, False, f"an obstacle is on the remaining path{where}", found.contact)
        self._blocked = (view.key, verdict)
        return verdict


def _follows(occ, before) -> bool:
    """`occ` is the map right after `before` and says what it added."""
    return occ is not None and before is not None and occ.added is not None and occ.serial == before.serial + 1 > 1


class ScenePathCheck(Check):
    """The remaining path against the map, static objects and attachments (everything a scene edit can change).

    A planned path was checked against all of them and against the robot itself (which no edit changes); a clear
    verdict holds until the scene changes or the path is read from other trajectories, so it is remembered per
    (scene version, trajectories).
    """

    name = "scene"

    def __init__(self, checker: CollisionChecker):
        self.checker, self.paddings = checker, Paddings(checker)
        self._clear_for: tuple | None = None

    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict:
        version = self.checker.world.snapshot().version
        memo = (version, view.key, view.padding)
        if not fresh and memo == self._clear_for:
            return self.clear()
        checker = self.paddings.get(view.padding)  # the padding the path was planned with
        result = checker.check_path(view.path, robot_pairs=False) if len(view.path) >= 2 else None
        if result is None or result.valid:
            self._clear_for = memo
            return self.clear()
        self._clear_for = None
        return Verdict(self.name, False, f"the remaining path collides: {result.contact}", result.contact)


class SafetyDistanceCheck(Check):
    """The measured arm against the map, inflated by the safety distance: closer than that, brake."""

    name = "safety_distance"

    def __init__(self, checker: CollisionChecker, safety: CollisionChecker, distance: float):
        self.checker, self.safety, self.distance = checker, safety, distance

    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict:
        if self.safety.is_valid(view.q, octree_only=True):
            return self.clear()
        c = self.checker.clearance(view.q, max_distance=max(0.2, 2 * self.distance))
        reason = f"{c.body} is {c.distance:.3f} m from {c.obstacle}, within the safety distance"
        return Verdict(self.name, False, reason, None, c.distance)


class StopRegionCheck(Check):
    """The stretch a brake decided at the next check would still travel: blocked there, this is the last chance.

    The next check may come later than the rate says (a busy machine): the gap between checks seen is used.
    """

    name = "stop_region"
    only_when_blocked = True

    def __init__(self, checker: CollisionChecker, generator: TrajectoryGenerator, min_gap: float, brake_latency: float):
        self.checker, self.gen, self.paddings = checker, generator, Paddings(checker)
        self.min_gap, self.brake_latency = min_gap, brake_latency

    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict:
        start, traj = view.segment
        horizon = max(self.min_gap, 2.0 * view.check_gap, 0.03) + self.brake_latency
        t = min(view.now - start + horizon, traj.duration)
        stop = self.gen.brake(traj, t)
        s_a, s_b = traj.s_at(view.now - start), stop.s_at(stop.duration)
        if s_b - s_a < 1e-6:
            return self.clear()
        pts = traj.curve.eval(np.linspace(s_a, s_b, max(2, int((s_b - s_a) / 0.02) + 2)))
        # along the path, with the padding it was planned with: the robot's pairs were checked
        result = self.paddings.get(view.padding).check_path(pts, robot_pairs=False)
        if result.valid:
            return self.clear()
        reason = f"braking now is the last chance to stop before the obstacle ({result.contact})"
        return Verdict(self.name, False, reason, result.contact)
