"""One straight motion through the sphere layer in one compiled call: the configurations a path check would
interpolate (collision.interpolate's, same count), each placed and classified in turn, every 8th first, stopping at
the first certain contact. The planner checks thousands of motions a plan; this keeps Python out of each one."""

from __future__ import annotations

import numba
import numpy as np

from .kernels import chain_frames
from .sphere_layer import SphereScene, VoxelVolume, _one

STRIDE = 8  # every 8th configuration first: a contact is usually found early
OUTSIDE = -2  # what `BoundMotion` says of a motion with an end outside the joint limits


class BoundMotion:
    """The compiled motion check of one sphere layer and map with its arguments bound once: a planner asks
    thousands of times a plan, and each call then pays only for its own arguments.

    Args:
        robot: the robot model; layer, vol: the sphere layer and the map's voxel volume.
        lo, hi: joint limits the ends must lie within (None: not checked).
        reach (dof,): how far any robot point moves per unit of each joint [m/rad] (steps = |b - a| . reach / res).
    """

    def __init__(self, robot, layer: SphereScene, vol: VoxelVolume, lo, hi, reach):
        limits = lo is not None
        dof = robot.dof
        self.args = (
            np.asarray(lo if limits else np.full(dof, -np.inf), np.float64),
            np.asarray(hi if limits else np.full(dof, np.inf), np.float64),
            np.ascontiguousarray(reach, dtype=np.float64), robot._F, robot._prismatic, robot._joint_order,
            robot._chain_parents, layer.tab_i, layer.tab_f, layer.tab, layer.local, layer.radius, layer.first,
            layer.in_local, layer.in_rad, layer.in_first, layer.ball_slot, layer.ball_c, layer.ball_r, layer.gf,
            layer.env_pad, layer.map_pad, layer.self_pad, layer.env_mask, layer.ob_kind, layer.ob_inv, layer.ob_dim,
            layer.ob_id, layer.ob_exact, layer.octree_mask, vol.sat, vol.key_min, vol.inv_res, layer.pair_a,
            layer.pair_b,
        )  # fmt: skip

    def __call__(self, a: np.ndarray, b: np.ndarray, resolution: float) -> tuple[int, np.ndarray, int]:
        """(verdict, unsure, steps) of the motion a -> b (float64 (dof,)) checked every `resolution` [m]: verdict
        -1 if a configuration is in contact for certain, OUTSIDE if an end is outside the limits, else 1 with the
        indices k of the configurations a + k / steps (b - a) the layer could not decide. resolution 0: a alone."""
        return _checked_motion(a, b, resolution, *self.args)


@numba.njit(cache=True, nogil=True)
def _checked_motion(
    a, b, resolution, lo, hi, reach, F, prismatic, joints, parents, tab_i, tab_f, table, local, rad, first, in_local,
    in_rad, in_first, ball_slot, ball_c, ball_r, gf, env_pad, map_pad, self_pad, env_mask, ob_kind, ob_inv, ob_dim,
    ob_id, ob_exact, octree_mask, sat, key_min, inv_res, pair_a, pair_b,
):  # fmt: skip
    travel = 0.0
    for j in range(a.shape[0]):
        if not (lo[j] <= a[j] <= hi[j] and lo[j] <= b[j] <= hi[j]):
            return OUTSIDE, np.empty(0, np.int64), 0
        travel += abs(b[j] - a[j]) * reach[j]
    steps = 0 if resolution <= 0.0 else max(1, np.int64(np.ceil(travel / resolution)))
    unsure = np.empty(steps + 1, np.int64)
    m = _motion(
        a, b, steps, F, prismatic, joints, parents, tab_i, tab_f, table, local, rad, first, in_local, in_rad, in_first,
        ball_slot, ball_c, ball_r, gf, env_pad, map_pad, self_pad, env_mask, ob_kind, ob_inv, ob_dim, ob_id, ob_exact,
        octree_mask, sat, key_min, inv_res, pair_a, pair_b, unsure,
    )  # fmt: skip
    return (-1, unsure[:0], steps) if m < 0 else (1, unsure[:m], steps)


@numba.njit(cache=True, nogil=True)
def _motion(
    a, b, steps, F, prismatic, joints, parents, tab_i, tab_f, table, local, rad, first, in_local, in_rad, in_first,
    ball_slot, ball_c, ball_r, gf, env_pad, map_pad, self_pad, env_mask, ob_kind, ob_inv, ob_dim, ob_id, ob_exact,
    octree_mask, sat, key_min, inv_res, pair_a, pair_b, unsure,
):  # fmt: skip
    dof = a.shape[0]
    Q = np.empty((1, dof))
    frames = np.empty((1, dof + 1, 4, 4))
    C, IC = np.empty((local.shape[0], 3)), np.empty((in_local.shape[0], 3))
    BC, near = np.empty((ball_slot.shape[0], 3)), np.empty(ob_kind.shape[0], np.int64)
    placed = np.zeros(ball_slot.shape[0], np.bool_)
    m = 0
    for phase in range(2):
        for k in range(steps + 1):
            if (k % STRIDE == 0) != (phase == 0):
                continue
            for j in range(dof):
                Q[0, j] = a[j] + k / steps * (b[j] - a[j]) if k < steps else b[j]
            chain_frames(Q, F, prismatic, joints, parents, frames)
            v = _one(
                0, frames, Q, tab_i, tab_f, table, local, rad, first, in_local, in_rad, in_first, ball_slot, ball_c,
                ball_r, gf, env_pad, map_pad, self_pad, env_mask, ob_kind, ob_inv, ob_dim, ob_id, ob_exact,
                octree_mask, sat, key_min, inv_res, pair_a, pair_b, C, IC, BC, near, placed,
            )  # fmt: skip
            if v == -1:
                return -1
            if v == 0:
                unsure[m] = k
                m += 1
    return m
