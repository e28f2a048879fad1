"""The kinematic driver: follows what it is sent from the given start times; reports at its rate."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from replanner.control import KinematicDriver, Timeline
from replanner.control.moves import Moves
from replanner.errors import InvalidInputError
from replanner.trajectory.generator import TrajectoryGenerator


def test_timeline_replaces_from_the_start_time(panda):
    gen = TrajectoryGenerator(panda)
    a = gen.time(np.array([panda.home, panda.home + 0.3]))
    b = gen.time(np.array([a.state_at(0.2)[0], panda.home - 0.2]))
    tl = Timeline(panda.home)
    np.testing.assert_allclose(tl.state(5.0)[0], panda.home)  # nothing sent: at rest
    tl.add(a, 10.0)
    np.testing.assert_allclose(tl.state(10.1)[0], a.state_at(0.1)[0])
    tl.add(b, 10.2)
    np.testing.assert_allclose(tl.state(10.1)[0], a.state_at(0.1)[0])  # before the switch: the old one
    np.testing.assert_allclose(tl.state(10.3)[0], b.state_at(0.1)[0])
    np.testing.assert_allclose(tl.state(99.0)[0], panda.home - 0.2)  # after the end: holds the end


def test_splices_queued_behind_the_running_motion_never_drop_it(panda):
    """A box dropped near the path: each replan lands a little later than the one before, on it, and a dozen may be
    queued in a fraction of a second. The motion running now and each one queued stay (the account once kept the
    newest 8: the running one gone, the robot was told to be where it had stood before, 1.085 rad off); segments that
    ended long enough ago are forgotten."""
    gen = TrajectoryGenerator(panda)
    a = gen.time(np.array([panda.home, panda.home + 0.5]))
    tl = Timeline(panda.home)
    tl.add(a, 10.0, now=10.0)
    now, land, queued = 10.1, 10.3, [a]
    for _ in range(12):  # each lands on the last: from its state when it lands
        q = tl.state(land)[0]
        tl.add(b := gen.time(np.array([q, q + 0.05])), land, now)
        queued.append(b)
        now, land = now + 0.01, land + 0.01
    np.testing.assert_allclose(tl.state(now)[0], a.state_at(now - 10.0)[0])
    assert [tr for _, tr in tl.segments()] == queued
    tl.add(gen.time(np.array([tl.state(60.0)[0], panda.home])), 60.0, now=60.0)  # a minute on
    assert len(tl.segments()) == 8  # the ones long over are forgotten, the newest kept


def test_a_late_motion_from_rest_starts_on_arrival_a_late_splice_does_not(panda):
    gen = TrajectoryGenerator(panda)
    a = gen.time(np.array([panda.home, panda.home + 0.3]))
    tl = Timeline(panda.home)
    late = tl.receive(a, 10.0, 10.15)
    assert late == pytest.approx(0.15) and tl.segments()[0][0] == 10.15  # no jump into the middle of it
    np.testing.assert_allclose(tl.state(10.15)[0], panda.home)
    b = gen.slow_down(a, 0.2, 0.5)  # a splice: starts moving, lands at 10.35 on the robot's motion
    assert tl.receive(b, 10.35, 10.4) == 0.0 and tl.segments()[-1][0] == 10.35  # moving: it runs as stamped
    c = gen.time(np.array([tl.state(30.0)[0], panda.home]))
    assert tl.receive(c, 30.0, 20.0) == 0.0 and tl.segments()[-1][0] == 30.0  # early: waits for its start


def test_the_robot_refuses_a_trajectory_that_would_make_it_jump(panda):
    gen = TrajectoryGenerator(panda)
    tl = Timeline(panda.home)
    far = gen.time(np.array([panda.home + 0.5, panda.home]))  # starts half a radian from where the arm stands
    with pytest.raises(InvalidInputError, match=r"starts 0.500 rad away .* would jump"):
        tl.receive(far, 10.0, 10.0)
    assert tl.segments() == []
    tl.receive(gen.time(np.array([panda.home, panda.home + 0.3])), 10.0, 10.0)  # from where it is: taken
    assert len(tl.segments()) == 1


def _samples(tl, t0, t1, dt=0.001):
    ts = np.arange(t0, t1, dt)
    return ts, np.array([tl.state(t)[0] for t in ts])


def test_the_robots_own_stop_stays_on_the_path_and_within_the_acceleration(panda):
    gen = TrajectoryGenerator(panda)
    traj = gen.time(np.array([panda.home, panda.home + 0.8]))
    tl = Timeline(panda.home)
    tl.add(traj, 10.0)
    now = 10.0 + traj.duration / 2  # full speed
    acc = panda.limits.acceleration
    stands = tl.stop_along(now, acc)
    assert stands is not None and now < stands
    ts, Q = _samples(tl, now - 0.05, stands + 0.2)
    V = np.diff(Q, axis=0) / 0.001
    A = np.diff(V, axis=0) / 0.001
    assert np.all(np.abs(A) <= 1.1 * acc)  # within the acceleration (the bound's worst case), no jump in velocity
    assert np.abs(V[-50:]).max() < 1e-6  # stands
    # on the path: every sample is the trajectory's own configuration at some time, in order
    dense = np.array([traj.state_at(t)[0] for t in np.arange(0.0, traj.duration, 0.0005)])
    d = np.linalg.norm(Q[:, None] - dense[None], axis=2)
    assert d.min(axis=1).max() < 2e-3 and np.all(np.diff(d.argmin(axis=1)) >= 0)
    assert tl.stop_along(stands + 1.0, acc) is None  # standing: nothing to stop


def test_after_a_stall_the_robot_goes_on_from_where_it_was_and_brakes(panda):
    """A robot stopped for 2 s (SIGSTOP) must not replay its queue: no step larger than the limits allow."""
    gen = TrajectoryGenerator(panda)
    traj = gen.time(np.array([panda.home, panda.home + 1.0]))
    clock = VirtualClock(10.0)
    drv = KinematicDriver(panda.home, rate_hz=200, clock=clock, acceleration=panda.limits.acceleration,
                          stall_after=0.25)  # fmt: skip
    drv.execute(traj, 10.0)
    last = 10.0 + traj.duration / 3
    before = drv.state(last).position
    assert drv.stall_check(last, last + 2.0) and drv.stalls == 1
    q = [drv.state(last + 2.0 + k * 0.005).position for k in range(400)]
    steps = np.abs(np.diff(q, axis=0)).max(axis=0)
    assert np.all(steps <= panda.limits.velocity * 0.005 * 1.01)  # never a jump: at most the speed limit
    assert np.abs(q[0] - before).max() < 1e-9  # on from where it was
    assert np.abs(q[-1] - q[-2]).max() < 1e-9  # and stands
    without = KinematicDriver(panda.home, rate_hz=200, clock=clock)
    without.execute(traj, 10.0)
    assert not without.stall_check(last, last + 2.0)  # a simulated robot in the controller's process: no stall
    jump = np.abs(without.state(last + 2.0).position - without.state(last).position).max()
    assert jump > 0.5  # what a stale queue does


def test_a_brake_calls_off_a_motion_sent_but_not_started(panda):
    gen = TrajectoryGenerator(panda)
    now = [10.0]
    robot = Timeline(panda.home)
    moves = Moves(panda.home, gen, robot.add, lambda: now[0], 0.01, lambda *a, **k: None, lead=0.05)
    start = moves.send_planned(gen.time(np.array([panda.home, panda.home + 0.3])))  # a resume, say
    assert start == pytest.approx(10.05)
    now[0] = 10.02  # held again before it starts
    assert moves.brake() is None
    for t in (10.05, 10.2, 11.0):  # neither side ever runs it
        np.testing.assert_allclose(robot.state(t)[0], panda.home)
        np.testing.assert_allclose(moves.timeline.state(t)[0], panda.home)


def test_a_slow_down_keeps_a_splice_about_to_land_and_slows_it(panda):
    """Speed and separation slows the arm while a replan's splice is on its way: the splice still lands (slowed from
    where it lands); slowing the motion before it would call the avoidance off."""
    gen = TrajectoryGenerator(panda)
    now = [10.0]
    robot = Timeline(panda.home)
    moves = Moves(panda.home, gen, robot.add, lambda: now[0], 0.01, lambda *a, **k: None, lead=0.05)
    goal = panda.home + np.r_[0.8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    start = moves.send_planned(gen.time(np.array([panda.home, goal])))
    now[0] = start + 0.4
    land = now[0] + 0.15  # the replan's landing time
    base = moves.timeline.active(land)[1]
    q_land = base.state_at(land - start)[0]
    around = np.array([q_land, q_land + np.r_[0.2, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0], goal])
    moves.send_planned(gen.splice(base, land - start, around), land)
    now[0] += 0.02
    moves.slow_down(0.5)
    segs = moves.timeline.segments()
    assert segs[-1][0] == land, "the splice was called off"
    assert moves.timeline.later(now[0])[0][1].curve is not base.curve  # on the new path
    slowed = segs[-1][1]
    assert float((slowed.limits.velocity / slowed.nominal.velocity).max()) == pytest.approx(0.5)
    for k in range(3):  # where it lands, the slowed splice starts in the running motion's state
        np.testing.assert_allclose(slowed.state_at(0.0)[k], base.state_at(land - start)[k], atol=1e-6)
    np.testing.assert_allclose(robot.state(100.0)[0], goal, atol=1e-6)  # and reaches the goal on the new path
    # without a splice on its way, the running motion itself is slowed from now + latency
    now[0] = land + 0.3
    moves.slow_down(0.3)
    assert moves.timeline.segments()[-1][0] == pytest.approx(now[0] + 0.01)


def test_a_motion_the_robot_started_late_is_braked_from_where_the_arm_is(panda):
    """The robot got a motion from rest 240 ms after its stamp and started it on arrival (as the CI machine saw);
    the controller sees the measured arm behind, moves its record, and a brake then starts where the arm is."""
    gen = TrajectoryGenerator(panda)
    now = [10.0]
    robot = Timeline(panda.home)
    got = []
    moves = Moves(panda.home, gen, lambda tr, t: got.append((tr, t)), lambda: now[0], 0.01, lambda *a, **k: None, 0.05)
    start = moves.send_planned(gen.time(np.array([panda.home, panda.home + 0.6])))
    robot.receive(got[-1][0], start, start + 0.24)  # arrived late to a robot at rest: started on arrival
    now[0] = start + 0.27  # the robot is 30 ms into it; the controller's record says 270 ms
    q = robot.state(now[0] - 0.005)[0]  # a joint state 5 ms old
    assert moves.resync(q, now[0]) is q
    stop = moves.brake()
    robot.add(*got[-1])
    t0 = got[-1][1]
    q3 = [robot.state(t0 - k * 0.001)[0] for k in (0, 1, 2)]
    jump = np.abs(q3[0] - 2 * q3[1] + q3[2]).max()  # the second difference: a jump, not the motion's own step
    assert jump < 2e-3  # the brake starts where the arm is, to a joint state's age (without the resync: see below)
    assert np.abs(stop.state_at(0.0)[0] - robot.state(t0 - 1e-6)[0]).max() < 3e-3  # 5 ms of motion: the age
    # the same without the resync: the brake starts 240 ms further along, and the robot jumps there
    robot2, got2 = Timeline(panda.home), []
    blind = Moves(panda.home, gen, lambda tr, t: got2.append((tr, t)), lambda: now[0], 0.01, lambda *a, **k: None, 0.05)
    now[0] = 10.0
    s1 = blind.send_planned(gen.time(np.array([panda.home, panda.home + 0.6])))
    robot2.receive(got2[-1][0], s1, s1 + 0.24)
    now[0] = s1 + 0.27
    blind.brake()
    robot2.add(*got2[-1])
    t1 = got2[-1][1]
    q3 = [robot2.state(t1 - k * 0.001)[0] for k in (0, 1, 2)]
    assert np.abs(q3[0] - 2 * q3[1] + q3[2]).max() > 0.05
    # a robot on time is left alone
    on_time = Moves(panda.home, gen, lambda tr, t: None, lambda: now[0], 0.01, lambda *a, **k: None, 0.05)
    s2 = on_time.send_planned(gen.time(np.array([panda.home, panda.home + 0.6])))
    now[0] = s2 + 0.27
    on_time.resync(on_time.timeline.state(now[0] - 0.02)[0], now[0])  # 20 ms behind: a joint state's age and lag
    assert on_time.timeline.segments()[-1][0] == s2


class VirtualClock:
    """A clock only the test moves: the driver's waits advance it (no wall time involved)."""

    def __init__(self, t: float = 100.0):
        self.t = t
        self.lock = threading.Lock()

    def __call__(self) -> float:
        with self.lock:
            return self.t

    def wait(self, dt: float) -> None:
        with self.lock:
            self.t += dt
        time.sleep(0)  # let the test's thread run


