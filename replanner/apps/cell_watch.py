"""What a viewer needs to know about a robot's cell, kept up to date from Zenoh.

It holds the measured and commanded joints, the service's state and its last transitions, the occupancy map and the
static objects (both queried, never faster than asked), and the sim's ground truth when a sim runs. It only
reads: it sends nothing to the service except its `map/get`, `scene/list` and liveliness queries. Callbacks only
store; no callback blocks.
"""

from __future__ import annotations

import base64
import binascii
import json
import logging
import threading
import time
from collections import deque

import numpy as np
import zenoh

from ..errors import InvalidInputError
from ..trajectory import SampledTrajectory
from ..transport import messages as m
from ..transport.keys import Keys, sim_keys

log = logging.getLogger(__name__)


class CellWatch:
    """Subscribes to one robot's streams and polls its map and scene.

    Args:
        session: an open Zenoh session that reaches the service.
        keys: the robot's keys.
        joint_names: the robot's joints, in the service's order.
        map_hz: how often to ask for the map [Hz] (a query never overlaps the previous one).
        scene_hz: how often to ask for the static objects [Hz].
    """

    def __init__(self, session: zenoh.Session, keys: Keys, joint_names, map_hz: float = 2.0, scene_hz: float = 1.0):
        self.session, self.keys, self.joint_names = session, keys, tuple(joint_names)
        self.map_period, self.scene_period = 1.0 / map_hz, 1.0 / scene_hz
        self._lock = threading.Lock()
        self.q: np.ndarray | None = None  # measured joints
        self.status: dict | None = None  # the service's last status (its `state`)
        self.status_at = 0.0  # [s, monotonic] when it came
        self.transitions: deque[dict] = deque(maxlen=8)
        self.trajectory: tuple[float, SampledTrajectory] | None = None  # (start [s, wall clock], the trajectory)
        self.trajectory_count = 0
        self.voxels = np.zeros((0, 3), np.float32)
        self.resolution: float | None = None
        self.map_count = 0  # maps received
        self.objects: list[dict] = []
        self.attachments: list[dict] = []
        self.scene_count = 0
        self.bodies: dict | None = None  # the sim's operator and part (ground truth)
        self.contacts: deque[dict] = deque(maxlen=8)  # the sim's contact events
        self.clearance: float | None = None  # the sim's last clearance to the operator [m]
        self.alive = False
        self.bad = 0  # messages that could not be read (ignored)
        self.map_paused = False
        self.problem: str | None = self._no_service()  # what the viewer should say; None: all is well
        sk = sim_keys(keys.root)
        self._subs = [
            session.declare_subscriber(keys.joint_states, self._on_js),
            session.declare_subscriber(keys.status, self._on_status),
            session.declare_subscriber(keys.transitions, self._on_transition),
            session.declare_subscriber(keys.trajectory, self._on_trajectory),
            session.declare_subscriber(sk["bodies"], self._on_bodies),
            session.declare_subscriber(sk["truth"], self._on_truth),
            session.liveliness().declare_subscriber(keys.alive, self._on_alive, history=True),
        ]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, name="cell-watch", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for s in self._subs:
            s.undeclare()

    # ------------------------------------------------------------------ what the viewer reads
    def commanded(self, now: float | None = None) -> np.ndarray | None:
        """Where the last trajectory says the arm should be now (its end once it is over); None before any."""
        with self._lock:
            tr = self.trajectory
        if tr is None:
            return None
        start, traj = tr
        t = min(max((time.time() if now is None else now) - start, 0.0), traj.duration)
        return np.asarray(traj.state_at(t)[0], float)

    def path(self) -> np.ndarray | None:
        """The last trajectory's joint positions (N, dof), or None."""
        with self._lock:
            tr = self.trajectory
        return None if tr is None else np.asarray(tr[1].q, float)

    # ------------------------------------------------------------------ callbacks: store only
    def ignore(self, what: str, err: Exception) -> None:
        """Count a malformed message and say so in the log (the first five, then every hundredth)."""
        self.bad += 1
        if self.bad <= 5 or self.bad % 100 == 0:
            log.warning("ignored a %s message (%d so far): %s", what, self.bad, err)

    def _on_js(self, sample) -> None:
        try:
            _, q, _ = m.decode_joint_state(sample.payload.to_bytes(), self.joint_names)
        except (InvalidInputError, ValueError) as err:
            return self.ignore("joint state", err)
        with self._lock:
            self.q = np.asarray(q, float)

    def _json_object(self, sample, what: str) -> dict | None:
        """The sample's JSON object, or None (counted and logged) for anything else."""
        try:
            obj = json.loads(sample.payload.to_bytes())
            if not isinstance(obj, dict):
                raise ValueError("not a JSON object")
        except ValueError as err:
            self.ignore(what, err)
            return None
        return obj

    def _on_status(self, sample) -> None:
        status = self._json_object(sample, "status")
        if status is not None:
            with self._lock:
                self.status, self.status_at = status, time.monotonic()

    def _on_transition(self, sample) -> None:
        tr = self._json_object(sample, "transition")
        if tr is not None:
            with self._lock:
                self.transitions.append(tr)

    def _on_trajectory(self, sample) -> None:
        try:
            start, traj = SampledTrajectory.from_message(sample.payload.to_bytes(), self.joint_names)
        except (InvalidInputError, ValueError) as err:
            return self.ignore("trajectory", err)
        with self._lock:
            self.trajectory = (start, traj)
            self.trajectory_count += 1

    def _on_bodies(self, sample) -> None:
        bodies = self._json_object(sample, "sim bodies")
        if bodies is not None:
            with self._lock:
                self.bodies = bodies

    def _on_truth(self, sample) -> None:
        ev = self._json_object(sample, "sim truth")
        if ev is None:
            return
        with self._lock:
            if ev.get("kind") == "contact":
                self.contacts.append(ev)
            elif ev.get("kind") == "clearance":
                self.clearance = ev.get("clearance")

    def _on_alive(self, sample) -> None:
        self.alive = sample.kind == zenoh.SampleKind.PUT

    # ------------------------------------------------------------------ queries, off the callbacks
    def _ask(self, key: str, body: bytes = b"{}") -> dict | None:
        replies = list(self.session.get(key, payload=body, timeout=2.0))
        ok = [r.ok for r in replies if r.ok is not None]
        if not ok:
            return None
        reply = json.loads(ok[0].payload.to_bytes())
        return reply if isinstance(reply, dict) else None

    def _poll(self) -> None:
        next_map = next_scene = 0.0
        while not self._stop.wait(0.05):
            now = time.monotonic()
            try:
                if now >= next_map and not self.map_paused:
                    next_map = now + self.map_period
                    reply = self._ask(self.keys.map_get, b'{"encoding": "float32"}')
                    if reply is not None:
                        raw = base64.b64decode(reply.get("voxels") or "", validate=True)
                        vox = np.frombuffer(raw, "<f4").reshape(-1, 3)
                        with self._lock:
                            self.voxels, self.resolution = vox, reply.get("resolution")
                            self.map_count += 1
                if now >= next_scene:
                    next_scene = now + self.scene_period
                    reply = self._ask(self.keys.scene_list)
                    if reply is not None:
                        with self._lock:
                            self.objects = list(reply.get("objects") or [])
                            self.attachments = list(reply.get("attachments") or [])
                            self.scene_count += 1
            except (ValueError, TypeError, binascii.Error) as err:
                self.ignore("map or scene reply", err)
            except Exception as err:  # a closed session at shutdown, a transport error: say it, keep polling
                if not self._stop.is_set():
                    self.ignore("query", err)
            with self._lock:
                fresh = self.status is not None and time.monotonic() - self.status_at < 3.0
            self.problem = None if (self.alive and fresh) else self._no_service()

    def _no_service(self) -> str:
        return (
            f"no service on {self.keys.root}: waiting for it (is `replanner serve` running, with the same "
            "namespace, robot and connection flags?)"
        )
