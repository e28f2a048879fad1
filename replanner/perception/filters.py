"""Point cloud filters: range, workspace crop, voxel grid, robot self-filter, outliers.

Everything after the crop works on voxels of one dense, workspace-aligned grid, so de-duplication and
neighbour counts are scatters and gathers into a boolean array instead of sorts and KD-tree queries.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..model.geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from ..world.scene import WorldSnapshot
from .kernels import cell_keys, mark_inside, neighbour_counts


def finite_in_range(rows: np.ndarray, origin, min_range: float, max_range: float) -> np.ndarray:
    """Mask of points (rows x, y, z: (3, N)) that are finite and within [min_range, max_range] [m] of `origin`."""
    with np.errstate(invalid="ignore"):
        r2 = (rows[0] - origin[0]) ** 2
        r2 += (rows[1] - origin[1]) ** 2
        r2 += (rows[2] - origin[2]) ** 2
        return (r2 >= min_range * min_range) & (r2 <= max_range * max_range)  # NaN fails both


def jump_edges(z: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of a depth image (H, W) whose depth differs from a 4-neighbour's by more than `jump` times their nearer
    depth, and the image with those pixels at the nearest depth around them. At a depth edge a pixel may return a mix
    of both sides (a point in mid-air), and both sides' edge pixels go, since which of them is mixed cannot be told;
    the ray of each is free up to the nearer side, which still clears what it passes."""
    near = z.copy()
    with np.errstate(invalid="ignore"):
        edge = np.zeros(z.shape, dtype=bool)
        dx = np.abs(z[:, 1:] - z[:, :-1]) > jump * np.fmin(z[:, 1:], z[:, :-1])
        dy = np.abs(z[1:] - z[:-1]) > jump * np.fmin(z[1:], z[:-1])
        np.fmin(near[:, 1:], z[:, :-1], out=near[:, 1:])
        np.fmin(near[:, :-1], z[:, 1:], out=near[:, :-1])
        np.fmin(near[1:], z[:-1], out=near[1:])
        np.fmin(near[:-1], z[1:], out=near[:-1])
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return edge, np.where(edge, near, z)


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
        self.scratch = np.full(self.size, False)  # all False between uses; written now: no page faults mid-frame
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
        return cell_keys(np.ascontiguousarray(flat, dtype=np.int64), self.shape[1], self.shape[2], self.key_lo)

    def centers(self, flat: np.ndarray) -> np.ndarray:
        return (self.keys(flat) + 0.5) * self.resolution

    def unique(self, flat: np.ndarray) -> np.ndarray:
        """Sorted unique flat indices (a scatter into a boolean grid: no sort of N points)."""
        s = self.scratch
        s[flat] = True
        lo, hi = int(flat.min()), int(flat.max()) + 1
        out = np.flatnonzero(s[lo:hi]) + lo
        s[out] = False
        return out

    def neighbour_counts(self, flat: np.ndarray) -> np.ndarray:
        """For each of the given (unique) cells, how many of its 26 neighbours are among them."""
        return neighbour_counts(np.ascontiguousarray(flat, dtype=np.int64), self.neighbour_offsets, self.scratch)


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

    def __init__(self, robot, padding: float, static_padding: float | None = 0.01, grid: VoxelGrid | None = None):
        self.robot = robot
        self.padding = float(padding)
        self.static_padding = static_padding
        # the robot's own bodies never change: their rows and link offsets are stacked once
        self._robot_bodies = _Stack([_padded_local(b.shape, self.padding) for b in robot.bodies])
        self._robot_slots = [robot.frame_offset(b.link)[0] for b in robot.bodies]
        self._robot_offsets = np.array([robot.frame_offset(b.link)[1] @ b.T_link_body for b in robot.bodies])
        # grid: the known objects are drawn into it once per scene version; then a cell's test is one lookup
        self.grid = grid
        self._drawn: dict[int, tuple[np.ndarray, list[np.ndarray]]] = {}
        self._cells: dict[tuple, np.ndarray] = {}
        # the scene now and as it was at a frame's stamp: a few versions at most; np.full touches every page now
        drawing = grid is not None and static_padding is not None
        self._free = [np.full(grid.size, False) for _ in range(4)] if drawing else []

    def keep_mask(
        self, points: np.ndarray, q: np.ndarray, snapshot: WorldSnapshot | None = None, cells: np.ndarray | None = None
    ) -> np.ndarray:
        """True for points (N, 3) in the base frame that are neither the robot's at q nor a known object's.

        cells: the points' flat cells in `grid` when the points are those cells' centres (the objects' test is
        then a lookup in the drawn grid, same verdicts).
        """
        r = self.robot
        frames = r.frames(np.asarray(q, dtype=float)[None])[0]
        keep = np.ones(len(points), dtype=bool)
        objects = [] if snapshot is None or self.static_padding is None else list(snapshot.objects.values())
        stacks, poses = [], []
        if objects and cells is not None and self.grid is not None:
            keep &= ~self._drawn_objects(snapshot)[cells]
        elif objects:  # known objects first: the table takes most points, later bodies test only what is kept
            stacks.append(_Stack([_padded_local(o.shape, float(self.static_padding)) for o in objects]))
            poses.append(np.array([o.pose for o in objects]))
        if self._robot_slots:
            stacks.append(self._robot_bodies)
            poses.append(frames[self._robot_slots] @ self._robot_offsets)
        carried = [] if snapshot is None else list(snapshot.attachments.values())
        if carried:
            stacks.append(_Stack([_padded_local(a.shape, self.padding) for a in carried]))
            offsets = [r.frame_offset(a.link) for a in carried]
            poses.append(np.array([frames[i] @ T @ a.T_link_object for (i, T), a in zip(offsets, carried)]))
        if poses:
            _mark(points, keep, _Stack.join(stacks) if len(stacks) > 1 else stacks[0], np.concatenate(poses))
        return keep

    def _drawn_objects(self, snapshot: WorldSnapshot) -> np.ndarray:
        """Boolean over the grid's cells: the centre lies in a padded known object (cached per scene version)."""
        hit = self._drawn.get(snapshot.version)
        if hit is not None:
            return hit[0]
        cells = [self._object_cells(o.shape, o.pose) for o in snapshot.objects.values()]
        if self._free:
            drawn = self._free.pop()
        else:
            drawn, old = self._drawn.pop(next(iter(self._drawn)))
            for c in old:
                drawn[c] = False  # reused: clearing what it held is cheaper than a new grid
        for c in cells:
            drawn[c] = True
        self._drawn[snapshot.version] = (drawn, cells)
        return drawn

    def _object_cells(self, shape: Shape, pose: np.ndarray) -> np.ndarray:
        """Flat cells whose centre lies in the padded object (cached per shape and pose: most objects stay put)."""
        key = (shape, pose.tobytes())
        hit = self._cells.get(key)
        if hit is not None:
            return hit
        g = self.grid
        st = _Stack([_padded_local(shape, float(self.static_padding))])
        T = pose[None]
        lo, hi = _world_box(st, T)
        a = np.clip(np.floor(lo[0] / g.resolution).astype(np.int64), g.key_lo + 1, None)
        b = np.clip(np.floor(hi[0] / g.resolution).astype(np.int64), None, g.key_lo + np.array(g.shape) - 2)
        flat = np.zeros(0, dtype=np.int64)
        if np.all(b >= a):
            axes = [np.arange(a[i], b[i] + 1) for i in range(3)]
            keys = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            inside = np.ones(len(keys), dtype=bool)
            _mark((keys + 0.5) * g.resolution, inside, st, T)
            flat = (keys[~inside] - g.key_lo) @ g.strides
        if len(self._cells) >= 256:
            self._cells.pop(next(iter(self._cells)))
        self._cells[key] = flat
        return flat


