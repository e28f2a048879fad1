"""`replanner demo`: sim, service and pick-and-place client as three processes on loopback; metrics from truth."""

from __future__ import annotations

import json
import signal
import tempfile
import time
from pathlib import Path

import yaml
from rich.console import Console
from rich.live import Live
from rich.table import Table

from replanner.apps.client import Client
from replanner.apps.demo import Recorder, compute_metrics, plot_timeline
from replanner.config import ReplannerConfig, config_path
from replanner.errors import ReplannerError
from replanner.transport.session import free_port, node_session

from .procs import Proc, replanner_cmd

POLICIES = {
    "replan+reflex": "replan_reflex",
    "replan": "replan",
    "reflex": "reflex",
    "stop-and-wait": "stop_and_wait",
    "none": "none",
}


def _view_url(viewer: Proc, timeout: float = 60.0) -> str:
    """The URL `replanner view` prints once its page is served (or what went wrong)."""
    end = time.time() + timeout
    while time.time() < end:
        for line in viewer.tail(20).splitlines():
            if "open http" in line:
                return line.split("open ", 1)[1].split()[0]
        if not viewer.alive():
            return f"(the view did not start: {viewer.log})"
        time.sleep(0.2)
    return f"(the view is still starting: {viewer.log})"


def run(
    config: str,
    cfg: ReplannerConfig,
    *,
    cycles: int,
    duration: float | None,
    seed: int,
    policy: str,
    log_dir: str | None = None,
    live: bool = True,
    console: Console | None = None,
    tick=None,
    view_port: int | None = None,
    record_jobs: str | None = None,
) -> tuple[dict, object, dict]:
    """Run one demo; returns (metrics, recording, run info). `tick(elapsed, procs, recorder)` is called about
    four times a second while it runs (the soak samples there); a tick that returns True ends the run.
    `view_port`: also run `replanner view` there.
    `record_jobs`: the service keeps its planning jobs in this directory (planning.record_jobs)."""
    console = console or Console()
    logs = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix="replanner-demo-"))
    logs.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run_cfg = logs / "config.yaml"
    run_cfg.write_text(
        yaml.safe_dump(
            {
                "base": str(config_path(config)),
                "controller": {"reaction": POLICIES[policy]},
                "transport": {"endpoint": endpoint},
                **({"planning": {"record_jobs": str(Path(record_jobs).resolve())}} if record_jobs else {}),
            }
        )
    )
    c = str(run_cfg)
    serve = Proc("serve", replanner_cmd("serve", "-c", c, "-v"), logs)
    sim = Proc("sim", replanner_cmd("sim", "-c", c, "--seed", str(seed), "--log", str(logs / "truth.jsonl")), logs)
    procs = [serve, sim]
    session = node_session(endpoint)
    recorder = None
    client_proc = viewer = None
    interrupted = False
    t0 = t1 = time.time()
    try:
        client = Client(session, cfg.robot.name, cfg.transport.namespace, timeout=10.0)
        _wait_ready(client, session, procs, logs)
        recorder = Recorder(session, client.keys.root)
        if view_port is not None:
            viewer = Proc("view", replanner_cmd("view", "-c", c, "--port", str(view_port)), logs)
            url = _view_url(viewer)
            console.print(
                f"[bold]live view: {url}[/] (open it in a browser; `ssh -L {view_port}:127.0.0.1:{view_port} "
                "HOST` from another machine)"
            )
        args = ["pick-and-place", "-c", c, "--cycles", str(cycles)]
        client_proc = Proc("pick-and-place", replanner_cmd(*args), logs)
        procs.append(client_proc)
        t0 = time.time()
        try:
            _watch(recorder, client_proc, procs, cycles, duration, t0, policy, live, console, cfg, tick)
        except KeyboardInterrupt:
            interrupted = True
            console.print("[yellow]interrupted: stopping the client, the sim and the service[/]")
        t1 = time.time()
    finally:
        if client_proc is not None:
            client_proc.stop(signal.SIGINT, timeout=10)
        time.sleep(0.3)  # the last truth events and transitions arrive
        rec = recorder.snapshot() if recorder else None
        if recorder:
            recorder.close()
        session.close()
        if viewer is not None:
            viewer.stop(signal.SIGTERM, timeout=10)
        for p in (sim, serve):
            p.stop(signal.SIGINT, timeout=15)
    dead = [p.name for p in procs if p.p.returncode not in (0, -2, 130, None) and p is not client_proc]
    metrics = compute_metrics(
        rec, safety_distance=cfg.controller.safety_distance, bins=tuple(cfg.sim.task.bins), t0=t0, t1=t1
    )
    metrics.update(
        {
            "policy": policy,
            "seed": seed,
            "cycles_requested": cycles,
            "interrupted": interrupted,
            "client_exit": client_proc.p.returncode if client_proc else None,
            "logs": str(logs),
        }
    )
    if dead:
        metrics["crashed"] = dead
    return metrics, rec, {"t0": t0, "t1": t1, "logs": logs}


def _wait_ready(client: Client, session, procs: list[Proc], logs: Path, timeout: float = 300.0) -> None:
    # a fresh machine compiles the kernels on first use: a cold start beside two busy processes took over 120 s
    from replanner.apps.pick_place import Gripper

    end = time.monotonic() + timeout
    gripper = Gripper(session, client.keys.root, timeout=1.0)
    while time.monotonic() < end:
        for p in procs:
            if not p.alive():
                raise ReplannerError(f"{p.name} exited at start:\n{p.tail()}\n(logs in {logs})")
        if client.wait_alive(timeout=0.5):
            try:
                st = client.state()
                gripper.state()
                if st["position"] is not None and st.get("rejections") is not None:
                    return
            except ReplannerError:
                pass
        time.sleep(0.2)
    raise ReplannerError(f"the service and the sim did not come up within {timeout:.0f} s (logs in {logs})")


