"""The fast checker: spheres first (fast/layer.py), then the convex shapes FCL is given, compiled (fast/convex.py), and
the exact checker for what neither can decide. The verdicts are the exact checker's."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...model.robot import RobotModel
from ...world.occupancy import OccupancyMap
from ...world.scene import World
from ...world.volume import VoxelVolume
from ..checker import Clearance, Contact
from ..exact import CollisionChecker
from .convex import ConvexPass, decide_batch
from .layer import FREE, UNSURE, SphereScene
from .motion import BoundMotion


class Layers(NamedTuple):
    """The fast layers of one world version and one occupancy map."""

    version: int
    occupancy: OccupancyMap | None
    spheres: SphereScene
    volume: VoxelVolume
    convex: ConvexPass
    motion: BoundMotion


class FastChecker:
    """A collision checker's verdicts, fast: the sphere layer answers the configurations it finds free or in contact
    for certain, the convex pass most of the rest, the exact checker (FCL) what is left; the verdicts are the exact
    checker's (tests/test_sphere_layer.py). A `Checker`.

    Args:
        exact: the exact checker; its world's edits and map updates are followed.
        convex: run the convex pass (False: spheres, then FCL).
    """

    def __init__(self, exact: CollisionChecker, convex: bool = True):
        self._exact = exact
        self.convex = convex
        self._cache: Layers | None = None
        lim = exact.robot.limits
        self._lo, self._hi = lim.lower - 1e-9, lim.upper + 1e-9

    # ------------------------------------------------------------------ the exact checker's settings
    @property
    def exact(self) -> CollisionChecker:
        return self._exact

    @property
    def robot(self) -> RobotModel:
        return self._exact.robot

    @property
    def world(self) -> World:
        return self._exact.world

    @property
    def padding(self) -> float:
        return self._exact.padding

    @property
    def map_padding(self) -> float:
        return self._exact.map_padding

    @property
    def path_resolution(self) -> float:
        return self._exact.path_resolution

    # ------------------------------------------------------------------ the layers
    def layers(self) -> Layers:
        """The layers of the world as it is now: the spheres and the convex pass built once per world version (an edit
        or an attachment), the map's volume once per map."""
        c = self._cache
        snap = self._exact.world.snapshot()  # asked thousands of times a plan: the scene only when it changed
        if c is not None and c.version is snap.version and c.occupancy is snap.occupancy:
            return c
        scene = self._exact.scene(snap)
        if c is None or c.version != snap.version:
            spheres = SphereScene(self.robot, scene, snap, self.padding, self.map_padding)
            convex = ConvexPass(self.robot, scene, spheres)
        else:
            spheres, convex = c.spheres, c.convex
        volume = VoxelVolume.of(snap.occupancy) if c is None or c.occupancy is not snap.occupancy else c.volume
        limits = (self._lo, self._hi) if self._exact.check_limits else (None, None)
        motion = BoundMotion(self.robot, spheres, volume, *limits, scene.sweep, convex=convex if self.convex else None)
        c = self._cache = Layers(snap.version, snap.occupancy, spheres, volume, convex, motion)
        return c

    def ready(self) -> bool:
        """Whether the layers of the world's present version are built (a new map alone costs next to nothing)."""
        c = self._cache
        return c is not None and c.version == self._exact.world.snapshot().version

    def prepare(self) -> None:
        """Build the layers of the world's present version now."""
        self.layers()

    def warm(self) -> None:
        """Compile (or load) every pass now, not inside the first plan's deadline."""
        c = self.layers()
        q = self.robot.home[None]
        decide_batch(c.convex, c.spheres, self.robot.frames(q), np.zeros(1, np.int64), c.volume)
        self.is_valid_batch(q)
        self.path_valid(np.vstack([q, q]))
        VoxelVolume(np.zeros((1, 3), np.int64), 0.01)  # the first map's tables

    # ------------------------------------------------------------------ checks
    def _rows(self, Q) -> np.ndarray:
        Q = np.asarray(Q, dtype=np.float64)
        if Q.ndim != 2 or Q.shape[1] != len(self._lo) or not np.isfinite(Q).all():
            Q = self.robot.check_q(Q)  # raises with the reason
        return Q

    def is_valid_batch(self, Q) -> np.ndarray:
        """Validity (N,) of configurations Q (N, dof), as the exact checker's `is_valid_batch` says."""
        Q = self._rows(Q)
        c = self.layers()
        verdict = c.spheres.classify(Q, c.volume)
        unsure = np.flatnonzero(verdict == UNSURE)
        if self.convex and len(unsure):  # frames for the few the spheres left unsure only
            frames = self.robot.frames(Q[unsure])
            verdict[unsure] = decide_batch(c.convex, c.spheres, frames, np.arange(len(unsure)), c.volume)
        out = verdict == FREE
        if self._exact.check_limits:
            out &= ((Q >= self._lo) & (Q <= self._hi)).all(axis=1)
        rest = np.flatnonzero(verdict == UNSURE)
        if len(rest):
            out[rest] = self._exact.is_valid_batch(Q[rest])
        return out

    def is_valid(self, q) -> bool:
        q = self._rows(np.asarray(q, dtype=float)[None])[0]
        return self.motion_valid(q, q, 0.0)

    def check(self, q) -> Contact | None:
        """The exact checker's contact at q (for messages: it locates the contact)."""
        return self._exact.check(q)

    def clearance(self, q, max_distance: float = 1.0) -> Clearance:
        return self._exact.clearance(q, max_distance)

    def interpolate(self, waypoints, resolution: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The configurations a path check tests (the exact checker's: `motion_valid` samples the same)."""
        return self._exact.interpolate(waypoints, resolution)

    def path_valid(self, waypoints, resolution: float | None = None) -> bool:
        """As the exact checker's `path_valid`: each segment as `motion_valid` checks it (the same configurations);
        certain answers stand, FCL decides the unsure ones."""
        W = self._rows(waypoints)
        res = self.path_resolution if resolution is None else resolution
        if len(W) == 1:
            return self.motion_valid(W[0], W[0], 0.0)
        return all(self.motion_valid(a, b, res) for a, b in zip(W[:-1], W[1:]))

    def motion_valid(self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0) -> bool:
        """The straight motion a -> b (float64 (dof,), finite: a planner's own states) checked every `resolution`
        [m] (0: a alone): the spheres in one compiled call, then the convex pass and FCL on what is left. `given`:
        ends the caller knows free in this world, not checked again (1: a, 2: b, 3: both)."""
        c = self.layers()
        if self.convex:  # spheres and the convex pass in one compiled call
            v, rest = c.motion.decided(a, b, float(resolution), given)  # an int would compile another specialization
        else:
            v, unsure, Q = c.motion(a, b, float(resolution), given)
            rest = Q[unsure]
        return v > 0 and (not len(rest) or self._exact.all_valid(rest))
