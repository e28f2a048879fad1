"""Inverse kinematics: damped least squares from many seeds at once (batched FK and Jacobians)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError, ReplannerError
from ..model.transforms import make_transform


class IKError(ReplannerError):
    """No configuration reaches the pose within tolerance (or none of those is collision-free)."""


@dataclass(frozen=True)
class IKResult:
    q: np.ndarray
    position_error: float  # [m]
    orientation_error: float  # [rad]
    solutions: int  # valid solutions found among the restarts


def _rotation_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (N, 3) of R_target R^T, in the base frame."""
    E = R_target @ np.swapaxes(R, -1, -2)
    w = np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], axis=1)
    cos = np.clip((np.trace(E, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    angle = np.arccos(cos)
    sin = np.sin(angle)
    scale = np.where(sin > 1e-6, angle / (2 * np.maximum(sin, 1e-12)), 0.5)
    out = w * scale[:, None]
    # near pi the skew part vanishes: take the axis from the symmetric part
    near_pi = angle > np.pi - 1e-3
    if near_pi.any():
        for i in np.flatnonzero(near_pi):
            B = (E[i] + np.eye(3)) / 2
            axis = B[np.argmax(np.diag(B))]
            out[i] = axis / np.linalg.norm(axis) * angle[i]
    return out


def solve_ik(
    robot,
    link: str,
    T_target: np.ndarray,
    *,
    checker=None,
    seed=None,
    restarts: int = 16,
    position_tolerance: float = 0.002,
    orientation_tolerance: float = 0.02,
    max_iterations: int = 150,
    rng: np.random.Generator | None = None,
) -> IKResult:
    """A configuration placing `link` at T_target (base frame), nearest to `seed` among the valid solutions.

    Runs `restarts` damped-least-squares descents in one batch (from the seed and random configurations),
    keeps those within both tolerances, within the joint limits and (with a checker) collision-free. Stops as soon
    as the descent from the seed reaches a valid solution (the others only matter when it does not).
    """
    T_target = np.asarray(T_target, dtype=float)
    if T_target.shape != (4, 4) or not np.all(np.isfinite(T_target)):
        raise InvalidInputError("the target pose must be a finite 4x4 transform")
    rng = rng or np.random.default_rng()
    lim = robot.limits
    slot, T_frame_link = robot.frame_offset(link)
    # fail fast: farther than the chain can reach from the first joint
    reach = robot.reach(link, 0.0)
    j0 = robot.frames(robot.home[None])[0, 1, :3, 3]
    if reach.max() > 0 and np.linalg.norm(T_target[:3, 3] - j0) > reach.max() + position_tolerance:
        raise IKError(
            f"the target position is {np.linalg.norm(T_target[:3, 3] - j0):.3f} m from the first joint, beyond "
            f"the {link} reach of {reach.max():.3f} m"
        )
    seeds = [robot.home if seed is None else robot.check_q(seed, "seed")]
    Q = np.vstack([np.clip(np.asarray(seeds), lim.lower, lim.upper), robot.random_q(rng, restarts - 1)])
    p_t, R_t = T_target[:3, 3], T_target[:3, :3]
    lam2 = 1e-4
    seed_tried = False
    for _ in range(max_iterations):
        frames = robot.frames(Q)
        T = frames[:, slot] @ T_frame_link
        e = np.concatenate([p_t - T[:, :3, 3], _rotation_error(R_t, T[:, :3, :3])], axis=1)
        done = (np.linalg.norm(e[:, :3], axis=1) < position_tolerance * 0.5) & (
            np.linalg.norm(e[:, 3:], axis=1) < orientation_tolerance * 0.5
        )
        if done.all():
            break
        if done[0] and not seed_tried:  # the seed's own descent (nearest the start as a rule): enough if valid
            seed_tried = True
            if checker is None or checker.is_valid_batch(Q[:1])[0]:
                break
        J = robot.jacobian(Q, link)
        JJt = J @ np.swapaxes(J, 1, 2) + lam2 * np.eye(6)
        dq = np.einsum("nij,nj->ni", np.swapaxes(J, 1, 2), np.linalg.solve(JJt, e[:, :, None])[..., 0])
        step = np.linalg.norm(dq, axis=1, keepdims=True)
        dq = np.where(step > 0.5, dq * 0.5 / np.maximum(step, 1e-12), dq) * (~done)[:, None]
        Q = np.clip(Q + dq, lim.lower, lim.upper)
    T = robot.frames(Q)[:, slot] @ T_frame_link
    pos_err = np.linalg.norm(p_t - T[:, :3, 3], axis=1)
    rot_err = np.linalg.norm(_rotation_error(R_t, T[:, :3, :3]), axis=1)
    ok = (pos_err <= position_tolerance) & (rot_err <= orientation_tolerance)
    if not ok.any():
        best = int(np.argmin(pos_err / position_tolerance + rot_err / orientation_tolerance))
        raise IKError(
            f"no configuration reaches the pose: the closest of {restarts} tries is {pos_err[best]:.4f} m and "
            f"{rot_err[best]:.4f} rad away (tolerances {position_tolerance} m, {orientation_tolerance} rad); "
            "the pose may be out of reach or need a different orientation"
        )
    idx = np.flatnonzero(ok)
    if checker is not None:
        valid = checker.is_valid_batch(Q[idx])
        if not valid.any():
            contact = checker.check(Q[idx[0]])
            raise IKError(f"every configuration reaching the pose is in collision ({contact})")
        idx = idx[valid]
    ref = Q[0] if seed is None else seeds[0]
    best = idx[np.argmin(np.linalg.norm(Q[idx] - ref, axis=1))]
    return IKResult(Q[best].copy(), float(pos_err[best]), float(rot_err[best]), len(idx))


def pose(position, quat_xyzw) -> np.ndarray:
    """4x4 pose from a position [m] and a quaternion (x, y, z, w)."""
    return make_transform(position, quat_xyzw)
