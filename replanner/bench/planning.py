"""`replanner bench planning`: four seeded scene families, plan + simplify + time, verified at 1 kHz."""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np

from ..collision.exact import CollisionChecker
from ..collision.paddings import padded_checker
from ..config import ReplannerConfig
from ..errors import InvalidInputError, ReplannerError
from ..model.geometry import Box, Cylinder, Shape
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..planning.ik import IKError, solve_ik
from ..planning.planner import FINAL_CHECKS_SHARE
from ..planning.types import PlanningError
from ..stack import build_stack
from ..stats import summary
from ..trajectory import Trajectory, distance_to_polyline
from ..world.occupancy import OccupancyMap
from ..world.scene import World
from .families import GRASP_PADDING, STANDARD, standard_scene
from .scenes import PERSON, TABLE_SIZE, person_map

OURS = ("table", "shelf", "bin", "cage")
FAMILIES = OURS + STANDARD
DOWN = (1.0, 0.0, 0.0, 0.0)  # tool z pointing down
FORWARD = (0.0, 0.7071068, 0.0, 0.7071068)  # tool z pointing along +x


def pick_families(spec: str) -> tuple[str, ...]:
    """'all', 'ours', 'standard' or comma-separated family names; raises InvalidInputError naming the known ones."""
    named = {"all": FAMILIES, "ours": OURS, "standard": STANDARD}
    if spec in named:
        return named[spec]
    out = tuple(f.strip() for f in spec.split(",") if f.strip())
    unknown = [f for f in out if f not in FAMILIES]
    if unknown or not out:
        raise InvalidInputError(
            f"unknown families {unknown or [spec]}: choose from {', '.join(FAMILIES)}, or all, ours, standard"
        )
    return out


@dataclass
class Problem:
    family: str
    index: int
    objects: list[tuple[str, Shape, np.ndarray]]
    start: np.ndarray
    goal: np.ndarray
    padding: float | None = None  # [m] this problem's padding (None: the config's)
    target: str | None = None  # the object the goal grasps


def _yaw(q_xyzw, yaw: float):
    """Compose a rotation about the base z axis (yaw [rad]) before the tool orientation."""
    from ..model.transforms import matrix_to_quat, quat_to_matrix

    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return matrix_to_quat(Rz @ quat_to_matrix(q_xyzw))


def _table():
    return [("table", Box(size=TABLE_SIZE), make_transform((0.3, 0.0, -TABLE_SIZE[2] / 2)))]


