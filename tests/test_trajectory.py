"""Jerk-limited trajectories: limits at 1 kHz, the tube, pybullet collision checks, splicing and braking."""

from __future__ import annotations

import numpy as np
import pytest

from replanner.bench import planning as bench
from replanner.bench.scenes import add_table
from replanner.collision.exact import CollisionChecker
from replanner.errors import InvalidInputError
from replanner.sim.scene import PyBulletScene
from replanner.stack import build_stack
from replanner.trajectory import TrajectoryError, TrajectoryGenerator, distance_to_polyline, progress_along
from replanner.world.scene import World

DT = 1e-3
TOL = 1.001  # finite differences may exceed a limit by 0.1 % (rounding), never more


def executed(old, t0: float, new) -> np.ndarray:
    """What the arm runs: `old` until t0, then `new`, sampled every DT on one integer grid (no seam artefact)."""
    n0 = int(round(t0 / DT))
    n1 = int(np.ceil(new.duration / DT)) + 1
    before = old.evaluate(np.arange(n0) * DT, order=0)[0]
    after = new.evaluate(np.arange(n1) * DT, order=0)[0]
    return np.vstack([before, after])


def fd_ratios(q: np.ndarray, limits) -> tuple[float, float, float]:
    v = np.diff(q, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    j = np.diff(a, axis=0) / DT
    return (
        float((np.abs(v) / limits.velocity).max()),
        float((np.abs(a) / limits.acceleration).max()),
        float((np.abs(j) / limits.jerk).max()),
    )


@pytest.fixture(scope="module")
def planned(panda, panda_cfg):
    """Two problems of each bench family: (problem, checker, path)."""
    out = []
    for family in bench.OURS:
        for p in bench.make_problems(panda, panda_cfg, family, 2, seed=11):
            stack = build_stack(panda_cfg, robot=panda, static=p.objects, seed=5, cameras=False)
            res = stack.planner.plan(p.start, p.goal, deadline=3.0)
            out.append((p, stack.checker, res.path))
    return out


def test_timed_trajectories_hold_limits_tube_and_are_collision_free_in_pybullet(panda, panda_cfg, planned):
    ignore = bench.ignored_pairs(panda, panda_cfg.collision.allowed_contacts)
    timed = naive = 0.0
    for p, checker, path in planned:
        gen = TrajectoryGenerator(panda, checker, tube_radius=panda_cfg.planning.tube_radius)
        traj = gen.time(path)
        t = np.arange(0.0, traj.duration + DT, DT)
        q = traj.evaluate(t, order=0)[0]
        assert max(fd_ratios(q, traj.limits)) <= TOL
        assert distance_to_polyline(q, path).max() <= panda_cfg.planning.tube_radius + 1e-6
        np.testing.assert_allclose(q[0], path[0], atol=1e-9)
        np.testing.assert_allclose(q[-1], path[-1], atol=1e-6)
        sim = PyBulletScene(panda, room=False, self_collision=True)
        for name, shape, pose in p.objects:
            sim.add(name, shape, pose)
        hits = [c for qq in q[::5] for c in sim.contacts(qq, ignore)]
        sim.close()
        assert not hits, hits[:3]
        timed += traj.duration
        naive += gen.time_naive(path).duration
        assert traj.duration <= gen.time_naive(path).duration + 1e-9
    print(f"timed {timed:.2f} s vs stop-at-every-waypoint {naive:.2f} s (ratio {naive / timed:.3f})")
    assert timed < naive


def test_scaling_slows_down_and_keeps_the_scaled_limits(panda, planned):
    _, checker, path = planned[0]
    gen = TrajectoryGenerator(panda, checker)
    full, slow = gen.time(path), gen.time(path, velocity_scale=0.5, acceleration_scale=0.25)
    assert slow.duration > full.duration * 1.5
    q = slow.evaluate(np.arange(0, slow.duration, DT), order=0)[0]
    v, a, j = fd_ratios(q, slow.limits)
    assert max(v, a, j) <= TOL
    np.testing.assert_allclose(slow.limits.velocity, panda.limits.velocity * 0.5)


def test_speed_caps_along_the_path_hold_under_every_retiming(panda, planned):
    """Caps on the path speed over stretches of s (a person beside the middle of the path): the time law keeps under
    them and under the joint limits, at 1 kHz, timed from rest, after a slow-down and after a brake and a resume."""
    from replanner.trajectory.timelaw import SpeedCaps

    _, checker, path = planned[1]
    gen = TrajectoryGenerator(panda, checker)
    free = gen.time(path)
    L = free.curve.length
    peak = float(free.law.v.max())
    edges = np.array([0.0, 0.3 * L, 0.6 * L, L])
    caps = SpeedCaps(edges, np.array([peak, 0.25 * peak, peak]))

    def within(traj, t0=0.0):
        t = np.arange(t0, traj.duration, DT)
        s, v, _, _ = traj.law.eval(t)
        k = np.minimum(np.searchsorted(edges, s, side="right") - 1, 2)
        assert (v <= caps.speed[k] * 1.001 + 1e-9).all(), float((v / caps.speed[k]).max())
        assert max(fd_ratios(traj.evaluate(t, order=0)[0], traj.limits)) <= TOL

    slow = gen.time(path, caps_of=lambda curve: caps)
    assert slow.caps is caps and slow.duration > free.duration
    within(slow)
    t_mid = slow.duration * 0.5
    within(gen.slow_down(slow, t_mid, 0.5), 0.0)
    braked = gen.brake(slow, 0.2 * slow.duration)
    within(gen.resume(braked))
    with pytest.raises(ValueError, match="increasing edges"):
        SpeedCaps(np.array([0.0, 0.0]), np.array([1.0]))


@pytest.fixture(scope="module")
def table_motion(panda, panda_cfg):
    """A fixed scene (the table) and a fixed valid path: no planner randomness in the splice tests."""
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    path = np.array(
        [
            [-1.5, 0.2, 0.0, -1.9, 0.0, 2.1, 0.785],
            [0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785],
            [1.5, 0.2, 0.0, -1.9, 0.0, 2.1, 0.785],
        ]
    )
    assert checker.check_path(path).valid
    gen = TrajectoryGenerator(panda, checker)
    return checker, gen, gen.time(path)


def test_splice_is_continuous_never_backwards_and_within_limits(panda, table_motion):
    checker, gen, traj = table_motion
    t = np.arange(0.0, traj.duration, DT)
    speed = np.linalg.norm(traj.evaluate(t)[1], axis=1)
    t0 = t[int(np.argmax(speed))]  # mid-motion at full speed, on the 1 kHz grid
    q0, qd0, qdd0 = traj.state_at(t0)
    assert np.linalg.norm(qd0) > 1.0
    # a new path that veers off from where the arm is heading
    ahead = q0 + 0.3 * qd0 / np.linalg.norm(qd0)
    side = np.zeros(7)
    side[[1, 2]] = [0.25, -0.3]
    new_path = np.array([q0, ahead + side, panda.home])
    assert checker.check_path(new_path).valid
    new = gen.splice(traj, t0, new_path)
    q1, qd1, qdd1 = new.state_at(0.0)
    np.testing.assert_allclose(q1, q0, atol=1e-6)
    np.testing.assert_allclose(qd1, qd0, atol=1e-6)
    np.testing.assert_allclose(qdd1, qdd0, atol=1e-6)
    # what the arm executes: the old trajectory up to t0, then the new one
    executed = np.vstack(
        [
            traj.evaluate(np.arange(0.0, t0, DT), order=0)[0],
            new.evaluate(np.arange(0.0, new.duration + DT, DT), order=0)[0],
        ]
    )
    assert max(fd_ratios(executed, new.limits)) <= TOL
    progress = progress_along(new.evaluate(np.arange(0.0, new.duration, DT), order=0)[0], new_path)
    assert np.diff(progress).min() >= -1e-6
    np.testing.assert_allclose(new.evaluate(np.array([new.duration]), order=0)[0][0], panda.home, atol=1e-6)
    assert checker.check_path(new.evaluate(np.arange(0.0, new.duration, 0.01), order=0)[0]).valid


def test_splice_onto_a_path_that_turns_back_is_refused(table_motion):
    _, gen, traj = table_motion
    t0 = traj.duration / 2
    q0, qd0, _ = traj.state_at(t0)
    back = np.array([q0, q0 - 0.8 * qd0 / np.linalg.norm(qd0)])
    with pytest.raises(TrajectoryError, match="brake and plan from rest"):
        gen.splice(traj, t0, back)


def test_brake_from_full_speed_stops_on_the_path_within_jerk_limits(panda, panda_cfg, planned):
    for _, checker, path in planned[::3]:
        gen = TrajectoryGenerator(panda, checker, tube_radius=panda_cfg.planning.tube_radius)
        traj = gen.time(path)
        t = np.arange(0.0, traj.duration, DT)
        t0 = t[int(np.argmax(np.linalg.norm(traj.evaluate(t)[1], axis=1)))]
        stop = gen.brake(traj, t0)
        q0, qd0, qdd0 = traj.state_at(t0)
        s = stop.state_at(0.0)
        np.testing.assert_allclose(s[0], q0, atol=1e-9)
        np.testing.assert_allclose(s[1], qd0, atol=1e-6)
        np.testing.assert_allclose(s[2], qdd0, atol=1e-6)
        executed = np.vstack(
            [
                traj.evaluate(np.arange(0.0, t0, DT), order=0)[0],
                stop.evaluate(np.arange(0.0, stop.duration + DT, DT), order=0)[0],
            ]
        )
        assert max(fd_ratios(executed, stop.limits)) <= TOL
        qe, qde, qdde = stop.state_at(stop.duration)
        assert np.abs(qde).max() < 1e-9 and np.abs(qdde).max() < 1e-6  # at rest
        q = stop.evaluate(np.arange(0.0, stop.duration, DT), order=0)[0]
        assert distance_to_polyline(q, path).max() <= panda_cfg.planning.tube_radius + 1e-6
        # never longer than the plan's own stop (equal when the arm is already braking hard for the end)
        assert stop.duration <= traj.duration - t0 + 1e-9
        assert stop.s_at(stop.duration) <= traj.s_at(traj.duration) + 1e-9
        # on the path itself, not a straight line: every sample is a point of the planned curve
        s_vals = stop.path_state(np.arange(0.0, stop.duration, DT))[0]
        np.testing.assert_allclose(q, traj.curve.eval(s_vals), atol=1e-12)


@pytest.mark.parametrize(
    "path,kwargs,match",
    [
        (np.zeros((1, 7)), {}, "at least 2 waypoints"),
        (np.zeros((3, 6)), {}, "7 values"),
        (np.array([[0.0] * 7, [np.nan] * 7]), {}, "NaN"),
        (np.array([[0.0] * 7, [0.1] * 7]), {"velocity_scale": 0.0}, r"velocity_scale must be in \(0, 1\]"),
        (np.array([[0.0] * 7, [0.1] * 7]), {"acceleration_scale": 1.5}, "acceleration_scale"),
    ],
)
def test_bad_timing_requests(panda, path, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        TrajectoryGenerator(panda).time(path, **kwargs)


def test_sampling_for_the_robot(panda):
    traj = TrajectoryGenerator(panda).time(np.array([panda.home, panda.home + 0.2]))
    t, q, qd, qdd = traj.sample(0.01)
    assert t[0] == 0 and t[-1] == pytest.approx(traj.duration) and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(q[-1], panda.home + 0.2, atol=1e-6)
    assert np.abs(qd[[0, -1]]).max() < 1e-9


def test_slow_down_stays_on_the_curve_continuous_and_slower(panda, table_motion):
    _, gen, traj = table_motion
    t0 = round(traj.duration / 3, 3)  # on the 1 ms grid
    slow = gen.slow_down(traj, t0, 0.5)
    for a, b in zip(slow.state_at(0.0), traj.state_at(t0)):
        np.testing.assert_allclose(a, b, atol=1e-6)
    assert slow.duration > traj.duration - t0
    v, a, j = fd_ratios(executed(traj, t0, slow), traj.limits)
    assert max(a, j) <= TOL and v <= TOL
    tail = slow.evaluate(np.arange(0.5, slow.duration, DT))[1]  # once slowed, within the halved velocity limits
    assert (np.abs(tail) / (panda.limits.velocity * 0.5)).max() <= 1.001
    s = slow.path_state(np.arange(0.0, slow.duration, DT))[0]
    np.testing.assert_allclose(slow.evaluate(np.arange(0.0, slow.duration, DT), order=0)[0], traj.curve.eval(s))


def test_resume_after_a_brake_goes_on_to_the_goal(table_motion):
    _, gen, traj = table_motion
    stop = gen.brake(traj, traj.duration / 3)
    rest = gen.resume(stop)
    np.testing.assert_allclose(rest.state_at(0.0)[0], stop.state_at(stop.duration)[0], atol=1e-9)
    np.testing.assert_allclose(rest.end, traj.end, atol=1e-6)
    assert np.abs(rest.state_at(0.0)[1]).max() < 1e-9


def test_slow_downs_do_not_compound_and_a_resume_goes_back_to_full_speed(panda, table_motion):
    """Blocked, slowed, braked, resumed, blocked again: each slow-down is a share of the planned speed."""
    _, gen, traj = table_motion
    slow = gen.slow_down(traj, traj.duration / 4, 0.5)
    again = gen.slow_down(slow, slow.duration / 4, 0.5)
    np.testing.assert_allclose(again.limits.velocity, traj.limits.velocity * 0.5)
    rest = gen.resume(gen.brake(again, again.duration / 4))
    np.testing.assert_allclose(rest.limits.velocity, traj.limits.velocity)
    v = np.abs(rest.evaluate(np.arange(0.0, rest.duration, DT))[1]) / traj.limits.velocity
    assert v.max() > 0.55  # faster than the slowed limits allow


def test_derivative_bounds_of_transitions_hold_everywhere_on_them():
    """The compiled bounds a splice screens its transitions with: never below |q'|, |q''|, |q'''| sampled densely."""
    from replanner.trajectory.curve import QuinticPiece, quintic_coefficients

    rng = np.random.default_rng(3)
    ends = [rng.normal(0, s, (40, 7)) for s in (1.0, 1.0, 3.0, 1.0, 1.0, 3.0)]
    C = quintic_coefficients(*ends)
    for c in C:
        ell = float(rng.uniform(0.05, 2.0))
        for piece in QuinticPiece.split(c, ell, 8):
            x = np.linspace(0.0, piece.length, 4001)
            sampled = np.stack([np.abs(piece.eval(x, k)).max(axis=0) for k in (1, 2, 3)])
            assert np.all(piece.m >= sampled - 1e-12 * (1 + sampled))


def test_slow_downs_from_any_state_of_a_motion_succeed_and_keep_the_limits(panda):
    """From the middle of a short blend or at full acceleration: the arm brakes within the limits it runs at, then
    runs at the lower ones (before, 1 in 11 of these slow-downs could not be timed and the arm kept its speed)."""
    gen = TrajectoryGenerator(panda)
    rng = np.random.default_rng(0)
    A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
    B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
    tried = failed = 0
    for _ in range(25):
        W = np.vstack([A, A + rng.normal(0, 0.4, 7) * [1, 0.3, 1, 0.3, 1, 0.3, 1], B])
        traj = gen.time(np.clip(W, panda.limits.lower, panda.limits.upper), velocity_scale=rng.uniform(0.3, 1.0))
        for t0 in np.round(np.linspace(0.05, traj.duration - 0.05, 6), 3):
            for factor in (0.5, 0.2):
                tried += 1
                try:
                    slow = gen.slow_down(traj, t0, factor)
                except TrajectoryError:
                    failed += 1
                    continue
                assert max(fd_ratios(executed(traj, t0, slow), traj.limits)) <= TOL
                tail = slow.evaluate(np.arange(0.5, slow.duration, DT))[1]
                assert not len(tail) or (np.abs(tail) / (traj.nominal.velocity * factor)).max() <= 1.001
    assert failed <= 0.02 * tried, (failed, tried)


def test_the_timing_kernels_never_compile_again_mid_motion(panda):
    """A read-only limit (as the robot model holds them) or a strided view reaches the compiled kernels as the one
    kind they were compiled for: a new kind would compile for seconds in the middle of a motion."""
    from replanner.trajectory import Limits, Trajectory, kernels

    gen = TrajectoryGenerator(panda)  # warms the kernels up
    names = ("quintic_peaks", "path_bounds", "slowest_entry", "progress")
    before = {k: len(getattr(kernels, k).signatures) for k in names}
    lim = panda.limits  # read-only arrays
    traj = gen.time(np.array([panda.home, panda.home + 0.4, panda.home + [0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0]]))
    held = Trajectory(traj.curve, traj.law, Limits(lim.velocity, lim.acceleration, lim.jerk), traj.joint_names)
    slow = gen.slow_down(held, 0.3, 0.5)
    q0, v0, _ = slow.state_at(0.2)
    gen.splice(slow, 0.2, np.array([q0, q0 + 0.3 * v0 / np.linalg.norm(v0)]))
    assert {k: len(getattr(kernels, k).signatures) for k in before} == before


def test_curve_queries_in_any_order_and_along_the_polyline_agree_with_their_definitions():
    """Curve.eval in order (slices), out of order (masks), one point at a time and empty agree; the compiled progress
    along a polyline and the batched points at arc lengths agree with per-segment loops of their definitions."""
    from replanner.trajectory.curve import blended_curve, points_along

    rng = np.random.default_rng(4)
    W = np.cumsum(rng.normal(0, 0.3, (6, 7)), axis=0)
    curve = blended_curve(W, 0.1)
    s = np.linspace(0.0, curve.length, 500)
    perm = rng.permutation(len(s))
    for order in (0, 1, 2):
        in_order = curve.eval(s, order)
        np.testing.assert_allclose(curve.eval(s[perm], order), in_order[perm], rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.vstack([curve.eval(x, order) for x in s[::25]]), in_order[::25], atol=1e-12)
    assert curve.eval(np.zeros(0)).shape == (0, 7)

    seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
    starts = np.concatenate([[0.0], np.cumsum(seg)])
    P = rng.normal(W.mean(axis=0), 0.6, (300, 7))
    best_d, best_s = np.full(len(P), np.inf), np.zeros(len(P))
    for k in range(len(seg)):  # the closest point of each segment; before W[0] progress goes negative
        ab = W[k + 1] - W[k]
        t = np.minimum(((P - W[k]) @ ab) / (ab @ ab), 1.0)
        t = t if k == 0 else np.maximum(t, 0.0)
        d = np.linalg.norm(P - (W[k] + np.maximum(t, 0.0)[:, None] * ab), axis=1)
        better = d < best_d - 1e-12
        best_d[better], best_s[better] = d[better], starts[k] + t[better] * seg[k]
    assert (best_s < 0).any() and (best_s > starts[1]).any()
    np.testing.assert_allclose(progress_along(P, W), best_s, rtol=0, atol=1e-12)

    lengths = np.array([0.0, 0.3 * seg[0], seg[0], starts[3] + 0.5 * seg[3], starts[-1], starts[-1] + 1.0])
    B, ks = points_along(W, lengths)
    for b, k, length in zip(B, ks, lengths):
        k_ref = min(int(np.searchsorted(starts[1:], length)), len(seg) - 1)
        f = np.clip((length - starts[k_ref]) / seg[k_ref], 0.0, 1.0)
        assert k == k_ref
        np.testing.assert_allclose(b, W[k_ref] + f * (W[k_ref + 1] - W[k_ref]), atol=1e-12)
