"""Plans made for the protective distance: a replan, or a plan from a held arm, keeps S_p from every voxel at the
speed its own timing gives each stretch (checked against pybullet's kinematics and a brute-force distance), and a
path that would come closer than an arm at rest may is never handed out."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from replanner.bench.scenes import table
from replanner.monitor.ssm import SeparationPlan, intrusion_distance, surface_points
from replanner.planning import PlanningError, SeparationInfeasible
from replanner.planning.worker import JobPurpose, PlanJob, plan_and_time
from replanner.stack import build_stack
from replanner.world.occupancy import OccupancyMap

from .oracle import PyBulletOracle

LEFT = np.array([-0.29, 0.52, -0.68, -1.83, 0.4, 2.21, -0.36])  # the hand above (0.4, -0.5, 0.3), pointing down
RIGHT = np.array([0.29, 0.52, 0.68, -1.83, -0.4, 2.21, 1.93])  # and above (0.4, 0.5, 0.3)
SPACING = 0.02  # [m] the oracle's surface samples
DT = 0.02  # [s] between the oracle's looks at a trajectory


def forearm(shoulder, hand, radius: float = 0.05, res: float = 0.01) -> OccupancyMap:
    """Voxels filling a capsule from shoulder to hand: an operator's forearm as the cameras see it."""
    a, b = np.asarray(shoulder, float), np.asarray(hand, float)
    g = np.mgrid[0.0:1.2:res, -0.7:0.7:res, 0.0:1.0:res].reshape(3, -1).T + res / 2
    t = np.clip(((g - a) @ (b - a)) / ((b - a) @ (b - a)), 0.0, 1.0)
    inside = np.linalg.norm(g - (a + t[:, None] * (b - a)), axis=1) <= radius
    return OccupancyMap.from_points(g[inside], res)


@pytest.fixture(scope="module")
def cell(panda_cfg, panda):
    stack = build_stack(panda_cfg, robot=panda, static=[table()], cameras=False, seed=0)
    oracle = PyBulletOracle(panda)
    yield stack, oracle
    oracle.close()
    stack.close()


def _surface(robot):
    """Each body's link, its frame on the link and its surface samples with how far they may miss a point."""
    out = []
    for b in robot.bodies:
        pts, gap = surface_points(b.shape, SPACING)
        out.append((b.link, b.T_link_body, pts, gap))
    return out


def _posed(oracle, surface, q) -> np.ndarray:
    oracle.set_q(q)
    parts = []
    for link, T_lb, pts, _ in surface:
        T = oracle.link_pose(link) @ T_lb
        parts.append(pts @ T[:3, :3].T + T[:3, 3])
    return np.vstack(parts)


def _protective_margin_holds(stack, oracle, traj, occ, plan: SeparationPlan) -> tuple[float, int]:
    """The least S - S_p [m] over the trajectory, every DT, and how many looks: S from pybullet's poses of the
    surface samples to the nearest voxel (less the samples' gap and the voxel's half diagonal), S_p with the stop
    the generator brakes along (its duration T_s, the farthest a sample travels S_s) and the fastest sample's speed
    as v_r, all from pybullet's kinematics."""
    ssm, gen = plan.cfg, stack.generator
    surface = _surface(stack.planner.robot)
    gap = max(s[3] for s in surface)
    tree = cKDTree(occ.centers)
    half = occ.resolution * np.sqrt(3) / 2
    C = intrusion_distance(occ.resolution) if ssm.intrusion_distance is None else ssm.intrusion_distance
    worst, looks = np.inf, 0
    for t in np.arange(0.0, traj.duration, DT):
        q = traj.state_at(t)[0]
        P = _posed(oracle, surface, q)
        S = float(tree.query(P)[0].min()) - half - gap
        if S > 1.5:  # beyond any S_p this arm can have
            continue
        looks += 1
        v_r = float(np.linalg.norm(_posed(oracle, surface, traj.state_at(t + 1e-3)[0]) - P, axis=1).max()) / 1e-3
        stop = gen.brake(traj, t)
        ts = np.linspace(0.0, stop.duration, 8)
        track = np.stack([_posed(oracle, surface, stop.state_at(s)[0]) for s in ts])
        S_s = float(np.linalg.norm(np.diff(track, axis=0), axis=2).sum(axis=0).max())
        S_p = (
            ssm.approach_speed * (plan.reaction_time + stop.duration)
            + v_r * plan.reaction_time
            + S_s
            + C
            + ssm.sensor_uncertainty
            + ssm.robot_uncertainty
            + v_r * plan.joint_state_age
        )
        worst = min(worst, S - S_p)
    return worst, looks


