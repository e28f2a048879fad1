"""One straight motion through the sphere layer in one compiled call: the configurations a path check would
interpolate (collision/sweep.py), classified in turn, every 8th first, stopping at the first
certain contact. Anchors checked with a wider margin clear their neighbours without a check of their own (a plan's
motions run at a few millimetres' resolution). The planner checks thousands of motions a plan; this keeps Python out
of each one, the convex pass on what the spheres leave included (`BoundMotion.decided`)."""

from __future__ import annotations

import copy

import numba
import numpy as np
from numba.experimental import structref

from ...model.kinematics import frames_of
from ...world.volume import VoxelVolume
from ..selfclearance import may_collide_row
from ..sweep import Sweep, sweep
from .convex import ConvexPass, decide_all
from .layer import CONTACT, UNSURE, SphereScene, verdicts
from .layer_args import Unliteral

STRIDE = 8  # every 8th configuration first: a contact is usually found early
AHEAD = 0.02  # [m] the margin of an anchor's check: free with it, its neighbours within that travel are too
OUTSIDE = -2  # what `BoundMotion` says of a motion with an end outside the joint limits
_FIELDS = (
    "lo",
    "hi",
    "sw_slot",
    "sw_centre",
    "sw_radius",
    "sw_moves",
    "sw_beyond",
    "reach",
    "layer_reach",
    "env_pad",
    "map_pad",
    "self_pad",
    "L",
    "P",
    "D",
    "pfirst",
    "dfirst",
    "supported",
    "ob_R",
    "ob_t",
    "cpair_a",
    "cpair_b",
    "hv_first",
    "hv_nb",
    "hv_start",
)


@structref.register
class _BoundType(Unliteral):
    pass


class _Bound(structref.StructRefProxy):
    """The decided motion's arguments as one compiled object: a call unboxes it at once, not 20 arrays."""


structref.define_proxy(_Bound, _BoundType, list(_FIELDS))


class BoundMotion:
    """The compiled motion check of one sphere layer and map with its arguments bound once: a planner asks
    thousands of times a plan, and each call then pays only for its own arguments.

    Args:
        robot: the robot model; layer, vol: the sphere layer and the map's voxel volume.
        lo, hi: joint limits the ends must lie within (None: not checked).
        sweep: how finely a motion is sampled (the checker's scene's: FCL's path checks sample the same).
        ahead: [m] the margin of the anchors' checks (0: every configuration is checked on its own).
    """

    def __init__(
        self,
        robot,
        layer: SphereScene,
        vol: VoxelVolume,
        lo,
        hi,
        sweep: Sweep,
        ahead: float = AHEAD,
        convex: ConvexPass | None = None,
    ):
        limits = lo is not None
        dof = robot.dof
        self.ahead = float(ahead)
        self.args = (
            np.asarray(lo if limits else np.full(dof, -np.inf), np.float64),
            np.asarray(hi if limits else np.full(dof, np.inf), np.float64),
            *sweep.args[4:],
            layer.reach,
            layer.env_pad,
            layer.map_pad,
            layer.self_pad,
            layer.kernel_args(vol),
        )
        cp = convex
        self.bound = (
            None
            if cp is None
            else _bind(
                *self.args,
                cp.P,
                cp.D,
                cp.pfirst,
                cp.dfirst,
                cp.supported,
                cp.ob_R,
                cp.ob_t,
                cp.pair_a,
                cp.pair_b,
                cp.hv_first,
                cp.hv_nb,
                cp.hv_start,
            )
        )

    def with_ahead(self, ahead: float) -> BoundMotion:
        """The same check with another anchor margin `ahead` [m] (0: every configuration on its own)."""
        other = copy.copy(self)
        other.ahead = float(ahead)
        return other

    def __call__(
        self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0
    ) -> tuple[int, np.ndarray, np.ndarray]:
        """(verdict, unsure, Q) of the motion a -> b (float64 (dof,)) checked every `resolution` [m]: Q its
        configurations (a first, b last; a alone for resolution 0), verdict -1 if one is in contact for certain,
        OUTSIDE if an end is outside the limits, else 1 with the indices into Q of those the layer could not decide.
        `given`: ends already known free by the exact verdict, not checked again (1: a, 2: b, 3: both)."""
        return _sphere_motion(a, b, resolution, self.ahead, given, *self.args)

    def decided(self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0) -> tuple[int, np.ndarray]:
        """(verdict, rest) of the same motion with the convex pass (fast/convex.py, given at construction) on
        what the spheres left, in the same compiled call: verdict as `__call__`'s, and rest (r, dof) the
        configurations neither decided, FCL's to check. The verdicts of `__call__` then `decide_batch`."""
        return _decided_bound(a, b, resolution, self.ahead, given, self.bound)


@numba.njit(cache=True)
def _bind(*args):
    return _Bound(*args)


