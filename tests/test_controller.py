"""Every edge of the controller's state machine, and its reflex swerves, on a kinematic robot with clouds through
perception, all on a simulated clock the test advances (SteppedSim): no test races the wall clock; the same run on
any machine."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from replanner.config import parse_config
from replanner.control import Goal, GoalRejected, GoalStatus, State
from replanner.errors import InvalidInputError, UnknownNameError
from replanner.model.geometry import Box, Sphere
from replanner.model.transforms import make_transform
from replanner.planning import PoseGoal
from replanner.sim.stepped import SteppedSim
from replanner.trajectory import progress_along
from tests.conftest import CONFIGS
from tests.helpers import ARM_FORWARD, ARM_UP, sleeve

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
SLOW = 0.35  # velocity scale: ~2.5 s from A to B, time for the cameras to see things
# a plate through the goal's hand, facing the front camera: cameras map surfaces, so the hand must cross one
PLATE = Box(size=(0.02, 0.3, 0.3))
TABLE = ("table", Box(size=(1.6, 1.4, 0.05)), make_transform((0.3, 0.0, -0.025)))


def sim_config(**controller) -> dict:
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    front = data["perception"]["sensors"][0]
    front.update(width=320, height=240)
    data["perception"]["sensors"] = [front]
    # the replanning mechanism on its own: speed and separation would stop the arm near every box (tested apart)
    data["controller"] = {"speed_separation": {"enabled": False}, **data.get("controller", {}), **controller}
    return data


@pytest.fixture
def make_sim(panda):
    sims = []

    def make(**controller) -> SteppedSim:
        cfg = parse_config(copy.deepcopy(sim_config(**controller)), base_dir=CONFIGS)
        sim = SteppedSim(cfg, [TABLE], robot=panda, seed=3)
        sims.append(sim)
        return sim

    yield make
    for s in sims:
        s.close()


def submit(sim: SteppedSim, goal: Goal):
    """Hand a goal over; the controller decides on it at its next step."""
    h = sim.controller.submit(goal)
    sim.step()
    return h


def go_to(sim: SteppedSim, q, goal_id: str, within: float = 15.0, **kw):
    h = submit(sim, Goal.joints(goal_id, q, **kw))
    h.accepted(0.0)  # raises GoalRejected with the reason
    return result(sim, h, within)


def result(sim, handle, within: float):
    sim.run_until(lambda: handle.result is not None, within, f"the result of {handle.id}")
    return handle.result


def edges(sim) -> list[tuple[str, str, str]]:
    return [(t.source, t.dest, t.trigger) for t in sim.controller.transitions]


def wait_state(sim, state: State, within: float = 5.0):
    sim.run_until(lambda: sim.controller.state == state.value, within, state.value)


def at_rest(sim) -> bool:
    return np.abs(sim.state().velocity).max() < 1e-9


def hand_at(sim, q) -> np.ndarray:
    return sim.robot.link_pose(q, "panda_hand")[:3, 3]


def test_plan_ok_reaches_the_goal(make_sim):
    sim = make_sim()
    res = go_to(sim, A, "a")
    assert res.status == GoalStatus.SUCCEEDED
    assert np.abs(sim.state().position - A).max() < 0.01
    assert edges(sim) == [
        ("WAITING", "PLANNING", "plan"),
        ("PLANNING", "MONITORING", "start_motion"),
        ("MONITORING", "WAITING", "succeeded"),
    ]
    assert all(t.reason for t in sim.controller.transitions)


def test_goal_where_the_arm_is_succeeds_at_once(make_sim):
    sim = make_sim()
    assert go_to(sim, A, "a").status == GoalStatus.SUCCEEDED
    n = len(sim.controller.transitions)
    res = go_to(sim, A + 1e-4, "again")
    assert res.status == GoalStatus.SUCCEEDED and "already at the goal" in res.reason
    assert len(sim.controller.transitions) == n and sim.controller.state == State.WAITING.value


def test_plan_fails_retries_and_gives_up(make_sim):
    sim = make_sim()
    assert go_to(sim, ARM_UP, "up").status == GoalStatus.SUCCEEDED
    for name, shape, pose in sleeve(sim.robot):  # a sleeve the arm cannot bend out of (the world knows it)
        sim.world.add(name, shape, pose)
    h = submit(sim, Goal.joints("out", ARM_FORWARD, deadline=3.0))
    res = result(sim, h, 10)
    assert res.status == GoalStatus.FAILED and "planning failed" in res.reason, res
    attempts = int(res.reason.split("(")[1].split()[0])
    assert attempts >= 2  # retried with fresh trees until the deadline
    assert edges(sim)[-2:] == [("WAITING", "PLANNING", "plan"), ("PLANNING", "WAITING", "plan_failed")]


def _drop_on_path(sim, after: float, size=0.14, where: float = 0.5):
    mid = A + where * (B - A)
    c = hand_at(sim, mid)
    sim.run_for(after)
    sim.add_obstacle("intruder", Box(size=(size, size, size)), make_transform(c))
    return c


def test_block_then_replan_spliced_while_moving(make_sim):
    sim = make_sim()
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    t_start = sim.t
    _drop_on_path(sim, after=0.3, where=0.7)  # far enough ahead that a new path can land before it
    res = result(sim, h, 20)
    assert res.status == GoalStatus.SUCCEEDED, (res, edges(sim))
    e = edges(sim)
    assert ("MONITORING", "MONITORING_WITH_PLANNING_PENDING", "blocked") in e
    assert ("MONITORING_WITH_PLANNING_PENDING", "MONITORING", "spliced") in e
    assert not any(t[1] == "HOLDING" or t[2] == "brake_and_abort" for t in e)  # no stop on the way
    _check_executed_motion(sim, t_start)
    # the replan's own plan time is in the latency account (what `replanner status` and the demo report)
    ctl = sim.controller
    took = [d["plan_time"] for _, what, d in ctl.events_log if what == "plan_sent" and d["spliced"]]
    planned = ctl.latency.report(ctl.clock())["replan_plan"]
    assert took and planned["n"] >= len(took) and planned["max"] >= max(took)


def _check_executed_motion(sim, t_start: float):
    """What the robot actually ran, at 1 kHz: continuous, within limits, never backwards at a splice."""
    dt = 1e-3
    t = np.arange(t_start, sim.t, dt)
    q = np.array([sim.timeline.state(tt)[0] for tt in t])
    lim = sim.robot.limits
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    scale = SLOW
    assert (np.abs(v) / (lim.velocity * scale)).max() <= 1.001
    assert (np.abs(a) / lim.acceleration).max() <= 1.001
    assert (np.abs(j) / lim.jerk).max() <= 1.001
    segs = sim.timeline.segments()
    for start, traj in segs[1:]:
        if start <= t_start or traj.duration == 0:
            continue
        ts = np.arange(0, traj.duration, dt)
        qs = traj.evaluate(ts, order=0)[0]
        prog = progress_along(qs, traj.curve.polyline)
        assert np.diff(prog).min() >= -1e-6


def test_block_then_path_clears_cancels_the_replan(make_sim):
    sim = make_sim(pending_timeout=5.0)
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    # a box on the goal: every replan fails (goal in collision) while it is there
    goal_hand = hand_at(sim, B)
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW * 0.6))
    wait_state(sim, State.MONITORING)
    sim.add_obstacle("on_goal", PLATE, make_transform(goal_hand))
    wait_state(sim, State.PENDING, within=3.0)
    sim.remove_obstacle("on_goal")
    wait_state(sim, State.MONITORING, within=3.0)
    why = [(t.dest, t.reason) for t in sim.controller.transitions]
    assert edges(sim)[-1] == ("MONITORING_WITH_PLANNING_PENDING", "MONITORING", "path_clear"), why
    assert any(e[1] == "replan_canceled" for e in sim.controller.events_log)
    sim.run_for(0.1)  # slowed while the replan was pending: back to its planned speed once clear
    assert sim.controller.moves.speed_factor() == pytest.approx(1.0), sim.controller.events_log[-4:]
    assert result(sim, h, 20).status == GoalStatus.SUCCEEDED


def test_safety_distance_brakes_and_aborts(make_sim):
    sim = make_sim(policy="abort", pending_timeout=10.0)
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    goal_hand = hand_at(sim, B)
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.add_obstacle("on_goal", PLATE, make_transform(goal_hand))
    res = result(sim, h, 20)
    assert res.status == GoalStatus.FAILED, res
    assert edges(sim)[-1][1:] == ("WAITING", "brake_and_abort")
    sim.run_until(lambda: np.abs(sim.state().velocity).max() < 1e-9, 3.0, "the arm at rest")
    q = sim.state().position
    assert sim.checker.is_valid(q)  # stopped before touching anything the map holds
    assert any(e[1] == "brake" for e in sim.controller.events_log)


def test_brake_then_wait_and_resume_after_the_obstacle_leaves(make_sim):
    sim = make_sim(policy="wait_and_resume", pending_timeout=10.0, hold_timeout=20.0, hold_replan_interval=30.0)
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    goal_hand = hand_at(sim, B)
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.add_obstacle("on_goal", PLATE, make_transform(goal_hand))
    wait_state(sim, State.HOLDING, within=10.0)
    sim.run_for(0.5)
    assert sim.controller.state == State.HOLDING.value  # still blocked: still holding
    sim.remove_obstacle("on_goal")
    res = result(sim, h, 20)
    assert res.status == GoalStatus.SUCCEEDED, (res, edges(sim))
    assert ("HOLDING", "MONITORING", "resume") in edges(sim)


def test_stop_and_wait_brakes_at_once_then_plans_from_rest(make_sim):
    sim = make_sim(reaction="stop_and_wait", hold_timeout=20.0, hold_replan_interval=0.5)
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    _drop_on_path(sim, after=0.3, where=0.7)  # the box the replan policy goes around
    wait_state(sim, State.HOLDING, within=5.0)
    e = edges(sim)
    assert ("MONITORING", "HOLDING", "brake_and_hold") in e and not any("PENDING" in t[1] for t in e), e
    sim.run_until(lambda: np.abs(sim.state().velocity).max() < 1e-9, 3.0, "the arm at rest")
    res = result(sim, h, 20)
    assert res.status == GoalStatus.SUCCEEDED, (res, e)
    assert ("HOLDING", "MONITORING", "start_motion") in edges(sim)  # a new path from rest, around the box
    assert np.linalg.norm(hand_at(sim, sim.state().position) - hand_at(sim, B)) < 0.01


def test_reaction_none_never_looks_again(make_sim):
    sim = make_sim(reaction="none")
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    _drop_on_path(sim, after=0.3, where=0.7)
    res = result(sim, h, 20)
    assert res.status == GoalStatus.SUCCEEDED  # straight through the box: what the demo's baseline shows
    assert edges(sim)[-1] == ("MONITORING", "WAITING", "succeeded") and len(edges(sim)) == 6


def test_cancel_brakes_and_reports(make_sim):
    sim = make_sim()
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.run_for(0.5)
    sim.controller.cancel("across")
    res = result(sim, h, 5)
    assert res.status == GoalStatus.CANCELED
    sim.run_until(lambda: np.abs(sim.state().velocity).max() < 1e-9, 3.0, "the arm at rest")
    assert np.abs(sim.state().position - B).max() > 0.3  # stopped on the way, not at the goal
    with pytest.raises(UnknownNameError, match="active goal"):
        sim.controller.cancel("across")


def test_new_goal_preempts_the_current_one(make_sim):
    sim = make_sim()
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    first = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.run_for(0.4)
    second = submit(sim, Goal.joints("home", sim.robot.home))
    assert result(sim, first, 5).status == GoalStatus.PREEMPTED
    assert result(sim, second, 15).status == GoalStatus.SUCCEEDED
    assert np.abs(sim.state().position - sim.robot.home).max() < 0.01


def test_joint_state_silence_brakes_and_fails(make_sim):
    sim = make_sim()
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.joint_states_on = False
    res = result(sim, h, 5)
    assert res.status == GoalStatus.FAILED and "joint states silent" in res.reason
    assert edges(sim)[-1][2] == "fault"
    sim.joint_states_on = True


def test_a_robot_that_does_not_follow_fails_the_goal_and_the_next_plans_from_where_it_stands(panda):
    """The robot stops on its own mid-motion (a protective stop; it refuses what would make it jump, as `replanner
    robot` does): the controller's record has the arm going on, so nothing it would decide holds. It sees the
    measured arm off its command, fails the goal, and the next goal plans from where the arm stands."""
    cfg = parse_config(copy.deepcopy(sim_config()), base_dir=CONFIGS)
    sim = SteppedSim(cfg, [TABLE], robot=panda, seed=3, refuses_jumps=True)
    try:
        sim.timeline.hold(A, sim.t)  # moved by hand before the service looked: the record still says home
        sim.run_for(0.1)
        assert go_to(sim, B, "first").status == GoalStatus.SUCCEEDED  # an older rest in the record is no fault
        h = submit(sim, Goal.joints("across", A, velocity_scale=SLOW))
        wait_state(sim, State.MONITORING)
        sim.run_for(0.4)
        assert sim.controller.tracking_error < 1e-9  # a robot that follows exactly
        sim.timeline.stop_along(sim.t, sim.robot.limits.acceleration)  # the robot's own stop
        res = result(sim, h, 5)
        assert res.status == GoalStatus.FAILED and "does not follow its trajectory" in res.reason, res.reason
        assert edges(sim)[-1][2] == "fault" and sim.refused == 1  # the brake from the record would have jumped
        assert sim.controller.tracking_error > cfg.controller.tracking_tolerance
        sim.run_until(lambda: at_rest(sim), 3.0, "the arm at rest")
        assert np.abs(sim.state().position - A).max() > 0.3
        assert go_to(sim, B, "back").status == GoalStatus.SUCCEEDED  # planned from where the arm stands
        assert sim.refused == 1 and np.abs(sim.state().position - B).max() < 0.01
    finally:
        sim.close()


def test_camera_silence_brakes_and_fails(make_sim):
    sim = make_sim(sensor_timeout=0.5)
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW * 0.5))
    wait_state(sim, State.MONITORING)
    sim.cameras_on = False
    res = result(sim, h, 5)
    assert res.status == GoalStatus.FAILED and "camera 'front' silent" in res.reason
    with pytest.raises(GoalRejected, match="camera 'front' is silent"):
        submit(sim, Goal.joints("again", A)).accepted(0.0)


@pytest.mark.parametrize(
    "goal,match",
    [
        (Goal.joints("g", A[:6]), "7 values"),
        (Goal.joints("g", np.r_[np.nan, A[1:]]), "NaN"),
        (Goal.joints("g", np.r_[A[:3], 0.4, A[4:]]), "panda_joint4 = 0.4000 is outside"),
        (Goal.joints("g", np.array([0.0, 1.7, 0.0, -0.3, 0.0, 2.0, 0.8])), "panda_hand collides with object 'table'"),
        (Goal("g", PoseGoal("panda_grasptarget", (2.5, 0.0, 0.5), (1, 0, 0, 0))), "beyond"),
        (Goal("g", PoseGoal("no_such_link", (0.5, 0.0, 0.5), (1, 0, 0, 0))), "unknown link 'no_such_link'"),
    ],
)
def test_bad_goals_are_rejected_and_change_nothing(make_sim, goal, match):
    sim = make_sim()
    before = (sim.controller.state, len(sim.controller.transitions), sim.state().position.copy())
    with pytest.raises(GoalRejected, match=match):
        submit(sim, goal).accepted(0.0)
    assert (sim.controller.state, len(sim.controller.transitions)) == before[:2]
    np.testing.assert_allclose(sim.state().position, before[2])


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda: Goal.joints("g", A, planner="Teleport"), "unknown planner 'Teleport'"),
        (lambda: Goal.joints("g", A, deadline=-1.0), "deadline"),
        (lambda: Goal.joints("g", A, deadline=float("nan")), r"deadline \[s\] must be a number in \(0, 600\], got nan"),
        (lambda: Goal.joints("g", A, velocity_scale=2.0), "velocity_scale"),
        (lambda: Goal.joints("g", A, acceleration_scale=True), "acceleration_scale"),
        (lambda: Goal.joints("", A), "goal id"),
        (lambda: Goal("g", A), "JointGoal or a PoseGoal"),
    ],
)
def test_malformed_goals_cannot_be_made(make, match):
    with pytest.raises(InvalidInputError, match=match):
        make()


def test_a_held_arm_resumes_only_once_every_camera_has_looked_again():
    """Cameras may disagree on a voxel frame by frame: a path is clear when each has had a new look since it was
    first seen clear, not after a few checks between two frames of one camera."""
    from replanner.control.liveness import Liveness

    live = Liveness(("front", "side"), joint_state_timeout=0.2, sensor_timeout=0.5)
    assert not live.seen_all_since(10.0)  # no frames yet
    live.sensor(10.02, "front")
    assert not live.seen_all_since(10.0)  # the side camera has not looked since
    live.sensor(10.07, "side")
    assert live.seen_all_since(10.0) and not live.seen_all_since(10.05)
    assert Liveness((), 0.2, 0.5).seen_all_since(10.0)  # without cameras the checks decide alone


def test_held_the_replan_policy_goes_round_at_once_stop_and_wait_waits_its_interval(make_sim):
    """Both policies held by a box on the path (pending_timeout too short for a replan while moving): replan plans
    its way round as soon as the arm stands, stop-and-wait only after hold_replan_interval."""
    took = {}
    for reaction in ("replan", "stop_and_wait"):
        sim = make_sim(reaction=reaction, pending_timeout=0.01, hold_timeout=60.0, hold_replan_interval=6.0)
        assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
        h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
        wait_state(sim, State.MONITORING)
        _drop_on_path(sim, after=0.3, where=0.7)
        wait_state(sim, State.HOLDING, within=5.0)
        held = sim.t
        sim.run_until(lambda s=sim: s.controller.state != State.HOLDING.value, 20.0, "a way round")
        assert ("HOLDING", "MONITORING", "start_motion") in edges(sim), edges(sim)
        took[reaction] = sim.t - held
        assert result(sim, h, 30).status == GoalStatus.SUCCEEDED
    assert took["replan"] < 3.0 < 6.0 <= took["stop_and_wait"], took


def test_a_path_from_rest_that_speed_and_separation_would_stop_at_once_is_not_started(make_sim):
    """Held by a box on its path with room to move, the replan policy plans its way round, keeping S_p and the
    approach of a person while plans take as long as they have been taking; this one takes longer, and the box comes
    within the distance a reaction takes meanwhile: the new path is dropped, not started and braked again at once
    (the demo's co-worker reaching in did this), and the arm goes on along its own path once the box is gone."""
    sim = make_sim(
        reaction="replan",
        pending_timeout=0.01,
        hold_timeout=60.0,
        replan_deadline=0.02,  # plans from rest keep the approach of a person while they take this long
        speed_separation={"enabled": True, "approach_speed": 1.0},  # room for a plan from where the arm holds
    )
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.stack.worker.delay = 0.4  # [s] of simulated planning from now on: longer than plans have been taking
    _drop_on_path(sim, after=0.05, where=0.6)
    wait_state(sim, State.HOLDING, within=5.0)
    held = len(edges(sim))
    sim.run_until(lambda: any(e["purpose"] == "hold" for e in _events(sim, "plan_requested")), 5.0, "a plan round")
    hand = hand_at(sim, sim.state().position)
    sim.move_obstacle("intruder", make_transform(hand + [0.3, 0.0, 0.0]))  # 3 cm from the arm: not touching it
    sim.run_for(1.0)
    dropped = [e for e in _events(sim, "plan_dropped") if e["purpose"] == "hold"]
    assert dropped and "speed and separation" in dropped[0]["why"], sim.controller.events_log[-4:]
    assert edges(sim)[held:] == [] and sim.controller.state == State.HOLDING.value, edges(sim)[held:]
    sim.remove_obstacle("intruder")
    assert result(sim, h, 30).status == GoalStatus.SUCCEEDED
    assert edges(sim)[held:] == [("HOLDING", "MONITORING", "resume"), ("MONITORING", "WAITING", "succeeded")]


def test_a_goal_with_its_own_padding_plans_and_runs_close_to_a_known_object(make_sim):
    """A goal 5 mm from a known block: refused at the configured 1 cm padding (the reason names the distance),
    planned and run with padding 2 mm, and the monitor looks at that path with the same padding (no brake)."""
    sim = make_sim()
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    hand = hand_at(sim, B)
    z = hand[2] - 0.15
    sim.world.add("block", Box(size=(0.1, 0.1, 0.1)), make_transform((hand[0], hand[1], z)))
    for _ in range(4):  # lift the block until it is 5 mm below the arm at B
        z += sim.checker.clearance(B, max_distance=0.5).distance - 0.005
        sim.world.move("block", make_transform((hand[0], hand[1], z)))
    gap = sim.checker.clearance(B, max_distance=0.5)
    assert gap.obstacle == "block" and abs(gap.distance - 0.005) < 5e-4, gap
    with pytest.raises(GoalRejected, match=r"within the padding: .* plan with padding < 0\.00"):
        go_to(sim, B, "tight")
    before = len(edges(sim))
    res = go_to(sim, B, "close", within=20.0, padding=0.002, velocity_scale=SLOW)
    assert res.status == GoalStatus.SUCCEEDED, (res, edges(sim))
    assert edges(sim)[before:] == [("WAITING", "PLANNING", "plan"), ("PLANNING", "MONITORING", "start_motion"),
                                   ("MONITORING", "WAITING", "succeeded")]  # fmt: skip
    with pytest.raises(InvalidInputError, match=r"padding must be a number of metres in \[0, 0.2\]"):
        Goal.joints("bad", B, padding=-0.01)


# ---------------------------------------------------------------- the reflex in the loop (issue 16): swerves
def _box_over_the_path(sim):
    """From A towards B; 0.6 s on, a box appears over the hand's path at 55 % of the way (the forearm would clip
    it; lower, the arm passes). Returns (the goal's handle, when it was sent, when the arm began to move)."""
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    t_go = sim.t
    h = submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    t_start = sim.t
    sim.run_for(0.6)
    over = make_transform(hand_at(sim, A + 0.55 * (B - A)) + [0.0, 0.0, 0.12])
    sim.add_obstacle("intruder", Box(size=(0.14, 0.14, 0.14)), over)
    return h, t_go, t_start


def _events(sim, what: str) -> list[dict]:
    return [e[2] for e in sim.controller.events_log if e[1] == what]


def _no_contacts(sim, t_start: float, ignore=frozenset()) -> None:
    """Every 5 ms of what the robot ran since t_start: no penetration of anything in pybullet (table, intruder)."""
    for t in np.arange(t_start, sim.t, 0.005):
        hits = sim.scene.contacts(sim.timeline.state(t)[0], ignore, depth=1e-4)
        assert not hits, f"contact at {t:.3f} s: {hits}"


def _offsets_from(sim, t_start: float) -> float:
    """The farthest [rad] the executed motion left the goal's first straight path A -> B."""
    t = np.arange(t_start, sim.t, 0.01)
    Q = np.array([sim.timeline.state(x)[0] for x in t])
    d = B - A
    along = (Q - A) @ d / (d @ d)
    return float(np.linalg.norm(Q - (A + along[:, None] * d), axis=1).max())


def test_replan_reflex_swerves_at_once_and_replans_from_the_swerve(make_sim):
    sim = make_sim(reaction="replan_reflex", reflex={"r_max": 0.5})
    h, _, t_start = _box_over_the_path(sim)
    res = result(sim, h, 20)
    assert res.status == GoalStatus.SUCCEEDED, (res, edges(sim))
    log = [(ev[0], ev[1], ev[2]) for ev in sim.controller.events_log]
    swerves = [e for e in log if e[1] == "swerve"]
    assert swerves and all(0.02 <= e[2]["offset"] <= 0.3 + 1e-9 for e in swerves), swerves
    # at the moment the path was found blocked: the swerve first, then the replan, planned from the swerved motion
    blocked = next(i for i, e in enumerate(log) if e[1] == "blocked")
    after = [e[1] for e in log[blocked:] if e[0] == log[blocked][0]]
    assert after.index("swerve") < after.index("plan_requested"), after
    # the swerve alone cleared the path: the replan was called off, the arm went on round the box without a stop
    e = edges(sim)
    assert ("MONITORING_WITH_PLANNING_PENDING", "MONITORING", "path_clear") in e, e
    assert "replan_canceled" in [x[1] for x in log[blocked:]]
    assert not any(t[1] == "HOLDING" for t in e)
    _check_executed_motion(sim, t_start)
    _no_contacts(sim, t_start)
    assert _offsets_from(sim, t_start) > 0.1  # round the box, off the straight path
    assert sim.controller.status()["swerves"] == len(swerves)


def test_reflex_alone_swerves_and_comes_back_to_its_path_without_planning(make_sim):
    sim = make_sim(reaction="reflex", reflex={"r_max": 0.5}, pending_timeout=5.0)
    h, t_go, t_start = _box_over_the_path(sim)
    res = result(sim, h, 30)
    swerves = _events(sim, "swerve")
    assert swerves, edges(sim)
    # no replanning at all: the goal's one plan, nothing else
    asked = [ev[2]["purpose"] for ev in sim.controller.events_log if ev[1] == "plan_requested" and ev[0] >= t_go]
    assert asked == ["goal"], asked
    assert res.status == GoalStatus.SUCCEEDED, (res, edges(sim))
    assert np.abs(sim.state().position - B).max() <= sim.controller.cfg.goal_tolerance  # back on its path's end
    assert _offsets_from(sim, t_start) > 0.02  # it did leave the straight path
    _check_executed_motion(sim, t_start)
    _no_contacts(sim, t_start)


def test_a_swerve_never_goes_into_a_known_object(make_sim):
    """The detour of each size is checked before it is sent: the full swerve would put the hand into a known lamp,
    so the half-size one goes; with lamps on every size's way, nothing is sent."""
    sim = make_sim(reaction="reflex")
    assert go_to(sim, A, "start").status == GoalStatus.SUCCEEDED
    submit(sim, Goal.joints("across", B, velocity_scale=SLOW))
    wait_state(sim, State.MONITORING)
    sim.run_for(0.5)
    moves, reflex = sim.controller.moves, sim.controller.swerve.reflex
    dq = np.array([0.0, 0.0, 0.0, -0.3, 0.0, 0.0, 0.0])  # the elbow bends: the hand draws in off its path
    start, traj = moves.timeline.active(sim.t)
    t = sim.t - start + sim.controller.cfg.brake_latency  # where a swerve decided now starts (Moves' latency)
    sizes = [w for w, _ in reflex.detours(traj, t, dq)][::3]  # one per size (each size comes with 3 hold lengths)
    assert len(sizes) == 3
    full, half = hand_at(sim, sizes[0][1]), hand_at(sim, sizes[1][1])
    sim.world.add("lamp0", Sphere(radius=0.03), make_transform(full + 0.5 * (full - half)))  # beyond the full swerve
    assert [sim.checker.path_valid(w[:4]) for w in sizes] == [False, True, True]
    n = len(moves.timeline.segments())
    assert moves.swerve(lambda tr, t: reflex.detours(tr, t, dq))
    sent_at, sent = moves.timeline.segments()[-1]
    assert len(moves.timeline.segments()) == n + 1 and sent_at == start + t
    Q = sent.evaluate(np.linspace(0.0, sent.duration, 500), order=0)[0]
    assert sim.checker.is_valid_batch(Q).all()  # nowhere into the lamp
    assert np.abs(Q - traj.evaluate(np.linspace(t, traj.duration, 500), order=0)[0]).max() > 0.1  # it swerved
    # every size blocked: no swerve at all, the motion as it was
    for i, w in enumerate(sizes, 1):
        sim.world.add(f"lamp{i}", Sphere(radius=0.03), make_transform(hand_at(sim, w[1])))
    before = moves.timeline.segments()
    assert not moves.swerve(lambda tr, t: reflex.detours(tr, t, dq))
    assert moves.timeline.segments() == before
