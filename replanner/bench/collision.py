"""`replanner bench collision`: boolean and distance checks of a robot against a table and a ~50k-voxel octree."""

from __future__ import annotations

import os
import time

import numpy as np

from ..collision.exact import CollisionChecker
from ..collision.fast.checker import FastChecker
from ..collision.fast.convex import decide_batch
from ..collision.fast.layer import CONTACT, FREE, UNSURE
from ..config import ReplannerConfig
from ..model.robot import RobotModel
from ..stats import summary
from ..world.scene import World
from .scenes import add_table, clutter_map


def run(
    cfg: ReplannerConfig,
    *,
    seed: int = 0,
    runs: int = 5,
    n: int = 5000,
    voxels: int = 50_000,
    resolution: float = 0.01,
    chunk: int = 64,
    distance_n: int = 300,
    progress=None,
) -> dict:
    """Measure checks per second; inputs are fixed by `seed`. Returns a JSON-ready dict.

    Boolean checks are measured two ways: one configuration per call (`is_valid`, what a sampler calls) and
    `chunk` configurations per call (`is_valid_batch`, what path and motion checks call). Rates are medians over
    `runs` runs of `n` random configurations within the joint limits (the first, warm-up run is not counted).
    """
    rng = np.random.default_rng(seed)
    robot = RobotModel.from_config(cfg.robot)
    world = World(robot)
    add_table(world)
    occupancy = clutter_map(rng, voxels, resolution, broadphase_cell=cfg.collision.broadphase_cell)
    world.set_occupancy(occupancy)
    checker = CollisionChecker.from_config(robot, world, cfg.collision)
    Qs = [robot.random_q(rng, n) for _ in range(runs + 1)]
    Qd = robot.random_q(rng, distance_n)

    single_rates, batch_rates, latencies, valid = [], [], [], []
    for r, Q in enumerate(Qs):
        lat = np.empty(n)
        t_start = time.perf_counter()
        for i, q in enumerate(Q):
            t0 = time.perf_counter_ns()
            checker.is_valid(q)
            lat[i] = time.perf_counter_ns() - t0
        single = n / (time.perf_counter() - t_start)
        t_start = time.perf_counter()
        v = np.concatenate([checker.is_valid_batch(Q[i : i + chunk]) for i in range(0, n, chunk)])
        batch = n / (time.perf_counter() - t_start)
        if r > 0:  # run 0 warms caches up
            single_rates.append(single)
            batch_rates.append(batch)
            latencies.append(lat / 1e3)
            valid.append(v.mean())
        if progress:
            progress(r, runs + 1)
    layer = _layer_rates(checker, Qs, chunk)
    dist_lat = []
    for q in Qd:
        t0 = time.perf_counter_ns()
        checker.clearance(q)
        dist_lat.append((time.perf_counter_ns() - t0) / 1e3)
    lat_all = np.concatenate(latencies)
    return {
        "bench": "collision",
        "robot": robot.name,
        "seed": seed,
        "scene": {
            "table": True,
            "octree_voxels": len(occupancy),
            "resolution_m": resolution,
            "padding_m": checker.padding,
            "self_padding_m": robot.self_padding,
        },
        "configurations": "uniform random within joint limits",
        "valid_fraction": float(np.mean(valid)),
        "boolean_single": {
            "checks_per_s_median": float(np.median(single_rates)),
            "checks_per_s_runs": [round(x) for x in single_rates],
            "latency_us": summary(lat_all),
            "runs": runs,
            "n_per_run": n,
        },
        "boolean_batched": {
            "chunk": chunk,
            "checks_per_s_median": float(np.median(batch_rates)),
            "checks_per_s_runs": [round(x) for x in batch_rates],
            "runs": runs,
            "n_per_run": n,
        },
        "distance": {
            "queries_per_s_median": float(1e6 / np.median(dist_lat)),
            "latency_us": summary(np.array(dist_lat)),
            "max_distance_m": 1.0,
        },
        "planning_layer": layer,
        "bar_boolean_checks_per_s": 20_000,
        "bar_layer_checks_per_s": 1_000_000,
    }


def _layer_rates(checker: CollisionChecker, Qs: list[np.ndarray], chunk: int) -> dict:
    """The fast layer (collision/fast) on the same configurations: its own verdicts (free / contact for certain,
    or unsure) per second, forward kinematics included: whole runs on one core and on all, `chunk` at a time, and
    its verdicts with the convex pass and FCL deciding the unsure ones (`verdicts_unlike_fcl` counts those unlike
    FCL's, and the parallel kernel's unlike the serial one's: 0)."""
    fast = FastChecker(checker)
    robot = checker.robot
    c = fast.layers()
    layer, vol, convex = c.spheres, c.volume, c.convex
    whole, par, chunked, with_fcl, shares, disagree, left = [], [], [], [], [], 0, []
    for r, Q in enumerate(Qs):
        t0 = time.perf_counter()
        verdict = layer.classify(Q, vol)
        tp = time.perf_counter()
        disagree += int((layer.classify(Q, vol, parallel=True) != verdict).sum())
        t1 = time.perf_counter()
        for i in range(0, len(Q), chunk):
            layer.classify(Q[i : i + chunk], vol)
        t2 = time.perf_counter()
        valid = np.concatenate([fast.is_valid_batch(Q[i : i + chunk]) for i in range(0, len(Q), chunk)])
        t3 = time.perf_counter()
        if r > 0:  # run 0 compiles and warms up
            whole.append(len(Q) / (tp - t0))
            par.append(len(Q) / (t1 - tp))
            chunked.append(len(Q) / (t2 - t1))
            with_fcl.append(len(Q) / (t3 - t2))
            shares.append([float((verdict == k).mean()) for k in (FREE, CONTACT, UNSURE)])
            unsure = np.flatnonzero(verdict == UNSURE)
            left.append(float((decide_batch(convex, layer, robot.frames(Q), unsure, vol) == UNSURE).sum() / len(Q)))
            disagree += int((valid != checker.is_valid_batch(Q)).sum())
    share = np.mean(shares, axis=0)
    return {
        "spheres": len(layer.radius),
        "inner_balls": len(layer.in_rad),
        "checks_per_s_median": float(np.median(whole)),
        "checks_per_s_runs": [round(x) for x in whole],
        "parallel_checks_per_s_median": float(np.median(par)),
        "parallel_checks_per_s_runs": [round(x) for x in par],
        "cores": os.cpu_count(),
        "forward_kinematics_included": True,
        "chunk": chunk,
        "chunked_checks_per_s_median": float(np.median(chunked)),
        "with_fcl_checks_per_s_median": float(np.median(with_fcl)),
        "free_for_certain": float(share[0]),
        "contact_for_certain": float(share[1]),
        "unsure_after_spheres": float(share[2]),
        "unsure_to_fcl": float(np.mean(left)),  # what neither the spheres nor the convex pass decide
        "verdicts_unlike_fcl": disagree,
    }
