"""`replanner bench block`: the KineoWorks reactive-planning paper's experiment. An operator's forearm is set across
the transfer path between the bins before the arm arrives and held still, or a box is set down on the path and left
there; the arm is sent from above one bin to above the other. Per policy: did it reach the goal, how long it took
against the unblocked transfer, protective stops, the least separation from the obstacle against the S_p in force
then (pybullet's distance, every simulated step), and how far it went round (its path against the unblocked one).

Everything runs on one simulated clock (SteppedSim): the same figures on any machine, however busy.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from ..control import Goal, GoalStatus
from ..model.geometry import Box, Cylinder, Shape
from ..model.transforms import make_transform
from ..planning import PoseGoal
from ..sim.config import CellConfig
from ..sim.stepped import SteppedSim
from ..stats import summary
from ..world.scene import scene_from_config

DOWN = (1.0, 0.0, 0.0, 0.0)  # the tool pointing down (x, y, z, w)
FOREARM = (0.05, 0.45)  # [m] radius and length of a forearm
POLICIES = {"replan": "replan", "stop-and-wait": "stop_and_wait"}


def _above_bins(cfg: CellConfig) -> tuple[np.ndarray, np.ndarray]:
    """Where the pick-and-place client hovers over each bin's part: the transfer's two ends (tool positions)."""
    task, objects = cfg.sim.task, {o.name: o for o in cfg.scene}
    ends = []
    for name in task.bins:
        o = objects[name]
        top = np.asarray(o.position, float) + [0.0, 0.0, o.size[2] / 2 + task.part_size[2]]
        ends.append(top + [0.0, 0.0, task.approach_height])
    return ends[0], ends[1]


def _forearm(rng: np.random.Generator, path: np.ndarray) -> tuple[Shape, np.ndarray]:
    """A forearm from a shoulder beyond the table's far edge, its hand on the middle half of the tool's path."""
    hand = path[int(rng.uniform(0.3, 0.7) * (len(path) - 1))] + rng.uniform([-0.05, -0.05, -0.03], [0.05, 0.05, 0.03])
    shoulder = np.array([0.95, rng.uniform(-0.2, 0.2), rng.uniform(0.3, 0.5)])
    axis = hand - shoulder
    axis /= np.linalg.norm(axis)
    centre = hand - axis * (FOREARM[1] / 2 - FOREARM[0])  # the hand's end of the forearm at the hand
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, axis), float(z @ axis)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R = np.eye(3) + K + K @ K / (1.0 + c)  # z onto the forearm's axis
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centre
    return Cylinder(radius=FOREARM[0], length=FOREARM[1]), T


def _box(rng: np.random.Generator, path: np.ndarray) -> tuple[Shape, np.ndarray]:
    """A box standing on the table under the middle half of the tool's path, taller than the path is high."""
    at = path[int(rng.uniform(0.3, 0.7) * (len(path) - 1))]
    size = (rng.uniform(0.08, 0.15), rng.uniform(0.08, 0.15), float(at[2]) + rng.uniform(0.05, 0.1))
    return Box(size=size), make_transform((float(at[0]), float(at[1]), size[2] / 2))


def _separation(sim: SteppedSim, body: int, cutoff: float = 2.0) -> float:
    """pybullet's least distance [m] between the arm (where the sim holds it now) and the obstacle."""
    sim.scene.set_q(sim.state().position)
    pts = pb.getClosestPoints(sim.scene.body, body, cutoff, physicsClientId=sim.scene.client)
    return min((p[8] for p in pts), default=cutoff)


def run(
    cfg: CellConfig,
    *,
    seed: int = 0,
    poses: int = 20,
    boxes: int = 5,
    hold: float = 10.0,
    policies=("replan", "stop-and-wait"),
    camera_rate: float = 30.0,
    plan_delay: float = 0.05,
    progress=None,
) -> dict:
    """`poses` seeded forearms held for `hold` [s], then taken away, and `boxes` boxes left on the path, for each
    policy; planning takes `plan_delay` [s] of simulated time."""
    rng = np.random.default_rng(seed)
    static = scene_from_config(cfg)
    start_tool, goal_tool = _above_bins(cfg)
    base = SteppedSim(cfg, static, seed=seed, camera_rate=camera_rate, plan_delay=plan_delay)
    try:
        ik = base.planner
        home = base.robot.home
        tip = base.robot.tip_link
        qa = ik.resolve_goal(home, PoseGoal(tip, tuple(start_tool), DOWN))
        qb = ik.resolve_goal(qa, PoseGoal(tip, tuple(goal_tool), DOWN))
        clear = base.gen.time(ik.plan(qa, qb, deadline=5.0).path, cfg.sim.task.velocity_scale)
        Q = clear.evaluate(np.linspace(0.0, clear.duration, 200), 0)[0]
        path = np.array([base.robot.link_pose(q, tip)[:3, 3] for q in Q])
        unblocked = {"duration_s": clear.duration, "length_rad": clear.curve.length}
    finally:
        base.close()
    cases = [("forearm", *_forearm(rng, path)) for _ in range(poses)] + [
        ("box", *_box(rng, path)) for _ in range(boxes)
    ]
    out = {"bench": "block", "seed": seed, "hold_s": hold, "camera_rate_hz": camera_rate, "plan_delay_s": plan_delay}
    out["policies"] = list(policies)
    out["unblocked"] = unblocked
    done, total = 0, len(cases) * len(policies)
    for policy in policies:
        rows = []
        for k, (kind, shape, pose) in enumerate(cases):
            rows.append(
                _case(cfg, policy, kind, shape, pose, qa, qb, unblocked, hold, seed + k, camera_rate, plan_delay)
            )
            done += 1
            if progress:
                progress(done, total)
        out[policy] = {"cases": rows, **_totals(rows, unblocked)}
    return out


