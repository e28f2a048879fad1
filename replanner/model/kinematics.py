"""Forward kinematics compiled (numba): a joint chain's frames for many configurations, one loop each, where numpy's
batched 4x4 products are mostly overhead."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def frames_of(Q, n, F, prismatic, joints, parents, out, m):
    """out[m] = the frames (1 + dof, 4, 4) of configuration Q[n] (see chain_frames); inlined into the callers' loops:
    a call per configuration with a dozen arrays would cost more in reference counting than the arithmetic."""
    for r in range(4):
        for c in range(4):
            out[m, 0, r, c] = 1.0 if r == c else 0.0
    for k in range(joints.shape[0]):
        j, p = joints[k], parents[k]
        q = Q[n, j]
        cq, sq, d = (1.0, 0.0, q) if prismatic[j] else (np.cos(q), np.sin(q), 0.0)
        # local_j(q) = F[j] @ (rotation about z by q, or translation along z by d): rows 0-2
        l00, l01 = F[j, 0, 0] * cq + F[j, 0, 1] * sq, F[j, 0, 1] * cq - F[j, 0, 0] * sq
        l10, l11 = F[j, 1, 0] * cq + F[j, 1, 1] * sq, F[j, 1, 1] * cq - F[j, 1, 0] * sq
        l20, l21 = F[j, 2, 0] * cq + F[j, 2, 1] * sq, F[j, 2, 1] * cq - F[j, 2, 0] * sq
        l02, l12, l22 = F[j, 0, 2], F[j, 1, 2], F[j, 2, 2]
        l03, l13, l23 = F[j, 0, 3] + F[j, 0, 2] * d, F[j, 1, 3] + F[j, 1, 2] * d, F[j, 2, 3] + F[j, 2, 2] * d
        for r in range(3):
            a0, a1, a2, a3 = out[m, p, r, 0], out[m, p, r, 1], out[m, p, r, 2], out[m, p, r, 3]
            out[m, j + 1, r, 0] = a0 * l00 + a1 * l10 + a2 * l20
            out[m, j + 1, r, 1] = a0 * l01 + a1 * l11 + a2 * l21
            out[m, j + 1, r, 2] = a0 * l02 + a1 * l12 + a2 * l22
            out[m, j + 1, r, 3] = a0 * l03 + a1 * l13 + a2 * l23 + a3
        out[m, j + 1, 3, 0] = out[m, j + 1, 3, 1] = out[m, j + 1, 3, 2] = 0.0
        out[m, j + 1, 3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def chain_frames(Q, F, prismatic, joints, parents, out):
    """Frames out (N, 1 + dof, 4, 4) of a joint chain: out[:, 0] = I, out[:, 1 + j] = out[:, p] @ local_j(q_j).

    F (dof, 4, 4): joint j's frame at q = 0 in its parent's, z its axis; a revolute joint turns about z, a
    prismatic one slides along it. joints, parents: joint j and its parent's slot p (0: the base), parents first.
    Every transform is homogeneous (last row 0, 0, 0, 1): its last row is neither read nor multiplied.
    """
    for n in range(Q.shape[0]):
        frames_of(Q, n, F, prismatic, joints, parents, out, n)
    return out


def kernel_array(a, dtype=np.float64) -> np.ndarray:
    """C-contiguous and writable: numba compiles a kernel again for another layout or a read-only array, seconds
    in the middle of a motion on a cold cache."""
    a = np.ascontiguousarray(a, dtype=dtype)
    return a if a.flags.writeable else a.copy()


def warm_up() -> None:
    """Compile (or load from the cache) the chain's kernels now: a first compile takes seconds, too long mid-motion."""
    F, prismatic = np.eye(4)[None].copy(), np.zeros(1, bool)
    F.setflags(write=False)  # as a robot model holds them
    prismatic.setflags(write=False)
    chain_frames(np.zeros((1, 1)), F, prismatic, np.zeros(1, np.int64), np.zeros(1, np.int64), np.empty((1, 2, 4, 4)))
