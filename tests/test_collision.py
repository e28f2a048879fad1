"""Collision verdicts, distances and path checks against pybullet and against brute-force FCL."""

from __future__ import annotations

import fcl
import numpy as np
import pytest

from replanner.bench.scenes import add_table, clutter_map
from replanner.collision.boxes import boxes_apart
from replanner.collision.broadphase import hull_apart
from replanner.collision.exact import OCTREE, CollisionChecker
from replanner.collision.hulls import edge_graph
from replanner.collision.scene import CollisionScene
from replanner.collision.selfclearance import clearance_tables
from replanner.errors import InvalidInputError
from replanner.model.geometry import Box, Cylinder, Sphere, padded_geometry, padded_vertices, to_fcl
from replanner.model.transforms import make_transform
from replanner.world.occupancy import OccupancyMap
from replanner.world.scene import World
from tests.oracle import HULL_MARGIN, PyBulletOracle

PANDA_FOLDED = [0.0, 0.18, 0.02, -3.03, -0.63, 0.15, 0.8]  # elbow folded: the hand is inside link 1/2


def _random_boxes(rng, k):
    for i in range(k):
        size = tuple(rng.uniform(0.05, 0.3, 3))
        pose = make_transform(rng.uniform([-0.7, -0.7, 0.0], [0.8, 0.7, 1.0]), rng.normal(size=4))
        yield f"box{i}", Box(size=size), pose


def test_pybullet_hull_margin_is_what_the_oracle_assumes(panda):
    """FCL distance between the model's hulls minus pybullet's distance: pybullet's 1 mm margin per hull."""
    oracle = PyBulletOracle(panda)
    box, pose = Box(size=(0.2, 0.2, 0.2)), make_transform((0.5, 0.0, 0.4))
    body = oracle.add("b", box, pose)
    ref = fcl.CollisionObject(to_fcl(box), fcl.Transform(pose[:3, :3], pose[:3, 3]))
    import pybullet as pb

    diffs = []
    for q in panda.random_q(np.random.default_rng(0), 100):
        oracle.set_q(q)
        T = panda.fk(q)
        for b in panda.bodies:
            Tb = T[panda.link_index(b.link)] @ b.T_link_body
            obj = fcl.CollisionObject(to_fcl(b.shape), fcl.Transform(Tb[:3, :3], Tb[:3, 3]))
            d = fcl.distance(obj, ref, fcl.DistanceRequest())
            pts = pb.getClosestPoints(
                oracle.body, body, 0.3, linkIndexA=oracle.link_id[b.link], physicsClientId=oracle.cid
            )
            if pts and d > 0.002:
                diffs.append(d - min(c[8] for c in pts))
    oracle.close()
    diffs = np.array(diffs)
    assert len(diffs) > 100
    assert diffs.min() >= 0.0 and diffs.max() <= HULL_MARGIN * 1.1


def test_verdicts_agree_with_pybullet_over_2000_configurations(profile):
    cfg, robot = profile
    world = World(robot)
    add_table(world)
    checker = CollisionChecker.from_config(robot, world, cfg.collision)
    oracle = PyBulletOracle(robot)
    oracle.add("table", world.objects["table"].shape, world.objects["table"].pose)
    allowed = set(cfg.collision.allowed_contacts)
    pairs = sorted({(robot.bodies[a].link, robot.bodies[b].link) for a, b in robot.self_collision_pairs})
    rng = np.random.default_rng(11)
    n = unsafe = mismatch = invalid = 0
    for _scene in range(10):
        for name, shape, pose in _random_boxes(rng, 5):
            if name in world.objects:
                world.remove(name)
                import pybullet as pb

                pb.removeBody(oracle.obstacles.pop(name), physicsClientId=oracle.cid)
            world.add(name, shape, pose)
            oracle.add(name, shape, pose)
        for q in robot.random_q(rng, 200):
            oracle.set_q(q)
            ours_invalid = not checker.is_valid(q)
            d_world = oracle.min_world_distance(checker.padding + 0.02, allowed)
            d_self, _ = oracle.min_self_distance(pairs, robot.self_padding + 0.02)
            # pybullet's raw distances: any penetration there must be invalid here
            if not ours_invalid and (d_world < 0 or d_self < 0):
                unsafe += 1
            # same geometry, same thresholds: correct pybullet's hull margins
            ref_invalid = d_world + HULL_MARGIN < checker.padding or d_self + 2 * HULL_MARGIN < robot.self_padding
            mismatch += ours_invalid != ref_invalid
            invalid += ours_invalid
            n += 1
    oracle.close()
    print(
        f"{robot.name}: {n} configurations, {invalid} invalid, {mismatch} disagreements "
        f"({100 * mismatch / n:.2f} %), {unsafe} free-where-pybullet-penetrates"
    )
    assert n >= 2000
    assert 0.1 * n < invalid < 0.9 * n  # the scenes really test both outcomes
    assert unsafe == 0
    assert mismatch <= 0.01 * n


