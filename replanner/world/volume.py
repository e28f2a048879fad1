"""The occupancy map as a summed-volume table over its voxels' cells: whether a box or a ball may hold an occupied
voxel, in eight lookups, for the compiled collision layers."""

from __future__ import annotations

import numba
import numpy as np

from .kernels import key_bounds, summed_volume
from .occupancy import OccupancyMap

CBLOCK = 4  # cells a side of a coarse block: a 2 m map at 2 cm is 7,000 blocks, 28 kB in cache


class VoxelVolume:
    """The occupancy map as a summed-volume table over its voxels' bounding box: how many cells touch a box, in
    eight lookups. Cells are voxels merged `f` to an edge so the table stays under `MAX_CELLS` (a cell counts when
    any of its voxels is occupied: coarser is only more conservative). A second, coarse table over blocks of
    `CBLOCK` cells a side stays in cache and answers most boxes alone (`csat`)."""

    EMPTY: VoxelVolume
    MAX_CELLS = 1 << 19  # 2 MB of int32: a 2 m map at 1 cm merges 3x3x3 voxels, built in a few ms

    def __init__(self, keys: np.ndarray, resolution: float, bounds: tuple[np.ndarray, np.ndarray] | None = None):
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        if not len(keys):
            self.inv_res, self.key_min, self.whole = 1.0 / resolution, np.zeros(3, np.int64), True
            self.sat = self.csat = np.zeros((1, 1, 1), np.int32)
            return
        lo, hi = key_bounds(np.ascontiguousarray(keys)) if bounds is None else bounds  # keys' least and greatest
        span = hi - lo + 2
        f = 1
        while np.prod(-(-span // f) + 1) > self.MAX_CELLS:
            f += 1
        keys = keys // f
        self.inv_res = 1.0 / (resolution * f)
        self.whole = f == 1  # a cell is one voxel: a ball that meets an occupied cell meets a voxel
        self.key_min = lo // f  # floor division keeps the order: the merged keys' least and greatest
        n = hi // f - self.key_min + 1
        self.sat = np.zeros(tuple(n + 1), np.int32)
        self.csat = np.zeros(tuple(-(-n // CBLOCK) + 1), np.int32)
        _summed_volumes(keys - self.key_min + 1, self.sat, self.csat)  # a replan's first check waits for it

    @classmethod
    def of(cls, occ: OccupancyMap | None) -> VoxelVolume:
        return cls.EMPTY if occ is None or not len(occ) else cls(occ.keys, occ.resolution, occ.key_bounds)

    def count(self, lo, hi) -> int:
        """Cells with an occupied voxel that the box [lo, hi] [m] overlaps (0 when it overlaps none)."""
        return int(voxels_in(self.sat, self.csat, self.key_min, self.inv_res, *map(float, lo), *map(float, hi)))


VoxelVolume.EMPTY = VoxelVolume(np.zeros((0, 3), np.int64), 1.0)


@numba.njit(cache=True, nogil=True)
def _summed_volumes(k, sat, csat):
    """sat, csat (zeros, a zero first plane per axis) = the summed-volume tables of the cells k (M, 3; from 1)
    and of their CBLOCK-sided blocks (how many occupied cells each holds)."""
    for i in range(k.shape[0]):
        a, b, c = k[i, 0], k[i, 1], k[i, 2]
        if sat[a, b, c] == 0:
            sat[a, b, c] = 1
            csat[(a - 1) // CBLOCK + 1, (b - 1) // CBLOCK + 1, (c - 1) // CBLOCK + 1] += 1
    summed_volume(sat)
    summed_volume(csat)


@numba.njit(cache=True, nogil=True, inline="always")
def voxels_in(sat, csat, key_min, inv_res, lo0, lo1, lo2, hi0, hi1, hi2):
    """Cells with an occupied voxel whose cube meets the box [lo, hi] [m] (summed-volume tables with a zero first
    plane per axis): 0 at once when the coarse blocks around those cells hold none, else the fine table's count."""
    n0, n1, n2 = sat.shape[0] - 1, sat.shape[1] - 1, sat.shape[2] - 1
    a0 = max(np.int64(np.floor(lo0 * inv_res)) - key_min[0], 0)
    a1 = max(np.int64(np.floor(lo1 * inv_res)) - key_min[1], 0)
    a2 = max(np.int64(np.floor(lo2 * inv_res)) - key_min[2], 0)
    b0 = min(np.int64(np.floor(hi0 * inv_res)) - key_min[0], n0 - 1)
    b1 = min(np.int64(np.floor(hi1 * inv_res)) - key_min[1], n1 - 1)
    b2 = min(np.int64(np.floor(hi2 * inv_res)) - key_min[2], n2 - 1)
    if a0 > b0 or a1 > b1 or a2 > b2:
        return 0
    if (
        box_sum(csat, a0 // CBLOCK, a1 // CBLOCK, a2 // CBLOCK, b0 // CBLOCK + 1, b1 // CBLOCK + 1, b2 // CBLOCK + 1)
        == 0
    ):
        return 0
    return box_sum(sat, a0, a1, a2, b0 + 1, b1 + 1, b2 + 1)


@numba.njit(cache=True, nogil=True, inline="always")
def box_sum(sat, a0, a1, a2, b0, b1, b2):
    """The sum of the cells [a, b) of the summed-volume table `sat`."""
    return (
        sat[b0, b1, b2]
        - sat[a0, b1, b2]
        - sat[b0, a1, b2]
        - sat[b0, b1, a2]
        + sat[a0, a1, b2]
        + sat[a0, b1, a2]
        + sat[b0, a1, a2]
        - sat[a0, a1, a2]
    )


@numba.njit(cache=True, nogil=True, inline="always")
def ball_in_map(sat, csat, key_min, inv_res, x, y, z, g) -> bool:
    """Whether a voxel of the map may meet the ball at (x, y, z) of radius g (its bounding cube meets one)."""
    return voxels_in(sat, csat, key_min, inv_res, x - g, y - g, z - g, x + g, y + g, z + g) > 0


@numba.njit(cache=True, nogil=True, inline="always")
def map_box(sat, key_min, inv_res):
    """lo0, lo1, lo2, hi0, hi1, hi2 [m] of the volume's cells, a cell wider each way; an empty map's is empty."""
    if sat.shape[0] <= 1:
        return np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
    c = 1.0 / inv_res
    return (
        (key_min[0] - 1) * c,
        (key_min[1] - 1) * c,
        (key_min[2] - 1) * c,
        (key_min[0] + sat.shape[0]) * c,
        (key_min[1] + sat.shape[1]) * c,
        (key_min[2] + sat.shape[2]) * c,
    )