def completed_cycles(r) -> int:
    return sum(1 for e in r.truth if e["kind"] == "placed" and e.get("on") != e.get("picked_from"))


def _watch(recorder, client_proc, procs, cycles, duration, t0, policy, live, console, cfg, tick=None) -> None:
    def view() -> Table:
        r = recorder.snapshot()
        done = completed_cycles(r)
        contacts = sum(1 for e in r.truth if e["kind"] == "contact")
        clear = [e["clearance"] for e in r.truth if e["kind"] == "clearance" and e.get("clearance") is not None]
        state = r.status[-1]["state"] if r.status else "?"
        last = r.progress[-1] if r.progress else {}
        t = Table(title=f"replanner demo — policy {policy}", show_header=False, min_width=60)
        t.add_row("elapsed", f"{time.time() - t0:.1f} s")
        t.add_row("cycles completed (sim truth)", f"{done} / {cycles}")
        t.add_row("client step", f"cycle {last.get('cycle', '-')}: {last.get('step', '-')}")
        t.add_row("service state", state)
        t.add_row("intrusions", str(sum(1 for e in r.truth if e["kind"] == "operator_entering")))
        t.add_row("collisions (sim truth)", f"[{'red' if contacts else 'green'}]{contacts}[/]")
        t.add_row("min clearance to operator", f"{min(clear) * 1000:.0f} mm" if clear else "-")
        return t

    def finished() -> bool:
        if tick is not None and tick(time.time() - t0, procs, recorder):
            return True
        if not client_proc.alive():
            return True
        if duration is not None and time.time() - t0 > duration:
            return True
        for p in procs:
            if p is not client_proc and not p.alive():
                raise ReplannerError(f"{p.name} exited during the run:\n{p.tail()}")
        return False

    if live and console.is_terminal:
        with Live(view(), console=console, refresh_per_second=4) as lv:
            while not finished():
                time.sleep(0.25)
                lv.update(view())
    else:
        last = 0.0
        while not finished():
            time.sleep(0.25)
            if time.time() - last > 10:
                last = time.time()
                done = completed_cycles(recorder.snapshot())
                console.print(f"[{time.time() - t0:6.1f} s] cycles completed: {done}/{cycles}", highlight=False)


def table(metrics: dict) -> Table:
    t = Table(title=f"replanner demo — policy {metrics['policy']}, seed {metrics['seed']}")
    t.add_column("metric")
    t.add_column("value", justify="right")

    def lat(k):
        v = metrics[k]
        return f"{v['median'] * 1000:.0f} / {v['p95'] * 1000:.0f} ms (n={v['n']})" if v["n"] else "-"

    rate = metrics["completion_rate"]
    rows = [
        (
            "cycles completed / attempted",
            f"{metrics['cycles_completed']} / {metrics['cycles_attempted']}"
            + (f" ({rate:.0%})" if rate is not None else ""),
        ),
        ("cycles per minute", f"{metrics['cycles_per_minute']:.2f}"),
        ("collisions (sim truth)", str(metrics["collisions"])),
        (
            "min clearance to the operator",
            f"{metrics['min_clearance_m'] * 1000:.1f} mm" if metrics["min_clearance_m"] is not None else "-",
        ),
        ("safety distance", f"{metrics['safety_distance_m'] * 1000:.0f} mm"),
        ("intrusions (on the path)", f"{metrics['intrusions']} ({metrics['intrusions_on_path']})"),
        (
            "replans started / spliced / cancelled / failed",
            "{started} / {spliced} / {cancelled} / {failed}".format(**metrics["replans"]),
        ),
        ("brakes", str(metrics["brakes"])),
        ("swerves (reflex)", str(metrics["swerves"])),
        ("cycles failed (and carried on)", str(metrics["cycles_failed"])),
        ("reaction, median / p95", lat("reaction_s")),
        ("service T_r (speed and separation), median / p95", lat("service_reaction_time_s")),
        (
            "sim real-time factor, median / p95",
            "{median:.2f} / {p95:.2f}".format(**metrics["real_time_factor"])
            if metrics["real_time_factor"]["n"]
            else "-",
        ),
        ("busy processes alongside", str(metrics.get("load", {}).get("busy_processes", 0))),
        ("replan, median / p95", lat("replan_s")),
        ("clearing, median / p95", lat("clearing_s")),
        ("duration", f"{metrics['duration_s']:.1f} s"),
    ]
    for k, v in rows:
        t.add_row(k, v)
    return t


def write_outputs(
    metrics: dict, rec, info: dict, cfg: ReplannerConfig, json_path: str | None, plot_path: str | None
) -> None:
    if json_path:
        Path(json_path).write_text(json.dumps(metrics, indent=2))
    if plot_path:
        plot_timeline(
            rec,
            plot_path,
            t0=info["t0"],
            safety_distance=cfg.controller.safety_distance,
            title=f"policy {metrics['policy']}, seed {metrics['seed']}: {metrics['cycles_completed']} cycles, "
            f"{metrics['collisions']} collisions",
        )
