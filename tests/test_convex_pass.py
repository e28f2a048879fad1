"""The convex pass decides as FCL does: compiled GJK on the same padded shapes, FCL only for the band."""

from __future__ import annotations

import fcl
import numpy as np
import pytest

from replanner.bench.scenes import add_table, clutter_map, person_map
from replanner.collision.exact import CollisionChecker
from replanner.collision.fast.checker import FastChecker
from replanner.collision.fast.convex import ball_meets_cells, decide_batch
from replanner.collision.fast.gjk import APART, BAND, POINTS, TOUCH, decide
from replanner.collision.fast.layer import FREE, UNSURE
from replanner.collision.hulls import climb, edge_graph
from replanner.model.geometry import Box, ConvexHull, Cylinder, Sphere, padded, padding_directions, to_fcl
from replanner.model.transforms import make_transform
from replanner.world.scene import World
from replanner.world.volume import VoxelVolume


def test_gjk_says_apart_or_touching_as_fcl_does_on_random_shapes():
    rng = np.random.default_rng(11)
    ico = padding_directions()
    counts = {APART: 0, TOUCH: 0, BAND: 0}
    S, small = np.empty((4, 3)), np.empty(3)
    for i in range(3000):
        pts = rng.normal(size=(int(rng.integers(4, 40)), 3)) * rng.uniform(0.02, 0.15, 3)
        hull = ConvexHull.of_points(pts)
        pad = float(rng.choice([0.0, 0.002, 0.01]))
        Ta = make_transform(rng.uniform(-0.05, 0.05, 3), rng.normal(size=4))
        Tb = make_transform(rng.uniform(-0.35, 0.35, 3), rng.normal(size=4))
        kind = i % 3  # the sphere layer's numbers: box, ball, cylinder
        if kind == 0:
            prim = Box(size=tuple(rng.uniform(0.02, 0.4, 3)))
            dims = np.asarray(prim.size) / 2
        elif kind == 1:
            prim = Sphere(radius=float(rng.uniform(0.01, 0.2)))
            dims = np.array([prim.radius, 0.0, 0.0])
        else:
            prim = Cylinder(radius=float(rng.uniform(0.01, 0.1)), length=float(rng.uniform(0.05, 0.5)))
            dims = np.array([prim.radius, prim.length / 2, 0.0])
        V = np.ascontiguousarray(np.vstack([hull.vertices, ico]))
        nv = len(hull.vertices)
        first, nb, start = edge_graph([hull.vertices])
        a = fcl.CollisionObject(to_fcl(padded(hull, pad)), fcl.Transform(Ta[:3, :3], Ta[:3, 3]))
        b = fcl.CollisionObject(to_fcl(prim), fcl.Transform(Tb[:3, :3], Tb[:3, 3]))
        meets = fcl.collide(a, b, fcl.CollisionRequest(), fcl.CollisionResult())
        r = decide(
            POINTS, Ta[:3, :3], Ta[:3, 3], np.zeros(3), V, 0, nv, V, nv, len(V), pad,
            kind, np.ascontiguousarray(Tb[:3, :3]), np.ascontiguousarray(Tb[:3, 3]), dims, 0, 0, 0, 0, 0.0, 1e-6, S,
            small, first, nb, start.copy(), 0, -1,
        )  # fmt: skip
        counts[r] += 1
        assert not (r == APART and meets), (i, "apart for GJK, in contact for FCL")
        assert not (r == TOUCH and not meets), (i, "in contact for GJK, apart for FCL")
    assert counts[APART] > 500 and counts[TOUCH] > 500, counts
    assert counts[BAND] <= 3, counts  # only shapes within a micrometre of touching are left to FCL


def test_the_convex_pass_decides_what_the_spheres_cannot_as_fcl_does(profile):
    cfg, robot = profile
    rng = np.random.default_rng(8)
    world = World(robot)
    add_table(world)
    world.add("post", Cylinder(radius=0.05, length=0.8), make_transform((0.45, 0.35, 0.4), (0, 0, 0, 1)))
    world.add("ball", Sphere(radius=0.08), make_transform((0.3, -0.4, 0.6), (0, 0, 0, 1)))
    world.add("shelf", Box(size=(0.3, 0.6, 0.02)), make_transform((0.55, 0.0, 0.5), rng.normal(size=4)))
    tip = robot.bodies[-1].link
    world.attach_new("part", Box(size=(0.05, 0.05, 0.12)), tip, make_transform((0, 0, 0.1), (0, 0, 0, 1)))
    for padding in (0.002, cfg.collision.padding):
        for occ in (None, clutter_map(rng, 5_000)):
            world.set_occupancy(occ)
            checker = CollisionChecker(robot, world, padding=padding, path_resolution=cfg.collision.path_resolution,
                                       allowed_contacts=cfg.collision.allowed_contacts)  # fmt: skip
            fast = FastChecker(checker)
            Q = robot.random_q(rng, 4_000)
            c = fast.layers()
            layer, volume, convex = c.spheres, c.volume, c.convex
            frames = robot.frames(Q)
            unsure = np.flatnonzero(layer.classify(Q, volume) == UNSURE)
            verdict = decide_batch(convex, layer, frames, unsure, volume)
            valid = checker.is_valid_batch(Q[unsure])
            assert not np.any((verdict == FREE) & ~valid), "free for the pass, in contact for FCL"
            assert not np.any((verdict == -1) & valid), "in contact for the pass, free for FCL"
            if occ is None:  # without a map, the pass decides nearly all the spheres could not
                assert (verdict == 0).sum() <= 0.01 * len(unsure), ((verdict == 0).sum(), len(unsure))
            np.testing.assert_array_equal(fast.is_valid_batch(Q), checker.is_valid_batch(Q))


