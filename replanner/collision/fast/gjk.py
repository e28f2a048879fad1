"""Compiled GJK on convex shapes: is a padded robot body apart from a primitive or from another body?

The shapes are those FCL is given: a body is its points (hull vertices or box corners) plus its padding times a set
of directions (the padded polytope of geometry.padded, as a Minkowski sum: the support functions add); boxes,
balls and cylinders are exact. GJK keeps a rigorous lower bound of the distance, so "apart by more than `tol`" is
certain; "in contact" is only said of shapes that still meet when shrunk by `tol`. The band between is FCL's.
"""

from __future__ import annotations

import numba
import numpy as np

from ..hulls import climb

APART, TOUCH, BAND = 1, -1, 0  # what `decide` says of two shapes
POINTS, BOX, BALL, CYLINDER = 3, 0, 1, 2  # shape kinds (the primitives' numbers are fast/layer.py's)
MAX_ITER = 64


@numba.njit(cache=True, nogil=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, nogil=True, inline="always")
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@numba.njit(cache=True, nogil=True, inline="always")
def _axpy(s, a, b):
    return (b[0] + s * a[0], b[1] + s * a[1], b[2] + s * a[2])


@numba.njit(cache=True, nogil=True, inline="always")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@numba.njit(cache=True, nogil=True)
def support(kind, R, t, dims, P, p0, p1, D, d0, d1, pad, d, first, nb, hint, h):
    """The point of a shape farthest along world direction d. R (3, 3), t (3,): shape -> world; POINTS: the points
    P[p0:p1] plus pad times the farthest of D[d0:d1] (shape frame), found by climbing the hull edges first, nb
    (hulls.edge_graph) from hint[h], which is left at the answer; BOX: half extents dims; BALL: radius dims[0];
    CYLINDER: radius dims[0], half length dims[1] along z."""
    x = R[0, 0] * d[0] + R[1, 0] * d[1] + R[2, 0] * d[2]
    y = R[0, 1] * d[0] + R[1, 1] * d[1] + R[2, 1] * d[2]
    z = R[0, 2] * d[0] + R[1, 2] * d[1] + R[2, 2] * d[2]
    if kind == POINTS:
        k, _ = climb(P, first, nb, hint[h], x, y, z)
        hint[h] = k
        sx, sy, sz = P[k, 0], P[k, 1], P[k, 2]
        if pad != 0.0 and d1 > d0:
            best, k = -np.inf, d0
            for i in range(d0, d1):
                s = D[i, 0] * x + D[i, 1] * y + D[i, 2] * z
                if s > best:
                    best, k = s, i
            sx, sy, sz = sx + pad * D[k, 0], sy + pad * D[k, 1], sz + pad * D[k, 2]
    elif kind == BOX:
        sx = dims[0] if x >= 0.0 else -dims[0]
        sy = dims[1] if y >= 0.0 else -dims[1]
        sz = dims[2] if z >= 0.0 else -dims[2]
    elif kind == BALL:
        n = np.sqrt(x * x + y * y + z * z)
        if n > 0.0:
            sx, sy, sz = dims[0] * x / n, dims[0] * y / n, dims[0] * z / n
        else:
            sx, sy, sz = dims[0], 0.0, 0.0
    else:
        n = np.sqrt(x * x + y * y)
        if n > 0.0:
            sx, sy = dims[0] * x / n, dims[0] * y / n
        else:
            sx, sy = 0.0, 0.0
        sz = dims[1] if z >= 0.0 else -dims[1]
    return (
        R[0, 0] * sx + R[0, 1] * sy + R[0, 2] * sz + t[0],
        R[1, 0] * sx + R[1, 1] * sy + R[1, 2] * sz + t[1],
        R[2, 0] * sx + R[2, 1] * sy + R[2, 2] * sz + t[2],
    )


