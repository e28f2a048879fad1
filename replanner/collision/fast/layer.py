"""The sphere layer, fast and conservative: the robot (and what it carries) as spheres that cover
its bodies, static objects as primitives (boxes, spheres, cylinders exactly; other shapes as covering spheres),
the occupancy map as a summed-volume table of its voxels. `classify` says which configurations are free (or in
contact) for certain; FCL decides the rest, so every verdict stays FCL's and only the near misses pay for it.

Every test is conservative: a sphere grown by as far as FCL's padded shape reaches (a polytope's inradius factor,
√3 paddings at a padded box's corners), a voxel
counted when it touches the sphere's bounding box, self pairs compared sphere to sphere.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...model.geometry import Box, Cylinder, Sphere, padding_directions
from ...model.kinematics import frames_of, kernel_array
from ...world.scene import WorldSnapshot
from ...world.volume import VoxelVolume, ball_in_map, map_box
from ..scene import CollisionScene
from ..selfclearance import may_collide_row
from .layer_args import LayerArgs, layer_args
from .spheres import cover, refined

BOX, BALL, CYLINDER = 0, 1, 2
CONTACT, UNSURE, FREE = -1, 0, 1  # what `SphereScene.classify` says of a configuration


def _grow_factor(shape, polytope: float) -> float:
    """A padded shape reaches this many paddings beyond the shape at most: boxes grow at their corners."""
    return (
        math.sqrt(3.0)
        if isinstance(shape, Box)
        else math.sqrt(2.0)
        if isinstance(shape, Cylinder)
        else (1.0 if isinstance(shape, Sphere) else polytope)
    )


def _inradius_factor() -> float:
    """FCL's padded polytopes reach this many paddings from the body at most (see geometry.padded)."""
    return float(np.linalg.norm(padding_directions(), axis=1).max())


