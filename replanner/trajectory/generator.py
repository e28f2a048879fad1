"""Trajectories and the generator that times paths, splices new paths onto a motion in progress and brakes.

A trajectory is a geometric curve q(s) (`curve.py`) plus a jerk-limited time law s(t) (`timelaw.py`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError, TrajectoryError
from .curve import (
    SPLICE_PARTS,
    Curve,
    Line,
    QuinticPiece,
    basis,
    blended_curve,
    clip_curve,
    distance_to_polyline,
    points_along,
    progress_along,
    quintic_bounds,
    quintic_coefficients,
)
from .kernels import warm_up
from .timelaw import (
    Limits,
    SpeedCaps,
    TimeLaw,
    bounds_of,
    entry_speed,
    law_from_phases,
    max_speed,
    piece_bounds,
    slowest_entry,
    speed_bounds,
    time_law,
)

log = logging.getLogger(__name__)

SPLICE_LEADS = (0.0, 0.1, 0.25, 0.5, 0.8, 1.2)  # [rad of arc] followed along the old curve before turning
SPLICE_MERGES = (0.05, 0.1, 0.2, 0.35, 0.5, 0.8, 1.2, 1.8, 2.5)  # [rad of arc] along the new path where it merges


class Trajectory:
    """A timed, jerk-limited motion along a curve. Time runs from 0 to `duration` [s]."""

    def __init__(
        self,
        curve: Curve,
        law: TimeLaw,
        limits: Limits,
        joint_names: Sequence[str] = (),
        nominal: Limits | None = None,
        caps: SpeedCaps | None = None,
    ):
        self.curve = curve
        self.law = law
        self.limits = limits
        self.nominal = nominal or limits  # the limits before any slow-down: a resume goes back to them
        self.joint_names = tuple(joint_names)
        self.caps = caps  # path speed caps besides the limits (people near the curve): every retiming keeps them

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
        """[q, q_dot, q_ddot, q_dddot] (n, dof) up to the order-th derivative, at times t (clamped to [0, duration])."""
        s, v, a, j = self.law.eval(np.atleast_1d(np.asarray(t, dtype=float)))
        out = [self.curve.eval(s, 0)]
        if order == 0:
            return out
        d1 = self.curve.eval(s, 1)
        out.append(d1 * v[:, None])
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
    """How a path was timed: blends shrunk after collision checks, the final tube deviation [rad], and for a
    splice how many candidate transitions were looked at."""

    shrunk_blends: int = 0
    stops_at_corners: int = 0
    max_deviation: float = 0.0
    splice_candidates: int = 0


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
        warm_up()  # the timing kernels compile now, not in the first splice of a running motion

    @classmethod
    def from_config(cls, robot, checker, cfg) -> TrajectoryGenerator:
        """From a validated `planning` config section (its tube radius)."""
        return cls(robot, checker, tube_radius=cfg.tube_radius)

    def with_checker(self, checker) -> TrajectoryGenerator:
        """This generator with its curves checked by `checker` (a plan's own: more padding from the map, say)."""
        return TrajectoryGenerator(self.robot, checker, tube_radius=self.tube_radius)

    def limits(self, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> Limits:
        for name, f in (("velocity_scale", velocity_scale), ("acceleration_scale", acceleration_scale)):
            if not (0.0 < f <= 1.0):
                raise InvalidInputError(f"{name} must be in (0, 1], got {f}")
        lim = self.robot.limits
        return Limits(
            lim.velocity * velocity_scale, lim.acceleration * acceleration_scale, lim.jerk * acceleration_scale
        )

    def _check_path(self, W) -> np.ndarray:
        W = self.robot.check_q(W, "path")
        if W.ndim != 2 or len(W) < 2:
            raise InvalidInputError(f"a path needs at least 2 waypoints of {self.robot.dof} joints, got {W.shape}")
        return W

    # ------------------------------------------------------------------ timing
    def time(
        self,
        path,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
        report: TimingReport | None = None,
        caps_of: Callable[[Curve], SpeedCaps | None] | None = None,
    ) -> Trajectory:
        """A jerk-limited trajectory from rest to rest along `path` (m, dof), corners blended within the tube.

        caps_of(curve): path speed caps along a curve besides the joint limits (see `SeparationCaps`), or None."""
        W = self._check_path(path)
        lim = self.limits(velocity_scale, acceleration_scale)
        caps_of = caps_of or (lambda c: None)
        curve, scale = self._safe_curve(W, report)
        caps = caps_of(curve)
        law = time_law(curve, lim, 0.0, 0.0, 0.0, curve.length, caps=caps)
        # a tight blend can be slower than stopping at its corner: keep each blend only if it saves time
        for k in np.flatnonzero(scale > 0)[1:-1] if len(scale) > 2 else []:
            trial = scale.copy()
            trial[k] = 0.0
            c = blended_curve(W, self.tube_radius, trial)
            cc = caps_of(c)
            lw = time_law(c, lim, 0.0, 0.0, 0.0, c.length, caps=cc)
            if lw.duration < law.duration - 1e-9:
                curve, law, scale, caps = c, lw, trial, cc
        if len(scale) > 2 and np.any(scale[1:-1] > 0):  # blends chosen one at a time: never worse than none
            c = blended_curve(W, self.tube_radius, np.zeros(len(W)))
            cc = caps_of(c)
            lw = time_law(c, lim, 0.0, 0.0, 0.0, c.length, caps=cc)
            if lw.duration < law.duration - 1e-9:
                curve, law, scale, caps = c, lw, np.zeros(len(W)), cc
        if report:
            report.stops_at_corners = int(np.sum(scale[1:-1] == 0)) if len(scale) > 2 else 0
            report.max_deviation = float(distance_to_polyline(curve.samples(), curve.polyline).max())
        return Trajectory(curve, law, lim, self.robot.joint_names, caps=caps)

    def time_naive(self, path, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> Trajectory:
        """The reference: straight lines, coming to rest at every waypoint."""
        W = self._check_path(path)
        curve = blended_curve(W, self.tube_radius, blend_scale=np.zeros(len(W)))
        return Trajectory(
            curve,
            time_law(curve, self.limits(velocity_scale, acceleration_scale), 0, 0, 0, curve.length),
            self.limits(velocity_scale, acceleration_scale),
            self.robot.joint_names,
        )

    def _safe_curve(
        self, W: np.ndarray, report: TimingReport | None, head=None, first: Curve | None = None
    ) -> tuple[Curve, np.ndarray]:
        """Blend within the tube; shrink any blend whose corner cut collides (the polyline itself is valid).

        first: blended_curve(W, tube_radius, None, head) if already built."""
        scale = np.ones(len(W))
        for attempt in range(4):
            curve = first if attempt == 0 and first is not None else blended_curve(W, self.tube_radius, scale, head)
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
        """Indices of the corners of W whose blend collides (skipping the first `skip` pieces)."""
        none = np.zeros(0, dtype=np.int64)
        blends = [p for p in curve.pieces[skip:] if not isinstance(p, Line)]
        if self.checker is None or not blends:
            return none
        samples = [p.eval(np.linspace(0, p.length, 9), 0) for p in blends]
        # one check for all: what joins one blend to the next is a line of the (valid) polyline itself
        if self.checker.path_valid(np.vstack(samples)):
            return none
        bad = set()
        for pts in samples:
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
        lim = Limits(traj.limits.velocity * 1e3, traj.limits.acceleration, traj.limits.jerk)
        end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        if v0 <= 1e-9 and abs(a0) <= 1e-9:
            return Trajectory(
                curve, law_from_phases([], 0.0, s0), traj.limits, traj.joint_names, traj.nominal, traj.caps
            )
        # the closest stop point whose backward pass admits the current speed, then time it like any path;
        # speeding up, the arm still gains a^2 / 2j (at the weakest piece's jerk) before it can slow down
        j_min = min(piece_bounds(p, lim)[2] for p in curve.pieces)
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
                law = time_law(curve, lim, s0, v0, a0, stop)
                return Trajectory(curve, law, traj.limits, traj.joint_names, traj.nominal, traj.caps)
            except TrajectoryError:
                if stop >= end:
                    break
                stop = min(end, stop + 0.05 * (stop - s0) + 1e-4)  # a little farther: never a move elsewhere
        return self.retime_from(traj, t)

    def retime_from(self, traj: Trajectory, t: float) -> Trajectory:
        """The rest of `traj` from time t, as a trajectory starting at 0."""
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t])))
        end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        law = time_law(traj.curve, traj.limits, s0, v0, a0, end, caps=traj.caps)
        return Trajectory(traj.curve, law, traj.limits, traj.joint_names, traj.nominal, traj.caps)

    def slow_down(self, traj: Trajectory, t: float, factor: float) -> Trajectory:
        """The rest of `traj` from time t on its own curve, at `factor` in (0, 1] of its nominal velocity limits."""
        if not (0.0 < factor <= 1.0):
            raise InvalidInputError(f"factor must be in (0, 1], got {factor}")
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t])))
        base = traj.nominal  # slow-downs of slow-downs do not compound
        lim = Limits(base.velocity * factor, base.acceleration, base.jerk)
        try:  # slowing down within the limits it runs at, as hard as the path allows
            law = time_law(traj.curve, lim, s0, v0, a0, traj.curve.length, keep=traj.limits, caps=traj.caps)
        except TrajectoryError:  # where that cut lands badly (a stop already close): as the new limits allow
            law = time_law(traj.curve, lim, s0, v0, a0, traj.curve.length, caps=traj.caps)
        return Trajectory(traj.curve, law, lim, traj.joint_names, base, traj.caps)

    def resume(self, traj: Trajectory) -> Trajectory:
        """From where `traj` ends at rest (a brake's stop), on to the end of its curve at the nominal limits."""
        s_stop = traj.s_at(traj.duration)
        lim = traj.nominal
        if traj.curve.length - s_stop < 1e-9:
            return Trajectory(traj.curve, law_from_phases([], 0.0, s_stop), lim, traj.joint_names, caps=traj.caps)
        law = time_law(traj.curve, lim, s_stop, 0.0, 0.0, traj.curve.length, caps=traj.caps)
        return Trajectory(traj.curve, law, lim, traj.joint_names, caps=traj.caps)

    @staticmethod
    def _can_stop(curve: Curve, lim: Limits, s0: float, v0: float, stop: float) -> bool:
        first = int(curve.piece_at(np.array([s0]))[0])
        last = int(curve.piece_at(np.array([stop - 1e-12]))[0])
        v = 0.0
        for k in range(last, first - 1, -1):
            vmax, amax, jmax = piece_bounds(curve.pieces[k], lim)
            a_edge = max(s0, float(curve.starts[k]))
            b_edge = min(stop, float(curve.starts[k + 1]))
            v = max_speed(v, max(b_edge - a_edge, 0.0), amax, jmax, max(vmax, v0))
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
        merge_within: float | None = None,
        caps_of: Callable[[Curve], SpeedCaps | None] | None = None,
    ) -> Trajectory:
        """Continue `traj` from its state at time t0 onto new_path (whose first waypoint is that state's position).

        The result starts exactly in that state (position, velocity, acceleration): it may first follow the old
        curve a little (a lead-in, to slow down before turning), then a quintic transition merges tangentially
        into the new path. Progress along the new path never decreases. The candidates (lead-in x merge point)
        are tried in a fixed order, cheap tests first, at most len(SPLICE_LEADS) x len(SPLICE_MERGES) of them: the
        result depends on the inputs alone, never on the machine's speed. Raises TrajectoryError if none fits
        (e.g. the new path turns back against the motion): brake and plan from rest instead. `merge_within` [rad
        of arc along new_path]: merge no farther (a swerve must not skip its own detour). `caps_of`: as `time`'s (an
        arm faster than the first cap slows down to it as fast as the limits allow).
        """
        s0, v0, a0, _ = (float(x[0]) for x in traj.law.eval(np.array([t0])))
        q0 = traj.curve.eval(np.array([s0]))[0]
        W = self._check_path(new_path)
        if np.linalg.norm(W[0] - q0) > 1e-6:
            raise InvalidInputError("the new path must start at the trajectory's position at t0")
        lim = self.limits(velocity_scale, acceleration_scale)
        if v0 < 1e-9 and abs(a0) < 1e-9:
            return self.time(W, velocity_scale, acceleration_scale, report, caps_of)
        report = report if report is not None else TimingReport()
        old_end = float(traj.law.eval(np.array([traj.duration]))[0][0])
        total = float(np.sum(np.linalg.norm(np.diff(W, axis=0), axis=1)))
        heading = traj.curve.eval(np.array([s0]), 1)[0]
        first = W[1] - W[0]
        if heading @ first < -1e-3 * np.linalg.norm(heading) * np.linalg.norm(first):
            # every transition starts along the motion: its first step would already go backwards on the new path
            raise TrajectoryError(
                "cannot splice the new path onto the motion: it starts against the motion; brake and plan from rest"
            )
        last_err = "no transition fits"
        shape_basis = basis(np.linspace(0.0, 1.0, 12 * SPLICE_PARTS), 0)
        # the merge points do not depend on the lead-in
        reach = 0.9 * total if merge_within is None else min(0.9 * total, merge_within)
        B, ks = points_along(W, np.minimum(SPLICE_MERGES, reach))
        seg = W[ks + 1] - W[ks]
        d_b = seg / np.linalg.norm(seg, axis=1, keepdims=True)
        for lead in SPLICE_LEADS:
            if lead > 0 and s0 + lead > old_end - 1e-6:
                break
            head = clip_curve(traj.curve, s0, s0 + lead) if lead > 0 else []
            p1, t1, k1 = (traj.curve.eval(np.array([s0 + lead]), order)[0] for order in (0, 1, 2))
            if np.linalg.norm(t1) < 1e-9:
                continue
            # every merge point of this lead-in at once: transitions, their bounds and their shapes
            ell = np.linalg.norm(B - p1, axis=1)
            scale = np.linalg.norm(t1)  # |dq/ds| is 1 on lines, near 1 on blends: keep q' continuous as is
            e = ell[:, None]
            C = quintic_coefficients(p1, e * t1, e**2 * k1, B, e * scale * d_b, np.zeros_like(B))
            M = quintic_bounds(C, np.maximum(ell, 1e-6), np.linspace(0.0, 1.0, SPLICE_PARTS + 1))
            bounds = speed_bounds(M.reshape(-1, *M.shape[2:]), lim, strict=False).reshape(len(C), SPLICE_PARTS, 3)
            lengths = np.repeat(ell[:, None] / SPLICE_PARTS, SPLICE_PARTS, axis=1)
            if head:
                hb = np.broadcast_to(bounds_of(head, lim), (len(C), len(head), 3))
                bounds = np.concatenate([hb, bounds], axis=1)
                lengths = np.concatenate([np.broadcast_to([h.length for h in head], (len(C), len(head))), lengths], 1)
            entry = bounds[:, 0, 0]
            reachable = slowest_entry(bounds, lengths)
            head_pts = traj.curve.eval(np.linspace(s0, s0 + lead, 12 * len(head))) if head else np.zeros((0, len(q0)))
            curves = shape_basis @ C  # (merges, samples, dof)
            shapes = [np.vstack([head_pts, c]) for c in curves]
            P = np.vstack(shapes)
            back = np.diff(progress_along(P, W).reshape(len(C), -1), axis=1).min(axis=1) < -1e-6
            for i in range(len(C)):
                if ell[i] < 1e-6 or (i and np.array_equal(B[i], B[i - 1])):
                    continue  # a merge point already tried (the new path is shorter than the merge distances)
                report.splice_candidates += 1
                if entry[i] < v0 - 1e-9:
                    last_err = f"turning onto the new path at {v0:.2f} rad/s needs a longer lead-in"
                    continue
                if back[i]:  # the time law never goes back along s: the shape alone decides
                    last_err = "the transition would move backwards along the new path"
                    continue
                if reachable[i] < v0:
                    last_err = f"the arm cannot slow down from {v0:.2f} rad/s along this transition"
                    continue
                lead_in = head + QuinticPiece.split(C[i], float(ell[i]), SPLICE_PARTS, M[i])
                rest = np.vstack([B[i], W[ks[i] + 1 :]])
                draft = blended_curve(rest, self.tube_radius, None, lead_in)
                if entry_speed(draft, lim, len(lead_in) + 4) < v0 - 1e-9:
                    last_err = f"the arm cannot slow down from {v0:.2f} rad/s along this transition"
                    continue
                if self.checker is not None and not self.checker.path_valid(shapes[i]):
                    last_err = "the transition onto the new path collides"
                    continue
                try:
                    curve, _ = self._safe_curve(rest, report, head=lead_in, first=draft)
                    caps = None if caps_of is None else caps_of(curve)
                    keep = None if caps is None else lim  # above the first cap: slow down within the limits
                    law = time_law(curve, lim, 0.0, v0, a0, curve.length, keep=keep, caps=caps)
                except TrajectoryError as err:
                    last_err = str(err)
                    continue
                new = Trajectory(curve, law, lim, self.robot.joint_names, caps=caps)
                Q = new.evaluate(np.linspace(0, new.duration, 300), order=0)[0]
                if np.any(np.diff(progress_along(Q, W)) < -1e-6):
                    last_err = "the transition would move backwards along the new path"
                    continue
                return new
        raise TrajectoryError(f"cannot splice the new path onto the motion: {last_err}; brake and plan from rest")
