"""Planning in a child process: same answers, the world reaches it, errors keep their type, cancel works."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from replanner.bench.scenes import add_table
from replanner.planning.planner import GoalInvalid, PlanningCanceled, StartInvalid
from replanner.planning.process import PlanningProcess
from replanner.trajectory.generator import Trajectory, TrajectoryGenerator
from replanner.world.collision import CollisionChecker
from replanner.world.geometry import Box
from replanner.world.occupancy import OccupancyMap
from replanner.world.scene import World
from replanner.world.transforms import make_transform
from tests.helpers import ARM_FORWARD, ARM_UP, sleeve

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])


@pytest.fixture(scope="module")
def proc(panda_cfg):
    p = PlanningProcess(panda_cfg, seed=4)
    yield p
    p.close()


@pytest.fixture
def world(panda):
    w = World(panda)
    add_table(w)
    return w


def test_plans_and_times_in_the_child(proc, world, panda, panda_cfg):
    world.add("wall", Box(size=(0.3, 0.05, 0.6)), make_transform((0.5, 0.0, 0.3)))
    traj, res = proc.plan(world.snapshot(), A, B, deadline=2.0)
    assert isinstance(traj, Trajectory) and not res.direct  # the wall reached the child
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    q = traj.evaluate(np.linspace(0, traj.duration, 400), order=0)[0]
    assert checker.check_path(q).valid
    np.testing.assert_allclose(q[-1], B, atol=1e-6)


def test_the_occupancy_map_reaches_the_child(proc, world, panda):
    hand = panda.link_pose(A + 0.5 * (B - A), "panda_hand")[:3, 3]
    pts = hand + np.random.default_rng(0).uniform(-0.05, 0.05, (3000, 3))
    world.set_occupancy(OccupancyMap.from_points(pts, 0.01))
    traj, res = proc.plan(world.snapshot(), A, B, deadline=2.0)
    assert not res.direct
    world.set_occupancy(None)  # and its removal too
    traj, res = proc.plan(world.snapshot(), A, B, deadline=2.0)
    assert res.direct


def test_errors_keep_their_type(proc, world, panda):
    world.add("post", Box(size=(0.3, 0.3, 0.3)), make_transform(panda.link_pose(B, "panda_hand")[:3, 3]))
    with pytest.raises(GoalInvalid, match="goal is in collision"):
        proc.plan(world.snapshot(), A, B)
    with pytest.raises(StartInvalid, match="start is in collision"):
        proc.plan(world.snapshot(), B, A)


def test_cancel_stops_a_hopeless_search(proc, panda):
    w = World(panda)
    for name, shape, pose in sleeve(panda):
        w.add(name, shape, pose)
    threading.Timer(0.2, proc.cancel).start()
    t0 = time.perf_counter()
    with pytest.raises(PlanningCanceled):
        proc.plan(w.snapshot(), ARM_UP, ARM_FORWARD, deadline=5.0)
    assert time.perf_counter() - t0 < 1.0


def test_splice_in_the_child_continues_the_motion(proc, world, panda, panda_cfg):
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    gen = TrajectoryGenerator(panda, checker)
    old = gen.time(np.array([A, B]))
    t0 = old.duration / 2
    q0, qd0, qdd0 = old.state_at(t0)
    new, _ = proc.plan(world.snapshot(), q0, panda.home, base=(old, t0))
    s = new.state_at(0.0)
    for a, b in zip(s, (q0, qd0, qdd0)):
        np.testing.assert_allclose(a, b, atol=1e-6)
