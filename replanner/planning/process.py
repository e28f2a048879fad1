"""Planning in a child process: with the GIL, a planner thread and the monitor would share one core.

The child builds the same robot, checker, planner and trajectory generator from the config. Each job carries
the world as it is (static objects, attachments, and the occupancy voxels when they changed); the answer is
the finished trajectory (timed, or spliced onto the motion in progress) or the planning error.
"""

from __future__ import annotations

import itertools
import logging
import socket
import subprocess
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection

import numpy as np

from ..errors import ReplannerError
from ..trajectory.generator import Trajectory, TrajectoryError
from .planner import GoalInvalid, NoSolution, PlanningCanceled, PlanningError, PlanResult, StartInvalid

log = logging.getLogger(__name__)

_ERRORS = {
    c.__name__: c
    for c in (GoalInvalid, NoSolution, PlanningCanceled, PlanningError, StartInvalid, TrajectoryError, ReplannerError)
}


@dataclass
class _Request:
    static: tuple  # ((name, shape, pose), ...), or None when unchanged
    attachments: tuple  # ((name, shape, link, T_link_object, touch_links, support), ...), or None when unchanged
    occupancy: tuple | None  # (keys int32 (N, 3), resolution, stamp), None: unchanged, () : no map
    start: np.ndarray
    goal: np.ndarray
    planner: str | None
    deadline: float
    velocity_scale: float
    acceleration_scale: float
    base: tuple[Trajectory, float] | None  # (trajectory, t0): splice onto its state at t0


def _serve(conn, cancel_conn) -> None:
    """The child: `python -m replanner.planning.process <request fd> <cancel fd>`."""
    from ..config import parse_config
    from ..trajectory.generator import TrajectoryGenerator
    from ..world.collision import CollisionChecker
    from ..world.occupancy import OccupancyMap
    from ..world.robot import RobotModel
    from ..world.scene import World
    from .planner import Planner

    cfg_data, seed = conn.recv()
    cfg = parse_config(cfg_data)
    robot = RobotModel.from_config(cfg.robot)
    robot.self_clearance_tables()
    world = World(robot)
    checker = CollisionChecker.from_config(robot, world, cfg.collision)
    planner = Planner.from_config(checker, cfg.planning, seed=seed)
    gen = TrajectoryGenerator(robot, checker, tube_radius=cfg.planning.tube_radius)
    cancel = threading.Event()
    current = [0]

    def listen_for_cancels():
        while True:
            try:
                job = cancel_conn.recv()
            except (EOFError, OSError):
                return
            if job == current[0]:
                cancel.set()

    threading.Thread(target=listen_for_cancels, daemon=True).start()
    conn.send(("ready", None))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        job, req = msg
        current[0] = job
        cancel.clear()
        try:
            if req.static is not None or req.attachments is not None:
                for name in world.names():  # not world.clear(): that would drop the occupancy map too
                    world.remove(name)
                for name, shape, pose in req.static or ():
                    world.add(name, shape, pose)
                for name, shape, link, T, touch, support in req.attachments or ():
                    world.attach_new(name, shape, link, T, touch, support)
            if req.occupancy is not None:
                if req.occupancy == ():
                    world.set_occupancy(None)
                else:
                    keys, res, stamp = req.occupancy
                    world.set_occupancy(
                        OccupancyMap(
                            keys.astype(np.int64),
                            res,
                            stamp=stamp,
                            broadphase_cell=cfg.collision.broadphase_cell,
                            trusted=True,
                        )
                    )
            res = planner.plan(req.start, req.goal, planner=req.planner, deadline=req.deadline, cancel=cancel)
            if req.base is not None:
                traj = gen.splice(req.base[0], req.base[1], res.path, req.velocity_scale, req.acceleration_scale)
            else:
                traj = gen.time(res.path, req.velocity_scale, req.acceleration_scale)
            conn.send(("ok", (traj, res)))
        except ReplannerError as err:
            conn.send(("error", (type(err).__name__, str(err))))
        except Exception:  # the parent must always get an answer
            conn.send(("error", ("ReplannerError", traceback.format_exc())))


class PlanningProcess:
    """A planner in its own process. `plan` blocks the calling thread (not the GIL) until the answer comes.

    The child is `python -m replanner.planning.process` (not multiprocessing's spawn, which would re-run the caller's
    main script); requests and cancels travel over two inherited socket pairs.

    Args:
        cfg: the full config (robot, collision, planning sections are used).
        seed: OMPL seed in the child.
    """

    def __init__(self, cfg, seed: int | None = None, start_timeout: float = 60.0):
        req_parent, req_child = socket.socketpair()
        cancel_parent, cancel_child = socket.socketpair()
        fds = (req_child.fileno(), cancel_child.fileno())
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "replanner.planning.process", *map(str, fds)], pass_fds=fds
        )
        req_child.close()
        cancel_child.close()
        self._conn = Connection(req_parent.detach())
        self._cancel_conn = Connection(cancel_parent.detach())
        self._lock = threading.Lock()
        self._jobs = itertools.count(1)
        self._job = 0
        self._conn.send((cfg.core().model_dump(mode="python"), seed))
        if not self._conn.poll(start_timeout):
            self.close()
            raise ReplannerError(f"the planning process did not start within {start_timeout} s")
        self._conn.recv()
        self._sent_version: int | None = None
        self._sent_map: object | None = None

    def cancel(self) -> None:
        """Stop the running plan (it answers PlanningCanceled)."""
        try:
            self._cancel_conn.send(self._job)
        except OSError:
            pass

    def plan(
        self,
        snapshot,
        start,
        goal,
        *,
        planner=None,
        deadline=1.0,
        velocity_scale=1.0,
        acceleration_scale=1.0,
        base=None,
    ) -> tuple[Trajectory, PlanResult]:
        with self._lock:
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
                occupancy = (
                    () if occ is None or not len(occ) else (occ.keys.astype(np.int32), occ.resolution, occ.stamp)
                )
            req = _Request(
                static,
                attachments,
                occupancy,
                np.asarray(start, float),
                np.asarray(goal, float),
                planner,
                float(deadline),
                velocity_scale,
                acceleration_scale,
                base,
            )
            t0 = time.perf_counter()
            self._job = next(self._jobs)
            self._conn.send((self._job, req))
            self._sent_version, self._sent_map = snapshot.version, occ
            if not self._conn.poll(deadline + 30.0):
                raise PlanningError("the planning process did not answer")
            kind, data = self._conn.recv()
            log.debug("planning process answered in %.1f ms", (time.perf_counter() - t0) * 1e3)
        if kind == "ok":
            return data
        name, message = data
        raise _ERRORS.get(name, ReplannerError)(message)

    def close(self) -> None:
        try:
            self._conn.send(None)
        except OSError:
            pass
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.terminate()


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])), Connection(int(sys.argv[2])))
