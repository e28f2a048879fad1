"""The GPU potential-field paper's virtual forces for whole-arm avoidance (its Algorithm 1) on two CPU cores.

The robot is a vertex model (points on each link's collision surface); the environment a voxel map made from a
depth cloud (points inside the bounds, the robot's own voxels removed, voxels with too few neighbours removed).
Every vertex r and voxel centre v closer than r_max push the link: F(d) = f_max (1 - |d| / r_max)^2 d / |d|,
d = r - v, a second-order polynomial of the distance. Per link n: f_n = sum F(d), m_n = sum (r - o_n) x F(d), the
moment of each push about the link's origin o_n (the paper writes F(d) x d_c with d_c measured from the
environment point; we take the moment where the force acts, on the vertex).

The sum is exact: voxels are bucketed in cells of r_max, each vertex visits the 27 cells around it (compiled,
parallel over vertices), no pair within r_max is missed; `brute_force` is the all-pairs float64 reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import trimesh

from ..model.robot import RobotModel


@dataclass(frozen=True)
class VertexModel:
    """Vertices (V, 3) in their link frames, the frame slot of each (V,) in `robot.frames`, and which link (of
    `links`) each belongs to."""

    local: np.ndarray
    slot: np.ndarray
    link: np.ndarray
    links: tuple[str, ...]

    @classmethod
    def from_robot(cls, robot: RobotModel, count: int, seed: int = 0) -> VertexModel:
        """`count` vertices spread evenly over the collision surfaces, each link's share by its area."""
        rng = np.random.default_rng(seed)
        meshes, links = [], []
        for b in robot.bodies:
            m = trimesh.Trimesh(b.shape.vertices, b.shape.faces, process=False)
            meshes.append((b, m))
            if b.link not in links:
                links.append(b.link)
        areas = np.array([m.area for _, m in meshes])
        share = np.floor(count * areas / areas.sum()).astype(int)
        share[np.argsort(-areas)[: count - share.sum()]] += 1  # the remainder to the largest
        local, slot, link = [], [], []
        for (b, m), n in zip(meshes, share):
            pts, _ = trimesh.sample.sample_surface(m, int(n), seed=int(rng.integers(1 << 31)))
            s, off = robot.frame_offset(b.link)
            T = off @ b.T_link_body
            local.append(pts @ T[:3, :3].T + T[:3, 3])
            slot.append(np.full(len(pts), s))
            link.append(np.full(len(pts), links.index(b.link)))
        return cls(np.vstack(local), np.concatenate(slot), np.concatenate(link), tuple(links))

    def __len__(self) -> int:
        return len(self.local)

    def place(self, robot: RobotModel, q) -> np.ndarray:
        """Vertices (V, 3) in the base frame at configuration q."""
        F = robot.frames(np.asarray(q, dtype=float)[None])[0][self.slot]
        return np.einsum("vij,vj->vi", F[:, :3, :3], self.local) + F[:, :3, 3]


class VoxelMapBuilder:
    """Algorithm 1's map: voxels of `size` [m] inside the bounds (lo, lo + extent), the robot's own voxels (those
    of its vertices, grown by `robot_margin` voxels) removed, voxels with fewer than `neighbours` occupied
    neighbours (of 26) removed as outliers."""

    def __init__(self, size: float, lo, extent, neighbours: int = 2, robot_margin: int = 1):
        self.size, self.lo = float(size), np.asarray(lo, dtype=float)
        self.n = np.ceil(np.asarray(extent, dtype=float) / self.size).astype(np.int64)
        self.neighbours, self.margin = int(neighbours), int(robot_margin)

    def _keys(self, pts: np.ndarray) -> np.ndarray:
        k = np.floor((pts - self.lo) / self.size).astype(np.int64)
        inside = np.all((k >= 0) & (k < self.n), axis=1)
        k = k[inside]
        return np.unique((k[:, 0] * self.n[1] + k[:, 1]) * self.n[2] + k[:, 2])

    def build(self, points: np.ndarray, robot_vertices: np.ndarray | None = None) -> np.ndarray:
        """Centres (M, 3) [m] of the occupied voxels of a cloud (base frame, NaN rows allowed)."""
        pts = points[np.all(np.isfinite(points), axis=1)]
        keys = self._keys(pts)
        if robot_vertices is not None and len(keys):
            own = self._keys(robot_vertices)
            if self.margin:
                own = _grow(own, self.n, self.margin)
            keys = keys[~np.isin(keys, own, assume_unique=False)]
        if self.neighbours and len(keys):
            keys = keys[_neighbour_counts(keys, self.n) >= self.neighbours]
        i, rest = np.divmod(keys, self.n[1] * self.n[2])
        j, k = np.divmod(rest, self.n[2])
        return self.lo + (np.stack([i, j, k], axis=1) + 0.5) * self.size


def _shifted(keys: np.ndarray, n: np.ndarray, r: int, centre: bool) -> np.ndarray:
    """Keys (K, O) of each key's neighbours within r voxels (its own too if `centre`); -1 where outside the bounds."""
    d = np.arange(-r, r + 1)
    o = np.array(np.meshgrid(d, d, d, indexing="ij")).reshape(3, -1).T
    if not centre:
        o = o[np.any(o != 0, axis=1)]
    i, rest = np.divmod(keys, n[1] * n[2])
    j, k = np.divmod(rest, n[2])
    ijk = np.stack([i, j, k], axis=1)[:, None, :] + o[None]
    ok = np.all((ijk >= 0) & (ijk < n), axis=2)
    return np.where(ok, (ijk[..., 0] * n[1] + ijk[..., 1]) * n[2] + ijk[..., 2], -1)


