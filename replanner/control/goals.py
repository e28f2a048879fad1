"""Goals, their handles and results: what a client asks the controller for and what it gets back."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..collision.paddings import check_padding
from ..errors import InvalidInputError, ReplannerError
from ..planning.planner import planner_class
from ..planning.types import JointGoal, PoseGoal

MAX_ID_LENGTH = 128


class GoalStatus(str, Enum):
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELED = "canceled"
    PREEMPTED = "preempted"


class GoalRejected(ReplannerError):
    """A goal was not accepted; the controller's state is unchanged."""


def _number(name: str, value, lo: float, hi: float, lo_open: bool = True) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or not ((value > lo if lo_open else value >= lo) and value <= hi):
        bracket = "(" if lo_open else "["
        raise InvalidInputError(f"{name} must be a number in {bracket}{lo:g}, {hi:g}], got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Goal:
    """A motion request, checked when it is made.

    Args:
        id: the client's name for it (1 to 128 characters).
        target: a JointGoal (configuration [rad]) or a PoseGoal (a link's pose in the base frame).
        planner: OMPL planner name; None: the configured default.
        deadline: planning budget [s], retries included; None: the configured default.
        velocity_scale, acceleration_scale: shares (0, 1] of the robot's limits.
        padding: [m] from known objects, for this goal's plans and the monitor's look at its path (grasps sit
            within a centimetre of their objects); None: the configured collision.padding.
    """

    id: str
    target: JointGoal | PoseGoal
    planner: str | None = None
    deadline: float | None = None
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    padding: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id or len(self.id) > MAX_ID_LENGTH:
            raise InvalidInputError(f"goal id must be a non-empty string of at most {MAX_ID_LENGTH} characters")
        if not isinstance(self.target, JointGoal | PoseGoal):
            raise InvalidInputError(f"goal target must be a JointGoal or a PoseGoal, got {type(self.target).__name__}")
        if self.planner is not None:
            planner_class(self.planner)
        if self.deadline is not None:
            object.__setattr__(self, "deadline", _number("deadline [s]", self.deadline, 0.0, 600.0))
        object.__setattr__(self, "velocity_scale", _number("velocity_scale", self.velocity_scale, 0.0, 1.0))
        object.__setattr__(self, "acceleration_scale", _number("acceleration_scale", self.acceleration_scale, 0.0, 1.0))
        if self.padding is not None:
            object.__setattr__(self, "padding", check_padding(self.padding))

    @classmethod
    def joints(cls, id: str, q, **kw) -> Goal:
        """A joint-space goal: configuration q [rad]."""
        return cls(id, JointGoal(np.asarray(q, dtype=float)), **kw)


@dataclass(frozen=True)
class GoalResult:
    goal_id: str
    status: GoalStatus
    reason: str
    stamp: float


class GoalHandle:
    """The caller's view of a submitted goal: accepted (with its goal configuration) or rejected, then a result."""

    def __init__(self, goal: Goal):
        self.goal = goal
        self.q_goal: np.ndarray | None = None
        self.rejection: str | None = None
        self._decided = threading.Event()
        self._done = threading.Event()
        self._result: GoalResult | None = None

    @property
    def id(self) -> str:
        return self.goal.id

    @property
    def result(self) -> GoalResult | None:
        return self._result

    @property
    def active(self) -> bool:
        """Accepted and not finished."""
        return self.q_goal is not None and self._result is None

    def accepted(self, timeout: float | None = None) -> np.ndarray:
        """The goal configuration once the controller accepted the goal; raises GoalRejected with the reason."""
        if not self._decided.wait(timeout):
            raise GoalRejected(f"goal {self.id!r}: the controller did not answer within {timeout} s")
        if self.rejection is not None:
            raise GoalRejected(f"goal {self.id!r} rejected: {self.rejection}")
        return self.q_goal

    def wait(self, timeout: float | None = None) -> GoalResult | None:
        """The result, or None if it is not there within `timeout` [s]."""
        self._done.wait(timeout)
        return self._result

    # the controller's side
    def accept(self, q_goal: np.ndarray) -> None:
        self.q_goal = q_goal
        self._decided.set()

    def reject(self, reason: str) -> None:
        self.rejection = reason
        self._decided.set()

    def finish(self, result: GoalResult) -> bool:
        """Record the result once; False if there already was one."""
        if self._result is not None:
            return False
        self._result = result
        self._done.set()
        return True