class _BruteForce:
    """Every pair through FCL, no broadphase, no tables: the reference for the checker's shortcuts.

    Built from public inputs only: the world's objects and attachments, the robot's self pairs, the checker's
    paddings and allowed contacts. Build it after the last world edit.
    """

    def __init__(self, checker: CollisionChecker):
        self.checker = checker
        robot, world = checker.robot, checker.world
        allowed = checker.allowed_contacts
        names, links, shapes, _ = checker.body_poses(robot.home)
        nr = len(robot.bodies)
        assert names[:nr] == tuple(b.link for b in robot.bodies)
        assert names[nr:] == tuple(f"attached:{a}" for a in world.attachments)
        self.env = [padded_geometry(s, checker.padding)[0] for s in shapes]
        self.map_ = [padded_geometry(s, checker.map_padding)[0] for s in shapes]
        self.own = [padded_geometry(s, robot.self_body_padding)[0] for s in shapes]
        obstacles = [
            (o.name, fcl.CollisionObject(to_fcl(o.shape), fcl.Transform(o.pose[:3, :3], o.pose[:3, 3])))
            for o in world.objects.values()
        ]
        occ = world.occupancy
        octree = None if occ is None or occ.tree is None else fcl.CollisionObject(occ.tree, fcl.Transform())
        self.env_tests, self.map_tests = [], []
        self.pairs = [tuple(p) for p in robot.self_collision_pairs]
        for bi, link in enumerate(links):
            att = world.attachments[names[bi].removeprefix("attached:")] if bi >= nr else None
            for oname, obj in obstacles:
                if (att is None and (link, oname) not in allowed) or (att is not None and oname not in att.support):
                    self.env_tests.append((bi, obj))
            if octree is not None and (att is not None or (link, OCTREE) not in allowed):
                self.map_tests.append((bi, octree))
            if att is not None:
                self.pairs += [(ri, bi) for ri in range(nr) if links[ri] not in att.touch_links and links[ri] != link]

    def invalid(self, q) -> bool:
        lim = self.checker.robot.limits
        if np.any(q < lim.lower) or np.any(q > lim.upper):
            return True
        tf = [fcl.Transform(T[:3, :3], T[:3, 3]) for T in self.checker.body_poses(q).poses]
        env, map_, own = (
            [fcl.CollisionObject(g, t) for g, t in zip(geoms, tf)] for geoms in (self.env, self.map_, self.own)
        )
        req = fcl.CollisionRequest()
        for objs, tests in ((env, self.env_tests), (map_, self.map_tests)):
            if any(fcl.collide(objs[bi], other, req) for bi, other in tests):
                return True
        return any(fcl.collide(own[a], own[b], req) for a, b in self.pairs)


def test_body_poses_are_the_links_fk_times_the_body_offsets(panda):
    world = World(panda)
    world.attach_new("part", Box(size=(0.06, 0.06, 0.12)), "panda_hand", make_transform((0, 0, 0.16)))
    checker = CollisionChecker(panda, world)
    Q = panda.random_q(np.random.default_rng(1), 6).reshape(2, 3, 7)
    bodies = checker.body_poses(Q)
    offsets = [b.T_link_body for b in panda.bodies] + [world.attachments["part"].T_link_object]
    assert bodies.names == (*(b.link for b in panda.bodies), "attached:part")
    assert bodies.links == (*(b.link for b in panda.bodies), "panda_hand")
    assert bodies.shapes == (*(b.shape for b in panda.bodies), world.attachments["part"].shape)
    assert bodies.poses.shape == (2, 3, len(offsets), 4, 4)
    T = panda.fk(Q)
    for bi, (link, off) in enumerate(zip(bodies.links, offsets)):
        np.testing.assert_allclose(bodies.poses[..., bi, :, :], T[..., panda.link_index(link), :, :] @ off, atol=1e-12)


