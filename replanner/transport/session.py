"""Zenoh sessions: mode and endpoints from the config, overridable like zenoh's examples."""

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Literal

import zenoh

from ..errors import ConfigError
from ..sections import TransportConfig


def make_config(
    transport: TransportConfig,
    role: Literal["service", "node"],
    mode: str | None = None,
    connect=(),
    listen=(),
    zenoh_file: str | None = None,
) -> zenoh.Config:
    """A zenoh.Config: a JSON5 file if given (flags still override it), else the config's transport section.

    By default the service listens on `transport.endpoint` and every other process ("node") connects to it:
    peers on loopback, no router, no multicast.
    """
    if mode is not None and mode not in ("peer", "client", "router"):
        raise ConfigError(f"--mode must be peer, client or router, got {mode!r}")
    if zenoh_file:
        zenoh_file = str(zenoh_config_file(zenoh_file))
        try:
            conf = zenoh.Config.from_file(zenoh_file)
        except Exception as err:
            raise ConfigError(f"{zenoh_file}: not a usable Zenoh JSON5 config ({err})", source=zenoh_file) from None
        if mode:
            conf.insert_json5("mode", json.dumps(mode))
            if mode == "client" and not listen:  # a file written for a peer listens; a client cannot
                conf.insert_json5("listen/endpoints", "[]")
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        _wait_for_router(conf)
        return conf
    mode = mode or transport.mode
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    endpoints_c = list(connect) or list(transport.connect)
    endpoints_l = list(listen) or list(transport.listen)
    if role == "service" and not endpoints_l and mode != "client":
        endpoints_l = [transport.endpoint]
    if role == "node" and not endpoints_c:
        endpoints_c = [transport.endpoint]
    if mode == "client" and endpoints_l:
        raise ConfigError("a Zenoh client cannot listen: drop --listen (or transport.listen) or use --mode peer")
    if endpoints_c:
        conf.insert_json5("connect/endpoints", json.dumps(endpoints_c))
    if endpoints_l:
        conf.insert_json5("listen/endpoints", json.dumps(endpoints_l))
    elif mode == "peer":
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))  # loopback only, any port
    conf.insert_json5("scouting/multicast/enabled", json.dumps(transport.multicast_scouting))
    _wait_for_router(conf)
    return conf


ROUTER_WAIT_MS = 30000


def _wait_for_router(conf: zenoh.Config) -> None:
    """A client that was not told how long to wait for its router waits 30 s: processes start in any order."""
    if json.loads(conf.get_json("mode")) == "client" and json.loads(conf.get_json("connect/timeout_ms")) is None:
        conf.insert_json5("connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": ROUTER_WAIT_MS}))
        conf.insert_json5("connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": True}))


def zenoh_config_file(name: str) -> Path:
    """A JSON5 path, or the name of a shipped Zenoh config (configs/zenoh/<name>.json5: router, client)."""
    p = Path(name)
    if p.exists():
        return p
    import replanner_configs

    shipped = Path(replanner_configs.__file__).parent / "zenoh"
    if (shipped / f"{name}.json5").exists():
        return shipped / f"{name}.json5"
    names = ", ".join(sorted(f.stem for f in shipped.glob("*.json5")))
    raise ConfigError(f"--zenoh-config {name!r}: no such file, and not a shipped Zenoh config ({names})", source=name)


def free_port() -> int:
    """A TCP port on loopback that is free right now (tests and benches start services on it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def node_session(endpoint: str) -> zenoh.Session:
    """A peer that connects to `endpoint` only (loopback listener, no multicast): tests, benches, scripts."""
    return open_session(make_config(TransportConfig(endpoint=endpoint), "node"))


def open_session(conf: zenoh.Config) -> zenoh.Session:
    zenoh.try_init_log_from_env()  # RUST_LOG=... shows Zenoh's own log (stdout); without it Zenoh stays silent
    try:
        return zenoh.open(conf)
    except Exception as err:
        raise ConfigError(f"cannot open a Zenoh session: {err} (check --mode, --connect and --listen)") from None
