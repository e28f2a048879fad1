"""The Zenoh service end to end: `serve` and `robot --kinematic` as separate processes on loopback, clouds
rendered by pybullet in this process and published over Zenoh, the client library and the CLI."""

from __future__ import annotations

import json
import subprocess
import threading
import time

import numpy as np
import pytest
import yaml
from replanner_services.sim_node import CameraNode

from replanner.apps.client import Client
from replanner.config import parse_config
from replanner.model.geometry import Box
from replanner.model.robot import RobotModel
from replanner.model.transforms import make_transform
from replanner.sim.scene import PyBulletScene
from replanner.transport import messages as m
from replanner.world.scene import scene_from_config
from tests.conftest import CONFIGS
from tests.service_helpers import Stack, free_port, node_session, replanner_cmd

A = [-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785]
B = [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785]
HOME = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
SLOW = 0.35


class Recorder:
    """Everything the service and the robot publish, as decoded messages with their arrival time."""

    def __init__(self, session, keys, joint_names):
        self.joint_names = joint_names
        self.js: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.transitions: list[dict] = []
        self.rejections: list[dict] = []
        self.trajectories: list[bytes] = []
        self.lock = threading.Lock()
        self.subs = [
            session.declare_subscriber(keys.joint_states, self._js),
            session.declare_subscriber(keys.transitions, lambda s: self.transitions.append(_json(s))),
            session.declare_subscriber(keys.rejections, lambda s: self.rejections.append(_json(s))),
            session.declare_subscriber(keys.trajectory, lambda s: self.trajectories.append(s.payload.to_bytes())),
        ]

    def _js(self, sample):
        try:
            stamp, q, qd = m.decode_joint_state(sample.payload.to_bytes(), self.joint_names)
        except m.DecodeError:
            return  # the bad-input test's own messages
        with self.lock:
            self.js.append((stamp, q, qd))
            if len(self.js) > 20000:
                del self.js[:10000]

    def latest(self):
        with self.lock:
            return self.js[-1]

    def since(self, t0: float) -> np.ndarray:
        with self.lock:
            return np.array([q for stamp, q, _ in self.js if stamp >= t0])

    def edges(self, goal_id: str) -> list[tuple[str, str, str]]:
        return [(t["from"], t["to"], t["trigger"]) for t in self.transitions if t["goal_id"] == goal_id]

    def close(self):
        for s in self.subs:
            s.undeclare()


def _json(sample) -> dict:
    return json.loads(sample.payload.to_bytes())


@pytest.fixture(scope="module")
def svc(tmp_path_factory):
    """serve + robot processes, a camera publishing 320x240 clouds of a pybullet scene, a client, a recorder."""
    tmp = tmp_path_factory.mktemp("service")
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    front = data["perception"]["sensors"][0]
    front.update(width=320, height=240)
    data["perception"]["sensors"] = [front]
    # the service's plumbing and replanning: speed and separation (which stops the arm near the dropped box, as it
    # must near anything that may be a person) is tested on its own (tests/test_ssm.py)
    # the camera renders in this test's process: beside busy processes it can miss a second of frames, and the service
    # then (rightly) brakes for a silent camera; that watchdog is tested on its own (test_controller, cameras_on)
    data["controller"] = {"speed_separation": {"enabled": False}, "sensor_timeout": 3.0}
    stack_dir = tmp / "cfg"
    stack_dir.mkdir()
    cfg_path = stack_dir / "panda_test.yaml"
    stack = None
    try:
        # the endpoint is in the file, so the CLI commands find the service with -c alone
        port = free_port()
        data["transport"] = {**data.get("transport", {}), "endpoint": f"tcp/127.0.0.1:{port}"}
        cfg_path.write_text(yaml.safe_dump(data))
        stack = Stack(str(cfg_path), tmp, port=port)
        cfg = parse_config(data, base_dir=CONFIGS)
        robot = RobotModel.from_config(cfg.robot)
        session = node_session(stack.endpoint)
        client = Client(session, "panda", timeout=10.0)
        stack.wait_alive(session, client.keys.alive)
        rec = Recorder(session, client.keys, robot.joint_names)
        cameras = CameraNode(cfg, session, scene_from_config(cfg), rate_hz=10.0, robot=robot).start()
        camera = cameras.clouds
        _wait(lambda: rec.js and camera.frames >= 3, 20, "joint states and clouds", stack)
        _wait(lambda: client.state()["not_ready"] is None, 30, "the service ready for goals", stack)
        ns = type("Svc", (), {})()
        ns.stack, ns.cfg, ns.cfg_path, ns.robot, ns.session = stack, cfg, cfg_path, robot, session
        ns.client, ns.rec, ns.camera = client, rec, camera
        yield ns
        cameras.stop()
        rec.close()
        client.close()
        session.close()
    finally:
        if stack is not None:
            stack.stop()


