"""Motion planning with OMPL (2.x Python bindings) over the robot's joint space, within a deadline.

Validity comes from a collision `Checker`: single states through a Python callback, and whole motions through a
`MotionValidator` subclass that checks every sampled configuration of a segment in one call. A failed attempt is
retried until the deadline (the fallback of the KineoWorks reactive-planning paper), each planner growing its own
tree on from where its last attempt stopped (anew after a slip); the path is then shortcut, with the same checker,
within the same deadline.
"""

from __future__ import annotations

import atexit
import logging
import math
import threading
import time
import weakref
from collections.abc import Callable

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from ..collision.checker import Checker, ExactChecker
from ..collision.exact import CollisionChecker
from ..collision.fast import FastChecker
from ..collision.paddings import Paddings, within_padding
from ..errors import InvalidInputError
from ..model.transforms import make_transform
from ..sections import CollisionLayer
from .heading import check_heading, lead_along
from .ik import IKError, solve_ik
from .shortcut import shortcut
from .types import (
    GoalInvalid,
    JointGoal,
    NoSolution,
    PlanningCanceled,
    PlanResult,
    PoseGoal,
    StartInvalid,
    UnknownPlanner,
)

log = logging.getLogger(__name__)

ou.setLogLevel(ou.LogLevel.LOG_WARN)
FINAL_CHECKS_SHARE = 0.03  # of a deadline: the search stops this much early, FCL's final check this much late
CONFIRM_CHUNK = 512  # configurations FCL checks between two looks at the deadline (~0.4 ms alone, a few under load)
CONFIRM_FAR = (0.05, 2048)  # while 50 ms are left, chunks this large: two threads share them (halves of 256 do not)
START_LIMIT_SLACK = 1e-3  # [rad] a start this far past a joint limit (an arm at its limit, measured) plans from it
SLIP_REFINE = 2.0  # a search after a slip checks this many times finer (each refinement costs a search anew)

PLANNERS = {
    name: getattr(og, name)
    for name in (
        "RRTConnect",
        "RRT",
        "RRTstar",
        "InformedRRTstar",
        "BITstar",
        "AORRTC",
        "PRM",
        "PRMstar",
        "KPIECE1",
        "BKPIECE1",
        "LBKPIECE1",
    )
}


def planner_class(name: str):
    """The OMPL planner class of `name` (see PLANNERS); raises UnknownPlanner listing the names."""
    try:
        return PLANNERS[name]
    except (KeyError, TypeError):
        raise UnknownPlanner(f"unknown planner {name!r}; available: {', '.join(PLANNERS)}") from None


def _seed_ompl(seed: int) -> None:
    """Restart OMPL's seed generator: planners made after this draw the same random numbers."""
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)  # OMPL logs an error when reseeded after its first random number
    try:
        ou.RNG.setSeed(seed % 2_147_483_647 + 1)  # OMPL refuses 0
    finally:
        ou.setLogLevel(level)


class _Attempt:
    """One attempt's budget of validity checks; when it is spent, or the plan is canceled, its termination condition
    is set from the checks themselves (OMPL's own condition, not a Python one: multi-threaded planners such as PRM
    evaluate conditions on threads of their own)."""

    def __init__(self, ptc, checks: int, cancel: threading.Event | None):
        self.ptc, self.left, self.cancel = ptc, checks, cancel

    def count(self) -> None:
        self.left -= 1
        if self.left == 0 or (self.cancel is not None and self.cancel.is_set()):
            self.ptc.terminate()


