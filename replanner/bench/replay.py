"""`replanner bench replay DIR`: the jobs a service recorded (`planning.record_jobs`) planned again here, in one
planner as the service's planning process holds it (the world set up again only when it changed, each job's map
new): how long each plan takes on this machine and version, next to what the service took."""

from __future__ import annotations

import json

import numpy as np

from ..config import ReplannerConfig, parse_config
from ..errors import InvalidInputError
from ..model.geometry import shape_to_dict
from ..planning.recording import RecordedJob, load_jobs, recorded_config
from ..planning.types import PlanningError
from ..sections import CollisionLayer
from ..sim.config import load_cell_config
from ..stack import build_stack
from ..stats import summary
from ..world.occupancy import OccupancyMap


def config_of(directory: str, config: str | None = None, layer: CollisionLayer | None = None) -> ReplannerConfig:
    """`config` (a YAML file or a profile name), else the config recorded beside the jobs; `layer`: the search's
    collision layer instead of the config's."""
    if config is not None:
        cfg = load_cell_config(config).core()
    else:
        kept = recorded_config(directory)
        if kept is None:
            raise InvalidInputError(f"no config.json in {directory}: give the config the jobs were planned with (-c)")
        cfg = parse_config(kept, source=f"{directory}/config.json")
    if layer is not None:
        cfg = cfg.model_copy(update={"planning": cfg.planning.model_copy(update={"collision_layer": layer})})
    return cfg


def _world_key(job: RecordedJob) -> str:
    return json.dumps(
        [
            [(n, shape_to_dict(s), p.tolist()) for n, s, p in job.objects],
            [(n, shape_to_dict(s), link, T.tolist(), touch, sup) for n, s, link, T, touch, sup in job.attachments],
        ]
    )


def _set_world(world, job: RecordedJob) -> None:
    for name in world.names():  # as the planning process does: the map stays
        world.remove(name)
    for name, shape, pose in job.objects:
        world.add(name, shape, pose)
    for name, shape, link, T, touch, support in job.attachments:
        world.attach_new(name, shape, link, T, touch, support)


def run(cfg: ReplannerConfig, directory: str, *, seed: int = 0, repeat: int = 1, purposes=None) -> dict:
    """Plan the recorded jobs in order, the whole sequence `repeat` times; plan_ms of those of `purposes` (default
    all), as `plan()` times it (checks of start and goal, search, simplification: the part of a replan that is
    planning)."""
    jobs = load_jobs(directory)
    purposes = [p.strip() for p in purposes or () if p.strip()]  # the others are planned too, as they came, not told
    if purposes and not any(j.purpose in purposes for j in jobs):
        raise InvalidInputError(f"no recorded job of purpose {', '.join(purposes)} in {directory}")
    stack = build_stack(cfg, static=(), seed=seed, cameras=False)
    robot, planner, world = stack.robot, stack.planner, stack.world
    other = next((j for j in jobs if len(j.start) != robot.dof or j.robot not in (None, robot.name)), None)
    if other is not None:
        raise InvalidInputError(
            f"{other.path.name} was recorded for {other.robot or 'a robot'} with {len(other.start)} joints, the "
            f"config's robot is {robot.name} with {robot.dof}: give the config the jobs were recorded with (-c)"
        )
    rows, key = [], None
    # the whole sequence `repeat` times, not each job again at once (warm from itself); the first job once before,
    # untimed: what the service had compiled and built before its first job
    for n, job in enumerate([jobs[0], *(j for _ in range(repeat) for j in jobs)]):
        if _world_key(job) != key:  # the service set its world up again for this job
            _set_world(world, job)
            key = _world_key(job)
        planner.paddings.get(job.padding)  # a padding's geometry is built before its plan's deadline starts
        cell = cfg.collision.broadphase_cell  # each job brings a new map, built before its plan
        world.set_occupancy(
            OccupancyMap(job.keys, job.resolution, broadphase_cell=cell, trusted=True) if len(job.keys) else None
        )
        try:
            res = planner.plan(
                job.start,
                job.q_goal,
                planner=job.planner,
                deadline=job.deadline,
                padding=job.padding,
                heading=job.heading,
            )
            row = {"ok": True, "plan_ms": res.total_time * 1e3, "attempts": res.attempts}
        except PlanningError as err:
            row = {"ok": False, "reason": f"{type(err).__name__}: {err}"}
        planner.prepare()  # as the planning process does between jobs
        if n == 0 or (purposes and job.purpose not in purposes):
            continue
        recorded = job.outcome
        rows.append(
            {
                "job": job.path.name,
                "purpose": job.purpose,
                "map_voxels": len(job.keys),
                **row,
                "recorded_ok": recorded.get("ok"),
                "recorded_plan_ms": None if recorded.get("plan_s") is None else recorded["plan_s"] * 1e3,
            }
        )
    return summarize(rows, directory, robot.name, cfg.planning.collision_layer.value, repeat)


def summarize(rows: list[dict], directory: str, robot: str, layer: str, repeat: int) -> dict:
    def part(rs: list[dict]) -> dict:
        ok = [r for r in rs if r["ok"]]
        was = [r["recorded_plan_ms"] for r in rs if r["recorded_plan_ms"] is not None]
        return {
            "plans": len(rs),
            "success_rate": len(ok) / len(rs) if rs else None,
            "plan_ms": summary([r["plan_ms"] for r in ok]),
            "recorded_plan_ms": summary(was),
            "recorded_success_rate": float(np.mean([bool(r["recorded_ok"]) for r in rs])) if rs else None,
            "map_voxels": summary([r["map_voxels"] for r in rs]),
        }

    purposes = sorted({r["purpose"] for r in rows})
    return {
        "bench": "replay",
        "directory": str(directory),
        "robot": robot,
        "collision_layer": layer,
        "repeat": repeat,
        "overall": part(rows),
        "purposes": {p: part([r for r in rows if r["purpose"] == p]) for p in purposes},
        "rows": rows,
    }
