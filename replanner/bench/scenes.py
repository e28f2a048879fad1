"""Seeded scenes shared by benchmarks and tests."""

from __future__ import annotations

import numpy as np
import trimesh

from ..model.geometry import Box
from ..model.transforms import make_transform
from ..world.occupancy import OccupancyMap, voxel_keys
from ..world.scene import World

TABLE_SIZE = (1.6, 1.4, 0.05)


def table(name: str = "table", top_z: float = 0.0, center_xy=(0.3, 0.0)) -> tuple[str, Box, np.ndarray]:
    """(name, shape, pose) of the benches' table: its top at `top_z` [m]."""
    return name, Box(size=TABLE_SIZE), make_transform((center_xy[0], center_xy[1], top_z - TABLE_SIZE[2] / 2))


def add_table(world: World, name: str = "table", top_z: float = 0.0, center_xy=(0.3, 0.0)) -> None:
    """A table whose top surface is at `top_z` [m], under and around the robot base."""
    world.add(*table(name, top_z, center_xy))


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


PERSON = (0.18, 1.75)  # [m] radius and height of the column `person_map` stands up: a co-worker's size


def person_map(xy, resolution: float = 0.01) -> OccupancyMap:
    """The surface of a person-sized column (PERSON) standing at xy [m] on the floor plane z = 0, as a fresh map:
    what a planning job brings of a co-worker beside the arm (~20,000 voxels at 1 cm)."""
    r, h = PERSON
    th, z = np.meshgrid(
        np.linspace(0.0, 2 * np.pi, int(4 * np.pi * r / resolution), endpoint=False),
        np.linspace(0.0, h, int(2 * h / resolution)),
    )  # two samples a voxel: no holes
    P = np.stack([xy[0] + r * np.cos(th), xy[1] + r * np.sin(th), z], axis=-1).reshape(-1, 3)
    return OccupancyMap.from_points(P, resolution)


def operator_boxes(t: float, start=(1.0, -0.95), end=(-0.2, -0.95), reach: float = 0.35) -> dict:
    """A person walking from `start` to `end` [m] (fraction t in [0, 1]) beside the table, reaching over it.

    Returns {name: (Box, pose)}: a torso and a forearm pointing `reach` [m] towards the table's centre line.
    """
    start, end = np.asarray(start, float), np.asarray(end, float)
    p = start + (end - start) * t
    d = (end - start) / max(np.linalg.norm(end - start), 1e-9)
    n = np.array([-d[1], d[0]])
    if n @ (np.array([0.3, 0.0]) - p) < 0:  # face the table
        n = -n
    yaw = np.arctan2(n[1], n[0])
    q = (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    arm = p + n * (0.15 + reach / 2)
    return {
        "operator_torso": (Box(size=(0.3, 0.45, 0.8)), make_transform((p[0], p[1], 0.75), q)),
        "operator_arm": (Box(size=(reach, 0.08, 0.08)), make_transform((arm[0], arm[1], 0.35), q)),
    }


def tabletop_clutter(rng: np.random.Generator, n: int = 3) -> dict[str, tuple[Box, np.ndarray]]:
    """Seeded boxes standing on the table, out of the robot's base area."""
    out = {}
    for i in range(n):
        size = tuple(rng.uniform(0.06, 0.2, 3))
        xy = (rng.uniform(0.35, 0.75), rng.uniform(-0.5, 0.5))
        out[f"clutter{i}"] = (
            Box(size=size),
            make_transform((xy[0], xy[1], size[2] / 2), (0, 0, np.sin(rng.uniform(0, 1.5)), 1)),
        )
    return out
