"""Jerk-limited trajectories along a path: timing, splicing onto a motion in progress, braking along the path.

A trajectory is a geometric curve q(s) plus a time law s(t):

- the curve is the planner's polyline with every corner rounded by a quintic blend (continuous curvature,
  so joint acceleration stays continuous at speed) that keeps within `tube_radius` of the polyline;
- the time law is a 1-D jerk-limited motion along s, computed piece by piece with Ruckig's local
  state-to-state solver (never its intermediate waypoints, which call a cloud service) with min_velocity 0,
  so the arm never moves backwards along its path.

Joint limits become bounds on the path speed, acceleration and jerk per piece: with q' = dq/ds etc.,
q_dot = q' s_dot, q_ddot = q' s_ddot + q'' s_dot^2, q_dddot = q' s_dddot + 3 q'' s_dot s_ddot + q''' s_dot^3,
and each piece gets (s_dot, s_ddot, s_dddot) bounds that keep those within every joint's limits.
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import ruckig

from ..errors import InvalidInputError, ReplannerError

log = logging.getLogger(__name__)

_EPS = 1e-9
_CURVE_SHARE = 0.75
_BLEND_PARTS = 4  # a blend is timed in parts: its ends are straighter than its middle
_SPLICE_PARTS = 8  # of each joint's acceleration a blend may use for its curvature at full blend speed


class TrajectoryError(ReplannerError):
    """A path cannot be timed, spliced or braked as asked; the message says why."""


# ============================================================================ geometry
class _Piece(ABC):
    """One piece of the curve over local arc parameter x in [0, length]."""

    length: float
    m: np.ndarray  # (3, dof) bounds of |q'|, |q''|, |q'''| over the piece

    @abstractmethod
    def eval(self, x: np.ndarray, order: int) -> np.ndarray:  # (n, dof)
        """The derivative of this order with respect to x, at local parameters x (n,)."""


class _Line(_Piece):
    def __init__(self, a: np.ndarray, b: np.ndarray):
        self.a = np.asarray(a, dtype=float)
        diff = np.asarray(b, dtype=float) - self.a
        self.length = float(np.linalg.norm(diff))
        self.d = diff / self.length if self.length > _EPS else np.zeros_like(diff)
        self.m = np.vstack([np.abs(self.d), np.zeros_like(self.d), np.zeros_like(self.d)])

    def eval(self, x, order):
        x = np.asarray(x, dtype=float)[:, None]
        if order == 0:
            return self.a + x * self.d
        if order == 1:
            return np.broadcast_to(self.d, (len(x), len(self.d))).copy()
        return np.zeros((len(x), len(self.d)))


def _quintic(p0, v0, a0, p1, v1, a1) -> np.ndarray:
    """Coefficients c (6, dof) of q(u) = sum c_k u^k on [0, 1] with the given ends (derivatives in u)."""
    c0, c1, c2 = p0, v0, a0 / 2
    d = p1 - c0 - c1 - c2
    e = v1 - c1 - 2 * c2
    f = a1 - 2 * c2
    c3 = 10 * d - 4 * e + f / 2
    c4 = -15 * d + 7 * e - f
    c5 = 6 * d - 3 * e + f / 2
    return np.vstack([c0, c1, c2, c3, c4, c5])


class _Quintic(_Piece):
    """q(x) = Q(u0 + x / ell), Q a quintic on [0, 1]; this piece covers u in [u0, u1], x in [0, ell (u1 - u0)]."""

    _SAMPLES = 65

    def __init__(self, coeffs: np.ndarray, ell: float, u0: float = 0.0, u1: float = 1.0):
        self.c = coeffs
        self.ell = float(ell)
        self.u0 = float(u0)
        self.length = float(ell) * (u1 - u0)
        u = np.linspace(u0, u1, self._SAMPLES)
        derivs = [self._du(u, k) / ell**k for k in (1, 2, 3)]
        # sampled maxima plus the change possible between samples (next derivative x half the spacing)
        h = 0.5 / (self._SAMPLES - 1) * self.length
        m4 = np.abs(self._du(u, 4)).max(axis=0) / ell**4
        m3 = np.abs(derivs[2]).max(axis=0)
        self.m = np.vstack(
            [
                np.abs(derivs[0]).max(axis=0) + h * np.abs(derivs[1]).max(axis=0),
                np.abs(derivs[1]).max(axis=0) + h * m3,
                m3 + h * m4,
            ]
        )

    def _du(self, u, order):
        c = self.c
        powers = np.arange(6)
        coef = np.ones(6)
        for k in range(order):
            coef = coef * np.clip(powers - k, 0, None)
        exps = np.clip(powers - order, 0, None)
        U = np.asarray(u, dtype=float)[:, None] ** exps[None, :] * coef[None, :]
        return U @ c

    def eval(self, x, order):
        u = self.u0 + np.asarray(x, dtype=float) / self.ell
        return self._du(u, order) / self.ell**order

    @classmethod
    def split(cls, coeffs: np.ndarray, ell: float, parts: int) -> list[_Quintic]:
        """The curve in `parts` pieces, each with its own derivative bounds (tighter where it is straighter)."""
        edges = np.linspace(0.0, 1.0, parts + 1)
        return [cls(coeffs, ell, a, b) for a, b in zip(edges[:-1], edges[1:])]


@dataclass(frozen=True)
class _Limits:
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray


def _piece_bounds(piece: _Piece, lim: _Limits) -> tuple[float, float, float]:
    """(max s_dot, max s_ddot, max s_dddot) on a piece that keep every joint within its limits."""
    m1, m2, m3 = piece.m
    v, a, j = lim.velocity, lim.acceleration, lim.jerk
    with np.errstate(divide="ignore", invalid="ignore"):
        sv = np.min(np.where(m1 > _EPS, v / m1, np.inf))
        if not np.any(m2 > _EPS) and not np.any(m3 > _EPS):  # a straight line
            return sv, np.min(np.where(m1 > _EPS, a / m1, np.inf)), np.min(np.where(m1 > _EPS, j / m1, np.inf))
        # curved: most of the acceleration and a quarter of the jerk go to following the curve at speed
        sc = min(
            sv,
            np.min(np.where(m2 > _EPS, np.sqrt(_CURVE_SHARE * a / m2), np.inf)),
            np.min(np.where(m3 > _EPS, np.cbrt(0.25 * j / m3), np.inf)),
        )
        for _ in range(30):
            sa = np.min(np.where(m1 > _EPS, (a - m2 * sc**2) / m1, np.inf))
            sj = np.min(np.where(m1 > _EPS, (j - m3 * sc**3 - 3 * m2 * sc * sa) / m1, np.inf))
            if sa > 0 and sj > 0:
                return float(sc), float(sa), float(sj)
            sc *= 0.8
    raise TrajectoryError("a path piece is too sharply curved to be timed within the joint limits")


class Curve:
    """A path q(s) made of pieces; s in [0, length]."""

    def __init__(self, pieces: list[_Piece], polyline: np.ndarray):
        self.pieces = [p for p in pieces if p.length > _EPS]
        if not self.pieces:
            raise TrajectoryError("the path has zero length")
        self.starts = np.concatenate([[0.0], np.cumsum([p.length for p in self.pieces])])
        self.length = float(self.starts[-1])
        self.polyline = polyline  # the path the curve was built around (collision-checked)

    def piece_at(self, s: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.pieces) - 1)

    def eval(self, s, order: int = 0) -> np.ndarray:
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.length)
        idx = self.piece_at(s)
        out = np.empty((len(s), len(self.polyline[0])))
        for k in np.unique(idx):
            sel = idx == k
            out[sel] = self.pieces[k].eval(s[sel] - self.starts[k], order)
        return out

    def samples(self, per_curve: int = 24) -> np.ndarray:
        """Points along the curve: piece ends, plus `per_curve` inside each curved piece (for collision checks)."""
        pts = [self.pieces[0].eval(np.array([0.0]), 0)]
        for p in self.pieces:
            n = 1 if isinstance(p, _Line) else per_curve
            pts.append(p.eval(np.linspace(0, p.length, n + 1)[1:], 0))
        return np.vstack(pts)


def _deviation_factor(d_in: np.ndarray, d_out: np.ndarray) -> float:
    """Max distance from the unit blend (b = 1) to the corner's two segments."""
    corner = np.zeros_like(d_in)
    A, B = -d_in, d_out
    ell = float(np.linalg.norm(B - A))
    c = _quintic(A, ell * d_in, np.zeros_like(A), B, ell * d_out, np.zeros_like(A))
    u = np.linspace(0, 1, 65)[:, None]
    pts = (u ** np.arange(6)) @ c
    return float(np.minimum(_dist_to_segment(pts, A, corner), _dist_to_segment(pts, corner, B)).max())


