"""Compiled loops of the occupancy map (numba): its summed-volume count grid, the boxes it may hold a voxel in, the
voxels near some boxes, and OctoMap's node stream for FCL's octree."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def boxes_hit_table(lo, hi, origin, inv_cell, n, sat, out):
    """out[i] = the summed-volume table `sat` ((n + 1) cells a side, flat) counts an occupied voxel in a cell
    that box [lo[i], hi[i]] (M, 3) overlaps; `origin` is the table's corner, cells 1 / inv_cell a side."""
    for i in range(lo.shape[0]):
        out[i] = box_hits_table(lo[i, 0], lo[i, 1], lo[i, 2], hi[i, 0], hi[i, 1], hi[i, 2], origin, inv_cell, n, sat)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def box_hits_table(lo0, lo1, lo2, hi0, hi1, hi2, origin, inv_cell, n, sat) -> bool:
    """Whether `boxes_hit_table`'s table counts an occupied voxel in a cell the box [lo, hi] overlaps."""
    s1, s2 = n[2] + 1, (n[1] + 1) * (n[2] + 1)
    # cells [a, b] overlap the box; in table coordinates that is the half-open range [a, b + 1)
    a0, a1, a2 = (
        _cell(lo0, origin[0], inv_cell, 0.0, n[0]),
        _cell(lo1, origin[1], inv_cell, 0.0, n[1]),
        _cell(lo2, origin[2], inv_cell, 0.0, n[2]),
    )
    b0, b1, b2 = (
        _cell(hi0, origin[0], inv_cell, 1.0, n[0]),
        _cell(hi1, origin[1], inv_cell, 1.0, n[1]),
        _cell(hi2, origin[2], inv_cell, 1.0, n[2]),
    )
    count = (
        sat[b0 * s2 + b1 * s1 + b2]
        - sat[a0 * s2 + b1 * s1 + b2]
        - sat[b0 * s2 + a1 * s1 + b2]
        - sat[b0 * s2 + b1 * s1 + a2]
        + sat[a0 * s2 + a1 * s1 + b2]
        + sat[a0 * s2 + b1 * s1 + a2]
        + sat[b0 * s2 + a1 * s1 + a2]
        - sat[a0 * s2 + a1 * s1 + a2]
    )
    return count > 0


@numba.njit(cache=True, nogil=True, inline="always")
def _cell(x, origin, inv_cell, shift, n):
    """Table index of coordinate x: its cell + shift, clipped to [0, n]."""
    return np.int64(min(max(np.floor((x - origin) * inv_cell) + shift, 0.0), np.float64(n)))


@numba.njit(cache=True, nogil=True)
def key_bounds(keys):
    """The least and the greatest of integer keys (M >= 1, 3) per axis, in one pass (numpy's reductions along axis
    0 of three columns pass over the keys six times)."""
    lo, hi = keys[0].copy(), keys[0].copy()
    for i in range(1, keys.shape[0]):
        for j in range(3):
            v = keys[i, j]
            if v < lo[j]:
                lo[j] = v
            elif v > hi[j]:
                hi[j] = v
    return lo, hi


