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

from ..collision.checker import OCTREE
from ..collision.exact import CollisionChecker
from ..model.geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere
from ..sections import SpeedSeparationConfig
from ..trajectory import TrajectoryGenerator
from ..trajectory.timelaw import SpeedCaps, bounds_of, min_distance
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


def watched(checker: CollisionChecker, links) -> list[int]:
    """The bodies (indices into `links`, their links) speed and separation watches: all but those allowed to touch the
    map (a base standing in the table's noisy returns: it never moves, so it never comes at anyone)."""
    return [b for b, link in enumerate(links) if (link, OCTREE) not in checker.allowed_contacts]


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
        self._surface = _Surface(checker, cfg.point_spacing)
        self.last: SeparationTerms | None = None  # the terms of the last verdict (status and tests read them)
        self.last_separation: float | None = None
        self._points(checker.robot.home[None])  # sample the bodies now: the first check must not stall

    def _points(self, Q: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """Surface points (len(Q), n, 3) of every body at configurations Q, their covering margin [m], the body
        of each point (n,), and each body's bounding ball at Q[0]: centre and radius (B, 4) [m]."""
        bp = self.checker.body_poses(Q)
        local, owner, balls, margin = [], [], [], 0.0
        bodies = watched(self.checker, bp.links)
        for k, b in enumerate(bodies):
            hit = self._surface.sample(bp.shapes[b])
            local.append(hit[1])
            owner.append(np.full(len(hit[1]), k))
            T0 = bp.poses[0, b]
            balls.append(np.append(T0[:3, :3] @ hit[3] + T0[:3, 3], hit[4]))
            margin = max(margin, hit[2])
        L, idx = np.vstack(local), np.concatenate(owner)
        T = bp.poses[:, np.asarray(bodies)[idx]]  # (N, n, 4, 4)
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


def stopping(v, A, J):
    """(T_s [s], path length [s units]) of jerk-limited stops from path speeds v at rest acceleration, with path
    acceleration and jerk bounds A, J (arrays alike); a stop takes the jerk ramp A / J at least, whatever the speed."""
    v, A, J = (np.asarray(x, float) for x in (v, A, J))
    v = np.maximum(v, 0.0)
    T_s = np.where(v >= A * A / J, v / A + A / J, 2.0 * np.sqrt(v / J))
    return np.maximum(T_s, A / J), v / 2 * T_s


COARSE = 0.04  # [m] the cells of the map far from the arm (see SeparationCaps._distance)
NEAR = 0.05  # [m] beyond S_p at rest, distances to the map are exact
SLACK = 0.1  # [m] looked beyond what limits the speed: what the samples' covering margin adds
MAX_MARGIN = 0.9  # [m] the most a search keeps from the map beyond its padding
MARGIN_STEP = 0.02  # [m] a plan's map margin is a multiple of this: few margins, each one's geometry built once


@dataclass(frozen=True)
class SeparationPlan:
    """What a plan made for speed and separation is told: the section (v_h, C, Z_d, Z_r), T_r [s], the joint states'
    age [s], and how long [s] from the map it sees until its path runs (the plan's own time and the wait to land): a
    person comes that much closer meanwhile."""

    cfg: SpeedSeparationConfig
    reaction_time: float
    joint_state_age: float
    start_after: float


class SeparationCaps:
    """How a new path keeps the protective separation S_p from every voxel of a map (every one may be a person): the
    margin [m] its search keeps from the map, and path speed caps along its curve, slower near a voxel, full speed
    away from it.

    At samples along the curve, S is the least distance from the arm's surface (every body, as the run-time check
    samples it) to the map's voxels, less the approach v_h x (start_after + T_r): how far a person comes while the
    path is made and started. A stretch between two samples gets the highest path speed v with S_p(v) <= S (S: its
    ends' least, less how far a surface point moves to its middle), every surface point's speed counted as toward
    the person, the stop at the limits of the pieces around it. A stretch where not even a stop fits is `infeasible`.

    Args:
        checker: the bodies (and what the arm carries) of the world the map belongs to.
        occupancy: the map; every voxel may be a person.
        plan: the section, T_r, the joint states' age and the time until the path runs.
        limits: the joint limits the path will be timed at.
        step: [s units] between two samples along the curve.
    """

    def __init__(self, checker: CollisionChecker, occupancy, plan: SeparationPlan, limits, step: float = 0.02):
        cfg = plan.cfg
        self.checker, self.occ, self.cfg, self.plan, self.limits, self.step = (
            checker,
            occupancy,
            cfg,
            plan,
            limits,
            step,
        )
        self.T_r = plan.reaction_time
        self.started_after(plan.start_after)
        self._coarse: cKDTree | None = None

        self._surface = _Surface(checker, cfg.point_spacing)
        c = cfg.intrusion_distance
        self.C = intrusion_distance(occupancy.resolution) if c is None else c
        self.infeasible = 0  # stretches of the last curve too close to move at all (S < S_p at rest)

    def started_after(self, delay: float) -> None:
        """The path runs `delay` [s] after the map was seen (the plan took longer than told, say)."""
        self.approach = self.cfg.approach_speed * (delay + self.T_r)

    def start_room(self, q: np.ndarray) -> tuple[float, float]:
        """(S [m] at q, the margin [m] beyond the map padding a search from q keeps): the margin is `margin()`, or
        less where q itself is closer (to a whole centimetre below S: a path never needs to come closer than its
        start); S below `at_rest()`: no path from q keeps S_p."""
        S = float(self.separation(np.asarray(q, float)[None])[0])
        return S, max(0.0, min(self.margin(), math.floor((S - self.checker.map_padding) * 100.0) / 100.0 - 0.01))

    def at_rest(self) -> float:
        """S_p [m] of an arm about to stop, plus the approach: a path closer than this to a voxel cannot run."""
        ssm = self.cfg
        return ssm.approach_speed * self.T_r + self.C + ssm.sensor_uncertainty + ssm.robot_uncertainty + self.approach

    def margin(self) -> float:
        """[m] beyond the map padding a search keeps from the map: S_p at rest and the approach, plus what the
        separation's estimate takes off (a voxel's half diagonal, the surface samples' gap) and a centimetre for the
        search's motions checked at points, rounded up to MARGIN_STEP (padded geometry is built per margin)."""
        slack = self.occ.resolution * math.sqrt(3) / 2 + self._surface.margin() + 0.01
        need = self.at_rest() + slack - self.checker.map_padding
        # at most MAX_MARGIN: a path that needs more comes closer than S_p somewhere and its timing refuses it
        return min(max(0.0, math.ceil(need / MARGIN_STEP) * MARGIN_STEP), MAX_MARGIN)

    def protective(self, v, r, A, J):
        """S_p [m] at path speeds v, the fastest surface point moving r [m] per unit of s, all of it toward the person,
        stopping at path acceleration and jerk A, J (arrays alike)."""
        ssm = self.cfg
        T_s, arc = stopping(v, A, J)
        Z_r = ssm.robot_uncertainty + r * v * self.plan.joint_state_age
        return protective_separation(
            ssm.approach_speed, self.T_r, T_s, r * v, r * arc * 1.1, self.C, ssm.sensor_uncertainty, Z_r
        )

    def _caps(self, S: np.ndarray, vmax: np.ndarray, r: np.ndarray, A: np.ndarray, J: np.ndarray) -> np.ndarray:
        """The highest path speeds (<= vmax) whose S_p fits in S; a crawl where not even a stop fits (counted)."""
        stuck = self.protective(np.zeros_like(S), r, A, J) > S
        self.infeasible = int(stuck.sum())
        lo, hi = np.zeros_like(S), vmax.copy()
        full = self.protective(vmax, r, A, J) <= S
        for _ in range(30):  # S_p grows with v
            mid = (lo + hi) / 2
            fits = self.protective(mid, r, A, J) <= S
            lo, hi = np.where(fits, mid, lo), np.where(fits, hi, mid)
        return np.where(full, vmax, np.where(stuck, 1e-3, np.maximum(lo, 1e-3)))

    @property
    def near(self) -> float:
        """[m] distances to the map are exact up to here (see _distance)."""
        return self.at_rest() + self.occ.resolution * math.sqrt(3) / 2 + self._surface.margin() + NEAR

    def _distance(self, P: np.ndarray, within: float) -> np.ndarray:
        """A lower bound of the distance [m] from points P (M, 3) to the nearest voxel centre, inf beyond `within`:
        exact up to `self.near`, beyond it that to a coarse cell's centre less the cell's half diagonal (a KD-tree's
        search grows with its radius; far from the map a few centimetres less only lowers a speed already high)."""
        d, _ = self.occ.kdtree.query(P, distance_upper_bound=min(within, self.near))
        far = np.isinf(d)
        if far.any() and within > self.near:
            if self._coarse is None:
                keys = np.unique(np.floor(self.occ.centers / COARSE).astype(np.int64), axis=0)
                self._coarse = cKDTree((keys + 0.5) * COARSE)
            h = COARSE * math.sqrt(3) / 2
            dc, _ = self._coarse.query(P[far], distance_upper_bound=within + h)
            d[far] = np.maximum(dc - h, self.near)
        return d

    def separation(self, Q: np.ndarray) -> np.ndarray:
        """S [m] at configurations Q (N, dof): the least distance from the arm's surface to the map's voxels."""
        P, margin, _ = self._surface.points(Q)
        half = self.occ.resolution * math.sqrt(3) / 2
        d, _ = self.occ.kdtree.query(P.reshape(-1, 3), distance_upper_bound=self.cfg.range + half + margin)
        return d.reshape(P.shape[:2]).min(axis=1) - half - margin

    def __call__(self, curve) -> SpeedCaps:
        n = max(2, int(math.ceil(curve.length / self.step)) + 1)
        s = np.linspace(0.0, curve.length, n)
        Q, dQ = curve.eval(s, 0), curve.eval(s, 1)
        bounds = bounds_of(curve.pieces, self.limits)
        first, last = curve.piece_at(s[:-1]), curve.piece_at(np.maximum(s[1:] - 1e-9, 0.0))
        # a stop from a stretch may run into the pieces either side of it
        lo, hi = np.maximum(first - 1, 0), np.minimum(last + 2, len(bounds))
        vmax = np.array([bounds[a : b + 1, 0].min() for a, b in zip(first, last)])
        A = np.array([bounds[a:b, 1].min() for a, b in zip(lo, hi)])
        J = np.array([bounds[a:b, 2].min() for a, b in zip(lo, hi)])
        # voxels farther than S_p at full speed (and the approach) take nothing off the speed: not looked for
        half = self.occ.resolution * math.sqrt(3) / 2

        def beyond(rate: np.ndarray) -> float:  # S_p at full speed, the approach, a stretch's middle and the slack
            r = float(rate.max()) * 1.1
            return float(np.max(self.protective(vmax, r, A, J))) + self.approach + r * self.step + half + SLACK

        d, rate, margin = self._surface.clearance(Q, dQ, self._distance, self.near, beyond)
        r = np.maximum(rate[:-1], rate[1:]) * 1.1
        S = d - half - margin - self.approach
        # a stretch's least clearance: its ends' less how far a surface point moves to its middle (with slack)
        S = np.minimum(S[:-1], S[1:]) - 0.5 * r * np.diff(s)
        caps = np.where(np.isfinite(S), self._caps(np.where(np.isfinite(S), S, 1e9), vmax, r, A, J), vmax)
        return SpeedCaps(s, caps)


class _Surface:
    """Points on every watched body's surface (and what the arm carries) about `spacing` apart, and each body's
    bounding ball, posed at configurations."""

    def __init__(self, checker: CollisionChecker, spacing: float):
        self.checker, self.spacing = checker, spacing
        self._samples: dict[int, tuple] = {}

    def sample(self, shape: Shape) -> tuple:
        """(shape, points (n, 3), gap [m], ball centre (3,), ball radius [m]) in the body's frame, made once."""
        hit = self._samples.get(id(shape))
        if hit is None or hit[0] is not shape:
            pts, gap = surface_points(shape, self.spacing)
            c = (pts.min(axis=0) + pts.max(axis=0)) / 2
            hit = self._samples[id(shape)] = (shape, pts, gap, c, float(np.linalg.norm(pts - c, axis=1).max()) + gap)
        return hit

    def margin(self) -> float:
        """[m] how far any surface point may be from the nearest sample (every body's, at its own spacing)."""
        bp = self.checker.body_poses(self.checker.robot.home)
        return max(self.sample(bp.shapes[b])[2] for b in watched(self.checker, bp.links))

    def points(self, Q: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """Surface points (N, n, 3) at configurations Q (N, dof), their covering margin [m], each point's body (n,)."""
        bp = self.checker.body_poses(Q)
        bodies = watched(self.checker, bp.links)
        hits = [self.sample(bp.shapes[b]) for b in bodies]
        L = np.vstack([h[1] for h in hits])
        idx = np.concatenate([np.full(len(h[1]), b) for b, h in zip(bodies, hits)])
        T = bp.poses[:, idx]
        return np.einsum("nkij,kj->nki", T[..., :3, :3], L) + T[..., :3, 3], max(h[2] for h in hits), idx

    def clearance(
        self, Q: np.ndarray, dQ: np.ndarray, distance, exact: float, beyond
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """At configurations Q (N, dof) moving along dQ: the least distance(points (M, 3), within) [m] from the surface
        samples (a lower bound, exact up to `exact` [m]; inf where none is within beyond(rate) [m]: only bodies whose
        ball may come closer than that, and than the nearest body's farthest point, are sampled),
        the fastest any surface point moves per unit of the motion, `rate` (N,) (a rigid body's fastest point is at
        most its ball's radius times its turn rate from the centre's speed), and the samples' covering margin [m]."""
        eps = 1e-4
        n = len(Q)
        bp = self.checker.body_poses(np.concatenate([Q, Q + eps * dQ]))
        bodies = watched(self.checker, bp.links)
        hits = [self.sample(bp.shapes[b]) for b in bodies]
        T0, T1 = bp.poses[:n, bodies], bp.poses[n:, bodies]
        local_c = np.array([h[3] for h in hits])
        R = np.array([h[4] for h in hits])
        C0 = np.einsum("nbij,bj->nbi", T0[..., :3, :3], local_c) + T0[..., :3, 3]
        C1 = np.einsum("nbij,bj->nbi", T1[..., :3, :3], local_c) + T1[..., :3, 3]
        dR = np.einsum("nbij,nbkj->nbik", T1[..., :3, :3], T0[..., :3, :3])  # R1 R0^T: the turn over eps
        turn = np.arccos(np.clip((np.trace(dR, axis1=2, axis2=3) - 1.0) / 2.0, -1.0, 1.0))
        rate = ((np.linalg.norm(C1 - C0, axis=2) + turn * R) / eps).max(axis=1)
        beyond = float(beyond(rate))
        # bodies whose ball may come within `beyond`: their samples are looked at, the others are too far to count
        dc = distance(C0.reshape(-1, 3), beyond + R.max()).reshape(n, -1)
        # a body counts where its ball may come closer than every body's farthest point: the nearest body's
        nearest = np.minimum(np.where(dc <= exact, dc + R, np.inf).min(axis=1), beyond)
        near = (dc - R) <= nearest[:, None]
        d = np.full(n, np.inf)
        for b in np.flatnonzero(near.any(axis=0)):
            rows = np.flatnonzero(near[:, b])
            T = T0[rows, b]
            P = np.einsum("nij,kj->nki", T[:, :3, :3], hits[b][1]) + T[:, None, :3, 3]
            db = distance(P.reshape(-1, 3), beyond)
            d[rows] = np.minimum(d[rows], db.reshape(len(rows), -1).min(axis=1))
        return d, rate, max(h[2] for h in hits)