def _family_objects(family: str, rng: np.random.Generator):
    """Objects of one scene of the family and the goal regions (centre, tool orientation, yaw spread)."""
    objs = _table()
    if family == "table":
        for k in range(int(rng.integers(3, 6))):
            while True:
                xy = rng.uniform([0.25, -0.6], [0.8, 0.6])
                if np.linalg.norm(xy) > 0.3:
                    break
            h = rng.uniform(0.1, 0.4)
            if rng.random() < 0.5:
                shape = Box(size=(rng.uniform(0.06, 0.2), rng.uniform(0.06, 0.2), h))
            else:
                shape = Cylinder(radius=rng.uniform(0.03, 0.08), length=h)
            objs.append((f"obj{k}", shape, make_transform((xy[0], xy[1], h / 2), (0, 0, np.sin(rng.uniform(0, 1)), 1))))
        return objs, None
    if family == "shelf":
        x0 = rng.uniform(0.55, 0.65)
        depth, half_w, t = 0.3, 0.48, 0.02
        cx = x0 + depth / 2
        objs += [
            ("shelf_back", Box(size=(t, 2 * half_w, 0.74)), make_transform((x0 + depth, 0, 0.37))),
            ("shelf_left", Box(size=(depth, t, 0.74)), make_transform((cx, -half_w, 0.37))),
            ("shelf_right", Box(size=(depth, t, 0.74)), make_transform((cx, half_w, 0.37))),
            ("shelf_mid", Box(size=(depth, 2 * half_w, t)), make_transform((cx, 0, 0.36))),
            ("shelf_top", Box(size=(depth, 2 * half_w, t)), make_transform((cx, 0, 0.73))),
            ("shelf_div1", Box(size=(depth, t, 0.72)), make_transform((cx, -0.16, 0.37))),
            ("shelf_div2", Box(size=(depth, t, 0.72)), make_transform((cx, 0.16, 0.37))),
        ]
        goals = [(np.array([x0 + 0.1, y, z]), FORWARD, 0.3) for y in (-0.32, 0.0, 0.32) for z in (0.18, 0.54)]
        return objs, goals
    if family == "bin":
        y = rng.choice([-0.35, 0.35]) + rng.uniform(-0.05, 0.05)
        c = np.array([rng.uniform(0.45, 0.6), y])
        w, d, h, t = 0.32, 0.36, 0.22, 0.015
        objs += [
            ("bin_floor", Box(size=(w, d, t)), make_transform((c[0], c[1], t / 2))),
            ("bin_x0", Box(size=(t, d, h)), make_transform((c[0] - w / 2, c[1], h / 2))),
            ("bin_x1", Box(size=(t, d, h)), make_transform((c[0] + w / 2, c[1], h / 2))),
            ("bin_y0", Box(size=(w, t, h)), make_transform((c[0], c[1] - d / 2, h / 2))),
            ("bin_y1", Box(size=(w, t, h)), make_transform((c[0], c[1] + d / 2, h / 2))),
        ]
        return objs, [(np.array([c[0], c[1], 0.11]), DOWN, np.pi)]
    if family == "cage":
        c = np.array([rng.uniform(0.5, 0.6), rng.uniform(-0.1, 0.1)])
        hw, hd, h, r = 0.32, 0.3, 0.55, 0.012
        corners = [(c[0] + sx * hd, c[1] + sy * hw) for sx in (-1, 1) for sy in (-1, 1)]
        for k, (x, y) in enumerate(corners):
            objs.append((f"post{k}", Cylinder(radius=r, length=h), make_transform((x, y, h / 2))))
        for k, z in enumerate((0.28, h)):
            objs += [
                (f"rail{k}a", Box(size=(2 * hd, 2 * r, 2 * r)), make_transform((c[0], c[1] - hw, z))),
                (f"rail{k}b", Box(size=(2 * hd, 2 * r, 2 * r)), make_transform((c[0], c[1] + hw, z))),
                (f"rail{k}c", Box(size=(2 * r, 2 * hw, 2 * r)), make_transform((c[0] + hd, c[1], z))),
            ]
        objs.append(("top_bar", Box(size=(2 * r, 2 * hw, 2 * r)), make_transform((c[0], c[1], h))))
        return objs, [
            (np.array([c[0] + 0.05 * s, c[1] + 0.12 * t, 0.15]), DOWN, np.pi) for s in (-1, 1) for t in (-1, 1)
        ]
    raise ValueError(f"unknown family {family!r}; families: {', '.join(FAMILIES)}")


def _random_valid(robot, checker, rng, tip_link: str, tries: int = 2000):
    for _ in range(tries):
        q = robot.random_q(rng)
        tip = robot.link_pose(q, tip_link)[:3, 3]
        if tip[2] > 0.05 and checker.is_valid(q):
            return q
    raise RuntimeError("no valid random configuration")


def _ik_goal(robot, checker, rng, region, start, tip_link: str):
    center, quat, spread = region
    for _ in range(30):
        T = make_transform(center + rng.uniform(-0.03, 0.03, 3), _yaw(quat, rng.uniform(-spread, spread) / 2))
        try:
            return solve_ik(robot, tip_link, T, checker=checker, seed=start, restarts=24, rng=rng).q
        except IKError:
            continue
    return None


