"""A replan's first step along the arm's motion. A plan from a moving state knows nothing of the motion: its path may
start against it, and such a path cannot be spliced on (the arm would brake to a stop and plan again from rest). A
short first step along the motion lets the splice round that corner at speed instead."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InvalidInputError

LEAD_STEP = 0.05  # [rad] along the motion before the path turns (0.02 and 0.1 spliced fewer: docs/planning.md)


def check_heading(heading, robot) -> np.ndarray | None:
    """`heading` (dof,), the arm's joint velocity (any scale) as a unit vector; None for None or a standstill."""
    if heading is None:
        return None
    try:
        h = robot.check_q(heading, "heading")  # numbers, one per joint, finite
        ok = h.ndim == 1
    except InvalidInputError:
        ok = False
    if not ok:
        raise InvalidInputError(
            f"heading must be {robot.dof} finite joint velocities (the arm's motion), got {heading!r}"
        )
    norm = float(np.linalg.norm(h))
    return h / norm if norm > 1e-9 else None


def lead_along(W: np.ndarray, heading: np.ndarray, clear: Callable[[np.ndarray], bool]) -> np.ndarray:
    """W, or W with a first step of LEAD_STEP along `heading` (unit) when W starts against it and `clear` (a path ->
    bool: FCL's check at path resolution) finds the step and the way from it to W[1] free."""
    if heading @ (W[1] - W[0]) >= 0.0:
        return W
    led = np.vstack([W[:1], W[:1] + LEAD_STEP * heading, W[1:]])
    return led if clear(led[:3]) else W
