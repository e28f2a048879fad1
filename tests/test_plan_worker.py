"""The plan worker, both backends: same answers, the world reaches the child, errors keep type and data, cancel
works, and an answer given up on is never taken for the next job's."""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest

from replanner.bench.scenes import add_table
from replanner.model.geometry import Box
from replanner.model.transforms import make_transform
from replanner.planning import (
    GoalInvalid,
    JobPurpose,
    PlanAnswer,
    PlanJob,
    PlanningCanceled,
    PlanningError,
    ProcessWorker,
    StartInvalid,
    ThreadWorker,
    UnknownPlanner,
)
from replanner.stack import build_stack
from replanner.trajectory import Trajectory, TrajectoryError
from replanner.world.occupancy import OccupancyMap
from tests.helpers import ARM_FORWARD, ARM_UP, box_surface, sleeve

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
WAIT = 60.0  # [s] a generous bound for an answer that must come; never a measure of speed


class Answers:
    """Collects a worker's answers; `next()` waits for one."""

    def __init__(self):
        self.q: queue.Queue[PlanAnswer] = queue.Queue()
        self.ids = iter(range(1, 10_000))

    def next(self) -> PlanAnswer:
        return self.q.get(timeout=WAIT)

    def job(self, start, goal, deadline=2.0, **kw) -> PlanJob:
        return PlanJob(
            next(self.ids), JobPurpose.GOAL, np.asarray(start, float), np.asarray(goal, float), deadline, **kw
        )


@pytest.fixture(scope="module")
def stack(panda_cfg):
    s = build_stack(panda_cfg, static=(), seed=4, cameras=False)
    add_table(s.world)
    return s


@pytest.fixture(scope="module", params=["process", "thread"])
def worker(request, panda_cfg, stack):
    answers = Answers()
    w = ProcessWorker(panda_cfg, seed=4) if request.param == "process" else ThreadWorker(stack.planner, stack.generator)
    w.start(answers.q.put)
    w.answers = answers
    yield w
    w.close()


@pytest.fixture
def world(stack):
    yield stack.world
    for name in stack.world.names():
        if name != "table":
            stack.world.remove(name)
    stack.world.set_occupancy(None)


def test_plans_and_times(worker, world, stack, panda_cfg):
    world.add("wall", Box(size=(0.3, 0.05, 0.6)), make_transform((0.5, 0.0, 0.3)))
    worker.submit(worker.answers.job(A, B), world.snapshot())
    answer = worker.answers.next()
    assert answer.error is None and isinstance(answer.trajectory, Trajectory)
    assert not answer.result.direct  # the wall reached the planner
    q = answer.trajectory.evaluate(np.linspace(0, answer.trajectory.duration, 400), order=0)[0]
    assert stack.checker.check_path(q).valid
    np.testing.assert_allclose(q[-1], B, atol=1e-6)


def test_the_occupancy_map_reaches_the_planner(worker, world, panda):
    hand = panda.link_pose(A + 0.5 * (B - A), "panda_hand")[:3, 3]
    pts = hand + np.random.default_rng(0).uniform(-0.05, 0.05, (3000, 3))
    world.set_occupancy(OccupancyMap.from_points(pts, 0.01))
    worker.submit(worker.answers.job(A, B), world.snapshot())
    assert not worker.answers.next().result.direct
    world.set_occupancy(None)  # and its removal too
    worker.submit(worker.answers.job(A, B), world.snapshot())
    assert worker.answers.next().result.direct


def test_errors_keep_their_type_and_data(worker, world, stack, panda):
    world.add("post", Box(size=(0.3, 0.3, 0.3)), make_transform(panda.link_pose(B, "panda_hand")[:3, 3]))
    expected = stack.checker.check(B)
    worker.submit(worker.answers.job(A, B), world.snapshot())
    err = worker.answers.next().error
    assert type(err) is GoalInvalid and "goal is in collision" in str(err)
    assert err.contact == expected and err.reason == "goal_invalid"
    worker.submit(worker.answers.job(B, A), world.snapshot())
    err = worker.answers.next().error
    assert type(err) is StartInvalid and err.contact == expected
    worker.submit(worker.answers.job(A, A + 0.2, planner="Teleport"), world.snapshot())
    err = worker.answers.next().error
    assert type(err) is UnknownPlanner and "RRTConnect" in str(err)


def test_cancel_stops_a_hopeless_search(worker, world, panda):
    for name, shape, pose in sleeve(panda):
        world.add(name, shape, pose)
    job = worker.answers.job(ARM_UP, ARM_FORWARD, deadline=600.0)  # only a cancel ends this within WAIT
    worker.submit(job, world.snapshot())
    while not worker.busy():  # a job canceled before it starts is dropped unanswered
        time.sleep(0.001)
    worker.cancel(job)
    assert isinstance(worker.answers.next().error, PlanningCanceled)


