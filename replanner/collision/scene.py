"""What the collision checker derives from one world version: padded bodies, obstacles, masks and pair lists.

A `CollisionScene` is read-only and shared by all threads; `ThreadObjects` holds the FCL objects one thread
moves around (setTransform mutates them). Both are internals of `CollisionChecker`.
"""

from __future__ import annotations

from collections.abc import Set
from dataclasses import dataclass

import fcl
import numpy as np

from ..model.geometry import Shape, bounding_radius, padded_geometry, padded_vertices
from ..model.robot import RobotModel
from ..world.scene import WorldSnapshot
from .boxes import body_poses
from .checker import OCTREE
from .hulls import edge_graph
from .selfclearance import clearance_tables
from .sweep import Sweep


@dataclass(frozen=True, eq=False)
class SceneBody:
    """A robot collision body or an attached object, with its FCL geometry at each padding."""

    name: str
    link: str
    link_index: int
    T_link_body: np.ndarray
    raw_shape: Shape
    env: fcl.CollisionGeometry  # padded by the world padding
    map_: fcl.CollisionGeometry  # padded by the occupancy-map padding
    self_: fcl.CollisionGeometry  # padded by the self padding
    raw: fcl.CollisionGeometry
    env_box: tuple[np.ndarray, np.ndarray]
    map_box: tuple[np.ndarray, np.ndarray]
    self_box: tuple[np.ndarray, np.ndarray]
    raw_box: tuple[np.ndarray, np.ndarray]
    attached: bool
    touch: frozenset[str]

    @classmethod
    def build(cls, robot, name, link, T_lb, shape, attached, touch, padding, map_padding) -> SceneBody:
        env, env_box = padded_geometry(shape, padding)
        if map_padding == padding:
            map_, map_box = env, env_box
        else:
            map_, map_box = padded_geometry(shape, map_padding)
        own, own_box = padded_geometry(shape, robot.self_body_padding)
        raw, raw_box = padded_geometry(shape, 0.0)
        return cls(
            name,
            link,
            robot.link_index(link),
            np.asarray(T_lb, dtype=float),
            shape,
            env,
            map_,
            own,
            raw,
            env_box,
            map_box,
            own_box,
            raw_box,
            attached,
            touch,
        )


def hull_set(bodies, padding: float) -> tuple[np.ndarray, ...]:
    """The padded hulls of `bodies` (body frames) stacked: vertices (V, 3), each body's first vertex (B + 1,), and
    their edges (hulls.edge_graph: first, nb, start) for climbing to supports; a primitive has none."""
    hulls = [padded_vertices(b.raw_shape, padding) for b in bodies]
    first = np.concatenate([[0], np.cumsum([len(v) for v in hulls])]).astype(np.int64)
    return (np.ascontiguousarray(np.concatenate(hulls), dtype=np.float64), first, *edge_graph(hulls))


def ball_radius(shape: Shape, center: np.ndarray) -> float:
    """Radius of a ball around `center` (shape frame) that contains the shape."""
    if hasattr(shape, "vertices"):
        return float(np.linalg.norm(shape.vertices - center, axis=1).max())
    return bounding_radius(shape) + float(np.linalg.norm(center))


