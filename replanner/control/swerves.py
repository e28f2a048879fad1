"""The controller's reflex: when to swerve and what it sends (the how is `replanner.reflex`)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..collision.exact import CollisionChecker
from ..model.robot import RobotModel
from ..reflex import Reflex
from ..sections import ReflexConfig
from .moves import Moves


class Swerves:
    """Swerves off the running motion, away from the map's voxels near the arm, at most one per `interval`.

    Called by the controller only where its checks let the arm move on: a swerve never stands in for a brake.
    """

    def __init__(
        self,
        robot: RobotModel,
        cfg: ReflexConfig,
        checker: CollisionChecker,
        moves: Moves,
        log_event: Callable[..., None],
    ):
        self.reflex, self.cfg, self.checker, self.moves = Reflex(robot, cfg), cfg, checker, moves
        self.log_event = log_event
        self.count, self.last, self.tried = 0, -math.inf, -math.inf  # swerves sent, the last, the last look

    def __call__(self, now: float, why: str, urgent: bool = False) -> bool:
        """Swerve now if something in the map is near and a detour is free; True if one was sent. A look that found
        none waits `interval` / 3 before the next (`urgent`: the path was just found blocked, look now)."""
        if now - self.last < self.cfg.interval or (not urgent and now - self.tried < self.cfg.interval / 3):
            return False
        self.tried = now
        occ = self.checker.world.snapshot().occupancy
        if occ is None or not len(occ):
            return False

        def detours(traj, t):
            dq = self.reflex.offset_ahead(traj, t, occ.centers, occ.resolution)
            return () if dq is None else self.reflex.detours(traj, t, dq)

        if not self.moves.swerve(detours):
            return False
        self.count, self.last = self.count + 1, now
        self.log_event("swerve", why=why, offset=round(float(np.abs(self.reflex.last_detour).max()), 4))
        return True
