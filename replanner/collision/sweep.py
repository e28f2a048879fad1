"""How finely a straight joint-space motion is sampled so that no robot point travels farther than a path
resolution between two samples (FCL's path checks and the planning layer's motions sample the same).

A motion is cut into pieces; each gets its own even steps from a bound on how far any body point travels along it,
computed at the piece's middle for each body (a ball around it, carried by its frame):
- by distances: a point moves at most sum_j |dq_j| r_j, r_j its distance from joint j's axis; the body's distance
  there, grown by what the joints past j can move it within the piece (turning about j keeps it), never more than
  the arm's longest reach;
- by speed: the ball's points move at most |v_c| + |w| r (the centre's velocity and the angular velocity, exact at
  the middle) plus half of a bound on how fast that changes along the piece (the axes turn with the joints before
  them, the points with all of them).
The smaller one counts: a motion is sampled far less often than by the arm's longest reach alone, and the bound stays
above every vertex's way along it (tests/test_collision.py).
"""

from __future__ import annotations

import numba
import numpy as np

from ..model.kinematics import frames_of, kernel_array

PIECE = 0.15  # [rad] pieces at most this long (summed over joints): the speed bound's change grows with the square
PIECE_STEPS = 8  # nor shorter than this many steps of the longest reach: each piece rounds its steps up


