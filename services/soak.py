"""`replanner soak`: the demo's pick-and-place with the operator, looping for minutes; every minute the memory of
each process, the reaction latency, cycles, collisions and rejections, to see what grows."""

from __future__ import annotations

import json
from pathlib import Path

from rich.console import Console

from replanner.config import ReplannerConfig

from . import demo as demo_mod


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def children(pid: int) -> list[int]:
    """Process ids whose parent is `pid` (Linux /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(d.name))
            except (OSError, ValueError, IndexError):
                continue
    return out


class Sampler:
    """Every `every` seconds: RSS [MB] of each process (and the service's children: its planning process), and
    what the recording says so far. With `cycles`, a sample that counts that many completed cycles ends the run."""

    def __init__(self, every: float, cycles: int | None = None):
        self.every, self.rows, self._next, self.cycles = float(every), [], float(every), cycles

    def __call__(self, elapsed: float, procs, recorder) -> bool:
        if elapsed < self._next:
            return False
        self._next += self.every
        rss = {}
        for p in procs:
            if p.alive():
                rss[p.name] = _rss_mb(p.p.pid)
                if p.name == "serve":
                    for i, c in enumerate(children(p.p.pid)):
                        rss[f"serve child {i}"] = _rss_mb(c)
        r = recorder.snapshot()
        lat = [s["latency"] for s in r.status if s.get("latency") and s["stamp"] >= r.status[-1]["stamp"] - self.every]
        chain = [x.get("reaction_time_s") for x in lat if x.get("reaction_time_s") is not None]
        self.rows.append(
            {
                "minute": round(elapsed / 60.0, 2),
                "rss_mb": {k: round(v, 1) for k, v in rss.items() if v is not None},
                "cycles": demo_mod.completed_cycles(r),
                "collisions": sum(1 for e in r.truth if e["kind"] == "contact"),
                "rejections": r.status[-1].get("rejections", 0) if r.status else 0,
                "reaction_time_s": {
                    "p50": _pct(chain, 50),
                    "p99": _pct(chain, 99),
                },
            }
        )
        return self.cycles is not None and self.rows[-1]["cycles"] >= self.cycles


def _pct(values, q):
    import numpy as np

    return round(float(np.percentile(values, q)), 4) if values else None


def run(
    config: str,
    cfg: ReplannerConfig,
    *,
    minutes: float,
    seed: int,
    policy: str,
    every: float = 60.0,
    cycles: int | None = None,
    log_dir: str | None = None,
    console: Console | None = None,
) -> dict:
    """Loop the demo for `minutes`, or until a sample counts `cycles` completed cycles (the sim's truth)."""
    sampler = Sampler(every, cycles)
    metrics, rec, info = demo_mod.run(
        config,
        cfg,
        cycles=10**6,
        duration=minutes * 60.0,
        seed=seed,
        policy=policy,
        log_dir=log_dir,
        live=False,
        console=console,
        tick=sampler,
    )
    rows = sampler.rows
    return {
        "soak": True,
        "minutes": minutes,
        "policy": policy,
        "seed": seed,
        "every_s": every,
        "samples": rows,
        "growth": _growth(rows),
        "cycles": metrics["cycles_completed"],
        "collisions": metrics["collisions"],
        "crashed": metrics.get("crashed", []),
        "logs": metrics["logs"],
        "metrics": metrics,
    }


def _growth(rows: list[dict]) -> dict:
    """Per process: RSS at the last sample over RSS at the sample nearest minute 10 (or the first), minus one."""
    if len(rows) < 2:
        return {}
    ref = min(rows, key=lambda r: abs(r["minute"] - 10.0)) if rows[-1]["minute"] > 10.0 else rows[0]
    last = rows[-1]
    return {k: round(last["rss_mb"][k] / v - 1.0, 4) for k, v in ref["rss_mb"].items() if k in last["rss_mb"] and v}


def plot(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["samples"]
    t = [r["minute"] for r in rows]
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for name in sorted({k for r in rows for k in r["rss_mb"]}):
        ax[0].plot(t, [r["rss_mb"].get(name) for r in rows], label=name)
    ax[0].set_ylabel("RSS [MB]")
    ax[0].legend(fontsize=7)
    ax[1].plot(t, [r["reaction_time_s"]["p50"] for r in rows], label="T_r p50")
    ax[1].plot(t, [r["reaction_time_s"]["p99"] for r in rows], label="T_r p99")
    ax[1].set_ylabel("reaction [s]")
    ax[1].set_xlabel("minute")
    ax[1].legend(fontsize=7)
    fig.suptitle(f"soak: {result['minutes']} min, {result['cycles']} cycles, {result['collisions']} collisions")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write(result: dict, json_path: str | None, plot_path: str | None) -> None:
    if json_path:
        Path(json_path).write_text(json.dumps(result, indent=2))
    if plot_path:
        plot(result, plot_path)
