"""HOLDING: the arm braked on its path and waits; it resumes once the path is clear, plans around from rest, backs
off where no plan can start, or gives up (part of the controller, apart for its size)."""

from __future__ import annotations

import math

from ..planning.worker import JobPurpose
from ..sections import Reaction
from .goals import GoalStatus


class Holding:
    """The controller's HOLDING decisions (mixed into `Controller`, whose state they read and change)."""

    def _check_holding(self, now: float, view) -> None:
        moving, clear = self.moves.timeline.moving(now), self.monitor.check_path(view).clear
        self._clear_since = now if clear and self._clear_count == 0 else self._clear_since
        self._clear_count = self._clear_count + 1 if clear else 0
        room = moving or self.monitor.check_speed(view, 0.1).blocking is None  # may it move (people near)? at rest
        # clear for some checks and in a new frame of every camera (cameras may disagree on a voxel, frame by frame)
        seen = self._clear_count >= self.cfg.clear_checks and self.liveness.seen_all_since(self._clear_since)
        if self._resumable and seen and not moving and room:
            # everything that can block, nothing remembered, people's distance fresh: no resume into a blocked path
            final = self.monitor.check_path(view, fresh=True).blocking
            speed = self.monitor.check_speed(view)  # and not one the next check holds again (a hold-resume flap)
            if final is None and self._speed_refusal(speed) is None:
                self.moves.resume()
                self.resume(reason=f"the path was clear for {self._clear_count} checks")
                return
            self._clear_count = 0
        if now - self._hold_since > self.cfg.hold_timeout:
            self._finish(GoalStatus.FAILED, f"the path stayed blocked for {self.cfg.hold_timeout} s")
            self.give_up(reason=f"blocked for {self.cfg.hold_timeout} s")
        elif room and not (moving or clear) and self._job is None and now - self._hold_planned > self._hold_wait():
            self._hold_planned = now
            self._launch(JobPurpose.HOLD, self._deadline())

    def _speed_refusal(self, speed) -> str | None:
        """Why the speed checks' report `speed` stops the arm (too close even at rest, or too slow), or None."""
        if speed.blocking is not None:
            return speed.blocking.reason
        if speed.speed_factor < self.cfg.speed_separation.min_speed_share:
            return f"speed and separation allow {speed.speed_factor:.0%} of the speed"
        return None

    def _start_blocked(self, traj, now: float) -> str | None:
        """Why a new path from rest may not start now (speed and separation would stop it at once), or None."""
        q = self.measured()
        return None if q is None else self._speed_refusal(self.monitor.check_start(traj, now, q))

    def _hold_wait(self) -> float:  # replan goes round as soon as the arm stands; stop-and-wait waits first
        if self.cfg.reaction is Reaction.REFLEX:  # the reflex alone never plans: it waits for its own path
            return math.inf
        first = self._hold_planned == self._hold_since and self.cfg.reaction.replans
        return 0.0 if first else self.cfg.hold_replan_interval

    def _retreat(self, why: str) -> None:
        """Stopped where no plan can start: back off along its own curve (see Moves.escape), never stuck."""
        arc = self.moves.escape()
        if arc is None:
            self.log_event("stuck", why=why)
        else:
            self.log_event("retreat", arc=arc, why=why)
            self._resumable = False  # off its path now: only a new plan takes it on
