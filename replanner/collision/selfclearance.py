"""Precomputed self-clearance tables for body pairs whose relative pose depends on at most two joints.

Neighbouring links (link5 and link7 of a Panda, say) are always close, so box tests never rule them out and
every check would pay for FCL calls. Their relative pose is a function of one or two joint angles, so their
clearance is tabulated once on a grid (FCL distance) and looked up with a Lipschitz bound:

    clearance(q) >= table(q_grid) - sum_k reach_k * |q_k - q_grid_k|

When that bound is positive the pair is certainly apart; otherwise FCL decides. Tables are cached on disk.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import weakref
from pathlib import Path

import fcl
import numba
import numpy as np

from ..cache_dirs import default_cache_dir
from ..model.geometry import bounding_radius, padded, to_fcl
from ..model.kinematics import kernel_array

log = logging.getLogger(__name__)

_FORMAT = 3
DEFAULT_STEP = np.deg2rad(2.0)
MAX_POINTS = 256
BLOCK = 8  # grid points a side of a coarse cell: the cells' least clearances stay in cache and answer most lookups
_BUILT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # robot model -> its tables: every checker shares them
_BUILDING = threading.Lock()


def clearance_tables(robot) -> SelfClearanceTables:
    """The tables of `robot`'s close self-collision pairs: built once per robot model, cached on disk."""
    with _BUILDING:
        tables = _BUILT.get(robot)
        if tables is None:
            tables = _BUILT[robot] = SelfClearanceTables(
                robot, robot.self_collision_pairs, cache_dir=default_cache_dir()
            )
        return tables


