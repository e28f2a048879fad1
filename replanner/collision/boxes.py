"""Compiled box geometry of the exact checker (numba): bodies placed by the chain's frames, their world-aligned boxes,
and the separating-axis test of two oriented boxes."""

from __future__ import annotations

import numba
import numpy as np


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


def warm_up() -> None:
    """Compile (or load from the cache) the box kernels now: a first compile takes seconds, too long mid-check."""
    eye = np.eye(4)[None, None].copy()
    frames = np.repeat(eye, 2, axis=1)
    body_poses(frames, np.zeros(1, np.int64), np.eye(4)[None].copy(), np.empty((1, 1, 4, 4)))
    box = np.zeros((1, 1, 3))
    body_boxes(eye, box, box, np.empty((1, 1, 1, 3)), np.empty((1, 1, 1, 3)))
