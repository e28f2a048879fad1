"""One queue for every input of the controller, drained by one thread: callbacks never block, decisions never race."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from enum import Enum

log = logging.getLogger(__name__)


class Input(Enum):
    JOINT_STATE = "joint_state"
    MAP = "map"
    GOAL = "goal"
    CANCEL = "cancel"
    ANSWER = "answer"
    CALL = "call"  # data(): run in the controller's thread, between its other inputs (tools, fault tests)
    STOP = "stop"


class Inbox:
    """Queues inputs from any thread; `step` (the inbox's thread, or a test driving the clock) handles them all.

    Args:
        handle: handle(kind, data) for each input, in arrival order.
        tick: after the inputs of a step: the periodic work (checks, watchdogs).
        fail: fail(reason) when handling raised: a bug must not silence the controller.
        period: [s] the thread waits at most this long for an input before stepping anyway.
    """

    def __init__(
        self,
        handle: Callable[[Input, object], None],
        tick: Callable[[], None],
        fail: Callable[[str], None],
        period: float,
    ):
        self._handle, self._tick, self._fail, self.period = handle, tick, fail, period
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._step_began: float | None = None  # monotonic, while a step runs

    def stuck_for(self) -> float:
        """How long [s] the step now running has taken (0 between steps); inf if the inbox's thread died."""
        if self._thread is not None and not self._thread.is_alive() and not self._stop.is_set():
            return float("inf")
        began = self._step_began
        return 0.0 if began is None else time.monotonic() - began

    def put(self, kind: Input, data=None) -> None:
        self._queue.put((kind, data))

    def start(self, name: str = "controller") -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.put(Input.STOP)
        if self._thread is not None:
            self._thread.join(timeout=3.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                first = [self._queue.get(timeout=self.period)]
            except queue.Empty:
                first = []
            self.step(first)

    def step(self, events: list | None = None) -> None:
        """Handle `events` and everything queued, then tick."""
        events = list(events or [])
        while True:
            try:
                events.append(self._queue.get_nowait())
            except queue.Empty:
                break
        t0 = time.perf_counter()
        self._step_began = time.monotonic()
        try:
            for kind, data in events:
                self._handle(kind, data)
            self._tick()
            took = time.perf_counter() - t0
            if took > 0.1:
                log.warning(
                    "a controller step took %.0f ms (%d inputs): every reaction waited that long",
                    took * 1e3,
                    len(events),
                )
        except Exception:
            log.exception("controller error")
            self._fail("internal error (see the log)")
        finally:
            self._step_began = None
