"""Baumgartner and Klančar's directional convolution kernels on a voxel grid: avoidance velocities at points of
interest on the arm, mapped to joint velocities in the nullspace of the end-effector's task (its equations 1-6).

A kernel for axis d samples the grid at L points along d and W x W across it around the point of interest. Along
d its values are antisymmetric, largest next to the point (no zero at its middle: the point lies between the two
middle samples, half a voxel to each side) and decaying outwards (linear or Gaussian); across d they fall off
with the distance from the axis and keep the sign. An occupied voxel ahead (+d) gives a negative velocity: away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ..model.robot import RobotModel


@dataclass(frozen=True)
class KernelSpec:
    """length: samples along the axis (even: the point lies between the middle two); width: samples across (odd);
    decay: "linear" or "gaussian"; gain: [m/s] per unit of kernel sum."""

    length: int = 30
    width: int = 7
    decay: str = "gaussian"
    gain: float = 0.05

    def __post_init__(self):
        if self.length < 2 or self.length % 2 or self.width < 1 or self.width % 2 == 0:
            raise ValueError("kernel length must be even and >= 2, width odd and >= 1")
        if self.decay not in ("linear", "gaussian"):
            raise ValueError(f"decay must be 'linear' or 'gaussian', got {self.decay!r}")


def _profile(n: int, decay: str, along: bool) -> np.ndarray:
    """Magnitudes at the sample offsets (half-integers along the axis, integers across)."""
    if along:
        s = np.arange(n) + 0.5 - n / 2  # ..., -1.5, -0.5, 0.5, 1.5, ...
        h = n / 2
    else:
        s = np.arange(n) - (n - 1) / 2
        h = (n - 1) / 2 + 1
    if decay == "linear":
        return 1.0 - np.abs(s) / (h + 0.5)
    sigma = max(h / 2, 0.5)
    return np.exp(-(s**2) / (2 * sigma**2))


class AvoidanceKernels:
    """The three directional kernels of `spec` on a grid of voxel size `res` [m]: sample offsets (S, 3) [m] and
    values (3, S), one row per axis (x, y, z)."""

    def __init__(self, spec: KernelSpec, res: float):
        self.spec, self.res = spec, float(res)
        L, W = spec.length, spec.width
        along = (np.arange(L) + 0.5 - L / 2) * res
        across = (np.arange(W) - (W - 1) / 2) * res
        sign = np.sign(along)
        mag_a, mag_c = _profile(L, spec.decay, True), _profile(W, spec.decay, False)
        offsets, values = [], []
        for d in range(3):
            o1, o2 = [a for a in range(3) if a != d]
            A, B, C = np.meshgrid(np.arange(L), np.arange(W), np.arange(W), indexing="ij")
            off = np.zeros((L * W * W, 3))
            off[:, d], off[:, o1], off[:, o2] = along[A.ravel()], across[B.ravel()], across[C.ravel()]
            # obstacle ahead (+d): push back (-d); across the axis the weight falls off with the radius
            radial = np.hypot(across[B.ravel()], across[C.ravel()]) / res
            fall = np.interp(radial, np.abs(across / res)[(W - 1) // 2 :], mag_c[(W - 1) // 2 :])
            offsets.append(off)
            values.append(-sign[A.ravel()] * mag_a[A.ravel()] * fall)
        self.offsets = np.stack(offsets)  # (3, S, 3)
        self.values = np.stack(values)  # (3, S)

    def velocities(self, grid: OccupancyGrid, points: np.ndarray) -> np.ndarray:
        """Avoidance velocities (P, 3) [m/s] at points (P, 3) [m]: per axis, the sum of the kernel times the grid."""
        P = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty((len(P), 3))
        _kernel_sums(grid.a, grid.lo, grid.res, P, self.offsets, self.values.astype(np.float64), out)
        return self.spec.gain * out


@numba.njit(cache=True)
def _kernel_sums(a, lo, res, P, offsets, values, out):
    # OccupancyGrid.sample at every point + offset, times the kernel: no (P, S, 3) temporaries
    nx, ny, nz = a.shape
    for i in range(P.shape[0]):
        for d in range(3):
            acc = 0.0
            for j in range(offsets.shape[1]):
                kx = int(np.floor((P[i, 0] + offsets[d, j, 0] - lo[0]) / res))
                ky = int(np.floor((P[i, 1] + offsets[d, j, 1] - lo[1]) / res))
                kz = int(np.floor((P[i, 2] + offsets[d, j, 2] - lo[2]) / res))
                if 0 <= kx < nx and 0 <= ky < ny and 0 <= kz < nz and a[kx, ky, kz] != 0.0:
                    acc += a[kx, ky, kz] * values[d, j]
            out[i, d] = acc


class OccupancyGrid:
    """A dense boolean grid over the bounds (lo, lo + extent) at `res` [m], from voxel centres or points."""

    def __init__(self, lo, extent, res: float):
        self.lo, self.res = np.asarray(lo, dtype=float), float(res)
        self.n = np.ceil(np.asarray(extent, dtype=float) / self.res).astype(np.int64)
        self.a = np.zeros(tuple(self.n), dtype=np.float32)

    def fill(self, points: np.ndarray) -> OccupancyGrid:
        self.a[:] = 0
        k = np.floor((np.asarray(points, dtype=float) - self.lo) / self.res).astype(np.int64)
        k = k[np.all((k >= 0) & (k < self.n), axis=1)]
        self.a[k[:, 0], k[:, 1], k[:, 2]] = 1.0
        return self

    def sample(self, pts: np.ndarray) -> np.ndarray:
        """Occupancy (...,) at points (..., 3): 0 outside the bounds."""
        k = np.floor((pts - self.lo) / self.res).astype(np.int64)
        inside = np.all((k >= 0) & (k < self.n), axis=-1)
        k = np.where(inside[..., None], k, 0)
        return np.where(inside, self.a[k[..., 0], k[..., 1], k[..., 2]], 0.0)


@dataclass(frozen=True)
class NullspaceReflex:
    """Equation 3: q' = J+ x'_ee + N sum_poi J_poi+ x'_poi + N q'_mid, with J+ = (J^T J + k_damp I)^-1 J^T (eq. 1),
    N = I - J+ J (eq. 2), q'_mid = w_m ((q_max + q_min) / 2 - q) (eq. 4: the joints' mid-range; the paper's text
    writes the half-range, its intent is the midpoint)."""

    robot: RobotModel
    tip: str
    points: tuple[tuple[str, tuple[float, float, float]], ...]  # (link, point in the link) of interest
    k_damp: float = 1e-3
    w_mid: float = 0.1

    def pinv(self, J: np.ndarray) -> np.ndarray:
        return np.linalg.solve(J.T @ J + self.k_damp * np.eye(J.shape[1]), J.T)

    def poi_positions(self, q) -> np.ndarray:
        return np.array(
            [
                self.robot.link_pose(q, link)[:3, :3] @ p + self.robot.link_pose(q, link)[:3, 3]
                for link, p in self.points
            ]
        )

    def joint_velocity(self, q, x_ee_dot, x_poi_dot, use_avoidance: bool = True) -> np.ndarray:
        """Joint velocities [rad/s] for an end-effector linear velocity (3,) and avoidance velocities (P, 3)."""
        q = np.asarray(q, dtype=float)
        J = self.robot.jacobian(q, self.tip)[:3]
        Jp = self.pinv(J)
        N = np.eye(len(q)) - Jp @ J
        qd = Jp @ x_ee_dot
        if use_avoidance:
            for (link, p), v in zip(self.points, x_poi_dot):
                Jpoi = self.robot.jacobian(q, link, np.asarray(p))[:3]
                qd += N @ (self.pinv(Jpoi) @ v)
        lim = self.robot.limits
        qd += N @ (self.w_mid * ((lim.upper + lim.lower) / 2 - q))
        return qd


def attractive_velocity(x, goal, speed: float, slow_within: float = 0.05) -> np.ndarray:
    """The end-effector velocity down the distance field to `goal` (its gradient: towards the goal), `speed` [m/s],
    slowing linearly within `slow_within` [m] of the goal."""
    d = np.asarray(goal, dtype=float) - np.asarray(x, dtype=float)
    dist = float(np.linalg.norm(d))
    if dist < 1e-9:
        return np.zeros(3)
    return d / dist * speed * min(1.0, dist / slow_within)
