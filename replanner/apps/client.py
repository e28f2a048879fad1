"""A small Python client of the replanner service. The caller opens (and closes) the Zenoh session."""

from __future__ import annotations

import itertools
import json
import threading
import time
import uuid
from collections.abc import Callable

from ..errors import ReplannerError
from ..transport import messages as m
from ..transport.keys import Keys


class ServiceError(ReplannerError):
    """The service answered with an error (the message is its explanation) or did not answer."""


class GoalFuture:
    """An accepted goal; `wait` returns its result {"id", "status", "reason", "stamp"} or None on timeout."""

    def __init__(self, goal_id: str, reply: dict):
        self.id = goal_id
        self.reply = reply
        self._done = threading.Event()
        self.result: dict | None = None

    def resolve(self, result: dict) -> None:
        """The goal's result has come: `wait` returns it."""
        self.result = result
        self._done.set()

    def wait(self, timeout: float | None = None) -> dict | None:
        self._done.wait(timeout)
        return self.result


class Client:
    """Talks to the service of robot `robot` under `namespace` over an open Zenoh session."""

    def __init__(self, session, robot: str, namespace: str = "replanner", timeout: float = 5.0):
        self.session = session
        self.keys = Keys(robot, namespace)
        self.timeout = timeout
        self._futures: dict[str, GoalFuture] = {}
        self._early: dict[str, dict] = {}
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._results_sub = session.declare_subscriber(self.keys.results, self._on_result)
        self._subs: list = []

    def close(self) -> None:
        self._results_sub.undeclare()
        for s in self._subs:
            s.undeclare()

    # ------------------------------------------------------------------ requests
    def request(self, key: str, body: dict | None = None, timeout: float | None = None) -> dict:
        """A query: the reply as a dict, or ServiceError with the service's message."""
        payload = m.dumps(body) if body is not None else None
        replies = list(self.session.get(key, payload=payload, timeout=timeout or self.timeout))
        if not replies:
            raise ServiceError(
                f"no answer on {key}: is `replanner serve` running for robot "
                f"{self.keys.robot!r} in namespace {self.keys.namespace!r}?"
            )
        r = replies[0]
        if r.ok is not None:
            return json.loads(r.ok.payload.to_bytes())
        raw = r.err.payload.to_bytes()
        try:
            msg = json.loads(raw).get("error", raw.decode())
        except (ValueError, UnicodeDecodeError, AttributeError):
            msg = raw.decode(errors="replace")
        raise ServiceError(msg)

    def send_goal(self, joints=None, pose: dict | None = None, goal_id: str | None = None, **options) -> GoalFuture:
        """Send a goal (joints [rad] or pose {"link", "position", "quat_xyzw", ...}); raises ServiceError if rejected.

        options: planner, deadline [s], velocity_scale, acceleration_scale, padding [m].
        """
        goal_id = goal_id or f"goal-{uuid.uuid4().hex[:8]}-{next(self._ids)}"
        body = {"id": goal_id, **{k: v for k, v in options.items() if v is not None}}
        if joints is not None:
            body["joints"] = [float(x) for x in joints]
        if pose is not None:
            body["pose"] = pose
        fut = GoalFuture(goal_id, {})
        with self._lock:
            self._futures[goal_id] = fut  # before sending: a fast result must not be missed
        try:
            fut.reply = self.request(self.keys.goal, body)
        except ServiceError:
            with self._lock:
                self._futures.pop(goal_id, None)
            raise
        with self._lock:
            early = self._early.pop(goal_id, None)
        if early is not None:
            fut.resolve(early)
        return fut

    def move(self, joints=None, pose=None, timeout: float = 60.0, **options) -> dict:
        """Send a goal and wait for its result."""
        fut = self.send_goal(joints, pose, **options)
        res = fut.wait(timeout)
        if res is None:
            raise ServiceError(f"no result for goal {fut.id!r} within {timeout} s")
        return res

    def cancel(self, goal_id: str) -> dict:
        return self.request(self.keys.cancel, {"id": goal_id})

    def state(self) -> dict:
        return self.request(self.keys.state)

    def clear_map(self) -> dict:
        return self.request(self.keys.map_clear)

    # ------------------------------------------------------------------ scene
    def add_box(self, name: str, size, position, quat_xyzw=(0, 0, 0, 1)) -> dict:
        return self.add_object(name, {"type": "box", "size": list(size)}, position, quat_xyzw)

    def add_object(self, name: str, shape: dict, position, quat_xyzw=(0, 0, 0, 1)) -> dict:
        return self.request(
            self.keys.scene_add,
            {"name": name, "shape": shape, "pose": {"position": list(position), "quat_xyzw": list(quat_xyzw)}},
        )

    def move_object(self, name: str, position, quat_xyzw=(0, 0, 0, 1)) -> dict:
        return self.request(
            self.keys.scene_move, {"name": name, "pose": {"position": list(position), "quat_xyzw": list(quat_xyzw)}}
        )

    def remove_object(self, name: str) -> dict:
        return self.request(self.keys.scene_remove, {"name": name})

    def attach(self, name: str, link: str, touch_links=None, support=()) -> dict:
        """Carry `name` with `link` from where it is now; it may touch `support` (e.g. "table") until it left it."""
        body = {"name": name, "link": link, "support": list(support)}
        if touch_links is not None:
            body["touch_links"] = list(touch_links)
        return self.request(self.keys.scene_attach, body)

    def detach(self, name: str) -> dict:
        return self.request(self.keys.scene_detach, {"name": name})

    def scene(self) -> dict:
        return self.request(self.keys.scene_list)

    # ------------------------------------------------------------------ streams
    def watch(
        self,
        on_status: Callable[[dict], None] | None = None,
        on_transition: Callable[[dict], None] | None = None,
        on_result: Callable[[dict], None] | None = None,
    ) -> None:
        """Call back on status messages, state transitions and results (from Zenoh's thread: keep them short)."""
        for key, cb in (
            (self.keys.status, on_status),
            (self.keys.transitions, on_transition),
            (self.keys.results, on_result),
        ):
            if cb is not None:
                self._subs.append(self.session.declare_subscriber(key, _json_callback(cb)))

    def wait_alive(self, timeout: float = 10.0) -> bool:
        """Whether the service's liveliness token shows up within `timeout` [s]."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if list(self.session.liveliness().get(self.keys.alive, timeout=0.5)):
                return True
            time.sleep(0.1)
        return False

    def _on_result(self, sample) -> None:
        try:
            res = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        with self._lock:
            fut = self._futures.pop(res.get("id"), None)
            if fut is None:
                self._early[res.get("id")] = res
                if len(self._early) > 1000:
                    self._early.pop(next(iter(self._early)))
        if fut is not None:
            fut.resolve(res)


def _json_callback(cb):
    def on_sample(sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        cb(msg)

    return on_sample
