"""Compiled loops of the perception pipeline (numba): one pass over a frame's points where numpy would make five.

Compiled once per machine and cached (numba's cache, per version of the compiled sources: see cache_dirs.py).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def voxelize(pts, R, t, r2min, r2max, lo, hi, corner, inv, s0, s1, scratch, out):
    """Keep the finite points (N, 3) of the sensor frame with r2min <= |p|^2 <= r2max, transform them by R, t
    into the base frame, keep those within [lo, hi], and write the unique flat cells they fall in to `out`
    (first seen first).

    scratch: a boolean grid of every cell, all False; it is False again on return. Returns (in range, in the
    workspace, unique cells).
    """
    n_range = n_crop = m = 0
    for i in range(pts.shape[0]):
        px, py, pz = pts[i, 0], pts[i, 1], pts[i, 2]
        r2 = px * px + py * py + pz * pz
        if not (r2 >= r2min and r2 <= r2max):  # NaN fails both; out-of-range points skip the transform
            continue
        n_range += 1
        x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
            continue
        n_crop += 1
        # inside the workspace every coordinate is above the grid's corner: truncation is floor
        f = np.int64((x - corner[0]) * inv) * s0 + np.int64((y - corner[1]) * inv) * s1
        f += np.int64((z - corner[2]) * inv)
        if not scratch[f]:
            scratch[f] = True
            out[m] = f
            m += 1
    for k in range(m):
        scratch[out[k]] = False
    return n_range, n_crop, m


@numba.njit(cache=True, nogil=True)
def mark_inside(points, keep, wlo, whi, inv, rows, starts):
    """keep[i] = False for every point (N, 3) inside one of the bodies: body b has the world box [wlo[b], whi[b]],
    the base-to-body transform inv[b] (3, 4) and, in its frame, the half-spaces rows[starts[b]:starts[b + 1]]
    (a, b, c, d: a x + b y + c z + d <= 0 inside)."""
    for i in range(points.shape[0]):
        if not keep[i]:
            continue
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for b in range(starts.shape[0] - 1):
            if x < wlo[b, 0] or x > whi[b, 0] or y < wlo[b, 1] or y > whi[b, 1] or z < wlo[b, 2] or z > whi[b, 2]:
                continue
            m = inv[b]
            lx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
            ly = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
            lz = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
            inside = True
            for r in range(starts[b], starts[b + 1]):
                if rows[r, 0] * lx + rows[r, 1] * ly + rows[r, 2] * lz + rows[r, 3] > 0.0:
                    inside = False
                    break
            if inside:
                keep[i] = False
                break


@numba.njit(cache=True, nogil=True)
def neighbour_counts(flat, offsets, scratch):
    """How many of each cell's neighbours (flat + offsets) are among the unique cells `flat`; scratch: an
    all-False boolean grid, all False again on return."""
    for i in range(flat.shape[0]):
        scratch[flat[i]] = True
    out = np.zeros(flat.shape[0], np.int64)
    for i in range(flat.shape[0]):
        c = 0
        for o in offsets:
            c += scratch[flat[i] + o]
        out[i] = c
    for i in range(flat.shape[0]):
        scratch[flat[i]] = False
    return out


@numba.njit(cache=True, nogil=True)
def union_sorted(a, b):
    """The sorted union of two sorted arrays of unique integers."""
    out = np.empty(a.shape[0] + b.shape[0], a.dtype)
    i = j = m = 0
    while i < a.shape[0] and j < b.shape[0]:
        if a[i] < b[j]:
            out[m] = a[i]
            i += 1
        elif b[j] < a[i]:
            out[m] = b[j]
            j += 1
        else:
            out[m] = a[i]
            i += 1
            j += 1
        m += 1
    while i < a.shape[0]:
        out[m] = a[i]
        i += 1
        m += 1
    while j < b.shape[0]:
        out[m] = b[j]
        j += 1
        m += 1
    return out[:m]


@numba.njit(cache=True, nogil=True)
def in_sorted(a, b):
    """For each element of sorted unique `a`: whether it is in sorted unique `b`."""
    out = np.zeros(a.shape[0], np.bool_)
    j = 0
    for i in range(a.shape[0]):
        while j < b.shape[0] and b[j] < a[i]:
            j += 1
        if j == b.shape[0]:
            break
        out[i] = b[j] == a[i]
    return out


@numba.njit(cache=True, nogil=True)
def cell_keys(flat, ny, nz, key_lo):
    """Integer voxel keys (N, 3) of flat cell indices of a grid with (., ny, nz) cells whose first key is key_lo."""
    out = np.empty((flat.shape[0], 3), np.int64)
    for i in range(flat.shape[0]):
        f = flat[i]
        ix = f // (ny * nz)
        rem = f - ix * ny * nz
        iy = rem // nz
        out[i, 0] = ix + key_lo[0]
        out[i, 1] = iy + key_lo[1]
        out[i, 2] = rem - iy * nz + key_lo[2]
    return out


@numba.njit(cache=True, nogil=True)
def shadow_cells(keys, origin, res, steps, lo, hi, key_lo, s0, s1, scratch):
    """Unique flat cells (sorted) up to `steps` voxels behind each voxel `keys` (N, 3) along the ray from
    `origin`, within [lo, hi]; scratch: an all-False boolean grid, all False again on return."""
    out = np.empty(keys.shape[0] * steps, np.int64)
    m = 0
    for i in range(keys.shape[0]):
        cx, cy, cz = (keys[i, 0] + 0.5) * res, (keys[i, 1] + 0.5) * res, (keys[i, 2] + 0.5) * res
        dx, dy, dz = cx - origin[0], cy - origin[1], cz - origin[2]
        n = np.sqrt(dx * dx + dy * dy + dz * dz)
        if n == 0.0:
            continue
        dx, dy, dz = dx / n, dy / n, dz / n
        for k in range(1, steps + 1):
            x, y, z = cx + k * res * dx, cy + k * res * dy, cz + k * res * dz
            if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
                continue
            f = (np.int64(np.floor(x / res)) - key_lo[0]) * s0 + (np.int64(np.floor(y / res)) - key_lo[1]) * s1
            f += np.int64(np.floor(z / res)) - key_lo[2]
            if not scratch[f]:
                scratch[f] = True
                out[m] = f
                m += 1
    out = np.sort(out[:m])
    for k in range(m):
        scratch[out[k]] = False
    return out


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now: a first compile takes seconds, too long mid-stream."""
    f3, f64, i64 = np.zeros(3, np.float32), np.zeros(3), np.zeros(1, np.int64)
    pts = np.zeros((1, 3), np.float32)
    one = np.float32(1)
    voxelize(pts, np.eye(3, dtype=np.float32), f3, one, one, f3, f3, f64, 1.0, 1, 1, np.zeros(1, bool), i64)
    mark_inside(
        pts,
        np.ones(1, bool),
        np.zeros((1, 3)),
        np.zeros((1, 3)),
        np.zeros((1, 3, 4)),
        np.zeros((1, 4)),
        np.array([0, 1]),
    )
    cells = np.zeros(1, np.int64)
    neighbour_counts(cells, cells, np.zeros(1, bool))
    union_sorted(cells, cells)
    in_sorted(cells, cells)
    cell_keys(cells, 1, 1, np.zeros(3, np.int64))
    shadow_cells(np.zeros((1, 3), np.int64), f64, 1.0, 1, f64, f64, np.zeros(3, np.int64), 1, 1, np.zeros(1, bool))