@numba.njit(cache=True, nogil=True)
def keys_in_cells(keys, key_min, ratio, n, lo, hi, origin, inv_cell):
    """Which voxels (keys (M, 3)) lie in a cell of `count_cells`' grid (ratio voxels a side from key_min, n cells per
    axis; corner origin [m], 1 / inv_cell a side) that a box [lo[i], hi[i]] (K, 3) [m] overlaps: a mask (M,)."""
    mark = np.zeros(n[0] * n[1] * n[2], np.bool_)
    a, b = np.empty(3, np.int64), np.empty(3, np.int64)
    for i in range(lo.shape[0]):
        for j in range(3):  # the cells the box overlaps, clipped to the grid (a box off it marks its edge: harmless)
            a[j] = _cell(lo[i, j], origin[j], inv_cell, 0.0, n[j] - 1)
            b[j] = _cell(hi[i, j], origin[j], inv_cell, 0.0, n[j] - 1)
        for x in range(a[0], b[0] + 1):
            for y in range(a[1], b[1] + 1):
                for z in range(a[2], b[2] + 1):
                    mark[(x * n[1] + y) * n[2] + z] = True
    out = np.empty(keys.shape[0], np.bool_)
    for v in range(keys.shape[0]):
        x = (keys[v, 0] - key_min[0]) // ratio
        y = (keys[v, 1] - key_min[1]) // ratio
        out[v] = mark[(x * n[1] + y) * n[2] + (keys[v, 2] - key_min[2]) // ratio]
    return out


@numba.njit(cache=True, nogil=True)
def octree_stream(codes, depth):
    """OctoMap's binary node stream (uint16 per inner node, pre-order) of the leaves with sorted, unique Morton
    codes `codes` (3 bits per level, the root's digit highest) in a tree `depth` levels deep.

    Sorted codes meet the nodes in pre-order: each code opens new nodes below the level where it first differs
    from the code before; a node's record is reserved when it opens and its child bits are filled as they come.
    """
    out = np.zeros(codes.shape[0] * depth + 1, np.uint16)
    slot = np.empty(depth + 1, np.int64)
    slot[0] = 0
    m = 1
    prev = np.uint64(0)
    for i in range(codes.shape[0]):
        c = codes[i]
        d = 0
        if i > 0:
            x = prev ^ c
            while d < depth - 1 and (x >> np.uint64(3 * (depth - 1 - d))) == 0:
                d += 1
        for level in range(d, depth):
            digit = np.int64((c >> np.uint64(3 * (depth - 1 - level))) & np.uint64(7))
            if level < depth - 1:
                out[slot[level]] |= np.uint16(3 << (2 * digit))  # 11: an inner child
                slot[level + 1] = m
                m += 1
            else:
                out[slot[level]] |= np.uint16(2 << (2 * digit))  # an occupied leaf
        prev = c
    return out[:m]


@numba.njit(cache=True, nogil=True)
def count_cells(keys, key_min, ratio, n):
    """The summed-volume table (n + 1 per axis, a zero slab in front) of the voxels (keys (M, 3)) per coarse cell of
    `ratio` voxels a side from key_min: entry [i, j, k] counts the voxels of the cells before (i, j, k) on all axes."""
    sat = np.zeros((n[0] + 1, n[1] + 1, n[2] + 1), np.int32)
    for i in range(keys.shape[0]):
        sat[
            (keys[i, 0] - key_min[0]) // ratio + 1,
            (keys[i, 1] - key_min[1]) // ratio + 1,
            (keys[i, 2] - key_min[2]) // ratio + 1,
        ] += 1
    summed_volume(sat)
    return sat


@numba.njit(cache=True, nogil=True)
def summed_volume(t):
    """t (3-D counts, a zero first plane per axis) becomes its summed-volume table, in place: the cumulative sums
    along each axis in turn."""
    n0, n1, n2 = t.shape
    for a in range(n0):
        for b in range(n1):
            for c in range(1, n2):
                t[a, b, c] += t[a, b, c - 1]
        for b in range(1, n1):
            for c in range(n2):
                t[a, b, c] += t[a, b - 1, c]
    for a in range(1, n0):
        for b in range(n1):
            for c in range(n2):
                t[a, b, c] += t[a - 1, b, c]


def warm_up() -> None:
    """Compile (or load from the cache) the map kernels now: a first compile takes seconds, too long mid-check."""
    boxes_hit_table(
        np.zeros((1, 3)),
        np.zeros((1, 3)),
        np.zeros(3),
        1.0,
        np.ones(3, np.int64),
        np.zeros(8, np.int32),
        np.empty(1, bool),
    )
    octree_stream(np.zeros(1, np.uint64), 16)  # the first map's octree and broadphase grid
    keys = np.zeros((1, 3), np.int64)
    keys.setflags(write=False)  # as an occupancy map holds them: numba compiles read-only arrays apart
    count_cells(keys, np.zeros(3, np.int64), 1, np.ones(3, np.int64))
    key_bounds(keys)
    key_bounds(np.zeros((1, 3), np.int64))  # unique_keys' writable copy
    one = np.ones(3, np.int64)
    keys_in_cells(keys, np.zeros(3, np.int64), 1, one, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(3), 1.0)
