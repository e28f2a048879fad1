"""Planning jobs kept on disk (planning.record_jobs) and planned again by `bench replay`: what is read back is what
the worker planned in (objects, attachments, the map), the replay plans in that world, and what cannot be read
says which file and why."""

from __future__ import annotations

import json
import queue
import subprocess
import sys

import numpy as np
import pytest

from replanner.bench import replay
from replanner.bench.scenes import add_table
from replanner.config import parse_config
from replanner.errors import InvalidInputError
from replanner.model.geometry import Box, Mesh, Sphere, shape_from_dict, shape_to_dict
from replanner.model.transforms import make_transform
from replanner.planning import JobPurpose, PlanAnswer, PlanJob, ThreadWorker
from replanner.planning.recording import JobRecorder, load_jobs, recorded_config
from replanner.stack import build_stack
from replanner.world.occupancy import OccupancyMap

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
WAIT = 60.0  # [s] a generous bound for an answer that must come; never a measure of speed


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, panda_cfg, panda):
    """Three jobs planned by a thread worker and recorded: a wall in the way, then only the map in the way (with a
    part in the hand), then a goal inside a post, planned from a moving arm."""
    d = tmp_path_factory.mktemp("jobs")
    stack = build_stack(panda_cfg, static=(), seed=3, cameras=False)
    world = stack.world
    add_table(world)
    answers: queue.Queue = queue.Queue()
    worker = ThreadWorker(stack.planner, stack.generator)
    worker.recorder = JobRecorder(d, panda_cfg.core().model_dump(mode="json"))
    worker.start(answers.put)
    mid = panda.link_pose(A + 0.5 * (B - A), "panda_hand")[:3, 3]
    inputs = []

    def plan(n, goal, base=None):
        if base is None:
            job = PlanJob(n, JobPurpose.REPLAN, A.copy(), goal, 2.0)
        else:  # taking over 0.3 s into a motion started at 10 s
            job = PlanJob(n, JobPurpose.REPLAN, base.state_at(0.3)[0], goal, 2.0, land=10.3, base=(10.0, base))
        snap = world.snapshot()
        worker.submit(job, snap)
        inputs.append((job, snap))
        return answers.get(timeout=WAIT)

    world.add("wall", Box(size=(0.3, 0.05, 0.6)), make_transform((0.5, 0.0, 0.3)))
    first = plan(1, B)
    world.remove("wall")
    world.attach_new("part", Sphere(radius=0.03), "panda_hand", make_transform((0.0, 0.0, 0.1)), ["panda_leftfinger"])
    world.set_occupancy(OccupancyMap.from_points(mid + np.random.default_rng(0).uniform(-0.05, 0.05, (3000, 3)), 0.01))
    second = plan(2, B)
    world.set_occupancy(None)
    world.add("post", Box(size=(0.3, 0.3, 0.3)), make_transform(panda.link_pose(B, "panda_hand")[:3, 3]))
    third = plan(3, B, base=stack.generator.time(np.array([A, B])))  # a replan spliced onto a motion
    worker.recorder.flush()
    worker.close()
    assert first.error is None and not first.result.direct and second.error is None and not second.result.direct
    assert third.error is not None
    return d, inputs


def test_a_recorded_job_is_the_job_and_the_world_it_was_planned_in(recorded):
    d, inputs = recorded
    jobs = load_jobs(d)
    assert [j.path.name for j in jobs] == ["job-000001.npz", "job-000002.npz", "job-000003.npz"]
    for rec, (job, snap) in zip(jobs, inputs):
        assert rec.purpose == "replan" and rec.deadline == job.deadline and rec.padding is None
        np.testing.assert_array_equal(rec.start, job.start)
        np.testing.assert_array_equal(rec.q_goal, job.q_goal)
        assert [(n, s) for n, s, _ in rec.objects] == [(o.name, o.shape) for o in snap.objects.values()]
        for (_, _, pose), o in zip(rec.objects, snap.objects.values()):
            np.testing.assert_array_equal(pose, o.pose)
        assert [(n, s, link, set(t)) for n, s, link, _, t, _ in rec.attachments] == [
            (a.name, a.shape, a.link, set(a.touch_links)) for a in snap.attachments.values()
        ]
        occ = snap.occupancy
        assert len(rec.keys) == (0 if occ is None else len(occ))
        if occ is not None:
            np.testing.assert_array_equal(rec.keys, occ.keys)
            assert rec.resolution == occ.resolution
    assert jobs[0].heading is None and jobs[1].heading is None
    np.testing.assert_array_equal(jobs[2].heading, inputs[2][0].heading())
    assert np.linalg.norm(jobs[2].heading) > 0.1
    assert [j.outcome["ok"] for j in jobs] == [True, True, False]
    assert jobs[0].outcome["plan_s"] > 0 and "goal is in collision" in jobs[2].outcome["error"]


