"""What a benchmark ran on: the processor, its cores, and a fixed workload's time before and after the run. The
2-core VMs this project is measured on drift by up to 1.4x from hour to hour: two runs' figures compare only at like
reference times."""

from __future__ import annotations

import os
import platform
import time

import numpy as np

ROUNDS = 5  # the reference is the median of this many rounds of its workload


def reference_ms(rounds: int = ROUNDS) -> float:
    """Median time [ms] of a fixed workload none of replanner's code takes part in (a Python loop and numpy
    arithmetic on one core, a few ms a round: the mix a plan is made of), so code changes never move it."""
    times = []
    for _ in range(rounds):
        x = np.linspace(0.0, 1.0, 20_000)
        t = time.perf_counter()
        s = 0
        for i in range(50_000):
            s += i * i % 7
        for _ in range(10):
            x = np.sin(x) + 0.5
        times.append(time.perf_counter() - t)
    return round(float(np.median(times)) * 1e3, 3)


def processor() -> str:
    """The processor's model name (Linux: /proc/cpuinfo; elsewhere what `platform` says)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def describe(before_ms: float, after_ms: float) -> dict:
    """The JSON block a benchmark's result carries: `before_ms`, `after_ms` are `reference_ms()` around the run."""
    return {
        "processor": processor(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "reference_ms_before": before_ms,
        "reference_ms_after": after_ms,
        "reference": f"median of {ROUNDS} rounds of a fixed Python loop and numpy arithmetic on one core, measured "
        "before and after the run without its --load: a slower machine or hour gives larger times",
    }