def test_broadphase_and_tables_never_change_a_verdict_nor_does_splitting_it(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    rng = np.random.default_rng(5)
    for name, shape, pose in _random_boxes(rng, 4):
        world.add(name, shape, pose)
    world.attach_new("part", Box(size=(0.06, 0.06, 0.12)), "panda_hand", make_transform((0, 0, 0.16)))
    world.set_occupancy(clutter_map(rng, 20_000))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    Q = panda.random_q(rng, 1500)
    # half of them near the folded pose, where self pairs are close
    Q[::2] = np.clip(
        np.array(PANDA_FOLDED) + rng.normal(0, 0.25, (len(Q[::2]), 7)), panda.limits.lower, panda.limits.upper
    )
    batch = checker.is_valid_batch(Q)
    brute = _BruteForce(checker)
    ref = np.array([not brute.invalid(q) for q in Q])
    single = np.array([checker.is_valid(q) for q in Q])
    assert 0.1 < ref.mean() < 0.9
    np.testing.assert_array_equal(batch, ref)
    np.testing.assert_array_equal(single, ref)
    np.testing.assert_array_equal(checker.is_valid_batch(Q, split=True), ref)  # halves on two threads
    # a dense path's neighbours share their joined boxes' culling: it must skip only what each alone would
    P, _ = checker.interpolate(np.vstack([Q[1:12:2], Q[20]]), 0.01)
    ref = np.array([not brute.invalid(q) for q in P])
    assert len(P) > 200 and 0.1 < ref.mean() < 0.9
    np.testing.assert_array_equal(checker.is_valid_batch(P), ref)
    np.testing.assert_array_equal(checker.is_valid_batch(P, split=True), ref)


def test_a_new_maps_local_trees_give_its_whole_trees_verdicts(panda, panda_cfg):
    """A fresh map is checked against FCL trees of only the voxels near the bodies: the same verdicts as its whole
    tree (brute force), until local trees have cost half as much as its whole tree, and then with the whole tree."""
    rng = np.random.default_rng(8)
    world = World(panda)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    keys = clutter_map(rng, 30_000).keys
    Q = panda.random_q(rng, 400)
    for n in (1, 5, 40, 400):
        occ = OccupancyMap(keys, 0.01)
        world.set_occupancy(occ)
        got = checker.is_valid_batch(Q[:n])
        assert not occ.has_tree  # a fresh map's first check: a tree of the voxels near the bodies
        brute = _BruteForce(checker)  # its whole tree
        ref = np.array([not brute.invalid(q) for q in Q[:n]])
        np.testing.assert_array_equal(got, ref)
    assert 0.2 < ref.mean() < 0.8
    occ = OccupancyMap(keys, 0.01)
    world.set_occupancy(occ)
    checked = 0
    while not occ.has_tree:  # one configuration at a time, as a goal's checks go: the whole tree comes, once
        assert checker.is_valid(Q[checked]) == ref[checked]
        checked += 1
    assert 1 < checked < 400


def test_a_batch_against_the_map_alone_sees_its_voxels_and_nothing_else(panda, panda_cfg):
    """is_valid_batch(octree_only=True): each configuration as is_valid(q, octree_only=True) says, blind to the
    table and to the robot's own links, which the full check still sees."""
    rng = np.random.default_rng(12)
    world = World(panda)
    add_table(world)
    world.set_occupancy(clutter_map(rng, 20_000))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    Q = panda.random_q(rng, 600)
    got = checker.is_valid_batch(Q, octree_only=True)
    np.testing.assert_array_equal(got, [checker.is_valid(q, octree_only=True) for q in Q])
    full = checker.is_valid_batch(Q)
    assert not (full & ~got).any() and 0 < got.mean() < 1
    assert (got & ~full).sum() > 20  # refused for the table or the links alone: not the map's
    world.set_occupancy(None)
    assert checker.is_valid_batch(Q, octree_only=True).all() and not checker.is_valid_batch(Q).all()


def test_the_tables_coarse_blocks_give_the_fine_tables_answers(profile):
    """A block's least clearance is asked before the grid point's: the same answer as the fine table alone."""
    _, robot = profile
    t = clearance_tables(robot)
    rng = np.random.default_rng(2)
    Q = robot.random_q(rng, 4000)
    Q[::2] = np.clip(Q[::2] * 0.2, robot.limits.lower, robot.limits.upper)  # near zero, where links are close
    fine = np.empty((len(Q), len(t)), bool)
    for p in range(len(t)):
        u0 = (Q[:, t.j0[p]] - t.lo0[p]) / t.step0[p]
        u1 = (Q[:, t.j1[p]] - t.lo1[p]) / t.step1[p] if t.two[p] else np.zeros(len(Q))
        i0, i1 = np.clip(np.rint(u0), 0, t.n0[p] - 1), np.clip(np.rint(u1), 0, t.n1[p] - 1)
        slack = np.abs(u0 - i0) * t.r0[p] * t.step0[p] + np.abs(u1 - i1) * t.r1[p] * t.step1[p]
        fine[:, p] = t.table[(i0 * t.n1[p] + i1 + t.offset[p]).astype(int)] <= slack
    np.testing.assert_array_equal(t.may_collide(Q), fine)
    assert 0 < fine.mean() < 1


def test_oriented_box_test_never_separates_boxes_fcl_finds_touching():
    """The broadphase's separating axis test against FCL's box-box verdict on random oriented boxes (many of them
    with parallel faces and edges, where a cross axis vanishes): it never calls apart two boxes that touch, and it
    does rule out most pairs whose world-aligned boxes overlap."""
    rng = np.random.default_rng(11)
    n = 4000
    quats = rng.normal(size=(2, n, 4))
    quats[:, ::4] = (0.0, 0.0, 0.0, 1.0)  # axis-aligned pairs: parallel edges on every axis
    half_a, half_b = rng.uniform(0.01, 0.3, (n, 3)), rng.uniform(0.01, 0.3, (n, 3))
    T = np.stack([make_transform(rng.uniform(-0.6, 0.6, 3), q) for q in quats[0]])[:, None]
    obs = np.stack([make_transform(rng.uniform(-0.6, 0.6, 3), q) for q in quats[1]])
    center = rng.uniform(-0.05, 0.05, (n, 3))
    meets = np.empty((1, 1, 1), bool)
    scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3))
    touching = apart_found = aligned_overlaps = 0
    for i in range(n):
        R, c = T[i, 0, :3, :3], T[i, 0, :3, :3] @ center[i] + T[i, 0, :3, 3]
        lo, hi = (c - np.abs(R) @ half_a[i])[None, None, None], (c + np.abs(R) @ half_a[i])[None, None, None]
        Ro, co = obs[i, :3, :3], obs[i, :3, 3]
        olo, ohi = (co - np.abs(Ro) @ half_b[i])[None], (co + np.abs(Ro) @ half_b[i])[None]
        meets[0, 0, 0] = not boxes_apart(T[i, 0], c, half_a[i], Ro.copy(), co.copy(), half_b[i], *scratch)
        a = fcl.CollisionObject(fcl.Box(*(2 * half_a[i])), fcl.Transform(R, c))
        b = fcl.CollisionObject(fcl.Box(*(2 * half_b[i])), fcl.Transform(Ro, co))
        hit = fcl.collide(a, b, fcl.CollisionRequest()) > 0
        assert meets[0, 0, 0] or not hit, i
        touching += hit
        overlap = bool(np.all(lo[0, 0, 0] <= ohi[0]) and np.all(hi[0, 0, 0] >= olo[0]))
        aligned_overlaps += overlap
        apart_found += overlap and not meets[0, 0, 0]
    assert touching > 0.1 * n
    assert apart_found > 0.2 * (aligned_overlaps - touching)  # the test is not the world-aligned one again


