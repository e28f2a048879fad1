"""`replanner serve` and `replanner robot --kinematic` as real processes on loopback, and sessions to reach them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from replanner.transport.session import free_port, node_session  # noqa: F401  (tests import them from here)


def replanner_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "replanner_services.cli", *args]


class Proc:
    """A child process whose output goes to a log file (read back on failure)."""

    def __init__(self, name: str, args: list[str], log_dir: Path):
        self.name = name
        self.log = log_dir / f"{name}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self._f = open(self.log, "w")  # noqa: SIM115 (closed in stop)
        self.p = subprocess.Popen(args, stdout=self._f, stderr=subprocess.STDOUT, env=env)

    def tail(self, n: int = 40) -> str:
        return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])

    def alive(self) -> bool:
        return self.p.poll() is None

    def stop(self, sig=signal.SIGTERM, timeout: float = 15.0) -> int:
        if self.p.poll() is None:
            self.p.send_signal(sig)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()
        self._f.close()
        return self.p.returncode


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
