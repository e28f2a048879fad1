"""What planning answers: its errors (each with a short `reason` code) and results, and the goals it takes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..collision.exact import Contact
from ..errors import InvalidInputError, ReplannerError


class PlanningError(ReplannerError):
    """Planning failed; `reason` is a short code, the message says what to change."""

    reason = "failed"


class StartInvalid(PlanningError):
    reason = "start_invalid"

    def __init__(self, message: str, contact: Contact | None = None):
        self.contact = contact
        super().__init__(message)


class GoalInvalid(PlanningError):
    reason = "goal_invalid"

    def __init__(self, message: str, contact: Contact | None = None):
        self.contact = contact
        super().__init__(message)


class NoSolution(PlanningError):
    reason = "no_solution"


class SeparationInfeasible(PlanningError):
    """No path from the start keeps the protective separation from what the cameras see (the arm holds)."""

    reason = "separation"


class PlanningCanceled(PlanningError):
    reason = "canceled"


class UnknownPlanner(PlanningError, InvalidInputError):
    reason = "unknown_planner"


@dataclass(frozen=True)
class JointGoal:
    """A goal configuration [rad], one value per active joint."""

    q: np.ndarray


@dataclass(frozen=True)
class PoseGoal:
    """A goal pose of `link` in the base frame: position [m], quaternion (x, y, z, w), tolerances [m], [rad]."""

    link: str
    position: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    position_tolerance: float | None = None
    orientation_tolerance: float | None = None


@dataclass
class PlanResult:
    """A collision-free joint-space path (M, dof) from start to goal and how it was found.

    Times [s]: `search_time` the search, retries included; `simplify_time` the shortcutting; `total_time` the
    whole call (checks of start and goal, IK, search, simplification).
    """

    path: np.ndarray
    goal: np.ndarray
    planner: str
    attempts: int
    search_time: float
    simplify_time: float
    total_time: float
    direct: bool = False  # the straight line was free: no search needed
    raw_waypoints: int = 0
    slips: int = 0  # paths the coarse search found that FCL refused (each one grew the trees anew, finer)
