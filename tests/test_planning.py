"""Planning with OMPL and IK: solutions are valid, failures say why, bad requests are rejected clearly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from replanner.bench.scenes import add_table
from replanner.collision.exact import CollisionChecker
from replanner.errors import InvalidInputError
from replanner.model.geometry import Box
from replanner.model.transforms import make_transform, matrix_to_quat, rotation_angle
from replanner.planning import GoalInvalid, NoSolution, Planner, PoseGoal, StartInvalid, UnknownPlanner
from replanner.planning.ik import IKError, solve_ik
from replanner.planning.shortcut import shortcut
from replanner.world.scene import World
from tests.helpers import ARM_FORWARD, ARM_UP, sleeve

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])


@pytest.fixture(scope="module")
def wall_world(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    world.add("wall", Box(size=(0.3, 0.05, 0.6)), make_transform((0.5, 0.0, 0.3)))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    return world, checker


@pytest.fixture(scope="module")
def planner(wall_world, panda_cfg):
    return Planner.from_config(wall_world[1], panda_cfg.planning, seed=3)


def test_plans_around_a_wall(planner, wall_world):
    checker = wall_world[1]
    assert not checker.path_valid(np.array([A, B]))  # the straight swing is blocked
    res = planner.plan(A, B, deadline=2.0)
    assert not res.direct and res.attempts >= 1
    np.testing.assert_allclose(res.path[0], A)
    np.testing.assert_allclose(res.path[-1], B)
    assert checker.check_path(res.path).valid  # at the full resolution
    assert 0 < res.search_time <= res.total_time and 0 <= res.simplify_time <= res.total_time


def test_a_seeded_planner_gives_the_same_path_alone_or_after_others(wall_world, panda_cfg):
    first = Planner.from_config(wall_world[1], panda_cfg.planning, seed=11)
    other = Planner.from_config(wall_world[1], panda_cfg.planning, seed=99)
    alone = first.plan(A, B, deadline=5.0).path
    other.plan(B, A, deadline=5.0)  # draws from OMPL's (process-wide) generator in between
    first.plan(B, A, deadline=5.0)
    again = Planner.from_config(wall_world[1], panda_cfg.planning, seed=11).plan(A, B, deadline=5.0).path
    np.testing.assert_array_equal(alone, first.plan(A, B, deadline=5.0).path)
    np.testing.assert_array_equal(alone, again)


def test_a_seeded_kpiece_plan_is_the_same_whatever_was_built_before(wall_world):
    """KPIECE searches in a random projection of the joint space, drawn when a planner is built: a seeded planner
    draws the same one (a service's planner is built at start-up, before any seeded plan)."""
    checker = wall_world[1]
    for seed in (3, 4, 5, 6):
        alone = Planner(checker, seed=seed).plan(A, B, planner="LBKPIECE1", deadline=5.0)
        Planner(checker).plan(B, A, planner="LBKPIECE1", deadline=5.0)  # draws from OMPL's generator in between
        again = Planner(checker, seed=seed).plan(A, B, planner="LBKPIECE1", deadline=5.0)
        assert alone.planner == again.planner == "LBKPIECE1"
        np.testing.assert_array_equal(alone.path, again.path)


@pytest.mark.parametrize("name", ["RRTConnect", "RRTstar", "BITstar", "AORRTC", "PRM"])
def test_planners_by_name(planner, wall_world, name):
    res = planner.plan(A, B, planner=name, deadline=5.0)
    assert res.planner == name
    assert wall_world[1].check_path(res.path).valid


def test_retries_alternate_with_the_retry_planner_unless_a_planner_is_asked_for(wall_world):
    checker = wall_world[1]
    starved = dict(attempt_checks=1, seed=3)  # the first attempts cannot finish: retries decide
    res = Planner(checker, retry_planner="LBKPIECE1", **starved).plan(A, B, deadline=5.0)
    assert res.attempts >= 2 and res.planner == ("LBKPIECE1" if res.attempts % 2 == 0 else "RRTConnect")
    assert checker.check_path(res.path).valid
    assert Planner(checker, retry_planner=None, **starved).plan(A, B, deadline=5.0).planner == "RRTConnect"
    asked = Planner(checker, retry_planner="LBKPIECE1", **starved).plan(A, B, planner="RRTConnect", deadline=5.0)
    assert asked.planner == "RRTConnect" and asked.attempts >= 2
    with pytest.raises(UnknownPlanner, match="RRTTurbo"):
        Planner(checker, retry_planner="RRTTurbo")


def test_free_straight_line_needs_no_search(planner):
    res = planner.plan(A, A + np.r_[0.3, 0, 0, 0, 0, 0, 0])
    assert res.direct and len(res.path) == 2


def test_no_solution_in_time_retries_and_says_so(panda, panda_cfg):
    """The arm stands straight up in a closed sleeve that starts above its elbow: it cannot bend out."""
    up, forward = ARM_UP, ARM_FORWARD
    world = World(panda)
    for name, shape, pose in sleeve(panda):
        world.add(name, shape, pose)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    assert checker.is_valid(up) and checker.is_valid(forward)
    planner = Planner(checker, attempt_checks=200, seed=1)
    with pytest.raises(NoSolution, match=r"no path in 2.000 s \((\d+) attempts\)") as err:
        planner.plan(up, forward, deadline=2.0)
    assert int(str(err.value).split("(")[1].split()[0]) >= 2  # retried with fresh trees


class SteppedClock:
    """A machine on which every look at the clock finds `step` seconds gone."""

    def __init__(self, step: float):
        self.now, self.step = 0.0, step

    def __call__(self) -> float:
        self.now += self.step
        return self.now - self.step


def test_a_path_found_too_late_for_fcls_check_fails_at_the_deadline_instead_of_returning_late(wall_world):
    checker = wall_world[1]
    slow = SteppedClock(0.1)  # a tenth of the deadline per step: the path is found, the time is gone
    # "0 of": past the stated margin (3 %), FCL checks nothing more
    with pytest.raises(NoSolution, match=r"too late for FCL's check of it within the 1.000 s deadline \(0 of \d+"):
        Planner(checker, seed=3, clock=slow).plan(A, B, deadline=1.0)
    frozen = SteppedClock(0.0)
    res = Planner(checker, seed=3, clock=frozen).plan(A, B, deadline=1.0)
    assert not res.direct and checker.check_path(res.path).valid


@pytest.mark.parametrize(
    "start,goal,planner_name,deadline,error,match",
    [
        (A[:6], B, None, 1.0, StartInvalid, "7 values"),
        (A, np.r_[B, 0.0], None, 1.0, GoalInvalid, "7 values"),
        (np.r_[np.nan, A[1:]], B, None, 1.0, StartInvalid, "NaN"),
        (A, np.r_[B[:3], 0.5, B[4:]], None, 1.0, GoalInvalid, r"panda_joint4 = 0.5000 is outside its limits"),
        (A, B, "RRTTurbo", 1.0, UnknownPlanner, "available: RRTConnect"),
        (A, B, None, -1.0, InvalidInputError, "deadline must be a positive"),
        (A, B, None, float("nan"), InvalidInputError, "deadline"),
    ],
)
def test_bad_requests_name_the_problem(planner, start, goal, planner_name, deadline, error, match):
    with pytest.raises(error, match=match):
        planner.plan(start, goal, planner=planner_name, deadline=deadline)


@pytest.mark.parametrize("heading", [np.ones(6), np.r_[np.nan, np.ones(6)], "forward", np.ones((2, 7))])
def test_a_bad_heading_names_the_problem_a_standstill_is_none(planner, heading):
    with pytest.raises(InvalidInputError, match="heading must be 7 finite joint velocities"):
        planner.plan(A, B, heading=heading)
    np.testing.assert_array_equal(planner.plan(A, B, heading=np.zeros(7)).path, planner.plan(A, B).path)


def test_a_start_a_hair_past_a_limit_plans_from_the_limit_a_start_far_past_is_refused(planner, panda):
    start = A.copy()
    start[0] = panda.limits.lower[0] - 2e-5  # an arm settled at its limit, as measured
    res = planner.plan(start, B, deadline=2.0)
    assert res.path[0][0] == panda.limits.lower[0] and np.abs(res.path[0] - start).max() < 3e-5
    start[0] = panda.limits.lower[0] - 0.01
    with pytest.raises(StartInvalid, match="panda_joint1 = .* is outside its limits"):
        planner.plan(start, B)


def test_goal_and_start_in_collision_name_link_and_object(planner, wall_world, panda):
    into_wall = A.copy()
    hand_at = None
    for q0 in np.linspace(-0.5, 0.5, 81):  # swing joint 1 until the arm is in the wall (not only its padding)
        into_wall[0] = q0
        c = wall_world[1].check(into_wall)
        if c is not None and c.other == "wall" and wall_world[1].clearance(into_wall, 0.05).distance <= 0:
            hand_at = into_wall.copy()
            break
    assert hand_at is not None
    with pytest.raises(GoalInvalid, match=r"goal is in collision: panda_\w+ collides with object 'wall'") as err:
        planner.plan(A, hand_at)
    assert err.value.contact.other == "wall"
    with pytest.raises(StartInvalid, match="start is in collision: .*'wall'"):
        planner.plan(hand_at, A)


def test_pose_goal_is_reached_by_ik_nearest_the_start(planner, panda):
    T = panda.link_pose(B, "panda_grasptarget")
    goal = PoseGoal("panda_grasptarget", tuple(T[:3, 3]), tuple(matrix_to_quat(T[:3, :3])))
    res = planner.plan(A, goal, deadline=2.0)
    reached = panda.link_pose(res.path[-1], "panda_grasptarget")
    assert np.linalg.norm(reached[:3, 3] - T[:3, 3]) <= 0.002
    assert rotation_angle(reached[:3, :3].T @ T[:3, :3]) <= 0.02
    with pytest.raises(GoalInvalid, match="beyond the panda_grasptarget reach"):
        planner.plan(A, PoseGoal("panda_grasptarget", (3.0, 0.0, 0.5), (0, 0, 0, 1)))
    with pytest.raises(GoalInvalid, match="quaternion"):
        planner.plan(A, PoseGoal("panda_grasptarget", (0.5, 0.0, 0.5), (0, 0, 0, 0)))


def test_ik_solves_reachable_poses_and_fails_fast_on_unreachable(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    rng = np.random.default_rng(7)
    targets = []
    while len(targets) < 100:
        q = panda.random_q(rng)
        if checker.is_valid(q):
            targets.append(panda.link_pose(q, "panda_grasptarget"))
    solved = 0
    for T in targets:
        try:
            res = solve_ik(panda, "panda_grasptarget", T, checker=checker, seed=panda.home, restarts=16, rng=rng)
        except IKError:
            continue
        reached = panda.link_pose(res.q, "panda_grasptarget")
        assert np.linalg.norm(reached[:3, 3] - T[:3, 3]) <= 0.002
        assert rotation_angle(reached[:3, :3].T @ T[:3, :3]) <= 0.02
        assert checker.is_valid(res.q) and panda.limits.within(res.q)
        solved += 1
    print(f"IK solved {solved} of {len(targets)} reachable poses")
    assert solved >= 95
    far = make_transform((2.0, 0.0, 0.5))
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    with pytest.raises(IKError, match="beyond"):
        solve_ik(panda, "panda_grasptarget", far, checker=checker, rng=rng)
    assert rng.bit_generator.state == before  # refused before the search drew a single start


def test_ik_takes_the_seeds_own_solution_and_searches_on_when_that_one_collides(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    rng = np.random.default_rng(3)
    q0 = panda.home + 0.3
    T = panda.link_pose(q0, "panda_grasptarget")
    res = solve_ik(panda, "panda_grasptarget", T, checker=checker, seed=q0 + 0.05, restarts=16, rng=rng)
    assert np.abs(res.q - q0).max() < 0.1  # the descent from a nearby seed: the same arm posture, not another branch
    # a box where the seed's descent ends: the answer must come from another restart, collision-free
    world.add("block", Box(size=(0.12, 0.12, 0.12)), panda.link_pose(q0, "panda_link4"))
    blocked = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    assert not blocked.is_valid(q0)
    res = solve_ik(panda, "panda_grasptarget", T, checker=blocked, seed=q0 + 0.05, restarts=32, rng=rng)
    assert blocked.is_valid(res.q) and np.abs(res.q - q0).max() > 0.1


def test_a_goal_refused_only_for_its_padding_says_how_far_and_plans_with_less(panda, panda_cfg):
    from replanner.planning import padded_checker
    from tests.oracle import HULL_MARGIN, PyBulletOracle

    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)  # 10 mm padding
    hand = panda.link_pose(B, "panda_hand")[:3, 3]
    out = np.array([hand[0], hand[1], 0.0]) / np.linalg.norm(hand[:2])
    center = hand + 0.15 * out
    world.add("block", Box(size=(0.06, 0.06, 0.06)), make_transform(center))
    for _ in range(4):  # slide the block until the arm at B is 4 mm from it, as a grasp would be
        gap = checker.clearance(B, max_distance=0.5)
        n = (gap.point_on_robot - gap.point_on_obstacle) / np.linalg.norm(gap.point_on_robot - gap.point_on_obstacle)
        center = center + n * (gap.distance - 0.004)
        world.move("block", make_transform(center))
    gap = checker.clearance(B, max_distance=0.5)
    assert gap.obstacle == "block" and abs(gap.distance - 0.004) < 5e-4

    planner = Planner.from_config(checker, panda_cfg.planning, seed=2)
    with pytest.raises(GoalInvalid, match=rf"within the padding: .* {gap.distance * 1e3:.1f} mm from 'block'"):
        planner.plan(A, B, deadline=2.0)
    res = planner.plan(A, B, deadline=5.0, padding=0.002)
    tight = padded_checker(checker, 0.002)
    assert tight.path_resolution == pytest.approx(0.004)  # follows the padding: 2 x 2 mm
    assert tight.check_path(res.path).valid and planner.checker.exact is checker  # the planner's own padding is back
    with pytest.raises(GoalInvalid, match="within the padding"):
        planner.plan(A, B, deadline=2.0)
    # pybullet: the unpadded arm never goes into anything along the path, sampled ten times finer than checked
    oracle = PyBulletOracle(panda)
    for name, obj in world.objects.items():
        oracle.add(name, obj.shape, obj.pose)
    allowed = {tuple(p) for p in panda_cfg.collision.allowed_contacts}
    Q, _ = checker.interpolate(res.path, resolution=0.0004)
    worst = np.inf
    for q in Q:
        oracle.set_q(q)
        worst = min(worst, oracle.min_world_distance(0.05, allowed))
    oracle.close()
    assert worst > -HULL_MARGIN - 1e-4  # pybullet's hulls are 1 mm larger than ours
    for bad in (-0.01, 0.5, float("nan")):
        with pytest.raises(InvalidInputError, match="padding must be"):
            planner.plan(A, B, padding=bad)


def test_a_thin_plate_the_coarse_search_cannot_see_is_never_crossed(panda, panda_cfg):
    """The search checks motions at search_coarseness x the configured resolution whatever the padding (here 10 x
    2 cm against a 4 mm plate); what the plan returns is still clear at the padding's resolution and in pybullet."""
    from replanner.planning import padded_checker
    from tests.oracle import HULL_MARGIN, PyBulletOracle

    world = World(panda)
    add_table(world)
    world.add("plate", Box(size=(0.3, 0.004, 0.6)), make_transform((0.5, 0.0, 0.3)))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    cfg = panda_cfg.planning.model_copy(update={"search_coarseness": 10.0})
    planner = Planner.from_config(checker, cfg, seed=5)
    assert not checker.path_valid(np.array([A, B]))
    res = planner.plan(A, B, deadline=10.0, padding=0.002)
    assert padded_checker(checker, 0.002).check_path(res.path).valid  # FCL at 4 mm
    oracle = PyBulletOracle(panda)
    for name, obj in world.objects.items():
        oracle.add(name, obj.shape, obj.pose)
    allowed = {tuple(p) for p in panda_cfg.collision.allowed_contacts}
    Q, _ = checker.interpolate(res.path, resolution=0.0004)  # ten times finer than the padding's resolution
    worst = min(oracle.set_q(q) or oracle.min_world_distance(0.05, allowed) for q in Q)
    oracle.close()
    assert worst > -HULL_MARGIN - 1e-4


def test_a_shortcut_the_coarse_check_lets_through_a_thin_plate_is_shortcut_again_finer(panda, panda_cfg):
    """Shortcuts are checked at the search's coarse resolution; one that crosses a 4 mm plate between two coarse
    checks fails the full-resolution check of the result, and the path is shortcut again at the full resolution.
    What simplify returns is clear at 4 mm in FCL."""
    from replanner.planning import padded_checker

    world = World(panda)
    add_table(world)
    world.add("plate", Box(size=(0.3, 0.004, 0.6)), make_transform((0.5, 0.0, 0.3)))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    planner = Planner.from_config(checker, panda_cfg.planning, seed=5)
    fine = padded_checker(checker, 0.002)
    detour = planner.plan(A, B, deadline=10.0, padding=0.002).path
    coarse = planner.shortcut(detour, math.inf, 0.4, padding=0.002)  # coarse enough to step over the plate
    assert not fine.path_valid(coarse)  # the coarse shortcut crossed the plate
    W = planner.simplify(detour, 0.4, padding=0.002)
    assert fine.check_path(W).valid and len(W) <= len(detour)


def test_a_search_that_slipped_grows_anew_and_slips_once_per_resolution_at_most(panda, panda_cfg):
    """A path the coarse search found that FCL refuses at the padding's resolution (a slip): the trees hold its
    coarsely checked motions, so every tree is grown anew, finer. A grasp of the table_pick family (seed 4242, the
    bench's 51st) slips twice; kept trees went on returning slipped paths until the deadline (134 in 1 s)."""
    from replanner.bench import planning as bench
    from replanner.planning import padded_checker
    from replanner.planning.planner import SLIP_REFINE
    from replanner.stack import build_stack

    p = bench.make_problems(panda, panda_cfg, "table_pick", 51, seed=4242)[50]
    stack = build_stack(panda_cfg, robot=panda, static=p.objects, seed=4242, cameras=False)
    planner = stack.planner
    fine = padded_checker(stack.checker, p.padding)  # FCL
    coarse = panda_cfg.planning.search_coarseness * panda_cfg.collision.path_resolution
    for name in (None, "RRTConnect"):  # retries alternating with the retry planner; one planner, grown anew itself
        res = planner.plan(p.start, p.goal, planner=name, deadline=10.0, padding=p.padding)
        assert 1 <= res.slips <= math.ceil(math.log(coarse / fine.path_resolution, SLIP_REFINE)), name
        assert fine.check_path(res.path).valid


def test_the_standard_families_grasp_their_cans_close_and_clear(panda, panda_cfg):
    """Each standard family's goal holds its can between the fingers: clear of everything in pybullet, yet close."""
    import pybullet as pb

    from replanner.bench import planning as bench
    from tests.oracle import HULL_MARGIN, PyBulletOracle

    allowed = {tuple(p)[1] for p in panda_cfg.collision.allowed_contacts}  # the base on its table
    for family in bench.STANDARD:
        for p in bench.make_problems(panda, panda_cfg, family, 2, seed=4):
            oracle = PyBulletOracle(panda)
            for name, shape, pose in p.objects:
                oracle.add(name, shape, pose)
            oracle.set_q(p.goal)
            gap = {
                name: min((c[8] for c in pb.getClosestPoints(oracle.body, body, 0.1, physicsClientId=oracle.cid)),
                          default=0.1)
                for name, body in oracle.obstacles.items()
                if name not in allowed
            }  # fmt: skip
            oracle.close()
            assert p.padding == bench.GRASP_PADDING and min(gap.values()) > -HULL_MARGIN, (family, gap)
            assert gap[p.target] < 0.03, (family, p.target, gap[p.target])  # a grasp, not a pose somewhere near it


def test_the_planning_bench_builds_problems_for_any_robot_at_its_own_tip(iiwa, iiwa_cfg):
    """`bench planning --config iiwa`: grasps are posed for the config's tip link; a family whose scenes give this
    robot no problem stops after a bounded count of scenes with an error that names the way out."""
    from replanner.bench import planning as bench

    tip_link = iiwa_cfg.robot.tip_link
    for p in bench.make_problems(iiwa, iiwa_cfg, "bin", 2, seed=5):
        T = iiwa.link_pose(p.goal, tip_link)  # a grasp 11 cm over the bin's floor, the tool pointing down
        assert abs(T[2, 3] - 0.11) <= 0.03 + iiwa_cfg.planning.position_tolerance, T[:3, 3]
        assert T[2, 2] < -np.cos(iiwa_cfg.planning.orientation_tolerance), T[:3, 2]
    # no bookshelf grasp of the Panda's fits the iiwa: it gives up after 50 scenes, not its budget's 20,000
    with pytest.raises(InvalidInputError, match=r"only 0 of 100 bookshelf_small problems in 50 scenes.*--families"):
        bench.make_problems(iiwa, iiwa_cfg, "bookshelf_small", 100, seed=5)


def test_the_sphere_layer_changes_no_verdict_so_a_seeded_plan_is_the_same_path(wall_world, panda_cfg):
    """The layer answers only what is certain (free or in contact) and FCL the rest: OMPL sees the same verdicts,
    so with the same seed both layers return the same path, and FCL approves it at the full resolution."""
    world, checker = wall_world
    shelf = Box(size=(0.25, 0.5, 0.02))
    world.add("shelf", shelf, make_transform((0.45, -0.3, 0.45)))
    try:
        exact = CollisionChecker.from_config(world.robot, world, panda_cfg.collision)
        fast = Planner.from_config(exact, panda_cfg.planning, seed=11)
        cfg_fcl = panda_cfg.planning.model_copy(update={"collision_layer": "fcl"})
        plain = Planner.from_config(exact, cfg_fcl, seed=11)
        assert fast.layer == "spheres" and plain.layer == "fcl"
        rng = np.random.default_rng(4)
        planned = 0
        while planned < 6:
            a, b = world.robot.random_q(rng, 2)
            if not (exact.is_valid(a) and exact.is_valid(b)) or exact.path_valid(np.array([a, b])):
                continue
            p1, p2 = fast.plan(a, b, deadline=30.0), plain.plan(a, b, deadline=30.0)
            np.testing.assert_array_equal(p1.path, p2.path)
            assert exact.check_path(p1.path).valid
            planned += 1
    finally:
        world.remove("shelf")


def test_fcl_checks_every_configuration_of_a_returned_path_at_path_resolution(wall_world, panda_cfg, monkeypatch):
    """The last word is FCL's: the exact checker itself sees every configuration of a returned path's interpolation
    at path resolution, for a searched path (its shortcuts were checked coarser) and for a direct one."""
    world, _ = wall_world
    exact = CollisionChecker.from_config(world.robot, world, panda_cfg.collision)
    planner = Planner.from_config(exact, panda_cfg.planning, seed=5)
    seen: list[np.ndarray] = []
    real = exact.is_valid_batch

    def recorded(Q, **kw):
        seen.append(np.array(Q))
        return real(Q, **kw)

    monkeypatch.setattr(exact, "is_valid_batch", recorded)
    for goal, direct in ((B, False), (A + 0.05, True)):
        seen.clear()
        res = planner.plan(A, goal, deadline=5.0)
        assert res.direct == direct
        Q, _ = exact.interpolate(res.path)
        checked = {tuple(q) for q in np.concatenate(seen)}
        assert len(Q) > 2 and all(tuple(q) in checked for q in Q)


def test_shortcutting_asks_about_each_straight_motion_once(planner, wall_world):
    """The second waypoint skip after the random shortcuts asks again of waypoints the first one kept: those answers
    are remembered, so no motion is checked twice, and the path is the one every motion checked anew gives."""
    checker = wall_world[1]
    path = planner.plan(A, B, deadline=5.0).path
    t = np.linspace(0.0, 1.0, 5)[:-1, None]
    raw = np.vstack([a + t * (b - a) for a, b in zip(path[:-1], path[1:])] + [path[-1:]])  # a found path, 4x denser
    paths, asked = [], []
    for remember in (True, False):
        seen: list[tuple[bytes, bytes]] = []

        def motion_ok(a, b, seen=seen):
            seen.append((a.tobytes(), b.tobytes()))
            return checker.path_valid(np.array([a, b]))  # the resolution the path is judged at below

        paths.append(shortcut(raw, motion_ok, np.random.default_rng(0), tries=10, remember=remember))
        asked.append(seen)
    assert len(asked[0]) == len(set(asked[0])) < len(asked[1])  # without remembering, some are asked twice
    np.testing.assert_array_equal(paths[0], paths[1])
    assert len(paths[0]) < len(raw) and checker.check_path(paths[0]).valid


def test_every_segment_of_a_shortcut_path_was_checked_as_itself(planner, wall_world):
    """A random shortcut keeps pieces of the two segments it cuts: each is checked as a segment of its own (its
    configurations are not those checked along the whole segment, and one of them may touch the padding), so every
    segment of the result is a motion the check was asked about, ends and all."""
    checker = wall_world[1]
    path = planner.plan(A, B, deadline=5.0).path
    t = np.linspace(0.0, 1.0, 5)[:-1, None]
    raw = np.vstack([a + t * (b - a) for a, b in zip(path[:-1], path[1:])] + [path[-1:]])
    for seed in range(5):
        ok: set[tuple[bytes, bytes]] = set()

        def motion_ok(a, b, ok=ok):
            free = checker.path_valid(np.array([a, b]), 0.05)
            if free:
                ok.add((a.tobytes(), b.tobytes()))
            return free

        W = shortcut(raw, motion_ok, np.random.default_rng(seed), tries=10)
        assert len(W) < len(raw)
        assert all((a.tobytes(), b.tobytes()) in ok for a, b in zip(W[:-1], W[1:])), seed


def test_without_piece_checks_every_segment_lies_on_a_motion_found_free(planner, wall_world):
    """Where a finer check of the result decides (the planner's coarse shortcutting), the kept pieces of cut segments
    are not asked about again: each segment of the result then lies on a straight motion that was checked and found
    free, and the planner still returns only what FCL clears at the full resolution."""
    checker = wall_world[1]
    path = planner.plan(A, B, deadline=5.0).path
    t = np.linspace(0.0, 1.0, 5)[:-1, None]
    raw = np.vstack([a + t * (b - a) for a, b in zip(path[:-1], path[1:])] + [path[-1:]])
    free = [(a, b) for a, b in zip(raw[:-1], raw[1:])]  # the search checked the found path's own segments

    def on_free_motion(p, q):
        for a, b in free:
            d = b - a
            s = np.array([np.dot(x - a, d) / np.dot(d, d) for x in (p, q)])
            if np.all((s > -1e-9) & (s < 1 + 1e-9)) and all(
                np.allclose(a + si * d, x, atol=1e-9) for si, x in zip(s, (p, q))
            ):
                return True
        return False

    cut = 0
    for seed in range(5):
        asked = []

        def motion_ok(a, b, asked=asked):
            ok = checker.path_valid(np.array([a, b]), 0.05)
            asked.append(ok)
            if ok:
                free.append((a.copy(), b.copy()))
            return ok

        W = shortcut(raw, motion_ok, np.random.default_rng(seed), tries=10, pieces=False)
        with_pieces = []

        def counted(a, b, with_pieces=with_pieces):
            with_pieces.append(1)
            return checker.path_valid(np.array([a, b]), 0.05)

        shortcut(raw, counted, np.random.default_rng(seed), tries=10)
        cut += len(with_pieces) - len(asked)

        assert len(W) < len(raw)
        assert all(on_free_motion(a, b) for a, b in zip(W[:-1], W[1:])), seed
    assert cut > 0  # the pieces' own checks were the motions saved
    res = planner.plan(A, B, deadline=5.0)
    assert planner.exact.check_path(res.path).valid


def test_the_planning_bench_plans_beside_a_person_on_a_fresh_map_each_time(panda_cfg):
    """`bench planning --person`: a person-sized column of voxels beside each problem, clear of its start and goal;
    the plans avoid it (FCL on the timed trajectory, unpadded) and its voxels are counted."""
    from replanner.bench import planning as bench
    from replanner.bench.scenes import PERSON, person_map

    occ = person_map((0.7, -0.2))
    r = np.linalg.norm(occ.centers[:, :2] - [0.7, -0.2], axis=1)
    assert 10_000 < len(occ) < 40_000 and np.all(np.abs(r - PERSON[0]) < 0.01)
    assert occ.centers[:, 2].min() < 0.01 and occ.centers[:, 2].max() > PERSON[1] - 0.01
    out = bench.run(panda_cfg, per_family=2, families=("table", "box"), person=True)
    o = out["overall"]
    assert o["with_person"] == 4 and o["success_rate"] == 1.0, o.get("failures")
    assert o["map_voxels"]["median"] > 10_000 and o["map_colliding_samples"] == 0 and o["colliding_samples"] == 0
    # a plan's time split into its search and its shortcutting (FCL's re-check of the path included)
    assert o["search_ms"]["n"] == o["simplify_ms"]["n"] == 4
    assert max(o["search_ms"]["median"], o["simplify_ms"]["median"]) <= o["plan_ms"]["median"]  # parts of each plan


def test_after_an_edit_of_the_world_a_straight_plan_builds_no_layer(panda, panda_cfg):
    """The layer's spheres and shapes (~1 ms a world version) are built for a search, not for the checks of the
    ends and the straight line that FCL does as well: a goal after an attach or an edit that needs no search pays
    FCL's scene alone; one that needs a search builds the layer and plans the path it always did."""
    world = World(panda)
    add_table(world)
    planner = Planner.from_config(CollisionChecker.from_config(panda, world, panda_cfg.collision), panda_cfg.planning,
                                  seed=3)  # fmt: skip
    fast = planner.checker
    assert fast.ready()  # built when the planner was
    world.add("far", Box(size=(0.1, 0.1, 0.1)), make_transform((-0.6, 0.0, 0.05)))
    assert not fast.ready()
    res = planner.plan(A, B, deadline=2.0)
    assert res.direct and not fast.ready()
    world.add("post", Box(size=(0.2, 0.2, 0.2)), make_transform(panda.link_pose(A, "panda_hand")[:3, 3]))
    with pytest.raises(StartInvalid, match="start is in collision"):
        planner.plan(A, B, deadline=2.0)
    assert not fast.ready()
    world.remove("post")
    world.add("wall", Box(size=(0.3, 0.05, 0.6)), make_transform((0.5, 0.0, 0.3)))
    res = planner.plan(A, B, deadline=2.0)
    assert not res.direct and fast.ready()
    again = Planner.from_config(planner.checker.exact, panda_cfg.planning, seed=3).plan(A, B, deadline=2.0)
    np.testing.assert_array_equal(res.path, again.path)  # a layer built for the search, not before: the same path
