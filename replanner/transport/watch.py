"""The robot side's watch on the service: its liveliness token and its status stream (a heartbeat). A robot that
follows trajectories must not go on trusting a service that died or hangs: it brakes along its path."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from .keys import Keys

log = logging.getLogger(__name__)


class ServiceWatch:
    """Calls `on_lost(reason)` when the service's liveliness token goes, or when its status has been silent for
    `max_age` [s] (once per silence; armed by the first status heard).

    Args:
        session: the robot's Zenoh session.
        keys: the robot's keys (namespace and robot name).
        max_age: [s] of status silence that make the service lost.
        on_lost: called from a Zenoh or the watch's thread: must not block.
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        max_age: float,
        on_lost: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
    ):
        self.max_age, self.on_lost, self.clock = max_age, on_lost, clock
        self.last_status: float | None = None
        self.lost = 0  # times the service was found gone
        self._silent = False
        self._stop = threading.Event()
        self._subs = [
            session.liveliness().declare_subscriber(keys.alive, self._on_alive, history=True),
            session.declare_subscriber(keys.status, self._on_status),
        ]
        self._thread = threading.Thread(target=self._run, name="service-watch", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        for s in self._subs:
            s.undeclare()
        self._thread.join(timeout=2.0)

    def _lose(self, reason: str) -> None:
        self.lost += 1
        log.warning("service lost: %s", reason)
        try:
            self.on_lost(reason)
        except Exception:
            log.exception("the robot's reaction to a lost service failed")

    def _on_alive(self, sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            self._lose("its liveliness token is gone (the service stopped or its process died)")

    def _on_status(self, sample) -> None:
        self.last_status, self._silent = self.clock(), False

    def _run(self) -> None:
        while not self._stop.wait(self.max_age / 10):
            last = self.last_status
            if last is not None and not self._silent and self.clock() - last > self.max_age:
                self._silent = True
                self._lose(f"its status stream has been silent for more than {self.max_age} s")
