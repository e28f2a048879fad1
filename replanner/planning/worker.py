"""The plan worker: plans in the background while the arm moves, one job at a time, the newest job first.

One interface, two backends: `ThreadWorker` plans in a thread of this process (simple; shares the GIL with the
monitor), `ProcessWorker` in a child process (the product's default: the second core). A job is planned from its
start, then timed from rest or spliced onto the motion in progress; the answer (a trajectory, or the error with its
data) goes to the callback given to `start`, from the worker's thread.
"""

from __future__ import annotations

import functools
import logging
import pickle
import socket
import subprocess
import sys
import threading
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from multiprocessing.connection import Connection

import numpy as np

from ..errors import ReplannerError
from ..monitor.ssm import SeparationCaps, SeparationPlan
from ..trajectory import Trajectory, TrajectoryGenerator
from ..trajectory.timelaw import SpeedCaps
from ..world.scene import WorldSnapshot
from .planner import Planner
from .types import PlanningCanceled, PlanningError, PlanResult, SeparationInfeasible

log = logging.getLogger(__name__)


class JobPurpose(str, Enum):
    GOAL = "goal"  # the first plan of a goal, from rest or from the motion being preempted
    REPLAN = "replan"  # the path is blocked while moving: a new path spliced on where the arm will be
    HOLD = "hold"  # braked and holding: a new path from rest


@dataclass
class PlanJob:
    """What to plan: from `start` to `q_goal` within `deadline` [s]; spliced onto `base` at `land` if given.

    base: (start time [clock s], trajectory) running when the plan lands; land: absolute time the new trajectory
    takes over (None: from rest, as soon as it is ready).
    """

    id: int
    purpose: JobPurpose
    start: np.ndarray
    q_goal: np.ndarray
    deadline: float
    land: float | None = None
    base: tuple[float, Trajectory] | None = None
    planner: str | None = None
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    requested: float = 0.0
    padding: float | None = None  # [m] from known objects; None: the planner's
    separation: SeparationPlan | None = None  # keep speed and separation from the map's voxels (None: its padding)
    cancel: threading.Event = field(default_factory=threading.Event, repr=False)

    def heading(self) -> np.ndarray | None:
        """The joint velocity of the base's motion where the new trajectory takes over (None: from rest)."""
        return None if self.base is None else self.base[1].state_at(self.land - self.base[0])[1]

    def __getstate__(self) -> dict:  # the cancel event stays in this process
        return {k: v for k, v in self.__dict__.items() if k != "cancel"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, cancel=threading.Event())


@dataclass(frozen=True)
class PlanAnswer:
    """A job's outcome: a trajectory and how it was planned, or the error (any ReplannerError, data included)."""

    job: PlanJob
    trajectory: Trajectory | None = None
    result: PlanResult | None = None
    error: Exception | None = None


