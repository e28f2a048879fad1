"""What the controller did: its transitions and events, kept for observers, metrics and benches (bounded)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)
CAP = 2000  # records kept of each kind; when full, the oldest half goes


@dataclass(frozen=True)
class TransitionRecord:
    """One state change: when [controller clock s], from, to, which event, why, for which goal."""

    stamp: float
    source: str
    dest: str
    trigger: str
    reason: str
    goal_id: str | None


class History:
    """Transitions and events (time, what, details), and the callbacks that want to hear of them."""

    def __init__(self):
        self.transitions: list[TransitionRecord] = []
        self.events: list[tuple[float, str, dict]] = []
        self._on_transition: list[Callable[[TransitionRecord], None]] = []
        self._on_result: list[Callable] = []

    def subscribe(self, on_transition=None, on_result=None) -> None:
        if on_transition:
            self._on_transition.append(on_transition)
        if on_result:
            self._on_result.append(on_result)

    def transition(self, rec: TransitionRecord) -> None:
        _append(self.transitions, rec)
        log.info("%s -> %s (%s): %s", rec.source, rec.dest, rec.trigger, rec.reason)
        _tell(self._on_transition, rec, "transition")

    def event(self, stamp: float, what: str, details: dict) -> None:
        _append(self.events, (stamp, what, details))
        log.debug("%s at %.3f: %s", what, stamp, details)

    def result(self, result) -> None:
        _tell(self._on_result, result, "result")


def _tell(callbacks: list, item, what: str) -> None:
    for cb in list(callbacks):
        try:
            cb(item)
        except Exception:  # an observer's bug must not stop the controller
            log.exception("%s observer failed", what)


def _append(records: list, item) -> None:
    records.append(item)
    if len(records) > CAP:
        del records[: CAP // 2]