class Search:
    """What one plan's search asks and remembers: the checker of its padding, the resolution [m] its motions are
    checked at, the configurations it found free in its world (not checked again as a motion's ends) and the budget
    of the attempt that runs."""

    def __init__(self, checker: Checker, resolution: float, free: set[bytes] | None = None):
        self.checker, self.resolution, self.free = checker, resolution, free
        self.attempt: _Attempt | None = None

    def state_ok(self, q: np.ndarray) -> bool:
        ok = self.checker.motion_valid(q, q, 0.0)  # the layer's compiled call without a check's input checks
        if ok and self.free is not None:
            self.free.add(q.tobytes())
        return ok

    def motion_ok(self, a: np.ndarray, b: np.ndarray, resolution: float | None = None) -> bool:
        """The straight motion a -> b, checked every `resolution` [m] (None: the checker's path resolution)."""
        free, res = self.free, self.checker.path_resolution if resolution is None else resolution
        if free is None:  # the compiled call, without a path check's input checks
            return self.checker.motion_valid(a, b, res)
        ka, kb = a.tobytes(), b.tobytes()
        given = int(ka in free) | 2 * int(kb in free)  # ends found free before are not checked again
        ok = self.checker.motion_valid(a, b, res, given)
        if ok and given != 3:
            free.update((ka, kb))
        return ok


class _Searching:
    """The search OMPL's callbacks serve: OMPL holds the callbacks and they hold this, not the planner."""

    def __init__(self, search: Search, dof: int):
        self.search, self.joints = search, range(dof)

    def q(self, s) -> np.ndarray:
        return np.fromiter(map(s.__getitem__, self.joints), np.float64, len(self.joints))

    def state_valid(self, s) -> bool:
        search = self.search
        if search.attempt is not None:
            search.attempt.count()
        return search.state_ok(self.q(s))


class _BatchMotionValidator(ob.MotionValidator):
    """Checks a whole straight motion in one call of the search's checker."""

    def __init__(self, si, searching: _Searching):
        super().__init__(si)
        self.searching = searching

    def checkMotion(self, s1, s2) -> bool:
        searching = self.searching
        search = searching.search
        if search.attempt is not None:
            search.attempt.count()
        return search.motion_ok(searching.q(s1), searching.q(s2), search.resolution)


_LIVE: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _release_ompl() -> None:
    # nanobind reports OMPL objects still alive at exit as leaks: drop them first
    for planner in list(_LIVE):
        planner.close()