class SphereScene:
    """The sphere layer of one collision scene (read-only, shared by threads).

    Args:
        robot: the robot model (its chain, and its self padding between two bodies).
        scene: the checker's scene of this world version (bodies, masks, self pairs).
        snap: the same world version (its objects' shapes and poses).
        padding, map_padding: the checker's paddings [m] from known objects and from the occupancy map.
    """

    def __init__(self, robot, scene: CollisionScene, snap: WorldSnapshot, padding: float, map_padding: float):
        grow = _inradius_factor()
        slot, local, rad, body = [], [], [], []
        first, in_first, in_local, in_rad = [0], [0], [], []
        placed = []  # (shape, T_slot_shape) of each body, for the map's finer second look
        for bi, b in enumerate(scene.bodies):
            sp = cover(b.raw_shape)
            s, off = robot.frame_offset(b.link)
            T = off @ b.T_link_body
            placed.append((b.raw_shape, T))
            slot += [s] * len(sp)
            local.append(sp.center @ T[:3, :3].T + T[:3, 3])
            rad.append(sp.radius)
            body += [bi] * len(sp)
            first.append(first[-1] + len(sp))
            ic = np.zeros((0, 3)) if sp.inner_center is None else sp.inner_center
            in_local.append(ic @ T[:3, :3].T + T[:3, 3])
            in_rad.append(np.zeros(0) if sp.inner_radius is None else sp.inner_radius)
            in_first.append(in_first[-1] + len(ic))
        self.fine_local, self.fine_rad, self.fine_ptr, self.fine_idx = refined(placed)
        self.in_local = np.ascontiguousarray(np.concatenate(in_local))
        self.in_rad = np.concatenate(in_rad)
        self.in_first = np.array(in_first, dtype=np.int64)
        self.local = np.ascontiguousarray(np.concatenate(local))
        self.radius = np.concatenate(rad)
        self.body = np.array(body, dtype=np.int64)
        self.padding = float(padding)
        self.fk = robot.chain  # for `classify`
        self._args: tuple | None = None  # (volume, its LayerArgs)
        self.env_pad, self.map_pad, self.self_pad = float(padding), float(map_padding), float(robot.self_body_padding)
        # how far a padding p takes each padded body beyond its shape, per p (geometry.padded)
        self.gf = np.array([_grow_factor(b.raw_shape, grow) for b in scene.bodies])
        if (self.gf < 1.0).any():  # a padding grown by m must grow each sphere by m at least (fast/motion.py)
            raise RuntimeError(f"a body's padding grows it by less than the padding: factors {self.gf}")
        # self pairs of bodies; a body's spheres are first[b]:first[b + 1], inside a ball (slot, centre, radius)
        self.first = np.array(first, dtype=np.int64)
        # pairs that are always close (link 5 and 7) have clearance tables; the spheres take the others
        self.pair_a, self.pair_b = scene.box_a.astype(np.int64), scene.box_b.astype(np.int64)
        t = scene.tables
        self.tab_i, self.tab_f = t.packed_i, t.packed_f
        self.tab = t.lookup
        ball_c, ball_r, ball_slot = [], [], []
        for bi in range(len(scene.bodies)):
            c, r = self.local[first[bi] : first[bi + 1]], self.radius[first[bi] : first[bi + 1]]
            mid = (c - r[:, None]).min(axis=0) / 2 + (c + r[:, None]).max(axis=0) / 2
            ball_c.append(mid)
            ball_r.append(float((np.linalg.norm(c - mid, axis=1) + r).max()))
            ball_slot.append(slot[first[bi]])
        self.ball_c, self.ball_r = np.array(ball_c), np.array(ball_r)
        self.ball_slot = np.array(ball_slot, dtype=np.int64)
        # per joint: how far any sphere centre moves per unit of it (a body's spheres lie within its ball)
        self.reach = np.zeros(robot.dof)
        for s, c, r in zip(ball_slot, ball_c, ball_r):
            self.reach = np.maximum(self.reach, robot.frame_reach(int(s), float(np.linalg.norm(c)) + r))
        # obstacles: kind, world -> obstacle (3, 4), dimensions, world box, index in the scene's obstacle list
        kind, inv, dim, box, oid, exact = [], [], [], [], [], []
        names = [name for name, _ in scene.obstacles]
        for oi, name in enumerate(names):
            o = snap.objects[name]
            R, t = o.pose[:3, :3], o.pose[:3, 3]
            primitive = isinstance(o.shape, (Box, Sphere, Cylinder))
            if primitive:
                parts = [(np.zeros(3), o.shape)]
            else:
                sp = cover(o.shape)
                parts = [(c, Sphere(radius=float(r))) for c, r in zip(sp.center, sp.radius)]
            for c, shape in parts:
                exact.append(primitive)  # covering spheres reach past the object: a touch of them is not a contact
                kind.append(BOX if isinstance(shape, Box) else BALL if isinstance(shape, Sphere) else CYLINDER)
                inv.append(np.c_[R.T, -R.T @ (t + R @ c)])
                if isinstance(shape, Box):
                    dim.append(np.asarray(shape.size) / 2)
                elif isinstance(shape, Sphere):
                    dim.append([shape.radius, 0.0, 0.0])
                else:
                    dim.append([shape.radius, shape.length / 2, 0.0])
                d = dim[-1]
                half = d if kind[-1] == BOX else [d[0]] * 3 if kind[-1] == BALL else [d[0], d[0], d[1]]
                mid, ext = t + R @ c, np.abs(R) @ np.asarray(half, float) + 1e-9  # rounding in the boxes' favour
                box.append([*(mid - ext), *(mid + ext)])
                oid.append(oi)
        self.ob_kind = np.array(kind, dtype=np.int64)
        self.ob_inv = np.array(inv, dtype=np.float64).reshape(-1, 3, 4)
        self.ob_dim = np.array(dim, dtype=np.float64).reshape(-1, 3)
        self.ob_box = np.array(box, dtype=np.float64).reshape(-1, 6)  # lows, highs: a ball's box misses it, so does it
        self.ob_id = np.array(oid, dtype=np.int64)
        self.ob_exact = np.array(exact, dtype=np.bool_)
        self.env_mask = np.ascontiguousarray(scene.env_mask)
        self.octree_mask = np.ascontiguousarray(scene.octree_mask)

    def classify(self, Q: np.ndarray, volume: VoxelVolume | None, parallel: bool = False) -> np.ndarray:
        """Per configuration Q (N, dof): FREE (free for certain), CONTACT (in contact for certain: a ball inside a
        body meets a primitive or a ball inside another body) or UNSURE (ask FCL). Forward kinematics runs inside,
        one configuration at a time. `parallel`: on every core (large batches, one calling thread at a time)."""
        out = np.zeros(len(Q), dtype=np.int8)
        Q = kernel_array(Q)
        args = (self.env_pad, self.map_pad, self.self_pad, self.kernel_args(volume), out)
        if parallel:
            _classify_parallel(Q, *args)
        else:
            verdicts(Q, np.arange(len(Q)), False, *args)
        return out

    def kernel_args(self, volume: VoxelVolume | None) -> LayerArgs:
        """What `verdicts` and the convex pass read: the chain, the spheres, the obstacles and the map's volume (built
        once per volume)."""
        vol = volume or VoxelVolume.EMPTY
        last = self._args
        if last is not None and last[0] is vol:
            return last[1]
        args = layer_args(
            *self.fk,
            self.tab_i,
            self.tab_f,
            self.tab,
            self.local,
            self.radius,
            self.first,
            self.in_local,
            self.in_rad,
            self.in_first,
            self.ball_slot,
            self.ball_c,
            self.ball_r,
            self.gf,
            self.env_mask,
            self.ob_kind,
            self.ob_inv,
            self.ob_dim,
            self.ob_id,
            self.ob_exact,
            self.ob_box,
            self.octree_mask,
            vol.sat,
            vol.csat,
            vol.key_min,
            vol.inv_res,
            self.pair_a,
            self.pair_b,
            self.fine_local,
            self.fine_rad,
            self.fine_ptr,
            self.fine_idx,
            vol.whole,
        )
        self._args = (vol, args)  # one tuple: threads see the old pair or the new one
        return args


