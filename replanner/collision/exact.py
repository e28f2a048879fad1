"""One collision checker over the robot, the static objects, attached objects and the occupancy octree (FCL).

Each check is a vectorised broadphase in numpy (world-aligned boxes of every robot body against the octree's
summed-volume grid, the static objects' boxes and each other) followed by FCL narrowphase calls only for
the pairs the broadphase cannot rule out. The verdict is always FCL's: the broadphase only skips pairs
whose boxes do not overlap, which cannot collide.

Padding: the robot's bodies are inflated by `padding` for checks against the world (a polytope that contains
every point within `padding` of the body), so `is_valid(q)` is False whenever the clearance is below `padding`.
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
import threading
from collections.abc import Callable, Iterable
from dataclasses import replace

import fcl
import numpy as np

from ..errors import InvalidInputError
from ..model.kinematics import kernel_array
from ..model.robot import RobotModel
from ..world.scene import World, WorldSnapshot
from . import boxes
from .batches import run_batch
from .boxes import body_boxes
from .broadphase import MAP, broadphase
from .checker import OCTREE, BodyPoses, Clearance, Contact, ContactKind, PathCheck
from .scene import CollisionScene, ThreadObjects

log = logging.getLogger(__name__)
_NO_MAP = (np.zeros(3), 1.0, np.zeros(3, np.int64), np.zeros(1, np.int32))  # a one-cell table: no map


class CollisionChecker:
    """Boolean, distance and path checks of a robot against a `World`.

    Args:
        robot: the robot model (its bodies, self-collision pairs and self padding).
        world: static objects, attachments and the occupancy map; edits are seen by the next check.
        padding: safety padding [m] around the robot against the world (not against itself).
        map_padding: padding [m] against the occupancy map (people are there); default: `padding`.
        path_resolution: max displacement [m] of any robot point between two configurations a path check tests.
        allowed_contacts: (link, object) pairs that may touch, e.g. ("panda_link0", "table"); "octree" names
            the occupancy map.
        check_limits: also reject configurations outside the joint position limits.
    """

    def __init__(
        self,
        robot: RobotModel,
        world: World,
        *,
        padding: float = 0.01,
        map_padding: float | None = None,
        path_resolution: float = 0.01,
        allowed_contacts: Iterable[tuple[str, str]] = (),
        check_limits: bool = True,
    ):
        if world.robot is not robot:
            raise InvalidInputError("the world was made for another robot model; build World(robot) with this one")
        if not (0.0 <= padding < 1.0):
            raise InvalidInputError(f"padding must be in [0, 1) m, got {padding}")
        if not (0.0 < path_resolution <= 1.0):
            raise InvalidInputError(f"path_resolution must be in (0, 1] m, got {path_resolution}")
        self.robot = robot
        self.world = world
        self.padding = float(padding)
        self.map_padding = self.padding if map_padding is None else float(map_padding)
        if not (0.0 <= self.map_padding < 1.0):
            raise InvalidInputError(f"map_padding must be in [0, 1) m, got {map_padding}")
        self.path_resolution = float(path_resolution)
        self.check_limits = check_limits
        allowed = set()
        for link, obj in allowed_contacts:
            robot.link_index(link)
            allowed.add((link, obj))
        self.allowed_contacts: frozenset[tuple[str, str]] = frozenset(allowed)
        self._scene: CollisionScene | None = None
        self._scene_lock = threading.Lock()
        self._local = threading.local()
        self._octree_obj: tuple[object, fcl.CollisionObject] | None = None
        self._request = fcl.CollisionRequest()
        self._contact_request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=True)
        self._dist_request = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
        boxes.warm_up()
        self.is_valid(robot.home)  # compile the broadphase and build the scene now, not in the first check of a motion

    @classmethod
    def from_config(cls, robot: RobotModel, world: World, cfg) -> CollisionChecker:
        """Build from a validated `collision` config section."""
        return cls(
            robot,
            world,
            padding=cfg.padding,
            map_padding=cfg.map_padding,
            path_resolution=cfg.path_resolution,
            allowed_contacts=cfg.allowed_contacts,
        )

    # ------------------------------------------------------------------ the world's version
    def scene(self, snap: WorldSnapshot | None = None) -> CollisionScene:
        """What this checker derives from world version `snap` (default: the present one), built once per version."""
        snap = self.world.snapshot() if snap is None else snap
        scene = self._scene
        if scene is None or scene.version != snap.version:
            with self._scene_lock:
                scene = self._scene
                if scene is None or scene.version != snap.version:
                    scene = CollisionScene(
                        self.robot,
                        snap,
                        padding=self.padding,
                        map_padding=self.map_padding,
                        allowed_contacts=self.allowed_contacts,
                    )
                    self._scene = scene
        return scene

    @property
    def exact(self) -> CollisionChecker:
        """This checker: it is the exact one (see `Checker`)."""
        return self

    def ready(self) -> bool:
        """Whether the scene of the world's present version is built (an edit rebuilds it on the next check)."""
        scene = self._scene
        return scene is not None and scene.version == self.world.snapshot().version

    def prepare(self) -> None:
        """Build the scene of the world's present version now."""
        self.scene()

    def warm(self) -> None:
        """Compile and build what a first check needs, now (the constructor did: the scene of a new version)."""
        self.prepare()

    def _current(
        self, occupancy=None
    ) -> tuple[WorldSnapshot, CollisionScene, ThreadObjects, Callable[[], fcl.CollisionObject] | None]:
        snap = self.world.snapshot()
        if occupancy is not None:  # another map than the world's (e.g. only what is new in the world's)
            snap = replace(snap, occupancy=occupancy)
        scene = self.scene(snap)
        objs = getattr(self._local, "objs", None)
        if objs is None or objs.scene is not scene:
            objs = ThreadObjects(scene)
            self._local.objs = objs
        occ = snap.occupancy
        octree = None
        if occ is not None and len(occ):
            octree = functools.partial(self._octree_of, occ, occupancy is None)
        return snap, scene, objs, octree

    def _octree_of(self, occ, keep: bool) -> fcl.CollisionObject:
        """FCL's object of map `occ` (keep: the world's, asked for again and again), built when a test first needs
        it: a check whose bodies meet no voxel's cell never builds the tree (each planning job's map is new)."""
        cached = self._octree_obj
        if cached is None or cached[0] is not occ:
            cached = (occ, fcl.CollisionObject(occ.tree, fcl.Transform()))
            self._octree_obj = cached if keep else self._octree_obj
        return cached[1]

    def _octree_near(self, occ, keep: bool, scene: CollisionScene, T: np.ndarray, found: np.ndarray) -> Callable:
        """`octree` for this batch's map tests (found: broadphase rows): FCL's object of the voxels near the bodies'
        map boxes (OccupancyMap.tree_near), built on first use; the whole map's when that is the answer."""
        sel = found[found[:, 1] == MAP]
        lo, hi = self._aabbs(T, scene.box_c[2:3], scene.box_h[2:3])  # the map boxes of every row: cheap, compiled
        lo, hi = lo[sel[:, 0], 0, sel[:, 2]], hi[sel[:, 0], 0, sel[:, 2]]

        @functools.cache
        def near() -> fcl.CollisionObject:
            tree = occ.tree_near(lo, hi)  # None: the whole map's
            return self._octree_of(occ, keep) if tree is None else fcl.CollisionObject(tree, fcl.Transform())

        return near

    # ------------------------------------------------------------------ broadphase
    def _body_poses(self, scene: CollisionScene, Q: np.ndarray) -> np.ndarray:
        """Body poses (N, B, 4, 4) for configurations Q (N, dof)."""
        return scene.body_poses(self.robot.frames(Q))

    @staticmethod
    def _aabbs(T: np.ndarray, c: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-aligned boxes (N, K, B, 3) of local boxes (centres c, half extents h: (K, B, 3)) at poses T."""
        lo, hi = np.empty((len(T),) + c.shape), np.empty((len(T),) + c.shape)
        body_boxes(np.ascontiguousarray(T), c, h, lo, hi)
        return lo, hi

    # ------------------------------------------------------------------ narrowphase
    def _narrow(self, scene, objs, octree, T_n, tests, locate: bool = False) -> Contact | None:
        """FCL tests for one configuration, in order; returns the first contact found.

        tests: (kind, a, b) with kind 0 = body a vs octree (`octree()`), 1 = body a vs obstacle b, 2 = body a vs body b.
        locate: say where an octree contact is (a second FCL query: for messages, not for validity checks).
        """
        req = self._request
        collide = fcl.collide
        placed_env: dict[int, object] = {}
        placed_map: dict[int, object] = {}
        placed_self: dict[int, object] = {}

        def place(group, placed, bi):
            obj = placed.get(bi)
            if obj is None:
                Tb = T_n[bi]
                obj = group[bi]
                obj.setRotation(Tb[:3, :3])  # 40 % faster than setTransform(fcl.Transform(...)): no Transform built
                obj.setTranslation(Tb[:3, 3])
                placed[bi] = obj
            return obj

        bodies = scene.bodies
        for kind, a, b in tests:
            if kind == 0:
                body = place(objs.map_, placed_map, a)
                if collide(body, octree(), req):
                    near = self._contact_point(body, octree()) if locate else None
                    return Contact(ContactKind.OCTREE, bodies[a].name, OCTREE, near)
            elif kind == 1:
                name, obj = scene.obstacles[b]
                if collide(place(objs.env, placed_env, a), obj, req):
                    return Contact(ContactKind.WORLD, bodies[a].name, name)
            elif collide(place(objs.self_, placed_self, a), place(objs.self_, placed_self, b), req):
                return Contact(ContactKind.SELF, bodies[a].name, bodies[b].name)
        return None

    def _contact_point(self, body, octree) -> tuple[float, float, float] | None:
        res = fcl.CollisionResult()
        fcl.collide(body, octree, self._contact_request, res)
        return tuple(float(v) for v in res.contacts[0].pos) if res.contacts else None

    def _limits_contact(self, q: np.ndarray) -> Contact | None:
        lim = self.robot.limits
        bad = np.flatnonzero((q < lim.lower - 1e-9) | (q > lim.upper + 1e-9))
        return Contact(ContactKind.LIMITS, self.robot.joint_names[bad[0]], "") if len(bad) else None

    def _first_invalid(
        self,
        Q: np.ndarray,
        stop_at_first: bool,
        octree_only: bool = False,
        locate: bool = False,
        occupancy=None,
        robot_pairs: bool = True,
        split: bool = False,
    ) -> tuple[np.ndarray, list[Contact | None]]:
        """Validity (N,) of configurations Q (N, dof); contacts of the invalid ones (None where valid).

        octree_only: test the occupancy map alone (for paths already checked against everything else).
        occupancy: that map instead of the world's. robot_pairs: False skips the robot's own link pairs.
        split: the broadphase of a large batch in halves on two threads (the same tests, in the same order).
        """
        snap, scene, objs, octree = self._current(occupancy)
        N = len(Q)
        valid = np.ones(N, dtype=bool)
        contacts: list[Contact | None] = [None] * N
        if self.check_limits:
            lim = self.robot.limits
            valid &= ((Q >= lim.lower - 1e-9) & (Q <= lim.upper + 1e-9)).all(axis=1)
        T = np.empty((N, len(scene.bodies), 4, 4))
        occ = snap.occupancy
        table = occ.broadphase_table() if occ is not None and len(occ) else _NO_MAP
        k0 = len(scene.pair_a) if octree_only else 0 if robot_pairs else scene.n_robot_pairs
        Qk = kernel_array(Q)
        args = (*table, not octree_only, k0, *scene.broadphase_arrays)

        def tests_of(a: int, b: int):  # rows a:b (the broadphase releases the GIL)
            return broadphase(Qk[a:b], *args, T[a:b], np.empty((max(64, b - a), 4), np.int64))

        found, m = run_batch(tests_of, N, split)
        if octree is not None and occ.local_trees and (found[:m, 1] == MAP).any():
            octree = self._octree_near(occ, occupancy is None, scene, T, found[:m])
        # the narrowphase work per configuration, as plain lists: no numpy call per pair
        tests: dict[int, list] = {}
        for n, kind, a, b in found[:m].tolist():
            tests.setdefault(n, []).append((kind, a, b))
        bad_limits = np.flatnonzero(~valid).tolist()
        for n in sorted(set(tests).union(bad_limits)):
            if not valid[n]:
                contacts[n] = self._limits_contact(Q[n])
            else:
                c = self._narrow(scene, objs, octree, T[n], tests[n], locate)
                if c is None:
                    continue
                valid[n] = False
                contacts[n] = c
            if stop_at_first:
                break
        return valid, contacts

    # ------------------------------------------------------------------ public API
    def is_valid(self, q, octree_only: bool = False) -> bool:
        """True if q [rad] is within limits and collision-free with `padding` against the world.

        octree_only: against the occupancy map alone (with `map_padding`).
        """
        Q = self.robot.check_q(q).reshape(1, -1)
        valid, _ = self._first_invalid(Q, True, octree_only)
        return bool(valid[0])

    def body_poses(self, q) -> BodyPoses:
        """The bodies this checker tests in the current world and their poses T_base_body at q (..., dof) [rad].

        Bodies are the robot's collision bodies (in `robot.bodies` order), then the attached objects; poses
        have shape (..., B, 4, 4). For visualisation and for tests that check the checker against an oracle.
        """
        q = self.robot.check_q(q)
        scene = self.scene()
        T = self._body_poses(scene, q.reshape(-1, self.robot.dof))
        return BodyPoses(scene.names, scene.links, scene.shapes, T.reshape(q.shape[:-1] + T.shape[1:]))

    def all_valid(self, Q) -> bool:
        """Whether every configuration of Q (N, dof) is valid; stops at the first invalid one."""
        Q = self.robot.check_q(Q).reshape(-1, self.robot.dof)
        return bool(self._first_invalid(Q, True)[0].all())

    def motion_valid(self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0) -> bool:
        """Whether the straight motion a -> b is valid, checked every `resolution` [m] (0: a alone); `given` (ends known
        valid) is not needed here: a path check tests each configuration once."""
        if resolution == 0:
            return self.is_valid(a)
        return self.path_valid(np.array([a, b]), resolution)

    def check(self, q) -> Contact | None:
        """None if q is valid, else the first contact found (which link touches what)."""
        Q = self.robot.check_q(q).reshape(1, -1)
        _, contacts = self._first_invalid(Q, True, locate=True)
        return contacts[0]

    def is_valid_batch(self, Q, split: bool = False, octree_only: bool = False) -> np.ndarray:
        """Validity (N,) of configurations Q (N, dof). split: the broadphase of a large batch on two threads.
        octree_only: against the occupancy map alone (with `map_padding`)."""
        Q = self.robot.check_q(Q)
        if Q.ndim != 2:
            raise InvalidInputError(f"Q must be (N, {self.robot.dof}), got shape {Q.shape}")
        valid, _ = self._first_invalid(Q, False, octree_only, split=split)
        return valid

    def clearance(self, q, max_distance: float = 1.0) -> Clearance:
        """Minimum distance [m] from the unpadded robot (and attached objects) to static objects and the octree.

        Obstacles farther than `max_distance` [m] are ignored (the result is then capped at it).
        """
        q = self.robot.check_q(q)
        if q.ndim != 1:
            raise InvalidInputError("clearance takes one configuration (dof,)")
        snap, scene, objs, octree = self._current()
        T = self._body_poses(scene, q.reshape(1, -1))[0]
        best = (float(max_distance), None, None, None, None)
        lo, hi = self._aabbs(T[None], scene.box_c, scene.box_h)
        lo, hi = lo[0, 1] - max_distance, hi[0, 1] + max_distance
        req = self._dist_request

        def measure(bi, other, name):
            nonlocal best
            o = objs.raw[bi]
            Tb = T[bi]
            o.setTransform(fcl.Transform(Tb[:3, :3], Tb[:3, 3]))
            res = fcl.DistanceResult()
            d = fcl.distance(o, other, req, res)
            if d < best[0]:
                best = (float(d), scene.bodies[bi].name, name, res.nearest_points[0], res.nearest_points[1])

        for oi, (name, obj) in enumerate(scene.obstacles):
            near = np.all(lo <= scene.obs_hi[oi], axis=1) & np.all(hi >= scene.obs_lo[oi], axis=1)
            for bi in np.flatnonzero(near & scene.env_mask[:, oi]):
                measure(bi, obj, name)
        if octree is not None:
            occ = snap.occupancy
            near = np.flatnonzero(occ.any_in_boxes(lo, hi) & scene.octree_mask)
            if len(near):
                # lower bound per body: nearest voxel centre to its bounding ball, minus ball and half voxel diagonal
                centers = (T[near] @ scene.ball_c[near])[:, :3, 0]
                gap, _ = occ.kdtree.query(
                    centers, distance_upper_bound=best[0] + scene.ball_r[near].max() + occ.resolution
                )
                bound = gap - scene.ball_r[near] - occ.resolution * np.sqrt(3) / 2
                for k in np.argsort(bound):
                    if bound[k] >= best[0]:
                        break  # no remaining body can be closer than the best found
                    measure(near[k], octree(), OCTREE)
        d, body, obstacle, pa, pb = best
        return Clearance(d, body, obstacle, pa, pb)

    def interpolate(self, waypoints, resolution: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Dense configurations along straight joint-space segments so no robot point moves more than `resolution`.

        Returns (Q (M, dof), segment_position (M,)) where segment_position = i + fraction along segment i.
        """
        W = self.robot.check_q(waypoints, "waypoints")
        if W.ndim != 2 or len(W) < 1:
            raise InvalidInputError(f"waypoints must be (M>=1, {self.robot.dof}), got shape {W.shape}")
        res = self.path_resolution if resolution is None else resolution
        if isinstance(res, bool) or not (isinstance(res, numbers.Real) and math.isfinite(res) and res > 0.0):
            raise InvalidInputError(f"resolution must be a positive number of metres, got {resolution!r}")
        _, scene, _, _ = self._current()
        if len(W) == 1:
            return W.copy(), np.zeros(1)
        return scene.sweep(W, float(res))

    def path_valid(
        self,
        waypoints,
        resolution: float | None = None,
        octree_only: bool = False,
        occupancy=None,
        robot_pairs: bool = True,
    ) -> bool:
        """True if the joint-space segments between waypoints are valid; cheaper than `check_path` when invalid.

        Tests every 8th interpolated configuration first, so a collision is usually found early.
        octree_only: test against the occupancy map alone (the monitor's case: the rest was checked at planning).
        occupancy: test against this map instead of the world's (with octree_only: e.g. what a new map added).
        robot_pairs: False skips the robot's own link pairs (a path's self-collision never changes with the scene).
        """
        Q, _ = self.interpolate(waypoints, resolution)
        stride = 8
        kw = dict(octree_only=octree_only, occupancy=occupancy, robot_pairs=robot_pairs)
        if not self._first_invalid(Q[::stride], True, **kw)[0].all():
            return False
        rest = np.delete(Q, np.arange(0, len(Q), stride), axis=0)
        for start in range(0, len(rest), 512):
            if not self._first_invalid(rest[start : start + 512], True, **kw)[0].all():
                return False
        return True

    def check_path(
        self, waypoints, resolution: float | None = None, chunk: int = 128, robot_pairs: bool = True
    ) -> PathCheck:
        """Check straight joint-space segments between waypoints; report the first colliding configuration.

        robot_pairs: False skips the robot's own link pairs (for paths whose self-collision was checked)."""
        Q, pos = self.interpolate(waypoints, resolution)
        for start in range(0, len(Q), chunk):
            valid, contacts = self._first_invalid(Q[start : start + chunk], True, locate=True, robot_pairs=robot_pairs)
            bad = np.flatnonzero(~valid)
            if len(bad):
                i = start + int(bad[0])
                seg = min(int(pos[i]), len(waypoints) - 2) if len(Q) > 1 else 0
                return PathCheck(False, i + 1, seg, float(pos[i] - seg), Q[i].copy(), contacts[int(bad[0])])
        return PathCheck(True, len(Q))
