"""Ground truth: contacts of the arm (and what it carries) as episodes, clearance to the operator, and whether the
operator's forearm is on the rest of the commanded path. The demo's metrics are computed from these events."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pybullet as pb

from ..control.timeline import Timeline
from .bodies import CONTACT_DEPTH
from .cell import Cell, ShadowWorld

PATH_HORIZON = 3.0  # [s] of the commanded motion checked against the forearm
PATH_STEP = 0.04  # [s] between the configurations checked


class GroundTruth:
    """Measures the live world and reports changes as events.

    Events: `contact` when an object starts touching the arm or the carried part (its first depth [m], the link or
    "part", whether a part was carried) and `contact_end` with the episode's deepest penetration [m];
    `entered_path` / `left_path` when the forearm starts / stops intersecting the commanded motion.

    Args:
        cell: the live world.
        shadow: where the commanded motion is tried against the forearm.
        timeline: the commanded motion.
        event: records a ground-truth event, `event(kind, stamp, **fields)`.
    """

    def __init__(self, cell: Cell, shadow: ShadowWorld, timeline: Timeline, event: Callable[..., None]):
        self.cell, self.shadow, self.timeline, self.event = cell, shadow, timeline, event
        self.on_path = False
        self.contacts: dict[str, float] = {}  # object -> deepest penetration in the current episode [m]

    def measure(self, t: float, *, holding: bool, part_in: str | None, operator: bool) -> float:
        """Contacts at `t` [s] of the robot (and the part while `holding` it; `part_in` is the object it lifts off)
        with anything; returns the clearance [m] to the forearm (inf while no `operator` is present)."""
        cell = self.cell
        c, robot = cell.client, cell.body
        touching: dict[str, tuple[float, str]] = {}  # object -> (depth, robot link or "part")

        def touch(name: str, depth: float, who: str) -> None:
            if name not in touching or depth < touching[name][0]:
                touching[name] = (depth, who)

        for name, body in [*cell.static.items(), ("part", cell.part)]:
            if name == "part" and holding:
                continue
            for pt in pb.getClosestPoints(robot, body, 0.0, physicsClientId=c):
                link = cell.link_name.get(pt[3], str(pt[3]))
                if pt[8] < -CONTACT_DEPTH and (link, name) not in cell.allowed:
                    touch(name, pt[8] + CONTACT_DEPTH, link)
        clearance = math.inf
        who = None
        if operator:
            for pt in pb.getClosestPoints(robot, cell.forearm, 1.0, physicsClientId=c):
                if pt[8] + CONTACT_DEPTH < clearance:
                    clearance, who = pt[8] + CONTACT_DEPTH, cell.link_name.get(pt[3], str(pt[3]))
            if holding:
                for pt in pb.getClosestPoints(cell.part, cell.forearm, 1.0, physicsClientId=c):
                    if pt[8] + CONTACT_DEPTH < clearance:
                        clearance, who = pt[8] + CONTACT_DEPTH, "part"
            if clearance < 0:
                touch("operator", clearance, who)
        if holding:
            for name, body in cell.static.items():
                if name == part_in:
                    continue  # lifting off the bin it rested on
                for pt in pb.getClosestPoints(cell.part, body, 0.0, physicsClientId=c):
                    if pt[8] < -CONTACT_DEPTH:
                        touch(name, pt[8] + CONTACT_DEPTH, "part")
        for name, (depth, link) in touching.items():
            if name not in self.contacts:
                self.event("contact", t, object=name, depth=round(depth, 4), link=link, carrying=holding)
            self.contacts[name] = min(self.contacts.get(name, 0.0), depth)
        for name in [n for n in self.contacts if n not in touching]:
            self.event("contact_end", t, object=name, deepest=round(self.contacts.pop(name), 4))
        return clearance

    def check_path(self, t: float, forearm: np.ndarray | None, intrusion: int) -> None:
        """Does the forearm (its pose, None while away) intersect the robot anywhere on the rest of the commanded
        motion from `t` [s]? `intrusion` numbers the operator's visit in the events."""
        on = False
        if forearm is not None:
            seg = self.timeline.active(t)
            if seg is not None:
                start, traj = seg
                end = start + traj.duration
                if end > t:
                    self.shadow.place_forearm(forearm)
                    for tt in np.arange(t, min(end, t + PATH_HORIZON) + 1e-9, PATH_STEP):
                        if self.shadow.penetrates(self.timeline.state(tt)[0]):
                            on = True
                            break
        if on != self.on_path:
            self.on_path = on
            self.event("entered_path" if on else "left_path", t, intrusion=intrusion)
