"""When the controller checks the motion: at its check rate after a joint state, at once after a new map."""

from __future__ import annotations

import math

MAP_CHECK_GAP = 0.002  # [s] a new map is checked this soon after the last check, whatever the check rate


class CheckClock:
    """The check's clock: whether something new came in, when the last check ran, the recent gap between checks.

    Args:
        period: the check period [s] (1 / check rate).
    """

    def __init__(self, period: float):
        self.period = period
        self.dirty = self.new_map = False  # something to look at; a new map among it
        self.last = -math.inf  # [s] when the last check ran
        self.gap = 0.0  # recent gap between checks, decaying [s]

    def joint_state(self) -> None:
        self.dirty = True

    def map(self) -> None:
        self.dirty = self.new_map = True

    def due(self, now: float) -> float | None:
        """If a check is due now: the time since the last one [s] (0 before the first), and it counts as run."""
        # a new map is looked at at once: a wait would add to the reaction time
        wait = min(self.period, MAP_CHECK_GAP) if self.new_map else self.period
        if not self.dirty or now - self.last < wait:
            return None
        gap = now - self.last if self.last > -math.inf else 0.0
        if not (self.new_map and gap < self.period):  # the next check may still be a whole period away
            self.gap = min(max(gap, 0.9 * self.gap), 0.25)  # a stall is the watchdogs' case
        self.dirty = self.new_map = False
        self.last = now
        return gap