class PlanWorker(ABC):
    """Plans jobs one at a time in a thread of its own; a job submitted while another waits replaces it."""

    def __init__(self):
        self._on_answer: Callable[[PlanAnswer], None] | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._next: tuple[PlanJob, WorldSnapshot] | None = None
        self._running: PlanJob | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.recorder = None  # a recording.JobRecorder: every answered job is kept on disk too

    def start(self, on_answer: Callable[[PlanAnswer], None]) -> PlanWorker:
        """Begin; `on_answer` is called from the worker's thread with every answer (it must not block)."""
        self._on_answer = on_answer
        self._thread = threading.Thread(target=self._loop, name="plan-worker", daemon=True)
        self._thread.start()
        return self

    def submit(self, job: PlanJob, snapshot: WorldSnapshot) -> None:
        """Plan `job` against the world `snapshot` next (replacing a job that has not started)."""
        with self._lock:
            self._next = (job, snapshot)
            self._wake.set()

    def busy(self) -> bool:
        """A job is being planned now."""
        return self._running is not None

    def cancel(self, job: PlanJob) -> None:
        """Stop `job` (it answers PlanningCanceled if it was running, nothing if it had not started)."""
        job.cancel.set()
        with self._lock:
            if self._next is not None and self._next[0] is job:
                self._next = None
            running = self._running is job
        if running:
            self._interrupt(job)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._running is not None:
            self.cancel(self._running)
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            with self._lock:
                item, self._next = self._next, None
                self._wake.clear()
                if item is not None and item[0].cancel.is_set():
                    item = None  # canceled before it started: dropped unanswered, and the worker is not busy
                if item is not None:
                    self._running = item[0]
            if item is None:
                continue
            job, snapshot = item
            try:
                traj, res = self.solve(job, snapshot)
                answer = PlanAnswer(job, traj, res)
            except ReplannerError as err:
                answer = PlanAnswer(job, error=err)
            except Exception as err:  # the worker must always answer
                log.exception("plan worker failed")
                answer = PlanAnswer(job, error=err)
            finally:
                with self._lock:
                    self._running = None
            if self._on_answer is not None:
                self._on_answer(answer)
            if self.recorder is not None:
                self.recorder.record(job, snapshot, answer)
            self._between_jobs()

    def _between_jobs(self) -> None:  # noqa: B027  (a hook: the thread backend prepares its planner)
        """Work that must not wait inside the next job's deadline."""

    @abstractmethod
    def solve(self, job: PlanJob, snapshot: WorldSnapshot) -> tuple[Trajectory, PlanResult]:
        """Plan and time `job` (in the worker's thread); raise PlanningError or TrajectoryError."""

    def _interrupt(self, job: PlanJob) -> None:  # noqa: B027  (a hook: the thread backend watches job.cancel)
        """Stop the running `job` now."""


def plan_and_time(
    planner: Planner, gen: TrajectoryGenerator, job: PlanJob, cancel: threading.Event | None = None
) -> tuple[Trajectory, PlanResult]:
    """The work of a job: a path from its start, then timed from rest or spliced onto its base at `land` (the path
    told the base's motion there: one that would start against it cannot be spliced on). A job with `separation`
    keeps S_p from the map's voxels: its search keeps the margin at rest, its timing the speed each stretch allows."""
    if job.separation is not None:
        try:
            return _plan_and_time(planner, gen, job, cancel, _separation(planner, gen, job))
        except PlanningCanceled:
            raise
        except PlanningError:
            if job.purpose is not JobPurpose.GOAL:
                raise
            # a goal's first plan keeps its padding when no path keeps S_p: the monitor holds the arm till there is room
    return _plan_and_time(planner, gen, job, cancel, (None, 0.0))


def _plan_and_time(planner, gen, job, cancel, separation) -> tuple[Trajectory, PlanResult]:
    guard, margin = separation
    res = planner.plan(
        job.start,
        job.q_goal,
        planner=job.planner,
        deadline=job.deadline,
        cancel=cancel,
        padding=job.padding,
        heading=job.heading(),
        map_margin=margin,
    )
    caps_of = None
    if guard is not None:  # the curve's blends keep the path's margin too
        gen = gen.with_checker(planner.paddings.get(job.padding, None, margin).exact)
        caps_of = functools.partial(_caps, guard)
    if job.base is not None:
        start, base = job.base
        traj = gen.splice(base, job.land - start, res.path, job.velocity_scale, job.acceleration_scale, caps_of=caps_of)
    else:
        traj = gen.time(res.path, job.velocity_scale, job.acceleration_scale, caps_of=caps_of)
    return traj, res


def _separation(planner: Planner, gen: TrajectoryGenerator, job: PlanJob) -> tuple[SeparationCaps | None, float]:
    """The job's speed-and-separation guard (None: nothing to keep it from) and its search's map margin [m]; raises
    when its start has no room to move."""
    sep = job.separation
    occ = planner.exact.world.snapshot().occupancy
    if sep is None or not sep.cfg.enabled or occ is None or not len(occ):
        return None, 0.0
    guard = SeparationCaps(planner.exact, occ, sep, gen.limits(job.velocity_scale, job.acceleration_scale))
    S, margin = guard.start_room(job.start)
    if S < guard.at_rest():
        raise SeparationInfeasible(
            f"speed and separation: the start is {S:.3f} m from what the cameras see, less than the "
            f"{guard.at_rest():.3f} m a path from it needs (S_p at rest with T_r {sep.reaction_time * 1e3:.0f} ms, "
            f"and {guard.approach:.3f} m a person comes while it is made and started)"
        )
    return guard, margin


