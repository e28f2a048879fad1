"""Scenes shared by several test modules."""

from __future__ import annotations

import numpy as np

from replanner.model.geometry import Box
from replanner.model.transforms import make_transform
from replanner.world.occupancy import OccupancyMap

ARM_UP = np.array([0.0, 0.0, 0.0, -0.0698, 0.0, 0.3, 0.785])
ARM_FORWARD = np.array([0.0, 1.4, 0.0, -0.3, 0.0, 1.7, 0.785])  # reaching low, under the sleeve


def sleeve(robot, q=ARM_UP, gap: float = 0.03, t: float = 0.02, bottom: float = 0.62):
    """A closed sleeve around an upright arm, starting above its elbow: from q, the arm cannot bend out.

    Returns (name, shape, pose) boxes. With the arm at q inside, ARM_FORWARD is valid and unreachable.
    """
    T = robot.fk(q)
    pts = np.vstack(
        [
            b.shape.vertices @ (T[robot.link_index(b.link)] @ b.T_link_body)[:3, :3].T
            + (T[robot.link_index(b.link)] @ b.T_link_body)[:3, 3]
            for b in robot.bodies
        ]
    )
    lo, hi = pts.min(0), pts.max(0)
    top = hi[2] + gap
    mid, height = (bottom + top) / 2, top - bottom
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    wx, wy = hi[0] - lo[0] + 2 * gap, hi[1] - lo[1] + 2 * gap
    return [
        ("sleeve_px", Box(size=(t, wy + 2 * t, height)), make_transform((hi[0] + gap + t / 2, cy, mid))),
        ("sleeve_nx", Box(size=(t, wy + 2 * t, height)), make_transform((lo[0] - gap - t / 2, cy, mid))),
        ("sleeve_py", Box(size=(wx, t, height)), make_transform((cx, hi[1] + gap + t / 2, mid))),
        ("sleeve_ny", Box(size=(wx, t, height)), make_transform((cx, lo[1] - gap - t / 2, mid))),
        ("sleeve_lid", Box(size=(wx + 2 * t, wy + 2 * t, t)), make_transform((cx, cy, top + t / 2))),
    ]


def box_surface(center, size, res=0.01) -> OccupancyMap:
    """The voxels of a box's surface (edge `size` [m]) around `center`: an object the cameras see."""
    g = np.linspace(-size / 2, size / 2, int(size / 0.005) + 1)
    P = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return OccupancyMap.from_points(P[(np.abs(P) >= size / 2 - 1e-9).any(1)] + center, res)
