"""The simulation commands of `replanner`: sim, cameras, pick-and-place, demo."""

from __future__ import annotations

import json
import logging
import signal
import sys
import time

import typer
from rich.console import Console

from replanner.errors import ConfigError, ReplannerError

from .cli_common import (
    ConfigOpt,
    ConnectOpt,
    ListenOpt,
    LoadOpt,
    ModeOpt,
    ZenohConfigOpt,
    ZenohFlags,
    fail,
    resolve_config,
)
from .procs import Load

app = typer.Typer()  # merged into the root app by cli.py (no name: its commands sit at the top level)


def _check_cell(cfg, config: str) -> None:
    """The simulated cell needs the bins of sim.task among the scene's objects."""
    names = [o.name for o in cfg.scene]
    missing = [b for b in cfg.sim.task.bins if b not in names]
    if missing:
        raise ConfigError(
            f"{config}: sim.task.bins names {missing[0]!r}, which is not in scene: "
            f"(objects: {', '.join(names) or 'none'}); add the bins to scene: or use the demo profile (-c demo)"
        )


def _demo_cell(config: str, policy: str):
    """The cell config of a demo or a soak: a known policy (else exit 2), the bins in the scene, cameras."""
    from .demo import POLICIES

    if policy not in POLICIES:
        fail(typer.BadParameter(f"--policy must be one of {', '.join(POLICIES)}, got {policy!r}"))
    cfg = resolve_config(config)
    _check_cell(cfg, config)
    if cfg.perception is None or not cfg.perception.sensors:
        raise ConfigError(f"{config}: the demo needs cameras (perception.sensors)")
    return cfg