# The helpers below take arrays and indices, never a row's view: a view costs a reference count in the hot loop.


@numba.njit(cache=True, nogil=True, inline="always")
def primitive_distance(ob_inv, o, k, ob_dim, x, y, z):
    """Distance [m] from point (x, y, z) to solid primitive o (0 inside): kind k, world -> primitive ob_inv[o]."""
    p0 = ob_inv[o, 0, 0] * x + ob_inv[o, 0, 1] * y + ob_inv[o, 0, 2] * z + ob_inv[o, 0, 3]
    p1 = ob_inv[o, 1, 0] * x + ob_inv[o, 1, 1] * y + ob_inv[o, 1, 2] * z + ob_inv[o, 1, 3]
    p2 = ob_inv[o, 2, 0] * x + ob_inv[o, 2, 1] * y + ob_inv[o, 2, 2] * z + ob_inv[o, 2, 3]
    if k == 0:
        q0 = max(abs(p0) - ob_dim[o, 0], 0.0)
        q1 = max(abs(p1) - ob_dim[o, 1], 0.0)
        q2 = max(abs(p2) - ob_dim[o, 2], 0.0)
        return np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if k == 1:
        return max(np.sqrt(p0 * p0 + p1 * p1 + p2 * p2) - ob_dim[o, 0], 0.0)
    qr = max(np.sqrt(p0 * p0 + p1 * p1) - ob_dim[o, 0], 0.0)
    qz = max(abs(p2) - ob_dim[o, 1], 0.0)
    return np.sqrt(qr * qr + qz * qz)


@numba.njit(cache=True, nogil=True, inline="always")
def ball_meets_box(ob_box, o, x, y, z, r) -> bool:
    """Whether the box around the ball at (x, y, z) of radius r meets obstacle o's world box (lows, highs)."""
    b = ob_box[o]
    return ball_near_box(b[0], b[1], b[2], b[3], b[4], b[5], x, y, z, r)


@numba.njit(cache=True, nogil=True, inline="always")
def spheres_meet_primitive(C, rad, first, last, grow, ob_inv, o, kind, ob_dim) -> bool:
    """Whether any placed sphere C[first:last] (radii grown by `grow`) meets primitive o of kind `kind`."""
    for s in range(first, last):
        if primitive_distance(ob_inv, o, kind, ob_dim, C[s, 0], C[s, 1], C[s, 2]) <= rad[s] + grow:
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def spheres_meet_body(C, rad, a0, a1, b0, b1, BC, ba, bb, ball_r, grow, sel) -> bool:
    """Whether a placed sphere of body ba's C[a0:a1] meets one of body bb's C[b0:b1] (radii grown by `grow`
    together); each body's bounding ball (centres BC, radii ball_r) rules out most of the other's spheres first.
    `sel`: scratch for bb's spheres near ba's ball."""
    ax, ay, az, ar = BC[ba, 0], BC[ba, 1], BC[ba, 2], ball_r[ba] + grow
    m = 0
    for c in range(b0, b1):
        d0, d1, d2 = C[c, 0] - ax, C[c, 1] - ay, C[c, 2] - az
        if d0 * d0 + d1 * d1 + d2 * d2 <= (rad[c] + ar) ** 2:
            sel[m] = c
            m += 1
    if m == 0:
        return False
    bx, by, bz, br = BC[bb, 0], BC[bb, 1], BC[bb, 2], ball_r[bb] + grow
    for a in range(a0, a1):
        d0, d1, d2 = C[a, 0] - bx, C[a, 1] - by, C[a, 2] - bz
        if d0 * d0 + d1 * d1 + d2 * d2 > (rad[a] + br) ** 2:
            continue  # this sphere is apart from the other body's ball
        for i in range(m):
            c = sel[i]
            d0, d1, d2 = C[a, 0] - C[c, 0], C[a, 1] - C[c, 1], C[a, 2] - C[c, 2]
            reach = rad[a] + rad[c] + grow
            if d0 * d0 + d1 * d1 + d2 * d2 <= reach * reach:
                return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def ball_near_box(lo0, lo1, lo2, hi0, hi1, hi2, x, y, z, g) -> bool:
    """Whether the ball at (x, y, z) of radius g meets the box [lo, hi]."""
    return lo0 <= x + g and x - g <= hi0 and lo1 <= y + g and y - g <= hi1 and lo2 <= z + g and z - g <= hi2


