"""Child processes of the entry points (the demo, benches and tests start services this way)."""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
from pathlib import Path

# resolved here: a forked child of a threaded parent must not enter the dynamic loader
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    # the child gets SIGTERM when its parent dies, even killed: no services or busy loops left behind
    if _prctl is not None:
        _prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def replanner_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "replanner_services.cli", *args]


class Proc:
    """A child process whose output goes to a log file (read back on failure)."""

    def __init__(self, name: str, args: list[str], log_dir: Path, cwd: Path | None = None):
        self.name = name
        self.log = log_dir / f"{name}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self._f = open(self.log, "w")  # noqa: SIM115 (closed in stop)
        self.p = subprocess.Popen(
            args, stdout=self._f, stderr=subprocess.STDOUT, env=env, cwd=cwd, preexec_fn=_die_with_parent
        )

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


class Load:
    """`n` busy processes on the machine's cores for as long as the context lasts (at most `limit` s): a benchmark
    or a demo measured as a busy machine would run it. `with Load(2): ...`"""

    def __init__(self, n: int, limit: float = 7200.0):
        self.n, self.limit = int(n), float(limit)
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> Load:
        spin = f"import time\nend = time.monotonic() + {self.limit}\nwhile time.monotonic() < end: pass"
        self.procs = [
            subprocess.Popen([sys.executable, "-c", spin], preexec_fn=_die_with_parent) for _ in range(self.n)
        ]
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()

    def describe(self) -> dict:
        return {"busy_processes": self.n, "each": "a Python loop spinning on one core"}  # cores: in "machine"
