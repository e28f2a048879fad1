"""The reactive controller: a state machine (`transitions`) that owns every decision (paper 002, section 4.2).

WAITING → PLANNING → MONITORING → MONITORING_WITH_PLANNING_PENDING → (spliced | clear again | brake), and
HOLDING for the `wait_and_resume` policy (paper 002's robot waited for the operator to leave).

One controller thread takes every input from a queue (joint states, map updates, goals, cancels, plan
results, ticks), so callbacks never block and no decision races another. Plans are computed by a worker
thread; the arm keeps moving while they are, and the remaining path is re-checked at the monitor rate.
"""

from __future__ import annotations

import itertools
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from transitions import Machine

from ..config import ControllerConfig
from ..errors import InvalidInputError, ReplannerError, UnknownNameError
from ..planning.planner import GoalInvalid, JointGoal, Planner, PlanningError, PoseGoal, StartInvalid
from ..trajectory.generator import Trajectory, TrajectoryError, TrajectoryGenerator
from ..world.collision import CollisionChecker
from ..world.robot import RobotModel

log = logging.getLogger(__name__)


class State(str, Enum):
    WAITING = "WAITING"
    PLANNING = "PLANNING"
    MONITORING = "MONITORING"
    PENDING = "MONITORING_WITH_PLANNING_PENDING"
    HOLDING = "HOLDING"


class GoalStatus(str, Enum):
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELED = "canceled"
    PREEMPTED = "preempted"


class GoalRejected(ReplannerError):
    """A goal was not accepted; the controller's state is unchanged."""


@dataclass(frozen=True)
class Goal:
    """A motion request: exactly one of `joints` [rad] or `pose`; optional planner, deadline [s], scaling."""

    id: str
    joints: np.ndarray | None = None
    pose: PoseGoal | None = None
    planner: str | None = None
    deadline: float | None = None
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0


@dataclass(frozen=True)
class GoalResult:
    goal_id: str
    status: GoalStatus
    reason: str
    stamp: float


@dataclass(frozen=True)
class TransitionRecord:
    """One state change: when [controller clock s], from, to, which event, why, for which goal."""

    stamp: float
    source: str
    dest: str
    trigger: str
    reason: str
    goal_id: str | None


class GoalHandle:
    """The caller's view of an accepted goal."""

    def __init__(self, goal: Goal, q_goal: np.ndarray):
        self.goal = goal
        self.q_goal = q_goal
        self._done = threading.Event()
        self._result: GoalResult | None = None

    @property
    def id(self) -> str:
        return self.goal.id

    @property
    def result(self) -> GoalResult | None:
        return self._result

    def wait(self, timeout: float | None = None) -> GoalResult | None:
        """The result, or None if it is not there within `timeout` [s]."""
        self._done.wait(timeout)
        return self._result

    def _finish(self, result: GoalResult) -> bool:
        if self._result is not None:
            return False
        self._result = result
        self._done.set()
        return True


@dataclass
class _Job:
    """A planning request handed to the worker thread."""

    id: int
    purpose: str  # "goal", "replan", "hold"
    start: np.ndarray
    q_goal: np.ndarray
    land: float | None  # absolute time the result starts; None: as soon as it is ready
    base: tuple[float, Trajectory] | None  # (start, trajectory) to splice onto at `land`
    deadline: float
    cancel: threading.Event = field(default_factory=threading.Event)
    requested: float = 0.0


@dataclass
class MonitorStats:
    checks: int = 0
    check_ms: list = field(default_factory=list)  # last durations of remaining-path checks
    last_check: float = 0.0