def _collect(drv, got, n: int) -> None:
    drv.start()
    end = time.monotonic() + 30  # a bound on a hung thread only: the figures come from the virtual clock
    while len(got) < n and time.monotonic() < end:
        time.sleep(0.001)
    drv.stop()
    assert len(got) >= n


def test_driver_reports_at_its_rate(panda):
    clock, got = VirtualClock(), []
    drv = KinematicDriver(panda.home, rate_hz=200, on_state=got.append, clock=clock, wait=clock.wait)
    _collect(drv, got, 100)
    np.testing.assert_allclose(np.diff([s.stamp for s in got[:100]]), 0.005, atol=1e-9)


def test_driver_that_falls_behind_does_not_burst(panda):
    clock, got = VirtualClock(), []

    def on_state(js):
        got.append(js)
        if len(got) == 10:
            clock.wait(0.1)  # the machine stalls for 20 periods inside one callback

    drv = KinematicDriver(panda.home, rate_hz=200, on_state=on_state, clock=clock, wait=clock.wait)
    _collect(drv, got, 30)
    gaps = np.diff([s.stamp for s in got[:30]])
    assert gaps[9] >= 0.1 - 1e-9  # the stall itself
    np.testing.assert_allclose(np.delete(gaps, 9), 0.005, atol=1e-9)  # then the rate again, no catch-up burst