def _wait(pred, timeout, what, stack=None):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}" + (f"\n{stack.logs()}" if stack else ""))


def _move(svc, joints=None, pose=None, timeout=30.0, **kw) -> dict:
    fut = svc.client.send_goal(joints, pose, **kw)
    res = fut.wait(timeout)
    assert res is not None, f"no result for {fut.id}\n{svc.stack.logs()}"
    return res | {"id": fut.id}


def _at_rest(svc, timeout=5.0):
    _wait(
        lambda: np.abs(svc.rec.latest()[2]).max() < 1e-6 and svc.client.state()["state"] == "WAITING",
        timeout,
        "the arm at rest",
        svc.stack,
    )


# --------------------------------------------------------------------------------------------- goals
def test_liveliness_token_is_up(svc):
    assert svc.client.wait_alive(timeout=5.0)


def test_joint_goal_succeeds(svc):
    res = _move(svc, joints=A)
    assert res["status"] == "succeeded", res
    _at_rest(svc)
    assert np.abs(svc.rec.latest()[1] - A).max() < 1e-3
    # the result and the transitions come on different keys: one may overtake the other
    _wait(lambda: len(svc.rec.edges(res["id"])) >= 3, 5.0, "the goal's transitions", svc.stack)
    assert svc.rec.edges(res["id"]) == [
        ("WAITING", "PLANNING", "plan"),
        ("PLANNING", "MONITORING", "start_motion"),
        ("MONITORING", "WAITING", "succeeded"),
    ]


def test_cartesian_goal_succeeds_checked_by_pybullet(svc):
    target = [0.45, -0.2, 0.3]
    res = _move(svc, pose={"link": "panda_grasptarget", "position": target, "quat_xyzw": [1, 0, 0, 0]})
    assert res["status"] == "succeeded", res
    _at_rest(svc)
    scene = PyBulletScene(svc.robot, room=False)
    try:
        import pybullet as pb

        scene.set_q(svc.rec.latest()[1])
        state = pb.getLinkState(
            scene.body,
            scene.link_index["panda_grasptarget"],
            computeForwardKinematics=True,
            physicsClientId=scene.client,
        )
        pos, quat = np.array(state[4]), np.array(state[5])
    finally:
        scene.close()
    assert np.linalg.norm(pos - target) < 2e-3, pos
    assert abs(abs(quat[0]) - 1.0) < 2e-3, quat  # 180 deg about x: pointing down