def test_the_hull_cull_never_parts_a_link_from_a_box_fcl_finds_touching(panda):
    """The broadphase's last test before FCL (the support of the padded hull FCL is given, on an obstacle box's axes)
    against FCL's own verdict on that hull and box, links at random poses around random boxes: it never parts a pair
    FCL finds touching, and it parts most pairs whose oriented boxes meet but FCL finds apart."""
    rng = np.random.default_rng(13)
    n = 3000
    scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3))
    touching = parted = boxes_meet_only = 0
    for i in range(n):
        body = panda.bodies[rng.integers(len(panda.bodies))]
        V = padded_vertices(body.shape, 0.01)
        geom, (c, h) = padded_geometry(body.shape, 0.01)
        T = make_transform(rng.uniform(-0.25, 0.25, 3), rng.normal(size=4))[None, None].copy()
        Ro = make_transform((0, 0, 0), rng.normal(size=4))[:3, :3].copy()
        half = rng.uniform(0.02, 0.3, 3)
        hit = fcl.collide(fcl.CollisionObject(geom, fcl.Transform(T[0, 0, :3, :3], T[0, 0, :3, 3])),
                          fcl.CollisionObject(fcl.Box(*(2 * half)), fcl.Transform(Ro, np.zeros(3))),
                          fcl.CollisionRequest()) > 0  # fmt: skip
        first, nb, start = edge_graph([V])
        hint = np.full((1, 6), start[0])
        apart = hull_apart(T, 0, 0, V, Ro, np.zeros(3), half, first, nb, hint)
        assert not (hit and apart), i
        touching += hit
        centre = T[0, 0, :3, :3] @ c + T[0, 0, :3, 3]
        if not hit and not boxes_apart(T[0, 0], centre, h, Ro, np.zeros(3), half, *scratch):
            boxes_meet_only += 1
            parted += apart
    assert touching > 0.2 * n and boxes_meet_only > 0.05 * n
    assert parted > 0.3 * boxes_meet_only  # the hull is tighter than its box


