"""The simulated cell behind `replanner sim`: the arm under pybullet physics, a scripted operator, ground truth.

The arm follows the trajectory stream with pybullet's joint motors and publishes measured joint states. The
operator's forearm (a capsule) enters the workspace, lingers and leaves, seeded; often it reaches to where the
arm will be a moment later. Obstacles do not push the arm: contacts are measured, not simulated, so a collision
is counted rather than hidden by a deflected arm. Ground truth (contacts, clearance, the obstacle on the planned
path, parts placed) is published on `<root>/sim/truth` and optionally written to a JSON-lines file.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time

import numpy as np
import pybullet as pb

from ..control.driver import SampledTrajectory, Timeline
from ..errors import InvalidInputError
from ..transport import messages as m
from ..transport.keys import Keys
from ..world.geometry import Box
from ..world.robot import RobotModel
from ..world.scene import scene_from_config
from ..world.transforms import make_transform, matrix_to_quat
from .config import CellConfig, OperatorConfig
from .scene import PyBulletScene

log = logging.getLogger(__name__)

OPERATOR_HZ = 100.0  # the hand moves in 1 cm steps at 1 m/s: each step costs two closest-point queries
PARK = (0.0, 0.0, -5.0)  # where absent bodies wait: under the floor, out of every camera's view
CONTACT_DEPTH = 0.001  # pybullet reports distances up to its 1 mm collision margin short: deeper counts


def sim_keys(keys: Keys) -> dict[str, str]:
    return {k: f"{keys.root}/sim/{k}" for k in ("truth", "bodies", "gripper", "state")}


def capsule_pose(tip: np.ndarray, direction: np.ndarray, length: float) -> np.ndarray:
    """Pose of a capsule (axis z) whose far end is at `tip`, pointing along `direction`."""
    d = direction / np.linalg.norm(direction)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(z @ d)
    if s < 1e-9:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = axis / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + s * K + (1 - c) * K @ K
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = tip - d * (length / 2)
    return T


def create_capsule(client: int, radius: float, length: float) -> int:
    col = pb.createCollisionShape(pb.GEOM_CAPSULE, radius=radius, height=length, physicsClientId=client)
    vis = pb.createVisualShape(pb.GEOM_CAPSULE, radius=radius, length=length, physicsClientId=client)
    return pb.createMultiBody(0, col, vis, basePosition=PARK, physicsClientId=client)


def set_pose(client: int, body: int, T: np.ndarray | None) -> None:
    if T is None:
        pb.resetBasePositionAndOrientation(body, PARK, (0, 0, 0, 1), physicsClientId=client)
    else:
        pb.resetBasePositionAndOrientation(
            body, T[:3, 3].tolist(), matrix_to_quat(T[:3, :3]).tolist(), physicsClientId=client
        )


def pose_list(T: np.ndarray | None) -> list[float] | None:
    return None if T is None else [*T[:3, 3].tolist(), *matrix_to_quat(T[:3, :3]).tolist()]


def pose_from_list(p) -> np.ndarray | None:
    return None if p is None else make_transform(p[:3], p[3:])


class Operator:
    """A seeded script: pause, reach in (often to where the arm is about to be), linger, withdraw.

    The hand never moves towards the arm once within `stop_distance` of it (it pauses), and it only sets
    off on a way in that keeps `keep_off_arm` from the arm: contacts and close calls are the arm's doing.
    """

    def __init__(self, cfg: OperatorConfig, rng: np.random.Generator, t0: float):
        self.cfg = cfg
        self.rng = rng
        self.phase = "idle"
        self.until = t0 + cfg.first_after
        self.tip: np.ndarray | None = None
        self.start = self.target = None
        self.aimed = False
        self.aim_deadline: float | None = None
        self.count = 0

    @property
    def present(self) -> bool:
        return self.tip is not None

    def direction(self) -> np.ndarray:
        d = self.target - np.asarray(self.cfg.stand)
        return d / np.linalg.norm(d)

    def pose(self) -> np.ndarray | None:
        if self.tip is None:
            return None
        return capsule_pose(self.tip, self.direction(), self.cfg.arm_length)

    def uniform(self, r) -> float:
        return float(self.rng.uniform(r[0], r[1]))


class PhysicsSim:
    """The cell: robot, static scene (from the config's `scene:`), part, operator, ground truth.

    Args:
        cfg: full config; `sim:` holds rates, noise, the operator's script and the pick-and-place task.
        session: an open Zenoh session (not closed here).
        seed: seeds the operator's script.
        gui: open pybullet's window.
        truth_log: a JSON-lines file every ground-truth event is appended to.
    """

    def __init__(
        self,
        cfg: CellConfig,
        session,
        *,
        seed: int = 0,
        gui: bool = False,
        truth_log: str | None = None,
        operator: bool | None = None,
    ):
        self.cfg, self.session, self.seed = cfg, session, seed
        self.sc = cfg.sim
        self.robot = RobotModel.from_config(cfg.robot)
        self.keys = Keys(self.robot.name, cfg.transport.namespace)
        self.skeys = sim_keys(self.keys)
        self.client = pb.connect(pb.GUI if gui else pb.DIRECT)
        pb.setGravity(0, 0, -9.81, physicsClientId=self.client)
        pb.setTimeStep(1.0 / self.sc.physics_hz, physicsClientId=self.client)
        self.scene = PyBulletScene(self.robot, self.client)
        self.static = {}
        for name, shape, pose in scene_from_config(cfg):
            self.static[name] = self.scene.add(name, shape, pose)
        self.joint_ids = [self.scene.joint_index[n] for n in self.robot.joint_names]
        self.forces = [pb.getJointInfo(self.scene.body, j, physicsClientId=self.client)[10] for j in self.joint_ids]
        self.forces = [f if f > 0 else 100.0 for f in self.forces]
        self.link_name = {v: k for k, v in self.scene.link_index.items()}
        self.link_name[-1] = self.robot.base_link
        self.tip_index = self.scene.link_index[self.robot.tip_link]
        self.allowed = {(a, b) for a, b in cfg.collision.allowed_contacts}
        q0 = self.robot.home
        self.scene.set_q(q0)
        self.timeline = Timeline(q0)
        # the part: a box resting on the first bin
        task = self.sc.task
        self.part_shape = Box(size=tuple(task.part_size))
        self.part = self.scene.add("part", self.part_shape, make_transform(PARK))
        self.part_pose = self._rest_on(task.bins[0], self.part_shape)
        set_pose(self.client, self.part, self.part_pose)
        self.grasped: np.ndarray | None = None  # T_tip_part while held
        self.part_in = task.bins[0]
        # the operator's forearm: a capsule (kinematic)
        oc = self.sc.operator
        self.op_on = oc.enabled if operator is None else operator
        self.op_body = create_capsule(self.client, oc.arm_radius, oc.arm_length)
        self.op = Operator(oc, np.random.default_rng(seed), time.time())
        # nothing pushes the arm: contacts are measured (ground truth), not simulated
        for other in [*self.static.values(), self.part, self.op_body, *self.scene.room.values()]:
            for link in [-1, *self.scene.link_index.values()]:
                pb.setCollisionFilterPair(self.scene.body, other, link, -1, 0, physicsClientId=self.client)
        # a second world for "is the obstacle on the planned path?": the robot at future configurations
        self.shadow = PyBulletScene(self.robot, room=False)
        self.shadow_op = create_capsule(self.shadow.client, oc.arm_radius, oc.arm_length)
        self._log = open(truth_log, "a") if truth_log else None  # noqa: SIM115 (closed in stop)
        self._requests: queue.Queue = queue.Queue(maxsize=64)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.q = q0.copy()
        self.qd = np.zeros_like(q0)
        self.on_path = False
        self.contacts: dict[str, float] = {}  # object -> deepest penetration in the current episode
        self.steps = 0
        self.rejected = 0

    # ------------------------------------------------------------------ geometry helpers
    def _rest_on(self, obj: str, shape: Box) -> np.ndarray:
        """Pose of `shape` resting on the middle of the top face of static object `obj`."""
        aabb = pb.getAABB(self.static[obj], physicsClientId=self.client)
        lo, hi = np.array(aabb[0]), np.array(aabb[1])
        c = (lo + hi) / 2
        margin = 0.001  # pybullet's AABBs include its collision margin
        return make_transform((c[0], c[1], hi[2] - margin + shape.size[2] / 2))

    def tip_pose(self) -> np.ndarray:
        ls = pb.getLinkState(self.scene.body, self.tip_index, computeForwardKinematics=1, physicsClientId=self.client)
        return make_transform(ls[4], ls[5])

    # ------------------------------------------------------------------ running
    def start(self) -> PhysicsSim:
        s = self.session
        self.pub_js = s.declare_publisher(self.keys.joint_states)
        self.pub_truth = s.declare_publisher(self.skeys["truth"])
        self.pub_bodies = s.declare_publisher(self.skeys["bodies"])
        self._decl = [
            s.declare_subscriber(self.keys.trajectory, self._on_trajectory),
            s.declare_queryable(self.skeys["gripper"], self._enqueue("gripper")),
            s.declare_queryable(self.skeys["state"], self._enqueue("state")),
        ]
        self.t0 = time.time()
        self.event("start", seed=self.seed, operator=self.op_on, physics_hz=self.sc.physics_hz)
        self._thread = threading.Thread(target=self._loop, name="physics", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        for d in self._decl:
            d.undeclare()
        self.event("stop", steps=self.steps)
        if self._log:
            self._log.close()
        self.shadow.close()
        pb.disconnect(self.client)

    def event(self, kind: str, stamp: float | None = None, **data) -> None:
        msg = {"stamp": time.time() if stamp is None else stamp, "kind": kind, **data}
        text = json.dumps(msg)
        try:
            self.pub_truth.put(text)
        except Exception:
            log.exception("truth publishing failed")
        if self._log:
            self._log.write(text + "\n")
            self._log.flush()

    # ------------------------------------------------------------------ inputs (callbacks: never block)
    def _on_trajectory(self, sample) -> None:
        try:
            start, traj = SampledTrajectory.from_message(sample.payload.to_bytes(), self.robot.joint_names)
        except InvalidInputError as err:
            self.rejected += 1
            log.warning("trajectory rejected: %s", err)
            return
        self.timeline.add(traj, start)

    def _enqueue(self, name: str):
        def callback(query) -> None:
            try:
                self._requests.put_nowait((name, query))
            except queue.Full:
                query.reply_err(json.dumps({"error": "the simulator is busy; try again"}))
                query.drop()

        return callback

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        sc = self.sc
        dt = 1.0 / sc.physics_hz
        every = {
            "js": max(1, round(sc.physics_hz / sc.joint_state_hz)),
            "truth": max(1, round(sc.physics_hz / sc.truth_rate_hz)),
            "path": max(1, round(sc.physics_hz / sc.path_check_hz)),
            "bodies": max(1, round(sc.physics_hz / 60.0)),
            "operator": max(1, round(sc.physics_hz / OPERATOR_HZ)),
            "report": max(1, round(sc.physics_hz / 10.0)),
        }
        t0 = time.time()
        k = 0
        window = math.inf
        while not self._stop.is_set():
            due = int((time.time() - t0) / dt)
            burst = 0
            while k <= due and burst < 50:  # fell behind (a busy machine): catch up, but keep answering
                t = t0 + k * dt
                self._step(t, operate=self.op_on and k % every["operator"] == 0)
                if k % every["js"] == 0:
                    self._publish_js(t)
                if k % every["truth"] == 0:
                    c = self._truth(t)
                    window = min(window, c)
                if self.op_on and k % every["path"] == 0:
                    self._path_truth(t)
                if k % every["bodies"] == 0:
                    self._publish_bodies(t)
                if k % every["report"] == 0:
                    self.event(
                        "clearance",
                        t,
                        clearance=None if window == math.inf else round(window, 4),
                        operator=self.op.present,
                        on_path=self.on_path,
                    )
                    window = math.inf
                k += 1
                burst += 1
                self.steps += 1
            if burst >= 50:
                t0 = time.time() - k * dt  # drop the backlog rather than run in a burst forever
            self._serve_requests()
            delay = t0 + k * dt - time.time()
            if delay > 0:
                time.sleep(delay)

    def _step(self, t: float, operate: bool = False) -> None:
        c = self.client
        q_d, qd_d = self.timeline.state(t)
        pb.setJointMotorControlArray(
            self.scene.body,
            self.joint_ids,
            pb.POSITION_CONTROL,
            targetPositions=q_d.tolist(),
            targetVelocities=qd_d.tolist(),
            positionGains=[0.3] * len(self.joint_ids),
            velocityGains=[1.0] * len(self.joint_ids),
            forces=self.forces,
            physicsClientId=c,
        )
        if operate:
            self._operate(t)
        pb.stepSimulation(physicsClientId=c)
        if self.grasped is not None:
            self.part_pose = self.tip_pose() @ self.grasped
            set_pose(c, self.part, self.part_pose)

    def _publish_js(self, t: float) -> None:
        states = pb.getJointStates(self.scene.body, self.joint_ids, physicsClientId=self.client)
        self.q = np.array([s[0] for s in states])
        self.qd = np.array([s[1] for s in states])
        self.pub_js.put(m.encode_joint_state(t, self.robot.joint_names, self.q, self.qd))

    def _publish_bodies(self, t: float) -> None:
        # the arm too: cameras render one instant, or a carried part trails the hand into the map
        states = pb.getJointStates(self.scene.body, self.joint_ids, physicsClientId=self.client)
        msg = {
            "stamp": t,
            "q": [s[0] for s in states],
            "operator": pose_list(self.op.pose()),
            "part": pose_list(self.part_pose),
        }
        self.pub_bodies.put(json.dumps(msg))

    # ------------------------------------------------------------------ ground truth
    def _truth(self, t: float) -> float:
        """Contacts of the robot (and what it carries) with anything; returns the clearance to the operator."""
        c, robot = self.client, self.scene.body
        touching: dict[str, tuple[float, str]] = {}  # object -> (depth, robot link or "part")

        def touch(name: str, depth: float, who: str) -> None:
            if name not in touching or depth < touching[name][0]:
                touching[name] = (depth, who)

        for name, body in [*self.static.items(), ("part", self.part)]:
            if name == "part" and self.grasped is not None:
                continue
            for pt in pb.getClosestPoints(robot, body, 0.0, physicsClientId=c):
                link = self.link_name.get(pt[3], str(pt[3]))
                if pt[8] < -CONTACT_DEPTH and (link, name) not in self.allowed:
                    touch(name, pt[8] + CONTACT_DEPTH, link)
        clearance = math.inf
        who = None
        if self.op.present:
            for pt in pb.getClosestPoints(robot, self.op_body, 1.0, physicsClientId=c):
                if pt[8] + CONTACT_DEPTH < clearance:
                    clearance, who = pt[8] + CONTACT_DEPTH, self.link_name.get(pt[3], str(pt[3]))
            if self.grasped is not None:
                for pt in pb.getClosestPoints(self.part, self.op_body, 1.0, physicsClientId=c):
                    if pt[8] + CONTACT_DEPTH < clearance:
                        clearance, who = pt[8] + CONTACT_DEPTH, "part"
            if clearance < 0:
                touch("operator", clearance, who)
        if self.grasped is not None:
            for name, body in self.static.items():
                if name == self.part_in:
                    continue  # lifting off the bin it rested on
                for pt in pb.getClosestPoints(self.part, body, 0.0, physicsClientId=c):
                    if pt[8] < -CONTACT_DEPTH:
                        touch(name, pt[8] + CONTACT_DEPTH, "part")
        for name, (depth, link) in touching.items():
            if name not in self.contacts:
                self.event(
                    "contact", t, object=name, depth=round(depth, 4), link=link, carrying=self.grasped is not None
                )
            self.contacts[name] = min(self.contacts.get(name, 0.0), depth)
        for name in [n for n in self.contacts if n not in touching]:
            self.event("contact_end", t, object=name, deepest=round(self.contacts.pop(name), 4))
        return clearance

    def _path_truth(self, t: float) -> None:
        """Does the operator's forearm intersect the robot anywhere on the rest of the commanded trajectory?"""
        on = False
        if self.op.present:
            seg = self.timeline.active(t)
            if seg is not None:
                start, traj = seg
                end = start + traj.duration
                if end > t:
                    set_pose(self.shadow.client, self.shadow_op, self.op.pose())
                    for tt in np.arange(t, min(end, t + 3.0) + 1e-9, 0.04):
                        self.shadow.set_q(self.timeline.state(tt)[0])
                        pts = pb.getClosestPoints(
                            self.shadow.body, self.shadow_op, 0.0, physicsClientId=self.shadow.client
                        )
                        if any(p[8] < -CONTACT_DEPTH for p in pts):
                            on = True
                            break
        if on != self.on_path:
            self.on_path = on
            self.event("entered_path" if on else "left_path", t, intrusion=self.op.count)

    # ------------------------------------------------------------------ the operator
    def _operate(self, t: float) -> None:
        op, oc = self.op, self.sc.operator
        step = oc.speed / OPERATOR_HZ
        if op.phase == "idle":
            if t >= op.until:
                self._choose_target(t)
        elif op.phase == "in":
            if self._move_hand(op.target, step):
                op.phase, op.until = "stay", t + op.uniform(oc.linger)
                self.event("operator_arrived", t, intrusion=op.count, aimed=op.aimed, at=op.target.round(3).tolist())
        elif op.phase == "stay":
            if t >= op.until:
                op.phase = "out"
                self.event("operator_leaving", t, intrusion=op.count)
        elif op.phase == "out":
            if self._move_hand(op.start, step):
                op.tip = None
                op.phase, op.until = "idle", t + op.uniform(oc.interval)
                self.event("operator_left", t, intrusion=op.count)
        set_pose(self.client, self.op_body, op.pose())

    def _move_hand(self, goal: np.ndarray, step: float) -> bool:
        """One step of the hand towards `goal` unless it would push into the arm; True once it is there."""
        op = self.op
        d = goal - op.tip
        dist = float(np.linalg.norm(d))
        nxt = goal if dist <= step else op.tip + d / dist * step
        if self._keeps_off(nxt):
            op.tip = nxt
        return bool(np.array_equal(op.tip, goal))

    def _keeps_off(self, tip: np.ndarray) -> bool:
        """A person does not push into a robot: no step ends within `stop_distance` of the arm unless it leaves."""
        c, robot, body, oc = self.client, self.scene.body, self.op_body, self.sc.operator
        before = pb.getClosestPoints(robot, body, 0.5, physicsClientId=c)  # the capsule is where the hand is now
        set_pose(c, body, capsule_pose(tip, self.op.direction(), oc.arm_length))
        after = pb.getClosestPoints(robot, body, oc.stop_distance, physicsClientId=c)
        return not after or min(p[8] for p in after) >= min((p[8] for p in before), default=1.0)

    def _choose_target(self, t: float) -> None:
        op, oc = self.op, self.sc.operator
        stand = np.asarray(oc.stand, float)
        if op.aim_deadline is None:  # a new intrusion: aimed or not is rolled once
            op.count += 1
            op.aimed = bool(op.rng.random() < oc.in_path_probability)
            op.aim_deadline = t + oc.aim_patience
        target = self._aim(t, stand) if op.aimed else None
        if target is None and op.aimed and t < op.aim_deadline:
            op.until = t + 0.02  # wait for a motion the hand can meet
            return
        op.aim_deadline = None
        if target is None:
            op.aimed = False
            for _ in range(10):
                cand = op.rng.uniform(*np.asarray(oc.reach_region, float))
                if self._corridor_clear(stand, cand, t):
                    target = cand
                    break
        if target is None:
            op.phase, op.until = "idle", t + 0.5  # no way in that keeps off the arm now: try again shortly
            op.count -= 1
            return
        op.start = stand.copy()
        op.target = target
        op.tip = stand.copy()
        op.phase = "in"
        self.event("operator_entering", t, intrusion=op.count, aimed=op.aimed, target=target.round(3).tolist())

    def _aim(self, t: float, stand: np.ndarray) -> np.ndarray | None:
        """The earliest point of the arm's motion the hand can block with `lead_time` to spare.

        Lead is from the hand's arrival to the arm's first coming within `stop_distance` of the forearm, the
        time a system has to see the hand, decide and act; points near where the motion ends are skipped.
        """
        op, oc = self.op, self.sc.operator
        seg = self.timeline.active(t)
        if seg is None or seg[0] + seg[1].duration < t + 0.5:
            return None
        start, traj = seg
        end = start + traj.duration
        link = self._reach_link(op.rng)
        lead = op.uniform(oc.lead_time)
        goal = self._link_point(self.timeline.state(end)[0], link)
        for tt in np.arange(t + lead, end, 0.1):  # the arm's aimed point gets there at tt
            cand = self._link_point(self.timeline.state(tt)[0], link)
            arrive = t + float(np.linalg.norm(cand - stand)) / oc.speed
            if arrive + lead > tt or np.linalg.norm(cand - goal) < oc.goal_margin:
                continue
            if self._first_meeting(stand, cand, arrive, tt) - arrive >= lead and self._corridor_clear(stand, cand, t):
                return cand
        return None

    def _first_meeting(self, stand: np.ndarray, tip: np.ndarray, t0: float, t1: float) -> float:
        """When in [t0, t1] the commanded arm first comes within `stop_distance` of a forearm reaching to tip."""
        sh, oc = self.shadow, self.sc.operator
        d = (tip - stand) / np.linalg.norm(tip - stand)
        set_pose(sh.client, self.shadow_op, capsule_pose(tip, d, oc.arm_length))
        for tt in np.arange(t0, t1, 0.04):
            sh.set_q(self.timeline.state(tt)[0])
            if pb.getClosestPoints(sh.body, self.shadow_op, oc.stop_distance, physicsClientId=sh.client):
                return float(tt)
        return t1

    def _reach_link(self, rng: np.random.Generator) -> str:
        """Where a reaching person meets the arm: the hand or the wrist."""
        if "panda_hand" in self.shadow.link_index:
            return str(rng.choice([self.robot.tip_link, "panda_hand", "panda_link6"]))
        return self.robot.tip_link

    def _link_point(self, q: np.ndarray, link: str) -> np.ndarray:
        self.shadow.set_q(q)
        ls = pb.getLinkState(
            self.shadow.body,
            self.shadow.link_index[link],
            computeForwardKinematics=1,
            physicsClientId=self.shadow.client,
        )
        return np.array(ls[4])

    def _corridor_clear(self, stand: np.ndarray, target: np.ndarray, t: float) -> bool:
        """The way in (stand → target) keeps `keep_off_arm` from the arm over the time it takes."""
        oc = self.sc.operator
        reach = float(np.linalg.norm(target - stand))
        if reach > 1.3 or reach < oc.arm_length:
            return False
        d = (target - stand) / reach
        sh = self.shadow
        for f in np.linspace(0.0, 1.0, 8):
            tip = stand + d * reach * f
            tt = t + reach * f / oc.speed
            sh.set_q(self.timeline.state(tt)[0])
            set_pose(sh.client, self.shadow_op, capsule_pose(tip, d, oc.arm_length))
            if pb.getClosestPoints(sh.body, self.shadow_op, oc.keep_off_arm, physicsClientId=sh.client):
                return False
        return True

    # ------------------------------------------------------------------ requests (answered in the loop thread)
    def _serve_requests(self) -> None:
        while True:
            try:
                name, query = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                payload = json.loads(query.payload.to_bytes()) if query.payload else {}
                if not isinstance(payload, dict):
                    raise InvalidInputError("the request must be a JSON object")
                reply = self._gripper(payload) if name == "gripper" else self._state()
                query.reply(query.key_expr, json.dumps(reply))
            except (InvalidInputError, ValueError) as err:
                query.reply_err(json.dumps({"error": str(err)}))
            except Exception as err:
                log.exception("sim request failed")
                query.reply_err(json.dumps({"error": f"internal error: {err}"}))
            finally:
                query.drop()

    def _state(self) -> dict:
        return {
            "part": pose_list(self.part_pose),
            "part_size": list(self.part_shape.size),
            "part_in": self.part_in,
            "grasped": self.grasped is not None,
            "bins": list(self.sc.task.bins),
            "operator": self.op.present,
            "position": self.q.tolist(),
        }

    def _gripper(self, req: dict) -> dict:
        cmd = req.get("command")
        tip = self.tip_pose()
        t = time.time()
        if cmd == "grasp":
            if self.grasped is not None:
                raise InvalidInputError("already holding the part; release it first")
            top = self.part_pose[:3, 3] + self.part_pose[:3, 2] * self.part_shape.size[2] / 2
            gap = float(np.linalg.norm(top - tip[:3, 3]))
            reach = self.sc.task.grasp_gap + 0.03
            if gap > reach:
                raise InvalidInputError(f"no part within {reach:.3f} m of the tip (the part's top is {gap:.3f} m away)")
            self.grasped = np.linalg.inv(tip) @ self.part_pose
            self.event("grasped", t, bin=self.part_in, gap=round(gap, 4))
            return {"grasped": "part", "pose": pose_list(self.part_pose)}
        if cmd == "release":
            if self.grasped is None:
                raise InvalidInputError("not holding anything")
            self.grasped = None
            # the part settles straight down onto whatever is below it
            p = self.part_pose[:3, 3]
            bottom = p[2] - self.part_shape.size[2] / 2
            hits = pb.rayTest([p[0], p[1], bottom - 1e-4], [p[0], p[1], bottom - 1.0], physicsClientId=self.client)
            below = {v: k for k, v in self.static.items()}.get(hits[0][0])
            drop = (bottom - 1e-4 - hits[0][3][2]) if hits[0][0] >= 0 else 0.0
            self.part_pose = self.part_pose.copy()
            self.part_pose[2, 3] -= drop
            set_pose(self.client, self.part, self.part_pose)
            prev, self.part_in = self.part_in, below
            self.event("placed", t, on=below, picked_from=prev, drop=round(drop, 4))
            return {"released": "part", "on": below, "pose": pose_list(self.part_pose)}
        raise InvalidInputError(f"unknown command {cmd!r}; use 'grasp' or 'release'")