def _dist_to_segment(P: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((P - a) @ ab) / max(ab @ ab, _EPS), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * ab), axis=1)


def distance_to_polyline(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Distance (n,) of points P (n, dof) to the polyline W (m, dof)."""
    d = np.full(len(P), np.inf)
    for a, b in zip(W[:-1], W[1:]):
        d = np.minimum(d, _dist_to_segment(P, a, b))
    return d


def progress_along(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Arc-length position (n,) of the closest point of the polyline W to each point of P."""
    seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
    starts = np.concatenate([[0.0], np.cumsum(seg)])
    best_d = np.full(len(P), np.inf)
    best_s = np.zeros(len(P))
    for k, (a, b) in enumerate(zip(W[:-1], W[1:])):
        ab = b - a
        # before the first waypoint progress is negative: moving away from the path's start counts as backwards
        t = np.clip(((P - a) @ ab) / max(ab @ ab, _EPS), -np.inf if k == 0 else 0.0, 1.0)
        d = np.linalg.norm(P - (a + np.maximum(t, 0.0)[:, None] * ab), axis=1)
        better = d < best_d - 1e-12
        best_d[better] = d[better]
        best_s[better] = starts[k] + t[better] * seg[k]
    return best_s


def blended_curve(
    W: np.ndarray, tube_radius: float, blend_scale: np.ndarray | None = None, head: list[_Piece] | None = None
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
    for k in range(1, n - 1):
        if D[k - 1] @ D[k] < -0.98:  # turning back: no blend can do it, stop at the corner
            continue
        f = _deviation_factor(D[k - 1], D[k])
        size = tube_radius / f if f > _EPS else np.inf
        scale = 1.0 if blend_scale is None else float(blend_scale[k])
        b[k] = scale * min(size, 0.45 * L[k - 1], 0.45 * L[k])
    pieces: list[_Piece] = list(head or [])
    cursor = W[0]
    for k in range(1, n):
        end = W[k] - b[k] * D[k - 1] if k < n - 1 else W[k]
        pieces.append(_Line(cursor, end))
        if k < n - 1 and b[k] > _EPS:
            A, B = end, W[k] + b[k] * D[k]
            ell = float(np.linalg.norm(B - A))
            z = np.zeros_like(A)
            pieces += _Quintic.split(_quintic(A, ell * D[k - 1], z, B, ell * D[k], z), ell, _BLEND_PARTS)
            cursor = B
        else:
            cursor = end
    return Curve(pieces, W)


# ============================================================================ time law
@dataclass(frozen=True)
class _Law:
    """Piecewise constant-jerk motion along s: phase k starts at t[k] with (s, v, a) and jerk j."""

    t: np.ndarray
    s: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray
    duration: float

    def eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        dt = t - self.t[k]
        j, a, v = self.j[k], self.a[k], self.v[k]
        s = self.s[k] + v * dt + a * dt**2 / 2 + j * dt**3 / 6
        return s, v + a * dt + j * dt**2 / 2, a + j * dt, j


def _phases_of(traj: ruckig.Trajectory, t0: float) -> list[tuple[float, float, float, float, float, float]]:
    """(t_start, duration, s, v, a, j) of every non-empty phase of a 1-DoF Ruckig trajectory."""
    out = []
    pr = traj.profiles[0][0]
    t = t0
    br = pr.brake
    if br.duration > 0:
        for i in range(2):
            if br.t[i] > 0:
                out.append((t, br.t[i], br.p[i], br.v[i], br.a[i], br.j[i]))
                t += br.t[i]
    for i in range(7):
        if pr.t[i] > 0:
            out.append((t, pr.t[i], pr.p[i], pr.v[i], pr.a[i], pr.j[i]))
            t += pr.t[i]
    return out


def _min_distance(va: float, vb: float, a: float, j: float) -> float:
    """Shortest path length to change speed va -> vb from rest acceleration to rest acceleration."""
    dv = abs(vb - va)
    T = dv / a + a / j if dv >= a * a / j else 2 * math.sqrt(dv / j)
    return (va + vb) / 2 * T


def _max_speed(v_other: float, length: float, a: float, j: float, cap: float) -> float:
    """Highest speed (<= cap) that can change to v_other within `length`."""
    if _min_distance(cap, v_other, a, j) <= length:
        return cap
    lo, hi = min(v_other, cap), cap
    for _ in range(40):
        mid = (lo + hi) / 2
        if _min_distance(mid, v_other, a, j) <= length:
            lo = mid
        else:
            hi = mid
    return lo


class _Solver:
    def __init__(self):
        self.otg = ruckig.Ruckig(1)
        self.inp = ruckig.InputParameter(1)
        self.out = ruckig.Trajectory(1)

    def reach(self, s0, v0, a0, s1, v1, vmax, amax, jmax) -> ruckig.Trajectory | None:
        i = self.inp
        i.control_interface = ruckig.ControlInterface.Position
        i.current_position, i.current_velocity, i.current_acceleration = [s0], [v0], [a0]
        i.target_position, i.target_velocity, i.target_acceleration = [s1], [v1], [0.0]
        i.max_velocity, i.max_acceleration, i.max_jerk = [vmax], [amax], [jmax]
        i.min_velocity = [0.0]
        try:
            res = self.otg.calculate(i, self.out)
        except (RuntimeError, ruckig.RuckigError):
            return None
        if res not in (ruckig.Result.Working, ruckig.Result.Finished):
            return None
        ext = self.out.position_extrema[0]
        if ext.max > s1 + 1e-7 or ext.min < s0 - 1e-7:
            return None  # would overshoot the piece or back up
        return self.out

    def stop(self, s0, v0, a0, amax, jmax) -> ruckig.Trajectory:
        i = self.inp
        i.control_interface = ruckig.ControlInterface.Velocity
        i.current_position, i.current_velocity, i.current_acceleration = [s0], [v0], [a0]
        i.target_velocity, i.target_acceleration = [0.0], [0.0]
        i.max_velocity, i.max_acceleration, i.max_jerk = [max(v0, 1e-9) * 2], [amax], [jmax]
        self.otg.calculate(i, self.out)
        return self.out


def _time_law(curve: Curve, lim: _Limits, s0: float, v0: float, a0: float, s_end: float) -> _Law:
    """Jerk-limited s(t) from (s0, v0, a0) to rest at s_end, piece by piece, never backwards."""
    first = int(curve.piece_at(np.array([s0]))[0])
    last = int(curve.piece_at(np.array([s_end - 1e-12]))[0])
    ks = list(range(first, last + 1))
    bounds = [_piece_bounds(curve.pieces[k], lim) for k in ks]
    edges = [s0] + [float(curve.starts[k + 1]) for k in ks[:-1]] + [s_end]
    n = len(ks)
    cap = np.empty(n + 1)
    cap[0] = v0
    for i in range(1, n):
        cap[i] = min(bounds[i - 1][0], bounds[i][0])
    cap[n] = 0.0
    for i in range(1, n):  # two pieces meeting at an angle (an unblended corner): come to rest there
        before = curve.pieces[ks[i - 1]]
        t_in = before.eval(np.array([before.length]), 1)[0]
        t_out = curve.pieces[ks[i]].eval(np.array([0.0]), 1)[0]
        if np.linalg.norm(t_in - t_out) > 1e-6:
            cap[i] = 0.0
    for i in range(n - 1, 0, -1):  # backward: able to slow down in time
        vmax, amax, jmax = bounds[i]
        cap[i] = min(cap[i], _max_speed(cap[i + 1], edges[i + 1] - edges[i], amax, jmax, max(cap[i], cap[i + 1])))
    for i in range(1, n):  # forward: able to speed up in time
        vmax, amax, jmax = bounds[i - 1]
        cap[i] = min(cap[i], _max_speed(cap[i - 1], edges[i] - edges[i - 1], amax, jmax, max(cap[i], cap[i - 1])))
    solver = _Solver()
    phases: list[tuple] = []
    t, a_now = 0.0, a0
    for i in range(n):
        vmax, amax, jmax = bounds[i]
        target = cap[i + 1]
        start_v = cap[i]
        sol = None
        for _ in range(25):
            sol = solver.reach(edges[i], start_v, a_now, edges[i + 1], target, vmax, amax, jmax)
            if sol is not None or target <= 1e-9:
                break
            target *= 0.7  # the piece is too short for this handover speed
        if sol is None:
            raise TrajectoryError(f"cannot time path piece {ks[i]} from speed {start_v:.3f} within the limits")
        cap[i + 1] = target
        phases += _phases_of(sol, t)
        t += sol.duration
        a_now = 0.0
    return _law_from(phases, t, s_end)


def _law_from(phases, duration: float, s_end: float) -> _Law:
    if not phases:
        phases = [(0.0, 0.0, s_end, 0.0, 0.0, 0.0)]
    arr = np.array(phases, dtype=float)
    return _Law(arr[:, 0], arr[:, 2], arr[:, 3], arr[:, 4], arr[:, 5], float(duration))


# ============================================================================ trajectories
class Trajectory:
    """A timed, jerk-limited motion along a curve. Time runs from 0 to `duration` [s]."""

    def __init__(
        self, curve: Curve, law: _Law, limits: _Limits, joint_names: Sequence[str] = (), nominal: _Limits | None = None
    ):
        self.curve = curve
        self.law = law
        self.limits = limits
        self.nominal = nominal or limits  # the limits before any slow-down: a resume goes back to them
        self.joint_names = tuple(joint_names)

    @property
    def duration(self) -> float:
        return self.law.duration

    @property
    def start(self) -> np.ndarray:
        return self.curve.eval(self.law.s[:1])[0]

    @property
    def end(self) -> np.ndarray:
        return self.curve.eval(np.array([self.law.eval(np.array([self.duration]))[0][0]]))[0]

    def path_state(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s, s_dot, s_ddot, s_dddot) at times t."""
        return self.law.eval(np.atleast_1d(t))

    def evaluate(self, t, order: int = 2) -> list[np.ndarray]:
        """[q, q_dot, q_ddot(, q_dddot)] (n, dof) at times t (clamped to [0, duration])."""
        s, v, a, j = self.law.eval(np.atleast_1d(np.asarray(t, dtype=float)))
        d1 = self.curve.eval(s, 1)
        out = [self.curve.eval(s, 0), d1 * v[:, None]]
        if order >= 2:
            d2 = self.curve.eval(s, 2)
            out.append(d1 * a[:, None] + d2 * (v**2)[:, None])
            if order >= 3:
                d3 = self.curve.eval(s, 3)
                out.append(d1 * j[:, None] + 3 * d2 * (v * a)[:, None] + d3 * (v**3)[:, None])
        return out

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q_dot, q_ddot) at time t [s]."""
        q, qd, qdd = self.evaluate(np.array([t]))
        return q[0], qd[0], qdd[0]

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Times, positions, velocities, accelerations every dt [s], the end included."""
        if not dt > 0:
            raise InvalidInputError(f"dt must be > 0, got {dt}")
        t = np.arange(0.0, self.duration, dt)
        t = np.append(t, self.duration)
        q, qd, qdd = self.evaluate(t)
        return t, q, qd, qdd

    def s_at(self, t: float) -> float:
        return float(self.law.eval(np.array([t]))[0][0])

    def __repr__(self) -> str:
        c = self.curve
        return f"Trajectory(duration={self.duration:.3f} s, length={c.length:.3f}, pieces={len(c.pieces)})"


@dataclass
class TimingReport:
    """How a path was timed: blends shrunk after collision checks, the final tube deviation [rad]."""

    shrunk_blends: int = 0
    stops_at_corners: int = 0
    max_deviation: float = 0.0


class TrajectoryGenerator:
    """Times paths, splices new paths onto motions in progress, and brakes along paths.

    Args:
        robot: for the joint limits.
        checker: the collision checker; timed curves are re-checked at its path resolution. None skips it.
        tube_radius: how far [rad, joint-space Euclidean] the curve may leave the collision-free polyline.
    """

    def __init__(self, robot, checker=None, *, tube_radius: float = 0.1):
        if not tube_radius > 0:
            raise InvalidInputError(f"tube_radius must be > 0 rad, got {tube_radius}")
        self.robot = robot
        self.checker = checker
        self.tube_radius = float(tube_radius)

    def limits(self, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> _Limits:
        for name, f in (("velocity_scale", velocity_scale), ("acceleration_scale", acceleration_scale)):
            if not (0.0 < f <= 1.0):
                raise InvalidInputError(f"{name} must be in (0, 1], got {f}")
        lim = self.robot.limits
        return _Limits(
            lim.velocity * velocity_scale, lim.acceleration * acceleration_scale, lim.jerk * acceleration_scale
        )

    def _check_path(self, W) -> np.ndarray:
        W = self.robot.check_q(W, "path")
        if W.ndim != 2 or len(W) < 2:
            raise InvalidInputError(f"a path needs at least 2 waypoints of {self.robot.dof} joints, got {W.shape}")
        return W

    # ------------------------------------------------------------------ timing
    def time(
        self, path, velocity_scale: float = 1.0, acceleration_scale: float = 1.0, report: TimingReport | None = None
    ) -> Trajectory:
        """A jerk-limited trajectory from rest to rest along `path` (m, dof), corners blended within the tube."""
        W = self._check_path(path)
        lim = self.limits(velocity_scale, acceleration_scale)
        curve, scale = self._safe_curve(W, report)
        law = _time_law(curve, lim, 0.0, 0.0, 0.0, curve.length)
        # a tight blend can be slower than stopping at its corner: keep each blend only if it saves time
        for k in np.flatnonzero(scale > 0)[1:-1] if len(scale) > 2 else []:
            trial = scale.copy()
            trial[k] = 0.0
            c = blended_curve(W, self.tube_radius, trial)
            lw = _time_law(c, lim, 0.0, 0.0, 0.0, c.length)
            if lw.duration < law.duration - 1e-9:
                curve, law, scale = c, lw, trial
        if len(scale) > 2 and np.any(scale[1:-1] > 0):  # blends chosen one at a time: never worse than none
            c = blended_curve(W, self.tube_radius, np.zeros(len(W)))
            lw = _time_law(c, lim, 0.0, 0.0, 0.0, c.length)
            if lw.duration < law.duration - 1e-9:
                curve, law, scale = c, lw, np.zeros(len(W))
        if report:
            report.stops_at_corners = int(np.sum(scale[1:-1] == 0)) if len(scale) > 2 else 0
            report.max_deviation = float(distance_to_polyline(curve.samples(), curve.polyline).max())
        return Trajectory(curve, law, lim, self.robot.joint_names)

    def time_naive(self, path, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> Trajectory:
        """The reference: straight lines, coming to rest at every waypoint."""
        W = self._check_path(path)
        curve = blended_curve(W, self.tube_radius, blend_scale=np.zeros(len(W)))
        return Trajectory(
            curve,
            _time_law(curve, self.limits(velocity_scale, acceleration_scale), 0, 0, 0, curve.length),
            self.limits(velocity_scale, acceleration_scale),
            self.robot.joint_names,
        )

    def _safe_curve(self, W: np.ndarray, report: TimingReport | None, head=None) -> tuple[Curve, np.ndarray]:
        """Blend within the tube; shrink any blend whose corner cut collides (the polyline itself is valid)."""
        scale = np.ones(len(W))
        for attempt in range(4):
            curve = blended_curve(W, self.tube_radius, scale, head)
            bad = self._colliding_corners(curve, W, skip=len(head or []))
            if not len(bad):
                break
            if attempt == 3:
                scale[bad] = 0.0
                curve = blended_curve(W, self.tube_radius, scale, head)
                break
            scale[bad] *= 0.4
            if report:
                report.shrunk_blends += len(bad)
        return curve, scale

    def _colliding_corners(self, curve: Curve, W: np.ndarray, skip: int = 0) -> np.ndarray:
        if self.checker is None:
            return np.zeros(0, dtype=np.int64)
        bad = set()
        for piece in curve.pieces[skip:]:
            if isinstance(piece, _Line):
                continue
            pts = piece.eval(np.linspace(0, piece.length, 9), 0)
            if not self.checker.path_valid(pts):
                mid = pts[len(pts) // 2]
                bad.add(int(np.argmin(np.linalg.norm(W - mid, axis=1))))  # the corner this blend rounds
        return np.array(sorted(bad), dtype=np.int64)

    # ------------------------------------------------------------------ brake
    def brake(self, traj: Trajectory, t: float) -> Trajectory:
        """The shortest jerk-limited stop from the state at time t that stays on the trajectory's own curve."""
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t])))
        curve = traj.curve
        # a stop only slows down: no velocity cap (the arm may still be above a just-lowered one)
        lim = _Limits(traj.limits.velocity * 1e3, traj.limits.acceleration, traj.limits.jerk)
        end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        if v0 <= 1e-9 and abs(a0) <= 1e-9:
            return Trajectory(curve, _law_from([], 0.0, s0), traj.limits, traj.joint_names, traj.nominal)
        # the closest stop point whose backward pass admits the current speed, then time it like any path;
        # speeding up, the arm still gains a^2 / 2j (at the weakest piece's jerk) before it can slow down
        j_min = min(_piece_bounds(p, lim)[2] for p in curve.pieces)
        v_eff = v0 + (a0 * a0 / (2 * j_min) if a0 > 0 else 0.0)
        lo, hi = s0, end
        if not self._can_stop(curve, lim, s0, v_eff, hi):
            return self.retime_from(traj, t)
        for _ in range(40):
            mid = (lo + hi) / 2
            if self._can_stop(curve, lim, s0, v_eff, mid):
                hi = mid
            else:
                lo = mid
        stop = hi
        for _ in range(60):
            try:
                law = _time_law(curve, lim, s0, v0, a0, stop)
                return Trajectory(curve, law, traj.limits, traj.joint_names, traj.nominal)
            except TrajectoryError:
                if stop >= end:
                    break
                stop = min(end, stop + 0.05 * (stop - s0) + 1e-4)  # a little farther: never a move elsewhere
        return self.retime_from(traj, t)

    def retime_from(self, traj: Trajectory, t: float) -> Trajectory:
        """The rest of `traj` from time t, as a trajectory starting at 0."""
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t])))
        end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        return Trajectory(
            traj.curve, _time_law(traj.curve, traj.limits, s0, v0, a0, end), traj.limits, traj.joint_names, traj.nominal
        )

    def slow_down(self, traj: Trajectory, t: float, factor: float) -> Trajectory:
        """The rest of `traj` from time t on its own curve, at `factor` in (0, 1] of its nominal velocity limits."""
        if not (0.0 < factor <= 1.0):
            raise InvalidInputError(f"factor must be in (0, 1], got {factor}")
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t])))
        base = traj.nominal  # slow-downs of slow-downs do not compound
        lim = _Limits(base.velocity * factor, base.acceleration, base.jerk)
        law = _time_law(traj.curve, lim, s0, v0, a0, traj.curve.length)
        return Trajectory(traj.curve, law, lim, traj.joint_names, base)

    def resume(self, traj: Trajectory) -> Trajectory:
        """From where `traj` ends at rest (a brake's stop), on to the end of its curve at the nominal limits."""
        s_stop = traj.s_at(traj.duration)
        lim = traj.nominal
        if traj.curve.length - s_stop < 1e-9:
            return Trajectory(traj.curve, _law_from([], 0.0, s_stop), lim, traj.joint_names)
        law = _time_law(traj.curve, lim, s_stop, 0.0, 0.0, traj.curve.length)
        return Trajectory(traj.curve, law, lim, traj.joint_names)

    @staticmethod
    def _can_stop(curve: Curve, lim: _Limits, s0: float, v0: float, stop: float) -> bool:
        first = int(curve.piece_at(np.array([s0]))[0])
        last = int(curve.piece_at(np.array([stop - 1e-12]))[0])
        v = 0.0
        for k in range(last, first - 1, -1):
            vmax, amax, jmax = _piece_bounds(curve.pieces[k], lim)
            a_edge = max(s0, float(curve.starts[k]))
            b_edge = min(stop, float(curve.starts[k + 1]))
            v = _max_speed(v, max(b_edge - a_edge, 0.0), amax, jmax, max(vmax, v0))
        return v >= v0 - 1e-9

    # ------------------------------------------------------------------ splice
    def splice(
        self,
        traj: Trajectory,
        t0: float,
        new_path,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
        report: TimingReport | None = None,
        budget: float = 0.1,
    ) -> Trajectory:
        """Continue `traj` from its state at time t0 onto new_path (whose first waypoint is that state's position).

        The result starts exactly in that state (position, velocity, acceleration): it may first follow the old
        curve a little (a lead-in, to slow down before turning), then a quintic transition merges tangentially
        into the new path. Progress along the new path never decreases. Raises TrajectoryError if no such
        transition exists (the new path turns back against the motion) or none is found within `budget` [s]:
        brake and plan from rest instead.
        """
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t0])))
        q0 = traj.curve.eval(np.array([s0]))[0]
        W = self._check_path(new_path)
        if np.linalg.norm(W[0] - q0) > 1e-6:
            raise InvalidInputError("the new path must start at the trajectory's position at t0")
        lim = self.limits(velocity_scale, acceleration_scale)
        if v0 < 1e-9 and abs(a0) < 1e-9:
            return self.time(W, velocity_scale, acceleration_scale, report)
        old_end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        total = float(np.sum(np.linalg.norm(np.diff(W, axis=0), axis=1)))
        last_err = "no transition fits"
        give_up = time.perf_counter() + budget
        for lead in (0.0, 0.1, 0.25, 0.5, 0.8, 1.2):
            if time.perf_counter() > give_up:
                last_err += f" (searched for {budget:.2f} s)"
                break
            if lead > 0 and s0 + lead > old_end - 1e-6:
                break
            head = _clip(traj.curve, s0, s0 + lead) if lead > 0 else []
            s1 = s0 + lead
            p1 = traj.curve.eval(np.array([s1]), 0)[0]
            t1 = traj.curve.eval(np.array([s1]), 1)[0]
            k1 = traj.curve.eval(np.array([s1]), 2)[0]
            if np.linalg.norm(t1) < 1e-9:
                continue
            scale = np.linalg.norm(t1)  # |dq/ds| is 1 on lines, near 1 on blends: keep q' continuous as is
            for length in (0.05, 0.1, 0.2, 0.35, 0.5, 0.8, 1.2, 1.8, 2.5):
                length = min(length, 0.9 * total)
                B, k = _point_along(W, length)
                d_b = (W[k + 1] - W[k]) / np.linalg.norm(W[k + 1] - W[k])
                ell = float(np.linalg.norm(B - p1))
                if ell < 1e-6:
                    continue
                coeffs = _quintic(p1, ell * t1, ell**2 * k1, B, ell * scale * d_b, np.zeros_like(p1))
                transition = _Quintic.split(coeffs, ell, _SPLICE_PARTS)
                first = (head or transition)[0]
                if _piece_bounds(first, lim)[0] < v0 - 1e-9:
                    last_err = f"turning onto the new path at {v0:.2f} rad/s needs a longer lead-in"
                    continue
                rest = np.vstack([B, W[k + 1 :]])
                try:
                    curve, _ = self._safe_curve(rest, report, head=head + transition)
                    pts = np.vstack([h.eval(np.linspace(0, h.length, 5), 0) for h in head + transition])
                    if self.checker is not None and not self.checker.path_valid(pts):
                        last_err = "the transition onto the new path collides"
                        continue
                    law = _time_law(curve, lim, 0.0, v0, a0, curve.length)
                except TrajectoryError as err:
                    last_err = str(err)
                    continue
                new = Trajectory(curve, law, lim, self.robot.joint_names)
                P = new.evaluate(np.linspace(0, new.duration, 300), order=0)[0]
                if np.any(np.diff(progress_along(P, W)) < -1e-6):
                    last_err = "the transition would move backwards along the new path"
                    continue
                return new
        raise TrajectoryError(f"cannot splice the new path onto the motion: {last_err}; brake and plan from rest")


def _clip(curve: Curve, a: float, b: float) -> list[_Piece]:
    """The pieces of `curve` between arc positions a and b, cut where needed."""
    out: list[_Piece] = []
    for k, piece in enumerate(curve.pieces):
        lo, hi = float(curve.starts[k]), float(curve.starts[k + 1])
        x0, x1 = max(a, lo) - lo, min(b, hi) - lo
        if x1 - x0 <= 1e-12:
            continue
        if isinstance(piece, _Line):
            out.append(_Line(piece.eval(np.array([x0]), 0)[0], piece.eval(np.array([x1]), 0)[0]))
        else:
            out.append(_Quintic(piece.c, piece.ell, piece.u0 + x0 / piece.ell, piece.u0 + x1 / piece.ell))
    return out


def _point_along(W: np.ndarray, length: float) -> tuple[np.ndarray, int]:
    """The point at arc length `length` along W and the index of its segment."""
    seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
    acc = 0.0
    for k, L in enumerate(seg):
        if acc + L >= length or k == len(seg) - 1:
            f = np.clip((length - acc) / L, 0.0, 1.0)
            return W[k] + f * (W[k + 1] - W[k]), k
        acc += L
    return W[-1], len(seg) - 1
