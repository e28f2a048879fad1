"""The physics sim on a busy machine: a backlog it cannot step moves the arm on along its command, measured."""

from __future__ import annotations

import json

import numpy as np
import pytest

from replanner.sim.config import load_cell_config
from replanner.sim.physics import MAX_BURST, PhysicsSim
from replanner.trajectory.generator import TrajectoryGenerator


@pytest.fixture()
def sim():
    events: list[dict] = []
    s = PhysicsSim(load_cell_config("demo"), operator=False, publish_truth=lambda e: events.append(json.loads(e)))
    s.events = events  # what it published, for the test to read
    yield s
    s.stop()


def run(sim: PhysicsSim, now: float, until: float, dt: float) -> list[float]:
    """Advance the sim's clock from `now` to `until` [s] in steps of `dt`; the arm's largest distance from its
    command after each step [rad]."""
    errors = []
    for t in np.arange(now + dt, until, dt):
        sim.advance(t)
        q, _ = sim.cell.joint_states()
        errors.append(float(np.abs(q - sim.timeline.state(sim.t)[0]).max()))
    return errors


def test_after_a_backlog_the_arm_is_where_its_command_is_and_tracks_it(sim):
    """A frozen arm used to chase its command after a dropped backlog and overshoot: 56 mm into the table."""
    home, dt = sim.robot.home, 1.0 / sim.sc.physics_hz
    via = home + np.array([1.2, 0.5, 0.0, 0.8, 0.0, -0.3, 0.0])
    goal = home + np.array([0.0, 0.3, 0.5, 0.0, 0.0, 0.0, 0.0])
    traj = TrajectoryGenerator(sim.robot).time(np.array([home, via, goal]))  # the stall spans the turn
    start = sim.t + 0.01
    sim.add_trajectory(start, traj)
    stall_at = start + 0.3 * traj.duration
    before = run(sim, start - 0.01, stall_at, dt)
    stall = 0.4 * traj.duration  # far more than MAX_BURST steps: most of it is not stepped
    assert stall > 3 * MAX_BURST * dt
    dropped = sim.dropped
    sim.advance(stall_at + stall)
    assert sim.dropped - dropped > 0.5 * stall
    after = run(sim, stall_at + stall, start + traj.duration + 0.3, dt)
    assert max(before) < 0.02 and max(after) < 0.02, (max(before), max(after))
    np.testing.assert_allclose(sim.cell.joint_states()[0], goal, atol=0.01)


def test_contacts_in_a_backlog_are_measured(sim):
    """The arm dips into the table and back while the sim steps none of it: the contact is still counted."""
    home = sim.robot.home
    into = home + np.array([0.0, 2.0, 0.0, 1.0, 0.0, 0.0, 0.0])  # the hand 0.1 m below the table's top
    traj = TrajectoryGenerator(sim.robot).time(np.array([home, into, home]))
    start = sim.t + 0.01
    sim.add_trajectory(start, traj)
    sim.advance(start + traj.duration + 0.1)  # one call: MAX_BURST steps of physics, the rest walked
    assert sim.steps == MAX_BURST
    hits = [e for e in sim.events if e["kind"] == "contact"]
    assert hits and {e["object"] for e in hits} == {"table"}, sim.events
    assert min(e["deepest"] for e in sim.events if e["kind"] == "contact_end") < -0.05, sim.events
    np.testing.assert_allclose(sim.cell.joint_states()[0], home, atol=1e-6)


def test_the_forearm_on_the_path_is_seen_in_a_backlog():
    """The demo times reactions from the sim's `entered_path`: a backlog walked without physics still checks the
    coming motion against the forearm at the path-check rate, not only after the backlog."""
    events: list[dict] = []
    sim = PhysicsSim(load_cell_config("demo"), operator=True, publish_truth=lambda e: events.append(json.loads(e)))
    try:
        home = sim.robot.home
        goal = home + np.array([1.0, 0.3, 0.0, 0.5, 0.0, 0.0, 0.0])
        traj = TrajectoryGenerator(sim.robot).time(np.array([home, goal]))
        op = sim.operator
        # the hand's point halfway along the motion: the forearm's tip waits there from the start
        tip = sim.shadow.link_point(traj.state_at(0.5 * traj.duration)[0], sim.cell.robot.tip_link)
        op.tip, op.start, op.target = tip.copy(), np.asarray(op.cfg.stand, float), tip.copy()
        op.phase, op.until = "stay", np.inf
        t0 = sim.t
        burst_end = t0 + MAX_BURST / sim.sc.physics_hz
        start = burst_end + 0.2  # the motion begins inside the walked part of the backlog
        sim.add_trajectory(start, traj)
        sim.advance(start + 0.5)  # one call: MAX_BURST steps of physics, the rest walked
        assert sim.steps == MAX_BURST
        entered = [e["stamp"] for e in events if e["kind"] == "entered_path"]
        assert entered, events
        assert start <= entered[0] <= start + 1.0 / sim.sc.path_check_hz + 1e-6, entered[0] - start
    finally:
        sim.stop()
