"""Speed and separation monitoring after ISO/TS 15066: how fast the arm may move near what the cameras see.

    S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r

Every occupied voxel of the map is treated as possibly a person (known objects are not in the map: perception
removes them). S is the separation between the arm (its collision bodies and what it carries) and the nearest
voxel. T_r is the measured reaction latency at a high percentile: a busy machine makes it grow, and the arm slows.
docs/safety.md gives each term's source and value.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..collision.exact import CollisionChecker
from ..model.geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from ..sections import SpeedSeparationConfig
from ..trajectory import TrajectoryGenerator
from ..trajectory.timelaw import bounds_of, min_distance
from .checks import Check, MotionView, Verdict


@dataclass(frozen=True)
class SeparationTerms:
    """The terms of S_p [m, s, m/s]; `tau` [s]: the jerk ramp every stop takes whatever the speed."""

    v_h: float
    T_r: float
    T_s: float
    v_r: float
    S_s: float
    C: float
    Z_d: float
    Z_r: float
    tau: float = 0.0

    @property
    def S_p(self) -> float:
        return protective_separation(self.v_h, self.T_r, self.T_s, self.v_r, self.S_s, self.C, self.Z_d, self.Z_r)

    def at_scale(self, k: float) -> float:
        """S_p with the arm's speed scaled by k >= 0: stopping time shrinks in proportion (down to `tau`), stopping
        distance at least in proportion (k <= 1) or with the square (k > 1), the speed toward the person with k."""
        t_s = self.tau + k * max(self.T_s - self.tau, 0.0)
        s_s = self.S_s * (k if k <= 1.0 else k * k)
        return protective_separation(self.v_h, self.T_r, t_s, k * self.v_r, s_s, self.C, self.Z_d, self.Z_r)


def protective_separation(v_h, T_r, T_s, v_r, S_s, C, Z_d, Z_r) -> float:
    """ISO/TS 15066's protective separation distance S_p [m] (inputs in m, s, m/s)."""
    return v_h * (T_r + T_s) + v_r * T_r + S_s + C + Z_d + Z_r


def safe_speed_scale(S: float, terms: SeparationTerms) -> float:
    """The largest k >= 0 with terms.at_scale(k) <= S; -1 if not even at rest (S < S_p at k = 0: brake)."""
    base = terms.at_scale(0.0)
    if S < base:
        return -1.0
    slope = terms.v_h * max(terms.T_s - terms.tau, 0.0) + terms.v_r * terms.T_r + terms.S_s  # dS_p/dk for k <= 1
    if slope <= 1e-12:
        return math.inf
    k = (S - base) / slope
    if k <= 1.0:
        return k
    # k > 1: S_s grows with k^2: solve S_s k^2 + (slope - S_s) k + base - S = 0
    a, b, c = terms.S_s, slope - terms.S_s, base - S
    if a <= 1e-12:
        return -c / b
    return (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)


def intrusion_distance(resolution: float) -> float:
    """C [m] for a detection capability of one voxel, after ISO 13855: 8 (d - 14 mm), at least 0."""
    return max(0.0, 8.0 * (resolution * 1e3 - 14.0)) * 1e-3


def _mesh(shape: Shape) -> trimesh.Trimesh:
    if isinstance(shape, ConvexHull | Mesh):
        return trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    if isinstance(shape, Box):
        return trimesh.creation.box(extents=shape.size)
    if isinstance(shape, Cylinder):
        return trimesh.creation.cylinder(radius=shape.radius, height=shape.length, sections=24)
    if isinstance(shape, Sphere):
        return trimesh.creation.icosphere(subdivisions=2, radius=shape.radius)
    raise TypeError(f"no surface for {type(shape).__name__}")