class Planner:
    """Plans joint-space paths for one robot against the checker's world.

    Args:
        checker: validity of states and motions (the exact checker: the last word on every path).
        planner: default OMPL planner name (see PLANNERS).
        attempt_checks: validity checks (states and motions) of the first attempt before retrying (the planner's tree
            grows on), each retry twice as many (counts: with time enough, a seeded plan is the same on any machine;
            the deadline may still cut it short).
        shortcut_tries: random shortcuts tried after the search (at most; six misses in a row end it sooner).
        planner_range: planner step [rad]; None keeps OMPL's default.
        search_coarseness: motions are checked this many times coarser than the checker's path resolution while
            searching, whatever a plan's padding (the result is then checked at the padding's resolution; if a thin
            obstacle slipped through, every tree is searched anew, SLIP_REFINE times finer each time).
        collision_layer: what the search asks first (the fast layer, or FCL alone).
        retry_planner: the default planner's retries alternate with this one (None: the same planner again).
        seed: every plan starts from this seed (OMPL's generator and the shortcutting): the same problem gives the
            same path, alone or after others. None: fresh randomness. OMPL's generator is per process: planners
            planning at the same time in threads of one process share it.
        clock: the time source [s] of the deadline's arithmetic (OMPL's own timer aside); tests step it.
    """

    def __init__(
        self,
        checker: CollisionChecker,
        *,
        planner: str = "RRTConnect",
        attempt_checks: int = 1000,
        shortcut_tries: int = 10,
        planner_range: float | None = None,
        ik_restarts: int = 16,
        position_tolerance: float = 0.002,
        orientation_tolerance: float = 0.02,
        search_coarseness: float = 4.0,
        seed: int | None = None,
        collision_layer: CollisionLayer | str = CollisionLayer.SPHERES,
        retry_planner: str | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ):
        self.clock = clock
        try:
            self.layer = CollisionLayer(collision_layer)
        except ValueError:
            names = " or ".join(repr(v.value) for v in CollisionLayer)
            raise InvalidInputError(f"collision_layer must be {names}, got {collision_layer!r}") from None
        self.exact = checker  # FCL: the last word on every path a plan returns
        self.checker: Checker = self._layered(checker)
        self.paddings = Paddings(checker, self._layered)
        self.robot = checker.robot
        planner_class(planner)  # raises on an unknown name
        self.default_planner = planner
        if retry_planner is not None:
            planner_class(retry_planner)
        self.retry_planner = retry_planner
        if attempt_checks < 1 or shortcut_tries < 0:
            raise InvalidInputError("attempt_checks must be >= 1 and shortcut_tries >= 0")
        self.attempt_checks = int(attempt_checks)
        self._last: Checker | None = None  # the checker of the last plan's padding
        self.shortcut_tries = int(shortcut_tries)
        self.planner_range = planner_range
        self.ik_restarts = ik_restarts
        self.position_tolerance = position_tolerance
        self.orientation_tolerance = orientation_tolerance
        self.seed = None if seed is None else int(seed)
        self._rng = np.random.default_rng(seed)
        # motions are checked coarser while searching; the found path is checked at the full resolution
        self.search_coarseness = float(search_coarseness)
        dof = self.robot.dof
        self.space = ob.RealVectorStateSpace(dof)
        bounds = ob.RealVectorBounds(dof)
        for i in range(dof):
            bounds.setLow(i, float(self.robot.limits.lower[i]))
            bounds.setHigh(i, float(self.robot.limits.upper[i]))
        self.space.setBounds(bounds)
        self.si = ob.SpaceInformation(self.space)
        # between plans the callbacks ask the planner's own checker (OMPL may look at states while setting up)
        self._searching = _Searching(Search(self.checker, self._coarse_resolution()), dof)
        self.si.setStateValidityChecker(self._searching.state_valid)
        self._motion_validator = _BatchMotionValidator(self.si, self._searching)
        self.si.setMotionValidator(self._motion_validator)
        if self.seed is not None:  # the space's default projection (KPIECE's) is drawn here: the same for a seed
            _seed_ompl(self.seed)
        self.si.setup()
        _LIVE.add(self)
        self.checker.warm()  # compile and build the layer now, not inside the first plan's deadline

    @classmethod
    def from_config(cls, checker: CollisionChecker, cfg, seed: int | None = None) -> Planner:
        return cls(
            checker,
            planner=cfg.planner,
            attempt_checks=cfg.attempt_checks,
            shortcut_tries=cfg.shortcut_tries,
            planner_range=cfg.range,
            ik_restarts=cfg.ik_restarts,
            position_tolerance=cfg.position_tolerance,
            orientation_tolerance=cfg.orientation_tolerance,
            search_coarseness=cfg.search_coarseness,
            seed=seed,
            collision_layer=cfg.collision_layer,
            retry_planner=cfg.retry_planner,
        )

    def close(self) -> None:
        """Drop the OMPL objects (before the interpreter's exit: nanobind reports live ones as leaks)."""
        self.si = self.space = self._motion_validator = None

    def _layered(self, checker: CollisionChecker) -> Checker:
        """The checker the search asks: the fast layer in front of FCL, or FCL alone."""
        return FastChecker(checker) if self.layer is CollisionLayer.SPHERES else checker

    def _coarse_resolution(self) -> float:
        """The search's resolution [m]: the configured checker's, coarsened (a small padding only tightens the final
        check)."""
        return self.search_coarseness * self.exact.path_resolution

    # ------------------------------------------------------------------ conversions
    def _alloc(self, q: np.ndarray):
        st = self.space.allocState()
        for i, v in enumerate(q):
            st[i] = float(v)
        return st

    # ------------------------------------------------------------------ goals
    def resolve_goal(self, start: np.ndarray, goal, padding: float | None = None, lazy: bool = False) -> np.ndarray:
        """Goal configuration: a JointGoal's q (checked), or IK of a PoseGoal nearest the start; `padding` [m]
        against known objects (None: this planner's). `lazy`: a joint goal is checked by FCL, not the layer."""
        return self._resolve_goal(start, goal, self.paddings.get(padding, self.checker), lazy)

    def _resolve_goal(self, start: np.ndarray, goal, checker: Checker, lazy: bool) -> np.ndarray:
        r = self.robot
        if isinstance(goal, PoseGoal):
            try:
                T = make_transform(goal.position, goal.quat_xyzw)
            except InvalidInputError as err:
                raise GoalInvalid(f"goal pose: {err}") from None
            r.link_index(goal.link)
            try:
                res = solve_ik(
                    r,
                    goal.link,
                    T,
                    checker=checker,
                    seed=start,
                    restarts=self.ik_restarts,
                    position_tolerance=goal.position_tolerance or self.position_tolerance,
                    orientation_tolerance=goal.orientation_tolerance or self.orientation_tolerance,
                    rng=self._rng,
                )
            except IKError as err:
                raise GoalInvalid(f"goal pose of {goal.link}: {err}") from None
            return res.q
        q = goal.q if isinstance(goal, JointGoal) else goal
        try:
            q = r.check_within_limits(q, "goal")
        except InvalidInputError as err:
            raise GoalInvalid(str(err)) from None
        if q.ndim != 1:
            raise GoalInvalid(f"goal must be one configuration of {r.dof} joints, got shape {q.shape}")
        checker = checker.exact if lazy else checker
        contact = None if checker.is_valid(q) else checker.check(q)  # the layer first: FCL's tree only if needed
        if contact is not None:
            raise GoalInvalid(within_padding(checker, q, contact, "goal"), contact)
        return q

    # ------------------------------------------------------------------ planning
    def plan(
        self,
        start,
        goal,
        *,
        planner: str | None = None,
        deadline: float = 1.0,
        cancel: threading.Event | None = None,
        padding: float | None = None,
        heading=None,
        map_margin: float = 0.0,
    ) -> PlanResult:
        """A collision-free path from start to goal (JointGoal, PoseGoal or an array) within `deadline` [s].

        `cancel`, when set from another thread, stops the search at once (raises PlanningCanceled).
        `padding` [m]: this plan's padding against known objects (None: the checker's); the path resolution follows
        it (see `padded_checker`). Grasps sit within a centimetre of their objects. A padding's first plan builds its
        padded geometry before the deadline starts (the last few paddings are kept).
        `heading` (dof,): the joint velocity of an arm moving at `start` (a replan to be spliced onto its motion): a
        path that would start against it starts with a short step along it (planning/heading.py).
        `map_margin` [m]: kept from the occupancy map beyond its padding (speed and separation: see SeparationCaps).
        """
        heading = check_heading(heading, self.robot)
        search = Search(self.paddings.get(padding, self.checker, map_margin), self._coarse_resolution())
        self._last = search.checker
        self._searching.search = search  # what OMPL's callbacks ask, for this plan
        try:
            return self._plan(search, start, goal, planner, deadline, cancel, heading)
        finally:
            self._searching.search = Search(self.checker, self._coarse_resolution())

    def prepare(self) -> None:
        """The search's layer of the world as it is now (this planner's padding, its last plan's), built between jobs:
        a plan after an edit builds none unless it searches, and a replan must not wait for it."""
        for c in (self.checker, self._last):
            if c is not None and not c.ready():
                c.prepare()

    def _plan(self, search: Search, start, goal, planner: str | None, deadline: float, cancel, heading) -> PlanResult:
        clock = self.clock
        t_begin = clock()
        if self.seed is not None:
            _seed_ompl(self.seed)
            self._rng = np.random.default_rng(self.seed)
        if not (isinstance(deadline, int | float) and np.isfinite(deadline) and deadline > 0):
            raise InvalidInputError(f"deadline must be a positive number of seconds, got {deadline!r}")
        name = planner or self.default_planner
        cls = planner_class(name)
        r = self.robot
        try:
            start = r.check_within_limits(start, "start", tol=START_LIMIT_SLACK)
        except InvalidInputError as err:
            raise StartInvalid(str(err)) from None
        start = np.clip(start, r.limits.lower, r.limits.upper)  # a measured arm settles a hair past a limit
        # after an edit of the world, FCL checks the ends and the straight line: the layer is built only for a search
        lazy = not search.checker.ready()
        first = search.checker.exact if lazy else search.checker
        contact = None if first.is_valid(start) else first.check(start)
        if contact is not None:
            raise StartInvalid(within_padding(search.checker, start, contact, "start"), contact)
        q_goal = self._resolve_goal(start, goal, search.checker, lazy)
        search.free = {start.tobytes(), np.asarray(q_goal, np.float64).tobytes()}
        t_end = t_begin + deadline * (1.0 - FINAL_CHECKS_SHARE)
        t_stop = t_begin + deadline * (1.0 + FINAL_CHECKS_SHARE)  # the promise: back by then, or failed

        def exact(W: np.ndarray) -> bool:
            return self._exact_clear(search.checker.exact, W, t_stop, t_begin, deadline)

        def led(W: np.ndarray) -> np.ndarray:  # a replan's path turned to start along the motion, if time is left
            return W if heading is None or clock() > t_stop else lead_along(W, heading, exact)

        fine = search.checker.path_resolution
        direct = np.array([start, q_goal])
        res = search.resolution
        straight = first.path_valid(direct, res) if lazy else search.motion_ok(start, q_goal, res)
        if straight and exact(direct):
            W = led(direct)
            return PlanResult(W, q_goal, name, 0, 0.0, 0.0, clock() - t_begin, direct=True, raw_waypoints=2)
        t_searching = clock()
        ss = og.SimpleSetup(self.si)
        ss.setStartAndGoalStates(self._alloc(start), self._alloc(q_goal))
        # the default planner's retries alternate with the retry planner: planners fail on different problems
        other = planner_class(self.retry_planner) if planner is None and self.retry_planner else cls
        attempts, used, algos = 0, None, {}
        pdef = ss.getProblemDefinition()
        W = raw_path = None
        simplify_time, slips = 0.0, 0
        while W is None:
            remaining = t_end - clock()
            if remaining <= 0 or (cancel is not None and cancel.is_set()):
                break
            attempts += 1
            use = other if attempts % 2 == 0 else cls
            algo = algos.get(use)  # one planner of each kind a plan: a retry grows its tree on
            if algo is None:
                algo = algos[use] = use(self.si)
                if self.planner_range is not None and hasattr(algo, "setRange"):
                    algo.setRange(self.planner_range)
            if use is not used:
                used = use
                ss.setPlanner(algo)
            ptc = ob.plannerOrTerminationCondition(
                ob.exactSolnPlannerTerminationCondition(pdef),
                ob.timedPlannerTerminationCondition(remaining),  # the deadline, the only clock in a plan
            )
            # each retry may check twice as much: hard problems get big trees, easy ones stay quick
            search.attempt = _Attempt(ptc, self.attempt_checks << min(attempts - 1, 12), cancel)
            try:
                status = ss.solve(ptc)
            finally:
                search.attempt = None
            if bool(status) and pdef.hasExactSolution():
                raw_path = self._solution(ss)
                t_simp = clock()
                W = self._simplify(search, raw_path, search.resolution, t_end, exact)
                simplify_time += clock() - t_simp
                if W is None:  # a thin obstacle slipped between the coarse search checks: search anew, finer
                    slips += 1
                    search.resolution = max(fine, search.resolution / SLIP_REFINE)
                    for grown in algos.values():  # motions checked as coarsely: kept, they give slipped paths again
                        grown.clear()
            if W is None:
                pdef.clearSolutionPaths()
        search_time = clock() - t_searching - simplify_time
        if cancel is not None and cancel.is_set():
            raise PlanningCanceled(f"planning canceled after {clock() - t_begin:.3f} s")
        if W is None:
            raise NoSolution(
                f"{name} found no path in {deadline:.3f} s ({attempts} attempts); give a longer deadline, "
                "another planner, or check that the goal is reachable"
            )
        W = led(W)
        total = clock() - t_begin
        name = next(k for k, v in PLANNERS.items() if v is used)
        return PlanResult(
            W, q_goal, name, attempts, search_time, simplify_time, total, raw_waypoints=len(raw_path), slips=slips
        )

    def simplify(
        self,
        raw: np.ndarray,
        resolution: float,
        t_end: float = math.inf,
        exact: Callable | None = None,
        padding: float | None = None,
    ) -> np.ndarray | None:
        """A found path shortcut with motions checked every `resolution` [m] (the search's), then checked at the full
        path resolution by `exact` (a path -> bool; None: the checker's `path_valid`); if a shortcut slipped through a
        thin obstacle, shortcut at the full resolution. None: `raw` itself slipped through one. `padding` [m]: from
        known objects (None: this planner's)."""
        search = Search(self.paddings.get(padding, self.checker), resolution)
        return self._simplify(search, raw, resolution, t_end, exact)

    def _simplify(
        self, search: Search, raw: np.ndarray, resolution: float, t_end: float, exact: Callable | None
    ) -> np.ndarray | None:
        exact = exact or search.checker.path_valid
        W = self._shortcut(search, raw, t_end, resolution)
        if exact(W):
            return W
        if not search.checker.path_valid(raw):
            return None
        W = self._shortcut(search, raw, t_end, None)
        if not exact(W):  # every segment was cleared at the full resolution: the layers disagree with FCL
            log.error("the sphere layer cleared a path FCL refuses: a bug, please report it with the scene")
            raise NoSolution("the path found collides by FCL's check (sphere layer disagreement): plan again")
        return W

    def _exact_clear(self, exact: ExactChecker, W: np.ndarray, t_stop: float, t_begin: float, deadline: float) -> bool:
        """FCL's own check of a path at path resolution (the last word on every path a plan returns; the layers in
        front of it only ever clear), a chunk at a time: past `t_stop` the plan fails rather than return late."""
        Q, _ = exact.interpolate(W)
        i = 0
        while i < len(Q):
            now = self.clock()
            if now > t_stop:
                raise NoSolution(
                    f"a path was found, too late for FCL's check of it within the {deadline:.3f} s deadline "
                    f"({i} of {len(Q)} configurations checked after {now - t_begin:.3f} s); give a longer deadline"
                )
            n = CONFIRM_FAR[1] if t_stop - now > CONFIRM_FAR[0] else CONFIRM_CHUNK
            if not exact.is_valid_batch(Q[i : i + n], split=True).all():
                return False
            i += n
        return True

    def _solution(self, ss) -> np.ndarray:
        path = ss.getSolutionPath()
        return np.array([self._searching.q(path.getState(i)) for i in range(path.getStateCount())])

    # ------------------------------------------------------------------ simplification
    def shortcut(
        self, W: np.ndarray, t_end: float = math.inf, resolution: float | None = None, padding: float | None = None
    ) -> np.ndarray:
        """Fewer, shorter segments (planning/shortcut.py): up to `shortcut_tries` random shortcuts between waypoint
        skips, each checked every `resolution` [m] (None: the checker's path resolution), `padding` [m] from known
        objects (None: this planner's).

        Bounded by counts; `t_end` (a time of `clock`, the plan's deadline) may only cut it short. A coarser
        `resolution` leaves the kept pieces of cut segments unchecked: `simplify` checks the result finer.
        """
        search = Search(self.paddings.get(padding, self.checker), self._coarse_resolution())
        return self._shortcut(search, W, t_end, resolution)

    def _shortcut(self, search: Search, W: np.ndarray, t_end: float, resolution: float | None) -> np.ndarray:
        return shortcut(
            W,
            lambda a, b: search.motion_ok(a, b, resolution),
            self._rng,
            tries=self.shortcut_tries,
            t_end=t_end,
            clock=self.clock,
            pieces=resolution is None,
        )
