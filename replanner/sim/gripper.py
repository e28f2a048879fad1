"""The suction gripper and the part it carries: the part rests on a bin, follows the tip while held, and settles
straight down onto whatever is below it when let go."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pybullet as pb

from ..errors import InvalidInputError
from ..model.geometry import Box
from ..model.transforms import make_transform
from .bodies import pose_list, set_pose
from .cell import Cell
from .config import TaskConfig


class SuctionGripper:
    """Holds the part when the tip is within `grasp_gap` (+3 cm) of its top; the part starts on the first bin.

    Events: `grasped` (the bin, the gap [m]) and `placed` (the object it came to rest on, the one it was picked
    from, how far it dropped [m]).

    Args:
        cell: the live world; its `part` body is the part.
        task: the part's size, the bins, the grasp gap.
        event: records a ground-truth event, `event(kind, stamp, **fields)`.
    """

    def __init__(self, cell: Cell, task: TaskConfig, event: Callable[..., None]):
        self.cell, self.task, self.event = cell, task, event
        self.shape: Box = cell.part_shape
        self.pose = self._rest_on(task.bins[0], self.shape)  # T_base_part
        set_pose(cell.client, cell.part, self.pose)
        self.held: np.ndarray | None = None  # T_tip_part while held
        self.part_in: str | None = task.bins[0]  # the object the part rests on (None: the floor or nothing)

    @property
    def holding(self) -> bool:
        return self.held is not None

    def _rest_on(self, obj: str, shape: Box) -> np.ndarray:
        """Pose of `shape` resting on the middle of the top face of static object `obj`."""
        aabb = pb.getAABB(self.cell.static[obj], physicsClientId=self.cell.client)
        lo, hi = np.array(aabb[0]), np.array(aabb[1])
        c = (lo + hi) / 2
        margin = 0.001  # pybullet's AABBs include its collision margin
        return make_transform((c[0], c[1], hi[2] - margin + shape.size[2] / 2))

    def follow_tip(self) -> None:
        """A held part moves with the tip (call after each physics step)."""
        if self.held is not None:
            self.pose = self.cell.tip_pose() @ self.held
            set_pose(self.cell.client, self.cell.part, self.pose)

    def command(self, request: dict) -> dict:
        """`{"command": "grasp"}` or `{"command": "release"}`; raises InvalidInputError saying why it cannot."""
        cmd = request.get("command")
        tip = self.cell.tip_pose()
        t = time.time()
        if cmd == "grasp":
            return self._grasp(tip, t)
        if cmd == "release":
            return self._release(t)
        raise InvalidInputError(f"unknown command {cmd!r}; use 'grasp' or 'release'")

    def _grasp(self, tip: np.ndarray, t: float) -> dict:
        if self.held is not None:
            raise InvalidInputError("already holding the part; release it first")
        top = self.pose[:3, 3] + self.pose[:3, 2] * self.shape.size[2] / 2
        gap = float(np.linalg.norm(top - tip[:3, 3]))
        reach = self.task.grasp_gap + 0.03
        if gap > reach:
            raise InvalidInputError(f"no part within {reach:.3f} m of the tip (the part's top is {gap:.3f} m away)")
        self.held = np.linalg.inv(tip) @ self.pose
        self.event("grasped", t, bin=self.part_in, gap=round(gap, 4))
        return {"grasped": "part", "pose": pose_list(self.pose)}

    def _release(self, t: float) -> dict:
        if self.held is None:
            raise InvalidInputError("not holding anything")
        self.held = None
        cell = self.cell
        p = self.pose[:3, 3]
        bottom = p[2] - self.shape.size[2] / 2
        hits = pb.rayTest([p[0], p[1], bottom - 1e-4], [p[0], p[1], bottom - 1.0], physicsClientId=cell.client)
        below = {v: k for k, v in cell.static.items()}.get(hits[0][0])
        drop = (bottom - 1e-4 - hits[0][3][2]) if hits[0][0] >= 0 else 0.0
        self.pose = self.pose.copy()
        self.pose[2, 3] -= drop
        set_pose(cell.client, cell.part, self.pose)
        prev, self.part_in = self.part_in, below
        self.event("placed", t, on=below, picked_from=prev, drop=round(drop, 4))
        return {"released": "part", "on": below, "pose": pose_list(self.pose)}

    def report(self) -> dict:
        """The part as the `state` query reports it."""
        return {
            "part": pose_list(self.pose),
            "part_size": list(self.shape.size),
            "part_in": self.part_in,
            "grasped": self.holding,
            "bins": list(self.task.bins),
        }