@numba.njit(cache=True, nogil=True)
def _decided_bound(a, b, resolution, ahead, given, m):
    """`BoundMotion.decided` of the arguments bound in m: the spheres, then the convex pass on what they left."""
    L = m.L
    v, unsure, Q = _sphere_motion(
        a,
        b,
        resolution,
        ahead,
        given,
        m.lo,
        m.hi,
        m.sw_slot,
        m.sw_centre,
        m.sw_radius,
        m.sw_moves,
        m.sw_beyond,
        m.reach,
        m.layer_reach,
        m.env_pad,
        m.map_pad,
        m.self_pad,
        L,
    )
    u = unsure.shape[0]
    if v != 1 or u == 0:
        return v, Q[:0]
    frames = np.empty((u, a.shape[0] + 1, 4, 4))
    for i in range(u):
        frames_of(Q, unsure[i], L.Fj, L.prismatic, L.joints, L.parents, frames, i)
    out = np.zeros(u, np.int8)
    decide_all(
        frames,
        np.arange(u),
        out,
        True,
        m.P,
        m.D,
        m.pfirst,
        m.dfirst,
        m.supported,
        m.env_pad,
        m.self_pad,
        m.map_pad,
        m.ob_R,
        m.ob_t,
        m.cpair_a,
        m.cpair_b,
        m.hv_first,
        m.hv_nb,
        m.hv_start,
        L,
    )
    rest = np.empty((u, a.shape[0]))
    r = 0
    for i in range(u):
        if out[i] == CONTACT:
            return -1, Q[:0]
        if out[i] == UNSURE:
            rest[r] = Q[unsure[i]]
            r += 1
    return 1, rest[:r]


@numba.njit(cache=True, nogil=True)
def _sphere_motion(
    a,
    b,
    resolution,
    ahead,
    given,
    lo,
    hi,
    slot,
    centre,
    radius,
    moves,
    beyond,
    reach,
    layer_reach,
    env_pad,
    map_pad,
    self_pad,
    L,
):
    """(verdict, unsure, Q): BoundMotion's answer and the motion's configurations Q (steps + 1, dof)."""
    for j in range(a.shape[0]):
        if not (lo[j] <= a[j] <= hi[j] and lo[j] <= b[j] <= hi[j]):
            return OUTSIDE, np.empty(0, np.int64), np.empty((0, a.shape[0]))
    if resolution <= 0.0:
        Q = np.empty((1, a.shape[0]))
        Q[0] = a
    else:
        W = np.empty((2, a.shape[0]))
        W[0], W[1] = a, b
        Q = sweep(W, resolution, L.Fj, L.prismatic, L.joints, L.parents, slot, centre, radius, moves, beyond, reach)[0]
    steps = Q.shape[0] - 1
    v = np.zeros(steps + 1, np.int8)
    known = np.zeros(steps + 1, np.bool_)  # free for certain without a check of its own
    ends = np.zeros(steps + 1, np.bool_)  # ends the caller knows free by the exact verdict: nothing to ask
    if steps > 0:
        ends[0] = given & 1 != 0
        ends[steps] = given & 2 != 0
    # anchors every 2J + 1 configurations, checked with every padding grown by `ahead`: free there, the J on
    # each side are free too, as no sphere centre moves more than J steps' travel <= ahead (relative: 2 x, and
    # a self pair's padding grows by 2 x ahead at least)
    step = 0.0  # the farthest any sphere centre moves in one step (steps differ from piece to piece)
    for k in range(steps):
        travel = 0.0
        for j in range(a.shape[0]):
            travel += abs(Q[k + 1, j] - Q[k, j]) * layer_reach[j]
        step = max(step, travel)
    J = steps if step <= 0.0 else min(steps, np.int64(np.floor(ahead / step)))
    if ahead > 0.0 and J >= 1:
        anchors = np.minimum(np.arange(J, steps + J + 1, 2 * J + 1), steps)
        if verdicts(Q, anchors, True, env_pad + ahead, map_pad + ahead, self_pad + ahead, L, v) >= 0:
            return -1, np.empty(0, np.int64), Q  # an inner ball's contact: no padding takes part in it
        for k in anchors:
            if v[k] == 1:
                known[max(k - J, 0) : k + J + 1] = True
    # the rest, every 8th first: a contact is usually found early
    seq = np.empty(steps + 1, np.int64)
    m = 0
    for phase in range(2):
        for k in range(steps + 1):
            if (k % STRIDE == 0) == (phase == 0):
                seq[m] = k
                m += 1
    if verdicts(Q, seq[~(known[seq] | ends[seq])], True, env_pad, map_pad, self_pad, L, v) >= 0:
        return -1, np.empty(0, np.int64), Q
    unsure = np.empty(steps + 1, np.int64)
    u = 0
    for k in seq:
        if ends[k]:
            continue
        # the always-close pairs' tables are not spheres: a configuration cleared by an anchor still asks them
        if (v[k] == 0 and not known[k]) or (
            known[k] and L.tab_i.shape[0] and may_collide_row(Q, k, L.tab_i, L.tab_f, L.table)
        ):
            unsure[u] = k
            u += 1
    return 1, unsure[:u], Q
