"""The planning child process: `python -m replanner.plan_process <request fd> <cancel fd>` (planning.ProcessWorker).

With the GIL, a planner thread and the monitor would share one core: the child plans on the other one. It builds
the same stack from the config it is sent, mirrors the world it is given with each job, and answers every job
with (kind, job number, data): the finished trajectory and its PlanResult, or the error itself (data included).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from multiprocessing.connection import Connection

import numpy as np

EARLY_CANCELS = 64  # cancels of jobs not (yet) seen that are kept


def serve(conn: Connection, cancel_conn: Connection) -> None:
    from . import late_compiles
    from .collision.selfclearance import clearance_tables
    from .config import parse_config
    from .planning import PlanningCanceled
    from .planning.worker import error_for_the_wire, plan_and_time
    from .stack import build_stack
    from .world.occupancy import OccupancyMap

    cfg_data, seed = conn.recv()
    cfg = parse_config(cfg_data)
    with late_compiles.building():
        stack = build_stack(cfg, seed=seed, static=(), cameras=False)
        clearance_tables(stack.robot)
    late_compiles.watch()  # a compile from here on eats a replan's deadline
    world = stack.world
    cancel = threading.Event()
    current = [0]
    early: dict[int, None] = {}  # jobs canceled before their request was read: a cancel may overtake its request
    lock = threading.Lock()

    def listen_for_cancels() -> None:
        while True:
            try:
                job = cancel_conn.recv()
            except (EOFError, OSError):
                return
            with lock:
                if job == current[0]:
                    cancel.set()
                else:
                    early[job] = None
                    while len(early) > EARLY_CANCELS:  # the oldest: jobs that had ended before their cancel came
                        early.pop(next(iter(early)))

    def die_with_the_parent(parent: int) -> None:
        while os.getppid() == parent:  # a plan in progress reads no socket: a killed parent must end it too
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=listen_for_cancels, daemon=True).start()
    threading.Thread(target=die_with_the_parent, args=(os.getppid(),), daemon=True).start()
    conn.send(("ready", 0, None))
    while True:
        try:
            req = conn.recv()
        except (EOFError, OSError):
            return  # the parent is gone
        if req is None:
            return
        with lock:
            current[0] = req.job
            if req.job in early:
                del early[req.job]
                cancel.set()
            else:
                cancel.clear()
        try:
            if req.static is not None or req.attachments is not None:
                for name in world.names():  # not world.clear(): that would drop the occupancy map too
                    world.remove(name)
                for name, shape, pose in req.static or ():
                    world.add(name, shape, pose)
                for name, shape, link, T, touch, support in req.attachments or ():
                    world.attach_new(name, shape, link, T, touch, support)
            if req.occupancy == ():
                world.set_occupancy(None)
            elif req.occupancy is not None:
                keys, res, stamp = req.occupancy
                cell = cfg.collision.broadphase_cell
                world.set_occupancy(
                    OccupancyMap(keys.astype(np.int64), res, stamp=stamp, broadphase_cell=cell, trusted=True)
                )
            if cancel.is_set():
                raise PlanningCanceled("planning canceled before it started")
            answer = ("ok", req.job, plan_and_time(stack.planner, stack.generator, req.plan, cancel))
        except Exception as err:  # the parent must always get an answer
            answer = ("error", req.job, error_for_the_wire(err))
        try:
            conn.send(answer)
        except (EOFError, OSError):
            return
        try:
            stack.planner.prepare()  # between jobs, not inside the next one's deadline
        except Exception:  # the next job says what is wrong, with its own answer
            pass
        late_compiles.new_signatures()  # logs a specialization the warm-ups missed: the next cold start stalls there


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches the whole group: the parent decides, EOF ends us
    serve(Connection(int(sys.argv[1])), Connection(int(sys.argv[2])))