def _world_box(st: _Stack, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World boxes (B, 3) lo, hi of stacked bodies at poses T (B, 4, 4)."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    wc = np.einsum("bij,bj->bi", R, st.center) + t
    ext = np.einsum("bij,bj->bi", np.abs(R), st.extent)
    return wc - ext, wc + ext


def _mark(points: np.ndarray, keep: np.ndarray, st: _Stack, T: np.ndarray) -> None:
    """keep[i] = False for the points inside one of the stacked bodies at poses T (B, 4, 4)."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    lo, hi = _world_box(st, T)
    Rt = np.ascontiguousarray(R.transpose(0, 2, 1))
    inv = np.concatenate([Rt, -np.einsum("bij,bj->bi", Rt, t)[:, :, None]], axis=2)  # base → body (B, 3, 4)
    mark_inside(np.ascontiguousarray(points, dtype=np.float32), keep, lo, hi, inv, st.rows, st.starts)


class _Stack:
    """Bodies' local rows stacked for `mark_inside`: rows[starts[b]:starts[b + 1]] and the local box of body b."""

    def __init__(self, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]):
        self.rows = np.ascontiguousarray(np.vstack([p[0] for p in parts])) if parts else np.zeros((0, 4))
        self.starts = np.cumsum([0] + [len(p[0]) for p in parts]).astype(np.int64)
        self.center = np.array([p[1] for p in parts]).reshape(-1, 3)
        self.extent = np.array([p[2] for p in parts]).reshape(-1, 3)

    @classmethod
    def join(cls, stacks: list[_Stack]) -> _Stack:
        out = cls([])
        out.rows = np.ascontiguousarray(np.vstack([s.rows for s in stacks]))
        offsets = np.cumsum([0] + [s.starts[-1] for s in stacks[:-1]])
        out.starts = np.concatenate([stacks[0].starts[:1]] + [s.starts[1:] + o for s, o in zip(stacks, offsets)])
        out.center = np.vstack([s.center for s in stacks])
        out.extent = np.vstack([s.extent for s in stacks])
        return out


@lru_cache(maxsize=1024)
def _padded_local(shape: Shape, pad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (K, 4) of `shape` grown by `pad` in its own frame (a x + b y + c z + d <= 0 inside); the centre and
    half extent of its padded local box."""
    D, h, lo, hi = _support_constraints(shape)
    c, e = (lo + hi) / 2, (hi - lo) / 2 + pad
    if isinstance(shape, Box):  # a box grown by pad along its axes (a little more at the corners)
        eye = np.eye(3)
        return np.vstack([np.hstack([eye, -(c + e)[:, None]]), np.hstack([-eye, (c - e)[:, None]])]), c, e
    rows = np.hstack([D, -(h + pad)[:, None]])
    # the sphere directions alone bound a larger polytope: most points outside fail one of them first
    return np.vstack([rows[-N_DIRECTIONS:], rows[:-N_DIRECTIONS]]), c, e