@numba.njit(cache=True, nogil=True)
def _closest(S, k):
    """Closest point to the origin of the simplex S[:k] (k <= 4); S is reduced to the vertices that span it.
    Returns (point, k', inside) with inside True when a tetrahedron holds the origin."""
    a = (S[0, 0], S[0, 1], S[0, 2])
    if k == 1:
        return a, 1, False
    b = (S[1, 0], S[1, 1], S[1, 2])
    if k == 2:
        ab = _sub(b, a)
        den = _dot(ab, ab)
        u = -_dot(a, ab) / den if den > 0.0 else 0.0
        if u <= 0.0:
            return a, 1, False
        if u >= 1.0:
            S[0, 0], S[0, 1], S[0, 2] = b
            return b, 1, False
        return _axpy(u, ab, a), 2, False
    c = (S[2, 0], S[2, 1], S[2, 2])
    if k == 3:
        return _triangle(S, a, b, c)
    d = (S[3, 0], S[3, 1], S[3, 2])
    best, bk, found = (0.0, 0.0, 0.0), 0, False
    bd = np.inf
    T = np.empty((3, 3))
    faces = ((0, 1, 2, 3), (0, 2, 3, 1), (0, 3, 1, 2), (1, 3, 2, 0))
    V = (a, b, c, d)
    for f in faces:
        p, q, r, o = V[f[0]], V[f[1]], V[f[2]], V[f[3]]
        n = _cross(_sub(q, p), _sub(r, p))
        side_o = _dot(_sub(o, p), n)
        side_0 = -_dot(p, n)
        if side_o * side_0 < 0.0 or abs(side_o) < 1e-30:  # the origin is beyond this face (or the solid is flat)
            T[0, 0], T[0, 1], T[0, 2] = p
            T[1, 0], T[1, 1], T[1, 2] = q
            T[2, 0], T[2, 1], T[2, 2] = r
            x, m, _ = _triangle(T, p, q, r)
            dd = _dot(x, x)
            if dd < bd:
                bd, best, bk, found = dd, x, m, True
                for i in range(m):
                    for j in range(3):
                        S[i, j] = T[i, j]
    if not found:
        return (0.0, 0.0, 0.0), 4, True
    return best, bk, False


@numba.njit(cache=True, nogil=True)
def _triangle(S, a, b, c):
    """Closest point to the origin of triangle abc (Ericson, Real-Time Collision Detection 5.1.5); S[:k'] gets the
    vertices of the feature it lies on."""
    ab, ac = _sub(b, a), _sub(c, a)
    d1, d2 = -_dot(ab, a), -_dot(ac, a)
    if d1 <= 0.0 and d2 <= 0.0:
        _keep(S, a, a, a, 1)
        return a, 1, False
    d3, d4 = -_dot(ab, b), -_dot(ac, b)
    if d3 >= 0.0 and d4 <= d3:
        _keep(S, b, b, b, 1)
        return b, 1, False
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        _keep(S, a, b, b, 2)
        return _axpy(v, ab, a), 2, False
    d5, d6 = -_dot(ab, c), -_dot(ac, c)
    if d6 >= 0.0 and d5 <= d6:
        _keep(S, c, c, c, 1)
        return c, 1, False
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        _keep(S, a, c, c, 2)
        return _axpy(w, ac, a), 2, False
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        _keep(S, b, c, c, 2)
        return _axpy(w, _sub(c, b), b), 2, False
    den = va + vb + vc
    v, w = vb / den, vc / den
    _keep(S, a, b, c, 3)
    return _axpy(w, ac, _axpy(v, ab, a)), 3, False


@numba.njit(cache=True, nogil=True, inline="always")
def _keep(S, a, b, c, m):
    S[0, 0], S[0, 1], S[0, 2] = a
    if m > 1:
        S[1, 0], S[1, 1], S[1, 2] = b
    if m > 2:
        S[2, 0], S[2, 1], S[2, 2] = c


