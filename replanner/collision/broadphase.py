"""The exact checker's broadphase in one compiled pass: per configuration, forward kinematics, the bodies' poses and
boxes, and the pairs whose boxes meet (what FCL must test), in the order FCL tests them. One pass instead of a
kernel per step with Python between them: a path's worth of configurations costs microseconds each. A path's
neighbouring configurations are taken CHUNK at a time: a pair whose boxes over the whole chunk stay apart is not
tested for any of them (the same tests, fewer of them)."""

from __future__ import annotations

import numba
import numpy as np

from ..model.kinematics import frames_of
from ..world.kernels import box_hits_table
from .boxes import box_centre, boxes_apart, place_body, world_box
from .hulls import climb
from .selfclearance import pair_maybe

MAP, OBJECT, SELF = 0, 1, 2  # what a test's second part is: the occupancy map, a static object, another body
GAP = 1e-9  # [m] a hull parted from a box by less is left to FCL
CHUNK = 16  # configurations whose boxes are joined first: a body far from an obstacle is tested once a chunk


@numba.njit(cache=True, nogil=True, inline="always")
def hull_apart(T, n, b, V, R, c, h, first, nb, hint) -> bool:
    """Whether one of a box's axes (rotation R: its axes as columns, centre c, half extents h, world) parts it from
    body b's hull (vertices V in its frame, edges first, nb: hulls.edge_graph, at pose T[n, b]): the hull's
    support along the axis, exact, against the box's half extent, climbed from hint[b] (6: the last lows and highs
    per axis, hull vertices; left at the answers)."""
    for k in range(3):
        # the axis in the body's frame, and the body origin's offset from the box centre along it
        u0 = T[n, b, 0, 0] * R[0, k] + T[n, b, 1, 0] * R[1, k] + T[n, b, 2, 0] * R[2, k]
        u1 = T[n, b, 0, 1] * R[0, k] + T[n, b, 1, 1] * R[1, k] + T[n, b, 2, 1] * R[2, k]
        u2 = T[n, b, 0, 2] * R[0, k] + T[n, b, 1, 2] * R[1, k] + T[n, b, 2, 2] * R[2, k]
        base = (T[n, b, 0, 3] - c[0]) * R[0, k] + (T[n, b, 1, 3] - c[1]) * R[1, k] + (T[n, b, 2, 3] - c[2]) * R[2, k]
        hint[b, 2 * k], low = climb(V, first, nb, hint[b, 2 * k], -u0, -u1, -u2)
        if base - low > h[k] + GAP:
            return True
        hint[b, 2 * k + 1], high = climb(V, first, nb, hint[b, 2 * k + 1], u0, u1, u2)
        if base + high < -h[k] - GAP:
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def _push(tests, m, n, kind, a, b):
    if m == tests.shape[0]:
        grown = np.empty((2 * m + 64, 4), np.int64)
        grown[:m] = tests[:m]
        tests = grown
    tests[m, 0], tests[m, 1], tests[m, 2], tests[m, 3] = n, kind, a, b
    return tests, m + 1


