"""World editing, the occupancy snapshot (fcl.OcTree from OctoMap's format) and its broadphase grid."""

from __future__ import annotations

import threading

import fcl
import numpy as np
import pytest

from replanner.collision.exact import CollisionChecker
from replanner.errors import InvalidInputError, UnknownNameError, WorldError
from replanner.model.geometry import Box, Mesh, Sphere
from replanner.model.transforms import make_transform
from replanner.world.occupancy import OccupancyMap, voxel_centers
from replanner.world.scene import World


def _voxel_distance(centers, res, p):
    """Distance from point p to the nearest voxel box (0 inside)."""
    d = np.maximum(np.abs(centers - p) - res / 2, 0.0)
    return np.linalg.norm(d, axis=1).min()


def test_octree_leaves_are_exactly_the_given_voxels():
    rng = np.random.default_rng(0)
    res = 0.02
    keys = np.unique(rng.integers(-20, 20, (300, 3)), axis=0)
    occ = OccupancyMap(keys, res)
    tree = fcl.CollisionObject(occ.tree, fcl.Transform())
    ball = fcl.CollisionObject(fcl.Sphere(0.004))
    mismatches = 0
    for p in rng.uniform(-0.45, 0.45, (3000, 3)):
        ball.setTranslation(p)
        hit = fcl.collide(ball, tree, fcl.CollisionRequest()) > 0
        truth = _voxel_distance(occ.centers, res, p) < 0.004
        mismatches += hit != truth
    assert mismatches == 0


def test_octree_with_the_header_left_in_would_be_wrong():
    """The reason build_fcl_octree strips OctoMap's ASCII header (fcl parses it as payload silently)."""
    import octomap

    res = 0.05
    centers = voxel_centers(np.array([[2, 2, 2]]), res)
    t = octomap.OcTree(res)
    t.updateNodes(centers, True)
    blob = t.writeBinary()
    wrong = fcl.CollisionObject(fcl.OcTree(res, np.frombuffer(blob, np.int8)), fcl.Transform())
    right = fcl.CollisionObject(OccupancyMap(np.array([[2, 2, 2]]), res).tree, fcl.Transform())
    ball = fcl.CollisionObject(fcl.Sphere(0.01), fcl.Transform(centers[0]))
    assert fcl.collide(ball, right, fcl.CollisionRequest()) > 0
    assert fcl.collide(ball, wrong, fcl.CollisionRequest()) == 0


