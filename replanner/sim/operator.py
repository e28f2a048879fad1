"""The operator: a seeded script that reaches into the cell (often where the arm is about to be), and the rules a
reaching hand keeps (it never pushes into the arm; it sets off only on a way in that keeps off it)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pybullet as pb

from ..control.timeline import Timeline
from .bodies import capsule_pose, set_pose
from .cell import Cell, ShadowWorld
from .config import OperatorConfig

OPERATOR_HZ = 100.0  # the hand moves in 1 cm steps at 1 m/s: each step costs two closest-point queries


class Operator:
    """Pause, reach in, linger, withdraw; the forearm (a capsule) in the live world follows the hand's tip.

    The hand never moves towards the arm once within `stop_distance` of it (it pauses), and it only sets
    off on a way in that keeps `keep_off_arm` from the arm: contacts and close calls are the arm's doing.

    Args:
        cfg: the script (rates, ranges, where the operator stands).
        rng: the script's random numbers (seeded by the caller).
        t0: when the script starts [s, wall clock]; the first intrusion comes `cfg.first_after` later.
        cell: the live world; the forearm is `cell.forearm`.
        shadow: where the arm's coming motion is tried against a forearm.
        timeline: the commanded motion.
        event: records a ground-truth event, `event(kind, stamp, **fields)`.
    """

    def __init__(
        self,
        cfg: OperatorConfig,
        rng: np.random.Generator,
        t0: float,
        *,
        cell: Cell,
        shadow: ShadowWorld,
        timeline: Timeline,
        event: Callable[..., None],
    ):
        self.cfg, self.rng = cfg, rng
        self.cell, self.shadow, self.timeline, self.event = cell, shadow, timeline, event
        self.phase = "idle"
        self.until = t0 + cfg.first_after
        self.tip: np.ndarray | None = None
        self.start = self.target = None
        self.aimed = False
        self.aim_deadline: float | None = None
        self.count = 0  # intrusions so far; events carry it as `intrusion`

    @property
    def present(self) -> bool:
        return self.tip is not None

    def direction(self) -> np.ndarray:
        d = self.target - np.asarray(self.cfg.stand)
        return d / np.linalg.norm(d)

    def pose(self) -> np.ndarray | None:
        """The forearm's pose (base frame), None while the operator is away."""
        if self.tip is None:
            return None
        return capsule_pose(self.tip, self.direction(), self.cfg.arm_length)

    def uniform(self, r) -> float:
        return float(self.rng.uniform(r[0], r[1]))

    # ------------------------------------------------------------------ the script
    def operate(self, t: float) -> None:
        """One step of the script at `t` [s]; call at OPERATOR_HZ."""
        oc = self.cfg
        step = oc.speed / OPERATOR_HZ
        if self.phase == "idle":
            if t >= self.until:
                self._choose_target(t)
        elif self.phase == "in":
            if self._move_hand(self.target, step):
                self.phase, self.until = "stay", t + self.uniform(oc.linger)
                self.event(
                    "operator_arrived", t, intrusion=self.count, aimed=self.aimed, at=self.target.round(3).tolist()
                )
        elif self.phase == "stay":
            if t >= self.until:
                self.phase = "out"
                self.event("operator_leaving", t, intrusion=self.count)
        elif self.phase == "out":
            if self._move_hand(self.start, step):
                self.tip = None
                self.phase, self.until = "idle", t + self.uniform(oc.interval)
                self.event("operator_left", t, intrusion=self.count)
        set_pose(self.cell.client, self.cell.forearm, self.pose())

    def _choose_target(self, t: float) -> None:
        oc = self.cfg
        stand = np.asarray(oc.stand, float)
        if self.aim_deadline is None:  # a new intrusion: aimed or not is rolled once
            self.count += 1
            self.aimed = bool(self.rng.random() < oc.in_path_probability)
            self.aim_deadline = t + oc.aim_patience
        target = self._aim(t, stand) if self.aimed else None
        if target is None and self.aimed and t < self.aim_deadline:
            self.until = t + 0.02  # wait for a motion the hand can meet
            return
        self.aim_deadline = None
        if target is None:
            self.aimed = False
            for _ in range(10):
                cand = self.rng.uniform(*np.asarray(oc.reach_region, float))
                if self._corridor_clear(stand, cand, t):
                    target = cand
                    break
        if target is None:
            self.phase, self.until = "idle", t + 0.5  # no way in that keeps off the arm now: try again shortly
            self.count -= 1
            return
        self.start = stand.copy()
        self.target = target
        self.tip = stand.copy()
        self.phase = "in"
        self.event("operator_entering", t, intrusion=self.count, aimed=self.aimed, target=target.round(3).tolist())

    # ------------------------------------------------------------------ the hand's rules
    def _move_hand(self, goal: np.ndarray, step: float) -> bool:
        """One step of the hand towards `goal` unless it would push into the arm; True once it is there."""
        d = goal - self.tip
        dist = float(np.linalg.norm(d))
        nxt = goal if dist <= step else self.tip + d / dist * step
        if self._keeps_off(nxt):
            self.tip = nxt
        return bool(np.array_equal(self.tip, goal))

    def _keeps_off(self, tip: np.ndarray) -> bool:
        """A person does not push into a robot: no step ends within `stop_distance` of the arm unless it leaves."""
        c, robot, body, oc = self.cell.client, self.cell.body, self.cell.forearm, self.cfg
        before = pb.getClosestPoints(robot, body, 0.5, physicsClientId=c)  # the capsule is where the hand is now
        set_pose(c, body, capsule_pose(tip, self.direction(), oc.arm_length))
        after = pb.getClosestPoints(robot, body, oc.stop_distance, physicsClientId=c)
        # a hand withdrawing along its own axis keeps its distance: rounding must not decide whether it may go on
        return not after or min(p[8] for p in after) >= min((p[8] for p in before), default=1.0) - 1e-9

    def _aim(self, t: float, stand: np.ndarray) -> np.ndarray | None:
        """The earliest point of the arm's motion the hand can block with `lead_time` to spare.

        Lead is from the hand's arrival to the arm's first coming within `stop_distance` of the forearm, the
        time a system has to see the hand, decide and act; points near where the motion ends are skipped.
        """
        oc, timeline = self.cfg, self.timeline
        seg = timeline.active(t)
        if seg is None or seg[0] + seg[1].duration < t + 0.5:
            return None
        start, traj = seg
        end = start + traj.duration
        link = self._reach_link()
        lead = self.uniform(oc.lead_time)
        goal = self.shadow.link_point(timeline.state(end)[0], link)
        for tt in np.arange(t + lead, end, 0.1):  # the arm's aimed point gets there at tt
            cand = self.shadow.link_point(timeline.state(tt)[0], link)
            arrive = t + float(np.linalg.norm(cand - stand)) / oc.speed
            if arrive + lead > tt or np.linalg.norm(cand - goal) < oc.goal_margin:
                continue
            if self._first_meeting(stand, cand, arrive, tt) - arrive >= lead and self._corridor_clear(stand, cand, t):
                return cand
        return None

    def _first_meeting(self, stand: np.ndarray, tip: np.ndarray, t0: float, t1: float) -> float:
        """When in [t0, t1] the commanded arm first comes within `stop_distance` of a forearm reaching to tip."""
        oc = self.cfg
        d = (tip - stand) / np.linalg.norm(tip - stand)
        self.shadow.place_forearm(capsule_pose(tip, d, oc.arm_length))
        for tt in np.arange(t0, t1, 0.04):
            if self.shadow.within(self.timeline.state(tt)[0], oc.stop_distance):
                return float(tt)
        return t1

    def _reach_link(self) -> str:
        """Where a reaching person meets the arm: the hand or the wrist."""
        tip_link = self.cell.robot.tip_link
        if self.shadow.has_link("panda_hand"):
            return str(self.rng.choice([tip_link, "panda_hand", "panda_link6"]))
        return tip_link

    def _corridor_clear(self, stand: np.ndarray, target: np.ndarray, t: float) -> bool:
        """The way in (stand → target) keeps `keep_off_arm` from the arm over the time it takes."""
        oc = self.cfg
        reach = float(np.linalg.norm(target - stand))
        if reach > 1.3 or reach < oc.arm_length:
            return False
        d = (target - stand) / reach
        for f in np.linspace(0.0, 1.0, 8):
            tip = stand + d * reach * f
            tt = t + reach * f / oc.speed
            self.shadow.place_forearm(capsule_pose(tip, d, oc.arm_length))
            if self.shadow.within(self.timeline.state(tt)[0], oc.keep_off_arm):
                return False
        return True
