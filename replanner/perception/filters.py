"""Point cloud filters: range, workspace crop, voxel grid, robot self-filter, outliers.

Everything after the crop works on voxels of one dense, workspace-aligned grid, so de-duplication and
neighbour counts are scatters and gathers into a boolean array instead of sorts and KD-tree queries.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..world.geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from ..world.scene import WorldSnapshot


def finite_in_range(rows: np.ndarray, origin, min_range: float, max_range: float) -> np.ndarray:
    """Mask of points (rows x, y, z: (3, N)) that are finite and within [min_range, max_range] [m] of `origin`."""
    with np.errstate(invalid="ignore"):
        r2 = (rows[0] - origin[0]) ** 2
        r2 += (rows[1] - origin[1]) ** 2
        r2 += (rows[2] - origin[2]) ** 2
        return (r2 >= min_range * min_range) & (r2 <= max_range * max_range)  # NaN fails both


class VoxelGrid:
    """A dense grid over the workspace box, aligned with OctoMap's voxels (voxel i covers [i*res, (i+1)*res)).

    It has one empty margin cell on every side so that neighbour offsets never leave the array.
    """

    def __init__(self, lo, hi, resolution: float):
        self.resolution = float(resolution)
        self.key_lo = np.floor(np.asarray(lo, dtype=float) / resolution).astype(np.int64) - 1
        key_hi = np.floor(np.asarray(hi, dtype=float) / resolution).astype(np.int64) + 1
        self.shape = tuple(int(n) for n in key_hi - self.key_lo + 1)
        nx, ny, nz = self.shape
        self.strides = np.array([ny * nz, nz, 1], dtype=np.int64)
        self.size = nx * ny * nz
        # inner box: points here map to non-margin cells
        self.lo = (self.key_lo + 1) * resolution
        self.hi = (key_hi - 1 + 1) * resolution - 1e-9
        self._scratch = np.full(self.size, False)  # written now, so no page faults mid-frame
        offsets = [
            (dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1) if (dx, dy, dz) != (0, 0, 0)
        ]
        self.neighbour_offsets = np.array(offsets, dtype=np.int64) @ self.strides

    def flat(self, points: np.ndarray) -> np.ndarray:
        """Flat cell index of points (N, 3) inside the workspace (callers crop first)."""
        return self.flat_rows(np.ascontiguousarray(np.asarray(points).T))

    def flat_rows(self, rows: np.ndarray) -> np.ndarray:
        """Flat cell index of points given as rows x, y, z (3, N), inside the workspace."""
        inv = 1.0 / self.resolution
        # inside the workspace every coordinate is above the grid's corner, so truncation is floor
        corner = self.key_lo * self.resolution
        out = ((rows[0] - corner[0]) * inv).astype(np.int64) * self.strides[0]
        out += ((rows[1] - corner[1]) * inv).astype(np.int64) * self.strides[1]
        out += ((rows[2] - corner[2]) * inv).astype(np.int64)
        return out

    def keys(self, flat: np.ndarray) -> np.ndarray:
        """Integer OctoMap-grid voxel keys (N, 3) of flat indices."""
        nx, ny, nz = self.shape
        ix, rem = np.divmod(flat, ny * nz)
        iy, iz = np.divmod(rem, nz)
        return np.stack([ix, iy, iz], axis=1) + self.key_lo

    def centers(self, flat: np.ndarray) -> np.ndarray:
        return (self.keys(flat) + 0.5) * self.resolution

    def unique(self, flat: np.ndarray) -> np.ndarray:
        """Sorted unique flat indices (a scatter into a boolean grid: no sort of N points)."""
        s = self._scratch
        s[flat] = True
        lo, hi = int(flat.min()), int(flat.max()) + 1
        out = np.flatnonzero(s[lo:hi]) + lo
        s[out] = False
        return out

    def neighbour_counts(self, flat: np.ndarray) -> np.ndarray:
        """For each of the given (unique) cells, how many of its 26 neighbours are among them."""
        s = self._scratch
        s[flat] = True
        count = np.zeros(len(flat), dtype=np.int64)
        for off in self.neighbour_offsets:
            count += s[flat + off]
        s[flat] = False
        return count


def statistical_outliers(centers: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    """Keep mask of PCL's statistical outlier removal: mean distance to k neighbours <= mean + ratio * std."""
    if len(centers) <= k:
        return np.ones(len(centers), dtype=bool)
    d, _ = cKDTree(centers).query(centers, k + 1, workers=-1)
    mean = d[:, 1:].mean(axis=1)
    return mean <= mean.mean() + std_ratio * mean.std()


# --------------------------------------------------------------------------------------------- self filter
N_DIRECTIONS = 42  # rows of the sphere directions, last in every constraint matrix


@lru_cache(maxsize=1)
def _sphere_directions() -> np.ndarray:
    return np.asarray(trimesh.creation.icosphere(subdivisions=1).vertices)  # 42 directions, ~30 deg apart