def make_problems(robot: RobotModel, cfg: ReplannerConfig, family: str, n: int, seed: int) -> list[Problem]:
    """`n` problems of a family; each has its own seeded scene, and a valid start and goal.

    Raises InvalidInputError when 200 scenes per problem (50 if none gives one) give fewer:
    a robot whose reach or tip link fits the family's scenes badly."""
    rng = np.random.default_rng([seed, FAMILIES.index(family)])
    tip = cfg.robot.tip_link
    budget = 200 * n
    problems, scenes = [], 0
    while len(problems) < n and scenes < budget and (problems or scenes < 50):  # none in 50: the rest fail as slowly
        scenes += 1
        if family in STANDARD:
            problem = _standard_problem(robot, cfg, family, len(problems), rng)
            if problem is not None:
                problems.append(problem)
            continue
        objects, regions = _family_objects(family, rng)
        checker = build_stack(cfg, robot=robot, static=objects, cameras=False).checker
        if regions is None:  # the table: random pairs whose straight line is blocked (a real planning problem)
            start, goal = _random_valid(robot, checker, rng, tip), _random_valid(robot, checker, rng, tip)
            if checker.path_valid(np.array([start, goal])):
                continue
        else:
            if family == "shelf":  # from one compartment to another
                a, b = rng.choice(len(regions), 2, replace=False)
                start = _ik_goal(robot, checker, rng, regions[a], robot.home, tip)
                goal = _ik_goal(robot, checker, rng, regions[b], robot.home, tip)
            else:
                start = _random_valid(robot, checker, rng, tip)
                goal = _ik_goal(robot, checker, rng, regions[int(rng.integers(len(regions)))], start, tip)
            if start is None or goal is None:
                continue
        problems.append(Problem(family, len(problems), objects, start, goal))
    if len(problems) == n:
        return problems
    raise InvalidInputError(
        f"{robot.name}: only {len(problems)} of {n} {family} problems in {scenes} scenes: the family's scenes "
        f"(sized for the Panda) rarely give this robot and its tip link {tip!r} a valid start and goal; leave "
        f"{family} out (--families)"
    )


def _standard_problem(robot, cfg, family: str, index: int, rng) -> Problem | None:
    """A scene of a standard family; the start near the robot's home, the goal a grasp of one of its cans."""
    objects, targets = standard_scene(family, rng)
    objects = _table() + objects
    checker = padded_checker(build_stack(cfg, robot=robot, static=objects, cameras=False).checker, GRASP_PADDING)
    for _ in range(20):
        start = np.clip(robot.home + rng.normal(0.0, 0.15, robot.dof), robot.limits.lower, robot.limits.upper)
        if checker.is_valid(start):
            break
    else:
        return None
    if not targets:
        return None
    target, poses = targets[int(rng.integers(len(targets)))]
    for k in rng.permutation(len(poses)):
        try:
            goal = solve_ik(robot, cfg.robot.tip_link, poses[k], checker=checker, seed=start, restarts=24, rng=rng).q
        except IKError:
            continue
        return Problem(family, index, objects, start, goal, GRASP_PADDING, target[0])
    return None


def verify(traj: Trajectory, tube: float, sim=None, ignore=frozenset(), rate: float = 1000.0) -> dict:
    """Sampled at `rate` Hz: worst limit ratios by finite differences, tube deviation, pybullet penetrations."""
    dt = 1.0 / rate
    t = np.arange(0.0, traj.duration + dt, dt)
    q = traj.evaluate(t, order=0)[0]
    lim = traj.limits
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    out = {
        "velocity_ratio": float((np.abs(v) / lim.velocity).max(initial=0)),
        "acceleration_ratio": float((np.abs(a) / lim.acceleration).max(initial=0)),
        "jerk_ratio": float((np.abs(j) / lim.jerk).max(initial=0)),
        "tube_deviation": float(distance_to_polyline(q, traj.curve.polyline).max()),
        "samples": len(t),
    }
    if sim is not None:
        out["colliding_samples"] = int(sum(bool(sim.contacts(qq, ignore)) for qq in q))
    return out


def ignored_pairs(robot: RobotModel, allowed_contacts) -> set[frozenset[str]]:
    """Name pairs pybullet may report that the model allows: unchecked link pairs and allowed contacts."""
    checked = {frozenset((robot.bodies[a].link, robot.bodies[b].link)) for a, b in robot.self_collision_pairs}
    links = {b.link for b in robot.bodies}
    out = {frozenset(p) for p in itertools.combinations(links, 2)} - checked
    return out | {frozenset(p) for p in allowed_contacts}