def _case(cfg, policy, kind, shape, pose, qa, qb, unblocked, hold, seed, camera_rate, plan_delay) -> dict:
    pcfg = cfg.override({"controller": {"reaction": POLICIES[policy]}})
    sim = SteppedSim(pcfg, scene_from_config(pcfg), seed=seed, camera_rate=camera_rate, plan_delay=plan_delay)
    try:
        ctl = sim.controller
        h = ctl.submit(Goal.joints("to-start", qa))
        sim.run_until(lambda: h.result is not None, 30.0, "the arm at the start")
        if h.result.status is not GoalStatus.SUCCEEDED:
            raise RuntimeError(f"the arm did not reach the start: {h.result.reason}")
        sim.add_obstacle("obstacle", shape, pose)
        body = sim.scene.objects["obstacle"]
        sim.run_for(0.3)  # in the map before the arm sets off
        n_trans, t0 = len(ctl.transitions), sim.t
        h = ctl.submit(Goal.joints("across", qb, velocity_scale=cfg.sim.task.velocity_scale))
        ssm = ctl.monitor.speed_checks[0] if ctl.monitor.speed_checks else None
        worst, at_worst, least = math.inf, None, math.inf
        travelled, last_q = 0.0, sim.state().position
        limit = unblocked["duration_s"] + hold + 20.0
        while h.result is None and sim.t - t0 < limit:
            if kind == "forearm" and "obstacle" in sim.scene.objects and sim.t - t0 >= hold:
                sim.remove_obstacle("obstacle")
            sim.step()
            q = sim.state().position
            travelled += float(np.linalg.norm(q - last_q))
            last_q = q
            if "obstacle" not in sim.scene.objects:
                continue
            S = _separation(sim, body)
            least = min(least, S)
            terms = ssm.last if ssm is not None else None
            moving = float(np.abs(sim.state().velocity).max()) > 1e-6
            if moving and terms is not None and S - terms.S_p < worst:  # the S_p the monitor holds the arm to now
                worst, at_worst = S - terms.S_p, (round(S, 4), round(float(terms.S_p), 4))
        reached = h.result is not None and h.result.status is GoalStatus.SUCCEEDED
        took = sim.t - t0
        stops = sum(1 for r in ctl.transitions[n_trans:] if r.dest == "HOLDING")
        return {
            "kind": kind,
            "reached": reached,
            "time_s": round(took, 3),
            "extra_s": round(took - unblocked["duration_s"], 3),
            "protective_stops": stops,
            "least_separation_m": round(least, 4),
            "separation_minus_sp_m": None if at_worst is None else round(float(worst), 4),
            "separation_and_sp_then_m": None if at_worst is None else [float(x) for x in at_worst],
            "path_ratio": round(travelled / unblocked["length_rad"], 3),
            "went_round": travelled > 1.2 * unblocked["length_rad"],
            "collided": least <= 0.0,
        }
    finally:
        sim.close()


def _totals(rows: list[dict], unblocked: dict) -> dict:
    def share(kind: str, within: float | None) -> float | None:
        sel = [r for r in rows if r["kind"] == kind]
        if not sel:
            return None
        ok = [r for r in sel if r["reached"] and (within is None or r["extra_s"] <= within)]
        return round(len(ok) / len(sel), 3)

    margins = [r["separation_minus_sp_m"] for r in rows if r["separation_minus_sp_m"] is not None]
    return {
        "forearm_reached_within_3s": share("forearm", 3.0),
        "box_reached_within_3s": share("box", 3.0),
        "forearm_reached": share("forearm", None),
        "box_reached": share("box", None),
        "collisions": sum(r["collided"] for r in rows),
        "separation_below_sp": sum(1 for m in margins if m < 0.0),
        "least_separation_minus_sp_m": min(margins) if margins else None,
        "extra_s": summary([r["extra_s"] for r in rows if r["reached"]]),
        "protective_stops": sum(r["protective_stops"] for r in rows),
        "path_ratio": summary([r["path_ratio"] for r in rows if r["reached"]]),
    }
