"""Path shortcutting: fewer, shorter straight segments between a found path's waypoints, bounded by counts (a
deadline may only cut it short). The planner's `shortcut` runs it with its own motion check and random state."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

MAX_MISSES = 6  # random shortcuts that fail in a row end the tries


def shortcut(
    W: np.ndarray,
    motion_ok: Callable[[np.ndarray, np.ndarray], bool],
    rng: np.random.Generator,
    *,
    tries: int,
    t_end: float = math.inf,
    clock: Callable[[], float] = time.perf_counter,
    remember: bool = True,
    pieces: bool = True,
) -> np.ndarray:
    """Skip waypoints, try up to `tries` random shortcuts between points of the path, skip again.

    motion_ok(a, b): is the straight motion a -> b free? `t_end` (a time of `clock`) keeps the rest of the path as
    it is once passed (valid, only longer). `remember`: ask about each straight motion once (the second skip asks
    again of the waypoints the first one kept); the path is the same either way. `pieces`: the pieces a shortcut
    keeps of the two segments it cuts are checked as segments of their own; False only where a finer check of the
    result decides (they lie on segments already checked at this resolution)."""
    known: dict[tuple[bytes, bytes], bool] = {}

    def reachable(a: np.ndarray, b: np.ndarray) -> bool:
        if not remember:
            return motion_ok(a, b)
        key = (a.tobytes(), b.tobytes())
        ok = known.get(key)
        if ok is None:
            ok = known[key] = motion_ok(a, b)
        return ok

    W = skip_waypoints(W, reachable, t_end, clock)
    misses = done = 0
    while done < tries and len(W) > 2 and misses < MAX_MISSES and clock() < t_end:
        done += 1
        seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
        acc = np.concatenate([[0.0], np.cumsum(seg)])
        a, b = np.sort(rng.uniform(0, acc[-1], 2))
        ia = min(int(np.searchsorted(acc, a, side="right") - 1), len(seg) - 1)
        ib = min(int(np.searchsorted(acc, b, side="right") - 1), len(seg) - 1)
        if ia == ib:
            continue
        pa = W[ia] + (a - acc[ia]) / seg[ia] * (W[ia + 1] - W[ia])
        pb = W[ib] + (b - acc[ib]) / seg[ib] * (W[ib + 1] - W[ib])
        # with `pieces`, the kept pieces of the cut segments are checked as segments of their own: at other
        # configurations than the whole, a line within the padding between two of them may touch it at one of these
        if motion_ok(pa, pb) and (not pieces or (reachable(W[ia], pa) and reachable(pb, W[ib + 1]))):
            W = np.vstack([W[: ia + 1], pa, pb, W[ib + 1 :]])
            misses = 0
        else:
            misses += 1
    return skip_waypoints(W, reachable, t_end, clock)


def skip_waypoints(
    W: np.ndarray,
    reachable: Callable[[np.ndarray, np.ndarray], bool],
    t_end: float = math.inf,
    clock: Callable[[], float] = time.perf_counter,
) -> np.ndarray:
    """From each kept waypoint, straight to the farthest later one `reachable` says it can go to. Past `t_end` the
    rest of the path is kept as it is."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(W, axis=0), axis=1) > 1e-9])
    W = W[keep]
    out, i = [W[0]], 0
    while i < len(W) - 1:
        if clock() >= t_end:
            out.extend(W[i + 1 :])
            break
        j = len(W) - 1
        while j > i + 1 and not reachable(W[i], W[j]):
            j -= 1
        out.append(W[j])
        i = j
    return np.array(out)