class Sweep:
    """The bodies as the bound sees them: balls around each body, carried by the chain's frames.

    Args:
        robot: the robot model (its chain).
        slot (B,): each body's slot in `robot.frames` (0: the base).
        centre (B, 3), radius (B,): a ball containing each body, its centre in the body's slot's frame.
        reach (dof,): the longest reach [m/rad] of any body point from each joint (never exceeded).
    """

    def __init__(self, robot, slot, centre, radius, reach):
        F, prismatic, joints, parents = robot.chain
        slot = np.asarray(slot, np.int64)
        c = np.asarray(centre, np.float64).reshape(-1, 3)
        # moves[b, j]: joint j moves body b; beyond[j, k]: k lies past j
        anc = robot.moved_by
        moves = np.array([anc[s - 1] if s > 0 else np.zeros(robot.dof, bool) for s in slot]).reshape(-1, robot.dof)
        beyond = anc.T.copy()
        np.fill_diagonal(beyond, False)
        self.args = (
            F,
            prismatic,
            joints,
            parents,
            slot,
            np.ascontiguousarray(c),
            np.asarray(radius, np.float64),
            np.ascontiguousarray(moves),
            np.ascontiguousarray(beyond),
            np.ascontiguousarray(reach, dtype=np.float64),
        )
        self(np.zeros((2, robot.dof)), 1.0)  # compiled (or loaded) now, not in the middle of a running path check

    def travel(self, a: np.ndarray, b: np.ndarray) -> float:
        """The bound [m] on how far any body point travels on the straight motion a -> b (one piece)."""
        dof = len(a)
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        return piece_travel(a, b, 0.0, 1.0, *self.args, np.empty((1, dof)), np.empty((1, dof + 1, 4, 4)), np.zeros(dof))

    def __call__(self, W: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
        """(Q, pos) of waypoints W (M >= 2, dof) sampled every `resolution` [m] (see sweep)."""
        return sweep(kernel_array(W), float(resolution), *self.args)


@numba.njit(cache=True, nogil=True)
def piece_travel(a, b, u, v, F, prismatic, joints, parents, slot, centre, radius, moves, beyond, reach, qm, fr, R):
    """Upper bound [m] on how far any body point moves from a + u (b - a) to a + v (b - a) (qm (1, dof), fr
    (1, 1 + dof, 4, 4) and R (dof,) are work space)."""
    dof, w = a.shape[0], v - u
    for j in range(dof):
        qm[0, j] = a[j] + 0.5 * (u + v) * (b[j] - a[j])
    frames_of(qm, 0, F, prismatic, joints, parents, fr, 0)
    worst = 0.0
    for n in range(slot.shape[0]):  # a body's points move with its own distances from the axes
        s = slot[n]
        if s == 0:
            continue
        px = fr[0, s, 0, 0] * centre[n, 0] + fr[0, s, 0, 1] * centre[n, 1] + fr[0, s, 0, 2] * centre[n, 2]
        py = fr[0, s, 1, 0] * centre[n, 0] + fr[0, s, 1, 1] * centre[n, 1] + fr[0, s, 1, 2] * centre[n, 2]
        pz = fr[0, s, 2, 0] * centre[n, 0] + fr[0, s, 2, 1] * centre[n, 1] + fr[0, s, 2, 2] * centre[n, 2]
        px, py, pz = px + fr[0, s, 0, 3], py + fr[0, s, 1, 3], pz + fr[0, s, 2, 3]
        rn = radius[n]
        travel = 0.0  # sum_j |dq_j| R_j: the distances' bound
        vx = vy = vz = wx = wy = wz = 0.0  # the centre's velocity and the body's angular velocity at the middle
        acc = 0.0  # a bound on how fast (v + |w| r) changes along the piece
        revolute = True
        for i in range(joints.shape[0] - 1, -1, -1):  # joints past j first: their bounds grow j's
            j = joints[i]
            if not moves[n, j]:
                continue
            dj = (b[j] - a[j]) * w
            if prismatic[j]:
                R[j] = reach[j]
                revolute = False
                travel += abs(dj) * R[j]
                continue
            ox, oy, oz = fr[0, j + 1, 0, 3], fr[0, j + 1, 1, 3], fr[0, j + 1, 2, 3]
            zx, zy, zz = fr[0, j + 1, 0, 2], fr[0, j + 1, 1, 2], fr[0, j + 1, 2, 2]
            ex, ey, ez = px - ox, py - oy, pz - oz
            t = ex * zx + ey * zy + ez * zz
            e = np.sqrt(ex * ex + ey * ey + ez * ez)
            past = 0.0  # sum over k > j of |dq_k| R_k: how far the joints past j move the body relative to j's axis
            for k in range(dof):
                if beyond[j, k] and moves[n, k]:
                    past += abs(b[k] - a[k]) * w * R[k]
            grow = 0.5 * past  # half the piece each way from its middle
            R[j] = min(np.sqrt(max(e * e - t * t, 0.0)) + rn + grow, reach[j])
            past += abs(dj) * R[j]
            travel += abs(dj) * R[j]
            vx += dj * (zy * ez - zz * ey)
            vy += dj * (zz * ex - zx * ez)
            vz += dj * (zx * ey - zy * ex)
            wx, wy, wz = wx + dj * zx, wy + dj * zy, wz + dj * zz
            up = 0.0  # how fast j's axis turns: the joints before it
            for k in range(dof):
                if beyond[k, j] and moves[n, k]:
                    up += abs(b[k] - a[k]) * w
            acc += abs(dj) * (2.0 * up * (e + grow) + past) + rn * abs(dj) * up
        speed = np.sqrt(vx * vx + vy * vy + vz * vz) + rn * np.sqrt(wx * wx + wy * wy + wz * wz) + 0.5 * acc
        worst = max(worst, min(travel, speed) if revolute else travel)
    return worst


@numba.njit(cache=True, nogil=True)
def _pieces(a, b, resolution, reach):
    """How many pieces the motion a -> b is cut into."""
    length, far = 0.0, 0.0
    for j in range(a.shape[0]):
        length += abs(b[j] - a[j])
        far += abs(b[j] - a[j]) * reach[j]
    return max(1, min(np.int64(np.ceil(length / PIECE)), np.int64(far / (resolution * PIECE_STEPS))))


@numba.njit(cache=True, nogil=True)
def sweep(W, resolution, F, prismatic, joints, parents, slot, centre, radius, moves, beyond, reach):
    """(Q (N, dof), pos (N,)): W's segments sampled so no body point moves more than `resolution` [m] between two
    rows, pos = i + the fraction along segment i (the last row is W[-1], pos M - 1)."""
    M, dof = W.shape
    qm, fr, R = np.empty((1, dof)), np.empty((1, dof + 1, 4, 4)), np.zeros(dof)
    cuts = np.empty(M - 1, np.int64)
    for i in range(M - 1):
        cuts[i] = _pieces(W[i], W[i + 1], resolution, reach)
    steps = np.empty(cuts.sum(), np.int64)
    p = 0
    for i in range(M - 1):
        for k in range(cuts[i]):
            t = piece_travel(
                W[i],
                W[i + 1],
                k / cuts[i],
                (k + 1) / cuts[i],
                F,
                prismatic,
                joints,
                parents,
                slot,
                centre,
                radius,
                moves,
                beyond,
                reach,
                qm,
                fr,
                R,
            )
            steps[p] = max(1, np.int64(np.ceil(t / resolution)))
            p += 1
    N = steps.sum() + 1
    Q, pos = np.empty((N, dof)), np.empty(N)
    n = p = 0
    for i in range(M - 1):
        for k in range(cuts[i]):
            for s in range(steps[p]):
                f = (k + s / steps[p]) / cuts[i]
                pos[n] = i + f
                for j in range(dof):
                    Q[n, j] = W[i, j] + f * (W[i + 1, j] - W[i, j])
                n += 1
            p += 1
    Q[n] = W[M - 1]
    pos[n] = M - 1
    return Q, pos
