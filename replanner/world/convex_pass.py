"""The second pass of the planning layer: configurations the spheres could not decide, decided on the convex shapes
FCL is given (world/gjk.py), compiled. What it cannot decide (the map's voxels, meshes that are not primitives,
shapes within a micrometre of touching) stays FCL's.
"""

from __future__ import annotations

import numba
import numpy as np

from .collision_scene import CollisionScene
from .geometry import Box, ConvexHull, Mesh, padding_directions
from .gjk import APART, POINTS, TOUCH, decide
from .hull_graph import edge_graph
from .sphere_layer import (
    SphereScene,
    _place,
    ball_in_map,
    ball_near_box,
    map_box,
    pair_grow,
    primitive_distance,
    spheres_meet_body,
    spheres_meet_map,
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
    _decide_all(
        np.ascontiguousarray(frames), np.asarray(idx, np.int64), out, stop, cp.P, cp.D, cp.pfirst, cp.dfirst,
        cp.supported, layer.env_pad, layer.self_pad, cp.ob_R, cp.ob_t, cp.pair_a, cp.pair_b, layer.local, layer.radius,
        layer.first, layer.ball_slot, layer.ball_c, layer.ball_r, layer.gf, layer.map_pad, layer.env_mask,
        layer.ob_kind, layer.ob_inv, layer.ob_dim, layer.ob_id, layer.ob_exact, layer.octree_mask, vol.sat,
        vol.csat, vol.key_min, vol.inv_res, cp.hv_first, cp.hv_nb, cp.hv_start,
    )  # fmt: skip
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _merge(verdict, r):
    """One pair's answer folded into the configuration's: a contact decides it, the band leaves it to FCL."""
    return -1 if r == TOUCH else verdict if r == APART else 0


@numba.njit(cache=True, nogil=True)
def _decide_all(
    frames, idx, out, stop, P, D, pfirst, dfirst, supported, env_pad, self_pad, ob_R, ob_t, pair_a, pair_b,
    local, rad, first, ball_slot, ball_c, ball_r, gf, map_pad, env_mask,
    ob_kind, ob_inv, ob_dim, ob_id, ob_exact, octree_mask, sat, csat, key_min, inv_res, hv_first, hv_nb, hv_start,
):  # fmt: skip
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
            _place(frames, n, ball_slot[b], ball_c, b, b + 1, BC)
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
                    _place(frames, n, ball_slot[b], local, first[b], first[b + 1], C)
                    placed[b] = True
                if not spheres_meet_primitive(C, rad, first[b], first[b + 1], eg, ob_inv, o, ob_kind[o], ob_dim):
                    continue  # the covering spheres are clear of it: so is the body
                if not (supported[b] and ob_exact[o]):
                    verdict = 0
                    continue
                r = decide(
                    POINTS, F[:3, :3], F[:3, 3], none, P, pfirst[b], pfirst[b + 1], D, dfirst[b], dfirst[b + 1],
                    env_pad, ob_kind[o], ob_R[o], ob_t[o], ob_dim[o], 0, 0, 0, 0, 0.0, TOL, S, small, hv_first, hv_nb,
                    hint, b, -1,
                )  # fmt: skip
                verdict = _merge(verdict, r)
                if verdict == -1:
                    break
            if verdict == -1:
                break
            mg = map_pad * gf[b]
            # the map's voxels: the spheres' test, else FCL's
            if verdict == APART and octree_mask[b] and ball_near_box(m0, m1, m2, M0, M1, M2, x, y, z, ball_r[b] + mg):
                if ball_in_map(sat, csat, key_min, inv_res, x, y, z, ball_r[b] + mg):
                    if not placed[b]:
                        _place(frames, n, ball_slot[b], local, first[b], first[b + 1], C)
                        placed[b] = True
                    if spheres_meet_map(C, rad, first[b], first[b + 1], mg, sat, csat, key_min, inv_res):
                        verdict = 0
        if verdict != -1:
            for p in range(pair_a.shape[0]):
                a, b = pair_a[p], pair_b[p]
                sg = pair_grow(BC, ball_r, gf, self_pad, a, b)
                if sg < 0.0:
                    continue
                for bo in (a, b):
                    if not placed[bo]:
                        _place(frames, n, ball_slot[bo], local, first[bo], first[bo + 1], C)
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
                    POINTS, Fa[:3, :3], Fa[:3, 3], none, P, pfirst[a], pfirst[a + 1], D, dfirst[a], dfirst[a + 1],
                    self_pad, POINTS, Fb[:3, :3], Fb[:3, 3], none, pfirst[b], pfirst[b + 1], dfirst[b], dfirst[b + 1],
                    self_pad, TOL, S, small, hv_first, hv_nb, hint, a, b,
                )  # fmt: skip
                verdict = _merge(verdict, r)
                if verdict == -1:
                    break
        out[j] = verdict
        if verdict == -1 and stop:
            return
