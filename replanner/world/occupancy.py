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
from .kernels import boxes_hit_table, count_cells, key_bounds, keys_in_cells, octree_stream

_OCTOMAP_HEADER_END = b"data\n"
TREE_FIXED = 6000  # voxels' worth of an fcl.OcTree's fixed cost (~0.75 ms; ~0.12 us a voxel more, measured)


def voxel_keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """Integer voxel indices (N, 3) of points (N, 3) [m] on OctoMap's grid."""
    return np.floor(np.asarray(points, dtype=np.float64) * (1.0 / resolution)).astype(np.int64)  # as OctoMap


def unique_keys(keys: np.ndarray) -> np.ndarray:
    """The distinct rows of integer keys (N, 3), sorted as np.unique(axis=0) sorts them, through one flat index
    (np.unique on rows is several times slower)."""
    keys = np.ascontiguousarray(keys, dtype=np.int64).reshape(-1, 3)
    if not len(keys):
        return keys
    lo, hi = key_bounds(keys)
    k = keys - lo
    n = hi - lo + 1
    flat = np.unique((k[:, 0] * n[1] + k[:, 1]) * n[2] + k[:, 2])
    i, rest = np.divmod(flat, n[1] * n[2])
    j, m = np.divmod(rest, n[2])
    return np.stack([i, j, m], axis=1) + lo


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
    codes = np.sort(codes)
    codes = codes[np.r_[True, codes[1:] != codes[:-1]]]
    return octree_stream(codes, _TREE_DEPTH).astype("<u2").tobytes()


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
        serial: the map's number in a stream of maps; added: the voxels (K, 3) it has that map serial - 1 had not
            (a path clear of that map is clear of this one if it is clear of these).
    """

    def __init__(
        self,
        keys: np.ndarray,
        resolution: float,
        *,
        broadphase_cell: float = 0.04,
        stamp: float | None = None,
        trusted: bool = False,
        serial: int = 0,
        added: np.ndarray | None = None,
    ):
        if not (resolution > 0 and np.isfinite(resolution)):
            raise InvalidInputError(f"resolution must be > 0 [m], got {resolution}")
        k = np.asarray(keys)
        if k.ndim != 2 or k.shape[1] != 3 or not np.issubdtype(k.dtype, np.integer):
            raise InvalidInputError(f"keys must be an (N, 3) integer array of voxel indices, got {k.dtype} {k.shape}")
        if not trusted:  # `trusted`: the caller guarantees unique int64 keys (the perception pipeline does)
            k = unique_keys(k)
        k.setflags(write=False)
        self.keys = k
        self.resolution = float(resolution)
        self.stamp = time.time() if stamp is None else float(stamp)
        self.centers = voxel_centers(k, resolution)
        self.centers.setflags(write=False)
        self._tree: fcl.OcTree | None = None
        self._local_spent = 0  # voxels the local trees of this map held (`tree_near`)
        # whole voxels per cell, so each voxel box lies inside exactly one cell
        self._broadphase_cell = float(broadphase_cell)
        self._broadphase_ready = False  # built on the first any_in_boxes: a map nobody checks never needs it
        # which map this one follows (serial - 1) and the voxels it has that one had not: what can newly block
        self.serial = int(serial)
        self.added = None if added is None else np.asarray(added, dtype=np.int64).reshape(-1, 3)

    @property
    def tree(self) -> fcl.OcTree | None:
        """The voxels' fcl.OcTree, built on first use (a check of only the added voxels never needs it)."""
        # no tree for an empty map: fcl would read a childless root as one huge occupied voxel
        if self._tree is None and len(self.keys):
            self._tree = build_fcl_octree(self.keys, self.resolution)  # two racing builds make equal trees
        return self._tree

    def tree_near(self, lo: np.ndarray, hi: np.ndarray) -> fcl.OcTree | None:
        """An fcl.OcTree of the voxels in the broadphase cells the boxes [lo, hi] (K, 3) [m] overlap: every voxel that
        meets a box, so FCL's verdict on a body inside one is the whole map's. None (use `tree`) once the whole tree
        is built, or once this map's local trees have cost half as much as its whole tree (TREE_FIXED each, plus their
        voxels): a map checked again and again builds its tree once, at worst 1.5 x, and a planning job's map,
        checked a few times, only the voxels near its paths."""
        if not self.local_trees:
            return None
        origin, inv_cell, n, _ = self.broadphase_table()
        lo, hi = np.ascontiguousarray(lo, dtype=np.float64), np.ascontiguousarray(hi, dtype=np.float64)
        near = self.keys[keys_in_cells(self.keys, self.key_bounds[0], self._ratio, n, lo, hi, origin, inv_cell)]
        self._local_spent += TREE_FIXED + len(near)
        return build_fcl_octree(near, self.resolution) if len(near) else None

    @property
    def local_trees(self) -> bool:
        """Whether `tree_near` still builds local trees (a small map's whole tree costs what a part of it would)."""
        n = len(self.keys)
        return self._tree is None and n >= TREE_FIXED and 2 * self._local_spent < TREE_FIXED + n

    @cached_property
    def key_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The least and the greatest voxel index (3,) per axis (zeros for an empty map)."""
        if not len(self.keys):
            return np.zeros(3, np.int64), np.zeros(3, np.int64)
        return key_bounds(self.keys)

    @property
    def has_tree(self) -> bool:
        """Whether `tree` has been built: checks whose bodies meet none of the map's cells never build it."""
        return self._tree is not None

    @cached_property
    def added_map(self) -> OccupancyMap | None:
        """A map of only the voxels this one added to the one before it (None if it says nothing about that)."""
        if self.added is None:
            return None
        return OccupancyMap(self.added, self.resolution, broadphase_cell=self._broadphase_cell, trusted=True)

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

    def _build_broadphase(self) -> None:
        ratio = max(1, round(self._broadphase_cell / self.resolution))  # whole voxels per cell
        key_min, key_max = self.key_bounds
        shape = (key_max - key_min) // ratio + 1
        self._ratio = ratio
        sat = count_cells(self.keys, key_min, ratio, shape)  # summed-volume table with a zero slab in front
        self._origin = (key_min * self.resolution).astype(np.float64)  # boxes fall inside the first voxel's cell
        self._n = shape.astype(np.int64)
        self._sat = sat.ravel()
        self._inv_cell = 1.0 / (ratio * self.resolution)

    def any_in_boxes(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """For axis-aligned boxes [lo, hi] (..., 3) [m]: True where an occupied voxel may overlap.

        Never a false False; a True may be a voxel nearby in the same coarse cell.
        """
        if not len(self.keys):
            return np.zeros(np.shape(lo)[:-1], dtype=bool)
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        shape = lo.shape[:-1]
        out = np.empty(int(np.prod(shape)), dtype=bool)
        boxes_hit_table(
            np.ascontiguousarray(lo.reshape(-1, 3)),
            np.ascontiguousarray(hi.reshape(-1, 3)),
            *self.broadphase_table(),
            out,
        )
        return out.reshape(shape)

    def broadphase_table(self) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """What `kernels.boxes_hit_table` looks voxels up in: the table's corner [m], 1 / its cell size [1/m], its
        cells per axis and its flat summed-volume counts (built on the first look; a map needs voxels)."""
        if not self._broadphase_ready:  # two racing builds write equal tables
            self._build_broadphase()
            self._broadphase_ready = True
        return self._origin, self._inv_cell, self._n, self._sat

    def __repr__(self) -> str:
        return f"OccupancyMap(voxels={len(self)}, resolution={self.resolution})"