@app.command("sim")
def sim(
    config: ConfigOpt = "demo",
    seed: int = typer.Option(0, min=0, help="Seeds the operator's script and the depth noise."),
    gui: bool = typer.Option(False, "--gui", help="Open pybullet's window."),
    log: str | None = typer.Option(None, "--log", help="Append every ground-truth event to this JSON-lines file."),
    no_operator: bool = typer.Option(False, "--no-operator", help="Nobody steps in."),
    no_cameras: bool = typer.Option(False, "--no-cameras", help="Do not render or publish point clouds."),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """The cell under pybullet physics: the arm follows the trajectory stream, cameras publish clouds,
    an operator steps in, ground truth goes out on `<root>/sim/truth`."""
    from . import sim_node
    from .procs import replanner_cmd

    zenoh = ZenohFlags.of(mode, connect, listen, zenoh_config)
    try:
        cfg = resolve_config(config)
        _check_cell(cfg, config)
        if not no_cameras and (cfg.perception is None or not cfg.perception.sensors):
            raise ConfigError(f"{config}: no perception.sensors to simulate (or pass --no-cameras)")
        cams = None
        if not no_cameras:  # the cameras' process connects like the sim but never listens (the port is the sim's)
            cams = replanner_cmd("cameras", "-c", config, "--seed", str(seed), *zenoh.args(listen=False))
        sim_node.run_sim(
            cfg,
            zenoh.config(cfg.transport, "node"),
            seed=seed,
            gui=gui,
            truth_log=log,
            operator=not no_operator and cfg.sim.operator.enabled,
            cameras_cmd=cams,
        )
    except ReplannerError as err:
        fail(err)


@app.command("cameras", hidden=True)
def cameras(
    config: ConfigOpt = "demo",
    seed: int = typer.Option(0, min=0),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """The simulated depth cameras (started by `replanner sim`)."""
    from . import sim_node

    try:
        cfg = resolve_config(config)
        conf = ZenohFlags.of(mode, connect, listen, zenoh_config).config(cfg.transport, "node")
        sim_node.run_cameras(cfg, conf, seed=seed)
    except ReplannerError as err:
        fail(err)


@app.command("pick-and-place")
def pick_and_place(
    config: ConfigOpt = "demo",
    cycles: int = typer.Option(10, min=1, help="Cycles to run (each carries the part to the other bin)."),
    duration: float | None = typer.Option(None, min=1.0, help="Stop starting cycles after this long [s]."),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Loop pick at one bin -> place at the other, using the service and the sim's suction gripper."""
    from replanner.apps.client import Client
    from replanner.apps.pick_place import Gripper, PickAndPlace
    from replanner.transport.session import open_session
    from replanner.world.scene import scene_from_config, top_centers, world_boxes

    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        cfg = resolve_config(config)
        _check_cell(cfg, config)
        session = open_session(ZenohFlags.of(mode, connect, listen, zenoh_config).config(cfg.transport, "node"))
    except ReplannerError as err:
        fail(err)
    client = Client(session, cfg.robot.name, cfg.transport.namespace, timeout=10.0)
    pub = session.declare_publisher(f"{client.keys.root}/task/progress")

    def progress(msg: dict) -> None:
        msg = {"stamp": time.time(), **msg}
        pub.put(json.dumps(msg))
        print(json.dumps(msg), flush=True)

    try:
        if not client.wait_alive(timeout=30.0):
            raise ReplannerError(f"no service on {client.keys.root} (start `replanner serve -c {config}`)")
        gripper = Gripper(session, client.keys.root)
        objects = scene_from_config(cfg)
        task = PickAndPlace(
            client,
            gripper,
            cfg.sim.task,
            cfg.robot.tip_link,
            top_centers(objects),
            boxes=world_boxes(objects),
            on_progress=progress,
        )
        task.setup()
        task.run(cycles, until=None if duration is None else time.time() + duration)
    except KeyboardInterrupt:
        print("pick-and-place: interrupted", file=sys.stderr)
    except ReplannerError as err:
        fail(err, 1)
    finally:
        client.close()
        session.close()


@app.command("soak")
def soak(
    config: ConfigOpt = "demo",
    minutes: float = typer.Option(60.0, min=0.5, help="How long to loop the pick-and-place [min]."),
    seed: int = typer.Option(7, min=0, help="Seeds the operator's script."),
    policy: str = typer.Option("replan", help="replan+reflex, replan, reflex, stop-and-wait or none."),
    every: float = typer.Option(60.0, min=5.0, help="Sample every this many seconds."),
    cycles: int | None = typer.Option(
        None,
        "--cycles",
        min=1,
        help="Stop at the first sample that counts this many completed cycles (or at --minutes).",
    ),
    json_path: str | None = typer.Option(None, "--json", help="Write the samples and totals to this JSON file."),
    plot: str | None = typer.Option(None, "--plot", help="Draw memory and reaction latency over time to a PNG."),
    log_dir: str | None = typer.Option(None, "--log-dir", help="Keep the processes' logs and the truth here."),
    load: LoadOpt = 0,
) -> None:
    """The demo looping for minutes: every minute each process's memory, reaction latency, cycles, collisions."""
    from . import soak as soak_mod

    console = Console()
    try:
        cfg = _demo_cell(config, policy)
        with Load(load) as busy:
            result = soak_mod.run(
                config,
                cfg,
                minutes=minutes,
                seed=seed,
                policy=policy,
                every=every,
                cycles=cycles,
                log_dir=log_dir,
                console=console,
            )
        result["load"] = busy.describe()
        soak_mod.write(result, json_path, plot)
    except ReplannerError as err:
        fail(err)
    for r in result["samples"]:
        console.print(
            f"min {r['minute']:5.1f}: cycles {r['cycles']}, collisions {r['collisions']}, rejections "
            f"{r['rejections']}, T_r p50/p99 {r['reaction_time_s']['p50']}/{r['reaction_time_s']['p99']} s, RSS MB "
            + ", ".join(f"{k} {v:.0f}" for k, v in r["rss_mb"].items()),
            highlight=False,
        )
    console.print(f"RSS growth (last sample vs minute 10, or the first): {result['growth']}")
    if result["crashed"]:
        fail(ReplannerError(f"a process crashed: {', '.join(result['crashed'])} (see {result['logs']})"), 1)


@app.command("demo")
def demo(
    config: ConfigOpt = "demo",
    cycles: int = typer.Option(6, min=1, help="Pick-and-place cycles."),
    duration: float | None = typer.Option(None, min=5.0, help="Stop after this long [s] (default: the cycles)."),
    seed: int = typer.Option(7, min=0, help="Seeds the operator's script and the camera noise."),
    policy: str = typer.Option(
        "replan",
        help="replan (this service), replan+reflex (swerving at once while it replans), reflex (swerve and return, "
        "no replanning), stop-and-wait (MoveIt-style: stop, wait, plan from rest) or none.",
    ),
    json_path: str | None = typer.Option(None, "--json", help="Write the metrics to this JSON file."),
    plot: str | None = typer.Option(None, "--plot", help="Draw the timeline (state, clearance, events) to a PNG."),
    log_dir: str | None = typer.Option(None, "--log-dir", help="Keep the processes' logs and the truth here."),
    load: LoadOpt = 0,
    view: bool = typer.Option(False, "--view", help="Serve the live web view too (`replanner view`); prints its URL."),
    view_port: int = typer.Option(8080, "--view-port", min=0, max=65535, help="The web view's port (0: any free one)."),
    record_jobs: str | None = typer.Option(
        None, "--record-jobs", help="Keep every planning job of the service in this directory (replanner bench replay)."
    ),
    verbose: bool = typer.Option(False, "-v", "--verbose"),
) -> None:
    """Sim, service and pick-and-place client as three processes on loopback; a table of what happened."""
    # No Zenoh flags: the demo picks a free loopback port and wires its three processes to it itself.
    from . import demo as demo_mod

    logging.getLogger().setLevel(logging.INFO if verbose else logging.WARNING)
    console = Console()
    try:
        cfg = _demo_cell(config, policy)
        with Load(load) as busy:
            metrics, rec, info = demo_mod.run(
                config,
                cfg,
                cycles=cycles,
                duration=duration,
                seed=seed,
                policy=policy,
                log_dir=log_dir,
                console=console,
                view_port=view_port if view else None,
                record_jobs=record_jobs,
            )
        metrics["load"] = busy.describe()
        demo_mod.write_outputs(metrics, rec, info, cfg, json_path, plot)
    except ReplannerError as err:
        fail(err)
    console.print(demo_mod.table(metrics))
    if plot:
        console.print(f"timeline: {plot}")
    console.print(f"logs and ground truth: {metrics['logs']}")
    if metrics.get("crashed"):
        fail(ReplannerError(f"a process crashed: {', '.join(metrics['crashed'])} (see the logs)"), 1)
