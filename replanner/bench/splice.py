"""`replanner bench splice`: a new path spliced onto a motion at full speed, from seeded mid-motion states."""

from __future__ import annotations

import time

import numpy as np

from ..config import ReplannerConfig
from ..errors import TrajectoryError
from ..model.robot import RobotModel
from ..planning import PlanningError
from ..stack import build_stack
from ..stats import summary
from ..trajectory import TimingReport
from .scenes import table


def _states(robot, checker, rng, n: int) -> list[np.ndarray]:
    out = []
    while len(out) < n:
        q = robot.random_q(rng)
        if robot.link_pose(q, robot.tip_link)[2, 3] > 0.1 and checker.is_valid(q):
            out.append(q)
    return out


def run(cfg: ReplannerConfig, *, seed: int = 0, n: int = 100, progress=None) -> dict:
    """Each case: a timed motion between two seeded valid states; at a seeded time in its middle third, a path
    planned from where the arm is to a new seeded goal (told the arm's motion there) is spliced on. Refusals (a
    new path that turns back) are timed too: they are on the same hot path."""
    rng = np.random.default_rng(seed)
    robot = RobotModel.from_config(cfg.robot)
    stack = build_stack(cfg, robot=robot, static=[table()], seed=seed, cameras=False)
    checker, planner, gen = stack.checker, stack.planner, stack.generator
    warm = gen.time(np.array([robot.home, robot.home + 0.3]))  # first calls build lazily made geometry
    q_warm = warm.state_at(0.2)[0]
    checker.path_valid(np.array([robot.home, q_warm]))  # the collision scene is built on its first check
    try:
        gen.splice(warm, 0.2, np.array([q_warm, q_warm + 0.2]))
    except TrajectoryError:
        pass
    ms, ok_ms, refused_ms, candidates, speeds = [], [], [], [], []
    refusals: dict[str, int] = {}
    while len(ms) < n:
        a, b, c = _states(robot, checker, rng, 3)
        try:
            motion = gen.time(planner.plan(a, b, deadline=5.0).path)
            t0 = float(rng.uniform(motion.duration / 3, 2 * motion.duration / 3))
            q0, qd0, _ = motion.state_at(t0)
            new = planner.plan(q0, c, deadline=5.0, heading=qd0).path  # told the motion, as the service plans
        except (PlanningError, TrajectoryError):
            continue
        report = TimingReport()
        t_start = time.perf_counter()
        try:
            gen.splice(motion, t0, new, report=report)
            spliced = True
        except TrajectoryError as err:
            spliced = False
            why = str(err).split(": ", 1)[-1].split(";")[0]
            refusals[why] = refusals.get(why, 0) + 1
        dt = (time.perf_counter() - t_start) * 1e3
        ms.append(dt)
        (ok_ms if spliced else refused_ms).append(dt)
        candidates.append(report.splice_candidates)
        speeds.append(float(np.linalg.norm(qd0)))
        if progress:
            progress(len(ms), n)
    return {
        "bench": "splice",
        "robot": robot.name,
        "seed": seed,
        "cases": "table scene; motion between seeded valid states; splice at a seeded time in its middle third "
        "onto a path planned to a new seeded goal",
        "splice_ms": summary(ms),
        "spliced_ms": summary(ok_ms),
        "refused_ms": summary(refused_ms),
        "spliced": len(ok_ms),
        "refused": refusals,
        "candidates_tried": summary(candidates),
        "joint_speed_at_splice_rad_s": summary(speeds),
        "bars": {"splice_ms_p95": 10.0},
    }
