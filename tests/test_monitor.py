"""The monitor on its own: the remaining path read from the measured state, each check's verdict, the incremental
map check (only what a new map added), remembered scene verdicts and the full look before a resume."""

from __future__ import annotations

import numpy as np
import pytest

from replanner.bench.scenes import table
from replanner.control import Timeline
from replanner.errors import ReplannerError
from replanner.model.geometry import Box
from replanner.model.transforms import make_transform
from replanner.monitor import MapPathCheck, Monitor, ScenePathCheck, Verdict, build_monitor
from replanner.monitor.checks import Check, MotionView
from replanner.stack import build_stack
from replanner.world.occupancy import OccupancyMap, voxel_keys
from tests.helpers import box_surface

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])


@pytest.fixture
def scene(panda_cfg, panda):
    stack = build_stack(panda_cfg, robot=panda, static=[table()], cameras=False)
    traj = stack.generator.time(np.array([A, B]), velocity_scale=0.5)
    timeline = Timeline(A)
    timeline.add(traj, 10.0)
    return stack, traj, timeline


def _blob(center, size=0.08, res=0.01) -> np.ndarray:
    g = np.arange(-size / 2, size / 2, res) + res / 2
    return voxel_keys(np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3) + center, res)


def _map(keys, serial=0, added=None) -> OccupancyMap:
    return OccupancyMap(keys, 0.01, serial=serial, added=added)


def test_the_view_starts_at_the_measured_state(scene):
    stack, traj, timeline = scene
    monitor = build_monitor(stack.checker, stack.generator, stack.cfg.controller)
    t = traj.duration / 2
    q = traj.state_at(t)[0] + 0.003  # measured a little off the curve
    view = monitor.view(timeline, 10.0 + t, q)
    np.testing.assert_array_equal(view.path[0], q)
    np.testing.assert_allclose(view.path[-1], B, atol=1e-9)
    assert 0.4 < view.progress < 0.6 and view.segment == (10.0, traj)
    assert monitor.view(timeline, 9.0, q) is None  # nothing runs yet


def test_a_splice_queued_behind_another_cuts_it_short_in_the_view(scene):
    """Replans queued one behind the other (each lands on the last, a little later): the view follows each only until
    the next takes over. Something on the rest of the first, which the second replaced, does not block the path
    (the view once held every queued trajectory whole: the arm replanned again and again, one splice per check)."""
    stack, traj, timeline = scene
    gen, robot = stack.generator, stack.robot
    q1 = traj.state_at(0.6)[0]
    r1 = gen.splice(traj, 0.6, np.array([q1, q1 + [0.5, -0.5, 0.0, 0.4, 0.0, 0.0, 0.0], B]))
    timeline.add(r1, 10.6)
    r2 = gen.splice(r1, 0.15, np.array([r1.state_at(0.15)[0], B]))
    timeline.add(r2, 10.75)
    hand = robot.link_pose(r1.state_at(r1.duration * 0.6)[0], "panda_hand")[:3, 3]
    stack.world.set_occupancy(_map(_blob(hand)))  # on the rest of r1, past where r2 takes over
    check, monitor = MapPathCheck(stack.checker), Monitor([])
    assert not stack.checker.path_valid(monitor.grid(r1, False)[1], octree_only=True)
    assert stack.checker.path_valid(monitor.grid(r2, False)[1], octree_only=True)
    view = monitor.view(timeline, 10.2, timeline.state(10.2)[0])
    assert check(view, fresh=True).clear
    np.testing.assert_allclose(view.path[-1], B)


def test_a_new_map_is_checked_by_what_it_added(scene, monkeypatch):
    stack, traj, timeline = scene
    check = MapPathCheck(stack.checker)
    view = build_monitor(stack.checker, stack.generator, stack.cfg.controller).view(timeline, 10.0, A)
    far = _blob(np.array([0.3, -0.7, 0.9]))
    on_path = _blob(stack.robot.link_pose(traj.state_at(traj.duration / 2)[0], "panda_hand")[:3, 3])
    checked: list = []
    real = stack.checker.path_valid
    monkeypatch.setattr(
        stack.checker, "path_valid", lambda *a, **kw: checked.append(kw.get("occupancy")) or real(*a, **kw)
    )
    stack.world.set_occupancy(_map(far, serial=1))
    assert check(view).clear and checked[-1] is None  # the first map: all of it
    second = np.vstack([far, far[:5] + [0, 0, 30]])
    stack.world.set_occupancy(_map(second, serial=2, added=second[-5:]))
    assert check(view).clear and len(checked[-1]) == 5  # only the five new voxels
    third = np.vstack([second, on_path])
    stack.world.set_occupancy(_map(third, serial=3, added=on_path))
    assert not check(view).clear  # what it added blocks the path
    stack.world.set_occupancy(_map(far, serial=4, added=np.zeros((0, 3), np.int64)))
    assert check(view).clear and checked[-1] is None  # after a blocked verdict: all of it again
    stack.world.set_occupancy(_map(third, serial=6, added=on_path[:1]))
    assert not check(view).clear  # a map that does not follow the last one: all of it (the skipped one added more)


