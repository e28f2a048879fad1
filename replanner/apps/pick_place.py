"""A pick-and-place loop over Zenoh: the service moves the arm, the simulator's suction gripper holds the part.

One cycle carries the part from one bin to the other (the next cycle carries it back): above the part, down to
it, grasp (and `scene/attach` with the bin as support), lift, above the other bin, down, release (and
`scene/detach`, then `scene/move` to where the part came to rest), up. Goals that fail are retried.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable

import numpy as np

from ..sim.config import TaskConfig
from ..transport.keys import sim_keys
from .client import Client, ServiceError

log = logging.getLogger(__name__)

DOWN = (1.0, 0.0, 0.0, 0.0)  # tip z axis pointing down (quat xyzw)


class Gripper:
    """The simulator's suction gripper (`<root>/sim/gripper`) and its part report (`<root>/sim/state`)."""

    def __init__(self, session, root: str, timeout: float = 5.0):
        self.session, self.root, self.timeout = session, root, timeout
        self.keys = sim_keys(root)

    def _get(self, key: str, body: dict) -> dict:
        for reply in self.session.get(self.keys[key], payload=json.dumps(body), timeout=self.timeout):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
            raise ServiceError(json.loads(reply.err.payload.to_bytes()).get("error", "error"))
        raise ServiceError(f"no simulator answers on {self.keys[key]}: is `replanner sim` running?")

    def state(self) -> dict:
        return self._get("state", {})

    def command(self, name: str) -> dict:
        """Send `{"command": name}` to the gripper; raises ServiceError with the simulator's reason if refused."""
        return self._get("gripper", {"command": name})

    def grasp(self) -> dict:
        return self.command("grasp")

    def release(self) -> dict:
        return self.command("release")


class PickAndPlace:
    """Runs cycles; `on_progress` hears each step (for displays; metrics come from ground truth, not from here)."""

    def __init__(
        self,
        client: Client,
        gripper: Gripper,
        task: TaskConfig,
        tip_link: str,
        bin_tops: dict[str, np.ndarray],
        boxes: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
        on_progress: Callable[[dict], None] | None = None,
        goal_timeout: float = 60.0,
        retries: int = 20,
    ):
        self.client, self.gripper, self.task, self.tip_link = client, gripper, task, tip_link
        missing = [b for b in task.bins if b not in bin_tops]
        if missing:
            raise ServiceError(f"the config's scene: has no bin {missing[0]!r} (sim.task.bins names scene objects)")
        self.bin_tops = {k: np.asarray(v, float) for k, v in bin_tops.items()}
        self.boxes = boxes or {}
        self.on_progress = on_progress or (lambda msg: None)
        self.goal_timeout, self.retries = goal_timeout, retries
        self.cycle = 0
        self.goals = 0
        self.failed_goals = 0

    def setup(self, timeout: float = 30.0) -> dict:
        end = time.monotonic() + timeout
        while True:  # a fresh session learns of the simulator's queryables a moment after it opens
            try:
                st = self.gripper.state()
                break
            except ServiceError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.2)
        scene = self.client.scene()
        objects = [o["name"] for o in scene.get("objects", []) + scene.get("attachments", [])]
        if st["grasped"]:
            raise ServiceError("the simulator's gripper holds the part: restart `replanner sim`")
        pos, quat = st["part"][:3], st["part"][3:]
        # the part in the service's scene where the simulator says it is
        if "part" in objects:
            self.client.move_object("part", pos, quat)
        else:
            self.client.add_object("part", {"type": "box", "size": st["part_size"]}, pos, quat)
        return st

    def _goal(self, position, what: str) -> None:
        for attempt in range(1, self.retries + 1):
            self.goals += 1
            try:
                fut = self.client.send_goal(
                    pose={"link": self.tip_link, "position": list(map(float, position)), "quat_xyzw": list(DOWN)},
                    velocity_scale=self.task.velocity_scale,
                )
                res = fut.wait(self.goal_timeout) or {"status": "timeout", "reason": f"{self.goal_timeout} s"}
            except ServiceError as err:  # rejected (e.g. the operator's hand is where the goal is): wait, retry
                res = {"status": "rejected", "reason": str(err)}
            self.on_progress(
                {
                    "cycle": self.cycle,
                    "step": what,
                    "attempt": attempt,
                    "result": res.get("status"),
                    "reason": res.get("reason"),
                }
            )
            if res.get("status") == "succeeded":
                return
            self.failed_goals += 1
            log.info("%s: %s (%s); retrying", what, res.get("status"), res.get("reason"))
            time.sleep(0.5)
        raise ServiceError(f"{what}: no success in {self.retries} attempts")

    def run_cycle(self) -> dict:
        """Carry the part to the other bin; returns where the simulator says it came to rest.

        A cycle takes up from where things are: after a failed one the part may already be in the hand.
        """
        self.cycle += 1
        t = self.task
        st = self.gripper.state()
        src = st["part_in"]
        dst = t.bins[1] if src == t.bins[0] else t.bins[0]
        part = np.asarray(st["part"][:3])
        h = t.part_size[2]
        top = part + [0, 0, h / 2]
        self.on_progress({"cycle": self.cycle, "step": "start", "from": src, "to": dst})
        if not st["grasped"]:
            self._goal(top + [0, 0, t.approach_height], f"above {src}")
            self._goal(top + [0, 0, t.grasp_gap], f"down to the part in {src}")
            self.gripper.grasp()
            self.client.attach("part", self.tip_link, support=self._support(part, src))
        self._goal(top + [0, 0, t.approach_height], f"lift from {src}")
        floor = self.bin_tops[dst]
        drop_top = np.array([floor[0], floor[1], floor[2] + t.place_gap + h])
        self._goal(drop_top + [0, 0, t.approach_height], f"above {dst}")
        self._goal(drop_top + [0, 0, t.grasp_gap], f"down into {dst}")
        rel = self.gripper.release()
        self.client.detach("part")
        self.client.move_object("part", rel["pose"][:3], rel["pose"][3:])
        self._goal(drop_top + [0, 0, t.approach_height], f"up from {dst}")
        self.on_progress({"cycle": self.cycle, "step": "done", "on": rel.get("on")})
        return rel

    def run(self, cycles: int, until: float | None = None) -> int:
        """Run `cycles` cycles (or until time.time() passes `until`); a cycle that cannot finish is counted as failed
        and the next one takes up from where things are. Returns the failed cycles."""
        failed = 0
        for _ in range(cycles):
            if until is not None and time.time() > until:
                break
            try:
                self.run_cycle()
            except ServiceError as err:
                failed += 1
                self.on_progress({"cycle": self.cycle, "step": "failed", "reason": str(err)})
                log.warning("cycle %d failed: %s; the next one takes up from here", self.cycle, err)
        return failed

    def _support(self, center: np.ndarray, src: str, reach: float = 0.03) -> list[str]:
        """The bin and whatever else is within `reach` below the part (the table under a thin floor)."""
        half = np.asarray(self.task.part_size) / 2
        lo, hi = center - half, center + half
        near = [
            n
            for n, (blo, bhi) in self.boxes.items()
            if (blo[:2] <= hi[:2]).all() and (bhi[:2] >= lo[:2]).all() and lo[2] - reach <= bhi[2] <= lo[2] + 0.005
        ]
        return sorted({src, *near})
