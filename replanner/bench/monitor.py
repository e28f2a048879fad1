"""`replanner bench monitor`: remaining-path checks against a ~50k-voxel octree; check rate idle vs planning."""

from __future__ import annotations

import threading
import time

import numpy as np

from ..config import ReplannerConfig
from ..control import Controller, Goal, KinematicDriver, State
from ..model.robot import RobotModel
from ..planning import Planner, PlanningError
from ..stack import build_stack
from ..stats import summary
from ..world.occupancy import OccupancyMap
from .scenes import clutter_map, table

A = np.array([-1.4, 0.2, 0.0, -1.9, 0.0, 2.1, 0.785])
B = np.array([1.4, 0.2, 0.0, -1.9, 0.0, 2.1, 0.785])


def run(cfg: ReplannerConfig, *, seed: int = 0, voxels: int = 50_000, samples: int = 300, window: float = 2.0) -> dict:
    rng = np.random.default_rng(seed)
    robot = RobotModel.from_config(cfg.robot)
    driver = KinematicDriver(A, rate_hz=cfg.controller.driver_rate_hz)
    stack = build_stack(
        cfg, robot=robot, static=[table()], seed=seed, cameras=False, execute=driver.execute, plan_in="thread"
    )
    world, checker, ctl = stack.world, stack.checker, stack.controller
    while True:  # a seeded clutter that leaves the A -> B swing free, so every check runs to the end
        world.set_occupancy(clutter_map(rng, voxels, broadphase_cell=cfg.collision.broadphase_cell))
        if checker.path_valid(np.array([A, B])):
            break
    driver.subscribe(stack.on_joint_state)
    driver.start()
    ctl.start()
    try:
        # 1. the check itself, on remaining paths of >= 100 waypoints along a slow swing
        time.sleep(0.1)
        h = ctl.submit(Goal.joints("swing", B, velocity_scale=0.08))
        deadline = time.monotonic() + 5
        while ctl.state != State.MONITORING.value and time.monotonic() < deadline:
            time.sleep(0.01)
        stop_feed = threading.Event()

        def maps():  # a camera-rate stream of map updates, so the monitor checks on map updates too
            while not stop_feed.is_set():
                ctl.on_map()
                stop_feed.wait(1 / 30)

        feeder = threading.Thread(target=maps, daemon=True)
        feeder.start()
        lengths, paths, in_loop = [], [], []
        give_up = time.monotonic() + 20
        while len(paths) < samples and time.monotonic() < give_up:
            view = ctl.monitor.view(ctl.moves.timeline, time.monotonic(), ctl.measured())
            if view is None:
                time.sleep(0.005)
                continue
            if len(view.path) < 100:
                break
            t0 = time.perf_counter()
            checker.path_valid(view.path, robot_pairs=False)
            in_loop.append((time.perf_counter() - t0) * 1e3)  # beside the running controller's own threads
            paths.append(view.path)
            lengths.append(len(view.path))
            time.sleep(0.003)
        # 2. the controller's own check rate, idle and while a plan is being computed alongside
        idle = _rate(ctl, window)
        busy_stop = threading.Event()
        plans = []

        pairs = _blocked_pairs(robot, checker, rng, 20)

        def plan_forever():
            other = Planner.from_config(checker, cfg.planning)
            k = 0
            while not busy_stop.is_set():
                t0 = time.perf_counter()
                try:
                    other.plan(*pairs[k % len(pairs)], deadline=1.0)
                except PlanningError:
                    pass
                plans.append(time.perf_counter() - t0)
                k += 1

        worker = threading.Thread(target=plan_forever, daemon=True)
        worker.start()
        time.sleep(0.1)
        busy = _rate(ctl, window)
        busy_stop.set()
        worker.join(5)
        stop_feed.set()
        still_monitoring = ctl.state == State.MONITORING.value
        ctl.cancel("swing") if h.result is None else None
    finally:
        stack.close()
        driver.stop()
    # the check's own cost, with nothing else running in the process
    durations, full, new_map = _check_costs(checker, world, paths, cfg.collision.broadphase_cell)
    return {
        "bench": "monitor",
        "robot": robot.name,
        "seed": seed,
        "octree_voxels": len(world.occupancy),
        "remaining_path_check_ms": summary(durations),
        "remaining_path_check": "against the octree (static objects and self-collision were checked at planning)",
        "full_check_ms": summary(full),
        "full_check": "against the octree, static objects and attached objects (what a scene edit can change; "
        "the robot's own link pairs were checked at planning), on the remaining paths recorded during the swing",
        "full_check_in_loop_ms": summary(in_loop),
        "full_check_in_loop": "the same, timed during the swing beside the controller's threads (interpreter lock)",
        "full_check_new_map_ms": summary(new_map),
        "full_check_new_map": "the same on a map nobody has checked yet: builds its fcl.OcTree and broadphase first "
        "(the first check of a new path does this once per map)",
        "remaining_path_waypoints": summary(lengths),
        "check_rate_cap_hz": cfg.controller.check_rate_hz,
        "check_rate_idle_hz": idle,
        "check_rate_while_planning_hz": busy,
        "plans_during_window": len(plans),
        "plan_ms_during_window": summary(np.array(plans) * 1e3),
        "monitoring_throughout": still_monitoring,
        "bars": {"check_ms_median": 5.0, "full_check_ms_p95": 2.0, "rate_while_planning_hz": 100.0},
    }


def _check_costs(checker, world, paths, broadphase_cell: float) -> tuple[list, list, list]:
    """Per recorded path: octree-only check, full check, full check on a fresh copy of the map [ms]."""
    occ = world.occupancy
    octree, full, new_map = [], [], []
    for path in paths:
        t0 = time.perf_counter()
        checker.path_valid(path, octree_only=True)
        octree.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        checker.path_valid(path, robot_pairs=False)
        full.append((time.perf_counter() - t0) * 1e3)
    for path in paths[:: max(1, len(paths) // 30)]:
        fresh = OccupancyMap(occ.keys, occ.resolution, broadphase_cell=broadphase_cell, trusted=True)
        world.set_occupancy(fresh)
        t0 = time.perf_counter()
        checker.path_valid(path, robot_pairs=False)
        new_map.append((time.perf_counter() - t0) * 1e3)
    world.set_occupancy(occ)
    return octree, full, new_map


def _blocked_pairs(robot, checker, rng, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Valid start/goal pairs whose straight line is blocked: real planning work."""
    out = []
    while len(out) < n:
        a, b = robot.random_q(rng), robot.random_q(rng)
        if checker.is_valid(a) and checker.is_valid(b) and not checker.path_valid(np.array([a, b])):
            out.append((a, b))
    return out


def _rate(ctl: Controller, window: float) -> float:
    c0, t0 = ctl.monitor.stats.checks, time.monotonic()
    time.sleep(window)
    return (ctl.monitor.stats.checks - c0) / (time.monotonic() - t0)