def test_scene_verdicts_are_remembered_until_the_scene_or_the_path_changes(scene, monkeypatch):
    stack, traj, timeline = scene
    monitor = build_monitor(stack.checker, stack.generator, stack.cfg.controller)
    check = ScenePathCheck(stack.checker)
    view = monitor.view(timeline, 10.0, A)
    calls: list = []
    real = stack.checker.check_path
    monkeypatch.setattr(stack.checker, "check_path", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    assert check(view).clear and check(view).clear and len(calls) == 1  # remembered
    assert check(view, fresh=True).clear and len(calls) == 2  # a full look when asked (before a resume)
    hand = stack.robot.link_pose(traj.state_at(traj.duration / 2)[0], "panda_hand")[:3, 3]
    stack.world.add("box", Box(size=(0.1, 0.1, 0.1)), make_transform(hand))
    verdict = check(view)
    assert not verdict.clear and verdict.contact.other == "box" and "box" in verdict.reason


class _Says(Check):
    def __init__(self, name, clear):
        self.name, self.ok, self.calls = name, clear, 0

    def __call__(self, view, fresh=False):
        self.calls += 1
        return Verdict(self.name, self.ok)


def test_the_monitor_stops_at_the_first_blocking_verdict(scene):
    stack, traj, timeline = scene
    first, second, third = _Says("a", True), _Says("b", False), _Says("c", True)
    monitor = Monitor([first, second, third])
    report = monitor.check_path(
        build_monitor(stack.checker, stack.generator, stack.cfg.controller).view(timeline, 10, A)
    )
    assert [v.check for v in report.verdicts] == ["a", "b"] and third.calls == 0
    assert not report.clear and report.blocking.check == "b" and monitor.stats.checks == 1


def test_close_checks_brake_near_what_the_cameras_see(scene):
    stack, traj, timeline = scene
    monitor = build_monitor(stack.checker, stack.generator, stack.cfg.controller)
    t = traj.duration / 2
    q = traj.state_at(t)[0]
    hand = stack.robot.link_pose(q, "panda_hand")[:3, 3]
    stack.world.set_occupancy(_map(_blob(hand + [0.0, 0.0, -0.13], size=0.04)))  # 2 cm under the fingers
    view = monitor.view(timeline, 10.0 + t, q)
    report = monitor.check_close(view, path_clear=False)
    assert report.blocking is not None and report.blocking.check == "safety_distance"
    assert report.blocking.clearance < stack.cfg.controller.safety_distance


@pytest.mark.parametrize("margin", [0.01, 0.0])
def test_a_replan_around_what_the_cameras_see_is_clear_for_the_monitor(panda_cfg, panda, margin):
    """A path is clear of the map by its padding where it was checked, by half a path resolution less in between;
    the monitor samples a fresh replan's curve elsewhere. Plans that keep that half resolution more from the map
    (planning.map_margin 0.01) are never blocked the moment they land; without the margin (the default) some are, and
    the monitor sees each as one more replan. Boxes of voxels where the hand will be, replans spliced on from ever
    later times."""
    cfg = panda_cfg.override({"planning": {"map_margin": margin}})
    stack = build_stack(cfg, robot=panda, static=[table()], cameras=False, seed=0)
    motion = stack.generator.time(np.array([A, B]), velocity_scale=0.4)
    rng = np.random.default_rng(7)
    spliced, blocked = 0, []
    for k in range(30):
        size, t_box = rng.uniform(0.08, 0.16), rng.uniform(0.9, 1.6)
        hand = panda.link_pose(motion.state_at(t_box)[0], "panda_hand")[:3, 3]
        stack.world.set_occupancy(box_surface(hand + rng.uniform(-0.03, 0.03, 3), size))
        for land in np.arange(t_box - 1.0, t_box - 0.4, 0.04):
            try:
                q, qd, _ = motion.state_at(land)
                path = stack.planner.plan(q, B, deadline=1.0, heading=qd).path  # as the service plans a replan
                new = stack.generator.splice(motion, land, path)
            except ReplannerError:
                continue
            spliced += 1
            grid = Monitor([]).grid(new, False)[1]
            view = MotionView(0.0, grid[0], grid, 0.0, (0.0, new), (new, k, land), 0.0, None)
            if not MapPathCheck(stack.checker)(view, fresh=True).clear:
                blocked.append((k, round(land - t_box, 2)))
    assert spliced > 380  # of 450: told the motion, few replans start against it
    if margin > 0:
        assert blocked == [], f"replans blocked by the monitor at once (box, landing time): {blocked}"
    else:  # the test can see the trouble: without the margin it is there
        assert blocked
