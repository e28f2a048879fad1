"""The world the robot moves in: named static objects, objects attached to robot links, and an occupancy map.

Edits are copy-on-write: each edit publishes a new immutable `WorldSnapshot`, so a checker that took a
snapshot keeps a consistent scene while another thread edits the world or swaps the occupancy map.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np

from ..errors import InvalidInputError, UnknownNameError, WorldError
from ..model.geometry import Shape
from ..model.robot import RobotModel
from ..model.transforms import check_transform, invert_transform
from .kernels import warm_up
from .occupancy import OccupancyMap


@dataclass(frozen=True, eq=False)
class WorldObject:
    """A static object: `pose` is T_base_object (4x4)."""

    name: str
    shape: Shape
    pose: np.ndarray


@dataclass(frozen=True, eq=False)
class Attachment:
    """An object carried by a robot link: T_link_object places it; `touch_links` may touch it (e.g. fingers).

    `support`: static objects it may touch until it has left them (the table it was picked from).
    """

    name: str
    shape: Shape
    link: str
    T_link_object: np.ndarray
    touch_links: frozenset[str] = field(default_factory=frozenset)
    support: frozenset[str] = field(default_factory=frozenset)


@dataclass(frozen=True, eq=False)
class WorldSnapshot:
    """One consistent state of the world. `version` changes on every static edit, `occupancy` may change alone."""

    objects: MappingProxyType
    attachments: MappingProxyType
    occupancy: OccupancyMap | None
    version: int


def _frozen(T: np.ndarray, name: str) -> np.ndarray:
    a = check_transform(T, name).copy()
    a.setflags(write=False)
    return a


class World:
    """Static objects, attachments and the occupancy map, for one robot.

    Args:
        robot: the robot whose links objects can be attached to.
    """

    def __init__(self, robot: RobotModel):
        warm_up()  # the map's kernels compile now, not when the first camera frame arrives mid-motion
        self.robot = robot
        self._lock = threading.Lock()
        self._snap = WorldSnapshot(MappingProxyType({}), MappingProxyType({}), None, 0)
        self._history: deque[tuple[float, WorldSnapshot]] = deque([(-math.inf, self._snap)], maxlen=64)

    # ------------------------------------------------------------------ reading
    def snapshot(self) -> WorldSnapshot:
        """The current state; never changes after it is returned."""
        return self._snap

    def scene_at(self, stamp: float) -> WorldSnapshot:
        """The objects and attachments as they were at `stamp` (time.time() clock; the oldest kept if earlier).

        A camera frame is filtered with the scene of the moment it was taken: a part let go after the frame
        was rendered is still the robot's in it.
        """
        hist = list(self._history)
        for t, snap in reversed(hist):
            if t <= stamp:
                return snap
        return hist[0][1]

    @property
    def objects(self) -> MappingProxyType:
        return self._snap.objects

    @property
    def attachments(self) -> MappingProxyType:
        return self._snap.attachments

    @property
    def occupancy(self) -> OccupancyMap | None:
        return self._snap.occupancy

    def names(self) -> list[str]:
        s = self._snap
        return sorted([*s.objects, *s.attachments])

    # ------------------------------------------------------------------ editing
    def _publish(self, objects=None, attachments=None, occupancy=..., bump: bool = True) -> None:
        s = self._snap
        self._snap = WorldSnapshot(
            MappingProxyType(dict(s.objects if objects is None else objects)),
            MappingProxyType(dict(s.attachments if attachments is None else attachments)),
            s.occupancy if occupancy is ... else occupancy,
            s.version + 1 if bump else s.version,
        )
        if bump:  # without the map: the history must not keep old maps alive
            self._history.append((time.time(), replace(self._snap, occupancy=None)))

    def _check_new_name(self, name: str) -> None:
        if not isinstance(name, str) or not name or len(name) > 128:
            raise InvalidInputError(f"object name must be a non-empty string of at most 128 characters, got {name!r}")
        if name in self._snap.objects or name in self._snap.attachments:
            raise WorldError(f"an object named {name!r} already exists; remove it first or choose another name")

    def add(self, name: str, shape: Shape, pose: np.ndarray) -> None:
        """Add a static object at pose T_base_object."""
        with self._lock:
            self._check_new_name(name)
            objects = dict(self._snap.objects)
            objects[name] = WorldObject(name, shape, _frozen(pose, f"pose of {name!r}"))
            self._publish(objects=objects)

    def move(self, name: str, pose: np.ndarray) -> None:
        """Move a static object to a new pose T_base_object."""
        with self._lock:
            obj = self._get_static(name)
            objects = dict(self._snap.objects)
            objects[name] = replace(obj, pose=_frozen(pose, f"pose of {name!r}"))
            self._publish(objects=objects)

    def remove(self, name: str) -> None:
        """Remove a static or attached object."""
        with self._lock:
            s = self._snap
            if name in s.objects:
                objects = dict(s.objects)
                del objects[name]
                self._publish(objects=objects)
            elif name in s.attachments:
                attachments = dict(s.attachments)
                del attachments[name]
                self._publish(attachments=attachments)
            else:
                raise UnknownNameError("object", name, self.names())

    def attach(
        self, name: str, link: str, q, touch_links: Iterable[str] | None = None, support: Iterable[str] = ()
    ) -> None:
        """Attach the static object `name` to `link`, keeping its pose relative to the link at configuration q.

        `touch_links` may touch the object without counting as a collision (default: the link itself and every
        link rigidly fixed to it, e.g. the gripper fingers). `support`: static objects the object rests on; it
        may touch them until `release_support` finds it clear of them (MoveIt's pick does the same).
        """
        with self._lock:
            obj = self._get_static(name)
            if self.robot.frame_offset(link)[0] == 0:
                raise WorldError(
                    f"{link} does not move (it is fixed to the base): an object on it is a static object; "
                    "attach to a link a joint moves"
                )
            T_base_link = self.robot.link_pose(self.robot.check_q(q, "q"), link)
            T_link_object = invert_transform(T_base_link) @ obj.pose
            touch = self._touch_links(link, touch_links)
            support = self._check_support(name, support)
            objects = dict(self._snap.objects)
            del objects[name]
            attachments = dict(self._snap.attachments)
            attachments[name] = Attachment(
                name, obj.shape, link, _frozen(T_link_object, "T_link_object"), touch, support
            )
            self._publish(objects=objects, attachments=attachments)

    def release_support(self, q, clearance: float) -> list[tuple[str, str]]:
        """Drop each support an attached object is now farther than `clearance` [m] from; returns (object, support)."""
        import fcl

        from ..model.geometry import padded_geometry

        s = self._snap
        if not any(a.support for a in s.attachments.values()):
            return []
        q = self.robot.check_q(q, "q")
        released = []
        for a in s.attachments.values():
            for sup in a.support:
                obj = s.objects.get(sup)
                if obj is not None:
                    T = self.robot.link_pose(q, a.link) @ a.T_link_object
                    oa = fcl.CollisionObject(padded_geometry(a.shape, 0.0)[0], fcl.Transform(T[:3, :3], T[:3, 3]))
                    ob = fcl.CollisionObject(
                        padded_geometry(obj.shape, 0.0)[0], fcl.Transform(obj.pose[:3, :3], obj.pose[:3, 3])
                    )
                    if fcl.distance(oa, ob, fcl.DistanceRequest(), fcl.DistanceResult()) <= clearance:
                        continue
                released.append((a.name, sup))
        if released:
            with self._lock:
                attachments = dict(self._snap.attachments)
                for name, sup in released:
                    if name in attachments:
                        attachments[name] = replace(attachments[name], support=attachments[name].support - {sup})
                self._publish(attachments=attachments)
        return released

    def attach_new(
        self,
        name: str,
        shape: Shape,
        link: str,
        T_link_object: np.ndarray,
        touch_links: Iterable[str] | None = None,
        support: Iterable[str] = (),
    ) -> None:
        """Create an object directly in the hand, at T_link_object (`support` as in `attach`)."""
        with self._lock:
            self._check_new_name(name)
            touch = self._touch_links(link, touch_links)
            support = self._check_support(name, support)
            attachments = dict(self._snap.attachments)
            attachments[name] = Attachment(name, shape, link, _frozen(T_link_object, "T_link_object"), touch, support)
            self._publish(attachments=attachments)

    def _check_support(self, name: str, support: Iterable[str]) -> frozenset[str]:
        support = [support] if isinstance(support, str) else list(support)
        for s_name in support:
            if s_name == name or s_name not in self._snap.objects:
                raise UnknownNameError("support object", s_name, sorted(set(self._snap.objects) - {name}))
        return frozenset(support)

    def detach(self, name: str, q) -> None:
        """Put an attached object back into the world where it is at configuration q."""
        with self._lock:
            s = self._snap
            if name not in s.attachments:
                raise UnknownNameError("attached object", name, sorted(s.attachments))
            att = s.attachments[name]
            pose = self.robot.link_pose(self.robot.check_q(q, "q"), att.link) @ att.T_link_object
            attachments = dict(s.attachments)
            del attachments[name]
            objects = dict(s.objects)
            objects[name] = WorldObject(name, att.shape, _frozen(pose, f"pose of {name!r}"))
            self._publish(objects=objects, attachments=attachments)

    def set_occupancy(self, occupancy: OccupancyMap | None) -> None:
        """Replace the occupancy map whole (None clears it)."""
        if occupancy is not None and not isinstance(occupancy, OccupancyMap):
            raise InvalidInputError(f"occupancy must be an OccupancyMap or None, got {type(occupancy).__name__}")
        with self._lock:
            self._publish(occupancy=occupancy, bump=False)

    def clear(self) -> None:
        """Remove every object, attachment and the occupancy map."""
        with self._lock:
            self._publish(objects={}, attachments={}, occupancy=None)

    # ------------------------------------------------------------------ helpers
    def _get_static(self, name: str) -> WorldObject:
        s = self._snap
        if name in s.attachments:
            raise WorldError(f"{name!r} is attached to {s.attachments[name].link}; detach it first")
        if name not in s.objects:
            raise UnknownNameError("static object", name, sorted(s.objects))
        return s.objects[name]

    def _touch_links(self, link: str, touch_links: Iterable[str] | None) -> frozenset[str]:
        r = self.robot
        frame = r.link_frame_index(link)
        if touch_links is None:
            return frozenset(n for n in r.link_names if r.link_frame_index(n) == frame)
        touch = set(touch_links) | {link}
        for n in touch:
            r.link_index(n)  # raises with the valid names
        return frozenset(touch)


def scene_from_config(cfg) -> list[tuple[str, Shape, np.ndarray]]:
    """(name, shape, pose) of the config's `scene:` objects."""
    from ..model.geometry import Box, Cylinder, Sphere
    from ..model.transforms import make_transform

    out = []
    for o in cfg.scene:
        if o.type == "box":
            shape = Box(size=tuple(o.size))
        elif o.type == "cylinder":
            shape = Cylinder(radius=o.radius, length=o.length)
        else:
            shape = Sphere(radius=o.radius)
        out.append((o.name, shape, make_transform(o.position, o.quat_xyzw)))
    return out


def world_boxes(objects) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World-aligned bounding boxes (lo, hi) of (name, shape, pose) objects."""
    from ..model.geometry import local_box

    out = {}
    for name, shape, pose in objects:
        c, h = local_box(shape)
        wc, wh = pose[:3, :3] @ c + pose[:3, 3], np.abs(pose[:3, :3]) @ h
        out[name] = (wc - wh, wc + wh)
    return out


def top_centers(objects) -> dict[str, np.ndarray]:
    """Centre of the top face of each (name, shape, pose) box, e.g. where a part is set down on a bin's floor."""
    from ..model.geometry import Box

    out = {}
    for name, shape, pose in objects:
        if isinstance(shape, Box):
            half = np.abs(pose[:3, :3]) @ (np.asarray(shape.size) / 2)  # of the world-aligned bounding box
            out[name] = pose[:3, 3] + np.array([0.0, 0.0, half[2]])
    return out
