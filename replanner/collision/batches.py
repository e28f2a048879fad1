"""How a batch's broadphase runs: in halves on two threads when it is large (the broadphase releases the GIL)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

SPLIT_MIN = 256  # configurations a split broadphase takes at least: a second thread's hand-off costs ~30 us
_HELPER: list[ThreadPoolExecutor] = []
_HELPER_LOCK = threading.Lock()

Broadphase = Callable[[int, int], tuple[np.ndarray, int]]  # rows a:b -> (tests, count), row numbers from a


def _second_thread() -> ThreadPoolExecutor:
    """The one thread split broadphases share, started on first use."""
    with _HELPER_LOCK:
        if not _HELPER:
            _HELPER.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="broadphase"))
        return _HELPER[0]


os.register_at_fork(after_in_child=_HELPER.clear)  # a forked child has no helper thread: it starts its own


def run_batch(tests_of: Broadphase, N: int, split: bool) -> tuple[np.ndarray, int]:
    """tests_of over rows 0:N; split: in halves on two threads (the same tests, in the same order)."""
    if not (split and N >= SPLIT_MIN):
        return tests_of(0, N)
    h = N // 2
    first = _second_thread().submit(tests_of, 0, h)
    rest, r = tests_of(h, N)
    found, m = first.result()
    rest[:r, 0] += h
    return np.concatenate([found[:m], rest[:r]]), m + r