@pytest.mark.parametrize("robot", ["panda", "iiwa"])
def test_the_hull_cull_never_parts_two_links_fcl_finds_touching(robot, request):
    """The self pairs' last test before FCL (each body's padded hull, the one FCL is given, on the other body's box
    axes) against FCL's own verdict on the two hulls, at configurations near the robot's home and anywhere: it never
    parts a pair FCL finds touching, and it parts most pairs whose oriented boxes meet but FCL finds apart."""
    model = request.getfixturevalue(robot)
    scene = CollisionScene(model, World(model).snapshot(), padding=0.0, map_padding=0.0, allowed_contacts=frozenset())
    rng = np.random.default_rng(17)
    near_home = np.clip(model.home + rng.normal(0.0, 0.6, (1500, model.dof)), model.limits.lower, model.limits.upper)
    Q = np.concatenate([near_home, model.random_q(rng, 3000)])
    T = scene.body_poses(model.frames(Q))
    graph = (scene.own_edges, scene.own_nb)
    hint = np.repeat(scene.own_start[:, None], 6, axis=1)
    scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3))
    touching = boxes_meet_only = parted = 0
    for n in range(len(Q)):
        for a, b in zip(scene.box_a, scene.box_b):
            wa = T[n, a, :3, :3] @ scene.box_c[1, a] + T[n, a, :3, 3]
            wb = T[n, b, :3, :3] @ scene.box_c[1, b] + T[n, b, :3, 3]
            if boxes_apart(T[n, a], wa, scene.box_h[1, a], T[n, b, :3, :3].copy(), wb, scene.box_h[1, b], *scratch):
                continue
            Ta, Tb = T[n : n + 1].copy(), T[n : n + 1].copy()
            apart = hull_apart(Ta, 0, b, scene.own_v, T[n, a, :3, :3].copy(), wa, scene.box_h[1, a], *graph, hint)
            apart = apart or hull_apart(Tb, 0, a, scene.own_v, T[n, b, :3, :3].copy(), wb, scene.box_h[1, b], *graph,
                                        hint)  # fmt: skip
            ga, gb = (fcl.CollisionObject(scene.bodies[k].self_, fcl.Transform(T[n, k, :3, :3], T[n, k, :3, 3]))
                      for k in (a, b))  # fmt: skip
            hit = fcl.collide(ga, gb, fcl.CollisionRequest()) > 0
            assert not (hit and apart), (n, scene.names[a], scene.names[b])
            touching += hit
            boxes_meet_only += not hit
            parted += apart and not hit
    assert touching > 0 and boxes_meet_only > 100
    assert parted > 0.5 * boxes_meet_only  # the hulls are tighter than their boxes