@numba.njit(cache=True, nogil=True)
def broadphase(
    Q,
    origin,
    inv_cell,
    ncell,
    sat,
    objects,
    k0,
    F,
    prismatic,
    joints,
    parents,
    slot,
    off,
    box_c,
    box_h,
    octree_mask,
    env_mask,
    obs_lo,
    obs_hi,
    obs_R,
    obs_c,
    obs_h,
    hull_v,
    hull_first,
    hull_edges,
    hull_nb,
    hull_start,
    pair_a,
    pair_b,
    pair_tab,
    tab_i,
    tab_f,
    table,
    own_v,
    own_first,
    own_edges,
    own_nb,
    own_start,
    T,
    tests,
):
    """T[n] = the body poses (B, 4, 4) of configuration Q[n] (body b: frame slot[b] times off[b]); returns `tests`
    (grown when full) and the count of its rows (n, kind, a, b) filled, the pairs whose boxes meet, per
    configuration in this order:

    - MAP: body a's map box (box_c[2], box_h[2]) overlaps a cell of the map's summed-volume table `sat` (a table of
      one cell: no map) and octree_mask[a];
    - OBJECT (when `objects`): body a's world box (box_c[0], box_h[0]) meets obstacle b's, world-aligned (obs_lo,
      obs_hi) and oriented (obs_R, obs_c, obs_h), the hull FCL is given for body a (hull_v[hull_first[a]:hull_first[a
      + 1]], body frame, edges hull_edges, hull_nb from hull_start[a]: hulls.edge_graph; none: not asked)
      reaches the box on each of its axes, and env_mask[a, b];
    - SELF: pairs k >= k0 (pair_a[k], pair_b[k]): pair_tab[k] >= 0 asks its clearance table (tab_i, tab_f, table),
      the others their self boxes (box_c[1], box_h[1]), world-aligned, then oriented.

    A pair is tested for the configurations of a chunk only when its world-aligned boxes joined over the chunk meet:
    what the joined boxes keep apart, each configuration's keeps apart too.
    """
    N, B, O, dof = Q.shape[0], slot.shape[0], obs_lo.shape[0], Q.shape[1]
    P = pair_a.shape[0]
    frames = np.empty((1, dof + 1, 4, 4))
    lo, hi = np.empty((CHUNK, 3, B, 3)), np.empty((CHUNK, 3, B, 3))
    ulo, uhi = np.empty((3, B, 3)), np.empty((3, B, 3))  # each body's boxes over a chunk of configurations
    near_b, near_o = np.empty(B * O, np.int64), np.empty(B * O, np.int64)
    near_map, near_k = np.empty(B, np.int64), np.empty(P, np.int64)
    R, A = np.empty((3, 3)), np.empty((3, 3))
    t, wa, wb = np.empty(3), np.empty(3), np.empty(3)
    with_map = sat.shape[0] > 1
    hint = np.empty((B, 6), np.int64)  # each hull's last support points: the next configuration's starts
    own_hint = np.empty((B, 6), np.int64)  # the same of the hulls against the robot's own bodies
    for b in range(B):
        hint[b, :] = hull_start[b]
        own_hint[b, :] = own_start[b]
    m = 0
    for n0 in range(0, N, CHUNK):
        n1 = min(N, n0 + CHUNK)
        for n in range(n0, n1):
            frames_of(Q, n, F, prismatic, joints, parents, frames, 0)
            for b in range(B):
                place_body(frames, 0, slot[b], off, b, T, n)
                for k in range(3):
                    if (k == 0 and not objects) or (k == 2 and not with_map):
                        continue
                    world_box(T, n, b, box_c, box_h, k, lo, hi, n - n0)
        # what a chunk's boxes together miss, none of its configurations' boxes meets
        for k in range(3):
            if (k == 0 and not objects) or (k == 2 and not with_map):
                continue
            for b in range(B):
                for r in range(3):
                    a, z = lo[0, k, b, r], hi[0, k, b, r]
                    for i in range(1, n1 - n0):
                        a, z = min(a, lo[i, k, b, r]), max(z, hi[i, k, b, r])
                    ulo[k, b, r], uhi[k, b, r] = a, z
        nm = 0
        if with_map:
            for b in range(B):
                if octree_mask[b] and box_hits_table(
                    ulo[2, b, 0],
                    ulo[2, b, 1],
                    ulo[2, b, 2],
                    uhi[2, b, 0],
                    uhi[2, b, 1],
                    uhi[2, b, 2],
                    origin,
                    inv_cell,
                    ncell,
                    sat,
                ):
                    near_map[nm] = b
                    nm += 1
        no = 0
        if objects:
            for b in range(B):
                for o in range(O):
                    if env_mask[b, o] and not (
                        ulo[0, b, 0] > obs_hi[o, 0] or uhi[0, b, 0] < obs_lo[o, 0]
                        or ulo[0, b, 1] > obs_hi[o, 1] or uhi[0, b, 1] < obs_lo[o, 1]
                        or ulo[0, b, 2] > obs_hi[o, 2] or uhi[0, b, 2] < obs_lo[o, 2]
                    ):  # fmt: skip
                        near_b[no], near_o[no] = b, o
                        no += 1
        nk = 0
        for k in range(k0, P):
            a, b = pair_a[k], pair_b[k]
            if pair_tab[k] >= 0 or not (
                ulo[1, a, 0] > uhi[1, b, 0] or uhi[1, a, 0] < ulo[1, b, 0]
                or ulo[1, a, 1] > uhi[1, b, 1] or uhi[1, a, 1] < ulo[1, b, 1]
                or ulo[1, a, 2] > uhi[1, b, 2] or uhi[1, a, 2] < ulo[1, b, 2]
            ):  # fmt: skip
                near_k[nk] = k
                nk += 1
        for n in range(n0, n1):
            i = n - n0
            for j in range(nm):
                b = near_map[j]
                if box_hits_table(
                    lo[i, 2, b, 0],
                    lo[i, 2, b, 1],
                    lo[i, 2, b, 2],
                    hi[i, 2, b, 0],
                    hi[i, 2, b, 1],
                    hi[i, 2, b, 2],
                    origin,
                    inv_cell,
                    ncell,
                    sat,
                ):
                    tests, m = _push(tests, m, n, MAP, b, 0)
            last = -1
            for j in range(no):
                b, o = near_b[j], near_o[j]
                if (
                    lo[i, 0, b, 0] > obs_hi[o, 0] or hi[i, 0, b, 0] < obs_lo[o, 0]
                    or lo[i, 0, b, 1] > obs_hi[o, 1] or hi[i, 0, b, 1] < obs_lo[o, 1]
                    or lo[i, 0, b, 2] > obs_hi[o, 2] or hi[i, 0, b, 2] < obs_lo[o, 2]
                ):  # fmt: skip
                    continue
                if b != last:
                    box_centre(T[n, b], box_c[0, b], wa)
                    last = b
                if boxes_apart(T[n, b], wa, box_h[0, b], obs_R[o], obs_c[o], obs_h[o], R, A, t):
                    continue
                if hull_first[b + 1] > hull_first[b] and hull_apart(
                    T, n, b, hull_v, obs_R[o], obs_c[o], obs_h[o], hull_edges, hull_nb, hint
                ):
                    continue
                tests, m = _push(tests, m, n, OBJECT, b, o)
            for j in range(nk):
                k = near_k[j]
                a, b = pair_a[k], pair_b[k]
                if pair_tab[k] >= 0:
                    if pair_maybe(Q, n, pair_tab[k], tab_i, tab_f, table):
                        tests, m = _push(tests, m, n, SELF, a, b)
                    continue
                if (
                    lo[i, 1, a, 0] > hi[i, 1, b, 0] or hi[i, 1, a, 0] < lo[i, 1, b, 0]
                    or lo[i, 1, a, 1] > hi[i, 1, b, 1] or hi[i, 1, a, 1] < lo[i, 1, b, 1]
                    or lo[i, 1, a, 2] > hi[i, 1, b, 2] or hi[i, 1, a, 2] < lo[i, 1, b, 2]
                ):  # fmt: skip
                    continue
                box_centre(T[n, a], box_c[1, a], wa)
                box_centre(T[n, b], box_c[1, b], wb)
                if boxes_apart(T[n, a], wa, box_h[1, a], T[n, b, :3, :3], wb, box_h[1, b], R, A, t):
                    continue
                # each hull against the other's box: a link's box is loose where its neighbour's comes close
                if own_first[b + 1] > own_first[b] and hull_apart(
                    T, n, b, own_v, T[n, a, :3, :3], wa, box_h[1, a], own_edges, own_nb, own_hint
                ):
                    continue
                if own_first[a + 1] > own_first[a] and hull_apart(
                    T, n, a, own_v, T[n, b, :3, :3], wb, box_h[1, b], own_edges, own_nb, own_hint
                ):
                    continue
                tests, m = _push(tests, m, n, SELF, a, b)
    return tests, m
