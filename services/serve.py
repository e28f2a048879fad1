"""`replanner serve`: the controller as a Zenoh service (see docs/protocol.md)."""

from __future__ import annotations

import base64
import logging
import queue
import signal
import sys
import threading
import time

import numpy as np
import zenoh

from replanner.config import ReplannerConfig
from replanner.control import Goal, GoalRejected, JointState
from replanner.control.liveness import admit_joint_state
from replanner.errors import InvalidInputError, ReplannerError, UnknownNameError, WorldError
from replanner.model.geometry import encloses_base, gap_to_links
from replanner.model.transforms import check_transform
from replanner.perception import CloudFrame, CloudRejected
from replanner.planning import JointGoal, PoseGoal
from replanner.stack import build_stack
from replanner.transport import messages as m
from replanner.transport.keys import Keys
from replanner.transport.refusals import Refusals, access_control_on

log = logging.getLogger(__name__)
MAX_GRASP_GAP = 0.05  # [m] an attached object is held: this close to the link that carries it (suction: ~3 cm)


class Service:
    """The controller, perception and world of one robot behind Zenoh keys.

    Args:
        cfg: the full config.
        session: an open Zenoh session (the service does not close it).
        planning_process: plan in a child process (the product default).
        refusals: what Zenoh's access control refused in this process (`Refusals.capture`), shown in the status.
    """

    def __init__(
        self,
        cfg: ReplannerConfig,
        session: zenoh.Session,
        *,
        planning_process: bool | None = None,
        clock=time.time,
        refusals: Refusals | None = None,
    ):
        self.cfg, self.session, self.clock, self.refusals = cfg, session, clock, refusals
        plan_in = None if planning_process is None else ("process" if planning_process else "thread")
        self.stack = build_stack(cfg, execute=self._execute, plan_in=plan_in, clock=clock)
        self.robot, self.world = self.stack.robot, self.stack.world
        self.perception, self.controller = self.stack.perception, self.stack.controller
        self.keys = Keys(self.robot.name, cfg.transport.namespace)
        self.rejections: dict[str, int] = {}
        self.last_js: JointState | None = None
        self._js_frames = ("", self.robot.base_link)  # a JointState's frame_id: usually empty
        self._requests: queue.Queue = queue.Queue(maxsize=256)
        self._clouds: dict[str, tuple] = {}
        self._cloud_event = threading.Event()
        self._stop = threading.Event()
        self._decl: list = []
        self._threads: list[threading.Thread] = []

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Service:
        s, k = self.session, self.keys
        self.pub_status = s.declare_publisher(k.status)
        self.pub_transitions = s.declare_publisher(k.transitions)
        self.pub_results = s.declare_publisher(k.results)
        self.pub_trajectory = s.declare_publisher(k.trajectory)
        self.pub_rejections = s.declare_publisher(k.rejections)
        self.pub_latency = s.declare_publisher(k.latency)
        self.controller.subscribe(on_transition=self._on_transition, on_result=self._on_result)
        self.controller.start()
        for name in (
            "goal",
            "cancel",
            "state",
            "scene_add",
            "scene_move",
            "scene_remove",
            "scene_attach",
            "scene_detach",
            "scene_list",
            "map_get",
            "map_clear",
        ):
            self._decl.append(s.declare_queryable(getattr(k, name), self._enqueue_query(name)))
        self._decl.append(s.declare_subscriber(k.joint_states, self._on_joint_state))
        self._decl.append(s.declare_subscriber(k.clouds, self._on_cloud))  # without cameras: refused, counted
        for target, name in (
            (self._serve_requests, "requests"),
            (self._serve_clouds, "clouds"),
            (self._publish_status, "status"),
        ):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        self.token = s.liveliness().declare_token(k.alive)
        log.info(
            "replanner serving %s (%s)",
            k.root,
            "cameras: " + ", ".join(self.controller.sensors)
            if self.controller.sensors
            else "no cameras: static objects only",
        )
        return self

    def stop(self, brake_timeout: float = 2.0) -> None:
        """Brake a moving arm (the brake trajectory is published), then stop answering."""
        h = self.controller.active_goal()
        if h is not None:
            try:
                self.controller.cancel(h.id)
                h.wait(brake_timeout)
            except UnknownNameError:
                pass  # finished in the meantime
        self._stop.set()
        self._cloud_event.set()
        self.token.undeclare()
        for d in self._decl:
            d.undeclare()
        self.stack.close()
        for t in self._threads:
            t.join(timeout=2.0)

    # ------------------------------------------------------------------ outputs
    def _execute(self, traj, start: float) -> None:
        t, q, qd, qdd = traj.sample(self.cfg.transport.trajectory_dt)
        self.pub_trajectory.put(m.encode_trajectory(start, self.robot.joint_names, t, q, qd, qdd, self.robot.base_link))
        self.controller.log_event("trajectory_published", start=start, duration=float(t[-1]))

    def _on_transition(self, rec) -> None:
        self.pub_transitions.put(
            m.dumps(
                {
                    "stamp": rec.stamp,
                    "from": rec.source,
                    "to": rec.dest,
                    "trigger": rec.trigger,
                    "reason": rec.reason,
                    "goal_id": rec.goal_id,
                }
            )
        )

    def _on_result(self, res) -> None:
        self.pub_results.put(
            m.dumps({"id": res.goal_id, "status": res.status.value, "reason": res.reason, "stamp": res.stamp})
        )

    def state(self) -> dict:
        st = self.controller.status()
        js = self.last_js
        occ = self.world.occupancy
        st.update(
            {
                "robot": self.robot.name,
                "joint_names": list(self.robot.joint_names),
                "position": js.position.tolist() if js else None,
                "position_age": round(self.clock() - js.stamp, 4) if js else None,
                "stamp": self.clock(),
                "objects": sorted(self.world.objects),
                "attachments": sorted(self.world.attachments),
                "map_voxels": len(occ) if occ is not None else 0,
                "rejections": dict(self.rejections),
                "access_refused": self.refusals.table() if self.refusals is not None else None,
            }
        )
        return st

    def _publish_status(self) -> None:
        period = 1.0 / self.cfg.transport.status_rate_hz
        withheld = False
        while not self._stop.wait(period):
            stuck = self.controller.inbox.stuck_for()
            if stuck > self.cfg.controller.robot_watchdog / 4:
                if not withheld:  # the status is the robot's heartbeat: it must stop when no one watches the path
                    log.error(
                        "status withheld: the controller has been in one step for %.1f s (the robot brakes)", stuck
                    )
                withheld = True
                continue
            if withheld:
                log.warning("status resumes: the controller is stepping again")
                withheld = False
            try:
                state = self.state()
                self.pub_status.put(m.dumps(state))
                self.pub_latency.put(m.dumps({"stamp": state["stamp"], **state["latency"]}))
            except Exception:
                log.exception("status publishing failed")

    def _reject(self, source: str, err: Exception) -> None:
        if source not in self.rejections and len(self.rejections) >= 64:
            source = "(other sources)"  # anyone may publish on any key: the counts stay bounded
        self.rejections[source] = self.rejections.get(source, 0) + 1
        log.warning("%s rejected: %s", source, err)
        try:
            self.pub_rejections.put(m.dumps({"source": source, "reason": str(err), "count": self.rejections[source]}))
        except Exception:
            log.exception("rejection publishing failed")

    # ------------------------------------------------------------------ stream inputs (callbacks: never block)
    def _on_joint_state(self, sample) -> None:
        try:
            stamp, q, qd = m.decode_joint_state(sample.payload.to_bytes(), self.robot.joint_names, self._js_frames)
            last = self.last_js.stamp if self.last_js is not None else None
            admit_joint_state(stamp, q, last=last, now=self.clock(), robot=self.robot, cfg=self.cfg.controller)
            if qd is None:  # a robot that sends no velocities: the last step's
                prev = self.last_js
                qd = (q - prev.position) / (stamp - prev.stamp) if prev is not None else np.zeros_like(q)
            js = JointState(stamp, q, qd)
            self.stack.on_joint_state(js)
        except (InvalidInputError, ReplannerError) as err:
            self._reject("joint_states", err)
            return
        self.last_js = js

    def _on_cloud(self, sample) -> None:
        sensor = str(sample.key_expr).rsplit("/", 1)[-1]
        self._clouds[sensor] = (
            sample.payload.to_bytes(),
            sample.attachment.to_bytes() if sample.attachment else None,
        )  # the newest per camera: a slow pipeline skips frames
        self._cloud_event.set()

    def _serve_clouds(self) -> None:
        while not self._stop.is_set():
            self._cloud_event.wait(0.5)
            self._cloud_event.clear()
            for sensor in list(self._clouds):
                item = self._clouds.pop(sensor, None)
                if item is not None:
                    self._integrate(sensor, *item)

    def _integrate(self, sensor: str, data: bytes, attachment: bytes | None) -> None:
        try:
            if self.perception is None:
                raise InvalidInputError(
                    f"clouds/{sensor}: this service runs without cameras (--no-cameras, or no perception.sensors "
                    "in its config): clouds are not used"
                )
            stamp, pts, width, height = m.decode_cloud(data, f"clouds/{sensor}")
            T = None
            if attachment:
                pose = m.parse_json(m.Pose, attachment, f"clouds/{sensor} attachment")
                T = check_transform(pose.matrix(), "sensor pose")
            cfg = next((s for s in self.cfg.perception.sensors if s.name == sensor), None)
            organized = cfg is not None and height > 1
            if organized and (width, height) != (cfg.width, cfg.height):
                raise InvalidInputError(
                    f"clouds/{sensor}: an organized cloud (height > 1) must be the camera's {cfg.width}x{cfg.height}"
                    f" pixels, got {width}x{height}; send height 1 for an unorganized cloud"
                )
            self.perception.integrate(CloudFrame(sensor, stamp, pts, T, organized=organized))  # tells the controller
        except (CloudRejected, InvalidInputError, ReplannerError) as err:
            self._reject(f"clouds/{sensor}", err)

    # ------------------------------------------------------------------ requests (answered by a worker)
    def _enqueue_query(self, name: str):
        def callback(query) -> None:
            try:
                self._requests.put_nowait((name, query))
            except queue.Full:
                query.reply_err(m.dumps({"error": "the service is overloaded; try again"}))
                query.drop()

        return callback

    def _serve_requests(self) -> None:
        while not self._stop.is_set():
            try:
                name, query = self._requests.get(timeout=0.2)
            except queue.Empty:
                continue
            payload = query.payload.to_bytes() if query.payload else None
            try:
                reply = getattr(self, f"_q_{name}")(payload)
                query.reply(query.key_expr, m.dumps(reply))
            except (InvalidInputError, ReplannerError, GoalRejected, WorldError, UnknownNameError) as err:
                query.reply_err(m.dumps({"error": str(err)}))
            except Exception as err:  # answer, log, and keep serving
                log.exception("request %s failed", name)
                query.reply_err(m.dumps({"error": f"internal error: {err}"}))
            finally:
                query.drop()

    def _q_goal(self, payload):
        req = m.parse_json(m.GoalRequest, payload, "goal")
        if (req.joints is None) == (req.pose is None):
            raise InvalidInputError("give exactly one of joints or pose")
        if req.pose is not None:
            p = req.pose
            target = PoseGoal(p.link, p.position, p.quat_xyzw, p.position_tolerance, p.orientation_tolerance)
        else:
            target = JointGoal(np.asarray(req.joints, float))
        goal = Goal(req.id, target, req.planner, req.deadline, req.velocity_scale, req.acceleration_scale, req.padding)
        q_goal = self.controller.submit(goal).accepted(timeout=10.0)
        return {"accepted": True, "id": req.id, "goal_joints": q_goal.tolist()}

    def _q_cancel(self, payload):
        req = m.parse_json(m.CancelRequest, payload, "cancel")
        self.controller.cancel(req.id)
        return {"canceled": req.id}

    def _q_state(self, payload):
        m.parse_json(m.Empty, payload, "state")
        return self.state()

    def _q_scene_add(self, payload):
        req = m.parse_json(m.SceneAdd, payload, "scene/add")
        shape, pose = m.shape_from(req.shape), req.pose.matrix()
        if encloses_base(shape, pose):
            raise InvalidInputError(
                f"{req.name!r} would enclose the robot's base: no configuration of the arm is free of it; "
                "check its size and position (metres, in the base frame)"
            )
        self.world.add(req.name, shape, pose)
        return {"added": req.name}

    def _q_scene_move(self, payload):
        req = m.parse_json(m.SceneMove, payload, "scene/move")
        self.world.move(req.name, req.pose.matrix())
        return {"moved": req.name}

    def _q_scene_remove(self, payload):
        req = m.parse_json(m.SceneName, payload, "scene/remove")
        self.world.remove(req.name)
        return {"removed": req.name}

    def _current_q(self) -> np.ndarray:
        if self.last_js is None:
            raise InvalidInputError("no joint state yet: cannot tell where the hand is")
        return self.last_js.position

    def _q_scene_attach(self, payload):
        req = m.parse_json(m.SceneAttach, payload, "scene/attach")
        q = self._current_q()
        obj = self.world.objects.get(req.name)
        if obj is not None and req.link in self.robot.link_names:
            gap = gap_to_links(self.robot, q, {req.link, *(req.touch_links or ())}, obj.shape, obj.pose)
            if gap > MAX_GRASP_GAP:  # a carried object is held: not a table half a metre below the hand
                raise InvalidInputError(
                    f"{req.name!r} is {gap:.3f} m from {req.link}: only an object the gripper holds (within "
                    f"{MAX_GRASP_GAP} m of the link or its touch_links) can be attached"
                )
        self.world.attach(req.name, req.link, q, req.touch_links, req.support)
        return {"attached": req.name, "link": req.link}

    def _q_scene_detach(self, payload):
        req = m.parse_json(m.SceneName, payload, "scene/detach")
        self.world.detach(req.name, self._current_q())
        return {"detached": req.name}

    def _q_scene_list(self, payload):
        m.parse_json(m.Empty, payload, "scene/list")
        snap = self.world.snapshot()
        objects = [
            {"name": o.name, "shape": m.shape_to_msg(o.shape), "pose": _pose(o.pose)} for o in snap.objects.values()
        ]
        attached = [
            {
                "name": a.name,
                "link": a.link,
                "shape": m.shape_to_msg(a.shape),
                "pose_in_link": _pose(a.T_link_object),
                "support": sorted(a.support),
            }
            for a in snap.attachments.values()
        ]
        return {"objects": objects, "attachments": attached}

    def _q_map_get(self, payload):
        req = m.parse_json(m.MapGet, payload or b"{}", "map/get")  # no payload: the whole map
        occ = self.world.snapshot().occupancy
        if occ is None or not len(occ):
            res = self.cfg.perception.resolution if self.cfg.perception is not None else None
            c = np.zeros((0, 3))
            out = {"resolution": res, "stamp": occ.stamp if occ is not None else None, "count": 0}
        else:
            c = occ.centers
            if req.min is not None:
                c = c[np.all((c >= req.min) & (c <= req.max), axis=1)]
            out = {"resolution": occ.resolution, "stamp": occ.stamp, "count": len(c)}
        if req.encoding == "float32":  # a 75k-voxel map as JSON lists costs the service ~0.1 s of its GIL per query
            return {**out, "encoding": "float32", "voxels": base64.b64encode(c.astype("<f4").tobytes()).decode()}
        return {**out, "voxels": c.round(4).tolist()}

    def _q_map_clear(self, payload):
        m.parse_json(m.Empty, payload, "map/clear")
        if self.perception is not None:
            self.perception.clear()
        else:
            self.world.set_occupancy(None)
        return {"cleared": True}


def _pose(T) -> dict:
    from replanner.model.transforms import matrix_to_quat

    return {"position": T[:3, 3].tolist(), "quat_xyzw": matrix_to_quat(T[:3, :3]).tolist()}


def run(cfg: ReplannerConfig, conf: zenoh.Config) -> None:
    """Serve until SIGINT or SIGTERM; then brake, withdraw the liveliness token and close."""
    from replanner.transport.session import open_session

    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    refusals = Refusals.capture() if access_control_on(conf) else None
    session = open_session(conf)
    try:
        service = Service(cfg, session, refusals=refusals).start()
        print(f"replanner: serving {service.keys.root} (Ctrl-C stops)", file=sys.stderr, flush=True)
        done.wait()
        log.info("stopping")
        service.stop()
    finally:
        session.close()
