"""`replanner serve` and `replanner robot --kinematic` as real processes on loopback, and sessions to reach them."""

from __future__ import annotations

import time
from pathlib import Path

import zenoh
from replanner_services.procs import Proc, replanner_cmd

from replanner.transport.session import free_port, node_session  # noqa: F401  (tests import them from here)


class Stack:
    """serve (listening on a free loopback port) + robot --kinematic, both connecting nowhere else."""

    def __init__(self, config: str, log_dir: Path, serve_args=(), robot_args=(), port: int | None = None):
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.config = config
        self.log_dir = log_dir
        self.serve = Proc(
            "serve", replanner_cmd("serve", "-c", config, "-l", self.endpoint, "-v", *serve_args), log_dir
        )
        self.robot = Proc(
            "robot", replanner_cmd("robot", "--kinematic", "-c", config, "-e", self.endpoint, *robot_args), log_dir
        )

    def logs(self) -> str:
        return f"--- serve ---\n{self.serve.tail()}\n--- robot ---\n{self.robot.tail()}"

    def wait_alive(self, session: zenoh.Session, key: str, timeout: float = 60.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if not self.serve.alive() or not self.robot.alive():
                raise AssertionError(f"a process died at start\n{self.logs()}")
            if list(session.liveliness().get(key, timeout=0.5)):
                return
            time.sleep(0.1)
        raise AssertionError(f"no liveliness token on {key} within {timeout} s\n{self.logs()}")

    def stop(self) -> None:
        self.serve.stop()
        self.robot.stop()
