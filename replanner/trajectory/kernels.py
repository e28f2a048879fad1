"""Compiled loops of the timing hot path (numba): derivative bounds of quintics and path speed bounds, which a splice
computes for dozens of candidate transitions at once, where numpy spends its time on temporaries and call overhead.

Compiled once per machine and cached (numba's cache, per version of the compiled sources: see cache_dirs.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np


def writable(x) -> np.ndarray:
    """x as the one array kind the kernels are compiled for (float64, C order, writable): another kind (a read-only
    robot limit, a strided view) would compile a new version in the middle of a motion, seconds long."""
    return np.require(x, dtype=np.float64, requirements=["C", "W"])


STEP = 0.8  # a curved piece's speed is lowered this factor at a time ...
STEPS = 30  # ... at most this many times (to 0.8^29 of its first guess)


# no NaN or inf reaches these loops (finite waypoints): without those checks LLVM vectorizes the maxima; the
# arithmetic itself is unchanged (no reassociation, no fused multiply-add)
EXACT_FAST = {"nnan", "ninf", "nsz"}


@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=EXACT_FAST)
def quintic_peaks(c, ell, edges, samples, out):
    """out (N, parts, 4, dof): the largest |d^k q / dx^k| (k = 1..4) at `samples` evenly spaced u in each
    [edges[i], edges[i+1]] of the quintics q(u) = sum c[n, p] u^p (c: (N, 6, dof)), x = u * ell[n]."""
    N, dof = c.shape[0], c.shape[2]
    parts = edges.shape[0] - 1
    us = np.empty(parts * samples)
    for i in range(parts):
        for s in range(samples):
            us[i * samples + s] = edges[i] + (edges[i + 1] - edges[i]) * (s / (samples - 1))
    for n in range(N):
        inv = 1.0 / ell[n]
        for d in range(dof):
            c1, c2, c3, c4, c5 = c[n, 1, d], c[n, 2, d], c[n, 3, d], c[n, 4, d], c[n, 5, d]
            for i in range(parts):
                p1 = p2 = p3 = p4 = 0.0
                for s in range(i * samples, (i + 1) * samples):
                    u = us[s]
                    d1 = abs(c1 + u * (2 * c2 + u * (3 * c3 + u * (4 * c4 + u * 5 * c5))))
                    d2 = abs(2 * c2 + u * (6 * c3 + u * (12 * c4 + u * 20 * c5)))
                    d3 = abs(6 * c3 + u * (24 * c4 + u * 60 * c5))
                    d4 = abs(24 * c4 + u * 120 * c5)
                    p1 = d1 if d1 > p1 else p1
                    p2 = d2 if d2 > p2 else p2
                    p3 = d3 if d3 > p3 else p3
                    p4 = d4 if d4 > p4 else p4
                out[n, i, 0, d] = p1 * inv
                out[n, i, 1, d] = p2 * inv * inv
                out[n, i, 2, d] = p3 * inv * inv * inv
                out[n, i, 3, d] = p4 * inv * inv * inv * inv
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def path_bounds(m, v, a, j, eps, curve_share, out):
    """out (P, 3): the highest path speed, acceleration and jerk on each of P pieces with derivative bounds
    m (P, 3, dof) that keep every joint within v, a, j. A curved piece lowers its speed STEP at a time until
    acceleration and jerk are left over; one that never gets there gets zeros. Returns which pieces could be timed.
    """
    P, dof = m.shape[0], m.shape[2]
    timable = np.ones(P, dtype=np.bool_)
    for p in range(P):
        sv = sa = sj = np.inf
        curved = False
        for d in range(dof):
            m1 = m[p, 0, d]
            if m1 > eps:
                sv, sa, sj = min(sv, v[d] / m1), min(sa, a[d] / m1), min(sj, j[d] / m1)
            if m[p, 1, d] > eps or m[p, 2, d] > eps:
                curved = True
        if not curved:
            out[p, 0], out[p, 1], out[p, 2] = sv, sa, sj
            continue
        # curved: most of the acceleration and a quarter of the jerk go to following the curve at speed
        sc = sv
        for d in range(dof):
            if m[p, 1, d] > eps:
                sc = min(sc, math.sqrt(curve_share * a[d] / m[p, 1, d]))
            if m[p, 2, d] > eps:
                sc = min(sc, np.cbrt(0.25 * j[d] / m[p, 2, d]))
        timable[p] = False
        out[p, 0] = out[p, 1] = out[p, 2] = 0.0
        for _ in range(STEPS):
            SA = np.inf
            for d in range(dof):
                if m[p, 0, d] > eps:
                    SA = min(SA, (a[d] - m[p, 1, d] * sc * sc) / m[p, 0, d])
            SJ = np.inf
            for d in range(dof):
                if m[p, 0, d] > eps:
                    SJ = min(SJ, (j[d] - m[p, 2, d] * sc * sc * sc - 3 * m[p, 1, d] * sc * SA) / m[p, 0, d])
            if SA > 0 and SJ > 0:
                out[p, 0], out[p, 1], out[p, 2] = sc, SA, SJ
                timable[p] = True
                break
            sc *= STEP
    return timable


@numba.njit(cache=True, nogil=True, error_model="numpy")
def reachable_from(vb, length, a, j):
    """The highest speed va >= vb that slows to vb within `length` (rest acceleration at both ends), closed form.

    min_distance: with dv = va - vb, length = (vb + dv/2)(dv/a + a/j) when dv >= a^2/j (a quadratic in dv), else
    length = (vb + dv/2) 2 sqrt(dv/j), a cubic in x = sqrt(dv/j): j x^3 + 2 vb x = length.
    """
    A, B, C = 1.0 / (2.0 * a), vb / a + a / (2.0 * j), vb * a / j - length
    dv = (-B + math.sqrt(max(B * B - 4.0 * A * C, 0.0))) / (2.0 * A)
    if not dv >= a * a / j:
        p, q = 2.0 * vb / j, -length / j
        disc = math.sqrt(q * q / 4.0 + p**3 / 27.0)
        x = np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc)
        dv = j * x * x
    if math.isnan(dv):
        return np.inf
    return vb + max(dv, 0.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def slowest_entry(bounds, lengths, out):
    """out (L,): an upper bound of the speed at the start of L chains of pieces (bounds (L, P, 3), lengths (L, P))
    from which each chain can be followed; what follows a chain does not constrain it."""
    L, P = bounds.shape[0], bounds.shape[1]
    for c in range(L):
        cap = bounds[c, P - 1, 0]
        for i in range(P - 1, -1, -1):
            cap = min(bounds[c, i, 0], reachable_from(cap, lengths[c, i], bounds[c, i, 1], bounds[c, i, 2]))
        out[c] = cap * (1.0 + 1e-6) + 1e-9  # lenient: a screen must never refuse what the exact check admits
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def progress(P, W, eps, out):
    """out (n,): the arc position along the polyline W (m, dof) of the closest point to each point of P (n, dof);
    before W[0] it is negative. The first segment wins a tie (another must be closer by 1e-12)."""
    n, dof, m = P.shape[0], P.shape[1], W.shape[0]
    seg, ab2 = np.empty(m - 1), np.empty(m - 1)
    starts = np.zeros(m)
    for k in range(m - 1):
        sq = 0.0
        for j in range(dof):
            sq += (W[k + 1, j] - W[k, j]) ** 2
        seg[k], ab2[k] = math.sqrt(sq), max(sq, eps)
        starts[k + 1] = starts[k] + seg[k]
    for i in range(n):
        best_d, best_s = np.inf, 0.0
        for k in range(m - 1):
            dot = 0.0
            for j in range(dof):
                dot += (P[i, j] - W[k, j]) * (W[k + 1, j] - W[k, j])
            t = min(dot / ab2[k], 1.0)
            if k > 0:
                t = max(t, 0.0)
            tc = max(t, 0.0)
            sq = 0.0
            for j in range(dof):
                sq += (P[i, j] - (W[k, j] + tc * (W[k + 1, j] - W[k, j]))) ** 2
            d = math.sqrt(sq)
            if d < best_d - 1e-12:
                best_d, best_s = d, starts[k] + t * seg[k]
        out[i] = best_s
    return out


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now: a first compile takes seconds, too long mid-splice."""
    m = np.ones((1, 3, 1))
    quintic_peaks(np.ones((1, 6, 1)), np.ones(1), np.array([0.0, 1.0]), 3, np.empty((1, 1, 4, 1)))
    path_bounds(m, np.ones(1), np.ones(1), np.ones(1), 1e-9, 0.75, np.empty((1, 3)))
    slowest_entry(np.ones((1, 1, 3)), np.ones((1, 1)), np.empty(1))
    progress(np.ones((1, 1)), np.array([[0.0], [1.0]]), 1e-9, np.empty(1))
