"""The sphere layer is conservative: what it calls free, FCL and pybullet call free too."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from replanner.bench.scenes import add_table, clutter_map
from replanner.collision.exact import CollisionChecker
from replanner.collision.fast.checker import FastChecker
from replanner.collision.fast.convex import decide_batch
from replanner.collision.fast.layer import CONTACT, FREE, UNSURE, ball_meets_box, primitive_distance
from replanner.collision.fast.spheres import cover, refine
from replanner.model.geometry import Box, Cylinder, Sphere, sample_surface
from replanner.model.transforms import make_transform
from replanner.world.occupancy import OccupancyMap
from replanner.world.scene import World
from replanner.world.volume import CBLOCK, VoxelVolume, map_box
from tests.oracle import HULL_MARGIN, PyBulletOracle


def _inside_any(pts: np.ndarray, sp) -> np.ndarray:
    d = np.linalg.norm(pts[:, None] - sp.center[None], axis=2) - sp.radius[None]
    return d.min(axis=1) <= 1e-9


def test_spheres_cover_every_point_of_every_body(profile):
    _, robot = profile
    rng = np.random.default_rng(3)
    shapes = [b.shape for b in robot.bodies] + [Box(size=(0.3, 0.05, 0.6)), Cylinder(radius=0.04, length=0.5)]
    for shape in shapes:
        sp = cover(shape)
        surface = sample_surface(shape, 4000, rng)
        w = rng.dirichlet(np.ones(len(surface)), size=500)  # points inside: mixtures of surface points
        assert _inside_any(surface, sp).all() and _inside_any(w @ surface, sp).all(), type(shape).__name__
        assert 0.0 <= sp.excess <= 0.06
        # the finer cover the map is looked at again with: a point in a sphere of the cover is in one of the fine
        # spheres listed under that sphere (only those are asked)
        rf, pts = refine(shape), np.vstack([surface, w @ surface])
        in_fine = np.linalg.norm(pts[:, None] - rf.center[None], axis=2) <= rf.radius[None] + 1e-9
        in_coarse = np.linalg.norm(pts[:, None] - sp.center[None], axis=2) <= sp.radius[None] + 1e-9
        for k in range(len(sp.radius)):
            listed = rf.index[rf.ptr[k] : rf.ptr[k + 1]]
            assert in_fine[in_coarse[:, k]][:, listed].any(axis=1).all(), (type(shape).__name__, k)
        assert len(rf.radius) > len(sp.radius) or len(sp.radius) == 1


def test_what_the_layer_calls_free_fcl_and_pybullet_call_free(profile):
    cfg, robot = profile
    rng = np.random.default_rng(5)
    world = World(robot)
    add_table(world)
    world.add("post", Cylinder(radius=0.05, length=0.8), make_transform((0.45, 0.35, 0.4), (0, 0, 0, 1)))
    world.add("ball", Sphere(radius=0.08), make_transform((0.3, -0.4, 0.6), (0, 0, 0, 1)))
    world.add("shelf", Box(size=(0.3, 0.6, 0.02)), make_transform((0.55, 0.0, 0.5), rng.normal(size=4)))
    occ = clutter_map(rng, 20_000)
    world.set_occupancy(occ)
    checker = CollisionChecker.from_config(robot, world, cfg.collision)
    fast = FastChecker(checker)
    Q = robot.random_q(rng, 10_000)
    layer, volume = fast.layers().spheres, fast.layers().volume
    verdict = layer.classify(Q, volume)
    np.testing.assert_array_equal(layer.classify(Q, volume, parallel=True), verdict)
    clear, certain = verdict == FREE, verdict == CONTACT
    valid = checker.is_valid_batch(Q)
    assert not np.any(clear & ~valid)  # never free where FCL finds a contact
    assert not np.any(certain & valid) and certain.sum() > 0.3 * (~valid).sum()  # most contacts need no FCL
    np.testing.assert_array_equal(fast.is_valid_batch(Q), valid)
    np.testing.assert_array_equal([fast.is_valid(q) for q in Q[:2000]], valid[:2000])  # the compiled call alone
    B = np.clip(Q[:300] + rng.normal(0, 0.2, (300, robot.dof)), robot.limits.lower, robot.limits.upper)
    B[::10, 0] = robot.limits.upper[0] + 0.1  # past a limit: refused whatever the spheres say
    res = cfg.collision.path_resolution
    motions = [fast.motion_valid(a, b, res) for a, b in zip(Q[:300], B)]
    assert motions == [checker.path_valid(np.array([a, b])) for a, b in zip(Q[:300], B)]
    assert 0 < sum(motions) < 300
    oracle = PyBulletOracle(robot)
    for name, o in world.objects.items():
        oracle.add(name, o.shape, o.pose)
    allowed = set(cfg.collision.allowed_contacts)
    pairs = sorted({(robot.bodies[a].link, robot.bodies[b].link) for a, b in robot.self_collision_pairs})
    misses = 0
    for q in Q[clear]:
        oracle.set_q(q)
        misses += oracle.min_world_distance(0.0, allowed) < 0 or oracle.min_self_distance(pairs, 0.0)[0] < 0
    for q in Q[certain][:300]:  # a certain contact is one for pybullet too (its hulls may differ by HULL_MARGIN)
        oracle.set_q(q)
        d = min(oracle.min_world_distance(0.01, allowed), oracle.min_self_distance(pairs, 0.01)[0])
        assert d <= HULL_MARGIN, (q, d)
    oracle.close()
    flagged_free = int((~clear & valid).sum())
    print(
        f"{robot.name}: {len(Q)} configurations, {int(clear.sum())} clear for the spheres, {int(valid.sum())} for FCL;"
        f" flagged but free: {flagged_free} ({100 * flagged_free / max(valid.sum(), 1):.1f} % of the free ones)"
    )
    assert misses == 0
    assert clear.sum() > 0.2 * valid.sum()  # the layer decides most free configurations itself
    assert pb.isConnected(oracle.cid) == 0


def _cluttered(profile, seed: int):
    """(robot, rng, FastChecker) of a table, a shelf, a post and 5,000 voxels of clutter."""
    cfg, robot = profile
    rng = np.random.default_rng(seed)
    world = World(robot)
    add_table(world)
    world.add("shelf", Box(size=(0.3, 0.6, 0.02)), make_transform((0.55, 0.0, 0.45), (0, 0, 0, 1)))
    world.add("post", Cylinder(radius=0.05, length=0.8), make_transform((0.45, 0.35, 0.4), (0, 0, 0, 1)))
    world.set_occupancy(clutter_map(rng, 5_000))
    return robot, rng, FastChecker(CollisionChecker.from_config(robot, world, cfg.collision))


def test_anchored_motion_checks_give_every_configurations_own_verdict(profile):
    """A motion's anchors, checked with a wider margin, clear their neighbours unchecked: the verdict and the
    configurations left to FCL must be those of checking each configuration on its own."""
    robot, rng, fast = _cluttered(profile, 11)
    anchored = fast.layers().motion
    each = anchored.with_ahead(0.0)
    A = robot.random_q(rng, 600)
    step = rng.normal(0, 1, A.shape) * rng.uniform(0.02, 0.6, (600, 1))
    B = np.clip(A + step, robot.limits.lower, robot.limits.upper)
    kinds = set()
    for a, b in zip(A, B):
        for res in (0.004, 0.02):
            v0, unsure0, Q0 = each(a, b, res)
            v, unsure, Q = anchored(a, b, res)
            assert v == v0 and np.array_equal(Q, Q0)
            if v0 == 1:
                assert sorted(unsure) == sorted(unsure0)
                kinds.add("free" if not len(unsure0) else "unsure")
            else:
                kinds.add("contact")
    assert kinds == {"free", "unsure", "contact"}  # every kind of verdict was compared


def test_a_motion_check_gives_the_layers_verdicts_on_its_configurations_every_eighth_first(profile):
    """The motion pass and `classify` run the same compiled loop: a motion is in contact when one of its
    configurations is, else it leaves to FCL exactly those `classify` calls unsure, every 8th configuration first."""
    cfg, robot = profile
    rng = np.random.default_rng(12)
    world = World(robot)
    add_table(world)
    world.add("post", Cylinder(radius=0.05, length=0.8), make_transform((0.45, 0.35, 0.4), (0, 0, 0, 1)))
    world.set_occupancy(clutter_map(rng, 5_000))
    fast = FastChecker(CollisionChecker.from_config(robot, world, cfg.collision))
    layer, volume = fast.layers().spheres, fast.layers().volume
    each = fast.layers().motion.with_ahead(0.0)
    A = robot.random_q(rng, 300)
    B = np.clip(A + rng.normal(0, 0.3, A.shape), robot.limits.lower, robot.limits.upper)
    kinds = set()
    for a, b in zip(A, B):
        v, unsure, Q = each(a, b, 0.01)
        steps = len(Q) - 1
        np.testing.assert_array_equal(Q, fast.interpolate(np.array([a, b]), 0.01)[0])  # FCL's path check's
        verdict = layer.classify(Q, volume)
        if (verdict == CONTACT).any():
            assert v == -1
            kinds.add("contact")
            continue
        order = [k for k in range(steps + 1) if k % 8 == 0] + [k for k in range(steps + 1) if k % 8]
        assert v == 1 and list(unsure) == [k for k in order if verdict[k] == UNSURE]
        kinds.add("unsure" if len(unsure) else "free")
    assert kinds == {"free", "unsure", "contact"}


def test_a_motion_from_ends_known_free_checks_only_what_lies_between(profile):
    """`given` ends (a planner's states found free before) are not asked again: the verdict and the configurations
    left unsure are those of the motion's other configurations, an end in contact included."""
    robot, rng, fast = _cluttered(profile, 17)
    layer, volume = fast.layers().spheres, fast.layers().volume
    each = fast.layers().motion.with_ahead(0.0)
    A = robot.random_q(rng, 400)
    step = np.repeat([0.3, 0.002], 200)[:, None]  # short motions: an end in contact, nothing between
    B = np.clip(A + rng.normal(0, 1, A.shape) * step, robot.limits.lower, robot.limits.upper)
    kinds = set()
    for a, b in zip(A, B):
        Q = each(a, b, 0.01)[2]
        steps = len(Q) - 1
        verdict = layer.classify(Q, volume)
        for given in (1, 2, 3):
            asked = np.ones(steps + 1, bool)
            asked[0], asked[-1] = not given & 1, not given & 2
            v, unsure, _ = each(a, b, 0.01, given)
            if (verdict[asked] == CONTACT).any():
                assert v == -1
                kinds.add("contact")
                continue
            order = [k for k in range(steps + 1) if k % 8 == 0] + [k for k in range(steps + 1) if k % 8]
            assert v == 1 and list(unsure) == [k for k in order if verdict[k] == UNSURE and asked[k]]
            kinds.add("an end in contact not asked" if (verdict == CONTACT).any() else "free or unsure")
        assert each(a, a, 0.0, 3)[0] == (-1 if verdict[0] == CONTACT else 1)  # a state check ignores `given`
    assert kinds == {"contact", "an end in contact not asked", "free or unsure"}


def test_a_motion_decided_in_one_call_is_the_spheres_then_the_convex_pass(profile):
    """`BoundMotion.decided` runs the convex pass inside the motion's compiled call: its verdict and the
    configurations it leaves to FCL are those of the sphere pass followed by `decide_batch`, call by call."""
    robot, rng, fast = _cluttered(profile, 13)
    c = fast.layers()
    motion, layer, volume, convex = c.motion, c.spheres, c.volume, c.convex
    A = robot.random_q(rng, 400)
    B = np.clip(A + rng.normal(0, 0.3, A.shape), robot.limits.lower, robot.limits.upper)
    kinds = set()
    for a, b in zip(A, B):
        v, rest = motion.decided(a, b, 0.01)
        v0, unsure, Q = motion(a, b, 0.01)
        if v0 < 0 or not len(unsure):
            assert (v, len(rest)) == (v0, 0)
            kinds.add("spheres")
            continue
        Q = Q[unsure]
        verdict = decide_batch(convex, layer, robot.frames(Q), np.arange(len(Q)), volume, stop=True)
        if (verdict == CONTACT).any():
            assert (v, len(rest)) == (-1, 0)
            kinds.add("convex contact")
        else:
            assert v == 1 and np.array_equal(rest, Q[verdict == UNSURE])
            kinds.add("convex free" if not len(rest) else "left to FCL")
    assert kinds == {"spheres", "convex contact", "convex free", "left to FCL"}


def test_the_coarse_blocks_never_hide_a_voxel_a_box_meets():
    """The map's two summed-volume tables: as numpy's cumulative sums build them, and against a brute count of
    the voxels (merged to the table's cells) that random boxes overlap, boxes reaching past the map included: the
    same count, 0 exactly when none. The box the layer looks at the map within holds every voxel."""
    rng = np.random.default_rng(11)
    for resolution, n_vox, spread in ((0.01, 3000, 60), (0.02, 4000, 300), (0.05, 40, 7)):
        keys = np.unique(rng.integers(-spread, spread, (n_vox, 3)) // [1, 2, 1] * [1, 2, 1], axis=0)
        vol = VoxelVolume(keys, resolution)
        cell = 1.0 / vol.inv_res
        cells = np.unique(keys // int(round(cell / resolution)), axis=0)
        grid = np.zeros(vol.sat.shape, np.int64)  # both tables as numpy's cumulative sums build them
        grid[tuple((cells - vol.key_min + 1).T)] = 1
        np.testing.assert_array_equal(vol.sat, grid.cumsum(0).cumsum(1).cumsum(2))
        blocks = np.zeros(vol.csat.shape, np.int64)
        np.add.at(blocks, tuple(((cells - vol.key_min) // CBLOCK + 1).T), 1)
        np.testing.assert_array_equal(vol.csat, blocks.cumsum(0).cumsum(1).cumsum(2))
        box = np.array(map_box(vol.sat, vol.key_min, vol.inv_res))  # every voxel a cell inside it
        assert (keys * resolution >= box[:3] + cell - 1e-9).all() and ((keys + 1) * resolution <= box[3:] - cell).all()
        zero = 0
        for _ in range(600):
            lo = rng.uniform(-1.3, 1.1, 3) * spread * resolution
            hi = lo + rng.uniform(0.0, 0.4, 3) * spread * resolution * rng.choice([0.05, 1.0])
            a, b = np.floor(lo / cell).astype(int), np.floor(hi / cell).astype(int)
            brute = int(((cells >= a) & (cells <= b)).all(axis=1).sum())
            assert vol.count(lo, hi) == brute, (resolution, lo, hi)
            zero += brute == 0
        assert 30 < zero < 570, (resolution, zero)  # both answers are asked for


def test_an_obstacles_world_box_never_parts_it_from_a_ball_that_meets_it(panda, panda_cfg):
    """The layer skips an obstacle whose world box misses a body ball's box: never one the ball meets."""
    rng = np.random.default_rng(8)
    world = World(panda)
    for k in range(12):
        shapes = [Box(size=tuple(rng.uniform(0.02, 0.5, 3))), Cylinder(radius=0.06, length=0.4), Sphere(radius=0.1)]
        shape = shapes[k % 3]
        world.add(f"o{k}", shape, make_transform(rng.uniform(-0.6, 0.6, 3), rng.normal(size=4)))
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    layer = FastChecker(checker).layers().spheres
    met = skipped = 0
    for _ in range(20_000):
        o, x, r = int(rng.integers(len(layer.ob_kind))), rng.uniform(-1.0, 1.0, 3), float(rng.uniform(0.0, 0.3))
        meets = primitive_distance(layer.ob_inv, o, layer.ob_kind[o], layer.ob_dim, *x) <= r
        boxed = ball_meets_box(layer.ob_box, o, *x, r)
        assert boxed or not meets, (o, x, r)
        met += meets
        skipped += not boxed
    assert met > 200 and skipped > 5000  # both answers are asked for


def test_one_voxel_on_the_arm_is_seen_and_an_empty_map_changes_no_verdict(panda, panda_cfg):
    """The layer skips the map's look when the map holds nothing: a single voxel on a body's surface still makes
    every layer refuse the configuration, as FCL does, and an empty map gives the verdicts of no map at all."""
    rng = np.random.default_rng(21)
    world = World(panda)
    add_table(world)
    checker = CollisionChecker.from_config(panda, world, panda_cfg.collision)
    fast = FastChecker(checker)
    Q = panda.random_q(rng, 3000)
    bare = fast.layers().spheres.classify(Q, fast.layers().volume)
    world.set_occupancy(OccupancyMap.empty(0.01))
    layer, volume = fast.layers().spheres, fast.layers().volume
    np.testing.assert_array_equal(layer.classify(Q, volume), bare)
    free = Q[checker.is_valid_batch(Q)][:40]
    assert len(free) == 40
    for k, q in enumerate(free):
        body = panda.bodies[k % len(panda.bodies)]
        T = panda.link_pose(q, body.link) @ body.T_link_body
        p = T[:3, :3] @ sample_surface(body.shape, 1, rng)[0] + T[:3, 3]
        world.set_occupancy(OccupancyMap.from_points(p[None], 0.01))
        layer, volume = fast.layers().spheres, fast.layers().volume
        assert not checker.is_valid(q), (k, body.link)
        assert layer.classify(q[None], volume)[0] != FREE, (k, body.link)
        assert not fast.is_valid(q) and not fast.is_valid_batch(q[None])[0], (k, body.link)
        assert not fast.motion_valid(q, q, 0.0), (k, body.link)
