"""An immutable occupancy snapshot: occupied voxels, their fcl.OcTree, and a broadphase count grid.

Voxels follow OctoMap's grid: voxel i along an axis covers [i * res, (i + 1) * res) in the base frame.
A snapshot is never modified after construction, so readers can use it while a new one is being built.
"""

from __future__ import annotations

import time
from functools import cached_property

import fcl
import numpy as np
from scipy.spatial import cKDTree

from ..errors import InvalidInputError

_OCTOMAP_HEADER_END = b"data\n"


def voxel_keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """Integer voxel indices (N, 3) of points (N, 3) [m] on OctoMap's grid."""
    return np.floor(np.asarray(points, dtype=np.float64) * (1.0 / resolution)).astype(np.int64)  # as OctoMap


def voxel_centers(keys: np.ndarray, resolution: float) -> np.ndarray:
    """Centres (N, 3) [m] of voxels given by integer indices."""
    return (np.asarray(keys, dtype=np.float64) + 0.5) * resolution


_TREE_DEPTH = 16
_KEY_OFFSET = 1 << (_TREE_DEPTH - 1)  # OctoMap key of the voxel whose lower corner is the origin


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Put bit i of a 16-bit integer at bit 3i (for Morton interleaving)."""
    x = x.astype(np.uint64) & np.uint64(0xFFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x0C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x249249249249)
    return x


def octomap_binary(keys: np.ndarray) -> bytes:
    """OctoMap's binary node stream (the payload after the `data` header line) of occupied leaf voxels `keys`.

    Pre-order over inner nodes; per node two bytes, two bits per child: 01 occupied leaf, 11 inner, 00 none.
    Child index = x bit + 2 y bit + 4 z bit of the key at that depth, so a Morton code sorts the tree.
    """
    k = np.asarray(keys, dtype=np.int64) + _KEY_OFFSET
    if len(k) and (k.min() < 0 or k.max() >= 1 << _TREE_DEPTH):
        raise InvalidInputError(f"voxel keys must lie within +-{_KEY_OFFSET} (OctoMap's 16-level tree)")
    if not len(k):
        raise InvalidInputError("an empty map has no tree: fcl would read a childless root as one occupied voxel")
    codes = _spread_bits(k[:, 0]) | (_spread_bits(k[:, 1]) << np.uint64(1)) | (_spread_bits(k[:, 2]) << np.uint64(2))
    codes = np.unique(codes)
    lefts, levels, bits = [], [], []
    for level in range(_TREE_DEPTH):
        child = codes >> np.uint64(3 * (_TREE_DEPTH - 1 - level))  # nodes one level below, with repeats
        if level < _TREE_DEPTH - 1:
            child = child[np.r_[True, child[1:] != child[:-1]]]
        parent = child >> np.uint64(3)
        digit = (child & np.uint64(7)).astype(np.int64)
        kind = 3 if level < _TREE_DEPTH - 1 else 2  # inner node, or occupied leaf at the bottom
        starts = np.flatnonzero(np.r_[True, parent[1:] != parent[:-1]])
        bits.append(np.add.reduceat(kind << (2 * digit), starts))
        lefts.append(parent[starts] << np.uint64(3 * (_TREE_DEPTH - level)))
        levels.append(np.full(len(starts), level, dtype=np.int64))
    order = np.lexsort((np.concatenate(levels), np.concatenate(lefts)))  # parents before their subtrees
    return np.concatenate(bits)[order].astype("<u2").tobytes()


def build_fcl_octree(keys: np.ndarray, resolution: float) -> fcl.OcTree:
    """An fcl.OcTree whose occupied leaves are exactly the voxels `keys`."""
    return fcl.OcTree(resolution, np.frombuffer(octomap_binary(keys), dtype=np.int8))


def octomap_payload(blob: bytes) -> np.ndarray:
    """The node stream of a whole OctoMap `.bt` blob: fcl parses the ASCII header as nodes, silently, if left in."""
    start = blob.index(_OCTOMAP_HEADER_END) + len(_OCTOMAP_HEADER_END)
    return np.frombuffer(blob, dtype=np.int8, offset=start)


class OccupancyMap:
    """Occupied voxels of one moment, ready for collision checks.

    Args:
        keys: integer voxel indices (N, 3) of occupied voxels (see `voxel_keys`); duplicates are merged.
        resolution: voxel edge [m].
        broadphase_cell: edge [m] of the coarse count grid used to skip links far from any voxel.
        stamp: time [s] the map describes (e.g. the newest cloud's timestamp).
    """

    def __init__(
        self,
        keys: np.ndarray,
        resolution: float,
        *,
        broadphase_cell: float = 0.04,
        stamp: float | None = None,
        trusted: bool = False,
    ):
        if not (resolution > 0 and np.isfinite(resolution)):
            raise InvalidInputError(f"resolution must be > 0 [m], got {resolution}")
        k = np.asarray(keys)
        if k.ndim != 2 or k.shape[1] != 3 or not np.issubdtype(k.dtype, np.integer):
            raise InvalidInputError(f"keys must be an (N, 3) integer array of voxel indices, got {k.dtype} {k.shape}")
        if not trusted:  # `trusted`: the caller guarantees unique int64 keys (the perception pipeline does)
            k = np.unique(k.astype(np.int64), axis=0) if len(k) else np.zeros((0, 3), np.int64)
        k.setflags(write=False)
        self.keys = k
        self.resolution = float(resolution)
        self.stamp = time.time() if stamp is None else float(stamp)
        self.centers = voxel_centers(k, resolution)
        self.centers.setflags(write=False)
        # no tree for an empty map: fcl would read a childless root as one huge occupied voxel
        self.tree = build_fcl_octree(k, self.resolution) if len(k) else None
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
        grid = np.bincount((idx @ np.array([shape[1] * shape[2], shape[2], 1])), minlength=int(np.prod(shape)))
        grid = grid.reshape(tuple(shape)).astype(np.int32)
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
