"""An immutable occupancy snapshot: occupied voxels, their fcl.OcTree, and a broadphase count grid.

Voxels follow OctoMap's grid: voxel i along an axis covers [i * res, (i + 1) * res) in the base frame.
A snapshot is never modified after construction, so readers can use it while a new one is being built.
"""

from __future__ import annotations

import time
from functools import cached_property

import fcl
import numpy as np
import octomap
from scipy.spatial import cKDTree

from .errors import InvalidInputError

_OCTOMAP_HEADER_END = b"data\n"


def voxel_keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """Integer voxel indices (N, 3) of points (N, 3) [m] on OctoMap's grid."""
    return np.floor(np.asarray(points, dtype=np.float64) / resolution).astype(np.int64)


def voxel_centers(keys: np.ndarray, resolution: float) -> np.ndarray:
    """Centres (N, 3) [m] of voxels given by integer indices."""
    return (np.asarray(keys, dtype=np.float64) + 0.5) * resolution


def build_fcl_octree(centers: np.ndarray, resolution: float) -> fcl.OcTree:
    """An fcl.OcTree whose occupied leaves are exactly the voxels at `centers` (via OctoMap's binary format)."""
    tree = octomap.OcTree(resolution)
    if len(centers):
        tree.updateNodes(np.ascontiguousarray(centers, dtype=np.float64), True, lazy_eval=True)
        tree.updateInnerOccupancy()
    blob = tree.writeBinary()
    # fcl reads only the payload; with the ASCII header left in it builds a wrong tree silently
    start = blob.index(_OCTOMAP_HEADER_END) + len(_OCTOMAP_HEADER_END)
    return fcl.OcTree(resolution, np.frombuffer(blob, dtype=np.int8, offset=start))


class OccupancyMap:
    """Occupied voxels of one moment, ready for collision checks.

    Args:
        keys: integer voxel indices (N, 3) of occupied voxels (see `voxel_keys`).
        resolution: voxel edge [m].
        broadphase_cell: edge [m] of the coarse count grid used to skip links far from any voxel.
        stamp: time [s] the map describes (e.g. the newest cloud's timestamp).
    """

    def __init__(
        self, keys: np.ndarray, resolution: float, *, broadphase_cell: float = 0.04, stamp: float | None = None
    ):
        if not (resolution > 0 and np.isfinite(resolution)):
            raise InvalidInputError(f"resolution must be > 0 [m], got {resolution}")
        k = np.asarray(keys)
        if k.ndim != 2 or k.shape[1] != 3 or not np.issubdtype(k.dtype, np.integer):
            raise InvalidInputError(f"keys must be an (N, 3) integer array of voxel indices, got {k.dtype} {k.shape}")
        k = np.unique(k.astype(np.int64), axis=0) if len(k) else np.zeros((0, 3), np.int64)
        k.setflags(write=False)
        self.keys = k
        self.resolution = float(resolution)
        self.stamp = time.time() if stamp is None else float(stamp)
        self.centers = voxel_centers(k, resolution)
        self.centers.setflags(write=False)
        self.tree = build_fcl_octree(self.centers, self.resolution)
        # whole voxels per cell, so each voxel box lies inside exactly one cell
        self._build_broadphase(self.resolution * max(1, round(float(broadphase_cell) / self.resolution)))

    @classmethod
    def from_points(cls, points: np.ndarray, resolution: float, **kw) -> OccupancyMap:
        """Snapshot with every voxel that contains at least one of `points` (N, 3) [m] occupied."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
            raise InvalidInputError(f"points must be a finite (N, 3) array [m], got shape {p.shape}")
        return cls(voxel_keys(p, resolution), resolution, **kw)

    @classmethod
    def empty(cls, resolution: float = 0.01, **kw) -> OccupancyMap:
        return cls(np.zeros((0, 3), np.int64), resolution, **kw)

    @cached_property
    def kdtree(self) -> cKDTree:
        """KD-tree of the voxel centres (built on first use)."""
        return cKDTree(self.centers)

    def __len__(self) -> int:
        return len(self.keys)

    def _build_broadphase(self, cell: float) -> None:
        self._cell = cell
        lo = self.centers.min(axis=0) if len(self.keys) else np.zeros(3)
        idx = np.floor((self.centers - lo) / cell).astype(np.int64)
        shape = idx.max(axis=0) + 1 if len(self.keys) else np.ones(3, np.int64)
        grid = np.zeros(shape, dtype=np.int32)
        np.add.at(grid, (idx[:, 0], idx[:, 1], idx[:, 2]), 1)
        sat = np.zeros(tuple(shape + 1), dtype=np.int32)  # summed-volume table with a zero slab in front
        sat[1:, 1:, 1:] = grid.cumsum(0).cumsum(1).cumsum(2)
        self._origin = lo - self.resolution / 2  # voxel boxes, not centres, must fall inside a cell
        self._n = shape
        self._sat = sat.ravel()
        strides = np.array([sat.shape[1] * sat.shape[2], sat.shape[2], 1], dtype=np.int64)
        # corner (i, j, k), i/j/k = 0 for the low side, 1 for the high side: index = sum of the chosen columns
        M = np.zeros((6, 8), dtype=np.int64)
        signs = np.zeros(8, dtype=np.int64)
        for c in range(8):
            ijk = ((c >> 2) & 1, (c >> 1) & 1, c & 1)
            for axis, side in enumerate(ijk):
                M[3 * side + axis, c] = strides[axis]
            signs[c] = (-1) ** (sum(ijk) + 1)
        self._corner_matrix, self._corner_sign = M, signs
        self._origin6 = np.concatenate([self._origin, self._origin])
        self._shift6 = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
        self._n6 = np.concatenate([self._n, self._n]).astype(np.float64)
        self._inv_cell = 1.0 / cell

    def any_in_boxes(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """For axis-aligned boxes [lo, hi] (..., 3) [m]: True where an occupied voxel may overlap.

        Never a false False; a True may be a voxel nearby in the same coarse cell.
        """
        if not len(self.keys):
            return np.zeros(np.shape(lo)[:-1], dtype=bool)
        # cells [a, b] overlap the box; in table coordinates that is the half-open range [a, b + 1)
        ab = np.floor((np.concatenate((lo, hi), axis=-1) - self._origin6) * self._inv_cell) + self._shift6
        corners = ab.clip(0, self._n6).astype(np.int64) @ self._corner_matrix  # flat indices of the 8 corners
        count = self._sat[corners] @ self._corner_sign
        return count > 0

    def __repr__(self) -> str:
        return f"OccupancyMap(voxels={len(self)}, resolution={self.resolution})"
