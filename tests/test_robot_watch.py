"""The robot does not trust a dead service: SIGKILL of `replanner serve` mid-motion, real processes on loopback."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import yaml
from replanner_services.procs import Proc, replanner_cmd
from replanner_services.robot_node import KinematicRobotNode
from replanner_services.soak import children as _children

from replanner.apps.client import Client
from replanner.config import TransportConfig, parse_config
from replanner.model.robot import RobotModel
from replanner.trajectory.generator import TrajectoryGenerator
from replanner.transport import messages as m
from replanner.transport.session import make_config, open_session
from tests.conftest import CONFIGS
from tests.service_helpers import Stack, free_port, node_session
from tests.test_service import HOME, Recorder, _wait

FAR = [2.0, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigkill_of_the_service_mid_motion_the_robot_brakes_along_its_path(tmp_path):
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    port = free_port()
    data["transport"] = {**data.get("transport", {}), "endpoint": f"tcp/127.0.0.1:{port}"}
    data["controller"] = {"speed_separation": {"enabled": False}, "robot_watchdog": 1.0}
    cfg_path = tmp_path / "panda_watch.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    cfg = parse_config(data, base_dir=CONFIGS)
    robot = RobotModel.from_config(cfg.robot)
    stack = Stack(str(cfg_path), tmp_path, serve_args=("--no-cameras",), port=port)
    session = node_session(stack.endpoint)
    rec = None
    try:
        client = Client(session, "panda", timeout=10.0)
        stack.wait_alive(session, client.keys.alive)
        rec = Recorder(session, client.keys, robot.joint_names)
        _wait(lambda: client.state()["position"] is not None and rec.js, 30, "the robot's joint states", stack)
        assert client.send_goal(HOME).wait(30)["status"] == "succeeded"
        client.send_goal(FAR, velocity_scale=0.15)
        _wait(lambda: client.state()["state"] == "MONITORING", 20, "the motion", stack)
        _wait(lambda: np.abs(rec.latest()[2]).max() > 0.05, 10, "the arm at speed", stack)
        planning = _children(stack.serve.p.pid)
        assert planning, "the service's planning process"
        killed = time.time()
        os.kill(stack.serve.p.pid, signal.SIGKILL)
        _wait(lambda: np.abs(rec.latest()[2]).max() < 1e-9, 20, "the robot to stand", stack)
        stamps = np.array([s for s, _, _ in rec.js])
        Q = np.array([q for _, q, _ in rec.js])
        V = np.array([v for _, _, v in rec.js])
        after = stamps >= killed
        stood = stamps[after][np.abs(V[after]).max(axis=1) < 1e-9][0]
        # it braked on its own: short of the goal it was sent to, and braking began within 2 x the watchdog age
        assert np.abs(Q[-1] - np.array(FAR)).max() > 0.3, "the robot ran on to the goal"
        slowing = stamps[after][np.linalg.norm(V[after], axis=1) < 0.95 * np.linalg.norm(V[after][0])]
        assert slowing[0] - killed <= 2 * cfg.controller.robot_watchdog, slowing[0] - killed
        steps = np.abs(np.diff(Q[after], axis=0)) / np.maximum(np.diff(stamps[after])[:, None], 1e-3)
        assert np.all(steps <= robot.limits.velocity * 1.05)  # no jump on the way
        print(f"braking began {slowing[0] - killed:.3f} s after the kill; the arm stood {stood - killed:.3f} s after")
        _wait(lambda: not any(_alive(p) for p in planning), 10, "the planning process to end")
        assert "the service is lost" in stack.robot.tail(200)
    finally:
        if rec is not None:
            rec.close()
        session.close()
        stack.stop()


def test_a_trajectory_the_robot_refuses_mid_motion_makes_it_brake_along_its_path(panda_cfg):
    """A well-formed trajectory the robot cannot follow (it would jump) means the sender no longer wants the running
    motion: the robot brakes along its path instead of running on to the old goal (real Zenoh sessions)."""
    port = free_port()
    listener = open_session(make_config(TransportConfig(endpoint=f"tcp/127.0.0.1:{port}"), "service"))
    session = node_session(f"tcp/127.0.0.1:{port}")
    node = KinematicRobotNode(panda_cfg, session).start()
    robot, keys = node.robot, node.keys
    rec = Recorder(listener, keys, robot.joint_names)
    pub = listener.declare_publisher(keys.trajectory)
    gen = TrajectoryGenerator(robot)

    def send(traj, start):
        t, q, qd, qdd = traj.sample(panda_cfg.transport.trajectory_dt)
        pub.put(m.encode_trajectory(start, robot.joint_names, t, q, qd, qdd))

    try:
        _wait(lambda: rec.js, 10, "the robot's joint states")
        goal = robot.home + np.r_[1.2, -0.4, 0.5, -0.6, 0.8, 0.6, 1.0]
        send(gen.time(np.array([robot.home, goal]), velocity_scale=0.3), time.time() + 0.05)
        _wait(lambda: np.abs(rec.latest()[2]).max() > 0.05, 10, "the arm at speed")
        q_now = rec.latest()[1]
        send(gen.time(np.array([q_now + 0.3, goal])), time.time() + 0.02)  # starts 0.3 rad off: would jump
        _wait(lambda: node.rejected == 1 and np.abs(rec.latest()[2]).max() < 1e-9, 10, "the robot to stand")
        assert node.stops == 1
        q_end = rec.latest()[1]
        assert np.abs(q_end - goal).max() > 0.1, "the robot ran on to the old goal"
        Q = np.array([q for _, q, _ in rec.js])
        direction = (goal - robot.home) / np.linalg.norm(goal - robot.home)
        off = Q - robot.home - np.outer((Q - robot.home) @ direction, direction)
        assert np.abs(off).max() < 1e-6  # every state on the straight path: it braked along it, no jump
    finally:
        rec.close()
        node.stop()
        session.close()
        listener.close()


def test_sigkill_of_the_service_mid_motion_the_sim_brakes_along_its_path(tmp_path):
    """The same for the physics sim (`replanner sim`): it watches the service and brakes along its path."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    cfg_path = tmp_path / "demo_watch.yaml"
    cfg_path.write_text(
        yaml.safe_dump(
            {
                "base": str(CONFIGS / "demo.yaml"),
                "transport": {"endpoint": endpoint},
                "controller": {"speed_separation": {"enabled": False}, "robot_watchdog": 1.0},
            }
        )
    )
    from replanner.sim.config import load_cell_config

    cfg = load_cell_config(str(cfg_path))
    robot = RobotModel.from_config(cfg.robot)
    serve = Proc("serve", replanner_cmd("serve", "-c", str(cfg_path), "--no-cameras", "-l", endpoint), tmp_path)
    sim = Proc(
        "sim", replanner_cmd("sim", "-c", str(cfg_path), "--no-operator", "--no-cameras", "-e", endpoint), tmp_path
    )
    session = node_session(endpoint)
    rec = None
    try:
        client = Client(session, "panda", timeout=10.0)
        _wait(lambda: list(session.liveliness().get(client.keys.alive, timeout=0.5)), 60, "the service")
        rec = Recorder(session, client.keys, robot.joint_names)
        _wait(lambda: client.state()["not_ready"] is None and rec.js, 60, "the sim's joint states")
        assert client.send_goal(HOME).wait(60)["status"] == "succeeded", serve.tail()
        client.send_goal(FAR, velocity_scale=0.15)
        _wait(lambda: client.state()["state"] == "MONITORING", 30, "the motion")
        _wait(lambda: np.abs(rec.latest()[2]).max() > 0.05, 10, "the arm at speed")
        killed = time.time()
        os.kill(serve.p.pid, signal.SIGKILL)
        _wait(lambda: np.abs(rec.latest()[2]).max() < 1e-3, 20, "the arm to stand")  # physics: not exactly 0
        stamps = np.array([s for s, _, _ in rec.js])
        Q = np.array([q for _, q, _ in rec.js])
        V = np.array([v for _, _, v in rec.js])
        after = stamps >= killed
        assert np.abs(Q[-1] - np.array(FAR)).max() > 0.3, "the sim ran on to the goal"
        slowing = stamps[after][np.linalg.norm(V[after], axis=1) < 0.95 * np.linalg.norm(V[after][0])]
        assert slowing[0] - killed <= 2 * cfg.controller.robot_watchdog, slowing[0] - killed
        _wait(lambda: "the service is lost" in sim.tail(200), 10, "the sim's log line")
    finally:
        if rec is not None:
            rec.close()
        session.close()
        sim.stop()
        serve.stop()


