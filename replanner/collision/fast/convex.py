"""The second pass of the planning layer: configurations the spheres could not decide, decided on the convex shapes
FCL is given (fast/gjk.py), compiled; near the map, by a finer cover of spheres tested exactly against the voxels
(free) and by balls inside the body grown by the padding (in contact). What it cannot decide (the map's closest
misses, meshes that are not primitives, shapes within a micrometre of touching) stays FCL's.
"""

from __future__ import annotations

import numba
import numpy as np

from ...model.geometry import Box, ConvexHull, Mesh, padding_directions
from ...world.volume import ball_in_map, box_sum, map_box
from ..hulls import edge_graph
from ..scene import CollisionScene
from .gjk import APART, POINTS, TOUCH, decide
from .layer import (
    SphereScene,
    ball_near_box,
    pair_grow,
    place_points,
    primitive_distance,
    spheres_meet_body,
    spheres_meet_primitive,
)

TOL = 1e-6  # [m] closer than this, or touching by less, is FCL's to decide
CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


class ConvexPass:
    """The bodies' convex shapes (points and padding directions in their frames' slots) and the primitives' poses
    of one collision scene; read-only, shared by threads.

    Args:
        robot: the robot model; scene: its collision scene; layer: the sphere layer of the same scene.
    """

    def __init__(self, robot, scene: CollisionScene, layer: SphereScene):
        ico = padding_directions()
        P, D, pf, df, supported = [], [], [0], [0], []
        for b in scene.bodies:
            s, off = robot.frame_offset(b.link)
            T = off @ b.T_link_body
            shape = b.raw_shape
            if isinstance(shape, ConvexHull) or (isinstance(shape, Mesh) and shape.convex):
                pts, dirs = np.asarray(shape.vertices, float), ico  # geometry.padded: the hull of pts + padding * ico
            elif isinstance(shape, Box):
                pts, dirs = CORNERS * np.asarray(shape.size) / 2, CORNERS  # a padded box grows by the padding
            else:
                pts, dirs = np.zeros((1, 3)), np.zeros((0, 3))  # balls, cylinders, concave meshes: FCL's
            supported.append(len(dirs) > 0)
            P.append(pts @ T[:3, :3].T + T[:3, 3])
            D.append(dirs @ T[:3, :3].T)
            pf.append(pf[-1] + len(pts))
            df.append(df[-1] + len(dirs))
        self.P, self.D = np.ascontiguousarray(np.vstack(P)), np.ascontiguousarray(np.vstack(D).reshape(-1, 3))
        self.pfirst, self.dfirst = np.array(pf, np.int64), np.array(df, np.int64)
        self.supported = np.array(supported, np.bool_)
        self.hv_first, self.hv_nb, self.hv_start = edge_graph(P)  # GJK's supports climb the hulls' edges
        # primitives: shape -> world (the inverse of the sphere layer's world -> shape)
        R = np.transpose(layer.ob_inv[:, :, :3], (0, 2, 1))
        t = -np.einsum("oij,oj->oi", R, layer.ob_inv[:, :, 3])
        self.ob_R, self.ob_t = np.ascontiguousarray(R), np.ascontiguousarray(t)
        self.pair_a, self.pair_b = scene.pair_a.astype(np.int64), scene.pair_b.astype(np.int64)