class Controller:
    """Reactive execution of goals for one robot.

    Args:
        robot, checker, planner, generator: the planning stack (the checker sees the live world).
        execute: sends a trajectory to the robot: execute(trajectory, start_time [clock s]).
        cfg: the controller config section.
        sensors: names of the cameras whose silence is a fault; empty: static objects only.
        clock: time source [s] shared with the robot driver and the sensors.
        planning_process: a PlanningProcess to plan in (the second core); None plans in a thread here.
    """

    def __init__(
        self,
        robot: RobotModel,
        checker: CollisionChecker,
        planner: Planner,
        generator: TrajectoryGenerator,
        execute: Callable[[Trajectory, float], None],
        cfg: ControllerConfig,
        *,
        sensors: list[str] | tuple[str, ...] = (),
        clock: Callable[[], float] = time.monotonic,
        default_deadline: float = 1.0,
        planning_process=None,
    ):
        self.robot, self.checker, self.planner, self.gen = robot, checker, planner, generator
        self._safety = CollisionChecker(
            robot,
            checker.world,
            padding=max(cfg.safety_distance, checker.padding),
            map_padding=cfg.safety_distance,  # the safety distance is kept from what the cameras see
            path_resolution=checker.path_resolution,
            allowed_contacts=checker._allowed_contacts,
            check_limits=False,
        )
        # build lazily made geometry now: the first PENDING check must not stall the thread (and the GIL)
        self._safety.is_valid(robot.home)
        checker.is_valid(robot.home)
        self._execute = execute
        self._proc = planning_process
        self.cfg = cfg
        self.clock = clock
        self.default_deadline = default_deadline
        self.sensors = tuple(sensors)
        if not self.sensors:
            log.warning("no cameras configured: the controller sees static objects only")
        self.machine = Machine(
            model=self,
            states=[s.value for s in State],
            initial=State.WAITING.value,
            send_event=True,
            auto_transitions=False,
            after_state_change="_record",
            transitions=self._table(),
        )
        self.transitions: list[TransitionRecord] = []
        self._observers: list[Callable[[TransitionRecord], None]] = []
        self._result_observers: list[Callable[[GoalResult], None]] = []
        self._events: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._job_ids = itertools.count(1)
        self._job: _Job | None = None
        self._next_job: tuple | None = None
        self._worker: threading.Thread | None = None
        self._worker_lock = threading.Lock()
        self._worker_wake = threading.Event()
        self._retry_at: float | None = None
        self._checked_version = -1
        self._check_gap = 0.0  # static scene version the current path was fully checked against
        self._handle: GoalHandle | None = None
        self._last_js = None  # (receipt time, JointState)
        self._cloud_seen: dict[str, float] = {}
        self._map_dirty = False
        self._js_dirty = False
        self._segments: list[tuple[float, Trajectory]] = []  # what the robot was told to run
        self._grid_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._clear_count = 0
        self._pending_since = 0.0
        self._hold_since = 0.0
        self._hold_planned = 0.0
        self._settle_until = math.inf
        self.stats = MonitorStats()
        self.last_clearance: float | None = None
        self.events_log: list[tuple[float, str, dict]] = []  # (time, what, details) for metrics and benches

    # ------------------------------------------------------------------ state machine
    @staticmethod
    def _table() -> list[dict]:
        W, P, M, PD, H = (s.value for s in State)
        busy = [P, M, PD, H]
        return [
            {"trigger": "plan", "source": [W, P, M, PD, H], "dest": P},
            {"trigger": "plan_failed", "source": P, "dest": W},
            {"trigger": "start_motion", "source": [P, H], "dest": M},
            {"trigger": "blocked", "source": M, "dest": PD},
            {"trigger": "path_clear", "source": PD, "dest": M},
            {"trigger": "spliced", "source": PD, "dest": M},
            {"trigger": "brake_and_hold", "source": [M, PD], "dest": H},
            {"trigger": "brake_and_abort", "source": [M, PD], "dest": W},
            {"trigger": "resume", "source": H, "dest": M},
            {"trigger": "give_up", "source": H, "dest": W},
            {"trigger": "succeeded", "source": [M, PD], "dest": W},
            {"trigger": "failed", "source": busy, "dest": W},
            {"trigger": "canceled", "source": busy, "dest": W},
            {"trigger": "fault", "source": busy, "dest": W},
        ]

    def _record(self, event) -> None:
        rec = TransitionRecord(
            self.clock(),
            event.transition.source,
            event.transition.dest,
            event.event.name,
            event.kwargs.get("reason", ""),
            self._handle.id if self._handle else None,
        )
        self.transitions.append(rec)
        log.info("%s -> %s (%s): %s", rec.source, rec.dest, rec.trigger, rec.reason)
        for cb in list(self._observers):
            try:
                cb(rec)
            except Exception:
                log.exception("transition observer failed")

    def subscribe(
        self,
        on_transition: Callable[[TransitionRecord], None] | None = None,
        on_result: Callable[[GoalResult], None] | None = None,
    ) -> None:
        if on_transition:
            self._observers.append(on_transition)
        if on_result:
            self._result_observers.append(on_result)

    # ------------------------------------------------------------------ inputs (any thread, never block)
    def on_joint_state(self, js) -> None:
        self._events.put(("js", js))

    def on_map_update(self, stamp: float | None = None) -> None:
        self._events.put(("map", stamp))

    def on_cloud(self, sensor: str, stamp: float | None = None) -> None:
        self._cloud_seen[sensor] = self.clock()

    def submit(self, goal: Goal) -> GoalHandle:
        """Validate and accept a goal (a busy controller preempts its current goal). Raises GoalRejected."""
        try:
            q_goal = self._validate(goal)
        except (InvalidInputError, GoalInvalid, UnknownNameError, PlanningError) as err:
            raise GoalRejected(f"goal {getattr(goal, 'id', '?')!r} rejected: {err}") from None
        handle = GoalHandle(goal, q_goal)
        self._events.put(("goal", handle))
        return handle

    def cancel(self, goal_id: str) -> None:
        """Cancel the active goal `goal_id` (the arm brakes along its path). Raises UnknownNameError."""
        h = self._handle
        if h is None or h.id != goal_id or h.result is not None:
            raise UnknownNameError("active goal", goal_id, [h.id] if h is not None and h.result is None else [])
        self._events.put(("cancel", goal_id))

    # ------------------------------------------------------------------ validation
    def _validate(self, goal: Goal) -> np.ndarray:
        if not isinstance(goal, Goal):
            raise InvalidInputError(f"expected a Goal, got {type(goal).__name__}")
        if not isinstance(goal.id, str) or not goal.id or len(goal.id) > 128:
            raise InvalidInputError("goal id must be a non-empty string of at most 128 characters")
        h = self._handle
        if h is not None and h.id == goal.id and h.result is None:
            raise InvalidInputError(f"goal id {goal.id!r} is already active; use a new id")
        if (goal.joints is None) == (goal.pose is None):
            raise InvalidInputError("give exactly one of joints or pose")
        if goal.planner is not None:
            self.planner._planner_class(goal.planner)
        if goal.deadline is not None and not (isinstance(goal.deadline, int | float) and 0 < goal.deadline < 600):
            raise InvalidInputError(f"deadline must be in (0, 600) s, got {goal.deadline!r}")
        self.gen.limits(goal.velocity_scale, goal.acceleration_scale)
        js = self._last_js
        now = self.clock()
        if js is None or now - js[0] > self.cfg.joint_state_timeout:
            raise InvalidInputError("no recent joint state: the robot is not reporting (check the driver)")
        for s in self.sensors:
            seen = self._cloud_seen.get(s)
            if seen is None or now - seen > self.cfg.sensor_timeout:
                raise InvalidInputError(f"camera {s!r} is silent: its point clouds are needed to move safely")
        target = JointGoal(goal.joints) if goal.joints is not None else goal.pose
        return self.planner.resolve_goal(js[1].position, target)

    # ------------------------------------------------------------------ thread
    def start(self) -> Controller:
        self._stop.clear()
        self.stats.last_check = self.clock()
        self._thread = threading.Thread(target=self._run, name="controller", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._events.put(("stop", None))
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        if self._job is not None:
            self._job.cancel.set()

    def _run(self) -> None:
        period = 1.0 / self.cfg.check_rate_hz
        while not self._stop.is_set():
            try:
                events = [self._events.get(timeout=min(period, 0.02))]
            except queue.Empty:
                events = []
            while True:
                try:
                    events.append(self._events.get_nowait())
                except queue.Empty:
                    break
            try:
                for kind, data in events:
                    self._handle_event(kind, data)
                now = self.clock()
                if (self._js_dirty or self._map_dirty) and now - self.stats.last_check >= period:
                    self._js_dirty = self._map_dirty = False
                    # recent gap between checks, decaying: how late the next one may be (capped: a stall is a fault)
                    self._check_gap = min(max(now - self.stats.last_check, 0.9 * self._check_gap), 0.25)
                    self.stats.last_check = now
                    self._check(now)
                self._watchdogs(self.clock())
            except Exception:  # a bug must not silence the controller: brake and report
                log.exception("controller error")
                self._safe_stop("internal error (see the log)")

    def _handle_event(self, kind: str, data) -> None:
        if kind == "js":
            self._last_js = (self.clock(), data)
            self._js_dirty = True
            # a picked part may rest on its support until it has left it by more than the safety padding
            for name, sup in self.checker.world.release_support(data.position, self._safety.padding + 0.005):
                log.info("%s has left %s: it is checked against it again", name, sup)
        elif kind == "map":
            self._map_dirty = True
        elif kind == "goal":
            self._start_goal(data)
        elif kind == "cancel":
            if self._handle is not None and self._handle.id == data and self.state != State.WAITING.value:
                self._brake_if_moving()
                self._finish(GoalStatus.CANCELED, "canceled by the client")
                self.canceled(reason="canceled by the client")
        elif kind == "plan_done":
            self._plan_done(*data)
        elif kind == "plan_error":
            self._plan_error(*data)

    # ------------------------------------------------------------------ goals
    def _start_goal(self, handle: GoalHandle) -> None:
        if self._handle is not None and self._handle.result is None:
            self._cancel_job()
            self._brake_if_moving()
            self._finish(GoalStatus.PREEMPTED, f"preempted by goal {handle.id!r}")
        self._handle = handle
        self._settle_until = math.inf
        now = self.clock()
        idle = self.state == State.WAITING.value and not self._moving(now)
        if idle and self._last_js is not None and not any(t > now for t, _ in self._segments):
            err = float(np.abs(self._measured() - handle.q_goal).max())
            if err <= self.cfg.goal_tolerance:  # nothing to plan: a path needs two distinct points
                self._finish(GoalStatus.SUCCEEDED, f"already at the goal (within {err:.4f} rad)")
                return
        job = self._make_job("goal", handle.q_goal, self._deadline(handle.goal))
        self.plan(reason=f"goal {handle.id!r} accepted")
        self._launch(job)

    def _deadline(self, goal: Goal) -> float:
        return goal.deadline if goal.deadline is not None else self.default_deadline

    def _finish(self, status: GoalStatus, reason: str) -> None:
        h = self._handle
        if h is None:
            return
        result = GoalResult(h.id, status, reason, self.clock())
        if h._finish(result):
            self.events_log.append((result.stamp, "result", {"status": status.value, "reason": reason}))
            for cb in list(self._result_observers):
                try:
                    cb(result)
                except Exception:
                    log.exception("result observer failed")

    # ------------------------------------------------------------------ planning jobs
    def _active(self, t: float) -> tuple[float, Trajectory] | None:
        seg = None
        for start, traj in self._segments:
            if start <= t:
                seg = (start, traj)
        return seg

    def _moving(self, now: float) -> bool:
        seg = self._active(now)
        return seg is not None and now - seg[0] < seg[1].duration

    def _make_job(self, purpose: str, q_goal: np.ndarray, deadline: float) -> _Job:
        now = self.clock()
        seg = self._active(now)
        if seg is not None and now - seg[0] < seg[1].duration:  # moving: plan from where the arm will be
            land = now + deadline + self.cfg.splice_margin
            seg = self._active(land)  # the trajectory running then (a slow-down may take over first)
            start_q = seg[1].state_at(land - seg[0])[0]
            base = seg
        else:
            land, base = None, None
            start_q = self._measured() if self._last_js else self.robot.home
        return _Job(next(self._job_ids), purpose, start_q, q_goal, land, base, deadline, requested=now)

    def _launch(self, job: _Job) -> None:
        self._cancel_job()
        self._job = job
        self.events_log.append((job.requested, "plan_requested", {"purpose": job.purpose, "job": job.id}))
        goal = self._handle.goal if self._handle else None
        # one planner thread: OMPL's SpaceInformation is not thread-safe; the newest job wins
        with self._worker_lock:
            self._next_job = (job, goal)
            self._worker_wake.set()
            if self._worker is None or not self._worker.is_alive():
                self._worker = threading.Thread(target=self._worker_loop, name="planner", daemon=True)
                self._worker.start()

    def _worker_loop(self) -> None:
        while not self._stop.is_set():
            self._worker_wake.wait(0.5)
            with self._worker_lock:
                item, self._next_job = self._next_job, None
                self._worker_wake.clear()
            if item is not None and not item[0].cancel.is_set():
                self._work(*item)

    def _cancel_job(self) -> None:
        if self._job is not None:
            self._job.cancel.set()
            self._job = None

    def _work(self, job: _Job, goal: Goal | None) -> None:
        """Worker thread: plan, then time or splice; the result goes back through the queue."""
        try:
            vs = goal.velocity_scale if goal else 1.0
            acc = goal.acceleration_scale if goal else 1.0
            name = goal.planner if goal else None
            base = (job.base[1], job.land - job.base[0]) if job.base is not None else None
            if self._proc is not None:
                done = threading.Event()
                threading.Thread(target=self._forward_cancel, args=(job, done), daemon=True).start()
                try:
                    traj, res = self._proc.plan(
                        self.checker.world.snapshot(),
                        job.start,
                        job.q_goal,
                        planner=name,
                        deadline=job.deadline,
                        velocity_scale=vs,
                        acceleration_scale=acc,
                        base=base,
                    )
                finally:
                    done.set()
            else:
                res = self.planner.plan(job.start, job.q_goal, planner=name, deadline=job.deadline, cancel=job.cancel)
                if base is not None:
                    traj = self.gen.splice(base[0], base[1], res.path, vs, acc)
                else:
                    traj = self.gen.time(res.path, vs, acc)
            self._events.put(("plan_done", (job, traj, res)))
        except (PlanningError, TrajectoryError, InvalidInputError) as err:
            self._events.put(("plan_error", (job, err)))
        except Exception as err:  # the worker must always answer
            log.exception("planning worker failed")
            self._events.put(("plan_error", (job, err)))

    def _forward_cancel(self, job: _Job, done: threading.Event) -> None:
        """Pass a cancel on to the planning process while this job runs there."""
        while not done.is_set():
            if job.cancel.wait(0.01):
                self._proc.cancel()
                return

    def _plan_done(self, job: _Job, traj: Trajectory, res) -> None:
        if self._job is not job:
            return  # canceled or superseded
        self._job = None
        now = self.clock()
        if job.land is not None and now > job.land - 0.002:
            self._plan_error(job, TrajectoryError(f"the plan arrived {now - job.land:.3f} s after its landing time"))
            return
        start = job.land if job.land is not None else now + self.cfg.brake_latency
        self._send(traj, start)
        self.events_log.append(
            (
                now,
                "plan_sent",
                {
                    "purpose": job.purpose,
                    "job": job.id,
                    "land": start,
                    "plan_time": res.plan_time,
                    "spliced": job.base is not None,
                },
            )
        )
        state = self.state
        if job.purpose == "replan" and state == State.PENDING.value:
            self.spliced(reason=f"replan spliced at +{start - now:.3f} s ({len(res.path)} waypoints)")
        elif job.purpose == "goal" and state == State.PLANNING.value:
            self._settle_until = math.inf
            self.start_motion(reason=f"trajectory of {traj.duration:.2f} s sent")
        elif job.purpose == "hold" and state == State.HOLDING.value:
            self.start_motion(reason="a new path around the obstacle")

    def _plan_error(self, job: _Job, err: Exception) -> None:
        if self._job is not None and self._job is not job:
            return
        self._job = None
        now = self.clock()
        state = self.state
        self.events_log.append((now, "plan_error", {"purpose": job.purpose, "job": job.id, "error": str(err)}))
        if job.purpose == "goal" and state == State.PLANNING.value:
            self._brake_if_moving()
            self._finish(GoalStatus.FAILED, f"planning failed: {err}")
            self.plan_failed(reason=str(err))
        elif job.purpose == "replan" and state == State.PENDING.value:
            if isinstance(err, StartInvalid):  # where the arm would be when the plan lands is not free: stop
                self._safety_brake(f"the path is blocked just ahead ({err})")
            elif now - self._pending_since + self.cfg.replan_deadline >= self.cfg.pending_timeout:
                self._safety_brake(f"replanning failed: {err}")
            elif isinstance(err, GoalInvalid):  # the goal itself is blocked: keep watching, try again shortly
                self._retry_at = now + 0.1
            else:
                self._launch(self._make_job("replan", self._handle.q_goal, self.cfg.replan_deadline))
        # a failed hold replan: keep holding, the next attempt comes after hold_replan_interval

    # ------------------------------------------------------------------ motion commands
    def _send(self, traj: Trajectory, start: float) -> None:
        self._segments = [(t, tr) for t, tr in self._segments if t < start] + [(start, traj)]
        self._segments = self._segments[-3:]
        self._execute(traj, start)

    def _brake_if_moving(self) -> Trajectory | None:
        now = self.clock()
        seg = self._active(now)
        if seg is None or now - seg[0] >= seg[1].duration:
            return None
        start, traj = seg
        t = now - start + self.cfg.brake_latency
        stop = self.gen.brake(traj, min(t, traj.duration))
        self._send(stop, start + t)
        self.events_log.append((now, "brake", {"duration": stop.duration}))
        return stop

    def _slow_down(self, now: float) -> None:
        """Something is in the way: go on along the same curve at reduced speed while a new path is planned."""
        f = self.cfg.pending_speed_factor
        seg = self._active(now)
        if f >= 1.0 or seg is None or now - seg[0] >= seg[1].duration:
            return
        start, traj = seg
        t = now - start + self.cfg.brake_latency
        try:
            slow = self.gen.slow_down(traj, t, f)
        except TrajectoryError as err:
            log.warning("cannot slow down: %s", err)
            return
        self._send(slow, start + t)

    def _safety_brake(self, reason: str) -> None:
        self._cancel_job()
        self._brake_if_moving()
        if self.cfg.policy == "abort":
            self._finish(GoalStatus.FAILED, reason)
            self.brake_and_abort(reason=reason)
        else:
            now = self.clock()
            self._hold_since = self._hold_planned = now
            self._clear_count = 0
            self.brake_and_hold(reason=reason)

    def _safe_stop(self, reason: str) -> None:
        self._cancel_job()
        try:
            self._brake_if_moving()
        except Exception:
            log.exception("brake failed")
        if self.state != State.WAITING.value:
            self._finish(GoalStatus.FAILED, reason)
            self.fault(reason=reason)

    # ------------------------------------------------------------------ monitoring
    def _measured(self) -> np.ndarray:
        return self._last_js[1].position

    def _grid(self, traj: Trajectory, to_curve_end: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Points of the trajectory's curve every ~2 cm of joint-space arc (cached per trajectory).

        to_curve_end: up to the end of the curve, not where this trajectory stops (a brake stops early).
        """
        key = (id(traj), to_curve_end)
        hit = self._grid_cache.get(key)
        if hit is None or hit[2] is not traj:
            s0 = traj.s_at(0.0)
            s1 = traj.curve.length if to_curve_end else traj.s_at(traj.duration)
            n = max(2, int(math.ceil((s1 - s0) / 0.02)) + 1)
            s = np.linspace(s0, s1, n)
            hit = (s, traj.curve.eval(s), traj)
            if len(self._grid_cache) > 8:
                self._grid_cache.clear()
            self._grid_cache[key] = hit
        return hit[0], hit[1]

    def remaining_path(self, now: float, to_curve_end: bool = False) -> tuple[np.ndarray, float] | None:
        """Waypoints of what the arm still has to travel, located from the measured state; and progress."""
        seg = self._active(now)
        if seg is None or self._last_js is None:
            return None
        start, traj = seg
        s_grid, q_grid = self._grid(traj, to_curve_end)
        s_exp = traj.s_at(now - start)
        q = self._measured()
        window = np.flatnonzero((s_grid >= s_exp - 0.5) & (s_grid <= s_exp + 0.1))
        if not len(window):
            window = np.arange(len(s_grid))
        i = int(window[np.argmin(np.linalg.norm(q_grid[window] - q, axis=1))])
        later = [(t, tr) for t, tr in self._segments if t > now]
        if later:  # a spliced trajectory takes over at its start: the old one only runs until then
            s_switch = traj.s_at(later[0][0] - start)
            upto = q_grid[i + 1 :][s_grid[i + 1 :] < s_switch]
            pts = [q[None], upto, later[0][1].state_at(0.0)[0][None]]
            for _, tr in later:
                pts.append(self._grid(tr)[1])
        else:
            pts = [q[None], q_grid[i + 1 :]]
        path = np.vstack(pts)
        return path, float((s_grid[i] - s_grid[0]) / max(s_grid[-1] - s_grid[0], 1e-9))

    def _check(self, now: float) -> None:
        state = self.state
        if state == State.WAITING.value or self._last_js is None:
            return
        if self.cfg.reaction == "none":  # the comparison baseline: plan once, never look again
            self._reached(now)
            return
        # holding: the way to the goal, not the stretch the brake still travels
        rem = self.remaining_path(now, to_curve_end=state == State.HOLDING.value)
        if rem is None:
            return
        path, _ = rem
        # planned paths were checked against everything; while the static scene is unchanged only the map can block
        version = self.checker.world.snapshot().version
        octree_only = version == self._checked_version
        t0 = time.perf_counter()
        clear = len(path) < 2 or self.checker.path_valid(path, octree_only=octree_only)
        if clear and not octree_only:
            self._checked_version = version
        self.stats.checks += 1
        self.stats.check_ms.append((time.perf_counter() - t0) * 1e3)
        if len(self.stats.check_ms) > 2000:
            del self.stats.check_ms[:1000]
        if state == State.MONITORING.value:
            if self._reached(now):
                return
            if not clear and self.cfg.reaction == "stop_and_wait":
                self._safety_brake("an obstacle is on the remaining path: stop, wait, then plan from rest")
                return
            if not clear:
                self._pending_since = now
                self._clear_count = 0
                self._retry_at = None
                self.events_log.append((now, "blocked", {}))
                self._slow_down(now)
                self._launch(self._make_job("replan", self._handle.q_goal, self.cfg.replan_deadline))
                self.blocked(reason="an obstacle is on the remaining path")
        elif state == State.PENDING.value:
            if self._reached(now):
                return
            q = self._measured()
            # "clearance >= safety distance" is a boolean check with the robot inflated by that distance
            if not self._safety.is_valid(q, octree_only=True):
                c = self.checker.clearance(q, max_distance=max(0.2, 2 * self.cfg.safety_distance))
                self.last_clearance = c.distance
                self._safety_brake(f"{c.body} is {c.distance:.3f} m from {c.obstacle}, within the safety distance")
                return
            hit = self._stop_region_blocked(now) if not clear else None
            if hit is not None:
                self._safety_brake(f"braking now is the last chance to stop before the obstacle ({hit})")
                return
            if now - self._pending_since > self.cfg.pending_timeout:
                self._safety_brake(f"no new path within {self.cfg.pending_timeout} s")
                return
            if not clear and self._retry_at is not None and now >= self._retry_at and self._job is None:
                self._retry_at = None
                self._launch(self._make_job("replan", self._handle.q_goal, self.cfg.replan_deadline))
            self._clear_count = self._clear_count + 1 if clear else 0
            if self._clear_count >= self.cfg.clear_checks:
                self._cancel_job()
                self.events_log.append((now, "replan_canceled", {}))
                self.path_clear(reason=f"the path was clear for {self._clear_count} checks")
        elif state == State.HOLDING.value:
            self._clear_count = self._clear_count + 1 if clear else 0
            moving = self._moving(now)
            if self._clear_count >= self.cfg.clear_checks and not moving:
                start, traj = self._active(now)
                rest = self.gen.resume(traj)
                if rest.duration > 0:
                    self._send(rest, now + self.cfg.brake_latency)
                self.resume(reason=f"the path was clear for {self._clear_count} checks")
            elif now - self._hold_since > self.cfg.hold_timeout:
                self._finish(GoalStatus.FAILED, f"the path stayed blocked for {self.cfg.hold_timeout} s")
                self.give_up(reason=f"blocked for {self.cfg.hold_timeout} s")
            elif not moving and self._job is None and now - self._hold_planned > self.cfg.hold_replan_interval:
                self._hold_planned = now
                self._launch(self._make_job("hold", self._handle.q_goal, self._deadline(self._handle.goal)))

    def _stop_region_blocked(self, now: float):
        """The contact on the stretch a brake decided at the next check would still travel, or None."""
        seg = self._active(now)
        if seg is None:
            return None
        start, traj = seg
        # the next check may come later than the rate says (the GIL, a busy machine): use the gaps seen
        gap = max(2.0 / self.cfg.check_rate_hz, 2.0 * self._check_gap, 0.03)
        horizon = gap + self.cfg.brake_latency
        t = min(now - start + horizon, traj.duration)
        stop = self.gen.brake(traj, t)
        s_a, s_b = traj.s_at(now - start), stop.s_at(stop.duration)
        if s_b - s_a < 1e-6:
            return None
        pts = traj.curve.eval(np.linspace(s_a, s_b, max(2, int((s_b - s_a) / 0.02) + 2)))
        result = self.checker.check_path(pts)
        return None if result.valid else result.contact

    def _reached(self, now: float) -> bool:
        if self._moving(now) or any(t > now for t, _ in self._segments):
            return False
        h = self._handle
        err = float(np.abs(self._measured() - h.q_goal).max())
        if err <= self.cfg.goal_tolerance:
            self._cancel_job()
            self._finish(GoalStatus.SUCCEEDED, f"reached within {err:.4f} rad")
            self.succeeded(reason=f"goal {h.id!r} reached")
            return True
        if self._settle_until == math.inf:
            self._settle_until = now + self.cfg.settle_timeout
        elif now > self._settle_until:
            self._cancel_job()
            self._finish(GoalStatus.FAILED, f"the trajectory ended {err:.4f} rad from the goal")
            self.failed(reason="did not reach the goal")
            return True
        return False

    # ------------------------------------------------------------------ watchdogs
    def _watchdogs(self, now: float) -> None:
        if self.state == State.WAITING.value:
            return
        if self._last_js is None or now - self._last_js[0] > self.cfg.joint_state_timeout:
            age = now - self._last_js[0] if self._last_js else math.inf
            self._safe_stop(f"joint states silent for {age:.2f} s")
            return
        for s in self.sensors:
            seen = self._cloud_seen.get(s)
            if seen is None or now - seen > self.cfg.sensor_timeout:
                age = now - seen if seen is not None else math.inf
                self._safe_stop(f"camera {s!r} silent for {age:.2f} s")
                return

    # ------------------------------------------------------------------ status
    def status(self) -> dict:
        h = self._handle
        now = self.clock()
        rem = self.remaining_path(now) if self.state != State.WAITING.value else None
        return {
            "state": self.state,
            "goal_id": h.id if h is not None and h.result is None else None,
            "progress": rem[1] if rem else None,
            "perception": list(self.sensors) or "none: static objects only",
            "checks": self.stats.checks,
            "clearance": self.last_clearance,
        }
