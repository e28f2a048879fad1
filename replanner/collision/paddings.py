"""Checkers of one world at other paddings against known objects: a goal may ask for less than the configured
padding (grasps sit within a centimetre of their objects); its plan and the monitor's look at its path use it."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..errors import InvalidInputError
from .exact import CollisionChecker, Contact, ContactKind

MIN_RESOLUTION = 0.002  # [m] the finest path resolution a small padding asks for (padding 0: within 1 mm)
MAX_PADDING = 0.2  # [m]
KEEP = 4  # checkers of other paddings kept (each builds its padded geometry once per scene)


def check_padding(padding) -> float:
    """`padding` [m] as a float, or a clear error naming the range."""
    if isinstance(padding, bool) or not (
        isinstance(padding, int | float) and math.isfinite(padding) and 0.0 <= padding <= MAX_PADDING
    ):
        raise InvalidInputError(f"padding must be a number of metres in [0, {MAX_PADDING}], got {padding!r}")
    return float(padding)


def padded_checker(checker: CollisionChecker, padding: float) -> CollisionChecker:
    """A checker of the same world with another padding against known objects (the map keeps its own); its path
    resolution follows the padding, at most 2 x padding, so the unpadded robot stays clear between two checks."""
    padding = check_padding(padding)
    return CollisionChecker(
        checker.robot,
        checker.world,
        padding=padding,
        map_padding=checker.map_padding,
        path_resolution=min(checker.path_resolution, max(2.0 * padding, MIN_RESOLUTION)),
        allowed_contacts=checker.allowed_contacts,
        check_limits=checker.check_limits,
    )


def with_map_margin(checker: CollisionChecker, margin: float) -> CollisionChecker:
    """The checker plans are made with: `checker`'s world and paddings, `margin` [m] more from the map (the checker
    itself for 0). A path is clear of the map by its padding where it is checked, by that less half its resolution
    in between: the monitor samples it elsewhere, and a margin of half the resolution keeps it clear for the monitor
    (docs/architecture.md: what that costs and why the default is 0)."""
    if margin == 0:
        return checker
    return CollisionChecker(
        checker.robot,
        checker.world,
        padding=checker.padding,
        map_padding=checker.map_padding + float(margin),
        path_resolution=checker.path_resolution,
        allowed_contacts=checker.allowed_contacts,
        check_limits=checker.check_limits,
    )


class Paddings:
    """`checker` at other paddings, built on demand (their geometry too: before any deadline), the last KEEP kept.

    Args:
        checker: the configured checker (padding None or its own padding gives it back).
        wrap: what is handed out for a padded checker (e.g. the planning layer in front of it).
    """

    def __init__(self, checker: CollisionChecker, wrap: Callable[[CollisionChecker], object] = lambda c: c):
        self.checker, self.wrap = checker, wrap
        self._kept: dict[tuple[float, float], object] = {}

    def get(self, padding: float | None, base=None, map_margin: float = 0.0):
        """The checker for `padding` [m] and `map_margin` [m] more from the map (see `with_map_margin`); `base` is
        handed out for the configured one (default: the checker)."""
        if (padding is None or padding == self.checker.padding) and map_margin == 0:
            return self.checker if base is None else base
        padding = self.checker.padding if padding is None else check_padding(padding)
        if not (math.isfinite(map_margin) and 0.0 <= map_margin < 1.0):
            raise InvalidInputError(f"map_margin must be in [0, 1) m, got {map_margin!r}")
        key = (padding, float(map_margin))
        found = self._kept.pop(key, None)
        if found is None:
            c = self.checker if padding == self.checker.padding else padded_checker(self.checker, padding)
            found = self.wrap(with_map_margin(c, map_margin))
            # build the padded geometry now; a writable copy of home: the argument type the kernels were warmed up with
            found.is_valid(np.array(self.checker.robot.home))
        self._kept[key] = found  # most recently used last
        while len(self._kept) > KEEP:
            self._kept.pop(next(iter(self._kept)))
        return found


def within_padding(checker: CollisionChecker, q: np.ndarray, contact: Contact, what: str) -> str:
    """Why q is refused: "<what> is in collision: ...", or, when only the padding is touched, how far it is."""
    if contact.kind is ContactKind.WORLD and checker.padding > 0:
        gap = checker.clearance(q, max_distance=checker.padding)
        if gap.distance > 0 and gap.body is not None:
            return (
                f"{what} is within the padding: {gap.body} is {gap.distance * 1e3:.1f} mm from {gap.obstacle!r}, "
                f"inside the {checker.padding * 1e3:.1f} mm padding; plan with padding < {gap.distance:.4f} m to "
                "reach it"
            )
    return f"{what} is in collision: {contact}"
