"""Numba kernels that meet new argument types after a stack is running: each is a warm-up that missed them.

A first compile holds the GIL for up to seconds (LLVM runs under it): in the middle of a motion that silences
perception and the monitor with it. Every kernel the hot path calls is compiled when the stack is built
(the modules' `warm_up`); a call with other argument types (a strided array, a read-only one, another dtype)
compiles a new specialization on first use, or loads it from numba's cache when another run compiled it: the next
machine, with a cold cache, stalls. `watch()` names each compile in the log as it happens; `new_signatures()`
finds every specialization added since, compiled or loaded.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from numba.core import event
from numba.core.dispatcher import Dispatcher

log = logging.getLogger(__name__)


class _Listener(event.Listener):
    def __init__(self):
        self._started: dict[tuple[int, int], float] = {}

    def on_start(self, ev):
        self._started[(threading.get_ident(), id(ev.data["dispatcher"]))] = time.perf_counter()

    def on_end(self, ev):
        t0 = self._started.pop((threading.get_ident(), id(ev.data["dispatcher"])), None)
        fn = ev.data["dispatcher"].py_func
        if not fn.__module__.startswith("replanner.") or t0 is None or getattr(_building, "depth", 0):
            return  # numba's own helpers compile inside our kernels' compiles; a stack being built warms up
        log.warning(
            "kernel %s.%s compiled while running (%.2f s holding the GIL on thread %r) for %s: its module's warm_up "
            "misses these argument types",
            fn.__module__,
            fn.__qualname__,
            time.perf_counter() - t0,
            threading.current_thread().name,
            ev.data.get("args"),
        )


_listener: _Listener | None = None
_known: dict[str, tuple[Dispatcher, int]] = {}  # kernel -> (its dispatcher, specializations it had)
_lock = threading.Lock()
_building = threading.local()


@contextmanager
def building() -> Iterator[None]:
    """Compiles on this thread inside the block are warm-ups (a stack being built), not late."""
    _building.depth = getattr(_building, "depth", 0) + 1
    try:
        yield
    finally:
        _building.depth -= 1


def _kernels() -> dict[str, Dispatcher]:
    """The replanner kernels imported so far, by module.function."""
    found = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("replanner.") or module is None:
            continue
        for obj in list(vars(module).values()):
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                found[f"{name}.{obj.py_func.__qualname__}"] = obj
    return found


def watch(start: bool = True) -> None:
    """From now on, log every compile of a replanner kernel in this process outside `building()`, and remember the
    specializations there are now: called after each stack a process builds, whose warm-ups are not late (start:
    False only remembers, if watching has started)."""
    global _listener
    with _lock:
        if _listener is None:
            if not start:
                return
            _listener = _Listener()
            event.register("numba:compile", _listener)
        _known.update((k, (d, len(d.signatures))) for k, d in _kernels().items())


def new_signatures() -> list[tuple[str, str]]:
    """The specializations added since `watch()` (compiled or loaded from the cache), each logged once; counts
    only, microseconds: the planning child asks after every job."""
    fresh = []
    with _lock:
        for kernel, (d, n) in _known.items():
            sigs = d.signatures
            if len(sigs) > n:
                fresh += [(kernel, str(sig)) for sig in sigs[n:]]
                _known[kernel] = (d, len(sigs))
    for kernel, sig in fresh:
        log.warning("kernel %s met argument types its warm_up does not cover: %s", kernel, sig)
    return sorted(fresh)