def test_a_controller_stuck_in_one_step_silences_the_heartbeat_and_the_robot_brakes(tmp_path):
    """The service process lives, but its controller hangs in a step (a compile, a lock, a bug): its status must stop
    too, or the robot runs on unwatched. A real kinematic robot process; the service in this process, its step held."""
    import threading
    from types import SimpleNamespace

    from replanner_services.serve import Service

    from replanner.control import Input
    from replanner.transport.session import make_config, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    data["transport"] = {**data.get("transport", {}), "endpoint": endpoint}
    data["controller"] = {"speed_separation": {"enabled": False}, "robot_watchdog": 1.0}
    cfg_path = tmp_path / "panda_watch.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    cfg = parse_config(data, base_dir=CONFIGS).model_copy(update={"perception": None})
    robot = RobotModel.from_config(cfg.robot)
    served = open_session(make_config(cfg.transport, "service"))
    service = Service(cfg, served, planning_process=False).start()
    proc = Proc("robot", replanner_cmd("robot", "--kinematic", "-c", str(cfg_path), "-e", endpoint), tmp_path)
    session = node_session(endpoint)
    rec, release = None, threading.Event()
    try:
        client = Client(session, "panda", timeout=10.0)
        rec = Recorder(session, client.keys, robot.joint_names)
        _wait(lambda: client.state()["position"] is not None and rec.js, 30, "the robot's joint states")
        assert client.send_goal(HOME).wait(30)["status"] == "succeeded"
        client.send_goal(FAR, velocity_scale=0.15)
        _wait(lambda: client.state()["state"] == "MONITORING", 20, "the motion")
        _wait(lambda: np.abs(rec.latest()[2]).max() > 0.05, 10, "the arm at speed")
        service.controller.inbox.put(Input.CALL, lambda: release.wait(30))  # the next step hangs until released
        held = time.time()
        _wait(lambda: np.abs(rec.latest()[2]).max() < 1e-9, 20, "the robot to stand", SimpleNamespace(logs=proc.tail))
        stamps = np.array([s for s, _, _ in rec.js])
        V = np.array([v for _, _, v in rec.js])
        Q = np.array([q for _, q, _ in rec.js])
        after = stamps >= held
        slowing = stamps[after][np.linalg.norm(V[after], axis=1) < 0.95 * np.linalg.norm(V[after][0])]
        assert np.abs(Q[-1] - np.array(FAR)).max() > 0.3, "the robot ran on to the goal"
        assert slowing[0] - held <= 2 * cfg.controller.robot_watchdog, slowing[0] - held
        assert "the service is lost" in proc.tail(200)
        assert service.controller.inbox.stuck_for() > 0.5
        print(f"braking began {slowing[0] - held:.3f} s after the controller hung")
        release.set()
        _wait(lambda: service.controller.inbox.stuck_for() == 0.0, 10, "the controller to step again")
        heard = []
        sub = session.declare_subscriber(client.keys.status, lambda s: heard.append(s))
        _wait(lambda: heard, 5, "the status stream again")
        sub.undeclare()
    finally:
        release.set()
        if rec is not None:
            rec.close()
        session.close()
        proc.stop()
        service.stop()
        served.close()