def decide_batch(
    cp: ConvexPass, layer: SphereScene, frames: np.ndarray, idx: np.ndarray, vol, stop: bool = False
) -> np.ndarray:
    """Verdicts (len(idx),) on configurations frames[idx]: 1 free, -1 in contact, 0 FCL's to decide. `stop`:
    return at the first contact (the rest stay 0)."""
    out = np.zeros(len(idx), np.int8)
    decide_all(
        np.ascontiguousarray(frames),
        np.asarray(idx, np.int64),
        out,
        stop,
        cp.P,
        cp.D,
        cp.pfirst,
        cp.dfirst,
        cp.supported,
        layer.env_pad,
        layer.self_pad,
        layer.map_pad,
        cp.ob_R,
        cp.ob_t,
        cp.pair_a,
        cp.pair_b,
        cp.hv_first,
        cp.hv_nb,
        cp.hv_start,
        layer.kernel_args(vol),
    )
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _placed(F, P, k):
    """Point P[k] of a body's frame, placed by that frame's pose F (4, 4): world x, y, z."""
    x, y, z = P[k, 0], P[k, 1], P[k, 2]
    return (
        F[0, 0] * x + F[0, 1] * y + F[0, 2] * z + F[0, 3],
        F[1, 0] * x + F[1, 1] * y + F[1, 2] * z + F[1, 3],
        F[2, 0] * x + F[2, 1] * y + F[2, 2] * z + F[2, 3],
    )


@numba.njit(cache=True, nogil=True, inline="always")
def fine_meets_map(
    F, C, rad, first, last, grow, fine_local, fine_rad, fine_ptr, fine_idx, sat, csat, key_min, inv_res
) -> bool:
    """`spheres_meet_map` looked at again: the fine spheres (`SphereScene.fine_*`, placed by the body's frame F) of
    each placed sphere C[first:last] that may meet a voxel; whether any of those may."""
    for s in range(first, last):
        if not ball_meets_cells(sat, csat, key_min, inv_res, C[s, 0], C[s, 1], C[s, 2], rad[s] + grow):
            continue
        for e in range(fine_ptr[s], fine_ptr[s + 1]):
            f = fine_idx[e]
            wx, wy, wz = _placed(F, fine_local, f)
            if ball_meets_cells(sat, csat, key_min, inv_res, wx, wy, wz, fine_rad[f] + grow):
                return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def inner_meets_map(F, in_local, in_rad, first, last, grow, sat, csat, key_min, inv_res) -> bool:
    """Whether a ball inside the body (in_local[first:last], placed by its frame F), grown by `grow` (less than the
    padding: the padded body holds it), meets a voxel (cells of one voxel each): a contact for certain."""
    for k in range(first, last):
        wx, wy, wz = _placed(F, in_local, k)
        if ball_meets_cells(sat, csat, key_min, inv_res, wx, wy, wz, in_rad[k] + grow):
            return True
    return False


@numba.njit(cache=True, nogil=True)
def ball_meets_cells(sat, csat, key_min, inv_res, x, y, z, r) -> bool:
    """Whether the ball at (x, y, z) [m] of radius r meets an occupied cell of the volume (sat, csat, key_min,
    inv_res: VoxelVolume's), exactly: its bounding cube's cells halved while they hold one and the ball reaches
    them (ball_in_map asks the cube alone, whose corners reach 0.7 r past the ball)."""
    if not ball_in_map(sat, csat, key_min, inv_res, x, y, z, r):
        return False
    c = 1.0 / inv_res
    n0, n1, n2 = sat.shape[0] - 2, sat.shape[1] - 2, sat.shape[2] - 2  # the last cell index per axis
    stack = np.empty((64, 6), np.int64)  # boxes of cells [a, b], inclusive, relative to key_min
    stack[0] = (
        max(np.int64(np.floor((x - r) * inv_res)) - key_min[0], 0),
        max(np.int64(np.floor((y - r) * inv_res)) - key_min[1], 0),
        max(np.int64(np.floor((z - r) * inv_res)) - key_min[2], 0),
        min(np.int64(np.floor((x + r) * inv_res)) - key_min[0], n0),
        min(np.int64(np.floor((y + r) * inv_res)) - key_min[1], n1),
        min(np.int64(np.floor((z + r) * inv_res)) - key_min[2], n2),
    )
    top, rr = 1, r * r
    while top > 0:
        top -= 1
        a0, a1, a2, b0, b1, b2 = stack[top]
        if a0 > b0 or a1 > b1 or a2 > b2 or box_sum(sat, a0, a1, a2, b0 + 1, b1 + 1, b2 + 1) == 0:
            continue
        # the box's nearest point to the centre: farther than r, nothing in it meets the ball
        lo0, lo1, lo2 = (a0 + key_min[0]) * c, (a1 + key_min[1]) * c, (a2 + key_min[2]) * c
        hi0, hi1, hi2 = (b0 + 1 + key_min[0]) * c, (b1 + 1 + key_min[1]) * c, (b2 + 1 + key_min[2]) * c
        d0 = lo0 - x if x < lo0 else x - hi0 if x > hi0 else 0.0
        d1 = lo1 - y if y < lo1 else y - hi1 if y > hi1 else 0.0
        d2 = lo2 - z if z < lo2 else z - hi2 if z > hi2 else 0.0
        if d0 * d0 + d1 * d1 + d2 * d2 > rr:
            continue
        if a0 == b0 and a1 == b1 and a2 == b2:
            return True  # an occupied cell the ball reaches
        # halve along the longest side
        if b0 - a0 >= b1 - a1 and b0 - a0 >= b2 - a2:
            m = (a0 + b0) // 2
            stack[top] = (a0, a1, a2, m, b1, b2)
            stack[top + 1] = (m + 1, a1, a2, b0, b1, b2)
        elif b1 - a1 >= b2 - a2:
            m = (a1 + b1) // 2
            stack[top] = (a0, a1, a2, b0, m, b2)
            stack[top + 1] = (a0, m + 1, a2, b0, b1, b2)
        else:
            m = (a2 + b2) // 2
            stack[top] = (a0, a1, a2, b0, b1, m)
            stack[top + 1] = (a0, a1, m + 1, b0, b1, b2)
        top += 2
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def _merge(verdict, r):
    """One pair's answer folded into the configuration's: a contact decides it, the band leaves it to FCL."""
    return -1 if r == TOUCH else verdict if r == APART else 0