@numba.njit(cache=True, nogil=True, inline="always")
def pair_grow(BC, ball_r, gf, self_pad, a, b) -> float:
    """The padding [m] two bodies' spheres are grown by together, or -1 when their bounding balls (centres BC[a],
    BC[b]) are apart even with it: the pair needs no sphere test."""
    d0, d1, d2 = BC[a, 0] - BC[b, 0], BC[a, 1] - BC[b, 1], BC[a, 2] - BC[b, 2]
    sg = self_pad * (gf[a] + gf[b])
    reach = ball_r[a] + ball_r[b] + sg
    return -1.0 if d0 * d0 + d1 * d1 + d2 * d2 > reach * reach else sg


@numba.njit(cache=True, nogil=True, inline="always")
def spheres_meet_map(C, rad, first, last, grow, sat, csat, key_min, inv_res) -> bool:
    """Whether any placed sphere C[first:last] (radii grown by `grow`) may meet a voxel of the map."""
    for s in range(first, last):
        if ball_in_map(sat, csat, key_min, inv_res, C[s, 0], C[s, 1], C[s, 2], rad[s] + grow):
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def place_points(frames, n, slot, P, first, last, out):
    """out[first:last] = P[first:last] placed by the frame frames[n, slot]."""
    for s in range(first, last):
        x, y, z = P[s, 0], P[s, 1], P[s, 2]
        for r in range(3):
            out[s, r] = (
                frames[n, slot, r, 0] * x
                + frames[n, slot, r, 1] * y
                + frames[n, slot, r, 2] * z
                + frames[n, slot, r, 3]
            )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def verdicts(Q, order, stop, env_pad, map_pad, self_pad, L, out):
    """out[n] for each n of `order` in turn: the verdict on configuration Q[n], forward kinematics included (1 free
    for certain, -1 in contact for certain, 0 unsure), L the layer's `LayerArgs`. `stop`: return at the first
    contact, its index in `order`; else (or none) -1. One loop with everything inlined: a call per configuration
    with these arrays would cost more in reference counting than the configuration's own checks."""
    Fj, prismatic, joints, parents = L.Fj, L.prismatic, L.joints, L.parents
    tab_i, tab_f, table = L.tab_i, L.tab_f, L.table
    local, rad, first, in_local, in_rad, in_first = L.local, L.rad, L.first, L.in_local, L.in_rad, L.in_first
    ball_slot, ball_c, ball_r, gf, env_mask = L.ball_slot, L.ball_c, L.ball_r, L.gf, L.env_mask
    ob_kind, ob_inv, ob_dim, ob_id, ob_exact, ob_box = L.ob_kind, L.ob_inv, L.ob_dim, L.ob_id, L.ob_exact, L.ob_box
    octree_mask, sat, csat, key_min, inv_res = L.octree_mask, L.sat, L.csat, L.key_min, L.inv_res
    pair_a, pair_b = L.pair_a, L.pair_b
    B, O, dof = ball_slot.shape[0], ob_kind.shape[0], Q.shape[1]
    frames = np.empty((1, dof + 1, 4, 4))  # one configuration's frames: they stay in cache
    C, IC = np.empty((local.shape[0], 3)), np.empty((in_local.shape[0], 3))
    BC, near = np.empty((B, 3)), np.empty(O, np.int64)
    placed = np.zeros(B, np.bool_)  # a body's spheres are placed only when its ball meets something
    placed_in = np.zeros(B, np.bool_)  # and its inner balls only when a sphere meets something
    sel = np.empty(local.shape[0], np.int64)
    m0, m1, m2, M0, M1, M2 = map_box(sat, key_min, inv_res)  # a ball outside it needs no look at the map
    for t in range(order.shape[0]):
        n = order[t]
        frames_of(Q, n, Fj, prismatic, joints, parents, frames, 0)
        for b in range(B):
            place_points(frames, 0, ball_slot[b], ball_c, b, b + 1, BC)
            placed[b] = placed_in[b] = False
        verdict = 1
        for b in range(B):
            x, y, z = BC[b, 0], BC[b, 1], BC[b, 2]
            m = 0  # the obstacles this body's ball meets: only they are tested sphere by sphere
            eg, mg = env_pad * gf[b], map_pad * gf[b]
            reach = ball_r[b] + eg
            for o in range(O):
                if not env_mask[b, ob_id[o]] or not ball_meets_box(ob_box, o, x, y, z, reach):
                    continue
                if primitive_distance(ob_inv, o, ob_kind[o], ob_dim, x, y, z) <= reach:
                    near[m] = o
                    m += 1
            if m > 0 and not placed[b]:
                place_points(frames, 0, ball_slot[b], local, first[b], first[b + 1], C)
                placed[b] = True
            hit = False  # a covering sphere meets an obstacle: then maybe an inner ball does too (certain)
            for i in range(m):
                if spheres_meet_primitive(
                    C, rad, first[b], first[b + 1], eg, ob_inv, near[i], ob_kind[near[i]], ob_dim
                ):
                    hit = True
                    break
            if hit:
                verdict = 0
                place_points(frames, 0, ball_slot[b], in_local, in_first[b], in_first[b + 1], IC)
                placed_in[b] = True
                for i in range(m):
                    o = near[i]
                    if not ob_exact[o]:
                        continue
                    for k in range(in_first[b], in_first[b + 1]):
                        if primitive_distance(ob_inv, o, ob_kind[o], ob_dim, IC[k, 0], IC[k, 1], IC[k, 2]) < in_rad[k]:
                            verdict = -1
                            break
                    if verdict == -1:
                        break
                if verdict == -1:
                    break
            if verdict == 1 and octree_mask[b] and ball_near_box(m0, m1, m2, M0, M1, M2, x, y, z, ball_r[b] + mg):
                if ball_in_map(sat, csat, key_min, inv_res, x, y, z, ball_r[b] + mg):
                    if not placed[b]:
                        place_points(frames, 0, ball_slot[b], local, first[b], first[b + 1], C)
                        placed[b] = True
                    if spheres_meet_map(C, rad, first[b], first[b + 1], mg, sat, csat, key_min, inv_res):
                        verdict = 0
        if verdict != -1:
            for p in range(pair_a.shape[0]):
                ba, bb = pair_a[p], pair_b[p]
                sg = pair_grow(BC, ball_r, gf, self_pad, ba, bb)
                if sg < 0.0:
                    continue
                for bo in (ba, bb):
                    if not placed[bo]:
                        place_points(frames, 0, ball_slot[bo], local, first[bo], first[bo + 1], C)
                        placed[bo] = True
                if not spheres_meet_body(
                    C, rad, first[ba], first[ba + 1], first[bb], first[bb + 1], BC, ba, bb, ball_r, sg, sel
                ):
                    continue
                verdict = 0
                for bo in (ba, bb):  # inner balls are placed only when a contact for certain may be found
                    if not placed_in[bo]:
                        place_points(frames, 0, ball_slot[bo], in_local, in_first[bo], in_first[bo + 1], IC)
                        placed_in[bo] = True
                for a in range(in_first[ba], in_first[ba + 1]):  # two inner balls overlap: a contact for certain
                    for c in range(in_first[bb], in_first[bb + 1]):
                        d0, d1, d2 = IC[a, 0] - IC[c, 0], IC[a, 1] - IC[c, 1], IC[a, 2] - IC[c, 2]
                        reach = in_rad[a] + in_rad[c]
                        if d0 * d0 + d1 * d1 + d2 * d2 < reach * reach:
                            verdict = -1
                            break
                    if verdict == -1:
                        break
                if verdict == -1:
                    break
        if verdict == 1 and tab_i.shape[0] and may_collide_row(Q, n, tab_i, tab_f, table):
            verdict = 0  # the always-close pairs: their tables may only say "maybe"
        out[n] = verdict
        if verdict == -1 and stop:
            return t
    return -1


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _classify_parallel(Q, env_pad, map_pad, self_pad, L, out):
    N, chunk = Q.shape[0], 256
    for c in numba.prange((N + chunk - 1) // chunk):
        lo, hi = c * chunk, min(N, (c + 1) * chunk)
        verdicts(Q, np.arange(lo, hi), False, env_pad, map_pad, self_pad, L, out)
