"""The control room: the state machine that owns every decision, the goals it executes, the commands it sends."""

from .controller import Controller
from .driver import JointState, KinematicDriver
from .goals import Goal, GoalHandle, GoalRejected, GoalResult, GoalStatus
from .history import TransitionRecord
from .inbox import Input
from .moves import Moves
from .states import State
from .timeline import Timeline

__all__ = [
    "Controller",
    "Goal",
    "GoalHandle",
    "GoalRejected",
    "GoalResult",
    "GoalStatus",
    "Input",
    "JointState",
    "KinematicDriver",
    "Moves",
    "State",
    "Timeline",
    "TransitionRecord",
]