def _caps(guard: SeparationCaps, curve) -> SpeedCaps:
    caps = guard(curve)
    if guard.infeasible:
        raise SeparationInfeasible(
            f"speed and separation: {guard.infeasible} stretches of the path come closer to what the cameras see than "
            f"an arm at rest may ({guard.at_rest():.3f} m)"
        )
    return caps


class ThreadWorker(PlanWorker):
    """Plans in a thread of this process, with the checker the monitor uses (it sees the live world)."""

    def __init__(self, planner: Planner, generator: TrajectoryGenerator):
        super().__init__()
        self.planner, self.gen = planner, generator

    def solve(self, job: PlanJob, snapshot: WorldSnapshot) -> tuple[Trajectory, PlanResult]:
        return plan_and_time(self.planner, self.gen, job, job.cancel)

    def _between_jobs(self) -> None:
        self.planner.prepare()


class InlineWorker(PlanWorker):
    """Plans when a job is submitted, in the caller's thread; the answer is handed over by `deliver()` once `delay`
    [s] of `clock` has passed. Whoever drives that clock calls `deliver()`: a simulation that runs the same on any
    machine, with planning taking exactly `delay` of simulated time."""

    def __init__(
        self, planner: Planner, generator: TrajectoryGenerator, clock: Callable[[], float], delay: float = 0.0
    ):
        super().__init__()
        self.planner, self.gen, self.clock, self.delay = planner, generator, clock, float(delay)
        self._due: list[tuple[float, PlanAnswer]] = []

    def start(self, on_answer: Callable[[PlanAnswer], None]) -> PlanWorker:
        self._on_answer = on_answer
        return self

    def submit(self, job: PlanJob, snapshot: WorldSnapshot) -> None:
        try:
            traj, res = self.solve(job, snapshot)
            answer = PlanAnswer(job, traj, res)
        except ReplannerError as err:
            answer = PlanAnswer(job, error=err)
        self._due.append((self.clock() + self.delay, answer))
        if self.recorder is not None:
            self.recorder.record(job, snapshot, answer)

    def deliver(self) -> None:
        """Hand over every answer whose time has come."""
        now = self.clock()
        ready = [a for t, a in self._due if t <= now]
        self._due = [(t, a) for t, a in self._due if t > now]
        for answer in ready:
            if not answer.job.cancel.is_set() and self._on_answer is not None:
                self._on_answer(answer)

    def cancel(self, job: PlanJob) -> None:
        job.cancel.set()

    def close(self) -> None:
        self._due = []

    def solve(self, job: PlanJob, snapshot: WorldSnapshot) -> tuple[Trajectory, PlanResult]:
        return plan_and_time(self.planner, self.gen, job, job.cancel)


@dataclass
class PlanRequest:
    """One job for the child; the world travels only when it changed since the last request."""

    job: int
    static: tuple | None  # ((name, shape, pose), ...), or None when unchanged
    attachments: tuple | None  # ((name, shape, link, T_link_object, touch_links, support), ...) or None
    occupancy: tuple | None  # (keys int32 (N, 3), resolution, stamp), None: unchanged, (): no map
    plan: PlanJob


def start_plan_process() -> tuple[subprocess.Popen, Connection, Connection]:
    """Starts `python -m replanner.plan_process`; returns it with its request and cancel connections.

    The child waits for (core config as a dict, seed) on the request connection and answers ("ready", ...).
    """
    req_parent, req_child = socket.socketpair()
    cancel_parent, cancel_child = socket.socketpair()
    fds = (req_child.fileno(), cancel_child.fileno())
    proc = subprocess.Popen([sys.executable, "-m", "replanner.plan_process", *map(str, fds)], pass_fds=fds)
    req_child.close()
    cancel_child.close()
    return proc, Connection(req_parent.detach()), Connection(cancel_parent.detach())