def test_splice_continues_the_motion(worker, world, stack):
    old = stack.generator.time(np.array([A, B]))
    t0 = old.duration / 2
    q0, qd0, qdd0 = old.state_at(t0)
    worker.submit(worker.answers.job(q0, stack.robot.home, land=10.0 + t0, base=(10.0, old)), world.snapshot())
    new = worker.answers.next().trajectory
    for a, b in zip(new.state_at(0.0), (q0, qd0, qdd0)):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_a_replan_that_would_start_against_the_motion_is_spliced_on(worker, world, stack, panda):
    """A box where the hand will be: the path around it starts against the arm's motion, and spliced on as planned
    it is refused (the arm would brake and plan again from rest). Told the motion, the plan's path first steps along
    it: the same path after that step, spliced on at speed, clear of the box."""
    old = stack.generator.time(np.array([A, B]))
    land = 0.6
    q0, qd0, qdd0 = old.state_at(land)
    hand = panda.link_pose(old.state_at(1.0)[0], "panda_hand")[:3, 3]
    world.set_occupancy(box_surface(hand, 0.14))
    plain = stack.planner.plan(q0, B, deadline=2.0).path
    with pytest.raises(TrajectoryError, match="starts against the motion"):
        stack.generator.splice(old, land, plain)
    worker.submit(worker.answers.job(q0, B, land=10.0 + land, base=(10.0, old)), world.snapshot())
    answer = worker.answers.next()
    assert answer.error is None, answer.error
    path, new = answer.result.path, answer.trajectory
    assert qd0 @ (path[1] - path[0]) > 0 and qd0 @ (plain[1] - plain[0]) < 0
    np.testing.assert_allclose(path[2:], plain[1:])
    for a, b in zip(new.state_at(0.0), (q0, qd0, qdd0)):
        np.testing.assert_allclose(a, b, atol=1e-6)
    q = new.evaluate(np.linspace(0, new.duration, 600), order=0)[0]
    assert stack.checker.check_path(q).valid


def test_a_late_answer_is_never_taken_for_the_next_job(panda_cfg, stack, panda):
    answers = Answers()
    # the parent gives up on each job 3.5 s before its deadline: a hopeless search is still running then, and on until
    # its deadline (4 s: the test waits it out)
    w = ProcessWorker(panda_cfg, seed=4, answer_margin=-3.5).start(answers.q.put)
    try:
        world = build_stack(panda_cfg, static=sleeve(panda), cameras=False).world
        hopeless = answers.job(ARM_UP, ARM_FORWARD, deadline=4.0)
        w.submit(hopeless, world.snapshot())
        first = answers.next()
        assert first.job is hopeless and type(first.error) is PlanningError and "did not answer" in str(first.error)
        goal = ARM_UP + np.r_[0.2, 0, 0, 0, 0, 0, 0]  # a free straight line, answered at once
        easy = answers.job(ARM_UP, goal, deadline=40.0)  # waited for 36.5 s: the hopeless search ends first
        w.submit(easy, world.snapshot())
        second = answers.next()  # the child first finishes the hopeless search: its answer must be dropped
        assert second.job is easy and second.error is None
        np.testing.assert_allclose(second.trajectory.end, goal, atol=1e-9)
    finally:
        w.close()


def test_a_cancel_that_overtakes_its_request_still_stops_its_job(panda_cfg, panda):
    """The child reads cancels on a thread of its own, so a cancel sent just after a request may be read first. The
    job must still stop (the child used to drop such a cancel and plan on until the job's deadline)."""
    import subprocess

    from replanner.planning.worker import PlanRequest, start_plan_process

    child, conn, cancels = start_plan_process()
    try:
        conn.send((panda_cfg.core().model_dump(mode="python"), 4))
        assert conn.poll(300.0) and conn.recv()[0] == "ready"
        job = Answers().job(ARM_UP, ARM_FORWARD, deadline=600.0)  # only a cancel ends this within WAIT
        cancels.send(job.id)
        time.sleep(0.5)  # lets the child read the cancel first (what a busy machine does); the verdict waits on none
        conn.send(PlanRequest(job.id, tuple(sleeve(panda)), (), (), job))
        assert conn.poll(WAIT), "the canceled job planned on"
        kind, job_id, err = conn.recv()
        assert (kind, job_id) == ("error", job.id) and isinstance(err, PlanningCanceled), (kind, err)
    finally:
        conn.send(None)
        try:
            child.wait(30.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
