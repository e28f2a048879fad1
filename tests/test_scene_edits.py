"""A box added to the scene onto the path of a moving arm: the monitor checks everything that can block, before a
resume too; pybullet (the oracle) says the arm never went into it. A box added onto the arm itself: it backs off
along the way it came rather than stay stuck. Simulated time throughout."""

from __future__ import annotations

import numpy as np

from replanner.bench import scene_edit
from replanner.bench.scenes import table
from replanner.control import Goal, GoalStatus
from replanner.sim.stepped import SteppedSim


def test_a_box_added_on_the_path_is_never_driven_through(panda_cfg):
    result = scene_edit.run(panda_cfg, seed=5, runs=4)
    assert result["passed_through"] == 0, result["rows"]
    for row in result["rows"]:
        assert row["deepest_m"] == 0.0, row  # pybullet: no contact at all after the edit
        assert row["status"] == GoalStatus.SUCCEEDED.value or row["reason"], row


def test_a_box_too_close_to_stop_for_makes_the_arm_back_off_not_stay_stuck(panda_cfg, panda):
    """Added 20-50 ms ahead: no brake can stop short of it; the arm backs off the way it came and goes on."""
    cfg = scene_edit.small_camera(panda_cfg)
    rng = np.random.default_rng(4)
    sim = SteppedSim(cfg, [table()], robot=panda, seed=2)
    oracle = scene_edit.Oracle(panda)
    try:
        start = sim.controller.submit(Goal.joints("start", scene_edit.A))
        sim.run_until(lambda: start.result is not None, 30, "the start")
        h = sim.controller.submit(Goal.joints("across", scene_edit.B, velocity_scale=0.5))
        sim.run_for(0.8)
        box, lead = scene_edit.box_ahead(sim, panda, oracle, rng, min_lead=0.02, max_lead=0.05)
        sim.world.add(*box)
        sim.add_obstacle(*box)
        sim.run_until(lambda: h.result is not None, 60, "the result")
        events = [e[1] for e in sim.controller.events_log]
        assert "retreat" in events and "stuck" not in events, events
        assert h.result.status == GoalStatus.SUCCEEDED or h.result.reason
        if not sim.checker.is_valid(sim.state().position):
            raise AssertionError(f"left in collision: {sim.checker.check(sim.state().position)}; {events}")
    finally:
        oracle.close()
        sim.close()