def test_oriented_pair_test_never_separates_body_boxes_fcl_finds_touching():
    """The self pairs' separating axis test (two bodies' local boxes, off-centre, at random poses) against FCL's
    box-box verdict: it keeps every pair that touches and clears most pairs whose world-aligned boxes overlap."""
    rng = np.random.default_rng(12)
    n = 4000
    quats = rng.normal(size=(n, 2, 4))
    quats[::4, 1] = quats[::4, 0]  # parallel bodies: every cross axis vanishes
    half = rng.uniform(0.01, 0.3, (n, 2, 3))
    center = rng.uniform(-0.05, 0.05, (n, 2, 3))
    T = np.stack([[make_transform(rng.uniform(-0.4, 0.4, 3), q) for q in qq] for qq in quats])
    scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3))
    touching = apart_found = 0
    for i in range(n):
        mid = T[i, :, :3, :3] @ center[i][..., None] + T[i, :, :3, 3:]
        reach = np.abs(T[i, :, :3, :3]) @ half[i][..., None]
        lo = np.zeros((1, 2, 2, 3))
        hi = lo.copy()
        lo[0, 1], hi[0, 1] = (mid - reach)[..., 0], (mid + reach)[..., 0]  # the self group's world-aligned boxes
        keep = np.ones((1, 1), bool)
        keep[0, 0] = not boxes_apart(T[i, 0], mid[0, :, 0].copy(), half[i, 0], T[i, 1, :3, :3].copy(),
                                     mid[1, :, 0].copy(), half[i, 1], *scratch)  # fmt: skip
        a, b = (
            fcl.CollisionObject(
                fcl.Box(*(2 * half[i, k])),
                fcl.Transform(T[i, k, :3, :3], T[i, k, :3, :3] @ center[i, k] + T[i, k, :3, 3]),
            )
            for k in (0, 1)
        )
        hit = fcl.collide(a, b, fcl.CollisionRequest()) > 0
        assert keep[0, 0] or not hit, i
        touching += hit
        overlap = bool(np.all(lo[0, 1, 0] <= hi[0, 1, 1]) and np.all(hi[0, 1, 0] >= lo[0, 1, 1]))
        apart_found += overlap and not keep[0, 0]  # parted by the oriented test, not the world-aligned one
    assert touching > 0.1 * n and apart_found > 0.1 * n


def test_self_collision_folded_is_invalid_home_is_valid(profile):
    cfg, robot = profile
    checker = CollisionChecker.from_config(robot, World(robot), cfg.collision)
    oracle = PyBulletOracle(robot)
    pairs = sorted({(robot.bodies[a].link, robot.bodies[b].link) for a, b in robot.self_collision_pairs})
    assert checker.check(robot.home) is None
    oracle.set_q(robot.home)
    assert oracle.min_self_distance(pairs, 0.05)[0] > 0
    folded = PANDA_FOLDED if robot.name == "panda" else [-0.55, 2.08, 0.01, -2.09, 1.13, -1.56, 0.52]
    contact = checker.check(folded)
    assert contact is not None and contact.kind == "self", contact
    oracle.set_q(folded)
    d, who = oracle.min_self_distance(pairs, 0.05)
    oracle.close()
    assert d < -0.01, (d, who)  # pybullet agrees: the arm penetrates itself


