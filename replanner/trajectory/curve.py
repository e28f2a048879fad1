"""The geometry of a trajectory: the planner's polyline with every corner rounded by a quintic blend.

A blend keeps within `tube_radius` of the polyline and has continuous curvature, so joint acceleration stays
continuous at speed. Each piece bounds |q'|, |q''|, |q'''| over itself; the time law takes its speed,
acceleration and jerk bounds from them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property

import numpy as np

from ..errors import TrajectoryError
from .kernels import progress, quintic_peaks, writable

EPS = 1e-9
BLEND_PARTS = 4  # a blend is timed in parts: its ends are straighter than its middle
SPLICE_PARTS = 8  # a splice's transition likewise, in finer parts: it may be tightly curved


class Piece(ABC):
    """One piece of the curve over local arc parameter x in [0, length]."""

    length: float
    bounds_memo: tuple | None = None  # (limits, the piece's speed bounds): the timing law's, for the last limits
    m: np.ndarray  # (3, dof) bounds of |q'|, |q''|, |q'''| over the piece

    @abstractmethod
    def eval(self, x: np.ndarray, order: int) -> np.ndarray:  # (n, dof)
        """The derivative of this order with respect to x, at local parameters x (n,)."""

    @cached_property
    def end_tangents(self) -> tuple[np.ndarray, np.ndarray]:
        """dq/dx at x = 0 and at x = length (every timing of the curve asks at each corner)."""
        return self.eval(np.array([0.0]), 1)[0], self.eval(np.array([self.length]), 1)[0]


class Line(Piece):
    def __init__(self, a: np.ndarray, b: np.ndarray):
        self.a = np.asarray(a, dtype=float)
        diff = np.asarray(b, dtype=float) - self.a
        self.length = float(np.linalg.norm(diff))
        self.d = diff / self.length if self.length > EPS else np.zeros_like(diff)
        self.m = np.vstack([np.abs(self.d), np.zeros_like(self.d), np.zeros_like(self.d)])

    def eval(self, x, order):
        x = np.asarray(x, dtype=float)[:, None]
        if order == 0:
            return self.a + x * self.d
        if order == 1:
            return np.broadcast_to(self.d, (len(x), len(self.d))).copy()
        return np.zeros((len(x), len(self.d)))


def quintic_coefficients(p0, v0, a0, p1, v1, a1) -> np.ndarray:
    """Coefficients c (..., 6, dof) of q(u) = sum c_k u^k on [0, 1] with the given ends (derivatives in u).

    The ends may be batched: arrays (..., dof) give one quintic per leading index.
    """
    c0, c1, c2 = np.broadcast_arrays(p0, v0, np.asarray(a0) / 2)
    d = p1 - c0 - c1 - c2
    e = v1 - c1 - 2 * c2
    f = a1 - 2 * c2
    c3 = 10 * d - 4 * e + f / 2
    c4 = -15 * d + 7 * e - f
    c5 = 6 * d - 3 * e + f / 2
    return np.stack(np.broadcast_arrays(c0, c1, c2, c3, c4, c5), axis=-2)


_POWERS = np.arange(6)
# d^k/du^k of u^n is n!/(n-k)! u^(n-k): multipliers and exponents per derivative order k = 0..4
_FALLING = [np.array([np.prod(np.arange(n - k + 1, n + 1)) if n >= k else 0.0 for n in range(6)]) for k in range(5)]
_EXPONENTS = [np.clip(_POWERS - k, 0, None) for k in range(5)]


def basis(u: np.ndarray, order: int) -> np.ndarray:
    """The matrix (n, 6) that maps quintic coefficients to the order-th derivative at parameters u (n,)."""
    return np.asarray(u, dtype=float)[:, None] ** _EXPONENTS[order] * _FALLING[order]


def _du(c: np.ndarray, u: np.ndarray, order: int) -> np.ndarray:
    """The order-th derivative (n, dof) of the quintic with coefficients c (6, dof) at parameters u (n,)."""
    return basis(u, order) @ c


class QuinticPiece(Piece):
    """q(x) = Q(u0 + x / ell), Q a quintic on [0, 1]; this piece covers u in [u0, u1], x in [0, ell (u1 - u0)]."""

    SAMPLES = 65  # per piece, where its derivatives' peaks are sought

    def __init__(self, coeffs: np.ndarray, ell: float, u0: float = 0.0, u1: float = 1.0, m: np.ndarray | None = None):
        self.c = coeffs
        self.ell = float(ell)
        self.u0 = float(u0)
        self.length = float(ell) * (u1 - u0)
        self.m = quintic_bounds(coeffs, self.ell, np.array([u0, u1], dtype=float))[0] if m is None else m

    def eval(self, x, order):
        u = self.u0 + np.asarray(x, dtype=float) / self.ell
        return _du(self.c, u, order) / self.ell**order

    @classmethod
    def split(cls, coeffs: np.ndarray, ell: float, parts: int, m: np.ndarray | None = None) -> list[QuinticPiece]:
        """The curve in `parts` pieces, each with its own derivative bounds (tighter where it is straighter).

        m: those bounds (parts, 3, dof) if already known (see quintic_bounds).
        """
        edges = np.linspace(0.0, 1.0, parts + 1)
        m = quintic_bounds(coeffs, float(ell), edges) if m is None else m
        return [cls(coeffs, ell, a, b, m[i]) for i, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]


def quintic_bounds(c: np.ndarray, ell, edges: np.ndarray) -> np.ndarray:
    """Bounds (..., parts, 3, dof) of the first three derivatives' magnitudes over each [edges[i], edges[i+1]] of u.

    c: coefficients (..., 6, dof), ell: arc scale (...,). Sampled maxima plus the change possible between samples
    (the next derivative's maximum x half the spacing).
    """
    edges = writable(edges)
    lead, dof = c.shape[:-2], c.shape[-1]
    flat = writable(np.reshape(c, (-1, 6, dof)))
    ells = np.array(np.broadcast_to(np.asarray(ell, dtype=float), lead).reshape(-1))  # writable: one compiled kind
    S = QuinticPiece.SAMPLES
    peak = quintic_peaks(flat, ells, edges, S, np.empty((len(flat), len(edges) - 1, 4, dof)))
    h = (0.5 / (S - 1) * np.diff(edges))[:, None, None] * ells[:, None, None, None]
    return (peak[..., :3, :] + h * peak[..., 1:, :]).reshape(*lead, len(edges) - 1, 3, dof)


class Curve:
    """A path q(s) made of pieces; s in [0, length]."""

    def __init__(self, pieces: list[Piece], polyline: np.ndarray):
        self.pieces = [p for p in pieces if p.length > EPS]
        if not self.pieces:
            raise TrajectoryError("the path has zero length")
        self.starts = np.concatenate([[0.0], np.cumsum([p.length for p in self.pieces])])
        self.length = float(self.starts[-1])
        self.polyline = polyline  # the path the curve was built around (collision-checked)

    def piece_at(self, s: np.ndarray) -> np.ndarray:
        # minimum/maximum, not np.clip: a splice asks thousands of times, and clip costs ~10 us on a small array
        return np.minimum(np.maximum(np.searchsorted(self.starts, s, side="right") - 1, 0), len(self.pieces) - 1)

    def eval(self, s, order: int = 0) -> np.ndarray:
        s = np.minimum(np.maximum(np.atleast_1d(np.asarray(s, dtype=float)), 0.0), self.length)
        idx = self.piece_at(s)
        if len(idx) and (idx == idx[0]).all():  # all in one piece: no masks
            return self.pieces[idx[0]].eval(s - self.starts[idx[0]], order)
        out = np.empty((len(s), len(self.polyline[0])))
        if len(s) and (idx[1:] >= idx[:-1]).all():  # in order (a time series): slices, no masks
            cuts = [0, *(np.flatnonzero(idx[1:] != idx[:-1]) + 1).tolist(), len(s)]
            for a, b in zip(cuts[:-1], cuts[1:]):
                k = idx[a]
                out[a:b] = self.pieces[k].eval(s[a:b] - self.starts[k], order)
            return out
        for k in np.unique(idx):
            sel = idx == k
            out[sel] = self.pieces[k].eval(s[sel] - self.starts[k], order)
        return out

    def samples(self, per_curve: int = 24) -> np.ndarray:
        """Points along the curve: piece ends, plus `per_curve` inside each curved piece (for collision checks)."""
        pts = [self.pieces[0].eval(np.array([0.0]), 0)]
        for p in self.pieces:
            n = 1 if isinstance(p, Line) else per_curve
            pts.append(p.eval(np.linspace(0, p.length, n + 1)[1:], 0))
        return np.vstack(pts)


_U65 = np.linspace(0.0, 1.0, 65)[:, None] ** np.arange(6)


def _deviation_factors(d_in: np.ndarray, d_out: np.ndarray) -> np.ndarray:
    """Max distance (k,) from each unit blend (b = 1) to its corner's two segments; d_in, d_out (k, dof)."""
    A, B = -d_in, d_out
    ell = np.linalg.norm(B - A, axis=1)[:, None]
    z = np.zeros_like(A)
    pts = _U65 @ quintic_coefficients(A, ell * d_in, z, B, ell * d_out, z)  # (k, 65, dof)
    corner = np.zeros_like(A[:, None])
    return np.minimum(_dist_to_segment(pts, A[:, None], corner), _dist_to_segment(pts, corner, B[:, None])).max(axis=1)


def _dist_to_segment(P: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (...) of points P (..., dof) to the segments a -> b (broadcast against P)."""
    ab = b - a
    t = np.clip(np.sum((P - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), EPS), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[..., None] * ab), axis=-1)


def distance_to_polyline(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Distance (n,) of points P (n, dof) to the polyline W (m, dof)."""
    d = np.full(len(P), np.inf)
    for a, b in zip(W[:-1], W[1:]):
        d = np.minimum(d, _dist_to_segment(P, a, b))
    return d


def progress_along(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Arc-length position (n,) of the closest point of the polyline W to each point of P.

    Before the first waypoint progress is negative: moving away from the path's start counts as backwards.
    """
    P, W = writable(np.atleast_2d(P)), writable(W)
    return progress(P, W, EPS, np.empty(len(P)))


def blended_curve(
    W: np.ndarray, tube_radius: float, blend_scale: np.ndarray | None = None, head: list[Piece] | None = None
) -> Curve:
    """Lines between the waypoints W with every interior corner rounded within `tube_radius`.

    blend_scale (m,) shrinks individual blends (1 = as large as the tube allows, 0 = stop at the corner).
    head: pieces that come before W[0] (a splice's transition).
    """
    W = np.asarray(W, dtype=float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(W, axis=0), axis=1) > 1e-9])
    W = W[keep]
    if blend_scale is not None:
        blend_scale = np.asarray(blend_scale)[keep]
    n = len(W)
    if n < 2:
        raise TrajectoryError("a path needs two distinct waypoints")
    seg = np.diff(W, axis=0)
    L = np.linalg.norm(seg, axis=1)
    D = seg / L[:, None]
    b = np.zeros(n)
    factors = _deviation_factors(D[:-1], D[1:]) if n > 2 else None
    for k in range(1, n - 1):
        if D[k - 1] @ D[k] < -0.98:  # turning back: no blend can do it, stop at the corner
            continue
        f = factors[k - 1]
        size = tube_radius / f if f > EPS else np.inf
        scale = 1.0 if blend_scale is None else float(blend_scale[k])
        b[k] = scale * min(size, 0.45 * L[k - 1], 0.45 * L[k])
    pieces: list[Piece] = list(head or [])
    cursor = W[0]
    for k in range(1, n):
        end = W[k] - b[k] * D[k - 1] if k < n - 1 else W[k]
        pieces.append(Line(cursor, end))
        if k < n - 1 and b[k] > EPS:
            A, B = end, W[k] + b[k] * D[k]
            ell = float(np.linalg.norm(B - A))
            z = np.zeros_like(A)
            pieces += QuinticPiece.split(quintic_coefficients(A, ell * D[k - 1], z, B, ell * D[k], z), ell, BLEND_PARTS)
            cursor = B
        else:
            cursor = end
    return Curve(pieces, W)


def clip_curve(curve: Curve, a: float, b: float) -> list[Piece]:
    """The pieces of `curve` between arc positions a and b, cut where needed."""
    out: list[Piece] = []
    for k, piece in enumerate(curve.pieces):
        lo, hi = float(curve.starts[k]), float(curve.starts[k + 1])
        x0, x1 = max(a, lo) - lo, min(b, hi) - lo
        if x1 - x0 <= 1e-12:
            continue
        if isinstance(piece, Line):
            out.append(Line(piece.eval(np.array([x0]), 0)[0], piece.eval(np.array([x1]), 0)[0]))
        else:
            out.append(QuinticPiece(piece.c, piece.ell, piece.u0 + x0 / piece.ell, piece.u0 + x1 / piece.ell))
    return out


def points_along(W: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points (k, dof) at arc lengths `lengths` (k,) along W, and the indices (k,) of their segments."""
    seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
    ends = np.cumsum(seg)
    k = np.minimum(np.searchsorted(ends, lengths, side="left"), len(seg) - 1)
    starts = np.concatenate([[0.0], ends[:-1]])
    f = np.clip((np.asarray(lengths, dtype=float) - starts[k]) / seg[k], 0.0, 1.0)
    return W[k] + f[:, None] * (W[k + 1] - W[k]), k