@numba.njit(cache=True, nogil=True)
def decide_all(
    frames,
    idx,
    out,
    stop,
    P,
    D,
    pfirst,
    dfirst,
    supported,
    env_pad,
    self_pad,
    map_pad,
    ob_R,
    ob_t,
    pair_a,
    pair_b,
    hv_first,
    hv_nb,
    hv_start,
    L,
):
    """`decide_batch`'s verdicts into out, L the sphere layer's `LayerArgs` (pair_a, pair_b: the scene's pairs)."""
    local, rad, first, in_local, in_rad, in_first = L.local, L.rad, L.first, L.in_local, L.in_rad, L.in_first
    ball_slot, ball_c, ball_r, gf, env_mask = L.ball_slot, L.ball_c, L.ball_r, L.gf, L.env_mask
    ob_kind, ob_inv, ob_dim, ob_id, ob_exact = L.ob_kind, L.ob_inv, L.ob_dim, L.ob_id, L.ob_exact
    octree_mask, sat, csat, key_min, inv_res, whole = L.octree_mask, L.sat, L.csat, L.key_min, L.inv_res, L.whole
    fine_local, fine_rad, fine_ptr, fine_idx = L.fine_local, L.fine_rad, L.fine_ptr, L.fine_idx
    B, O = ball_slot.shape[0], ob_kind.shape[0]
    hint = hv_start.copy()  # each body's last support point: the next configuration's start
    BC, C = np.empty((B, 3)), np.empty((local.shape[0], 3))
    sel = np.empty(local.shape[0], np.int64)
    S, small, none = np.empty((4, 3)), np.empty(3), np.zeros(3)
    placed = np.zeros(B, np.bool_)
    m0, m1, m2, M0, M1, M2 = map_box(sat, key_min, inv_res)  # a ball outside it needs no look at the map
    for j in range(idx.shape[0]):
        n = idx[j]
        for b in range(B):
            place_points(frames, n, ball_slot[b], ball_c, b, b + 1, BC)
            placed[b] = False
        verdict = APART
        for b in range(B):
            F = frames[n, ball_slot[b]]
            x, y, z = BC[b, 0], BC[b, 1], BC[b, 2]
            eg = env_pad * gf[b]
            for o in range(O):
                if not env_mask[b, ob_id[o]]:
                    continue
                if primitive_distance(ob_inv, o, ob_kind[o], ob_dim, x, y, z) > ball_r[b] + eg:
                    continue
                if not placed[b]:
                    place_points(frames, n, ball_slot[b], local, first[b], first[b + 1], C)
                    placed[b] = True
                if not spheres_meet_primitive(C, rad, first[b], first[b + 1], eg, ob_inv, o, ob_kind[o], ob_dim):
                    continue  # the covering spheres are clear of it: so is the body
                if not (supported[b] and ob_exact[o]):
                    verdict = 0
                    continue
                r = decide(
                    POINTS,
                    F[:3, :3],
                    F[:3, 3],
                    none,
                    P,
                    pfirst[b],
                    pfirst[b + 1],
                    D,
                    dfirst[b],
                    dfirst[b + 1],
                    env_pad,
                    ob_kind[o],
                    ob_R[o],
                    ob_t[o],
                    ob_dim[o],
                    0,
                    0,
                    0,
                    0,
                    0.0,
                    TOL,
                    S,
                    small,
                    hv_first,
                    hv_nb,
                    hint,
                    b,
                    -1,
                )
                verdict = _merge(verdict, r)
                if verdict == -1:
                    break
            if verdict == -1:
                break
            mg = map_pad * gf[b]
            # the map's voxels: the spheres' test, then the finer spheres' where those meet a voxel, else FCL's
            if verdict == APART and octree_mask[b] and ball_near_box(m0, m1, m2, M0, M1, M2, x, y, z, ball_r[b] + mg):
                if ball_in_map(sat, csat, key_min, inv_res, x, y, z, ball_r[b] + mg):
                    if not placed[b]:
                        place_points(frames, n, ball_slot[b], local, first[b], first[b + 1], C)
                        placed[b] = True
                    if fine_meets_map(
                        F,
                        C,
                        rad,
                        first[b],
                        first[b + 1],
                        mg,
                        fine_local,
                        fine_rad,
                        fine_ptr,
                        fine_idx,
                        sat,
                        csat,
                        key_min,
                        inv_res,
                    ):
                        verdict = 0
                        if whole and inner_meets_map(
                            F,
                            in_local,
                            in_rad,
                            in_first[b],
                            in_first[b + 1],
                            map_pad - TOL,
                            sat,
                            csat,
                            key_min,
                            inv_res,
                        ):
                            verdict = -1
                            break
        if verdict != -1:
            for p in range(pair_a.shape[0]):
                a, b = pair_a[p], pair_b[p]
                sg = pair_grow(BC, ball_r, gf, self_pad, a, b)
                if sg < 0.0:
                    continue
                for bo in (a, b):
                    if not placed[bo]:
                        place_points(frames, n, ball_slot[bo], local, first[bo], first[bo + 1], C)
                        placed[bo] = True
                if not spheres_meet_body(
                    C, rad, first[a], first[a + 1], first[b], first[b + 1], BC, a, b, ball_r, sg, sel
                ):
                    continue
                if not (supported[a] and supported[b]):
                    verdict = 0
                    continue
                Fa, Fb = frames[n, ball_slot[a]], frames[n, ball_slot[b]]
                r = decide(
                    POINTS,
                    Fa[:3, :3],
                    Fa[:3, 3],
                    none,
                    P,
                    pfirst[a],
                    pfirst[a + 1],
                    D,
                    dfirst[a],
                    dfirst[a + 1],
                    self_pad,
                    POINTS,
                    Fb[:3, :3],
                    Fb[:3, 3],
                    none,
                    pfirst[b],
                    pfirst[b + 1],
                    dfirst[b],
                    dfirst[b + 1],
                    self_pad,
                    TOL,
                    S,
                    small,
                    hv_first,
                    hv_nb,
                    hint,
                    a,
                    b,
                )
                verdict = _merge(verdict, r)
                if verdict == -1:
                    break
        out[j] = verdict
        if verdict == -1 and stop:
            return