def _stand_person(
    checker, p: Problem, rng: np.random.Generator, resolution: float, tries: int = 50
) -> OccupancyMap | None:
    """A person's map (scenes.person_map) 0.5-0.9 m from the base, clear of the problem's start and goal (its
    checker's map padding), seeded draws, a fixed number of them; None if none was clear."""
    for _ in range(tries):
        r, phi = rng.uniform(0.5 + PERSON[0], 0.9 + PERSON[0]), rng.uniform(-np.pi, np.pi)
        occ = person_map((r * np.cos(phi), r * np.sin(phi)), resolution)
        checker.world.set_occupancy(occ)
        if checker.is_valid(p.start, octree_only=True) and checker.is_valid(p.goal, octree_only=True):
            return occ
    checker.world.set_occupancy(None)
    return None


def run(
    cfg: ReplannerConfig,
    *,
    seed: int = 0,
    per_family: int = 25,
    deadline: float | None = None,
    verify_all: bool = True,
    families=FAMILIES,
    person: bool = False,
    progress=None,
) -> dict:
    """person: each problem has a person-sized column of voxels beside it (`_stand_person`), a fresh map for each
    plan, as each of the service's planning jobs brings one; its timed trajectory is checked against those voxels
    too (FCL, unpadded: `map_colliding_samples`)."""
    robot = RobotModel.from_config(cfg.robot)
    deadline = deadline or cfg.planning.deadline
    rows = []
    ignore = ignored_pairs(robot, cfg.collision.allowed_contacts)
    total = per_family * len(families)
    taken = 0
    for family in families:
        timed = []  # verified after the family's plans: pybullet between two plans left the planner's caches cold
        for p in make_problems(robot, cfg, family, per_family, seed):
            taken += 1
            if progress:
                progress(taken, total)
            stack = build_stack(cfg, robot=robot, static=p.objects, seed=seed, cameras=False)
            planner, gen = stack.planner, stack.generator
            row = {"family": family, "index": p.index}
            planner.paddings.get(p.padding)  # a padding's geometry is built before its plan's deadline starts
            occ = None
            if person:
                rng = np.random.default_rng([seed, FAMILIES.index(family), p.index])
                occ = _stand_person(planner.exact, p, rng, cfg.perception.resolution)  # clear for the planner
            if occ is not None:  # the job's map is new to the planner: nothing of it built yet
                stack.world.set_occupancy(OccupancyMap(occ.keys, occ.resolution, trusted=True))
                row["map_voxels"] = len(occ)
            t0 = time.perf_counter()
            try:
                res = planner.plan(p.start, p.goal, deadline=deadline, padding=p.padding)
            except PlanningError as err:
                row.update(success=False, reason=err.reason, plan_ms=(time.perf_counter() - t0) * 1e3)
                rows.append(row)
                continue
            row.update(
                success=True,
                plan_ms=res.total_time * 1e3,
                search_ms=res.search_time * 1e3,
                simplify_ms=res.simplify_time * 1e3,
                waypoints=len(res.path),
                direct=res.direct,
                attempts=res.attempts,
            )
            t1 = time.perf_counter()
            try:
                traj = gen.time(res.path)
            except ReplannerError as err:
                row.update(success=False, reason=f"timing: {err}")
                rows.append(row)
                continue
            row["timing_ms"] = (time.perf_counter() - t1) * 1e3
            row["duration_s"] = traj.duration
            row["naive_duration_s"] = gen.time_naive(res.path).duration
            rows.append(row)
            timed.append((row, traj, p, occ))
        for row, traj, p, occ in timed if verify_all else ():
            from ..sim.scene import PyBulletScene

            sim = PyBulletScene(robot, room=False, self_collision=True)
            for name, shape, pose in p.objects:
                sim.add(name, shape, pose)
            row.update(verify(traj, cfg.planning.tube_radius, sim, ignore))
            sim.close()
            if occ is not None:
                row["map_colliding_samples"] = _map_contacts(robot, occ, traj)
    return summarize(rows, robot.name, seed, deadline, cfg)


def _map_contacts(robot: RobotModel, occ: OccupancyMap, traj: Trajectory, rate: float = 1000.0) -> int:
    """Samples of `traj` at `rate` Hz whose unpadded robot touches a voxel of `occ` (FCL)."""
    world = World(robot)
    world.set_occupancy(occ)
    checker = CollisionChecker(robot, world, padding=0.0, map_padding=0.0)
    q = traj.evaluate(np.arange(0.0, traj.duration + 1.0 / rate, 1.0 / rate), order=0)[0]
    q = np.clip(q, robot.limits.lower, robot.limits.upper)
    return int((~checker.is_valid_batch(q, octree_only=True)).sum())  # the map alone: self contacts are not its