def test_the_replay_plans_in_the_recorded_world(recorded):
    d, _ = recorded
    cfg = parse_config(recorded_config(d))
    out = replay.run(cfg, str(d))
    rows = out["rows"]
    assert [r["job"] for r in rows] == ["job-000001.npz", "job-000002.npz", "job-000003.npz"]
    # the wall, then the map alone, block the straight line: without them the replay's plans would be direct
    assert rows[0]["ok"] and rows[0]["attempts"] >= 1
    assert rows[1]["ok"] and rows[1]["attempts"] >= 1 and rows[1]["map_voxels"] > 0
    assert not rows[2]["ok"] and "GoalInvalid" in rows[2]["reason"] and rows[2]["recorded_ok"] is False
    assert out["overall"]["plans"] == 3 and out["overall"]["plan_ms"]["n"] == 2
    assert out["purposes"]["replan"]["recorded_plan_ms"]["n"] == 2
    twice = replay.run(cfg, str(d), repeat=2, purposes=["replan"])
    assert twice["overall"]["plans"] == 6


def test_what_cannot_be_replayed_says_what_to_change(recorded, tmp_path, iiwa_cfg):
    d, _ = recorded
    with pytest.raises(InvalidInputError, match="no recorded jobs"):
        load_jobs(tmp_path)
    with pytest.raises(InvalidInputError, match="not a directory"):
        load_jobs(tmp_path / "missing")
    with pytest.raises(InvalidInputError, match="recorded for panda with 7 joints, the config's robot is iiwa.*-c"):
        replay.run(iiwa_cfg, str(d))
    with pytest.raises(InvalidInputError, match="no recorded job of purpose hold"):
        replay.run(parse_config(recorded_config(d)), str(d), purposes=["hold"])
    (tmp_path / "job-000001.npz").write_bytes(b"not a zip")
    with pytest.raises(InvalidInputError, match="job-000001.npz is not a recorded planning job"):
        load_jobs(tmp_path)


def test_a_recorder_numbers_on_after_what_is_there(recorded, tmp_path):
    d, inputs = recorded
    (tmp_path / "job-000007.npz").write_bytes((d / "job-000001.npz").read_bytes())
    rec = JobRecorder(tmp_path)
    job, snap = inputs[0]
    rec.record(job, snap, PlanAnswer(job, error=InvalidInputError("no plan")))
    rec.flush()
    # a restarted service never writes over the jobs of the run before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["job-000007.npz", "job-000008.npz"]
    assert load_jobs(tmp_path)[1].outcome["error"] == "InvalidInputError: no plan"


def test_shapes_read_back_as_they_were_written_and_bad_ones_are_named():
    cube = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    for shape in (Box(size=(0.1, 0.2, 0.3)), Sphere(radius=0.05), Mesh(cube, [[0, 1, 2], [0, 1, 3]], convex=True)):
        assert shape_from_dict(shape_to_dict(shape)) == shape
    with pytest.raises(InvalidInputError, match="box, cylinder, sphere or mesh"):
        shape_from_dict({"type": "cone"})
    with pytest.raises(InvalidInputError, match="shape box: missing or malformed"):
        shape_from_dict({"type": "box"})


def test_the_replay_command_prints_its_figures_and_names_a_bad_directory(recorded, tmp_path):
    d, _ = recorded
    run = [sys.executable, "-m", "replanner_services.cli", "bench", "replay"]
    out = subprocess.run([*run, str(d), "--json", "--layer", "fcl"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["collision_layer"] == "fcl" and result["overall"]["plans"] == 3
    assert result["purposes"]["replan"]["plan_ms"]["n"] == 2
    out = subprocess.run([*run, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and "no config.json in" in out.stderr and "(-c)" in out.stderr