class ProcessWorker(PlanWorker):
    """Plans in a child process (`python -m replanner.plan_process`) built from the same config.

    Requests and cancels travel over two inherited socket pairs; answers carry their job's number, so an answer
    that comes too late for its job is never taken for the next one's.

    Args:
        cfg: the service's config (robot, collision, planning sections are used).
        seed: the child's planner seed (reproducible plans).
        start_timeout: [s] to wait for the child to build its stack (seconds; a first start compiles the kernels).
        answer_margin: [s] beyond a job's deadline to wait for the child before giving up on that job (negative:
            before it; tests use that to see a given-up answer arrive late).
        wait: wait here for the child to be ready; False: the caller builds meanwhile and calls `wait_ready()`
            (`start` waits too).
    """

    def __init__(
        self,
        cfg,
        seed: int | None = None,
        *,
        start_timeout: float = 300.0,
        answer_margin: float = 30.0,
        wait: bool = True,
    ):
        super().__init__()
        self._proc, self._conn, self._cancel_conn = start_plan_process()
        self.answer_margin, self.start_timeout = float(answer_margin), float(start_timeout)
        self._ready = False
        self._conn.send((cfg.core().model_dump(mode="python"), seed))
        self._sent_version: int | None = None
        self._sent_map: object | None = None
        if wait:
            self.wait_ready()

    def wait_ready(self) -> None:
        """Wait until the child has built its stack (at most `start_timeout`; then it is closed and this raises)."""
        if self._ready:
            return
        if not self._conn.poll(self.start_timeout):
            self.close()
            raise ReplannerError(
                f"the planning process did not start within {self.start_timeout} s (a first start on a machine "
                "compiles the kernels into numba's cache: see that the cache directory is writable, or set "
                "NUMBA_CACHE_DIR)"
            )
        self._conn.recv()
        self._ready = True

    def start(self, on_answer: Callable[[PlanAnswer], None]) -> PlanWorker:
        self.wait_ready()
        return super().start(on_answer)

    def _interrupt(self, job: PlanJob) -> None:
        try:
            self._cancel_conn.send(job.id)
        except OSError:
            pass

    def solve(self, job: PlanJob, snapshot: WorldSnapshot) -> tuple[Trajectory, PlanResult]:
        static = attachments = None
        if snapshot.version != self._sent_version:
            static = tuple((o.name, o.shape, o.pose) for o in snapshot.objects.values())
            attachments = tuple(
                (a.name, a.shape, a.link, a.T_link_object, a.touch_links, a.support)
                for a in snapshot.attachments.values()
            )
        occ = snapshot.occupancy
        occupancy = None
        if occ is not self._sent_map:
            occupancy = () if occ is None or not len(occ) else (occ.keys.astype(np.int32), occ.resolution, occ.stamp)
        self._conn.send(PlanRequest(job.id, static, attachments, occupancy, job))
        self._sent_version, self._sent_map = snapshot.version, occ
        wait = job.deadline + self.answer_margin
        while True:
            if not self._conn.poll(wait):
                raise PlanningError(f"the planning process did not answer within {wait:.1f} s")
            kind, job_id, data = self._conn.recv()
            if job_id == job.id:
                break
            log.debug("dropped a late answer of job %s", job_id)  # its job was given up: never the next one's
        if kind == "ok":
            return data
        raise data

    def close(self) -> None:
        super().close()
        try:
            self._conn.send(None)
        except OSError:
            pass
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.terminate()


def error_for_the_wire(err: BaseException) -> Exception:
    """`err` if it survives pickling (type and data intact), else a ReplannerError carrying its traceback."""
    try:
        pickle.loads(pickle.dumps(err))
        return err
    except Exception:
        text = "".join(traceback.format_exception(err))
        return ReplannerError(f"{type(err).__name__} in the planning process: {err}\n{text}")
