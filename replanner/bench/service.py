"""`replanner bench service`: end-to-end latency over Zenoh with `serve` and `robot --kinematic` as processes.

Request -> result of simple joint goals, split into what the arm needs (the trajectory's duration) and what
the service adds (acceptance, planning, timing, transport, settling). Static objects only (`--no-cameras`).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..apps.client import Client, ServiceError
from ..config import ReplannerConfig
from ..errors import ReplannerError
from ..stats import summary
from ..transport import messages as m
from ..transport.session import free_port, node_session


def run(config: str, cfg: ReplannerConfig, *, seed: int = 0, goals: int = 20, queries: int = 100) -> dict:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cli = [sys.executable, "-m", "replanner_services.cli"]
    logs = Path(tempfile.mkdtemp(prefix="replanner-bench-service-"))
    procs = []
    with open(logs / "serve.log", "w") as f_serve, open(logs / "robot.log", "w") as f_robot:
        procs.append(
            subprocess.Popen(
                [*cli, "serve", "-c", config, "--no-cameras", "-l", endpoint], stdout=f_serve, stderr=subprocess.STDOUT
            )
        )
        procs.append(
            subprocess.Popen(
                [*cli, "robot", "--kinematic", "-c", config, "-e", endpoint], stdout=f_robot, stderr=subprocess.STDOUT
            )
        )
        session = node_session(endpoint)
        try:
            return _measure(session, cfg, seed, goals, queries, procs, logs)
        finally:
            session.close()
            for p in procs:
                p.terminate()
            for p in procs:
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()


def _measure(session, cfg, seed, goals, queries, procs, logs) -> dict:
    client = Client(session, cfg.robot.name, cfg.transport.namespace, timeout=10.0)
    end = time.monotonic() + 120
    while not client.wait_alive(timeout=1.0):
        if time.monotonic() > end or any(p.poll() is not None for p in procs):
            raise ReplannerError(f"the service did not start; see {logs}")
    while client.state()["position"] is None:  # the robot's first joint state
        time.sleep(0.05)
    names = client.state()["joint_names"]
    durations: list[float] = []

    def on_traj(sample) -> None:
        _, t, *_ = m.decode_trajectory(sample.payload.to_bytes(), names)
        durations.append(float(t[-1]))

    sub = session.declare_subscriber(client.keys.trajectory, on_traj)
    try:
        rng = np.random.default_rng(seed)
        home = np.array(cfg.robot.home)
        q_ms = []
        for _ in range(queries):
            t0 = time.perf_counter()
            client.state()
            q_ms.append((time.perf_counter() - t0) * 1e3)
        accept_ms, result_s, traj_s, overhead_ms = [], [], [], []
        while len(result_s) < goals:
            # moves of 0.2-0.4 rad per joint around home: a simple goal, planned as a direct connection
            target = home + rng.uniform(0.2, 0.4, len(home)) * rng.choice([-1.0, 1.0], len(home))
            n = len(durations)
            t0 = time.perf_counter()
            try:
                fut = client.send_goal(target.tolist())
            except ServiceError:
                continue  # a seeded target in collision or out of limits: draw the next one
            t_acc = time.perf_counter()
            res = fut.wait(30)
            t_res = time.perf_counter()
            if res is None or res["status"] != "succeeded" or len(durations) <= n:
                raise ReplannerError(f"goal {fut.id} did not succeed: {res}; see {logs}")
            accept_ms.append((t_acc - t0) * 1e3)
            result_s.append(t_res - t0)
            traj_s.append(durations[n])
            overhead_ms.append((t_res - t0 - durations[n]) * 1e3)
    finally:
        sub.undeclare()
        client.close()
    return {
        "robot": cfg.robot.name,
        "seed": seed,
        "transport": "two processes + this client, Zenoh peers on loopback",
        "state_query_ms": summary(q_ms),
        "goal_accept_ms": summary(accept_ms),
        "goal_result_s": summary(result_s),
        "trajectory_s": summary(traj_s),
        "overhead_ms": summary(overhead_ms),
        "logs": str(logs),
    }