@numba.njit(cache=True, nogil=True)
def _apart(
    ka,
    Ra,
    ta,
    dimsa,
    P,
    pa0,
    pa1,
    D,
    da0,
    da1,
    pada,
    kb,
    Rb,
    tb,
    dimsb,
    pb0,
    pb1,
    db0,
    db1,
    padb,
    tol,
    S,
    first,
    nb,
    hint,
    ha,
    hb,
):
    """1: apart by more than tol for certain; -1: they meet (origin inside the difference); 0: undecided."""
    d = (tb[0] - ta[0], tb[1] - ta[1], tb[2] - ta[2])  # from a toward b: a first point near the closest
    if d[0] == 0.0 and d[1] == 0.0 and d[2] == 0.0:
        d = (1.0, 0.0, 0.0)
    v = _sub(
        support(ka, Ra, ta, dimsa, P, pa0, pa1, D, da0, da1, pada, d, first, nb, hint, ha),
        support(kb, Rb, tb, dimsb, P, pb0, pb1, D, db0, db1, padb, (-d[0], -d[1], -d[2]), first, nb, hint, hb),
    )
    S[0, 0], S[0, 1], S[0, 2] = v
    k = 1
    for _ in range(MAX_ITER):
        vv = _dot(v, v)
        if vv <= 1e-24:
            return -1
        n = (-v[0], -v[1], -v[2])
        w = _sub(
            support(ka, Ra, ta, dimsa, P, pa0, pa1, D, da0, da1, pada, n, first, nb, hint, ha),
            support(kb, Rb, tb, dimsb, P, pb0, pb1, D, db0, db1, padb, (v[0], v[1], v[2]), first, nb, hint, hb),
        )
        vw = _dot(v, w)
        if vw > tol * np.sqrt(vv):  # a separating plane with a gap of more than tol: the distance is above it
            return 1
        if vv - vw <= 1e-12 * vv:  # no progress: v is (nearly) the closest point, within tol of the origin
            return 0
        for i in range(k):  # a repeated vertex: numerically done
            if S[i, 0] == w[0] and S[i, 1] == w[1] and S[i, 2] == w[2]:
                return 0
        S[k, 0], S[k, 1], S[k, 2] = w
        k += 1
        v, k, inside = _closest(S, k)
        if inside:
            return -1
    return 0


@numba.njit(cache=True, nogil=True)
def decide(
    ka,
    Ra,
    ta,
    dimsa,
    P,
    pa0,
    pa1,
    D,
    da0,
    da1,
    pada,
    kb,
    Rb,
    tb,
    dimsb,
    pb0,
    pb1,
    db0,
    db1,
    padb,
    tol,
    S,
    dims_small,
    first,
    nb,
    hint,
    ha,
    hb,
):
    """APART (more than tol apart), TOUCH (they meet even with b shrunk by tol), or BAND (let FCL decide).
    first, nb, hint, ha, hb: `support`'s climb for a and b (their slots in hint; a primitive's is not read)."""
    r = _apart(
        ka,
        Ra,
        ta,
        dimsa,
        P,
        pa0,
        pa1,
        D,
        da0,
        da1,
        pada,
        kb,
        Rb,
        tb,
        dimsb,
        pb0,
        pb1,
        db0,
        db1,
        padb,
        tol,
        S,
        first,
        nb,
        hint,
        ha,
        hb,
    )
    if r == 1:
        return APART
    # shrink b by tol: primitives' dimensions, or a body's padding
    if kb == POINTS:
        if padb < tol:
            return BAND
        small_pad = padb - tol
        dims_small[:] = dimsb
    else:
        small_pad = padb
        for i in range(3):
            dims_small[i] = dimsb[i] - tol if dimsb[i] > 0.0 else 0.0
        if kb == BOX and (dims_small[0] <= 0.0 or dims_small[1] <= 0.0 or dims_small[2] <= 0.0):
            return BAND
        if dims_small[0] <= 0.0 or (kb == CYLINDER and dims_small[1] <= 0.0):
            return BAND
    r = _apart(
        ka,
        Ra,
        ta,
        dimsa,
        P,
        pa0,
        pa1,
        D,
        da0,
        da1,
        pada,
        kb,
        Rb,
        tb,
        dims_small,
        pb0,
        pb1,
        db0,
        db1,
        small_pad,
        0.0,
        S,
        first,
        nb,
        hint,
        ha,
        hb,
    )
    return TOUCH if r == -1 else BAND
