"""The reflex in the loop: a swerve off the path, away from what the map holds near the arm.

Which way: the virtual joint torques of the GPU potential-field paper (Kinect point clouds on a KUKA LWR): per-link
forces and moments from the voxels within r_max of the arm's vertices, tau = sum_n J_n^T [f_n; m_n], through an
admittance; or the kernel velocities of Baumgartner and Klančar ("Utilizing Convolution for Obstacle Avoidance during
Robotic Manipulator Movement") at one point of interest per link, q' = sum_p J_p+ x'_p; either projected into the
nullspace of the task. Our arms take position commands: the admittance M q'' + D q' = tau, run from rest for
`horizon` T, gives the offset dq = tau / D (T - M / D (1 - exp(-D T / M))).

How: a detour polyline, the path ahead shifted by dq (reached after `ramp` of arc, held for `hold`, back on the
path after another `ramp`), spliced onto the running motion by the trajectory generator, so it starts in the
arm's exact state, is jerk-limited and within the limits. The detour's segments must be valid for the collision
checker (objects and map, padded): a swerve into anything is never sent; a smaller offset is tried instead.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..model.robot import RobotModel
from ..sections import ReflexConfig
from ..trajectory import Trajectory, progress_along
from ..world.occupancy import unique_keys, voxel_centers, voxel_keys
from .forces import ForceField, VertexModel
from .kernels import AvoidanceKernels, KernelSpec, OccupancyGrid


class Reflex:
    """The joint offset a reflex takes at q, and the detours that take it.

    Args:
        robot: the arm's model (its collision surfaces give the vertices).
        cfg: the controller's `reflex` section.
        seed: the vertex sampling's seed (the model is the same on every run).
    """

    def __init__(self, robot: RobotModel, cfg: ReflexConfig, seed: int = 0):
        self.robot, self.cfg = robot, cfg
        count = cfg.vertices if cfg.method == "forces" else 40 * len(robot.bodies)
        self.model = VertexModel.from_robot(robot, count, seed)
        self.field = ForceField(cfg.r_max, cfg.f_max)
        # Baumgartner and Klančar's points of interest: each link's vertices' centre, in the vertices' frame
        self._poi = [self.model.local[self.model.link == i].mean(axis=0) for i in range(len(self.model.links))]
        self._kernels: AvoidanceKernels | None = None
        self.last_push: np.ndarray | None = None  # the last offset before its cap [rad]
        self.last_detour: np.ndarray | None = None
        # compile (or load from the cache) the method's kernel now: a first compile takes seconds, blind mid-motion
        self.pushes(robot.home[None], np.eye(robot.dof)[:1], self.model.place(robot, robot.home)[:1] + 0.05, 0.01)

    # ------------------------------------------------------------------ which way
    def _kinematics(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At configurations Q (K, dof): the vertices (K, V, 3), each link's origin (K, L, 3) [m] and geometric
        Jacobian (K, L, 6, dof)."""
        F = self.robot.frames(Q)[:, self.model.slot]  # (K, V, 4, 4)
        V = np.einsum("kvij,vj->kvi", F[..., :3, :3], self.model.local) + F[..., :3, 3]
        origins, Js = self.robot.origins_and_jacobians(Q, self.model.links)
        return V, origins, Js

    def _reach(self, resolution: float) -> float:
        """How far from the arm a voxel still pushes [m]: r_max, or a kernel's half length."""
        return self.cfg.r_max if self.cfg.method == "forces" else (self.cfg.kernel_length / 2 + 1) * resolution

    def pushes(self, Q, tangents, voxels: np.ndarray, resolution: float) -> np.ndarray:
        """The joint offsets (K, dof) [rad] the reflex asks for at configurations Q (K, dof), in the nullspace of the
        task there (`tangents` (K, dof): the path's direction). forces: the admittance's after `horizon`; kernels,
        their joint velocities times `horizon`. All K at once (one compiled call for the forces)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        c, (K, n) = self.cfg, Q.shape
        V, origins, Js = self._kinematics(Q)
        L = origins.shape[1]
        reach = self._reach(resolution)
        lo, hi = V.reshape(-1, 3).min(axis=0) - reach, V.reshape(-1, 3).max(axis=0) + reach
        near = voxels[np.all((voxels >= lo) & (voxels <= hi), axis=1)] if len(voxels) else voxels
        if not len(near):
            return np.zeros((K, n))
        if c.method == "forces":
            if c.voxel > resolution:  # a direction needs no fine map: merged voxels, far fewer pairs
                near = voxel_centers(unique_keys(voxel_keys(near, c.voxel)), c.voxel)
            link = (np.arange(K)[:, None] * L + self.model.link[None]).ravel()
            W = self.field.compute(V.reshape(-1, 3), link, origins.reshape(-1, 3), near).reshape(K, L, 6)
            tau = np.einsum("klsd,kls->kd", Js, W)  # sum_n J_n^T [f_n; m_n]
            T, M, D = c.horizon, c.mass, c.damping  # M q'' + D q' = tau, from rest, per joint
            dq = tau / D * (T - M / D * (1.0 - np.exp(-D * T / M)))
        else:
            kern = self._kernels
            if kern is None or kern.res != resolution:
                spec = KernelSpec(c.kernel_length, c.kernel_width, c.kernel_decay, c.kernel_gain)
                kern = self._kernels = AvoidanceKernels(spec, resolution)
            # points of interest: the centre of each link's vertices
            P = np.stack([V[:, self.model.link == i].mean(axis=1) for i in range(L)], axis=1)  # (K, L, 3)
            flat = P.reshape(-1, 3)
            # the grid spans only the occupied voxels within reach: outside it every sample reads 0 anyway
            g_lo = (
                np.floor(np.maximum(flat.min(axis=0) - reach, near.min(axis=0)) / resolution) * resolution
            )  # cells = map voxels
            g_hi = np.minimum(flat.max(axis=0) + reach, near.max(axis=0) + resolution)
            grid = OccupancyGrid(g_lo, np.maximum(g_hi - g_lo, resolution), resolution).fill(near)
            xd = kern.velocities(grid, flat).reshape(K, L, 3)
            r = P - origins
            Jp = Js[..., :3, :] - np.cross(r[..., None, :], np.swapaxes(Js[..., 3:, :], -1, -2)).swapaxes(-1, -2)
            JtJ = np.swapaxes(Jp, -1, -2) @ Jp + 1e-3 * np.eye(n)
            dq = c.horizon * np.linalg.solve(JtJ, np.swapaxes(Jp, -1, -2) @ xd[..., None])[..., 0].sum(axis=1)
        return np.einsum("kij,kj->ki", self._nullspaces(Q, np.atleast_2d(tangents)), dq)

    def _nullspaces(self, Q: np.ndarray, tangents: np.ndarray) -> np.ndarray:
        """The task's nullspace projectors (K, dof, dof): across the path's tangent, or the hand's position held."""
        n = Q.shape[1]
        if self.cfg.task == "position":
            J = self.robot.jacobian(Q)[:, :3]
            return np.eye(n) - np.linalg.solve(np.swapaxes(J, 1, 2) @ J + 1e-3 * np.eye(n), np.swapaxes(J, 1, 2)) @ J
        t = tangents / np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-12)
        return np.eye(n) - t[:, :, None] * t[:, None, :]

    def _capped(self, dq: np.ndarray) -> np.ndarray | None:
        self.last_push = dq
        big = float(np.abs(dq).max())
        if big < self.cfg.min_offset:
            return None
        return dq * min(1.0, self.cfg.max_offset / big)

    def offset(self, q, tangent, voxels: np.ndarray, resolution: float) -> np.ndarray | None:
        """The swerve's joint offset (dof,) [rad] at q (at most `max_offset` per joint), or None when it would be
        smaller than `min_offset`."""
        return self._capped(self.pushes(np.asarray(q)[None], np.asarray(tangent)[None], voxels, resolution)[0])

    def offset_ahead(self, traj: Trajectory, t: float, voxels: np.ndarray, resolution: float) -> np.ndarray | None:
        """The offset for a detour from time t of `traj`: the mean of the pushes at 4 points from t to the end of its
        longest hold. A detour shifts that stretch as a whole: the mean push is the gradient of the potential summed
        over the stretch (forces: sum_k tau(q_k)), not of one point's, so the detour clears what lies ahead too."""
        c, curve = self.cfg, traj.curve
        s0 = traj.s_at(t)
        s = np.linspace(s0, min(s0 + c.ramp + 4 * c.hold, curve.length), 4)
        return self._capped(self.pushes(curve.eval(s), curve.eval(s, 1), voxels, resolution).mean(axis=0))

    # ------------------------------------------------------------------ the detours
    def detours(self, traj: Trajectory, t: float, dq: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Detour polylines from the state at time t of `traj`: the path ahead shifted by dq (then dq / 2, ...:
        `tries` sizes), reached after `ramp` [rad of arc], held for `hold` (then 2 and 4 times as long: past what
        blocks), back on the path after another `ramp`, then the rest of it. With each, its own segments (from the
        state at t to where it is back on the path): what the swerve adds to the motion, which must be collision-free
        to be sent (what follows is the path the monitor already watches)."""
        c, curve = self.cfg, traj.curve
        s0, end = traj.s_at(t), curve.length
        if s0 + c.ramp >= end - 1e-6:
            return  # too close to the end of the motion: the brake's case, not a swerve's
        q0 = curve.eval(np.array([s0]))[0]
        P = curve.polyline
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
        lim = self.robot.limits
        lo, hi = lim.lower + 1e-3, lim.upper - 1e-3
        for k in range(c.tries):
            d = dq / (2**k)
            if float(np.abs(d).max()) < c.min_offset:
                return
            for hold in (c.hold, 2 * c.hold, 4 * c.hold) if c.hold > 0 else (0.0,):
                s1, s3 = s0 + c.ramp, min(s0 + 2 * c.ramp + hold, end)
                s2 = min(s0 + c.ramp + hold, s3)
                A, B, back = curve.eval(np.array([s1, s2, s3]))
                rest = P[cum > float(progress_along(back[None], P)[0]) + 1e-6] if s3 < end - 1e-6 else P[:0]
                mid = [np.clip(A + d, lo, hi)] + ([np.clip(B + d, lo, hi)] if s2 > s1 + 1e-6 else [])
                W = np.vstack([q0[None], *[m[None] for m in mid], back[None], rest])
                self.last_detour = d  # the offset of the detour yielded last (the one sent, if any)
                yield W, W[: len(mid) + 2]
                if s3 >= end - 1e-6:
                    break  # a longer hold would end at the same place
