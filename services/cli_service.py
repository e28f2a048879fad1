"""The service commands of `replanner`: serve, router, robot, goal, cancel, status, scene (see docs/protocol.md)."""

from __future__ import annotations

import json
import time

import typer

from replanner.errors import ConfigError, ReplannerError

from .cli_common import (
    ConfigOpt,
    ConnectOpt,
    ListenOpt,
    ModeOpt,
    RobotOpt,
    ZenohConfigOpt,
    ZenohFlags,
    fail,
    print_json,
    resolve_config,
)

app = typer.Typer()  # merged into the root app by cli.py (no name: its commands sit at the top level)
scene_app = typer.Typer(
    help="Static objects of the service's world: list, add, move, remove, attach, detach.", no_args_is_help=True
)
app.add_typer(scene_app, name="scene")

POSITION_HELP = "Position 'x,y,z' [m] in the robot base frame."
QUAT_HELP = "Orientation quaternion 'qx,qy,qz,qw'."


def floats(text: str, what: str, n: int | tuple[int, ...] | None = None) -> list[float]:
    """'0.1, -0.2 0.3' -> [0.1, -0.2, 0.3]; a clear error names the flag and what it needs."""
    try:
        values = [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise typer.BadParameter(f"{what} needs numbers separated by commas or spaces, got {text!r}") from None
    if n is not None and len(values) not in ((n,) if isinstance(n, int) else n):
        raise typer.BadParameter(f"{what} needs {n} numbers, got {len(values)}")
    return values


class Connection:
    """An open session and client for the CLI's one-shot commands (goal, cancel, status, scene)."""

    def __init__(self, config: str, robot: str | None, zenoh: ZenohFlags, timeout: float = 5.0):
        from replanner.apps.client import Client
        from replanner.transport.session import open_session

        self.cfg = resolve_config(config)
        self.session = open_session(zenoh.config(self.cfg.transport, "node"))
        self.client = Client(self.session, robot or self.cfg.robot.name, self.cfg.transport.namespace, timeout)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.client.close()
        self.session.close()


@app.command("serve")
def serve(
    config: ConfigOpt = "panda",
    no_cameras: bool = typer.Option(
        False,
        "--no-cameras",
        help="Ignore the configured cameras: plan against static objects only "
        "(nothing watches for people; for kinematic tries).",
    ),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log every transition and rejection."),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Run the controller as a Zenoh service (by default a peer listening on tcp/127.0.0.1:7448)."""
    import logging

    from . import serve as serve_mod

    logging.getLogger().setLevel(logging.INFO if verbose else logging.WARNING)
    try:
        cfg = resolve_config(config)
        if no_cameras:
            cfg = cfg.model_copy(update={"perception": None})
        serve_mod.run(cfg, ZenohFlags.of(mode, connect, listen, zenoh_config).config(cfg.transport, "service"))
    except ReplannerError as err:
        fail(err)


@app.command("router")
def router(
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = "router",
) -> None:
    """A Zenoh router in this Python process (where there is no zenohd): the other processes connect to
    it in client mode, e.g. `replanner serve -c demo --zenoh-config client -e tcp/127.0.0.1:7447`."""
    import signal
    import threading

    from replanner.sections import TransportConfig
    from replanner.transport.refusals import Refusals, access_control_on
    from replanner.transport.session import open_session

    try:
        conf = ZenohFlags.of("router", connect, listen, zenoh_config).config(TransportConfig(), "service")
        refusals = Refusals.capture() if access_control_on(conf) else None
        session = open_session(conf)
    except ReplannerError as err:
        fail(err)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(f"replanner: Zenoh router listening on {conf.get_json('listen/endpoints')} (Ctrl-C stops)", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    if refusals is not None:
        print(f"replanner: the router refused {refusals.total} messages by access control", flush=True)
    session.close()


@app.command("view")
def view(
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    host: str = typer.Option(
        "127.0.0.1", "--host", help="Where the page listens; 0.0.0.0 to open it from another machine."
    ),
    port: int = typer.Option(8080, "--port", min=0, max=65535, help="The page's port (0: any free one)."),
    rate: float = typer.Option(20.0, "--rate", min=1.0, max=60.0, help="Drawing rate [Hz]."),
    map_hz: float = typer.Option(2.0, "--map-hz", min=0.1, max=10.0, help="How often the map is fetched [Hz]."),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """The cell live in a browser: robot (measured, and a ghost at the commanded joints), map, objects, path,
    state, latency, cameras, the sim's operator; send or cancel goals from the page. Read-only otherwise."""
    import signal
    import threading

    from replanner.transport.session import open_session

    from .view import CellView

    try:
        cfg = resolve_config(config)
        session = open_session(ZenohFlags.of(mode, connect, listen, zenoh_config).config(cfg.transport, "node"))
    except ReplannerError as err:
        fail(err)
    try:
        cell = CellView(cfg, session, host, port, rate, map_hz, robot).start()
    except OSError as err:
        session.close()
        fail(ConfigError(f"cannot serve the page on {host}:{port}: {err} (choose another --port)"))
    print(f"replanner view: open {cell.url} (Ctrl-C stops)", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    cell.stop()
    session.close()


@app.command("certs")
def certs(
    out: str = typer.Argument(
        ..., metavar="DIR", help="Where to write the CA, the certificates and the Zenoh configs."
    ),
    identity: list[str] | None = typer.Option(
        None,
        "--identity",
        "-i",
        metavar="NAME:ROLE",
        help="An identity and its role (service, robot, sensor, sim, client, router); repeatable. Default: "
        "service:service robot:robot camera:sensor sim:sim operator:client router:router.",
    ),
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    endpoint: str = typer.Option(
        "tls/127.0.0.1:7447", "--endpoint", help="Where the service (peer to peer) or the router listens."
    ),
    host: list[str] | None = typer.Option(
        None, "--host", help="Another DNS name or IP address the certificates are valid for; repeatable."
    ),
    days: int = typer.Option(365, "--days", min=1, max=3650, help="Validity of the identities' certificates."),
    mount: str | None = typer.Option(
        None, "--mount", help="Where the processes find DIR, if elsewhere (e.g. /certs in containers)."
    ),
    via_router: bool = typer.Option(
        False, "--via-router", help="Everyone but the router is its client (else peers, the service listening)."
    ),
) -> None:
    """The secure profile: a CA, a certificate per identity and per identity a Zenoh config with mutual TLS and
    access control (only the service sends trajectories, only robots send joint states, only sensors send clouds,
    only clients send goals; nothing for anyone else). Run each process with `--zenoh-config DIR/<name>.json5`;
    see docs/security.md."""
    from pathlib import Path

    from replanner.transport.keys import Keys
    from replanner.transport.secure import DEFAULT_IDENTITIES, Identity, parse_identities, write_profile

    try:
        cfg = resolve_config(config)
        keys = Keys(robot or cfg.robot.name, cfg.transport.namespace)
        ids = parse_identities(identity) if identity else [Identity(n, r) for n, r in DEFAULT_IDENTITIES.items()]
        paths = write_profile(Path(out), keys, ids, endpoint, list(host or ()), days, mount, via_router)
    except ReplannerError as err:
        fail(err)
    print(f"secure profile for {keys.root} in {out}: CA ca.pem (keep ca.key offline once the identities exist)")
    for ident in ids:
        where = Path(mount) / paths[ident.name].name if mount else paths[ident.name]
        print(f"  {ident.name:<10} {ident.role:<8} --zenoh-config {where}")


@app.command("robot")
def robot(
    kinematic: bool = typer.Option(False, "--kinematic", help="Follow trajectories exactly (no physics)."),
    config: ConfigOpt = "panda",
    joints: str | None = typer.Option(None, "--joints", help="Start configuration [rad]; default: home."),
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """A robot on Zenoh: follows the trajectory stream and publishes joint states."""
    from . import robot_node

    if not kinematic:
        fail(ConfigError("only --kinematic exists here; the physics robot is `replanner sim`"))
    try:
        cfg = resolve_config(config)
        q0 = floats(joints, "--joints", len(cfg.robot.joints)) if joints else None
        robot_node.run(cfg, ZenohFlags.of(mode, connect, listen, zenoh_config).config(cfg.transport, "node"), q0)
    except ReplannerError as err:
        fail(err)


@app.command("goal")
def goal(
    joints: str | None = typer.Option(None, "--joints", "-j", help="Joint goal [rad], e.g. '0,-0.5,0,-2,0,1.6,0.8'."),
    pose: str | None = typer.Option(
        None, "--pose", "-p", help="Pose goal of --link: 'x,y,z' [m] or 'x,y,z,qx,qy,qz,qw'."
    ),
    link: str | None = typer.Option(None, "--link", help="Link of --pose; default: the config's tip link."),
    goal_id: str | None = typer.Option(None, "--id", help="Goal id; default: a fresh one."),
    planner: str | None = typer.Option(None, help="OMPL planner, e.g. RRTConnect."),
    deadline: float | None = typer.Option(None, help="Planning deadline [s]."),
    velocity_scale: float = typer.Option(1.0, help="Fraction of the velocity limits, (0, 1]."),
    padding: float | None = typer.Option(
        None, help="Padding from known objects [m] for this goal; default: the service's collision.padding."
    ),
    wait: bool = typer.Option(True, help="Wait for the result (else print the acceptance)."),
    timeout: float = typer.Option(60.0, min=0.1, help="How long to wait for the result [s]."),
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Send a goal and print its result (exit code 0 only if it succeeded)."""
    if (joints is None) == (pose is None):
        fail(typer.BadParameter("give exactly one of --joints or --pose"))
    try:
        with Connection(config, robot, ZenohFlags.of(mode, connect, listen, zenoh_config)) as c:
            target = None
            if pose is not None:
                v = floats(pose, "--pose", (3, 7))
                target = {"link": link or c.cfg.robot.tip_link, "position": v[:3]}
                if len(v) == 7:
                    target["quat_xyzw"] = v[3:]
            q = floats(joints, "--joints") if joints is not None else None
            t0 = time.monotonic()
            fut = c.client.send_goal(
                q, target, goal_id, planner=planner, deadline=deadline, velocity_scale=velocity_scale, padding=padding
            )
            if not wait:
                print_json({"accepted": fut.id, **fut.reply})
                return
            res = fut.wait(timeout)
            if res is None:
                fail(ReplannerError(f"no result for goal {fut.id!r} within {timeout} s"), 1)
            print_json({**res, "elapsed_s": round(time.monotonic() - t0, 3)})
            if res["status"] != "succeeded":
                raise typer.Exit(1)
    except ReplannerError as err:
        fail(err)


@app.command("cancel")
def cancel(
    goal_id: str = typer.Argument(..., help="Id of the active goal."),
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Cancel the active goal: the arm brakes along its path."""
    try:
        with Connection(config, robot, ZenohFlags.of(mode, connect, listen, zenoh_config)) as c:
            print_json(c.client.cancel(goal_id))
    except ReplannerError as err:
        fail(err)


@app.command("status")
def status(
    watch: bool = typer.Option(False, "--watch", "-w", help="Print transitions and results until Ctrl-C."),
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Print the service's state (JSON); with --watch, then each transition and result as a line."""
    try:
        with Connection(config, robot, ZenohFlags.of(mode, connect, listen, zenoh_config)) as c:
            print_json(c.client.state())
            if watch:

                def line(kind):
                    return lambda msg: print(json.dumps({"kind": kind, **msg}), flush=True)

                c.client.watch(on_transition=line("transition"), on_result=line("result"))
                try:
                    while True:
                        time.sleep(0.5)
                except KeyboardInterrupt:
                    pass
    except ReplannerError as err:
        fail(err)


# --------------------------------------------------------------------------------------------- scene
@scene_app.callback()
def scene_options(
    ctx: typer.Context,
    config: ConfigOpt = "panda",
    robot: RobotOpt = None,
    mode: ModeOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Connection options come before the subcommand: `replanner scene -e tcp/... list`."""
    target = {"config": config, "robot": robot, "zenoh": ZenohFlags.of(mode, connect, listen, zenoh_config)}
    ctx.ensure_object(dict)["scene"] = target  # next to typer's own keys in ctx.obj, not instead of them


def _scene_call(ctx: typer.Context, fn) -> None:
    try:
        with Connection(**ctx.obj["scene"]) as c:
            print_json(fn(c.client))
    except ReplannerError as err:
        fail(err)


@scene_app.command("list")
def scene_list(ctx: typer.Context) -> None:
    """Objects and attachments, with shapes and poses."""
    _scene_call(ctx, lambda c: c.scene())


@scene_app.command("add")
def scene_add(
    ctx: typer.Context,
    name: str = typer.Argument(..., help="Object name."),
    box: str | None = typer.Option(None, help="Box edge lengths 'x,y,z' [m]."),
    sphere: float | None = typer.Option(None, help="Sphere radius [m]."),
    cylinder: str | None = typer.Option(None, help="Cylinder 'radius,length' [m] (axis z)."),
    position: str = typer.Option(..., "--position", help=POSITION_HELP),
    quat: str = typer.Option("0,0,0,1", "--quat", help=QUAT_HELP),
) -> None:
    """Add a box, sphere or cylinder."""
    if sum(x is not None for x in (box, sphere, cylinder)) != 1:
        fail(typer.BadParameter("give exactly one of --box, --sphere or --cylinder"))
    if box is not None:
        shape = {"type": "box", "size": floats(box, "--box", 3)}
    elif sphere is not None:
        shape = {"type": "sphere", "radius": sphere}
    else:
        r, length = floats(cylinder, "--cylinder", 2)
        shape = {"type": "cylinder", "radius": r, "length": length}
    p, q = floats(position, "--position", 3), floats(quat, "--quat", 4)
    _scene_call(ctx, lambda c: c.add_object(name, shape, p, q))


@scene_app.command("move")
def scene_move(
    ctx: typer.Context,
    name: str = typer.Argument(..., help="Object name."),
    position: str = typer.Option(..., "--position", help=POSITION_HELP),
    quat: str = typer.Option("0,0,0,1", "--quat", help=QUAT_HELP),
) -> None:
    """Move an object to a new pose."""
    p, q = floats(position, "--position", 3), floats(quat, "--quat", 4)
    _scene_call(ctx, lambda c: c.move_object(name, p, q))


@scene_app.command("remove")
def scene_remove(ctx: typer.Context, name: str = typer.Argument(..., help="Object name.")) -> None:
    """Remove an object."""
    _scene_call(ctx, lambda c: c.remove_object(name))


@scene_app.command("attach")
def scene_attach(
    ctx: typer.Context,
    name: str = typer.Argument(..., help="Object name."),
    link: str = typer.Option(..., "--link", help="Robot link that carries it, e.g. panda_hand."),
) -> None:
    """Attach an object to a link where it is now (it moves with the link and is checked too)."""
    _scene_call(ctx, lambda c: c.attach(name, link))


@scene_app.command("detach")
def scene_detach(ctx: typer.Context, name: str = typer.Argument(..., help="Object name.")) -> None:
    """Detach an object where it is now."""
    _scene_call(ctx, lambda c: c.detach(name))


@scene_app.command("clear-map")
def scene_clear_map(ctx: typer.Context) -> None:
    """Empty the occupancy map (the cameras refill it)."""
    _scene_call(ctx, lambda c: c.clear_map())