class SelfClearanceTables:
    """Clearance tables for a subset of a robot's self-collision pairs.

    Args:
        robot: the robot model.
        pairs: (P, 2) body index pairs (indices into robot.bodies), e.g. robot.self_collision_pairs.
        step: grid step [rad] per joint (coarser for long ranges so no axis has more than MAX_POINTS).
        cache_dir: where tables are cached; None disables the cache.
    """

    def __init__(self, robot, pairs: np.ndarray, step: float = DEFAULT_STEP, cache_dir: Path | None = None):
        self.robot = robot
        rows = []
        for pi, (a, b) in enumerate(np.asarray(pairs).reshape(-1, 2)):
            joints = self._joints_between(robot, int(a), int(b))
            if joints is not None and 1 <= len(joints) <= 2 and not robot.prismatic[joints].any():
                rows.append((pi, int(a), int(b), joints))
        self.pair_index = np.array([r[0] for r in rows], dtype=np.int64)
        P = len(rows)
        lim = robot.limits
        j0 = np.array([r[3][0] for r in rows], dtype=np.int64)
        j1 = np.array([r[3][1] if len(r[3]) > 1 else r[3][0] for r in rows], dtype=np.int64)
        two = np.array([len(r[3]) > 1 for r in rows], dtype=bool)
        span0 = lim.upper[j0] - lim.lower[j0]
        span1 = np.where(two, lim.upper[j1] - lim.lower[j1], 0.0)
        n0 = np.minimum(MAX_POINTS, np.ceil(span0 / step).astype(np.int64) + 1)
        n1 = np.where(two, np.minimum(MAX_POINTS, np.ceil(span1 / step).astype(np.int64) + 1), 1)
        self.j0, self.j1, self.two = j0, j1, two
        self.lo0, self.lo1 = lim.lower[j0], np.where(two, lim.lower[j1], 0.0)
        self.step0 = span0 / np.maximum(n0 - 1, 1)
        self.step1 = np.where(two, span1 / np.maximum(n1 - 1, 1), 1.0)
        self.n0, self.n1 = n0, n1
        self.offset = np.concatenate([[0], np.cumsum(n0 * n1)[:-1]]).astype(np.int64) if P else np.zeros(0, np.int64)
        # Lipschitz constants: how far either body can move relative to the other per radian of each joint
        r0, r1 = np.zeros(P), np.zeros(P)
        for i, (_, a, b, joints) in enumerate(rows):
            ra = self._reach(robot, a)
            rb = self._reach(robot, b)
            r = np.maximum(ra, rb)
            r0[i] = r[joints[0]]
            r1[i] = r[joints[1]] if len(joints) > 1 else 0.0
        self.r0, self.r1 = r0, r1
        self.table = self._load_or_build(rows, cache_dir)
        coarse, self.cn1, self.coffset = self._coarse()
        # the table for compiled callers (never empty), then each pair's least clearance per BLOCK x BLOCK points
        self.lookup = np.concatenate([self.table, coarse]) if len(self.table) else np.zeros(1)
        # per pair, packed for the compiled lookups: joints, grid sizes, offset, coarse columns and offset; lows,
        # steps, slack per grid unit
        self.packed_i = np.ascontiguousarray(
            np.stack([j0, j1, n0, n1, self.offset, self.cn1, self.coffset], axis=1).reshape(P, 7), np.int64
        )
        self.packed_f = np.ascontiguousarray(
            np.stack([self.lo0, self.lo1, self.step0, self.step1, r0 * self.step0, r1 * self.step1], axis=1).reshape(
                P, 6
            )
        )
        for arr in (
            self.lookup,
            self.packed_i,
            self.packed_f,
            self.j0,
            self.j1,
            self.lo0,
            self.lo1,
            self.step0,
            self.step1,
            self.n0,
            self.n1,
            self.offset,
            self.cn1,
            self.coffset,
            self.r0,
            self.r1,
            self.table,
        ):
            arr.setflags(write=False)
        self.may_collide(robot.home[None])  # compile the lookup now, not in the monitor's first check

    def _coarse(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each pair's least clearance over blocks of BLOCK x BLOCK grid points, flat after the fine table; the
        coarse columns per pair and each pair's offset in the lookup array."""
        blocks, cols, offsets, at = [], [], [], len(self.table)
        for i in range(len(self.pair_index)):
            n0, n1 = int(self.n0[i]), int(self.n1[i])
            t = self.table[self.offset[i] : self.offset[i] + n0 * n1].reshape(n0, n1)
            b = np.minimum.reduceat(np.minimum.reduceat(t, np.arange(0, n0, BLOCK), 0), np.arange(0, n1, BLOCK), 1)
            blocks.append(b.ravel())
            cols.append(b.shape[1])
            offsets.append(at)
            at += b.size
        return (
            np.concatenate(blocks) if blocks else np.zeros(0),
            np.array(cols, np.int64),
            np.array(offsets, np.int64),
        )

    @staticmethod
    def _reach(robot, bi: int) -> np.ndarray:
        body = robot.bodies[bi]
        radius = bounding_radius(body.shape) + float(np.linalg.norm(body.T_link_body[:3, 3])) + robot.self_body_padding
        return robot.reach(body.link, radius)

    @staticmethod
    def _joints_between(robot, a: int, b: int) -> np.ndarray | None:
        ka = robot.link_frame_index(robot.bodies[a].link)
        kb = robot.link_frame_index(robot.bodies[b].link)
        anc_a = robot.moved_by[ka] if ka >= 0 else np.zeros(robot.dof, bool)
        anc_b = robot.moved_by[kb] if kb >= 0 else np.zeros(robot.dof, bool)
        return np.flatnonzero(anc_a ^ anc_b)

    def _key(self, rows) -> str:
        r = self.robot
        h = hashlib.sha256()
        h.update(f"{_FORMAT}|{r.self_padding!r}|".encode())
        h.update(r.kinematics_digest())
        for arr in (self.n0, self.n1, self.lo0, self.lo1, self.step0, self.step1):
            h.update(np.ascontiguousarray(arr).tobytes())
        for _, a, b, joints in rows:
            for bi in (a, b):
                body = r.bodies[bi]
                h.update(body.link.encode())
                h.update(np.ascontiguousarray(body.T_link_body).tobytes())
                h.update(
                    repr(body.shape if not hasattr(body.shape, "vertices") else body.shape.vertices.tobytes()).encode()
                )
            h.update(np.asarray(joints).tobytes())
        return h.hexdigest()[:24]

    def _load_or_build(self, rows, cache_dir: Path | None) -> np.ndarray:
        if not rows:
            return np.zeros(0)
        key = self._key(rows)
        path = None if cache_dir is None else Path(cache_dir) / f"selfclearance-{self.robot.name}-{key}.npy"
        if path is not None and path.is_file():
            try:
                table = np.load(path, allow_pickle=False)
                if table.shape == (int((self.n0 * self.n1).sum()),):
                    return table
            except (OSError, ValueError):
                log.warning("ignoring unreadable self-clearance cache %s", path)
        table = self._build(rows)
        if path is not None:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
                np.save(tmp, table)
                os.replace(tmp, path)
            except OSError as err:
                log.warning("cannot write self-clearance cache %s: %s", path, err)
        return table

    def _build(self, rows) -> np.ndarray:
        r = self.robot
        out = []
        req = fcl.DistanceRequest()
        for i, (_, a, b, _) in enumerate(rows):
            ga = fcl.CollisionObject(to_fcl(padded(r.bodies[a].shape, r.self_body_padding)))
            gb = fcl.CollisionObject(to_fcl(padded(r.bodies[b].shape, r.self_body_padding)))
            g0 = self.lo0[i] + self.step0[i] * np.arange(self.n0[i])
            g1 = self.lo1[i] + self.step1[i] * np.arange(self.n1[i])
            Q = np.tile(r.home, (len(g0) * len(g1), 1))
            Q[:, self.j0[i]] = np.repeat(g0, len(g1))
            if self.two[i]:
                Q[:, self.j1[i]] = np.tile(g1, len(g0))
            T = r.fk(Q)
            Ta = T[:, r.link_index(r.bodies[a].link)] @ r.bodies[a].T_link_body
            Tb = T[:, r.link_index(r.bodies[b].link)] @ r.bodies[b].T_link_body
            d = np.empty(len(Q))
            for n in range(len(Q)):
                ga.setTransform(fcl.Transform(Ta[n, :3, :3], Ta[n, :3, 3]))
                gb.setTransform(fcl.Transform(Tb[n, :3, :3], Tb[n, :3, 3]))
                d[n] = fcl.distance(ga, gb, req)
            out.append(np.maximum(d, 0.0))  # in contact: 0 (fcl may report -1)
        return np.concatenate(out)

    def __len__(self) -> int:
        return len(self.pair_index)

    def may_collide(self, Q: np.ndarray) -> np.ndarray:
        """(N, P_table) True where the tabulated pair may be in contact at configurations Q (N, dof)."""
        out = np.empty((len(Q), len(self.pair_index)), np.bool_)
        _may_collide_rows(kernel_array(Q), self.packed_i, self.packed_f, self.lookup, out)
        return out


@numba.njit(cache=True, nogil=True, inline="always")
def pair_maybe(Q, n, p, packed_i, packed_f, table) -> bool:
    """Whether tabulated pair p may be in contact at Q[n]: its nearest grid point's clearance less Lipschitz slack.
    The least clearance of that point's block is asked first: when it beats the slack, so does the point's."""
    j0, j1, n0, n1, off = packed_i[p, 0], packed_i[p, 1], packed_i[p, 2], packed_i[p, 3], packed_i[p, 4]
    u0 = (Q[n, j0] - packed_f[p, 0]) / packed_f[p, 2]
    u1 = (Q[n, j1] - packed_f[p, 1]) / packed_f[p, 3]
    i0 = np.int64(min(max(np.rint(u0), 0.0), n0 - 1.0))
    i1 = np.int64(min(max(np.rint(u1), 0.0), n1 - 1.0))
    slack = abs(u0 - i0) * packed_f[p, 4] + abs(u1 - i1) * packed_f[p, 5]
    if table[(i0 // BLOCK) * packed_i[p, 5] + i1 // BLOCK + packed_i[p, 6]] > slack:
        return False
    return table[i0 * n1 + i1 + off] <= slack


@numba.njit(cache=True, nogil=True)
def _may_collide_rows(Q, packed_i, packed_f, table, out):
    for n in range(Q.shape[0]):
        for p in range(packed_i.shape[0]):
            out[n, p] = pair_maybe(Q, n, p, packed_i, packed_f, table)


@numba.njit(cache=True, nogil=True, inline="always")
def may_collide_row(Q, n, packed_i, packed_f, table) -> bool:
    """True when any tabulated pair may be in contact at configuration Q[n]: `may_collide` for one row."""
    for p in range(packed_i.shape[0]):
        if pair_maybe(Q, n, p, packed_i, packed_f, table):
            return True
    return False