def summarize(rows: list[dict], robot: str, seed: int, deadline: float, cfg) -> dict:
    def stats(sel):
        ok = [r for r in sel if r["success"]]
        d = {
            "problems": len(sel),
            "success_rate": len(ok) / max(len(sel), 1),
            "plan_ms": summary([r["plan_ms"] for r in ok]),
            # where the plans' time went: the search, and the shortcutting with FCL's re-check of the path
            "search_ms": summary([r["search_ms"] for r in ok]),
            "simplify_ms": summary([r["simplify_ms"] for r in ok]),
            "timing_ms": summary([r["timing_ms"] for r in ok]),
            "duration_s": summary([r["duration_s"] for r in ok]),
            "naive_duration_s": summary([r["naive_duration_s"] for r in ok]),
            "direct_fraction": float(np.mean([r["direct"] for r in ok])) if ok else 0.0,
        }
        if ok:
            d["naive_over_timed_total"] = sum(r["naive_duration_s"] for r in ok) / sum(r["duration_s"] for r in ok)
            d["faster_than_naive"] = sum(r["duration_s"] < r["naive_duration_s"] - 1e-9 for r in ok)
            d["slower_than_naive"] = sum(r["duration_s"] > r["naive_duration_s"] + 1e-9 for r in ok)
        if ok and "velocity_ratio" in ok[0]:
            d["worst"] = {
                k: max(r[k] for r in ok)
                for k in ("velocity_ratio", "acceleration_ratio", "jerk_ratio", "tube_deviation")
            }
            d["colliding_samples"] = sum(r["colliding_samples"] for r in ok)
            d["samples"] = sum(r["samples"] for r in ok)
        with_map = [r for r in sel if "map_voxels" in r]
        if with_map:
            d["with_person"] = len(with_map)
            d["map_voxels"] = summary([r["map_voxels"] for r in with_map])
            d["map_colliding_samples"] = sum(r.get("map_colliding_samples", 0) for r in ok)
        failures = [r.get("reason") for r in sel if not r["success"]]
        if failures:
            d["failures"] = failures
        if sel:  # the problem to replay when a deadline is overrun
            slow = max(sel, key=lambda r: r["plan_ms"])
            d["slowest"] = {
                "family": slow["family"],
                "index": slow["index"],
                "plan_ms": slow["plan_ms"],
                "success": slow["success"],
            }
        return d

    families = sorted({r["family"] for r in rows}, key=FAMILIES.index)
    return {
        "bench": "planning",
        "robot": robot,
        "seed": seed,
        "deadline_s": deadline,
        "planner": cfg.planning.planner,
        "collision_layer": cfg.planning.collision_layer,
        "tube_radius_rad": cfg.planning.tube_radius,
        "families": {f: stats([r for r in rows if r["family"] == f]) for f in families},
        "overall": stats(rows),
        # plan() against its deadline, failures and simplification included: the slowest, over (+) or within (-) [ms]
        "deadline_overrun_ms_max": max([r["plan_ms"] - deadline * 1e3 for r in rows], default=0.0),
        # plan() promises to return (or fail) by its deadline plus FINAL_CHECKS_SHARE of it: the calls that did not
        "deadline_margin_ms": deadline * FINAL_CHECKS_SHARE * 1e3,
        "late_plans": [
            {"family": r["family"], "index": r["index"], "over_ms": r["plan_ms"] - deadline * 1e3}
            for r in rows
            if r["plan_ms"] > deadline * (1.0 + FINAL_CHECKS_SHARE) * 1e3
        ],
        # what the figures are held to: success overall and per family, plan + simplify median and p95, timing
        "bars": {
            "success_rate": 0.995,
            "family_success_rate": 0.99,
            "plan_ms_median": 5.0,
            "plan_ms_p95": 50.0,
            "timing_ms_median": 20.0,
        },
        "limit_tolerance": "finite differences at 1 kHz, ratio to the limit <= 1.001",
    }
