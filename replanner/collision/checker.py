"""What a collision checker answers: the `Checker` protocol, which the exact checker (FCL) and the fast layer in front
of it both satisfy, so that a caller never asks which one it holds, and the verdicts it returns."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

from ..model.geometry import Shape

if TYPE_CHECKING:
    from ..model.robot import RobotModel
    from ..world.scene import World

OCTREE = "octree"  # the occupancy map's name in allowed contacts, contacts and clearances


class ContactKind(str, Enum):
    """Why a configuration is invalid; a str, so `kind == "octree"` and JSON keep working."""

    WORLD = "world"  # a static object
    OCTREE = "octree"  # the occupancy map
    SELF = "self"  # another robot link or an attached object
    LIMITS = "limits"  # not a contact: a joint outside its position limits

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Contact:
    """Why a configuration is invalid: `body` (robot link or attached object) touches `other`.

    For LIMITS, `body` is the joint outside its limits and `other` is empty.
    """

    kind: ContactKind
    body: str
    other: str
    near: tuple[float, float, float] | None = None  # world point of an octree contact (to find the voxels)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", ContactKind(self.kind))  # a plain string still names a valid kind

    def __str__(self) -> str:
        if self.kind is ContactKind.LIMITS:
            return f"joint {self.body} is outside its limits"
        if self.kind is ContactKind.OCTREE:
            where = "" if self.near is None else " near ({:.3f}, {:.3f}, {:.3f})".format(*self.near)
            return f"{self.body} collides with the occupancy map{where}"
        what = "object" if self.kind is ContactKind.WORLD else "link"
        return f"{self.body} collides with {what} {self.other!r}"


@dataclass(frozen=True)
class Clearance:
    """Minimum distance [m] between the robot (unpadded) and the world, and who is closest.

    `distance` is capped at the query's `max_distance`; it is 0 or negative in contact.
    """

    distance: float
    body: str | None
    obstacle: str | None
    point_on_robot: np.ndarray | None
    point_on_obstacle: np.ndarray | None


@dataclass(frozen=True)
class PathCheck:
    """Result of a path check: `segment` i means between waypoints i and i+1, at `fraction` in [0, 1]."""

    valid: bool
    checked: int
    segment: int = -1
    fraction: float = 0.0
    q: np.ndarray | None = None
    contact: Contact | None = None


class BodyPoses(NamedTuple):
    """The bodies a checker tests, in its order, and their poses at some configurations."""

    names: tuple[str, ...]  # as in `Contact.body`: the link, or "attached:<object>"
    links: tuple[str, ...]  # the link each body is fixed to
    shapes: tuple[Shape, ...]  # unpadded, in the body frame
    poses: np.ndarray  # T_base_body (..., B, 4, 4)


class Checker(Protocol):
    """Validity of configurations, motions and paths of `robot` in `world`, with `padding` [m] from known objects and
    `map_padding` from the occupancy map; motions and paths are sampled so no robot point moves more than their
    resolution [m] between two checked configurations (`path_resolution` by default)."""

    robot: RobotModel
    world: World
    padding: float
    map_padding: float
    path_resolution: float

    @property
    def exact(self) -> ExactChecker:
        """The exact checker whose verdicts these are (itself, for the exact one): the last word on a path."""
        ...

    def ready(self) -> bool:
        """Whether what the world's present version needs is built: a check now builds nothing first."""
        ...

    def prepare(self) -> None:
        """Build what the world's present version needs, now (between jobs, not inside a deadline)."""
        ...

    def warm(self) -> None:
        """Compile and build everything a first check needs, now (before the first deadline)."""
        ...

    def is_valid(self, q) -> bool:
        """Whether configuration q (dof,) [rad] is within limits and clear."""
        ...

    def is_valid_batch(self, Q) -> np.ndarray:
        """Validity (N,) of configurations Q (N, dof)."""
        ...

    def check(self, q) -> Contact | None:
        """None if q is valid, else the first contact found."""
        ...

    def motion_valid(self, a: np.ndarray, b: np.ndarray, resolution: float, given: int = 0) -> bool:
        """Whether the straight motion a -> b is clear, checked every `resolution` [m] (0: a alone). `given`: ends the
        caller knows clear in this world (1: a, 2: b, 3: both), which a checker may skip."""
        ...

    def path_valid(self, waypoints, resolution: float | None = None) -> bool:
        """Whether the straight segments between waypoints (M, dof) are clear."""
        ...

    def clearance(self, q, max_distance: float = 1.0) -> Clearance:
        """The unpadded robot's least distance [m] from the world at q, capped at `max_distance`."""
        ...


class ExactChecker(Checker, Protocol):
    """A checker whose verdicts are FCL's (`CollisionChecker`): what the last word on a path needs besides."""

    def interpolate(self, waypoints, resolution: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The configurations (M, dof) a path check tests, and where each lies (segment + fraction)."""
        ...

    def is_valid_batch(self, Q, split: bool = False, octree_only: bool = False) -> np.ndarray:
        """Validity (N,) of configurations Q (N, dof); `split`: a large batch's broadphase on two threads."""
        ...

    def all_valid(self, Q) -> bool:
        """Whether every configuration of Q (N, dof) is valid; stops at the first invalid one."""
        ...
