"""The reactive controller: a state machine (`transitions`) that owns every decision, after the KineoWorks
reactive-planning paper's (its section 4.2).

WAITING → PLANNING → MONITORING → MONITORING_WITH_PLANNING_PENDING → (spliced | clear again | brake), and
HOLDING for the `wait_and_resume` policy (the paper's robot waited for the operator to leave).

Every input goes through one queue (joint states, map updates, goals, cancels, plan answers) and is handled by
`step`, run by the controller's thread or by a test that drives the clock: callbacks never block and no decision
races another. The monitor judges the motion, the plan worker plans in the background, this module decides.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable

import numpy as np
from transitions import Machine

from ..collision.exact import CollisionChecker
from ..errors import ReplannerError, UnknownNameError
from ..model.robot import RobotModel
from ..monitor import Monitor
from ..monitor.ssm import SeparationPlan
from ..planning import GoalInvalid, Planner, StartInvalid
from ..planning.worker import JobPurpose, PlanAnswer, PlanJob, PlanWorker
from ..sections import AfterBrake, ControllerConfig, Reaction
from ..trajectory import Trajectory, TrajectoryError, TrajectoryGenerator
from .cadence import CheckClock
from .goals import Goal, GoalHandle, GoalResult, GoalStatus
from .history import History, TransitionRecord
from .holding import Act, Decision, Hold, speed_refusal
from .inbox import Inbox, Input
from .latency import LatencyAccount
from .liveness import Liveness, off_record
from .moves import Moves
from .pending import Pending
from .states import State, edges
from .swerves import Swerves

log = logging.getLogger(__name__)


class Controller:
    """Reactive execution of goals for one robot.

    Args:
        robot, checker, planner, generator: the planning stack (the checker sees the live world).
        monitor: judges the remaining motion (see `replanner.monitor.build_monitor`).
        worker: plans in the background (a ThreadWorker or a ProcessWorker).
        execute: sends a trajectory to the robot: execute(trajectory, start_time [clock s]).
        cfg: the controller config section.
        sensors: names of the cameras whose silence is a fault; empty: static objects only.
        clock: time source [s] shared with the robot driver and the sensors.
        latency: the account of the reaction chain (the speed-and-separation check reads its T_r).
    """

    state: State  # set by the machine

    def __init__(
        self,
        robot: RobotModel,
        checker: CollisionChecker,
        planner: Planner,
        generator: TrajectoryGenerator,
        monitor: Monitor,
        worker: PlanWorker,
        execute: Callable[[Trajectory, float], None],
        cfg: ControllerConfig,
        *,
        sensors: list[str] | tuple[str, ...] = (),
        clock: Callable[[], float] = time.monotonic,
        default_deadline: float = 1.0,
        latency: LatencyAccount | None = None,
    ):
        self.robot, self.checker, self.planner = robot, checker, planner
        self.monitor, self.worker, self.cfg, self.clock = monitor, worker, cfg, clock
        self.default_deadline, self.sensors = default_deadline, tuple(sensors)
        if not self.sensors:
            log.warning("no cameras configured: the controller sees static objects only")
        checker.is_valid(robot.home)  # build lazily made geometry now: the first check must not stall the thread
        self.moves = Moves(robot.home, generator, execute, clock, cfg.brake_latency, self.log_event, cfg.start_lead)
        self.swerve = Swerves(robot, cfg.reflex, checker, self.moves, self.log_event) if cfg.reaction.swerves else None
        self.machine = Machine(
            model=self,
            states=State,
            initial=State.WAITING,
            send_event=True,
            auto_transitions=False,
            after_state_change="_record",
            transitions=edges(),
        )
        self.history = History()
        self.transitions, self.events_log = self.history.transitions, self.history.events
        self.inbox = Inbox(self._handle_input, self._tick, self._safe_stop, min(1.0 / cfg.check_rate_hz, 0.02))
        self._job_ids, self._job = itertools.count(1), None  # the job in flight: a PlanJob
        self._handle: GoalHandle | None = None
        self.liveness = Liveness(self.sensors, cfg.joint_state_timeout, cfg.sensor_timeout)
        self.latency = latency or LatencyAccount()
        self._checks = CheckClock(1.0 / cfg.check_rate_hz)
        self._pending: Pending | None = None  # while PENDING
        self._hold: Hold | None = None  # while HOLDING
        self._settle_until = math.inf  # [s] when a path that ended short of its goal has failed
        self.last_clearance: float | None = None
        self.tracking_error: float | None = None  # [rad] measured arm vs the record at its stamp (last check)

    # ------------------------------------------------------------------ bookkeeping that lives as long as its state
    # the machine calls on_enter_<name>/on_exit_<name> (a State member's name) as it enters and leaves that state
    def on_enter_PLANNING(self, event) -> None:
        self._settle_until = math.inf  # a new path: the settle clock starts at its end

    def on_enter_PENDING(self, event) -> None:
        self._pending = Pending(event.kwargs["now"])

    def on_exit_PENDING(self, event) -> None:
        self._pending = None

    def on_enter_HOLDING(self, event) -> None:
        self._hold = Hold(event.kwargs["now"], self.cfg, self.monitor, self.liveness)

    def on_exit_HOLDING(self, event) -> None:
        self._hold = None

    # ------------------------------------------------------------------ observers and history
    def _record(self, event) -> None:
        goal = self._handle.id if self._handle else None
        t = event.transition
        source, dest = State[t.source].value, State[t.dest].value  # the machine knows states by name, the wire by value
        rec = TransitionRecord(self.clock(), source, dest, event.event.name, event.kwargs.get("reason", ""), goal)
        self.history.transition(rec)

    def log_event(self, what: str, **details) -> None:
        """Record what happened (time, what, details) in `events_log`, for metrics and benches."""
        self.history.event(self.clock(), what, details)

    def subscribe(
        self,
        on_transition: Callable[[TransitionRecord], None] | None = None,
        on_result: Callable[[GoalResult], None] | None = None,
    ) -> None:
        """Hear of every transition and every goal result (called from the controller's thread; must not block)."""
        self.history.subscribe(on_transition, on_result)

    # ------------------------------------------------------------------ inputs (any thread, never block)
    def on_joint_state(self, js) -> None:
        """A measured joint state: it counts as heard now (a long step must not make a live robot look silent)."""
        now = self.clock()
        self.liveness.joint_state(now, js)
        self.latency.joint_state(now, js.stamp)
        self.inbox.put(Input.JOINT_STATE, js)

    def on_map(self, sensor: str | None = None, stamp: float | None = None) -> None:
        """A new map was integrated (from `sensor`'s frame): the sensor is alive and the path must be re-checked."""
        now = self.clock()
        if sensor is not None:
            self.liveness.sensor(now, sensor)
        self.latency.map_integrated(now, stamp)
        self.inbox.put(Input.MAP, stamp)

    def submit(self, goal: Goal) -> GoalHandle:
        """Hand a goal to the controller (a busy one preempts its current goal); `handle.accepted()` tells."""
        if not isinstance(goal, Goal):
            raise TypeError(f"expected a Goal, got {type(goal).__name__}")
        handle = GoalHandle(goal)
        self.inbox.put(Input.GOAL, handle)
        return handle

    def cancel(self, goal_id: str) -> None:
        """Cancel the active goal `goal_id` (the arm brakes along its path). Raises UnknownNameError."""
        h = self._handle
        if h is None or h.id != goal_id or not h.active:
            raise UnknownNameError("active goal", goal_id, [h.id] if h is not None and h.active else [])
        self.inbox.put(Input.CANCEL, goal_id)

    def active_goal(self) -> GoalHandle | None:
        h = self._handle
        return h if h is not None and h.active else None

    def measured(self) -> np.ndarray | None:
        """The last measured configuration [rad], or None before the first joint state."""
        js = self.liveness.last_js
        return None if js is None else js[1].position

    # ------------------------------------------------------------------ running
    def start(self, thread: bool = True) -> Controller:
        """Begin; thread=False: nothing runs until someone calls `step` (a simulation driving its own clock)."""
        self.worker.start(lambda answer: self.inbox.put(Input.ANSWER, answer))
        if thread:
            self.inbox.start()
        return self

    def stop(self) -> None:
        self.inbox.stop()
        self.worker.close()

    def step(self) -> None:
        """Handle every queued input and do what is due now (the controller's thread does this; so can a test)."""
        self.inbox.step()

    def _tick(self) -> None:
        now = self.clock()
        if (gap := self._checks.due(now)) is not None:
            sent, watching = self.moves.sent, self.state not in (State.WAITING, State.PLANNING)
            self._check(now)
            done = self.clock()
            self.latency.checked(done, gap, watching)
            if self.moves.sent != sent:
                self.latency.command_sent(done, now)
        if self.state is not State.WAITING and (why := self.liveness.silent(self.clock())) is not None:
            self._safe_stop(why)

    def _handle_input(self, kind: Input, data) -> None:
        if kind is Input.JOINT_STATE:
            self._checks.joint_state()
            # a picked part may rest on its support until it has left it by more than the safety padding
            padding = max(self.cfg.safety_distance, self.checker.padding) + 0.005
            for name, sup in self.checker.world.release_support(data.position, padding):
                log.info("%s has left %s: it is checked against it again", name, sup)
        elif kind is Input.MAP:
            self._checks.map()
        elif kind is Input.GOAL:
            self._start_goal(data)
        elif kind is Input.CANCEL:
            if self._handle is not None and self._handle.id == data and self.state is not State.WAITING:
                self.moves.brake()
                self._finish(GoalStatus.CANCELED, "canceled by the client")
                self.canceled(reason="canceled by the client")
        elif kind is Input.ANSWER:
            self._on_answer(data)
        elif kind is Input.CALL:
            data()

    # ------------------------------------------------------------------ goals
    def _accept(self, handle: GoalHandle) -> np.ndarray | None:
        """The goal configuration, or None after rejecting the goal with the reason."""
        h = self._handle
        if h is not None and h.id == handle.id and h.active:
            reason = f"goal id {handle.id!r} is already active; use a new id"
        else:
            reason = self.liveness.silent(self.clock(), ready=True)
        if reason is None and self.state is State.WAITING:  # a robot that stopped on its own: plan from there
            reason = self.moves.settle(self.liveness.last_js[1], self.cfg.tracking_tolerance)
        if reason is None:
            try:
                return self.planner.resolve_goal(self.measured(), handle.goal.target, handle.goal.padding)
            except ReplannerError as err:
                reason = str(err)
        handle.reject(reason)
        return None

    def _start_goal(self, handle: GoalHandle) -> None:
        q_goal = self._accept(handle)
        if q_goal is None:
            return
        if self._handle is not None and self._handle.active:
            self._cancel_job()
            self.moves.brake()
            self._finish(GoalStatus.PREEMPTED, f"preempted by goal {handle.id!r}")
        handle.accept(q_goal)
        self._handle, self.monitor.padding = handle, handle.goal.padding  # the monitor looks at its path with it
        now = self.clock()
        if self.state is State.WAITING and not self.moves.timeline.busy(now):
            err = float(np.abs(self.measured() - q_goal).max())
            if err <= self.cfg.goal_tolerance:  # nothing to plan: a path needs two distinct points
                self._finish(GoalStatus.SUCCEEDED, f"already at the goal (within {err:.4f} rad)")
                return
        self.plan(reason=f"goal {handle.id!r} accepted")
        self._launch(JobPurpose.GOAL, self._deadline())

    def _deadline(self) -> float:
        d = self._handle.goal.deadline
        return d if d is not None else self.default_deadline

    def _finish(self, status: GoalStatus, reason: str) -> None:
        h = self._handle
        if h is None:
            return
        result = GoalResult(h.id, status, reason, self.clock())
        if h.finish(result):
            self.log_event("result", status=status.value, reason=reason)
            self.history.result(result)

    # ------------------------------------------------------------------ planning jobs
    def _launch(self, purpose: JobPurpose, deadline: float) -> None:
        """Plan to the goal: from where the arm will be when the plan lands if it moves, else from rest."""
        self._cancel_job()
        now, goal = self.clock(), self._handle.goal
        land, base = None, None
        if self.moves.timeline.moving(now):
            land = now + deadline + self.latency.landing_margin(now, self.cfg.splice_margin)
            base = self.moves.timeline.active(land)  # running then (a slow-down may take over first)
            start_q = base[1].state_at(land - base[0])[0]
        else:
            start_q = self.measured() if self.liveness.last_js else self.robot.home
        rest = (goal.velocity_scale, goal.acceleration_scale, now, goal.padding, self._separation(purpose, now, land))
        q_goal, job_id = self._handle.q_goal, next(self._job_ids)
        self._job = PlanJob(job_id, purpose, start_q, q_goal, deadline, land, base, goal.planner, *rest)
        self.log_event("plan_requested", purpose=purpose.value, job=self._job.id)
        self.worker.submit(self._job, self.checker.world.snapshot())

    def _separation(self, purpose: JobPurpose, now: float, land: float | None) -> SeparationPlan | None:
        """Every plan keeps speed and separation from the map when the monitor watches it (the monitor's T_r, the time
        until the path runs: its landing, or the time plans have been taking)."""
        if not self.monitor.speed_checks or not self.cfg.speed_separation.plans:
            return None
        after = land - now if land is not None else self.latency.rest_answer(now, self.cfg.replan_deadline)
        lat = self.latency
        return SeparationPlan(self.cfg.speed_separation, lat.reaction_time(now), lat.joint_state_age(now), after)

    def _cancel_job(self) -> None:
        if self._job is not None:
            self.worker.cancel(self._job)
            self._job = None

    def _on_answer(self, answer: PlanAnswer) -> None:
        if self._job is not (job := answer.job):
            return  # canceled or superseded
        self._job, now = None, self.clock()
        if job.land is not None:
            self.latency.plan_answered(now, job.requested, job.deadline, answer.result and answer.result.total_time)
        else:
            self.latency.answered_at_rest(now, job.requested)
        if answer.error is None and job.land is not None and now > job.land - 0.002:
            late = TrajectoryError(f"the plan arrived {now - job.land:.3f} s after its landing time")
            answer = PlanAnswer(job, error=late)
        elif answer.error is None and job.base is not None:
            running = self.moves.timeline.active(job.land)
            if running is None or running[1] is not job.base[1] or running[0] != job.base[0]:
                changed = TrajectoryError("the motion changed while the replan was computed (a speed change)")
                answer = PlanAnswer(job, error=changed)
        if answer.error is not None:
            self._plan_error(job, answer.error)
            return
        if job.purpose is JobPurpose.HOLD and self.state is State.HOLDING:
            why = self._start_blocked(answer.trajectory, now)
            if why is not None:  # people came closer while it planned: the next check would only stop it again
                self.log_event("plan_dropped", purpose=job.purpose.value, job=job.id, why=why)
                return
        start = self.moves.send_planned(answer.trajectory, job.land)
        res = answer.result
        self.log_event(
            "plan_sent",
            purpose=job.purpose.value,
            job=job.id,
            land=start,
            plan_time=res.total_time,
            spliced=job.base is not None,
        )
        state = self.state
        if job.purpose is JobPurpose.REPLAN and state is State.PENDING:
            self.spliced(reason=f"replan spliced at +{start - now:.3f} s ({len(res.path)} waypoints)")
        elif job.purpose is JobPurpose.GOAL and state is State.PLANNING:
            self.start_motion(reason=f"trajectory of {answer.trajectory.duration:.2f} s sent")
        elif job.purpose is JobPurpose.HOLD and state is State.HOLDING:
            self.start_motion(reason="a new path around the obstacle")

    def _plan_error(self, job: PlanJob, err: Exception) -> None:
        now, state = self.clock(), self.state
        self.log_event("plan_error", purpose=job.purpose.value, job=job.id, error=str(err))
        if job.purpose is JobPurpose.GOAL and state is State.PLANNING:
            self.moves.brake()
            self._finish(GoalStatus.FAILED, f"planning failed: {err}")
            self.plan_failed(reason=str(err))
        elif job.purpose is JobPurpose.REPLAN and state is State.PENDING:
            if isinstance(err, StartInvalid):  # where the arm would be when the plan lands is not free: stop
                self._safety_brake(f"the path is blocked just ahead ({err})")
            elif now - self._pending.since + self.cfg.replan_deadline >= self.cfg.pending_timeout:
                self._safety_brake(f"replanning failed: {err}")
            elif isinstance(err, GoalInvalid):  # the goal itself is blocked: keep watching, try again shortly
                self._pending.retry_at = now + 0.1
            else:
                self._launch(JobPurpose.REPLAN, self.cfg.replan_deadline)
        elif job.purpose is JobPurpose.HOLD and state is State.HOLDING:
            self._on_hold(self._hold.plan_failed(err))

    # ------------------------------------------------------------------ stopping
    def _safety_brake(self, reason: str) -> None:
        self._cancel_job()
        self.moves.brake()
        if self.cfg.policy == AfterBrake.ABORT:
            self._finish(GoalStatus.FAILED, reason)
            self.brake_and_abort(reason=reason)
        else:
            self.brake_and_hold(reason=reason, now=self.clock())

    def _safe_stop(self, reason: str) -> None:
        self._cancel_job()
        try:
            self.moves.brake()
        except Exception:
            log.exception("brake failed")
        if self.state is not State.WAITING:
            self._finish(GoalStatus.FAILED, reason)
            self.fault(reason=reason)

    # ------------------------------------------------------------------ monitoring
    def _check(self, now: float) -> None:
        state = self.state
        if state in (State.WAITING, State.PLANNING) or self.liveness.last_js is None:
            return
        if self.cfg.reaction == Reaction.NONE:  # the comparison baseline: plan once, never look again
            self._reached(now)
            return
        js = self.liveness.last_js[1]
        holding, q = state is State.HOLDING, self.moves.resync(js.position, js.stamp, js.velocity)  # late
        self.tracking_error, why = off_record(
            js, self.moves.timeline, self.robot.joint_names, self.cfg.tracking_tolerance
        )
        if why is not None:
            self._safe_stop(why)
            return
        # holding: the way to the goal, not the stretch the brake still travels
        view = self.monitor.view(self.moves.timeline, now, q, to_curve_end=holding, check_gap=self._checks.gap)
        if view is None:
            return
        if holding:
            self._check_holding(now, view)
            return
        if self._reached(now):
            return
        speed = self.monitor.check_speed(view)
        if speed.blocking is not None:  # a protective stop: too close even at rest
            self.last_clearance = speed.blocking.clearance
            self._safety_brake(speed.blocking.reason)
            return
        if speed.speed_factor < self.cfg.speed_separation.min_speed_share:
            self._safety_brake(f"speed and separation allow {speed.speed_factor:.0%} of the speed: stop and hold")
            return
        if state is State.MONITORING:
            blocking = self.monitor.check_path(view).blocking
            if blocking is not None and self.cfg.reaction == Reaction.STOP_AND_WAIT:
                self._safety_brake(f"{blocking.reason}: stop, wait, then plan from rest")
            elif blocking is not None:
                self.log_event("blocked", check=blocking.check)
                self._reflex(now, "blocked", launch=False, urgent=True)  # first: the replan starts from the swerve
                self._set_speed(min(speed.speed_factor, self.cfg.pending_speed_factor))
                if self.cfg.reaction.replans:
                    self._launch(JobPurpose.REPLAN, self.cfg.replan_deadline)
                self.blocked(reason=blocking.reason, now=now)
            else:
                if speed.speed_factor < 1.0:  # speed and separation would slow the arm: move away as well
                    self._reflex(now, "close", launch=False)
                self._set_speed(speed.speed_factor)
        elif state is State.PENDING:
            self._check_pending(now, view, speed.speed_factor)

    def _reflex(self, now: float, why: str, launch: bool, urgent: bool = False) -> None:
        """Swerve if the reaction has a reflex; `launch`: a replan in flight was for the motion before the swerve."""
        if self.swerve is not None and self.swerve(now, why, urgent) and launch and self._job is not None:
            self._launch(JobPurpose.REPLAN, self.cfg.replan_deadline)

    def _set_speed(self, factor: float) -> None:
        if (was := self.moves.retime(factor)) is not None:
            self.log_event("speed", factor=round(factor, 3), was=round(was, 3))

    def _check_pending(self, now: float, view, speed_factor: float) -> None:
        pending = self._pending
        clear = self.monitor.check_path(view).clear
        stop = self.monitor.check_close(view, path_clear=clear).blocking
        if stop is not None:
            self.last_clearance = stop.clearance if stop.clearance is not None else self.last_clearance
            self._safety_brake(stop.reason)
        elif now - pending.since > self.cfg.pending_timeout:
            self._safety_brake(f"no new path within {self.cfg.pending_timeout} s")
        else:
            if not clear and self._job is None and pending.retry_due(now):
                self._launch(JobPurpose.REPLAN, self.cfg.replan_deadline)
            clear_count = pending.count(clear)
            if not clear or speed_factor < 1.0:
                self._reflex(now, "blocked" if not clear else "close", launch=True)
            if clear_count >= self.cfg.clear_checks:
                self._cancel_job()
                self.log_event("replan_canceled")
                self._set_speed(speed_factor)
                self.path_clear(reason=f"the path was clear for {clear_count} checks")
            else:
                self._set_speed(min(speed_factor, self.cfg.pending_speed_factor))

    # ------------------------------------------------------------------ holding
    def _check_holding(self, now: float, view) -> None:
        self._on_hold(self._hold.check(now, view, self.moves.timeline.moving(now), planning=self._job is not None))

    def _on_hold(self, decision: Decision) -> None:
        """Do what the hold decided."""
        if decision.act is Act.RESUME:
            self.moves.resume()
            self.resume(reason=decision.reason)
        elif decision.act is Act.GIVE_UP:
            self._finish(GoalStatus.FAILED, f"the path stayed blocked for {self.cfg.hold_timeout} s")
            self.give_up(reason=decision.reason)
        elif decision.act is Act.PLAN_AROUND:
            self._launch(JobPurpose.HOLD, self._deadline())
        elif decision.act is Act.RETREAT:
            self._retreat(decision.reason)

    def _retreat(self, why: str) -> None:
        """Stopped where no plan can start: back off along its own curve (see Moves.escape), never stuck."""
        arc = self.moves.escape()
        if arc is None:
            self.log_event("stuck", why=why)
        else:
            self.log_event("retreat", arc=arc, why=why)
            self._hold.left_path()

    def _start_blocked(self, traj, now: float) -> str | None:
        """Why a new path from rest may not start now (speed and separation would stop it at once), or None."""
        q, share = self.measured(), self.cfg.speed_separation.min_speed_share
        return None if q is None else speed_refusal(self.monitor.check_start(traj, now, q), share)

    def _reached(self, now: float) -> bool:
        if self.moves.timeline.busy(now):
            return False
        h = self._handle
        err = float(np.abs(self.measured() - h.q_goal).max())
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

    # ------------------------------------------------------------------ status
    def status(self) -> dict:
        h, now = self.active_goal(), self.clock()
        view = None
        if self.state not in (State.WAITING, State.PLANNING) and self.liveness.last_js is not None:
            view = self.monitor.view(self.moves.timeline, now, self.measured())
        return {
            "state": self.state.value,
            "goal_id": h.id if h is not None else None,
            "progress": view.progress if view is not None else None,
            "perception": list(self.sensors) or "none: static objects only",
            "checks": self.monitor.stats.checks,
            "clearance": self.last_clearance,
            "speed_factor": self.moves.speed_factor(),
            "tracking_error": self.tracking_error,  # [rad] the largest joint's, at the last check
            "swerves": self.swerve.count if self.swerve is not None else 0,
            "not_ready": self.liveness.silent(now, ready=True),  # why a goal sent now would be refused
            "latency": self.latency.report(now),
        }