class CollisionScene:
    """Everything derived from one world version: bodies, obstacles, pair lists and masks (read-only).

    Args:
        robot: the robot model.
        snap: the world version.
        padding, map_padding: the checker's paddings [m] against static objects and the occupancy map.
        allowed_contacts: (link, object) pairs that may touch; OCTREE names the occupancy map.
    """

    def __init__(
        self,
        robot: RobotModel,
        snap: WorldSnapshot,
        *,
        padding: float,
        map_padding: float,
        allowed_contacts: Set[tuple[str, str]],
    ):
        self.version = snap.version
        bodies: list[SceneBody] = []
        for b in robot.bodies:
            bodies.append(
                SceneBody.build(robot, b.link, b.link, b.T_link_body, b.shape, False, frozenset(), padding, map_padding)
            )
        for a in snap.attachments.values():
            bodies.append(
                SceneBody.build(
                    robot,
                    f"attached:{a.name}",
                    a.link,
                    a.T_link_object,
                    a.shape,
                    True,
                    a.touch_links,
                    padding,
                    map_padding,
                )
            )
        self.bodies = bodies
        self.names = tuple(b.name for b in bodies)
        self.links = tuple(b.link for b in bodies)
        self.shapes = tuple(b.raw_shape for b in bodies)
        B = len(bodies)
        slots, offsets = zip(*(robot.frame_offset(b.link) for b in bodies))
        self.body_slot = np.array(slots, dtype=np.int64)
        self.body_off = np.stack([off @ b.T_link_body for off, b in zip(offsets, bodies)])  # T_frame_body
        # local boxes (centres c, half extents h), padded for the world [0], self checks [1], the map [2]: (3, B, 3)
        c = np.stack([np.stack([getattr(b, k)[0] for b in bodies]) for k in ("env_box", "self_box", "map_box")])
        h = np.stack([np.stack([getattr(b, k)[1] for b in bodies]) for k in ("env_box", "self_box", "map_box")])
        self.box_c, self.box_h = np.ascontiguousarray(c, dtype=np.float64), np.ascontiguousarray(h, dtype=np.float64)
        # the hulls FCL is given against static objects (body frames): their support on an object's box axes
        self.hull_v, self.hull_first, self.hull_edges, self.hull_nb, self.hull_start = hull_set(bodies, padding)
        # and against the robot's own bodies: their support on the other body's box axes
        self.own_v, self.own_first, self.own_edges, self.own_nb, self.own_start = hull_set(
            bodies, robot.self_body_padding
        )
        # bounding balls of the unpadded bodies: centre (B, 4, 1) homogeneous in the body frame, radius (B,)
        self.ball_c = np.stack([np.append(b.raw_box[0], 1.0) for b in bodies])[..., None]
        self.ball_r = np.array([ball_radius(b.raw_shape, b.raw_box[0]) for b in bodies])

        # static obstacles
        self.obstacles = []
        lo, hi, rot, mid, half = [], [], [], [], []
        for o in snap.objects.values():
            g, (c, h) = padded_geometry(o.shape, 0.0)
            self.obstacles.append((o.name, fcl.CollisionObject(g, fcl.Transform(o.pose[:3, :3], o.pose[:3, 3]))))
            R = o.pose[:3, :3]
            wc, wh = R @ c + o.pose[:3, 3], np.abs(R) @ h
            lo.append(wc - wh)
            hi.append(wc + wh)
            rot.append(R)
            mid.append(wc)
            half.append(h)
        O = len(self.obstacles)
        self.obs_lo = np.array(lo).reshape(O, 3)
        self.obs_hi = np.array(hi).reshape(O, 3)
        # the same boxes oriented with their objects (the broadphase's second, tighter test)
        self.obs_R = np.ascontiguousarray(np.array(rot, dtype=np.float64).reshape(O, 3, 3))
        self.obs_c = np.ascontiguousarray(np.array(mid, dtype=np.float64).reshape(O, 3))
        self.obs_h = np.ascontiguousarray(np.array(half, dtype=np.float64).reshape(O, 3))
        self.env_mask = np.ones((B, O), dtype=bool)
        self.octree_mask = np.ones(B, dtype=bool)
        support = {f"attached:{a.name}": a.support for a in snap.attachments.values()}
        for bi, b in enumerate(bodies):
            for oi, (oname, _) in enumerate(self.obstacles):
                if (b.link, oname) in allowed_contacts and not b.attached:
                    self.env_mask[bi, oi] = False
                if b.attached and oname in support[b.name]:
                    self.env_mask[bi, oi] = False  # resting on it until it has left it
            if (b.link, OCTREE) in allowed_contacts and not b.attached:
                self.octree_mask[bi] = False

        # self pairs: the robot's own list plus attached objects against links they may not touch
        nr = len(robot.bodies)
        pairs = [tuple(p) for p in robot.self_collision_pairs]
        self.n_robot_pairs = len(pairs)  # the robot's own pairs come first
        for ai in range(nr, B):
            a = bodies[ai]
            for ri in range(nr):
                if bodies[ri].link not in a.touch and bodies[ri].link != a.link:
                    pairs.append((ri, ai))
        P = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        self.pair_a, self.pair_b = P[:, 0], P[:, 1]
        # robot pairs come first, so table columns index this list directly
        self.tables = clearance_tables(robot)
        self.table_cols = self.tables.pair_index
        box = np.ones(len(P), dtype=bool)
        box[self.table_cols] = False
        self.box_cols = np.flatnonzero(box)
        self.box_a, self.box_b = self.pair_a[self.box_cols], self.pair_b[self.box_cols]
        self.pair_tab = np.full(len(P), -1, dtype=np.int64)  # pair -> its clearance table's index (-1: its boxes)
        self.pair_tab[self.table_cols] = np.arange(len(self.table_cols))

        # per-joint reach of the farthest body point, for path interpolation
        reach = np.zeros(robot.dof)
        for b in bodies:
            radius = bounding_radius(b.raw_shape) + float(np.linalg.norm(b.T_link_body[:3, 3]))
            reach = np.maximum(reach, robot.reach(b.link, radius))
        self.sweep = Sweep(robot, self.body_slot, (self.body_off @ self.ball_c)[:, :3, 0], self.ball_r, reach)
        # what the compiled broadphase reads of this scene, in its order (collision/broadphase.py)
        t = self.tables
        self.broadphase_arrays = (
            *robot.chain,
            self.body_slot,
            self.body_off,
            self.box_c,
            self.box_h,
            self.octree_mask,
            self.env_mask,
            self.obs_lo,
            self.obs_hi,
            self.obs_R,
            self.obs_c,
            self.obs_h,
            self.hull_v,
            self.hull_first,
            self.hull_edges,
            self.hull_nb,
            self.hull_start,
            self.pair_a,
            self.pair_b,
            self.pair_tab,
            t.packed_i,
            t.packed_f,
            t.lookup,
            self.own_v,
            self.own_first,
            self.own_edges,
            self.own_nb,
            self.own_start,
        )

    def body_poses(self, frames: np.ndarray) -> np.ndarray:
        """Body poses (N, B, 4, 4) from the robot's `frames` (N, 1 + dof, 4, 4)."""
        out = np.empty((len(frames), len(self.body_slot), 4, 4))
        return body_poses(np.ascontiguousarray(frames), self.body_slot, self.body_off, out)


class ThreadObjects:
    """FCL collision objects for the bodies, owned by one thread (setTransform mutates them)."""

    def __init__(self, scene: CollisionScene):
        self.scene = scene
        self.env = [fcl.CollisionObject(b.env) for b in scene.bodies]
        self.map_ = [fcl.CollisionObject(b.map_) for b in scene.bodies]
        self.self_ = [fcl.CollisionObject(b.self_) for b in scene.bodies]
        self.raw = [fcl.CollisionObject(b.raw) for b in scene.bodies]