@lru_cache(maxsize=512)
def _support_constraints(shape: Shape) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(D, h, lo, hi): shape ⊂ {x : D x <= h}; with h + p it contains every point within p of the shape.

    D holds the hull's distinct face normals (exact on faces) and 42 sphere directions (at most ~5 % of the
    padding too far out at edges and corners; every row costs time on every frame). lo, hi: the shape's box.
    """
    if isinstance(shape, Sphere):
        D = _sphere_directions()
        return D, np.full(len(D), shape.radius), -np.full(3, shape.radius), np.full(3, shape.radius)
    if isinstance(shape, Box):
        h = np.asarray(shape.size) / 2
        verts = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
    elif isinstance(shape, Cylinder):
        a = np.linspace(0, 2 * np.pi, 32, endpoint=False)
        r = shape.radius / np.cos(np.pi / 32)  # circumscribed polygon: never smaller than the cylinder
        ring = np.column_stack([r * np.cos(a), r * np.sin(a)])
        verts = np.vstack([np.column_stack([ring, np.full(32, z)]) for z in (-shape.length / 2, shape.length / 2)])
    elif isinstance(shape, ConvexHull | Mesh):
        verts = shape.vertices
    else:
        raise TypeError(f"no self-filter geometry for {type(shape).__name__}")
    hull = trimesh.convex.convex_hull(verts)
    normals = np.unique(np.round(hull.face_normals, 6), axis=0)  # a mesh's coplanar triangles: one row
    D = np.vstack([normals / np.linalg.norm(normals, axis=1, keepdims=True), _sphere_directions()])
    h = (D @ np.asarray(hull.vertices).T).max(axis=1)
    return D, h, verts.min(axis=0), verts.max(axis=0)


class SelfFilter:
    """Removes points on the robot and what it carries (within `padding` [m]) at a configuration, and points on
    the world's known static objects (within `static_padding` [m]; None keeps them).
    """

    def __init__(self, robot, padding: float, static_padding: float | None = 0.01):
        self.robot = robot
        self.padding = float(padding)
        self.static_padding = static_padding

    def _bodies(self, q: np.ndarray, snapshot: WorldSnapshot | None):
        """(pose, shape, padding) of everything whose points are not obstacles; known objects first (the
        table takes most points, and each later body only tests the points still kept)."""
        r = self.robot
        if snapshot is not None and self.static_padding is not None:
            for o in snapshot.objects.values():
                yield o.pose, o.shape, self.static_padding
        frames = r.frames(np.asarray(q, dtype=float)[None])[0]

        def pose(link, T_link_body):
            slot, T_frame_link = r.frame_offset(link)
            return frames[slot] @ T_frame_link @ T_link_body

        for b in r.bodies:
            yield pose(b.link, b.T_link_body), b.shape, self.padding
        if snapshot is not None:
            for a in snapshot.attachments.values():
                yield pose(a.link, a.T_link_object), a.shape, self.padding

    def keep_mask(self, points: np.ndarray, q: np.ndarray, snapshot: WorldSnapshot | None = None) -> np.ndarray:
        """True for points (N, 3) in the base frame that are neither the robot's at q nor a known object's."""
        keep = np.ones(len(points), dtype=bool)
        rows = np.ascontiguousarray(points.T, dtype=np.float32)
        homog = np.vstack([rows, np.ones((1, len(points)), np.float32)])
        for T, shape, pad in self._bodies(q, snapshot):
            Dh, lo, hi = _padded_constraints(shape, pad)
            R, t = T[:3, :3], T[:3, 3]
            # world box of the padded body first, then the support test: max_k (D_k x_local - h_k - pad) <= 0
            c, e = (lo + hi) / 2, (hi - lo) / 2 + pad
            wlo, whi = R @ c + t - np.abs(R) @ e, R @ c + t + np.abs(R) @ e
            box = keep.copy()
            for axis in range(3):
                box &= (rows[axis] >= wlo[axis]) & (rows[axis] <= whi[axis])
            near = np.flatnonzero(box)
            if not len(near):
                continue
            T_inv = np.eye(4)
            T_inv[:3, :3], T_inv[:3, 3] = R.T, -R.T @ t
            if isinstance(shape, Box):  # a box grown by pad along its axes (a little more at the corners)
                local = (T_inv[:3, :3] @ rows[:, near]).T + T_inv[:3, 3]
                inside = np.all(np.abs(local - c) <= e, axis=1)
                keep[near[inside]] = False
                continue
            M = (Dh @ T_inv).astype(np.float32)  # constraints on base-frame points
            # the sphere directions alone bound a larger polytope: points outside it skip the face rows
            coarse = (M[-N_DIRECTIONS:] @ homog[:, near]).max(axis=0) <= 0.0
            near = near[coarse]
            if len(near) and len(M) > N_DIRECTIONS:
                near = near[(M[:-N_DIRECTIONS] @ homog[:, near]).max(axis=0) <= 0.0]
            keep[near] = False
        return keep


@lru_cache(maxsize=1024)
def _padded_constraints(shape: Shape, pad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows [D, -(h + pad)] (K, 4) of the support test in homogeneous form, and the shape's local box."""
    D, h, lo, hi = _support_constraints(shape)
    return np.hstack([D, -(h + pad)[:, None]]), lo, hi
