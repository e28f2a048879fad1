"""Speed and separation monitoring: the formula, the check against a known scene, and the arm slowing down when the
measured latency grows (on the stepped simulation: simulated time, the same run on any machine)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from replanner.bench.scenes import table
from replanner.control import Goal, GoalStatus
from replanner.model.geometry import Box
from replanner.model.transforms import make_transform
from replanner.monitor import SeparationTerms, SpeedSeparationCheck, protective_separation, safe_speed_scale
from replanner.monitor.checks import MotionView
from replanner.monitor.ssm import intrusion_distance
from replanner.sim.stepped import SteppedSim
from replanner.stack import build_stack
from replanner.world.occupancy import OccupancyMap

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
TERMS = SeparationTerms(v_h=1.6, T_r=0.2, T_s=0.3, v_r=0.5, S_s=0.1, C=0.0, Z_d=0.01, Z_r=0.005, tau=0.004)


def test_protective_separation_is_iso_ts_15066s():
    # v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r
    assert protective_separation(1.6, 0.2, 0.3, 0.5, 0.1, 0.02, 0.01, 0.005) == pytest.approx(
        0.8 + 0.1 + 0.1 + 0.02 + 0.01 + 0.005
    )
    assert TERMS.S_p == pytest.approx(1.6 * 0.5 + 0.5 * 0.2 + 0.1 + 0.015)
    assert TERMS.at_scale(1.0) == pytest.approx(TERMS.S_p)  # the current speed is scale 1
    assert TERMS.at_scale(0.0) == pytest.approx(1.6 * (0.2 + 0.004) + 0.015)  # at rest: reaction and jerk ramp


def test_intrusion_distance_after_iso_13855():
    assert intrusion_distance(0.01) == 0.0  # 8 (10 - 14) mm < 0
    assert intrusion_distance(0.04) == pytest.approx(8 * (40 - 14) * 1e-3)


@pytest.mark.parametrize("S", [0.2, 0.33, 0.5, 0.7, 0.93, 1.2, 3.0])
def test_the_speed_scale_meets_the_separation_exactly(S):
    k = safe_speed_scale(S, TERMS)
    if S < TERMS.at_scale(0.0):
        assert k == -1.0  # even at rest the person could reach the arm before it reacts: brake
    else:
        assert k >= 0 and TERMS.at_scale(k) == pytest.approx(S)  # as fast as the separation allows, no faster
        assert TERMS.at_scale(k * 1.01) > S


def test_more_latency_less_speed():
    scales = [
        safe_speed_scale(0.8, SeparationTerms(1.6, T_r, 0.3, 0.5, 0.1, 0.0, 0.01, 0.005, 0.004))
        for T_r in (0.05, 0.1, 0.2, 0.3)
    ]
    assert scales == sorted(scales, reverse=True) and scales[-1] < scales[0]


@pytest.fixture(scope="module")
def scene(panda_cfg, panda):
    stack = build_stack(panda_cfg, robot=panda, static=[table()], cameras=False)
    traj = stack.generator.time(np.array([A, B]), velocity_scale=0.5)
    return stack, traj


def _view(traj, t: float) -> MotionView:
    q = traj.state_at(t)[0]
    return MotionView(t, q, np.array([q, B]), 0.5, (0.0, traj), ("test",))


def _voxels_at(center, size=0.06, res=0.01) -> OccupancyMap:
    g = np.arange(-size / 2, size / 2, res) + res / 2
    pts = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3) + center
    return OccupancyMap.from_points(pts, res)


@pytest.mark.parametrize("T_r", [0.05, 0.2, 0.4])
def test_the_check_slows_or_brakes_as_the_formula_says(scene, panda_cfg, T_r):
    stack, traj = scene
    t = traj.duration / 2
    check = SpeedSeparationCheck(
        stack.checker, stack.generator, panda_cfg.controller.speed_separation, lambda now: T_r, lambda now: 0.0
    )
    top = stack.checker.body_poses(traj.state_at(t)[0])  # the arm's highest body origin: a "person" above it
    above = top.poses[:, :3, 3][np.argmax(top.poses[:, 2, 3])]
    try:
        for gap in (0.25, 0.5, 0.9):
            stack.world.set_occupancy(_voxels_at(above + [0.0, 0.0, gap + 0.03]))
            verdict = check(_view(traj, t))
            terms, S = check.last, check.last_separation
            assert terms.T_r == T_r and 0 < S < gap  # to the nearest surface point, less the sampling gap
            k = safe_speed_scale(S, terms)
            if k < 0:
                assert not verdict.clear and verdict.speed_factor == 0.0 and "speed and separation" in verdict.reason
            else:
                # the share of the trajectory's own nominal speed (its goal's velocity_scale is already in it)
                assert verdict.clear and verdict.speed_factor == pytest.approx(min(1.0, k) if math.isfinite(k) else 1.0)
    finally:
        stack.world.set_occupancy(None)


def test_an_arm_at_rest_held_by_the_resume_margin_says_so(scene, panda_cfg):
    stack, traj = scene
    cfg = panda_cfg.controller.speed_separation
    check = SpeedSeparationCheck(stack.checker, stack.generator, cfg, lambda now: 0.2, lambda now: 0.0)
    t = traj.duration  # at the goal: at rest
    top = stack.checker.body_poses(traj.state_at(t)[0])
    above = top.poses[:, :3, 3][np.argmax(top.poses[:, 2, 3])]
    held = 0
    try:
        for gap in np.arange(0.2, 0.7, 0.02):
            stack.world.set_occupancy(_voxels_at(above + [0.0, 0.0, gap + 0.03]))
            verdict = check(_view(traj, t))
            terms, S = check.last, check.last_separation
            if terms.at_scale(0.0) <= S < terms.at_scale(0.0) + cfg.resume_margin:  # only the margin holds it
                held += 1
                assert not verdict.clear and f"+ {cfg.resume_margin:.3f} m to move on from rest" in verdict.reason
    finally:
        stack.world.set_occupancy(None)
    assert held > 0


def _lowest_speed(panda_cfg, panda, camera_latency: float) -> tuple[float, object]:
    cfg = panda_cfg.override(
        {
            "perception": {"sensors": [{**panda_cfg.perception.sensors[0].model_dump(), "width": 320, "height": 240}]},
            # the monitor's slow-down, not the plan's (a plan for S_p is timed slower near the box in the first place)
            "controller": {"safety_distance": 0.0, "speed_separation": {"plans": False}},
        }
    )
    box = ("person", Box(size=(0.1, 0.1, 0.1)), make_transform((0.85, 0.0, 1.0)))  # above the swing, never on it
    sim = SteppedSim(cfg, [table()], robot=panda, seed=1, camera_latency=camera_latency)
    try:
        sim.add_obstacle(*box)  # only the cameras know it: possibly a person
        sim.run_for(0.3)  # the first frames arrive `camera_latency` late
        start = sim.controller.submit(Goal.joints("start", A))
        sim.run_until(lambda: start.result is not None, 20, "the start")
        h = sim.controller.submit(Goal.joints("across", B, velocity_scale=0.6))
        lowest = 1.0
        while h.result is None and sim.t < 60:
            sim.step()
            f = sim.controller.moves.speed_factor()
            lowest = min(lowest, f) if f is not None else lowest
        return lowest, h.result
    finally:
        sim.close()


def test_the_arm_slows_down_when_the_latency_grows(panda_cfg, panda):
    fast, res_fast = _lowest_speed(panda_cfg, panda, camera_latency=0.0)
    slow, res_slow = _lowest_speed(panda_cfg, panda, camera_latency=0.08)  # frames arrive 80 ms late: T_r grows
    assert res_fast.status == GoalStatus.SUCCEEDED and res_slow.status == GoalStatus.SUCCEEDED, (res_fast, res_slow)
    assert slow < fast - 0.1 and fast < 1.0  # near the "person" both slow, the late one more


def test_replans_land_later_when_answers_have_been_arriving_late():
    from replanner.control.latency import LatencyAccount

    acc = LatencyAccount(window=10.0)
    assert acc.landing_margin(0.0, 0.05) == 0.05  # nothing measured: as configured
    for k in range(20):  # answers 5-60 ms past their deadline of 0.15 s (a busy machine)
        acc.plan_answered(1.0 + k * 0.1, asked=1.0 + k * 0.1 - 0.15 - 0.005 * (k % 12 + 1), deadline=0.15)
    margin = acc.landing_margin(3.0, 0.05)
    assert 0.06 < margin < 0.08  # the 90th percentile of the overruns plus 10 ms
    acc.plan_answered(3.1, asked=3.1 - 5.0, deadline=0.15)  # one stall: never more than 0.25 s extra
    for _ in range(30):
        acc.plan_answered(3.2, asked=3.2 - 5.0, deadline=0.15)
    assert acc.landing_margin(3.3, 0.05) == pytest.approx(0.30)
    assert acc.report(3.3)["plan_overrun"]["n"] == 51
    assert acc.landing_margin(20.0, 0.05) == 0.05  # out of the window: back to the configured margin


def test_a_new_map_is_checked_at_once_whatever_the_check_rate(panda_cfg, panda):
    """A map waiting for the next periodic check would add up to a check period to T_r."""
    cfg = panda_cfg.override(
        {
            "perception": {"sensors": [{**panda_cfg.perception.sensors[0].model_dump(), "width": 160, "height": 120}]},
            "controller": {"check_rate_hz": 20.0},  # a check every 50 ms: 10 steps of the sim
        }
    )
    sim = SteppedSim(cfg, [table()], robot=panda, seed=1, camera_rate=7.0)  # frames between the periodic checks
    try:
        h = sim.controller.submit(Goal.joints("across", B, velocity_scale=0.3))
        sim.run_until(lambda: h.result is not None, 30, "the motion")
        report = sim.controller.latency.report(sim.t)
        assert h.result.status == GoalStatus.SUCCEEDED, h.result
        assert report["map_to_check"]["n"] >= 10 and report["map_to_check"]["max"] <= sim.dt + 1e-9
        assert report["check_gap"]["max"] >= 0.05 - 1e-9  # the periodic checks still come at their rate
    finally:
        sim.close()