def test_blocked_path_is_replanned_without_collision(svc):
    assert _move(svc, joints=A)["status"] == "succeeded"
    _at_rest(svc)
    t0 = time.time()
    fut = svc.client.send_goal(B, velocity_scale=SLOW)
    _wait(lambda: ("PLANNING", "MONITORING", "start_motion") in svc.rec.edges(fut.id), 10, "motion", svc.stack)
    mid = np.array(A) + 0.7 * (np.array(B) - np.array(A))
    c = svc.robot.link_pose(mid, "panda_hand")[:3, 3]
    time.sleep(0.3)
    box = (Box(size=(0.14, 0.14, 0.14)), make_transform(c))
    svc.camera.add_obstacle("intruder", *box)  # only the camera sees it: the service learns of it from clouds
    try:
        res = fut.wait(30)
        assert res is not None and res["status"] == "succeeded", (res, svc.rec.edges(fut.id), svc.stack.logs())
        e = svc.rec.edges(fut.id)
        assert ("MONITORING", "MONITORING_WITH_PLANNING_PENDING", "blocked") in e, e
        assert any(
            t in e
            for t in [
                ("MONITORING_WITH_PLANNING_PENDING", "MONITORING", "spliced"),
                ("HOLDING", "MONITORING", "start_motion"),
            ]
        ), e
        # the oracle: every joint state the robot reported, against the box in pybullet
        Q = svc.rec.since(t0)
        scene = PyBulletScene(svc.robot, room=False)
        try:
            scene.add("intruder", *box)
            hits = [q for q in Q[::2] if scene.contacts(q)]
        finally:
            scene.close()
        assert not hits, f"{len(hits)} of {len(Q[::2])} reported states touch the box"
    finally:
        svc.camera.remove_obstacle("intruder")
    _wait(lambda: svc.client.state()["map_voxels"] < 50, 10, "the box to leave the map", svc.stack)


def test_cancel_brakes_and_reports(svc):
    _at_rest(svc)
    start = svc.rec.latest()[1]
    target = A if np.abs(start - np.array(B)).max() < 0.1 else B
    fut = svc.client.send_goal(target, velocity_scale=SLOW)
    _wait(lambda: svc.client.state()["state"] == "MONITORING", 10, "motion", svc.stack)
    time.sleep(0.6)
    assert svc.client.cancel(fut.id) == {"canceled": fut.id}
    res = fut.wait(5)
    assert res is not None and res["status"] == "canceled", res
    _at_rest(svc, timeout=3.0)
    q = svc.rec.latest()[1]
    assert np.abs(q - start).max() > 0.05 and np.abs(q - np.array(target)).max() > 0.05  # stopped on the way


def test_new_goal_preempts(svc):
    _at_rest(svc)
    f1 = svc.client.send_goal(A, velocity_scale=SLOW)
    _wait(lambda: svc.client.state()["state"] == "MONITORING", 10, "motion", svc.stack)
    time.sleep(0.3)
    f2 = svc.client.send_goal(HOME)
    r1, r2 = f1.wait(10), f2.wait(20)
    assert r1 is not None and r1["status"] == "preempted" and f2.id in r1["reason"], r1
    assert r2 is not None and r2["status"] == "succeeded", r2
    _at_rest(svc)
    assert np.abs(svc.rec.latest()[1] - HOME).max() < 1e-3


# --------------------------------------------------------------------------------------------- bad input
def _joint_state(names, q, stamp=None) -> bytes:
    return m.encode_joint_state(time.time() if stamp is None else stamp, names, q)


def _raw_js(names=None, pos=None, vel=(), eff=(), sec=None, nanosec=0, frame="") -> bytes:
    """A JointState as any publisher could write it, right or wrong (rosbags' own serializer)."""
    ts = m.typestore()
    names = list(NAMES if names is None else names)
    pos = np.asarray(HOME if pos is None else pos, np.float64)
    sec = int(time.time()) if sec is None else sec
    header = ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame
    )
    msg = ts.types[m.JOINT_STATE](
        header=header, name=names, position=pos, velocity=np.asarray(vel, np.float64), effort=np.asarray(eff, float)
    )
    return bytes(ts.serialize_cdr(msg, m.JOINT_STATE))


