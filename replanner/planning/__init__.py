"""The planning room: OMPL over the joint space within a deadline, IK for pose goals, a background plan worker."""

from ..collision.paddings import padded_checker
from .ik import IKError, IKResult, solve_ik
from .planner import PLANNERS, Planner, planner_class
from .types import (
    GoalInvalid,
    JointGoal,
    NoSolution,
    PlanningCanceled,
    PlanningError,
    PlanResult,
    PoseGoal,
    SeparationInfeasible,
    StartInvalid,
    UnknownPlanner,
)
from .worker import InlineWorker, JobPurpose, PlanAnswer, PlanJob, PlanWorker, ProcessWorker, ThreadWorker

__all__ = [
    "PLANNERS",
    "GoalInvalid",
    "IKError",
    "IKResult",
    "InlineWorker",
    "JobPurpose",
    "JointGoal",
    "NoSolution",
    "PlanAnswer",
    "PlanJob",
    "PlanResult",
    "PlanWorker",
    "Planner",
    "PlanningCanceled",
    "PlanningError",
    "PoseGoal",
    "ProcessWorker",
    "SeparationInfeasible",
    "StartInvalid",
    "ThreadWorker",
    "UnknownPlanner",
    "padded_checker",
    "planner_class",
    "solve_ik",
]
