"""The planning layer in front of FCL: spheres first (world/sphere_layer.py), then the convex shapes FCL is given,
compiled (world/convex_pass.py), and FCL for what neither can decide. The verdicts are FCL's."""

from __future__ import annotations

import numpy as np

from .convex_pass import ConvexPass, decide_batch
from .motion_pass import BoundMotion
from .sphere_layer import FREE, UNSURE, SphereScene, VoxelVolume


class FastChecker:
    """A collision checker's verdicts, fast: the sphere layer answers the configurations it finds free or in contact
    for certain, the convex pass most of the rest, `checker` (FCL) what is left; the verdicts are the checker's
    (tests/test_sphere_layer.py).

    Args:
        checker: the exact checker; its world's edits and map updates are followed.
        convex: run the convex pass (False: spheres, then FCL, as before the pass existed).
    """

    def __init__(self, checker, convex: bool = True):
        self.checker = checker
        self.convex = convex
        self._cache: tuple | None = None  # (world version, map, SphereScene, VoxelVolume, ConvexPass, BoundMotion)
        lim = checker.robot.limits
        self._lo, self._hi = lim.lower - 1e-9, lim.upper + 1e-9

    def layer(self) -> tuple[SphereScene, VoxelVolume]:
        """The sphere layer and the map's voxel volume of the world as it is now (built once per version)."""
        c = self._layers()
        return c[2], c[3]

    def warm(self) -> None:
        """Compile (or load) every pass now, not inside the first plan's deadline."""
        c = self._layers()
        q = self.checker.robot.home[None]
        decide_batch(c[4], c[2], self.checker.robot.frames(q), np.zeros(1, np.int64), c[3])
        self.is_valid_batch(q)
        self.path_valid(np.vstack([q, q]))
        VoxelVolume(np.zeros((1, 3), np.int64), 0.01)  # the first map's tables

    def ready(self) -> bool:
        """Whether the layer of the world's present version is built (a new map alone costs next to nothing; an
        edit or an attachment rebuilds the scene's spheres and shapes, ~1 ms)."""
        c = self._cache
        return c is not None and c[0] == self.checker.world.snapshot().version

    def passes(self) -> tuple[SphereScene, VoxelVolume, ConvexPass]:
        """The sphere layer, the map's voxel volume and the convex pass of the world as it is now."""
        c = self._layers()
        return c[2], c[3], c[4]

    def motion(self) -> BoundMotion:
        """The compiled motion check of the world as it is now (what `motion_valid` asks first)."""
        return self._layers()[5]

    def _layers(self) -> tuple:
        c = self._cache
        snap = self.checker.world.snapshot()  # asked thousands of times a plan: the scene only when it changed
        if c is not None and c[0] is snap.version and c[1] is snap.occupancy:
            return c
        scene = self.checker._scene_of(snap)
        if c is None or c[0] != snap.version:
            robot = self.checker.robot
            layer = SphereScene(robot, scene, snap, self.checker.padding, self.checker.map_padding)
            convex = ConvexPass(robot, scene, layer)
        else:
            layer, convex = c[2], c[4]
        vol = VoxelVolume.of(snap.occupancy) if c is None or c[1] is not snap.occupancy else c[3]
        limits = (self._lo, self._hi) if self.checker.check_limits else (None, None)
        motion = BoundMotion(
            self.checker.robot, layer, vol, *limits, scene.sweep, convex=convex if self.convex else None
        )
        c = self._cache = (snap.version, snap.occupancy, layer, vol, convex, motion)
        return c

    def _rows(self, Q) -> np.ndarray:
        Q = np.asarray(Q, dtype=np.float64)
        if Q.ndim != 2 or Q.shape[1] != len(self._lo) or not np.isfinite(Q).all():
            Q = self.checker.robot.check_q(Q)  # raises with the reason
        return Q

    def is_valid_batch(self, Q) -> np.ndarray:
        """Validity (N,) of configurations Q (N, dof), as `checker.is_valid_batch` says."""
        Q = self._rows(Q)
        c = self._layers()
        verdict = c[2].classify(Q, c[3])
        unsure = np.flatnonzero(verdict == UNSURE)
        if self.convex and len(unsure):  # frames for the few the spheres left unsure only
            verdict[unsure] = decide_batch(
                c[4], c[2], self.checker.robot.frames(Q[unsure]), np.arange(len(unsure)), c[3]
            )
        out = verdict == FREE
        if self.checker.check_limits:
            out &= ((Q >= self._lo) & (Q <= self._hi)).all(axis=1)
        rest = np.flatnonzero(verdict == UNSURE)
        if len(rest):
            out[rest] = self.checker.is_valid_batch(Q[rest])
        return out

    def is_valid(self, q) -> bool:
        q = self._rows(np.asarray(q, dtype=float)[None])[0]
        return self.motion_valid(q, q, 0.0)

    def path_valid(self, waypoints, resolution: float | None = None) -> bool:
        """As `checker.path_valid`: each segment as `motion_valid` checks it (the same configurations); certain
        answers stand, FCL decides the unsure ones."""
        W = self._rows(waypoints)
        res = self.checker.path_resolution if resolution is None else resolution
        if len(W) == 1:
            return self.motion_valid(W[0], W[0], 0.0)
        return all(self.motion_valid(a, b, res) for a, b in zip(W[:-1], W[1:]))

    def motion_valid(self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0) -> bool:
        """The straight motion a -> b (float64 (dof,), finite: a planner's own states) checked every `resolution`
        [m] (0: a alone): the spheres in one compiled call, then the convex pass and FCL on what is left. `given`:
        ends the caller knows free in this world, not checked again (1: a, 2: b, 3: both)."""
        c = self._layers()
        if self.convex:  # spheres and the convex pass in one compiled call
            v, rest = c[5].decided(a, b, float(resolution), given)  # an int would compile another specialization
        else:
            v, unsure, Q = c[5](a, b, float(resolution), given)
            rest = Q[unsure]
        return v > 0 and (not len(rest) or bool(self.checker._first_invalid(rest, True)[0].all()))

    def __getattr__(self, name):  # everything else (interpolate, padding, check, ...) is the checker's
        return getattr(self.checker, name)
