"""Seeded scenes shared by benchmarks and tests."""

from __future__ import annotations

import numpy as np
import trimesh

from ..geometry import Box
from ..occupancy import OccupancyMap, voxel_keys
from ..transforms import make_transform
from ..world import World

TABLE_SIZE = (1.6, 1.4, 0.05)


def add_table(world: World, name: str = "table", top_z: float = 0.0, center_xy=(0.3, 0.0)) -> None:
    """A table whose top surface is at `top_z` [m], under and around the robot base."""
    world.add(name, Box(TABLE_SIZE), make_transform((center_xy[0], center_xy[1], top_z - TABLE_SIZE[2] / 2)))


def clutter_voxels(rng: np.random.Generator, target: int, resolution: float = 0.01) -> np.ndarray:
    """Integer voxel keys (~target of them) of surfaces a depth camera would see around a robot at the origin.

    A back wall, a person-sized pair of capsules (torso, arm) and random boxes and cylinders on the table;
    surfaces only, as a camera sees them.
    """
    meshes = [
        trimesh.creation.box(extents=(0.02, 1.6, 1.2), transform=make_transform((-0.75, 0.0, 0.6))),
        trimesh.creation.capsule(height=0.7, radius=0.18, transform=make_transform((0.55, 0.75, 0.55))),
        trimesh.creation.capsule(
            height=0.5, radius=0.05, transform=make_transform((0.55, 0.45, 0.9), (0.7071, 0.0, 0.0, 0.7071))
        ),
    ]
    keys = np.zeros((0, 3), np.int64)
    while True:
        pts = np.concatenate(
            [trimesh.sample.sample_surface_even(m, 40000, seed=int(rng.integers(2**31)))[0] for m in meshes]
        )
        keys = np.unique(np.concatenate([keys, voxel_keys(pts, resolution)]), axis=0)
        if len(keys) >= target:
            break
        # more clutter on the table until the target count is reached
        size = rng.uniform(0.05, 0.3, 3)
        pos = (rng.uniform(0.3, 0.8) * rng.choice([-1, 1]), rng.uniform(-0.6, 0.6), size[2] / 2)
        if rng.random() < 0.5:
            meshes.append(trimesh.creation.box(extents=size, transform=make_transform(pos)))
        else:
            meshes.append(trimesh.creation.cylinder(radius=size[0] / 2, height=size[2], transform=make_transform(pos)))
    return keys[rng.permutation(len(keys))[:target]]


def clutter_map(rng: np.random.Generator, target: int = 50_000, resolution: float = 0.01, **kw) -> OccupancyMap:
    return OccupancyMap(clutter_voxels(rng, target, resolution), resolution, **kw)
