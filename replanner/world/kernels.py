"""Compiled loops of the collision hot path (numba): forward kinematics, body poses and boxes, and the map's
broadphase for every configuration of a path at once, where numpy's batched 4x4 products are mostly overhead.

Compiled once per machine and cached (numba's cache, per version of the compiled sources: see cache_dirs.py).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def frames_of(Q, n, F, prismatic, joints, parents, out, m):
    """out[m] = the frames (1 + dof, 4, 4) of configuration Q[n] (see chain_frames); inlined into the callers' loops:
    a call per configuration with a dozen arrays would cost more in reference counting than the arithmetic."""
    for r in range(4):
        for c in range(4):
            out[m, 0, r, c] = 1.0 if r == c else 0.0
    for k in range(joints.shape[0]):
        j, p = joints[k], parents[k]
        q = Q[n, j]
        cq, sq, d = (1.0, 0.0, q) if prismatic[j] else (np.cos(q), np.sin(q), 0.0)
        # local_j(q) = F[j] @ (rotation about z by q, or translation along z by d): rows 0-2
        l00, l01 = F[j, 0, 0] * cq + F[j, 0, 1] * sq, F[j, 0, 1] * cq - F[j, 0, 0] * sq
        l10, l11 = F[j, 1, 0] * cq + F[j, 1, 1] * sq, F[j, 1, 1] * cq - F[j, 1, 0] * sq
        l20, l21 = F[j, 2, 0] * cq + F[j, 2, 1] * sq, F[j, 2, 1] * cq - F[j, 2, 0] * sq
        l02, l12, l22 = F[j, 0, 2], F[j, 1, 2], F[j, 2, 2]
        l03, l13, l23 = F[j, 0, 3] + F[j, 0, 2] * d, F[j, 1, 3] + F[j, 1, 2] * d, F[j, 2, 3] + F[j, 2, 2] * d
        for r in range(3):
            a0, a1, a2, a3 = out[m, p, r, 0], out[m, p, r, 1], out[m, p, r, 2], out[m, p, r, 3]
            out[m, j + 1, r, 0] = a0 * l00 + a1 * l10 + a2 * l20
            out[m, j + 1, r, 1] = a0 * l01 + a1 * l11 + a2 * l21
            out[m, j + 1, r, 2] = a0 * l02 + a1 * l12 + a2 * l22
            out[m, j + 1, r, 3] = a0 * l03 + a1 * l13 + a2 * l23 + a3
        out[m, j + 1, 3, 0] = out[m, j + 1, 3, 1] = out[m, j + 1, 3, 2] = 0.0
        out[m, j + 1, 3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def chain_frames(Q, F, prismatic, joints, parents, out):
    """Frames out (N, 1 + dof, 4, 4) of a joint chain: out[:, 0] = I, out[:, 1 + j] = out[:, p] @ local_j(q_j).

    F (dof, 4, 4): joint j's frame at q = 0 in its parent's, z its axis; a revolute joint turns about z, a
    prismatic one slides along it. joints, parents: joint j and its parent's slot p (0: the base), parents first.
    Every transform is homogeneous (last row 0, 0, 0, 1): its last row is neither read nor multiplied.
    """
    for n in range(Q.shape[0]):
        frames_of(Q, n, F, prismatic, joints, parents, out, n)
    return out


@numba.njit(cache=True, nogil=True)
def body_poses(frames, slot, off, out):
    """out[n, b] = frames[n, slot[b]] @ off[b]: poses (N, B, 4, 4) of bodies fixed in the chain's frames."""
    for n in range(frames.shape[0]):
        for b in range(slot.shape[0]):
            place_body(frames, n, slot[b], off, b, out, n)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def place_body(frames, i, s, off, b, T, n):
    """T[n, b] = frames[i, s] @ off[b] (homogeneous: the last row is 0, 0, 0, 1 and is not multiplied)."""
    for r in range(3):
        a0, a1, a2, a3 = frames[i, s, r, 0], frames[i, s, r, 1], frames[i, s, r, 2], frames[i, s, r, 3]
        for c in range(4):
            T[n, b, r, c] = a0 * off[b, 0, c] + a1 * off[b, 1, c] + a2 * off[b, 2, c] + a3 * off[b, 3, c]
    T[n, b, 3, 0] = T[n, b, 3, 1] = T[n, b, 3, 2] = 0.0
    T[n, b, 3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def body_boxes(T, center, half, lo, hi):
    """World-aligned boxes lo, hi (N, K, B, 3) around local boxes (centre (K, B, 3), half extent (K, B, 3)) of
    bodies at poses T (N, B, 4, 4)."""
    for n in range(T.shape[0]):
        for k in range(center.shape[0]):
            for b in range(center.shape[1]):
                world_box(T, n, b, center, half, k, lo, hi, n)
    return lo, hi


@numba.njit(cache=True, nogil=True, inline="always")
def world_box(T, n, b, center, half, k, lo, hi, m):
    """lo[m, k, b], hi[m, k, b] = the world-aligned box around body b's local box k (centre center[k, b], half
    extents half[k, b]) at pose T[n, b]."""
    for r in range(3):
        mid = T[n, b, r, 3]
        e = 0.0
        for c in range(3):
            mid += T[n, b, r, c] * center[k, b, c]
            e += abs(T[n, b, r, c]) * half[k, b, c]
        lo[m, k, b, r] = mid - e
        hi[m, k, b, r] = mid + e


@numba.njit(cache=True, nogil=True, inline="always")
def box_centre(Tb, c, w):
    for i in range(3):
        w[i] = Tb[i, 3] + Tb[i, 0] * c[0] + Tb[i, 1] * c[1] + Tb[i, 2] * c[2]


@numba.njit(cache=True, nogil=True, inline="always")
def boxes_apart(Ta, wa, e, Ro, wo, f, R, A, t):
    """True if a separating axis parts box a (rotation Ta[:3, :3], centre wa, half extents e) from box o (rotation
    Ro, centre wo, half extents f): the 15 axes of Ericson, Real-Time Collision Detection 4.4.1, 1e-9 m in the
    boxes' favour. R, A, t: scratch."""
    for i in range(3):  # box o's axes and centre in box a's frame
        t[i] = Ta[0, i] * (wo[0] - wa[0]) + Ta[1, i] * (wo[1] - wa[1]) + Ta[2, i] * (wo[2] - wa[2])
        for j in range(3):
            R[i, j] = Ta[0, i] * Ro[0, j] + Ta[1, i] * Ro[1, j] + Ta[2, i] * Ro[2, j]
            A[i, j] = abs(R[i, j]) + 1e-12  # parallel edges make a cross axis vanish
    for i in range(3):
        if abs(t[i]) > e[i] + f[0] * A[i, 0] + f[1] * A[i, 1] + f[2] * A[i, 2] + 1e-9:
            return True
    for j in range(3):
        s = abs(t[0] * R[0, j] + t[1] * R[1, j] + t[2] * R[2, j])
        if s > e[0] * A[0, j] + e[1] * A[1, j] + e[2] * A[2, j] + f[j] + 1e-9:
            return True
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = e[i1] * A[i2, j] + e[i2] * A[i1, j]
            rb = f[j1] * A[i, j2] + f[j2] * A[i, j1]
            if abs(t[i2] * R[i1, j] - t[i1] * R[i2, j]) > ra + rb + 1e-9:
                return True
    return False


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
    0 of three columns take ~10 x as long: 0.4 ms each for a person-sized map)."""
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


def kernel_array(a, dtype=np.float64) -> np.ndarray:
    """C-contiguous and writable: numba compiles a kernel again for another layout or a read-only array, seconds
    in the middle of a motion on a cold cache."""
    a = np.ascontiguousarray(a, dtype=dtype)
    return a if a.flags.writeable else a.copy()


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now: a first compile takes seconds, too long mid-check."""
    eye = np.eye(4)[None, None].copy()
    frames = np.repeat(eye, 2, axis=1)
    F, prismatic = np.eye(4)[None].copy(), np.zeros(1, bool)
    F.setflags(write=False)  # as a robot model holds them
    prismatic.setflags(write=False)
    chain_frames(np.zeros((1, 1)), F, prismatic, np.zeros(1, np.int64), np.zeros(1, np.int64), np.empty((1, 2, 4, 4)))
    body_poses(frames, np.zeros(1, np.int64), np.eye(4)[None].copy(), np.empty((1, 1, 4, 4)))
    box = np.zeros((1, 1, 3))
    body_boxes(eye, box, box, np.empty((1, 1, 1, 3)), np.empty((1, 1, 1, 3)))
    boxes_hit_table(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(3), 1.0, np.ones(3, np.int64),
                    np.zeros(8, np.int32), np.empty(1, bool))  # fmt: skip
    octree_stream(np.zeros(1, np.uint64), 16)  # the first map's octree and broadphase grid
    keys = np.zeros((1, 3), np.int64)
    keys.setflags(write=False)  # as an occupancy map holds them: numba compiles read-only arrays apart
    count_cells(keys, np.zeros(3, np.int64), 1, np.ones(3, np.int64))
    key_bounds(keys)
    key_bounds(np.zeros((1, 3), np.int64))  # unique_keys' writable copy
    one = np.ones(3, np.int64)
    keys_in_cells(keys, np.zeros(3, np.int64), 1, one, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(3), 1.0)


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
            (keys[i, 0] - key_min[0]) // ratio + 1, (keys[i, 1] - key_min[1]) // ratio + 1,
            (keys[i, 2] - key_min[2]) // ratio + 1,
        ] += 1  # fmt: skip
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