def _grow(keys: np.ndarray, n: np.ndarray, r: int) -> np.ndarray:
    grown = _shifted(keys, n, r, True).ravel()
    return np.unique(grown[grown >= 0])


def _neighbour_counts(keys: np.ndarray, n: np.ndarray) -> np.ndarray:
    cand = _shifted(keys, n, 1, False)
    pos = np.searchsorted(keys, cand).clip(0, len(keys) - 1)
    return ((keys[pos] == cand) & (cand >= 0)).sum(axis=1)


class ForceField:
    """Per-link virtual forces and moments (L, 6): [f; m] [N, N m] from the voxels within `r_max` [m] of the
    vertices, F(d) = f_max (1 - |d| / r_max)^2 along d = vertex - voxel."""

    def __init__(self, r_max: float = 0.3, f_max: float = 1.0):
        self.r_max, self.f_max = float(r_max), float(f_max)

    def compute(self, vertices: np.ndarray, link: np.ndarray, origins: np.ndarray, voxels: np.ndarray) -> np.ndarray:
        """vertices (V, 3) base frame, their link index (V,), each link's origin (L, 3), voxel centres (M, 3)."""
        L = len(origins)
        if not len(voxels) or not len(vertices):
            return np.zeros((L, 6))
        cell = self.r_max / CELLS_PER_R  # finer cells, culled by distance: fewer pairs tried beyond r_max
        lo = voxels.min(axis=0) - cell
        dims = np.floor((voxels.max(axis=0) + cell - lo) / cell).astype(np.int64) + 1
        ck = np.floor((voxels - lo) / cell).astype(np.int64)
        flat = (ck[:, 0] * dims[1] + ck[:, 1]) * dims[2] + ck[:, 2]
        order = np.argsort(flat, kind="stable")
        sorted_flat = flat[order]
        start = np.searchsorted(sorted_flat, np.arange(dims.prod() + 1))
        per_vertex = np.zeros((len(vertices), 6))
        _vertex_forces(
            np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(voxels[order], dtype=np.float64),
            start,
            lo,
            dims,
            cell,
            self.r_max,
            self.f_max,
            np.ascontiguousarray(origins[link], dtype=np.float64),
            per_vertex,
        )
        out = np.zeros((L, 6))
        np.add.at(out, link, per_vertex)
        return out


CELLS_PER_R = 2  # grid cells per r_max: 5^3 cells around a vertex, those wholly beyond r_max skipped


@numba.njit(cache=True, parallel=True, fastmath=False)
def _vertex_forces(R, V, start, lo, dims, cell, r_max, f_max, O, out):
    r2 = r_max * r_max
    for i in numba.prange(R.shape[0]):
        x, y, z = R[i, 0], R[i, 1], R[i, 2]
        cx = int(np.floor((x - lo[0]) / cell))
        cy = int(np.floor((y - lo[1]) / cell))
        cz = int(np.floor((z - lo[2]) / cell))
        fx = fy = fz = 0.0
        k = CELLS_PER_R
        for a in range(max(cx - k, 0), min(cx + k + 1, dims[0])):
            ex = max(lo[0] + a * cell - x, 0.0, x - lo[0] - (a + 1) * cell)
            for b in range(max(cy - k, 0), min(cy + k + 1, dims[1])):
                ey = max(lo[1] + b * cell - y, 0.0, y - lo[1] - (b + 1) * cell)
                if ex * ex + ey * ey >= r2:
                    continue
                for c in range(max(cz - k, 0), min(cz + k + 1, dims[2])):
                    ez = max(lo[2] + c * cell - z, 0.0, z - lo[2] - (c + 1) * cell)
                    if ex * ex + ey * ey + ez * ez >= r2:  # the whole cell is beyond r_max
                        continue
                    f = (a * dims[1] + b) * dims[2] + c
                    for j in range(start[f], start[f + 1]):
                        dx, dy, dz = x - V[j, 0], y - V[j, 1], z - V[j, 2]
                        s = dx * dx + dy * dy + dz * dz
                        if s >= r2 or s == 0.0:
                            continue
                        dist = np.sqrt(s)
                        w = 1.0 - dist / r_max
                        g = f_max * w * w / dist
                        fx += g * dx
                        fy += g * dy
                        fz += g * dz
        px, py, pz = x - O[i, 0], y - O[i, 1], z - O[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = fx, fy, fz
        out[i, 3] = py * fz - pz * fy
        out[i, 4] = pz * fx - px * fz
        out[i, 5] = px * fy - py * fx


def brute_force(vertices, link, origins, voxels, r_max: float, f_max: float) -> np.ndarray:
    """All vertex-voxel pairs in float64: the reference for `ForceField.compute` (small cases only)."""
    d = vertices[:, None, :] - voxels[None, :, :]
    dist = np.linalg.norm(d, axis=2)
    near = (dist < r_max) & (dist > 0)
    g = np.where(near, f_max * (1 - dist / r_max) ** 2 / np.where(near, dist, 1.0), 0.0)
    f = np.einsum("vm,vmk->vk", g, d)
    m = np.cross(vertices - origins[link], f)
    out = np.zeros((len(origins), 6))
    np.add.at(out, link, np.hstack([f, m]))
    return out