def test_a_support_climbed_along_hull_edges_is_the_farthest_point():
    """climb's answer against every point read, on random hulls of 4-400 points, flat, collinear and tiny sets
    included."""
    rng = np.random.default_rng(21)
    sets = [rng.normal(size=(int(rng.integers(4, 400)), 3)) * rng.uniform(0.005, 0.2, 3) for _ in range(60)]
    sets += [np.c_[rng.normal(size=(k, 2)), np.zeros(k)] for k in (20, 2000)]  # flat: hulled joggled
    sets += [np.c_[rng.normal(size=(50, 1)), np.zeros((50, 2))], np.zeros((1, 3)), rng.normal(size=(3, 3))]
    first, nb, start = edge_graph(sets)
    P = np.vstack(sets)
    assert len(nb) < 20 * len(P)  # a hull's edges, not every pair of a flat set's points
    offsets = np.cumsum([0] + [len(s) for s in sets])
    for i, pts in enumerate(sets):
        k = start[i]
        for d in rng.normal(size=(200, 3)):
            k, value = climb(P, first, nb, k, *d)  # from the last answer, as GJK and the broadphase climb
            assert offsets[i] <= k < offsets[i + 1]
            assert value == pytest.approx((pts @ d).max(), abs=1e-12)


def test_a_ball_meets_the_cells_exactly_where_a_voxel_lies_within_its_radius():
    """ball_meets_cells against every voxel's box, on sparse random maps: whole voxels exactly (a mutant that asks
    the ball's cube alone says yes at its corners), merged cells never a false no."""
    rng = np.random.default_rng(5)
    for merged in (False, True):
        keys = rng.integers(0, 40, (300, 3))
        res = 0.01
        vol = VoxelVolume(keys, res)
        if merged:  # a tiny cell budget merges voxels 3 x 3 x 3 (or more) into a cell
            VoxelVolume.MAX_CELLS, saved = 4000, VoxelVolume.MAX_CELLS
            try:
                vol = VoxelVolume(keys, res)
            finally:
                VoxelVolume.MAX_CELLS = saved
            assert not vol.whole
        else:
            assert vol.whole
        lo, hi = keys * res, (keys + 1) * res
        corners = 0
        for _ in range(3000):
            c, r = rng.uniform(-0.05, 0.45, 3), rng.uniform(0.002, 0.06)
            gap = np.linalg.norm(np.maximum(np.maximum(lo - c, c - hi), 0.0), axis=1).min()
            got = ball_meets_cells(vol.sat, vol.csat, vol.key_min, vol.inv_res, *c, r)
            if gap <= r - 1e-9:
                assert got, (c, r, gap)
            elif not merged and gap > r + 1e-9:
                assert not got, (c, r, gap)
            corners += gap > r and vol.count(c - r, c + r) > 0
        assert corners > 100  # the cube alone would have said yes this often


def test_the_map_near_a_person_is_decided_by_the_pass_as_fcl_does(panda, panda_cfg):
    """A person-sized column beside the arm and the demo's 4 cm map padding: of the configurations the spheres
    leave unsure, the pass decides most (free by its finer spheres, in contact by a ball inside a body), and says
    of none what FCL does not."""
    rng = np.random.default_rng(12)
    world = World(panda)
    add_table(world)
    world.set_occupancy(person_map((0.55, 0.25)))
    allowed = [("panda_link0", "table")]
    checker = CollisionChecker(panda, world, padding=0.01, map_padding=0.04, allowed_contacts=allowed)
    fast = FastChecker(checker)
    c = fast.layers()
    layer, volume, convex = c.spheres, c.volume, c.convex
    Q = panda.random_q(rng, 6000)
    unsure = np.flatnonzero(layer.classify(Q, volume) == UNSURE)
    verdict = decide_batch(convex, layer, panda.frames(Q), unsure, volume)
    valid = checker.is_valid_batch(Q[unsure])
    assert not np.any((verdict == FREE) & ~valid), "free for the pass, in contact for FCL"
    assert not np.any((verdict == -1) & valid), "in contact for the pass, free for FCL"
    counts = ((verdict == FREE).sum(), (verdict == -1).sum(), (verdict == 0).sum(), len(unsure))
    # without the finer spheres (the cubes of the cover's asking the map): 289 free, 1197 in contact, 630 left to
    # FCL of 2116; without the inner balls' look at the map: 891 in contact, 787 left to FCL
    assert len(unsure) > 500 and counts[0] > 0.17 * len(unsure) and counts[1] > 0.5 * len(unsure), counts
    assert counts[2] < 0.22 * len(unsure), counts
