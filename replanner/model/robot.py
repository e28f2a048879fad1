"""Robot model from a URDF: joints and limits, batched forward kinematics, Jacobians, collision bodies.

Kinematics: every active joint gets an internal frame whose z axis is the joint axis, so the motion of a
revolute joint is a rotation about z and a prismatic one a translation along z. Fixed and passive joints
(a gripper held at a set opening) are folded into constant offsets at load time. FK of N configurations is
then a handful of vectorised numpy operations plus one matrix product per active joint.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InvalidInputError, RobotModelError, UnknownNameError
from ..sections import RobotConfig
from .kinematics import chain_frames, warm_up
from .urdf import CollisionBody, collision_bodies, load_urdf

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointLimits:
    """Per active joint: position [rad|m] from the URDF; velocity, acceleration, jerk from the robot config."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def __post_init__(self) -> None:
        for name in ("lower", "upper", "velocity", "acceleration", "jerk"):
            a = np.array(getattr(self, name), dtype=np.float64)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def within(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """True where every joint of q (..., dof) is inside [lower, upper] (with tolerance tol)."""
        q = np.asarray(q)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)


def _align_z(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z column is the unit vector `axis` (the shortest rotation taking z to it)."""
    a = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    c = float(a @ z)
    if c > 1 - 1e-12:
        return np.eye(3)  # exactly: the usual z axes must give bit-identical frames (the table cache key hashes them)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, a)
    return Rotation.from_rotvec(v / np.linalg.norm(v) * np.arctan2(np.linalg.norm(v), c)).as_matrix()


def _joint_motion(jtype: str, axis: np.ndarray, value: float) -> np.ndarray:
    """Transform of a revolute/prismatic joint at `value` about/along `axis` in the joint frame."""
    T = np.eye(4)
    unit = axis / np.linalg.norm(axis)
    if jtype in ("revolute", "continuous"):
        T[:3, :3] = Rotation.from_rotvec(unit * value).as_matrix()
    elif jtype == "prismatic":
        T[:3, 3] = unit * value
    return T


class RobotModel:
    """Kinematics and collision geometry of a serial or tree-shaped robot loaded from a URDF.

    Args:
        urdf_path: path to the URDF file.
        tip_link: link that Cartesian goals refer to.
        velocity_limits, acceleration_limits, jerk_limits: per active joint [rad/s, rad/s^2, rad/s^3].
        joints: active joints in the order q uses; default: movable joints from base to tip.
        base_link: root of the tree; default: the URDF's root. Poses are in this link's frame.
        passive_joints: positions of movable joints that are not planned (e.g. gripper fingers).
        home: rest configuration [rad]; default: mid-range clipped to 0.
        allowed_self_pairs: link pairs never checked against each other (adjacent links are skipped anyway).
        self_padding: minimum distance [m] two links must keep from each other (each is inflated by half).
        name: profile name.
    """

    def __init__(
        self,
        urdf_path: str | os.PathLike,
        *,
        tip_link: str,
        velocity_limits: Sequence[float],
        acceleration_limits: Sequence[float],
        jerk_limits: Sequence[float],
        joints: Sequence[str] | None = None,
        base_link: str | None = None,
        passive_joints: Mapping[str, float] | None = None,
        home: Sequence[float] | None = None,
        allowed_self_pairs: Iterable[tuple[str, str]] = (),
        self_padding: float = 0.0,
        name: str = "robot",
    ):
        self.name = name
        self.urdf_path = Path(urdf_path)
        robot = load_urdf(self.urdf_path)
        link_names_all = [link.name for link in robot.links]
        links_by_name = {link.name: link for link in robot.links}
        children: dict[str, list] = {n: [] for n in link_names_all}
        child_links = set()
        for j in robot.joints:
            children[j.parent].append(j)
            child_links.add(j.child)
        roots = [n for n in link_names_all if n not in child_links]
        self.base_link = base_link or roots[0]
        if self.base_link not in links_by_name:
            raise UnknownNameError("link", self.base_link, link_names_all)

        # links of the subtree under base_link, in topological order
        order: list[tuple[str, object | None]] = []
        stack: list[tuple[str, object | None]] = [(self.base_link, None)]
        while stack:
            link, via = stack.pop()
            order.append((link, via))
            for j in reversed(children[link]):
                stack.append((j.child, j))
        self.link_names: tuple[str, ...] = tuple(n for n, _ in order)
        if tip_link not in self.link_names:
            raise UnknownNameError("link", tip_link, self.link_names)
        self.tip_link = tip_link
        joint_by_name = {j.name: j for _, j in order if j is not None}
        movable = [n for n, j in joint_by_name.items() if j.type != "fixed"]
        for j in joint_by_name.values():
            if j.type in ("floating", "planar"):
                raise RobotModelError(f"joint {j.name!r} is {j.type}; only revolute, continuous, prismatic, fixed")

        if joints is None:
            chain: list[str] = []
            link = tip_link
            parent_joint = {v.child: v for _, v in order if v is not None}
            while link != self.base_link:
                j = parent_joint[link]
                if j.type != "fixed":
                    chain.append(j.name)
                link = j.parent
            joints = list(reversed(chain))
        for jn in joints:
            if jn not in movable:
                raise UnknownNameError("movable joint", jn, movable)
        if len(set(joints)) != len(joints):
            raise RobotModelError(f"joints listed twice: {sorted(j for j in joints if list(joints).count(j) > 1)}")
        self.joint_names: tuple[str, ...] = tuple(joints)
        self.dof = len(self.joint_names)
        passive_joints = dict(passive_joints or {})
        for jn in passive_joints:
            if jn not in movable or jn in self.joint_names:
                raise UnknownNameError("passive joint", jn, [m for m in movable if m not in self.joint_names])

        def _urdf_limits(j) -> tuple[float, float]:
            if j.type == "continuous" or j.limit is None or j.limit.lower is None:
                return -np.pi, np.pi
            return float(j.limit.lower), float(j.limit.upper)

        def _passive_value(jn: str) -> float:
            j = joint_by_name[jn]
            if j.mimic is not None:
                if j.mimic.joint in self.joint_names:
                    raise RobotModelError(f"joint {jn!r} mimics active joint {j.mimic.joint!r}: not supported")
                return j.mimic.multiplier * _passive_value(j.mimic.joint) + j.mimic.offset
            if jn in passive_joints:
                return float(passive_joints[jn])
            lo, hi = _urdf_limits(j)
            return float(np.clip(0.0, lo, hi))

        self.passive_joint_positions = {jn: _passive_value(jn) for jn in movable if jn not in self.joint_names}

        # fold the tree into active-joint frames
        idx_of_joint = {n: i for i, n in enumerate(self.joint_names)}
        F = np.zeros((self.dof, 4, 4))
        parent = np.full(self.dof, -1, dtype=np.int64)
        prismatic = np.zeros(self.dof, dtype=bool)
        link_frame = np.full(len(self.link_names), -1, dtype=np.int64)
        link_offset = np.zeros((len(self.link_names), 4, 4))
        joint_order: list[int] = []
        state: dict[str, tuple[int, np.ndarray]] = {self.base_link: (-1, np.eye(4))}
        for link, j in order:
            if j is not None:
                k, D = state[j.parent]
                origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
                axis = np.asarray(j.axis if j.axis is not None else [1.0, 0.0, 0.0], dtype=float)
                if j.name in idx_of_joint:
                    i = idx_of_joint[j.name]
                    A = np.eye(4)
                    A[:3, :3] = _align_z(axis)
                    F[i] = D @ origin @ A
                    parent[i] = k
                    prismatic[i] = j.type == "prismatic"
                    joint_order.append(i)
                    state[link] = (i, np.linalg.inv(A))
                elif j.type == "fixed":
                    state[link] = (k, D @ origin)
                else:
                    state[link] = (k, D @ origin @ _joint_motion(j.type, axis, self.passive_joint_positions[j.name]))
            li = self.link_names.index(link)
            link_frame[li], link_offset[li] = state[link]
        self._F, self._parent, self._prismatic = F, parent, prismatic
        self._joint_order = np.array(joint_order, dtype=np.int64)
        self._link_frame, self._link_offset = link_frame, link_offset
        # anc[k, j]: active joint j moves frame k (k == j or j is an ancestor of k)
        anc = np.zeros((self.dof, self.dof), dtype=bool)
        chain_len = np.full((self.dof, self.dof), -np.inf)
        for k in range(self.dof):
            m, length = k, 0.0
            while m >= 0:
                anc[k, m] = True
                chain_len[m, k] = length
                length += float(np.linalg.norm(F[m, :3, 3]))
                m = parent[m]
        self._frame_anc = anc
        self._chain_len = chain_len  # [j, k]: upper bound on the distance from joint j's origin to frame k's
        for arr in (F, parent, prismatic, link_frame, link_offset, anc, chain_len):
            arr.setflags(write=False)
        self._chain_parents = np.ascontiguousarray(parent[self._joint_order] + 1, dtype=np.int64)

        lower, upper = zip(*(_urdf_limits(joint_by_name[n]) for n in self.joint_names)) if self.dof else ((), ())
        try:
            self.limits = JointLimits(
                np.array(lower), np.array(upper), velocity_limits, acceleration_limits, jerk_limits
            )
        except ValueError as err:
            raise RobotModelError(f"limits must be numeric arrays: {err}") from err
        for name in ("velocity", "acceleration", "jerk"):
            arr = getattr(self.limits, name)
            if arr.shape != (self.dof,) or np.any(~(arr > 0)) or not np.all(np.isfinite(arr)):
                raise RobotModelError(
                    f"{name} limits need {self.dof} finite values > 0 (one per joint {list(self.joint_names)}), "
                    f"got {arr.tolist()}"
                )
        if home is None:
            home = np.clip(np.zeros(self.dof), self.limits.lower, self.limits.upper)
        self.home = self.check_q(home, "home")
        self.home.setflags(write=False)

        self.bodies: tuple[CollisionBody, ...] = tuple(
            collision_bodies(links_by_name, self.link_names, self.urdf_path.parent)
        )
        if not self.bodies:
            raise RobotModelError(f"URDF {self.urdf_path} has no collision geometry under {self.base_link!r}")
        self.self_padding = float(self_padding)
        self.self_body_padding = self.self_padding / 2  # per body, so a pair keeps self_padding apart
        self.self_collision_pairs = self._self_pairs(order, allowed_self_pairs)
        warm_up()  # the kinematics kernels compile now, not in the first check of a running motion

    @classmethod
    def from_config(cls, cfg: RobotConfig) -> RobotModel:
        """Build from a validated robot config section."""
        return cls(
            cfg.urdf,
            tip_link=cfg.tip_link,
            velocity_limits=cfg.velocity_limits,
            acceleration_limits=cfg.acceleration_limits,
            jerk_limits=cfg.jerk_limits,
            joints=cfg.joints,
            base_link=cfg.base_link,
            passive_joints=cfg.passive_joints,
            home=cfg.home,
            allowed_self_pairs=cfg.self_collision.allowed_pairs,
            self_padding=cfg.self_collision.padding,
            name=cfg.name,
        )

    # ------------------------------------------------------------------ geometry
    def _self_pairs(self, order, allowed: Iterable[tuple[str, str]]) -> np.ndarray:
        with_geometry = {b.link for b in self.bodies}
        parent_link = {link: j.parent for link, j in order if j is not None}

        def geometric_parent(link: str) -> str | None:
            p = parent_link.get(link)
            while p is not None and p not in with_geometry:
                p = parent_link.get(p)
            return p

        skip = set()
        for a, b in allowed:
            for n in (a, b):
                if n not in self.link_names:
                    raise UnknownNameError("link", n, self.link_names)
            skip.add(frozenset((a, b)))
        for link in with_geometry:
            p = geometric_parent(link)
            if p is not None:
                skip.add(frozenset((link, p)))
        pairs = []
        for i, bi in enumerate(self.bodies):
            for j in range(i + 1, len(self.bodies)):
                bj = self.bodies[j]
                fi = self._link_frame[self.link_index(bi.link)]
                fj = self._link_frame[self.link_index(bj.link)]
                if bi.link == bj.link or fi == fj or frozenset((bi.link, bj.link)) in skip:
                    continue  # same rigid frame or declared allowed
                pairs.append((i, j))
        out = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        out.setflags(write=False)
        return out

    # ------------------------------------------------------------------ names and checks
    def link_index(self, link: str) -> int:
        try:
            return self.link_names.index(link)
        except ValueError:
            raise UnknownNameError("link", link, self.link_names) from None

    def check_q(self, q, name: str = "q") -> np.ndarray:
        """q as a float array (..., dof); raises on wrong length or non-finite values (limits not checked)."""
        try:
            a = np.array(q, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInputError(f"{name} must be numbers, one per joint {list(self.joint_names)}") from None
        if a.ndim == 0 or a.shape[-1] != self.dof:
            raise InvalidInputError(
                f"{name} must have {self.dof} values (one per joint {list(self.joint_names)}), got shape {a.shape}"
            )
        if not np.all(np.isfinite(a)):
            raise InvalidInputError(f"{name} contains NaN or inf")
        return a

    def check_within_limits(self, q, name: str = "q", tol: float = 1e-9) -> np.ndarray:
        a = self.check_q(q, name)
        bad = np.flatnonzero((a < self.limits.lower - tol) | (a > self.limits.upper + tol)) if a.ndim == 1 else []
        if len(bad):
            i = int(bad[0])
            raise InvalidInputError(
                f"{name}: joint {self.joint_names[i]} = {a[i]:.4f} is outside its limits "
                f"[{self.limits.lower[i]:.4f}, {self.limits.upper[i]:.4f}]"
            )
        return a

    # ------------------------------------------------------------------ kinematics
    @property
    def chain(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The joint chain as compiled kernels take it (see `kernels.chain_frames`): F, prismatic, joints, parents."""
        return self._F, self._prismatic, self._joint_order, self._chain_parents

    def frames(self, Q: np.ndarray) -> np.ndarray:
        """Frames (N, 1 + dof, 4, 4) in the base frame for Q (N, dof): slot 0 is the base, slot 1 + j joint j's
        internal frame (z = its axis). Unchecked fast path; see `fk` for the checked public one."""
        Q = np.ascontiguousarray(Q, dtype=np.float64)
        out = np.empty((len(Q), self.dof + 1, 4, 4))
        return chain_frames(Q, *self.chain, out)

    def joint_frames(self, q) -> np.ndarray:
        """Internal active-joint frames (..., dof, 4, 4) in the base frame; z is each joint's axis."""
        q = np.asarray(q, dtype=np.float64)
        G = self.frames(q.reshape(-1, self.dof))[:, 1:]
        return G.reshape(q.shape[:-1] + (self.dof, 4, 4))

    def _link_transforms(self, frames: np.ndarray) -> np.ndarray:
        """Link frames (N, L, 4, 4) from `frames` (N, 1 + dof, 4, 4)."""
        return frames[:, self._link_frame + 1] @ self._link_offset

    def frame_offset(self, link: str) -> tuple[int, np.ndarray]:
        """(slot in `frames`, T_frame_link): the frame that carries `link` and the link's constant pose in it."""
        li = self.link_index(link)
        return int(self._link_frame[li]) + 1, self._link_offset[li]

    def fk(self, q) -> np.ndarray:
        """Poses of all links (..., L, 4, 4) in the base frame for q (..., dof) [rad|m]; order = link_names."""
        q = self.check_q(q)
        Q = q.reshape(-1, self.dof)
        T = self._link_transforms(self.frames(Q))
        return T.reshape(q.shape[:-1] + T.shape[1:])

    def link_pose(self, q, link: str) -> np.ndarray:
        """Pose (..., 4, 4) of one link in the base frame."""
        return self.fk(q)[..., self.link_index(link), :, :]

    def _jacobians_at(self, frames: np.ndarray, li: int, p: np.ndarray) -> np.ndarray:
        """Geometric Jacobians (N, 6, dof) of points p (N, 3) [m] carried by link li, from `frames` (N, 1 + dof)."""
        G = frames[:, 1:]
        z, o = G[:, :, :3, 2], G[:, :, :3, 3]
        k = self._link_frame[li]
        mask = self._frame_anc[k] if k >= 0 else np.zeros(self.dof, dtype=bool)
        J = np.zeros((len(frames), 6, self.dof))
        rev = ~self._prismatic
        lin = np.where(rev[None, :, None], np.cross(z, p[:, None, :] - o), z)
        J[:, :3] = np.swapaxes(lin, 1, 2) * mask
        J[:, 3:] = np.swapaxes(z, 1, 2) * (mask & rev)
        return J

    def origins_and_jacobians(self, Q: np.ndarray, links) -> tuple[np.ndarray, np.ndarray]:
        """The origins (N, n, 3) [m] and geometric Jacobians (N, n, 6, dof) of n links at configurations Q (N, dof),
        from one forward kinematics pass (rows as `jacobian`)."""
        Q = np.asarray(Q, dtype=np.float64).reshape(-1, self.dof)
        frames = self.frames(Q)
        T = self._link_transforms(frames)
        idx = [self.link_index(link) for link in links]
        origins = T[:, idx][..., :3, 3]
        return origins, np.stack([self._jacobians_at(frames, li, origins[:, n]) for n, li in enumerate(idx)], axis=1)

    def jacobian(self, q, link: str | None = None, point_in_link=None) -> np.ndarray:
        """Geometric Jacobian (..., 6, dof) of a point on a link: rows [v_x, v_y, v_z, w_x, w_y, w_z] in the base frame.

        Args:
            q: configuration(s) (..., dof) [rad|m].
            link: link name; default: the tip link.
            point_in_link: point (3,) in the link frame [m]; default: the link origin.
        """
        q = self.check_q(q)
        li = self.link_index(link or self.tip_link)
        frames = self.frames(q.reshape(-1, self.dof))
        T = self._link_transforms(frames)[:, li]
        p = T[:, :3, 3]
        if point_in_link is not None:
            p = p + T[:, :3, :3] @ np.asarray(point_in_link, dtype=float)
        return self._jacobians_at(frames, li, p).reshape(q.shape[:-1] + (6, self.dof))

    # ------------------------------------------------------------------ helpers for the checker
    def link_frame_index(self, link: str) -> int:
        """Active joint whose internal frame carries the link (-1: the base)."""
        return int(self._link_frame[self.link_index(link)])

    def reach(self, link: str, radius: float) -> np.ndarray:
        """Per active joint: upper bound [m] on how far a point within `radius` of the link origin is from the joint.

        Summed with |dq| it bounds how far any such point moves for a joint-space step dq.
        """
        li = self.link_index(link)
        return self.frame_reach(
            int(self._link_frame[li]) + 1, float(np.linalg.norm(self._link_offset[li][:3, 3])) + radius
        )

    @property
    def prismatic(self) -> np.ndarray:
        """(dof,) bool, read-only: which active joints slide (the rest turn)."""
        return self._prismatic

    def kinematics_digest(self) -> bytes:
        """The chain's geometry as bytes (joint frames, link offsets, passive joints' positions): equal for robots
        whose links move alike, so what is computed from it can be cached under it."""
        parts = [np.ascontiguousarray(a).tobytes() for a in (self._F, self._link_offset)]
        return b"".join(parts) + repr(sorted(self.passive_joint_positions.items())).encode()

    @property
    def moved_by(self) -> np.ndarray:
        """(dof, dof) bool, read-only: [k, j] when active joint j moves joint k's frame (k == j or j before k)."""
        return self._frame_anc

    def frame_reach(self, slot: int, radius: float) -> np.ndarray:
        """`reach` of the points within `radius` [m] of the origin of frame `slot` (a slot of `frames`: 0 the base)."""
        k = slot - 1
        out = np.zeros(self.dof)
        if k < 0:
            return out
        for j in range(self.dof):
            if self._frame_anc[k, j]:
                out[j] = self._chain_len[j, k] + radius if not self._prismatic[j] else 1.0
        return out

    def random_q(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Uniform random configurations within the position limits, (n, dof) or (dof,)."""
        size = (self.dof,) if n is None else (n, self.dof)
        return rng.uniform(self.limits.lower, self.limits.upper, size=size)

    def __repr__(self) -> str:
        return f"RobotModel({self.name!r}, dof={self.dof}, links={len(self.link_names)}, bodies={len(self.bodies)})"
