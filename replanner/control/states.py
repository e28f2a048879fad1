"""The controller's states and the edges between them (the KineoWorks reactive-planning paper's four, and HOLDING for
wait-and-resume)."""

from __future__ import annotations

from enum import Enum


class State(str, Enum):
    """A state; the machine (`transitions`) names it by the member's name, observers read its value."""

    WAITING = "WAITING"
    PLANNING = "PLANNING"
    MONITORING = "MONITORING"
    PENDING = "MONITORING_WITH_PLANNING_PENDING"
    HOLDING = "HOLDING"


def edges() -> list[dict]:
    """The transitions table: every trigger, from which states, to which."""
    W, P, M, PD, H = State
    busy = [P, M, PD, H]
    return [
        {"trigger": "plan", "source": [W, P, M, PD, H], "dest": P},
        {"trigger": "plan_failed", "source": P, "dest": W},
        {"trigger": "start_motion", "source": [P, H], "dest": M},
        {"trigger": "blocked", "source": M, "dest": PD},
        {"trigger": "path_clear", "source": PD, "dest": M},
        {"trigger": "spliced", "source": PD, "dest": M},
        {"trigger": "brake_and_hold", "source": [M, PD], "dest": H},
        {"trigger": "brake_and_abort", "source": [M, PD], "dest": W},
        {"trigger": "resume", "source": H, "dest": M},
        {"trigger": "give_up", "source": H, "dest": W},
        {"trigger": "succeeded", "source": [M, PD], "dest": W},
        {"trigger": "failed", "source": busy, "dest": W},
        {"trigger": "canceled", "source": busy, "dest": W},
        {"trigger": "fault", "source": busy, "dest": W},
    ]