def test_a_plan_keeps_the_protective_distance_at_the_speed_it_is_timed_at(cell, panda_cfg):
    """Forearms across the way between two poses above the bins, seeded: every plan handed out keeps S_p (at the
    speed of each of its instants) from every voxel all along, as pybullet's kinematics and a brute-force distance
    see it; slower near the forearm than away from it."""
    stack, oracle = cell
    ssm = panda_cfg.controller.speed_separation
    plan = SeparationPlan(ssm, reaction_time=0.07, joint_state_age=0.008, start_after=0.05)
    rng = np.random.default_rng(11)
    planned, refused = 0, 0
    for k in range(6):
        shoulder = [0.95, rng.uniform(-0.2, 0.2), rng.uniform(0.3, 0.5)]
        hand = [rng.uniform(0.7, 0.8), rng.uniform(-0.1, 0.1), rng.uniform(0.2, 0.5)]
        occ = forearm(shoulder, hand)
        stack.world.set_occupancy(occ)
        start, goal = (LEFT, RIGHT) if k % 2 == 0 else (RIGHT, LEFT)
        job = PlanJob(k, JobPurpose.HOLD, start, goal, 1.0, separation=plan)
        try:
            traj, _ = plan_and_time(stack.planner, stack.generator, job)
        except PlanningError:
            refused += 1
            continue
        planned += 1
        worst, looks = _protective_margin_holds(stack, oracle, traj, occ, plan)
        assert looks > 10, looks
        assert worst >= 0.0, f"scene {k}: the arm comes {-worst * 1e3:.1f} mm inside S_p"
        # near the forearm the arm runs slower than its limits let it: the caps took hold
        assert traj.caps is not None and traj.caps.speed.min() < traj.caps.speed.max()
    stack.world.set_occupancy(None)
    assert planned >= 3, (planned, refused)


def test_a_path_that_would_come_too_close_is_never_handed_out(cell, panda_cfg):
    """A start closer to the forearm than an arm at rest may be, or a goal beside it: no trajectory for a replan or
    a plan from a held arm, a reason; the same plans without speed and separation go through (only the padding is
    kept), and so does a goal's first plan."""
    stack, _ = cell
    ssm = panda_cfg.controller.speed_separation
    plan = SeparationPlan(ssm, reaction_time=0.07, joint_state_age=0.008, start_after=0.05)
    hand = stack.planner.robot.link_pose(LEFT, "panda_hand")[:3, 3]
    near_start = forearm([0.95, -0.3, 0.45], hand + [0.2, 0.0, 0.0])  # 15 cm from the hand
    goal_hand = stack.planner.robot.link_pose(RIGHT, "panda_hand")[:3, 3]
    near_goal = forearm([0.95, 0.3, 0.45], goal_hand + [0.2, 0.0, 0.0])
    for occ, why in ((near_start, SeparationInfeasible), (near_goal, PlanningError)):
        stack.world.set_occupancy(occ)
        with pytest.raises(why) as err:
            plan_and_time(
                stack.planner, stack.generator, PlanJob(1, JobPurpose.HOLD, LEFT, RIGHT, 1.0, separation=plan)
            )
        assert "separation" in str(err.value) or "goal" in str(err.value), err.value
        traj, _ = plan_and_time(stack.planner, stack.generator, PlanJob(2, JobPurpose.HOLD, LEFT, RIGHT, 1.0))
        assert traj.caps is None
        # a goal's first plan keeps its padding instead: the monitor holds the arm until there is room
        goal = PlanJob(3, JobPurpose.GOAL, LEFT, RIGHT, 1.0, separation=plan)
        assert plan_and_time(stack.planner, stack.generator, goal)[0].caps is None
    stack.world.set_occupancy(None)
