"""Support points of convex point sets by hill climbing their hull's edges: a linear function's local maximum over
a convex polytope's edge graph is its maximum, so a query from a nearby start reads a handful of vertices instead of
all of them (a link's hull has 300-500). GJK's iterations and a path's consecutive configurations ask nearby
directions: the last answer is the next start."""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np
from scipy.spatial import ConvexHull, QhullError


def edge_graph(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hull edges of each point set, over the sets stacked in order: (first (N + 1,), nb (E,), start (S,)), the
    neighbours of point i nb[first[i]:first[i + 1]] (indices into the stack), and each set's start, a hull vertex
    (-1: an empty set). A flat set is hulled joggled; one of under 4 points gets every pair of its points as edges."""
    edges, start, base = [], [], 0
    for P in points:
        P = np.ascontiguousarray(P, np.float64).reshape(-1, 3)
        e, s = _edges_of(P.tobytes())  # a world's scenes share their bodies' hulls: built once each
        edges.append(e + base)
        start.append(base + s if len(P) else -1)
        base += len(P)
    e = np.concatenate(edges) if edges else np.zeros((0, 2), np.int64)
    first = np.searchsorted(e[:, 0], np.arange(base + 1)).astype(np.int64)
    return first, np.ascontiguousarray(e[:, 1], np.int32), np.array(start, np.int64)


@lru_cache(maxsize=256)
def _edges_of(blob: bytes) -> tuple[np.ndarray, int]:
    """(edges (E, 2) both ways, sorted by their first point; a hull vertex) of the points in `blob` (float64 x 3)."""
    P = np.frombuffer(blob, np.float64).reshape(-1, 3)
    n = len(P)
    hull = None
    for options in (None, "QJ"):  # a flat set is hulled joggled (by ~1e-11 of its size: far below GJK's tolerance)
        try:
            hull = ConvexHull(P, qhull_options=options)
            break
        except (QhullError, ValueError):
            continue
    if hull is not None:
        tri = hull.simplices.astype(np.int64)
        e, s = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), int(hull.vertices[0])
    else:  # under 4 points: a climb over every point is the exhaustive scan
        e, s = np.stack(np.triu_indices(n, 1), axis=1).astype(np.int64), 0
    key = np.unique(np.concatenate([e[:, 0] * n + e[:, 1], e[:, 1] * n + e[:, 0]]))
    out = np.stack([key // max(n, 1), key % max(n, 1)], axis=1)
    out.setflags(write=False)
    return out, s


@numba.njit(cache=True, nogil=True, inline="always")
def climb(P, first, nb, k, x, y, z):
    """(index, value): a point of P farthest along (x, y, z), climbing hull edges (first, nb: `edge_graph`) from
    point k, a hull vertex of the same set; a step goes to the best neighbour, strictly better only."""
    best = P[k, 0] * x + P[k, 1] * y + P[k, 2] * z
    while True:
        step = k
        for e in range(first[k], first[k + 1]):
            i = nb[e]
            s = P[i, 0] * x + P[i, 1] * y + P[i, 2] * z
            if s > best:
                best, step = s, i
        if step == k:
            return k, best
        k = step
