"""The time law s(t) along a curve: jerk-limited, piece by piece, with Ruckig's local state-to-state solver.

Ruckig's intermediate waypoints call a cloud service: only its state-to-state calculations are used, with
min_velocity 0, so the arm never moves backwards along its path. Joint limits become bounds on the path speed,
acceleration and jerk per piece: with q' = dq/ds etc., q_dot = q' s_dot, q_ddot = q' s_ddot + q'' s_dot^2,
q_dddot = q' s_dddot + 3 q'' s_dot s_ddot + q''' s_dot^3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig

from ..errors import TrajectoryError
from . import kernels
from .curve import EPS, Curve, Piece

CURVE_SHARE = 0.75  # of each joint's acceleration a blend may use for its curvature at full blend speed


class PieceTimingError(TrajectoryError):
    """Ruckig could not time one piece: `result` is its answer (None if it refused the input), `inputs` what it got."""

    def __init__(self, message: str, result: str | None = None, inputs: dict | None = None):
        self.result = result
        self.inputs = dict(inputs or {})
        super().__init__(message)


@dataclass(frozen=True)
class Limits:
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray


@dataclass(frozen=True)
class SpeedCaps:
    """Path speed caps along a curve, piecewise constant: speed[i] [s units/s] on [edges[i], edges[i + 1]) of s.

    What else limits the speed (a person near the path, say) than the joint limits: the time law keeps under both.
    """

    edges: np.ndarray
    speed: np.ndarray

    def __post_init__(self) -> None:
        e, v = np.asarray(self.edges, float), np.asarray(self.speed, float)
        if e.ndim != 1 or v.shape != (len(e) - 1,) or len(v) < 1 or np.any(np.diff(e) <= 0) or np.any(~(v > 0)):
            raise ValueError("speed caps need increasing edges (K + 1,) and K speeds > 0")
        object.__setattr__(self, "edges", e)
        object.__setattr__(self, "speed", v)


def _capped(ks, bounds, edges, caps: SpeedCaps):
    """ks, bounds, edges with every part of a piece under one cap: pieces cut where a cap changes, their speed
    bounds lowered to it (beyond the caps' edges, the last cap holds)."""
    nk, nb, ne = [], [], [edges[0]]
    for i, k in enumerate(ks):
        a, b = edges[i], edges[i + 1]
        cuts = caps.edges[(caps.edges > a + 1e-9) & (caps.edges < b - 1e-9)]
        for lo, hi in zip([a, *cuts], [*cuts, b]):
            j = min(max(int(np.searchsorted(caps.edges, (lo + hi) / 2, side="right")) - 1, 0), len(caps.speed) - 1)
            nk.append(k)
            nb.append([min(bounds[i][0], float(caps.speed[j])), bounds[i][1], bounds[i][2]])
            ne.append(hi)
    return nk, nb, ne


def piece_bounds(piece: Piece, lim: Limits) -> tuple[float, float, float]:
    """(max s_dot, max s_ddot, max s_dddot) on a piece that keep every joint within its limits."""
    return tuple(bounds_of([piece], lim)[0])


def bounds_of(pieces: list[Piece], lim: Limits) -> np.ndarray:
    """piece_bounds of many pieces at once (P, 3); each piece remembers its bounds for the last limits asked."""
    out = np.empty((len(pieces), 3))
    todo = []
    for i, p in enumerate(pieces):
        memo = p.bounds_memo
        if memo is not None and memo[0] is lim:
            out[i] = memo[1]
        else:
            todo.append(i)
    if todo:
        out[todo] = speed_bounds(np.stack([pieces[i].m for i in todo]), lim)
        for i in todo:
            pieces[i].bounds_memo = (lim, out[i])
    return out


def speed_bounds(m: np.ndarray, lim: Limits, strict: bool = True) -> np.ndarray:
    """Path speed, acceleration and jerk bounds (P, 3) from derivative bounds m (P, 3, dof) of P pieces.

    A piece too sharply curved to be timed raises TrajectoryError, or with strict=False gets bounds 0.
    """
    m = kernels.writable(m)
    out = np.empty((len(m), 3))
    v, a, j = (kernels.writable(x) for x in (lim.velocity, lim.acceleration, lim.jerk))
    timable = kernels.path_bounds(m, v, a, j, EPS, CURVE_SHARE, out)
    if strict and not timable.all():
        raise TrajectoryError("a path piece is too sharply curved to be timed within the joint limits")
    return out


@dataclass(frozen=True)
class TimeLaw:
    """Piecewise constant-jerk motion along s: phase k starts at t[k] with (s, v, a) and jerk j."""

    t: np.ndarray
    s: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray
    duration: float

    def eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.minimum(np.maximum(np.asarray(t, dtype=float), 0.0), self.duration)  # np.clip: ~10 us more a call
        k = np.minimum(np.maximum(np.searchsorted(self.t, t, side="right") - 1, 0), len(self.t) - 1)
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


def min_distance(va: float, vb: float, a: float, j: float) -> float:
    """Shortest path length to change speed va -> vb from rest acceleration to rest acceleration."""
    dv = abs(vb - va)
    T = dv / a + a / j if dv >= a * a / j else 2 * math.sqrt(dv / j)
    return (va + vb) / 2 * T


def _boundary(ok, good: float, bad: float) -> float:
    """Between a value where ok() holds and one where it does not, the last where it holds (to 40 halvings)."""
    for _ in range(40):
        mid = (good + bad) / 2
        if ok(mid):
            good = mid
        else:
            bad = mid
    return good


def max_speed(v_other: float, length: float, a: float, j: float, cap: float) -> float:
    """Highest speed (<= cap) that can change to v_other within `length`."""
    if min_distance(cap, v_other, a, j) <= length:
        return cap
    return _boundary(lambda v: min_distance(v, v_other, a, j) <= length, min(v_other, cap), cap)


class _Solver:
    def __init__(self):
        self.otg = ruckig.Ruckig(1)
        self.inp = ruckig.InputParameter(1)
        self.out = ruckig.Trajectory(1)

    def reach(self, s0, v0, a0, s1, v1, vmax, amax, jmax) -> ruckig.Trajectory:
        """Rest acceleration at s1 with speed v1, from (s0, v0, a0); raises PieceTimingError with Ruckig's answer."""
        i = self.inp
        i.control_interface = ruckig.ControlInterface.Position
        i.current_position, i.current_velocity, i.current_acceleration = [s0], [v0], [a0]
        i.target_position, i.target_velocity, i.target_acceleration = [s1], [v1], [0.0]
        i.max_velocity, i.max_acceleration, i.max_jerk = [vmax], [amax], [jmax]
        i.min_velocity = [0.0]
        inputs = {"s0": s0, "v0": v0, "a0": a0, "s1": s1, "v1": v1, "vmax": vmax, "amax": amax, "jmax": jmax}
        try:
            res = self.otg.calculate(i, self.out)
        except (RuntimeError, ruckig.RuckigError) as err:
            raise PieceTimingError(f"Ruckig refused the input: {err}", None, inputs) from None
        if res not in (ruckig.Result.Working, ruckig.Result.Finished):
            raise PieceTimingError(f"Ruckig answered {res.name}", res.name, inputs)
        ext = self.out.position_extrema[0]
        if ext.max > s1 + 1e-7 or ext.min < s0 - 1e-7:
            raise PieceTimingError("the motion would overshoot the piece or back up", res.name, inputs)
        return self.out

    def stop(self, s0, v0, a0, amax, jmax) -> ruckig.Trajectory:
        i = self.inp
        i.control_interface = ruckig.ControlInterface.Velocity
        i.current_position, i.current_velocity, i.current_acceleration = [s0], [v0], [a0]
        i.target_velocity, i.target_acceleration = [0.0], [0.0]
        i.max_velocity, i.max_acceleration, i.max_jerk = [max(v0, 1e-9) * 2], [amax], [jmax]
        self.otg.calculate(i, self.out)
        return self.out


def min_speed_after(va: float, length: float, a: float, j: float) -> float:
    """The lowest speed that va can slow to within `length` (rest acceleration at both ends)."""
    if min_distance(va, 0.0, a, j) <= length:
        return 0.0
    return _boundary(lambda v: min_distance(va, v, a, j) <= length, va, 0.0)


def _speed_caps(
    curve: Curve,
    lim: Limits,
    s0: float,
    v0: float,
    s_end: float,
    end_cap: float | None,
    keep: Limits | None = None,
    a0: float = 0.0,
    caps: SpeedCaps | None = None,
):
    """Pieces ks from s0 to s_end, their bounds, edges, and the highest speed at each edge the arm can slow down from.

    end_cap: the speed allowed at s_end (0: come to rest there; None: the last piece's own speed bound).
    keep: the limits the arm is running at when `lim` is lower (a slow-down): until it can have slowed down to `lim`,
        braking as hard as each piece allows, a piece keeps the speed the arm can still have there (within `keep`).
    caps: speed caps along s besides the limits' (see SpeedCaps).
    """
    first = int(curve.piece_at(np.array([s0]))[0])
    last = int(curve.piece_at(np.array([s_end - 1e-12]))[0])
    ks = list(range(first, last + 1))
    bounds = bounds_of(curve.pieces[first : last + 1], lim).tolist()
    edges = [s0] + [float(curve.starts[k + 1]) for k in ks[:-1]] + [s_end]
    if caps is not None:
        ks, bounds, edges = _capped(ks, bounds, edges, caps)
    n = len(ks)
    if keep is not None and v0 > bounds[0][0]:
        ks, bounds, edges = _slowing(curve, ks, bounds, edges, keep, v0, a0)
        n = len(ks)
    cap = np.empty(n + 1)
    cap[0] = v0
    for i in range(1, n):
        cap[i] = min(bounds[i - 1][0], bounds[i][0])
    cap[n] = bounds[-1][0] if end_cap is None else end_cap
    for i in range(1, n):  # two pieces meeting at an angle (an unblended corner): come to rest there
        if ks[i - 1] == ks[i]:
            continue  # one piece in two parts (see _slowing)
        t_in, t_out = curve.pieces[ks[i - 1]].end_tangents[1], curve.pieces[ks[i]].end_tangents[0]
        if np.linalg.norm(t_in - t_out) > 1e-6:
            cap[i] = 0.0
    for i in range(n - 1, 0, -1):  # backward: able to slow down in time
        vmax, amax, jmax = bounds[i]
        cap[i] = min(cap[i], max_speed(cap[i + 1], edges[i + 1] - edges[i], amax, jmax, max(cap[i], cap[i + 1])))
    return ks, bounds, edges, cap


def _slowing(curve: Curve, ks, bounds, edges, keep: Limits, v0: float, a0: float):
    """ks, bounds, edges for an arm at v0 above `bounds` (a slow-down): braking as hard as each piece allows (within
    the limits it runs at, `keep`), it keeps the speed it can still have until it is down to a piece's own bound;
    that piece is cut there, the rest of it at its own bound."""
    old = bounds_of([curve.pieces[k] for k in ks], keep).tolist()
    env = v0 + (a0 * a0 / (2.0 * old[0][2]) if a0 > 0 else 0.0)  # speeding up, it gains a^2 / 2j first
    nk, nb, ne = [], [], [edges[0]]
    for i, k in enumerate(ks):
        length = edges[i + 1] - edges[i]
        if env <= bounds[i][0]:  # slowed down: the rest as timed at the new limits
            nk += ks[i:]
            nb += bounds[i:]
            ne += edges[i + 1 :]
            break
        b = [max(bounds[i][0], min(env, old[i][0])), min(bounds[i][1], old[i][1]), min(bounds[i][2], old[i][2])]
        need = min_distance(env, bounds[i][0], b[1], b[2]) / 0.8  # with slack: not to the last mm
        if need < length:
            nk += [k, k]
            nb += [b, bounds[i]]
            ne += [edges[i] + need, edges[i + 1]]
            env = 0.0
            continue
        nk.append(k)
        nb.append(b)
        ne.append(edges[i + 1])
        env = min_speed_after(env, 0.8 * length, b[1], b[2])
    return nk, nb, ne


def entry_speed(curve: Curve, lim: Limits, pieces: int) -> float:
    """The highest speed [along s] at s = 0 from which the first `pieces` pieces can be followed within the limits.

    What lies beyond them does not constrain it: a necessary condition for timing the whole curve, and a cheap one.
    """
    s_end = float(curve.starts[min(pieces, len(curve.pieces))])
    ks, bounds, edges, cap = _speed_caps(curve, lim, 0.0, 0.0, s_end, None)
    vmax, amax, jmax = bounds[0]
    return min(vmax, max_speed(cap[1], edges[1] - edges[0], amax, jmax, vmax))


def time_law(
    curve: Curve,
    lim: Limits,
    s0: float,
    v0: float,
    a0: float,
    s_end: float,
    keep: Limits | None = None,
    caps: SpeedCaps | None = None,
) -> TimeLaw:
    """Jerk-limited s(t) from (s0, v0, a0) to rest at s_end, piece by piece, never backwards.

    keep: the limits the arm runs at now, if higher than `lim`: it slows down to `lim` within them (see _speed_caps).
    caps: speed caps along s besides the limits' (an arm above one where it starts slows down within `keep`).
    """
    ks, bounds, edges, cap = _speed_caps(curve, lim, s0, v0, s_end, 0.0, keep, a0, caps)
    n = len(ks)
    for i in range(1, n):  # forward: able to speed up in time
        vmax, amax, jmax = bounds[i - 1]
        cap[i] = min(cap[i], max_speed(cap[i - 1], edges[i] - edges[i - 1], amax, jmax, max(cap[i], cap[i - 1])))
    solver = _Solver()
    phases: list[tuple] = []
    t, a_now = 0.0, a0
    for i in range(n):
        vmax, amax, jmax = bounds[i]
        target = cap[i + 1]
        start_v = cap[i]
        sol = None
        for _ in range(25):
            try:
                sol = solver.reach(edges[i], start_v, a_now, edges[i + 1], target, vmax, amax, jmax)
                break
            except PieceTimingError as err:
                if target <= 1e-9:
                    raise PieceTimingError(
                        f"cannot time path piece {ks[i]} from speed {start_v:.3f} within the limits ({err})",
                        err.result,
                        err.inputs,
                    ) from None
            target *= 0.7  # the piece is too short for this handover speed
        if sol is None:
            raise TrajectoryError(f"cannot time path piece {ks[i]} from speed {start_v:.3f} within the limits")
        cap[i + 1] = target
        phases += _phases_of(sol, t)
        t += sol.duration
        a_now = 0.0
    return law_from_phases(phases, t, s_end)


def law_from_phases(phases, duration: float, s_end: float) -> TimeLaw:
    if not phases:
        phases = [(0.0, 0.0, s_end, 0.0, 0.0, 0.0)]
    arr = np.array(phases, dtype=float)
    return TimeLaw(arr[:, 0], arr[:, 2], arr[:, 3], arr[:, 4], arr[:, 5], float(duration))


def slowest_entry(bounds: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """An upper bound (L,) of the speed at the start of L chains of pieces from which each can be followed.

    bounds (L, P, 3): each piece's (speed, acceleration, jerk) bounds; lengths (L, P). What follows a chain does
    not constrain it, so this is a cheap necessary condition (closed form, all chains at once) for `entry_speed`.
    """
    bounds = kernels.writable(bounds)
    return kernels.slowest_entry(bounds, kernels.writable(lengths), np.empty(len(bounds)))