def test_a_brake_on_the_senders_account_joins_a_motion_the_robot_started_late(panda):
    """The CI machine's case: a motion from rest reached the robot 29 ms after its stamp (started on arrival, too
    little for the controller to see), and the controller's brake starts where its own account has the arm. The
    robot runs it 29 ms late too, from where the arm is: continuous, not refused."""
    gen = TrajectoryGenerator(panda)
    now = [10.0]
    robot, got = Timeline(panda.home), []
    moves = Moves(panda.home, gen, lambda tr, t: got.append((tr, t)), lambda: now[0], 0.01, lambda *a, **k: None, 0.05)
    start = moves.send_planned(gen.time(np.array([panda.home, panda.home + 0.6])))
    assert robot.receive(got[-1][0], start, start + 0.029) == pytest.approx(0.029)
    now[0] = start + 0.35
    assert moves.resync(robot.state(now[0] - 0.005)[0], now[0]) is not None
    assert moves.timeline.segments()[-1][0] == start  # 29 ms: below what the controller can tell from the arm
    stop = moves.brake()
    t_stop = got[-1][1]
    assert np.abs(stop.state_at(0.0)[0] - robot.state(t_stop)[0]).max() > 0.02  # as stamped it would jump
    assert robot.receive(stop, t_stop, now[0]) == pytest.approx(0.029)
    t0 = t_stop + 0.029
    q3 = [robot.state(t0 + k * 0.001)[0] for k in (-1, 0, 1)]
    assert np.abs(q3[0] - 2 * q3[1] + q3[2]).max() < 1e-4  # no jump where the brake takes over
    np.testing.assert_allclose(robot.state(t0 + 10.0)[0], stop.state_at(stop.duration)[0], atol=1e-9)
    # a new motion from rest on time: the robot is no longer behind
    q_end = stop.state_at(stop.duration)[0]
    s2 = now[0] + 5.0
    assert robot.receive(gen.time(np.array([q_end, panda.home])), s2, s2 - 0.05) == 0.0 and robot.lag == 0.0


def test_a_motion_queued_behind_a_late_one_runs_as_late_and_so_does_its_brake(panda):
    """The sender queues a motion from rest after its account has the first one end; the robot, 80 ms behind, still
    runs the first then: it runs the second 80 ms late as well, and a brake of the second too."""
    gen = TrajectoryGenerator(panda)
    robot = Timeline(panda.home)
    m1 = gen.time(np.array([panda.home, panda.home + 0.6]))
    assert robot.receive(m1, 10.0, 10.08) == pytest.approx(0.08)  # started on arrival
    s2 = 10.0 + m1.duration + 0.03  # 30 ms after the first ends on the sender's account, 50 ms before the robot's
    m2 = gen.time(np.array([panda.home + 0.6, panda.home]))
    assert robot.moving(s2) and robot.receive(m2, s2, s2 - 0.5) == pytest.approx(0.08)
    assert robot.lag == pytest.approx(0.08)
    stop = gen.brake(m2, 0.4)
    assert np.abs(stop.state_at(0.0)[0] - robot.state(s2 + 0.4)[0]).max() > 0.02  # as stamped it would jump
    assert robot.receive(stop, s2 + 0.4, s2 + 0.39) == pytest.approx(0.08)
