"""HOLDING's decisions: resume once the path is clear, plan around from rest, back off, or give up."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from ..monitor import Monitor
from ..planning import StartInvalid
from ..sections import ControllerConfig, Reaction
from .liveness import Liveness


class Act(Enum):
    KEEP_HOLDING = "keep_holding"
    RESUME = "resume"  # along its own path, now clear
    PLAN_AROUND = "plan_around"  # a new path from rest
    RETREAT = "retreat"  # back off along its own curve: no plan can start where it stands
    GIVE_UP = "give_up"  # the goal fails


@dataclass(frozen=True)
class Decision:
    act: Act
    reason: str


def speed_refusal(speed, min_speed_share: float) -> str | None:
    """Why the speed checks' report `speed` stops the arm (too close even at rest, or too slow), or None."""
    if speed.blocking is not None:
        return speed.blocking.reason
    if speed.speed_factor < min_speed_share:
        return f"speed and separation allow {speed.speed_factor:.0%} of the speed"
    return None


class Hold:
    """HOLDING's bookkeeping and decisions: made on entering HOLDING, dropped on leaving it.

    Args:
        since: when the arm braked [controller clock s].
        cfg: the controller config section.
        monitor: judges the way to the goal.
        liveness: tells whether every camera has sent a frame since a given time.
    """

    def __init__(self, since: float, cfg: ControllerConfig, monitor: Monitor, liveness: Liveness):
        self.cfg, self.monitor, self.liveness = cfg, monitor, liveness
        self.since = self.planned = since  # planned: when it last planned around
        self.clear_count, self.clear_since = 0, since  # checks in a row the path was clear, since when
        self.resumable = True  # held on its own path: it may resume it once clear

    def check(self, now: float, view, moving: bool, planning: bool) -> Decision:
        """What to do after a look at the way to the goal; `moving`: still braking; `planning`: a plan is in flight."""
        clear = self.monitor.check_path(view).clear
        self.clear_since = now if clear and self.clear_count == 0 else self.clear_since
        self.clear_count = self.clear_count + 1 if clear else 0
        room = moving or self.monitor.check_speed(view, 0.1).blocking is None  # may it move (people near)? at rest
        # clear for some checks and in a new frame of every camera (cameras may disagree on a voxel, frame by frame)
        seen = self.clear_count >= self.cfg.clear_checks and self.liveness.seen_all_since(self.clear_since)
        refused = None
        if self.resumable and seen and not moving and room:
            # everything that can block, nothing remembered, people's distance fresh: no resume into a blocked path
            final = self.monitor.check_path(view, fresh=True).blocking
            speed = self.monitor.check_speed(view)  # and not one the next check holds again (a hold-resume flap)
            share = self.cfg.speed_separation.min_speed_share
            refused = final.reason if final is not None else speed_refusal(speed, share)
            if refused is None:
                return Decision(Act.RESUME, f"the path was clear for {self.clear_count} checks")
            self.clear_count = 0
        if now - self.since > self.cfg.hold_timeout:
            return Decision(Act.GIVE_UP, f"blocked for {self.cfg.hold_timeout} s")
        # blocked, or held by people near its own path: a new path from rest may keep them at their distance
        if (
            room
            and not moving
            and (refused is not None or not clear)
            and not planning
            and now - self.planned > self._wait()
        ):
            self.planned = now
            return Decision(
                Act.PLAN_AROUND, "blocked, and room to move" if refused is None else f"{refused}: a way round"
            )
        return Decision(Act.KEEP_HOLDING, refused or self._waits_for(moving, room, clear, planning))

    def plan_failed(self, err: Exception) -> Decision:
        """What to do when a plan around failed with `err`."""
        if isinstance(err, StartInvalid):  # stopped where no plan can start: never stuck there
            return Decision(Act.RETREAT, str(err))
        return Decision(Act.KEEP_HOLDING, f"planning around failed ({err}): the next attempt comes later")

    def left_path(self) -> None:
        """It backed off its path: only a new plan takes it on."""
        self.resumable = False

    def _wait(self) -> float:  # replan goes round as soon as the arm stands; stop-and-wait waits first
        if self.cfg.reaction is Reaction.REFLEX:  # the reflex alone never plans: it waits for its own path
            return math.inf
        first = self.planned == self.since and self.cfg.reaction.replans
        return 0.0 if first else self.cfg.hold_replan_interval

    def _waits_for(self, moving: bool, room: bool, clear: bool, planning: bool) -> str:
        if moving:
            return "still braking"
        if not room:
            return "people too close to move"
        if clear:
            return "clear, not yet for long enough" if self.resumable else "off its path: waits for a new plan"
        return "a plan around is in flight" if planning else "the path is blocked"