def test_broadphase_never_misses_a_voxel():
    rng = np.random.default_rng(1)
    res = 0.01
    occ = OccupancyMap(rng.integers(-40, 40, (2000, 3)), res, broadphase_cell=0.04)
    lo = rng.uniform(-0.5, 0.5, (5000, 3))
    hi = lo + rng.uniform(0.0, 0.1, (5000, 3))
    got = occ.any_in_boxes(lo, hi)
    vlo, vhi = occ.centers - res / 2, occ.centers + res / 2
    truth = np.array([np.any(np.all((vlo <= h) & (vhi >= l), axis=1)) for l, h in zip(lo, hi)])
    assert not np.any(truth & ~got)  # never a false "free"
    assert got.mean() < 0.9 and truth.mean() > 0.05  # and it does rule boxes out
    far = occ.any_in_boxes(np.array([[5.0, 5, 5], [-9, -9, -9]]), np.array([[6.0, 6, 6], [-8, -8, -8]]))
    assert not far.any()
    _, _, n, sat = occ.broadphase_table()  # the compiled table is numpy's cumulative sums of the counts per cell
    grid = np.zeros(n, np.int64)
    np.add.at(grid, tuple(((occ.keys - occ.keys.min(axis=0)) // 4).T), 1)
    want = np.zeros(n + 1, np.int64)
    want[1:, 1:, 1:] = grid.cumsum(0).cumsum(1).cumsum(2)
    np.testing.assert_array_equal(sat, want.ravel())


@pytest.mark.parametrize(
    "keys,res,match",
    [
        (np.zeros((3, 3)), 0.01, "integer"),
        (np.zeros((3, 2), np.int64), 0.01, r"\(N, 3\)"),
        (np.zeros((3, 3), np.int64), 0.0, "resolution"),
    ],
)
def test_bad_occupancy_input(keys, res, match):
    with pytest.raises(InvalidInputError, match=match):
        OccupancyMap(keys, res)


def test_bad_points():
    with pytest.raises(InvalidInputError, match="finite"):
        OccupancyMap.from_points(np.array([[0.0, np.nan, 0.0]]), 0.01)


def test_world_edits_reach_the_checker(panda):
    world = World(panda)
    checker = CollisionChecker(panda, world, padding=0.01)
    q = panda.home
    hand = panda.link_pose(q, "panda_hand")[:3, 3]
    assert checker.is_valid(q)
    world.add("box", Box(size=(0.1, 0.1, 0.1)), make_transform(hand))
    assert checker.check(q).other == "box"
    world.move("box", make_transform(hand + [0, 0, 0.5]))
    assert checker.is_valid(q)
    world.move("box", make_transform(hand))
    world.remove("box")
    assert checker.is_valid(q)
    world.add("ball", Sphere(radius=0.05), make_transform(hand))
    world.add("mesh", Mesh(*_tetra(0.1)), make_transform(hand + [0, 0, 0.4]))
    assert checker.check(q).other == "ball"
    world.remove("ball")
    assert checker.is_valid(q)
    world.move("mesh", make_transform(hand - [0.0, 0.0, 0.05]))
    assert checker.check(q).other == "mesh"
    world.clear()
    assert checker.is_valid(q) and world.names() == []


def _tetra(s):
    v = np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [0, 0, s]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def test_world_errors_say_what_to_change(panda):
    world = World(panda)
    world.add("box", Box(size=(0.1, 0.1, 0.1)), np.eye(4))
    with pytest.raises(WorldError, match="already exists"):
        world.add("box", Box(size=(0.1, 0.1, 0.1)), np.eye(4))
    with pytest.raises(UnknownNameError, match="unknown object 'boxx'.*box"):
        world.remove("boxx")
    with pytest.raises(UnknownNameError, match="panda_hand"):
        world.attach("box", "gripper", panda.home)
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(InvalidInputError, match="not a rigid transform"):
        world.move("box", bad)
    with pytest.raises(InvalidInputError, match=r"must be 3 finite numbers > 0"):
        Box(size=(0.1, -1.0, 0.1))
    world.attach("box", "panda_hand", panda.home)
    with pytest.raises(WorldError, match="attached to panda_hand.*detach it first"):
        world.move("box", np.eye(4))
    with pytest.raises(UnknownNameError, match="attached object"):
        world.detach("nothing", panda.home)
    assert world.names() == ["box"]


def test_snapshots_do_not_change_after_edits(panda):
    world = World(panda)
    world.add("a", Box(size=(0.1, 0.1, 0.1)), np.eye(4))
    before = world.snapshot()
    world.add("b", Box(size=(0.1, 0.1, 0.1)), np.eye(4))
    world.set_occupancy(OccupancyMap.empty())
    assert list(before.objects) == ["a"] and before.occupancy is None
    assert sorted(world.objects) == ["a", "b"] and world.occupancy is not None
    with pytest.raises(TypeError):
        before.objects["c"] = None


def test_occupancy_swaps_while_another_thread_checks(panda):
    """A checker never sees a half-swapped map: every verdict is one of the two maps' verdicts."""
    world = World(panda)
    checker = CollisionChecker(panda, world, padding=0.0)
    q = panda.home
    hand = panda.link_pose(q, "panda_hand")[:3, 3]
    blocking = OccupancyMap.from_points(hand + np.random.default_rng(0).uniform(-0.03, 0.03, (500, 3)), 0.01)
    elsewhere = OccupancyMap.from_points(np.array([[2.0, 2.0, 2.0]]), 0.01)
    stop = threading.Event()

    def swapper():
        while not stop.is_set():
            world.set_occupancy(blocking)
            world.set_occupancy(elsewhere)

    t = threading.Thread(target=swapper)
    t.start()
    try:
        verdicts = [checker.check(q) for _ in range(300)]
    finally:
        stop.set()
        t.join()
    kinds = {None if c is None else c.kind for c in verdicts}
    assert kinds <= {None, "octree"}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_octomap_writer_is_byte_identical_to_octomap(seed):
    """Our numpy writer of OctoMap's binary stream against OctoMap itself (octomap-python)."""
    import octomap

    from replanner.world.occupancy import octomap_binary, octomap_payload

    rng = np.random.default_rng(seed)
    keys = np.unique(np.vstack([rng.integers(-300, 300, (2000, 3)), rng.integers(-5, 5, (500, 3))]), axis=0)
    tree = octomap.OcTree(0.01)
    tree.updateNodes(voxel_centers(keys, 0.01), True)
    assert octomap_binary(keys) == octomap_payload(tree.writeBinary()).tobytes()


def test_empty_map_has_no_tree_and_collides_with_nothing(panda):
    occ = OccupancyMap.empty()
    assert occ.tree is None and len(occ) == 0
    world = World(panda)
    world.set_occupancy(occ)
    assert CollisionChecker(panda, world).is_valid(panda.home)


def test_a_map_the_robot_is_far_from_never_builds_its_tree_and_one_it_meets_does(panda):
    """A planning job brings a new map each time; its FCL tree (milliseconds) is built only when a test needs it."""
    world = World(panda)
    far = OccupancyMap.from_points(np.random.default_rng(0).uniform([2.0, 2.0, 0.0], [2.3, 2.3, 0.3], (500, 3)), 0.01)
    world.set_occupancy(far)
    checker = CollisionChecker(panda, world)
    Q = np.linspace(panda.home, panda.home + 0.3, 50)
    assert checker.is_valid_batch(Q).all() and checker.clearance(panda.home).distance > 0.5
    assert not far.has_tree  # nothing came within a cell of it
    p = panda.link_pose(panda.home, "panda_hand")[:3, 3]
    near = OccupancyMap.from_points(p + np.random.default_rng(1).uniform(-0.03, 0.03, (500, 3)), 0.01)
    world.set_occupancy(near)
    contact = checker.check(panda.home)
    assert near.has_tree and contact is not None and contact.kind == "octree"