def test_attached_box_moves_with_the_hand_and_hits_the_table(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    q_high = panda.home.copy()  # the hand points down, the grasp point ~0.48 m above the table
    assert panda.link_pose(q_high, "panda_grasptarget")[2, 3] > 0.4
    part = Box(size=(0.05, 0.05, 0.30))  # a long part held in the gripper, sticking out 0.2 m below the fingertips
    world.add("part", part, panda.link_pose(q_high, "panda_grasptarget") @ make_transform((0, 0, 0.1)))
    world.attach("part", "panda_grasptarget", q_high)
    assert checker.check(q_high) is None  # held between the fingers: the hand may touch it
    # lower the grasp point straight down (resolved rate) until the part, not the hand, reaches the table
    robot_only = CollisionChecker.from_config(panda, _without(world, "part"), panda_cfg.collision)
    q, lowered = q_high.copy(), None
    for _ in range(60):
        J = panda.jacobian(q, "panda_grasptarget")
        q = q + np.linalg.pinv(J) @ np.array([0, 0, -0.01, 0, 0, 0])
        if robot_only.is_valid(q) and not checker.is_valid(q):
            lowered = q
            break
    assert lowered is not None
    contact = checker.check(lowered)
    assert contact.kind == "world" and contact.body == "attached:part" and contact.other == "table"
    # the part followed the hand: pybullet puts a box at the same place and finds it in the table
    oracle = PyBulletOracle(panda)
    table = oracle.add("table", world.objects["table"].shape, world.objects["table"].pose)
    att = world.attachments["part"]
    pose = panda.link_pose(lowered, att.link) @ att.T_link_object
    box = oracle.add("part", part, pose)
    assert oracle.distance_between(box, table) < checker.padding
    oracle.close()
    world.detach("part", lowered)
    np.testing.assert_allclose(world.objects["part"].pose, pose, atol=1e-12)


def _without(world: World, name: str) -> World:
    copy = World(world.robot)
    for obj in world.objects.values():
        copy.add(obj.name, obj.shape, obj.pose)
    for att in world.attachments.values():
        if att.name != name:
            copy.attach_new(att.name, att.shape, att.link, att.T_link_object, att.touch_links)
    return copy


def test_path_check_finds_an_obstacle_between_far_apart_waypoints(panda, panda_cfg):
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    a = np.array([-1.5, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
    b = a.copy()
    b[0] = 1.5  # a 3 rad swing of the first joint
    assert checker.is_valid(a) and checker.is_valid(b)
    assert checker.check_path([a, b]).valid
    # a thin pillar on the arc swept by the hand, between the two ends
    tip = panda.link_pose(np.where(np.arange(7) == 0, 0.2, a), "panda_hand")[:3, 3]
    world.add("pillar", Cylinder(radius=0.02, length=1.0), make_transform((tip[0], tip[1], 0.5)))
    assert checker.is_valid(a) and checker.is_valid(b)
    result = checker.check_path([a, b])
    assert not result.valid
    assert result.segment == 0 and 0.0 < result.fraction < 1.0
    assert result.contact.other == "pillar"
    assert not checker.is_valid(result.q)
    # the reported point is the first one: a bit earlier on the segment is free
    earlier = a + (result.fraction - 0.01) * (b - a)
    assert checker.is_valid(earlier)


def test_interpolation_bounds_the_motion_of_every_robot_point(profile):
    """Between two samples no point of any body (an attached part included) travels farther than the resolution
    along its way (what a padding of half the resolution relies on), on short and long segments; and the bound is
    tight enough to matter: the farthest-moving point's travel per step averages over half the resolution (the
    arm's longest reach gives ~0.3)."""
    _, robot = profile
    world = World(robot)
    world.attach_new("part", Box(size=(0.05, 0.05, 0.3)), robot.link_names[-1], make_transform((0.1, 0, 0.2)))
    checker = CollisionChecker(robot, world, padding=0.0, path_resolution=0.02)
    rng = np.random.default_rng(9)
    a = robot.random_q(rng, 5)
    near = np.clip(a[-1] + rng.normal(0, 0.05, (4, robot.dof)), robot.limits.lower, robot.limits.upper)
    W = np.vstack([a, near, near[-1:]])  # long segments, short ones and a standstill
    Q, pos = checker.interpolate(W)
    assert np.all(np.diff(pos) >= 0) and pos[-1] == len(W) - 1 and np.all(np.isin(np.arange(len(W)), pos))
    sub = 8  # each step's way, sampled finely: a point's travel, not only the gap between its two ends
    f = np.arange(sub) / sub
    fine = np.vstack([(Q[:-1, None] + f[:, None] * (Q[1:] - Q[:-1])[:, None]).reshape(-1, robot.dof), Q[-1:]])
    bodies = checker.body_poses(fine)
    assert bodies.names[-1] == "attached:part"
    T = bodies.poses
    travel = np.zeros(len(Q) - 1)
    for bi, shape in enumerate(bodies.shapes):
        pts = shape.vertices if hasattr(shape, "vertices") else _box_corners(shape)
        world_pts = T[:, bi, :3, :3] @ pts.T + T[:, bi, :3, 3:4]  # the vertices bound every point's travel
        way = np.linalg.norm(np.diff(world_pts, axis=0), axis=1)
        travel = np.maximum(travel, way[: sub * (len(Q) - 1)].reshape(len(Q) - 1, sub, -1).sum(axis=1).max(axis=1))
    assert travel.max() <= 0.02
    moving = travel[np.diff(pos) > 0]
    assert moving.mean() > 0.5 * 0.02, moving.mean()
    for bad in (0.0, -0.01, float("nan"), "fine", True):
        with pytest.raises(InvalidInputError, match="resolution must be a positive number of metres"):
            checker.interpolate(W, bad)


def test_a_motions_travel_bound_covers_every_points_way(profile):
    """The bound a piece of a motion is sampled by: no vertex of any body (an attached part included) travels farther
    along its way, on pieces from 0.02 to 3 rad; and it is not far above the farthest vertex's way (median > 0.45)."""
    _, robot = profile
    world = World(robot)
    world.attach_new("part", Box(size=(0.05, 0.05, 0.3)), robot.link_names[-1], make_transform((0.1, 0, 0.2)))
    scene = CollisionScene(robot, world.snapshot(), padding=0.0, map_padding=0.0, allowed_contacts=frozenset())
    rng = np.random.default_rng(21)
    ratios = []
    for length in np.repeat([0.02, 0.1, 0.3, 1.0, 3.0], 40):
        a = robot.random_q(rng)
        b = np.clip(a + rng.normal(0, length / np.sqrt(robot.dof), robot.dof), robot.limits.lower, robot.limits.upper)
        T = scene.body_poses(robot.frames(a + np.linspace(0, 1, 401)[:, None] * (b - a)))
        way = 0.0
        for bi, shape in enumerate(scene.shapes):
            pts = shape.vertices if hasattr(shape, "vertices") else _box_corners(shape)
            world_pts = T[:, bi, :3, :3] @ pts.T + T[:, bi, :3, 3:4]
            way = max(way, np.linalg.norm(np.diff(world_pts, axis=0), axis=1).sum(axis=0).max())
        ratios.append(way / scene.sweep.travel(a, b))
    assert max(ratios) <= 1.0
    assert np.median(ratios) > 0.45, np.median(ratios)


def _box_corners(shape):
    h = np.asarray(shape.size) / 2
    return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h


def test_clearance_matches_pybullet(panda):
    world = World(panda)
    rng = np.random.default_rng(4)
    oracle = PyBulletOracle(panda)
    for name, shape, pose in _random_boxes(rng, 3):
        world.add(name, shape, pose)
        oracle.add(name, shape, pose)
    world.add("ball", Sphere(radius=0.08), make_transform((0.4, 0.3, 0.5)))
    oracle.add("ball", Sphere(radius=0.08), make_transform((0.4, 0.3, 0.5)))
    checker = CollisionChecker(panda, world, padding=0.0)
    checked = 0
    for q in panda.random_q(rng, 300):
        c = checker.clearance(q, max_distance=0.5)
        oracle.set_q(q)
        ref = oracle.min_world_distance(0.5)
        if ref >= 0.5 - 0.002 or ref < 0:
            continue
        assert c.distance == pytest.approx(ref + HULL_MARGIN, abs=HULL_MARGIN)
        # the nearest points are on the surfaces: the obstacle point is that far from the robot point
        assert np.linalg.norm(c.point_on_robot - c.point_on_obstacle) == pytest.approx(c.distance, abs=1e-6)
        checked += 1
    oracle.close()
    assert checked > 50


def test_clearance_reports_the_closest_link_and_the_octree(panda):
    world = World(panda)
    q = panda.home
    hand = panda.link_pose(q, "panda_hand")[:3, 3]
    # a blob of voxels 10 cm below the hand
    from replanner.world.occupancy import OccupancyMap

    pts = hand + np.array([0, 0, -0.20]) + np.random.default_rng(0).uniform(-0.02, 0.02, (200, 3))
    world.set_occupancy(OccupancyMap.from_points(pts, 0.01))
    checker = CollisionChecker(panda, world, padding=0.0)
    c = checker.clearance(q)
    assert c.obstacle == OCTREE
    assert c.body in ("panda_leftfinger", "panda_rightfinger", "panda_hand")
    assert 0.0 < c.distance < 0.15


def test_octree_contact_says_where_the_voxels_are(panda):
    from replanner.world.occupancy import OccupancyMap

    world = World(panda)
    q = panda.home
    hand = panda.link_pose(q, "panda_hand")[:3, 3]
    blob = hand + np.random.default_rng(1).uniform(-0.01, 0.01, (50, 3))
    world.set_occupancy(OccupancyMap.from_points(blob, 0.01))
    contact = CollisionChecker(panda, world, padding=0.0).check(q)
    assert contact is not None and contact.kind == "octree"
    assert np.linalg.norm(np.array(contact.near) - hand) < 0.05
    assert "near (" in str(contact)


def test_clearance_pruning_equals_brute_force(panda):
    """The octree distance skips bodies by a lower bound; the answer must equal FCL over every body."""
    world = World(panda)
    rng = np.random.default_rng(8)
    world.set_occupancy(clutter_map(rng, 8000))
    checker = CollisionChecker(panda, world, padding=0.0)
    octree = fcl.CollisionObject(world.occupancy.tree, fcl.Transform())
    for q in panda.random_q(rng, 40):
        got = checker.clearance(q, max_distance=1.0)
        bodies = checker.body_poses(q)
        ref = 1.0
        for shape, T in zip(bodies.shapes, bodies.poses):
            obj = fcl.CollisionObject(to_fcl(shape), fcl.Transform(T[:3, :3], T[:3, 3]))
            ref = min(ref, fcl.distance(obj, octree, fcl.DistanceRequest()))
        assert got.distance == pytest.approx(ref, abs=1e-9)