def _cloud_wh(width, height, row_step=None, z_at=8) -> bytes:
    """A PointCloud2 of width x height points as any publisher could write it (rosbags' own serializer)."""
    ts = m.typestore()
    F = ts.types["sensor_msgs/msg/PointField"]
    pts = np.random.default_rng(0).uniform(-0.2, 0.2, (width * height, 3)).astype(np.float32) + [0, 0, 1.5]
    msg = ts.types[m.POINT_CLOUD2](
        header=m.make_header(time.time(), "front"),
        height=height,
        width=width,
        fields=[F(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", z_at))],
        is_bigendian=False,
        point_step=12,
        row_step=12 * width if row_step is None else row_step,
        data=pts.astype(np.float32).view(np.uint8).ravel(),
        is_dense=True,
    )
    return bytes(ts.serialize_cdr(msg, m.POINT_CLOUD2))


def _cloud(n, stamp=None) -> bytes:
    pts = np.random.default_rng(0).uniform(-0.2, 0.2, (n, 3)).astype(np.float32) + [0, 0, 1.5]
    return m.encode_cloud(time.time() if stamp is None else stamp, pts, "front")


NAMES = [f"panda_joint{i}" for i in range(1, 8)]
GOOD = {"id": "g"}

REQUESTS = [
    # (name, key, payload, expected words in the error)
    ("malformed JSON", "goal", b'{"id": "x", "joints": [', "not valid JSON"),
    ("not an object", "goal", b"[1, 2, 3]", "must be a JSON object"),
    ("not UTF-8", "goal", b"\xff\xfe\x00", "not valid JSON"),
    ("empty goal", "goal", b"", "empty payload"),
    ("missing id", "goal", {"joints": HOME}, "id: Field required"),
    ("unknown field", "goal", {"id": "g", "jionts": HOME}, "jionts: unknown field"),
    ("wrong type", "goal", {"id": "g", "joints": "home"}, "joints"),
    ("wrong joint count", "goal", {"id": "g", "joints": [0.0] * 6}, "7 values"),
    ("NaN joint", "goal", b'{"id": "g", "joints": [NaN, 0, 0, -2, 0, 1.5, 0.7]}', "finite"),
    ("out of limits", "goal", {"id": "g", "joints": [0.0, 3.0, 0.0, -2.0, 0.0, 1.5, 0.7]}, "limit"),
    ("goal in collision", "goal", {"id": "g", "joints": [0.0, 1.5, 0.0, -0.5, 0.0, 1.5, 0.7]}, "collision"),
    ("NaN deadline", "goal", b'{"id": "g", "joints": [0, 0, 0, -2, 0, 1.5, 0.7], "deadline": NaN}', "finite number"),
    (
        "NaN acceleration scale",
        "goal",
        b'{"id": "g", "joints": [0, 0, 0, -2, 0, 1.5, 0.7], "acceleration_scale": NaN}',
        "acceleration_scale: Input should be a finite number",
    ),
    ("number as a string", "goal", {"id": "g", "joints": HOME, "velocity_scale": "0.4"}, "not a string"),
    ("true as a number", "goal", {"id": "g", "joints": HOME, "velocity_scale": True}, "not true or false"),
    ("padding negative", "goal", {"id": "g", "joints": HOME, "padding": -0.01}, "padding: Input should be greater"),
    ("JSON nested 100k deep", "goal", b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    (
        "unknown field in a pose",
        "goal",
        {"id": "g", "pose": {"link": "panda_hand", "position": [0.4, 0, 0.4], "orientation": [0, 0, 0, 1]}},
        "pose.orientation: unknown field; allowed: position, quat_xyzw, link",
    ),
    (
        "unknown field in a shape",
        "scene/add",
        {"name": "x", "shape": {"type": "box", "size": [0.1] * 3, "radius": 1}, "pose": {"position": [0.5, 0.5, 1]}},
        "shape.box.radius: unknown field; allowed: type, size",
    ),
    (
        "name with a slash",
        "scene/add",
        {"name": "a/b", "shape": {"type": "sphere", "radius": 0.1}, "pose": {"position": [0.5, 0.5, 1]}},
        "letters, digits",
    ),
    (
        "name with a NUL",
        "scene/add",
        {"name": "a\u0000", "shape": {"type": "sphere", "radius": 0.1}, "pose": {"position": [0.5, 0.5, 1]}},
        "letters, digits",
    ),
    (
        "a box around the robot",
        "scene/add",
        {"name": "hall", "shape": {"type": "box", "size": [1e6, 1e6, 1e6]}, "pose": {"position": [0, 0, 0]}},
        "enclose the robot's base",
    ),
    ("attach to the fixed base", "scene/attach", {"name": "table", "link": "panda_link0"}, "fixed to the base"),
    ("attach the table to the hand", "scene/attach", {"name": "table", "link": "panda_hand"}, "only an object the"),
    ("padding too large", "goal", {"id": "g", "joints": HOME, "padding": 0.5}, "padding: Input should be less"),
    ("deadline as a string", "goal", {"id": "g", "joints": HOME, "deadline": "1"}, "deadline: Input should be a valid"),
    ("a boolean joint", "goal", {"id": "g", "joints": [True, *HOME[1:]]}, "joints.0: Input should be a valid"),
    ("goal id too long", "goal", {"id": "g" * 129, "joints": HOME}, "at most 128"),
    ("empty name", "scene/remove", {"name": ""}, "at least 1 character"),
    ("name too long", "scene/remove", {"name": "n" * 129}, "at most 128"),
    ("map box NaN", "map/get", b'{"min": [NaN, 0, 0], "max": [1, 1, 1]}', "finite"),
    ("pose position of two", "scene/move", {"name": "table", "pose": {"position": [0, 0]}}, "at least 3"),
    (
        "quaternion as strings",
        "scene/move",
        {"name": "table", "pose": {"position": [0, 0, 0], "quat_xyzw": ["0"] * 4}},
        "not a string",
    ),  # fmt: skip
    ("cancel with a number", "cancel", {"id": 5}, "id: Input should be a valid string"),
    ("a null name", "scene/remove", {"name": None}, "valid string"),
    (
        "both targets",
        "goal",
        {"id": "g", "joints": HOME, "pose": {"link": "panda_hand", "position": [0.4, 0, 0.4]}},
        "exactly one",
    ),
    ("no target", "goal", {"id": "g"}, "exactly one"),
    ("unknown planner", "goal", {"id": "g", "joints": HOME, "planner": "Teleport"}, "Teleport"),
    ("velocity scale > 1", "goal", {"id": "g", "joints": HOME, "velocity_scale": 2.0}, "velocity_scale"),
    ("unknown link", "goal", {"id": "g", "pose": {"link": "panda_nose", "position": [0.4, 0, 0.4]}}, "panda_nose"),
    ("unreachable pose", "goal", {"id": "g", "pose": {"link": "panda_hand", "position": [3.0, 0, 0.4]}}, "reach"),
    ("negative deadline", "goal", {"id": "g", "joints": HOME, "deadline": -1}, "deadline"),
    ("cancel unknown id", "cancel", {"id": "nobody"}, "nobody"),
    ("cancel without id", "cancel", {}, "id: Field required"),
    (
        "add unknown shape",
        "scene/add",
        {"name": "x", "shape": {"type": "cone", "radius": 1}, "pose": {"position": [0, 0, 1]}},
        "shape",
    ),
    (
        "add negative size",
        "scene/add",
        {"name": "x", "shape": {"type": "box", "size": [0.1, -0.1, 0.1]}, "pose": {"position": [0.5, 0.5, 1]}},
        "> 0",
    ),
    (
        "add zero quaternion",
        "scene/add",
        {
            "name": "x",
            "shape": {"type": "sphere", "radius": 0.1},
            "pose": {"position": [0.5, 0.5, 1], "quat_xyzw": [0, 0, 0, 0]},
        },
        "quaternion",
    ),
    (
        "add taken name",
        "scene/add",
        {"name": "table", "shape": {"type": "sphere", "radius": 0.1}, "pose": {"position": [0.5, 0.5, 1]}},
        "already exists",
    ),
    (
        "add mesh bad face",
        "scene/add",
        {
            "name": "m",
            "shape": {"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "faces": [[0, 1, 9]]},
            "pose": {"position": [2, 2, 2]},
        },
        "face",
    ),
    ("move unknown object", "scene/move", {"name": "ghost", "pose": {"position": [0, 0, 1]}}, "ghost"),
    ("remove unknown object", "scene/remove", {"name": "ghost"}, "ghost"),
    ("attach unknown object", "scene/attach", {"name": "ghost", "link": "panda_hand"}, "ghost"),
    ("attach to unknown link", "scene/attach", {"name": "table", "link": "panda_tail"}, "panda_tail"),
    ("detach what is not attached", "scene/detach", {"name": "table"}, "table"),
    ("state with garbage", "state", b"?", "not valid JSON"),
    ("map clear with a field", "map/clear", {"all": True}, "all: unknown field"),
    ("map box upside down", "map/get", {"min": [1, 0, 0], "max": [0, 1, 1]}, "must be <= max"),
    ("map box half given", "map/get", {"min": [0, 0, 0]}, "give both min and max"),
]

STREAMS = [
    # (name, key suffix, payload made when sent, source counted, expected words in the rejection)
    ("joint state not CDR", "joint_states", lambda: b"hello", "joint_states", "CDR"),
    ("joint state truncated", "joint_states", lambda: _joint_state(NAMES, HOME)[:40], "joint_states", "CDR"),
    (
        "joint state missing joints",
        "joint_states",
        lambda: _joint_state(NAMES[:6], HOME[:6]),
        "joint_states",
        "missing",
    ),
    ("joint state NaN", "joint_states", lambda: _joint_state(NAMES, [np.nan] * 7), "joint_states", "NaN"),
    ("joint state positions short", "joint_states", lambda: _raw_js(pos=HOME[:6]), "joint_states", "7 names but 6"),
    (
        "joint state duplicate name",
        "joint_states",
        lambda: _raw_js(NAMES + NAMES[:1], np.r_[HOME, 0.3]),
        "joint_states",
        "named more than once",
    ),
    ("joint state velocity short", "joint_states", lambda: _raw_js(vel=[0.0] * 3), "joint_states", "3 velocity"),
    (
        "joint state velocity NaN",
        "joint_states",
        lambda: _raw_js(vel=[np.nan] * 7),
        "joint_states",
        "velocity contains",
    ),
    ("joint state effort long", "joint_states", lambda: _raw_js(eff=[0.0] * 9), "joint_states", "9 effort"),
    ("joint state effort inf", "joint_states", lambda: _raw_js(eff=[np.inf] * 7), "joint_states", "effort contains"),
    ("joint state nanosec 4e9", "joint_states", lambda: _raw_js(nanosec=4_000_000_000), "joint_states", "not a time"),
    ("joint state negative sec", "joint_states", lambda: _raw_js(sec=-5), "joint_states", "not a time"),
    ("joint state foreign frame", "joint_states", lambda: _raw_js(frame="map"), "joint_states", "frame_id 'map'"),
    (
        "joint state past its limit",
        "joint_states",
        lambda: _joint_state(NAMES, np.r_[10.0, HOME[1:]]),
        "joint_states",
        "panda_joint1 = 10.0000 rad is outside its limits",
    ),
    (
        "joint state 10 s old",
        "joint_states",
        lambda: _joint_state(NAMES, HOME, time.time() - 10),
        "joint_states",
        "s old",
    ),
    (
        "joint state from the future",
        "joint_states",
        lambda: _joint_state(NAMES, HOME, time.time() + 10),
        "joint_states",
        "in the future",
    ),
    (
        "joint state older than the last",
        "joint_states",
        lambda: _joint_state(NAMES, HOME, time.time() - 0.5),
        "joint_states",
        "not newer than the last",
    ),
    ("cloud not CDR", "clouds/front", lambda: b"\x00\x01\x00\x00garbage", "clouds/front", "CDR"),
    ("cloud truncated", "clouds/front", lambda: _cloud(500)[:300], "clouds/front", "CDR"),
    ("cloud larger than configured", "clouds/front", lambda: _cloud(320 * 240 + 1), "clouds/front", "max_points"),
    ("cloud from an unknown sensor", "clouds/rear", lambda: _cloud(100), "clouds/rear", "unknown sensor"),
    ("cloud 10x10 organized", "clouds/front", lambda: _cloud_wh(10, 10), "clouds/front", "got 10x10"),
    ("cloud row_step wrong", "clouds/front", lambda: _cloud_wh(50, 1, row_step=7), "clouds/front", "row_step 7"),
    ("cloud fields overrun", "clouds/front", lambda: _cloud_wh(50, 1, z_at=12), "clouds/front", "overrun point_step"),
    ("cloud from the past", "clouds/front", lambda: _cloud(100, stamp=1.0), "clouds/front", "not newer"),
    (
        "cloud with a bad pose",
        "clouds/front",
        lambda: (_cloud(100), b'{"position": [0, 0]}'),
        "clouds/front",
        "position",
    ),
]


def _observable(svc) -> dict:
    st = svc.client.state()
    keep = ("state", "goal_id", "objects", "attachments", "map_voxels", "position")
    return {k: st[k] for k in keep} | {"scene": svc.client.scene()}


def test_bad_requests_get_clear_errors_and_change_nothing(svc):
    _at_rest(svc)
    before = _observable(svc)
    wrong = []
    for name, key, payload, words in REQUESTS:
        raw = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        replies = list(svc.session.get(f"{svc.client.keys.root}/{key}", payload=raw or None, timeout=10.0))
        if len(replies) != 1 or replies[0].err is None:
            wrong.append(f"{name}: not answered with an error")
            continue
        error = json.loads(replies[0].err.payload.to_bytes())["error"]
        if words.lower() not in error.lower():
            wrong.append(f"{name}: {error!r} does not mention {words!r}")
    assert not wrong, "\n".join(wrong)
    assert _observable(svc) == before
    assert len(REQUESTS) + len(STREAMS) >= 20


def test_bad_stream_messages_are_counted_and_change_nothing(svc):
    _at_rest(svc)
    before = _observable(svc)
    counts = dict(svc.client.state()["rejections"])
    svc.camera.paused = True  # the service keeps the newest frame per camera: a good one must not replace a bad one
    time.sleep(0.3)
    for name, key, payload, source, words in STREAMS:
        n_before = len(svc.rec.rejections)
        data = payload()
        data, attachment = data if isinstance(data, tuple) else (data, None)
        svc.session.put(f"{svc.client.keys.root}/{key}", data, attachment=attachment)
        _wait(lambda n_before=n_before: len(svc.rec.rejections) > n_before, 5, f"the rejection of {name}", svc.stack)
        rej = svc.rec.rejections[-1]
        assert rej["source"] == source and words.lower() in rej["reason"].lower(), (name, rej)
        counts[source] = counts.get(source, 0) + 1
    svc.camera.paused = False
    after = svc.client.state()["rejections"]
    assert {k: after.get(k) for k in counts} == counts
    assert _observable(svc) == before
    assert svc.stack.serve.alive()
    res = _move(svc, joints=HOME)
    assert res["status"] == "succeeded", (res, svc.stack.logs())  # still serving


# --------------------------------------------------------------------------------------------- CDR
def test_messages_decode_as_standard_ros2_types(svc):
    """What the service and the robot put on the wire is read by rosbags' stock typestore (as rmw_zenoh would)."""
    from rosbags.typesys import Stores, get_typestore

    n = len(svc.rec.trajectories)
    res = _move(svc, joints=A)
    assert res["status"] == "succeeded", res
    for store in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY):
        ts = get_typestore(store)
        traj = ts.deserialize_cdr(svc.rec.trajectories[n], "trajectory_msgs/msg/JointTrajectory")
        assert list(traj.joint_names) == NAMES and traj.header.frame_id == "panda_link0"
        t = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in traj.points]
        assert t[0] == 0.0 and np.allclose(np.diff(t)[:-1], 0.01, atol=1e-6) and 0 < t[-1] - t[-2] <= 0.01 + 1e-6
        assert np.allclose(traj.points[-1].positions, A, atol=1e-4)
        assert abs(traj.header.stamp.sec + traj.header.stamp.nanosec * 1e-9 - time.time()) < 30
        got = []
        sub = svc.session.declare_subscriber(
            svc.client.keys.joint_states, lambda s, got=got: got.append(s.payload.to_bytes())
        )
        sub2 = svc.session.declare_subscriber(
            svc.client.keys.cloud("front"), lambda s, got=got: got.append(s.payload.to_bytes())
        )
        _wait(lambda got=got: len(got) > 40, 5, "joint states and a cloud")
        sub.undeclare()
        sub2.undeclare()
        js = [b for b in got if len(b) < 10000][0]
        cloud = [b for b in got if len(b) > 10000][0]
        msg = ts.deserialize_cdr(js, "sensor_msgs/msg/JointState")
        assert list(msg.name) == NAMES and len(msg.position) == 7 and len(msg.velocity) == 7
        pc = ts.deserialize_cdr(cloud, "sensor_msgs/msg/PointCloud2")
        assert (pc.width, pc.height, pc.point_step) == (320, 240, 12)
        assert [f.name for f in pc.fields] == ["x", "y", "z"]


# --------------------------------------------------------------------------------------------- CLI
def _cli(svc, *args, timeout=60) -> subprocess.CompletedProcess:
    return subprocess.run(replanner_cmd(*args), capture_output=True, text=True, timeout=timeout)


def test_cli_goal_status_scene_cancel(svc):
    c = str(svc.cfg_path)
    r = _cli(svc, "goal", "-c", c, "--joints", ",".join(map(str, HOME)))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["status"] == "succeeded" and out["elapsed_s"] > 0
    r = _cli(svc, "goal", "-c", c, "--pose", "0.4,0.1,0.4,1,0,0,0")
    assert r.returncode == 0 and json.loads(r.stdout)["status"] == "succeeded", r.stderr
    r = _cli(svc, "status", "-c", c)
    assert r.returncode == 0 and json.loads(r.stdout)["state"] == "WAITING"
    r = _cli(svc, "scene", "-c", c, "add", "cli_box", "--box", "0.1,0.1,0.1", "--position", "0.6,-0.5,0.3")
    assert r.returncode == 0 and json.loads(r.stdout) == {"added": "cli_box"}, r.stderr
    r = _cli(svc, "scene", "-c", c, "list")
    assert {o["name"] for o in json.loads(r.stdout)["objects"]} == {"table", "cli_box"}
    r = _cli(svc, "scene", "-c", c, "remove", "cli_box")
    assert r.returncode == 0, r.stderr
    r = _cli(svc, "cancel", "-c", c, "nobody")
    assert r.returncode == 2 and "nobody" in r.stderr
    r = _cli(svc, "goal", "-c", c, "--joints", "0,0,zero")
    assert r.returncode == 2 and "--joints" in r.stderr
    r = _cli(svc, "goal", "-c", c, "--joints", "0,0,0")
    assert r.returncode == 2 and "7 values" in r.stderr


def test_no_service_gives_a_clear_error():
    r = subprocess.run(
        replanner_cmd("status", "-e", f"tcp/127.0.0.1:{free_port()}"), capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "replanner serve" in r.stderr, r.stderr


# --------------------------------------------------------------------------------------------- shutdown
def test_sigterm_brakes_the_moving_arm_then_withdraws_liveliness(svc):
    """Last: stops the module's service."""
    _at_rest(svc)
    tokens: list[str] = []
    sub = svc.session.liveliness().declare_subscriber(
        svc.client.keys.alive, lambda s: tokens.append(str(s.kind)), history=True
    )
    _wait(lambda: tokens, 5, "the liveliness token")
    q0 = svc.rec.latest()[1]
    target = A if np.abs(q0 - np.array(B)).max() < 0.1 else B
    results = []
    svc.client.watch(on_result=results.append)
    fut = svc.client.send_goal(target, velocity_scale=0.2)
    _wait(lambda: svc.client.state()["state"] == "MONITORING", 10, "motion", svc.stack)
    time.sleep(0.5)
    assert svc.stack.serve.stop() == 0, svc.stack.logs()
    _wait(lambda: "SampleKind.DELETE" in tokens, 10, "the token to go")
    sub.undeclare()
    assert fut.wait(1) is not None and fut.result["status"] == "canceled", fut.result
    time.sleep(1.0)  # the robot keeps running its last (brake) trajectory
    _, q, qd = svc.rec.latest()
    assert np.abs(qd).max() < 1e-6, "the arm still moves after the service stopped"
    assert np.abs(q - np.array(target)).max() > 0.05