def surface_points(shape: Shape, spacing: float) -> tuple[np.ndarray, float]:
    """Points (n, 3) on the shape's surface about `spacing` [m] apart, and how far [m] any surface point may be
    from the nearest of them (measured on much denser samples, plus a twentieth of the spacing for what they miss)."""
    mesh = _mesh(shape)
    dense, _ = trimesh.sample.sample_surface(mesh, max(64, int(math.ceil(40.0 * mesh.area / spacing**2))), seed=0)
    dense = np.vstack([mesh.vertices, dense])
    # one point per `spacing` cell of a grid: evenly spread, corners first (a surface is farthest from samples there)
    _, first = np.unique(np.floor(dense / spacing).astype(np.int64), axis=0, return_index=True)
    pts = dense[np.sort(first)]
    check, _ = trimesh.sample.sample_surface(mesh, 4 * len(dense), seed=1)
    gap = float(cKDTree(pts).query(check)[0].max())
    return pts, gap + 0.05 * spacing  # what the check samples miss lies between them: a little more


class SpeedSeparationCheck(Check):
    """How fast the arm may move now: a verdict whose `speed_factor` is the share of its nominal speed that keeps
    S >= S_p; not clear (brake) when even the arm at rest would be too close (S < S_p at zero speed).

    Args:
        checker: the bodies and the world (its occupancy map).
        generator: the limits the arm brakes with.
        cfg: the controller's `speed_separation` section.
        reaction_time: reaction_time(now) -> T_r [s] (the latency account's percentile).
        joint_state_age: joint_state_age(now) -> [s]: the arm may be that far ahead of what was measured.
    """

    name = "speed_separation"

    def __init__(
        self,
        checker: CollisionChecker,
        generator: TrajectoryGenerator,
        cfg: SpeedSeparationConfig,
        reaction_time: Callable[[float], float],
        joint_state_age: Callable[[float], float],
    ):
        self.checker, self.gen, self.cfg = checker, generator, cfg
        self.reaction_time, self.joint_state_age = reaction_time, joint_state_age
        self._samples: dict[int, tuple[Shape, np.ndarray, float]] = {}
        self.last: SeparationTerms | None = None  # the terms of the last verdict (status and tests read them)
        self.last_separation: float | None = None
        self._points(checker.robot.home[None])  # sample the bodies now: the first check must not stall

    def _points(self, Q: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """Surface points (len(Q), n, 3) of every body at configurations Q, their covering margin [m], the body
        of each point (n,), and each body's bounding ball at Q[0]: centre and radius (B, 4) [m]."""
        bp = self.checker.body_poses(Q)
        local, owner, balls, margin = [], [], [], 0.0
        for b, shape in enumerate(bp.shapes):
            hit = self._samples.get(id(shape))
            if hit is None or hit[0] is not shape:
                pts, gap = surface_points(shape, self.cfg.point_spacing)
                c = (pts.min(axis=0) + pts.max(axis=0)) / 2
                hit = (shape, pts, gap, c, float(np.linalg.norm(pts - c, axis=1).max()))
                self._samples[id(shape)] = hit
            local.append(hit[1])
            owner.append(np.full(len(hit[1]), b))
            T0 = bp.poses[0, b]
            balls.append(np.append(T0[:3, :3] @ hit[3] + T0[:3, 3], hit[4]))
            margin = max(margin, hit[2])
        L, idx = np.vstack(local), np.concatenate(owner)
        T = bp.poses[:, idx]  # (N, n, 4, 4)
        return np.einsum("nkij,kj->nki", T[..., :3, :3], L) + T[..., :3, 3], margin, idx, np.array(balls)

    def __call__(self, view: MotionView, fresh: bool = False) -> Verdict:
        occ = self.checker.world.snapshot().occupancy
        if not self.cfg.enabled or occ is None or not len(occ):
            return Verdict(self.name, True, speed_factor=1.0)
        start, traj = view.segment
        t = view.now - start
        T_r = self.reaction_time(view.now)
        # the fastest the arm will go before a reaction can take hold: over [t, t + T_r] of its trajectory
        ts = np.linspace(t, min(t + T_r, traj.duration), 4)
        s, v, a, _ = traj.law.eval(ts)
        k = int(np.argmax(v))
        qd = traj.evaluate(ts[k : k + 1], order=1)[1][0]
        eps = 1e-3
        P, margin, owner, balls = self._points(np.stack([view.q, view.q + eps * qd]))
        half = occ.resolution * math.sqrt(3) / 2
        bound = self.cfg.range + half + margin
        # only bodies whose ball may hold a point within 5 cm of the nearest are searched point by point
        dc, _ = occ.kdtree.query(balls[:, :3], distance_upper_bound=bound + balls[:, 3].max())
        low, high = dc - balls[:, 3], dc + balls[:, 3]
        pick = np.flatnonzero(low <= min(float(high.min()), bound) + 0.05)
        sel = np.flatnonzero(np.isin(owner, pick))
        vel = (P[1] - P[0]) / eps
        points = P[0, sel]
        d, i = occ.kdtree.query(points, distance_upper_bound=bound)
        near = np.isfinite(d)
        if not near.any():
            self.last, self.last_separation = None, None
            return Verdict(self.name, True, speed_factor=1.0)
        S = float(d[near].min()) - half - margin
        # the speed toward the obstacle of the points about as close as the closest
        close = near & (d <= d[near].min() + 0.05)
        toward = occ.centers[i[close]] - points[close]
        toward /= np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-9)
        v_r = max(0.0, float(np.max(np.sum(vel[sel[close]] * toward, axis=1))))
        T_s, S_s, tau = self._stopping(traj, s[k], v[k], a[k], vel)
        speed = float(np.linalg.norm(vel, axis=1).max())
        terms = SeparationTerms(
            self.cfg.approach_speed,
            T_r,
            T_s,
            v_r,
            S_s,
            intrusion_distance(occ.resolution) if self.cfg.intrusion_distance is None else self.cfg.intrusion_distance,
            self.cfg.sensor_uncertainty,
            self.cfg.robot_uncertainty + speed * self.joint_state_age(view.now),
            tau,
        )
        self.last, self.last_separation = terms, S
        scale = safe_speed_scale(S, terms)
        now_factor = float(np.min(traj.limits.velocity / traj.nominal.velocity))
        at_rest = float(v.max()) < 1e-6  # held, or the motion's end: moving on needs room to spare
        if scale < 0 or (at_rest and S < terms.at_scale(0.0) + self.cfg.resume_margin):
            # at rest the arm moves on only with the resume margin to spare: say so, or the numbers contradict
            extra = f" + {self.cfg.resume_margin:.3f} m to move on from rest" if at_rest and scale >= 0 else ""
            reason = (
                f"speed and separation: {S:.3f} m to what the cameras see, less than the {terms.at_scale(0):.3f} m "
                f"a reaction takes at rest{extra} (T_r {T_r * 1e3:.0f} ms)"
            )
            return Verdict(self.name, False, reason, clearance=S, speed_factor=0.0)
        factor = min(1.0, now_factor * scale) if math.isfinite(scale) else 1.0
        return Verdict(self.name, True, clearance=S, speed_factor=factor)

    def _stopping(self, traj, s: float, v: float, a: float, vel: np.ndarray) -> tuple[float, float, float]:
        """T_s [s], S_s [m] of a jerk-limited stop from path speed v, acceleration a (at least what the limits of
        the pieces ahead allow), and the jerk ramp tau [s]; S_s is the farthest any surface point may travel."""
        curve = traj.curve
        k0 = int(curve.piece_at(np.array([s]))[0])
        b = bounds_of(curve.pieces[k0 : k0 + 6], traj.limits)
        A, J = float(b[:, 1].min()), float(b[:, 2].min())
        t1 = max(a, 0.0) / J  # a positive acceleration must ramp down first: the speed still grows a little
        v_eff = v + max(a, 0.0) ** 2 / (2 * J)
        T_s = t1 + (v_eff / A + A / J if v_eff >= A * A / J else 2.0 * math.sqrt(max(v_eff, 0.0) / J))
        arc = v * t1 + min_distance(v_eff, 0.0, A, J)
        # Cartesian speed per unit path speed, the largest of any point: stopping distance in metres
        ratio = float(np.linalg.norm(vel, axis=1).max()) / v if v > 1e-6 else 0.0
        return T_s, ratio * arc * 1.1, A / J
