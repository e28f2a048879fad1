"""Service, sim and pick-and-place client as separate processes, all Zenoh clients of one router process."""

from __future__ import annotations

import json
import time

import pytest

from replanner.apps.client import Client
from replanner.sections import TransportConfig
from replanner.transport.session import make_config, open_session, zenoh_config_file
from tests.service_helpers import Proc, free_port, replanner_cmd

pytestmark = pytest.mark.slow


def test_a_pick_and_place_cycle_through_a_router(tmp_path):
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    # the shipped client config, pointed at this router: what docker/compose.yaml does with tcp/router:7447
    via = ["--zenoh-config", "client", "-e", router_ep]
    router = Proc("router", replanner_cmd("router", "-l", router_ep), tmp_path)
    procs = [router]
    session = None
    try:
        procs.append(Proc("serve", replanner_cmd("serve", "-c", "demo", "-v", *via), tmp_path))
        procs.append(Proc("sim", replanner_cmd("sim", "-c", "demo", "--no-operator", *via), tmp_path))
        session = open_session(make_config(TransportConfig(), "node", None, [router_ep], (), "client"))
        client = Client(session, "panda", timeout=10.0)
        truth = []
        sub = session.declare_subscriber(
            f"{client.keys.root}/sim/truth", lambda s: truth.append(json.loads(s.payload.to_bytes()))
        )
        end = time.monotonic() + 90
        while not (client.wait_alive(1.0) and client.state()["position"] is not None):
            assert time.monotonic() < end and all(p.alive() for p in procs), "\n".join(p.tail() for p in procs)
        pnp = Proc("pick-and-place", replanner_cmd("pick-and-place", "-c", "demo", "--cycles", "1", *via), tmp_path)
        procs.append(pnp)
        try:
            rc = pnp.p.wait(180)
        except Exception:
            rc = None
        assert rc == 0, "\n".join(p.tail() for p in procs)
        time.sleep(0.5)
        sub.undeclare()
        kinds = [e["kind"] for e in truth]
        assert "grasped" in kinds and "placed" in kinds, kinds
        placed = next(e for e in truth if e["kind"] == "placed")
        assert placed["on"] == "bin_b" and placed["picked_from"] == "bin_a"
        assert "contact" not in kinds, [e for e in truth if e["kind"] == "contact"]
        # everyone reached everyone through the router: nobody listens but the router
        for p in procs[1:]:
            assert "listening" not in p.log.read_text()
    finally:
        if session is not None:
            session.close()
        for p in reversed(procs):
            p.stop()


def test_a_service_started_before_its_router_waits_for_it(tmp_path):
    """Processes of a cell start in any order (compose, systemd): a client that finds no router yet keeps trying."""
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    procs = [
        Proc("serve", replanner_cmd("serve", "-c", "demo", "--no-cameras", "-m", "client", "-e", router_ep), tmp_path)
    ]
    session = None
    try:
        time.sleep(2.0)  # longer than Zenoh's first retry period (1 s): a client that gives up would be gone
        assert procs[0].alive(), procs[0].tail()
        procs.append(Proc("router", replanner_cmd("router", "-l", router_ep), tmp_path))
        session = open_session(make_config(TransportConfig(), "node", "client", [router_ep]))
        client = Client(session, "panda", timeout=10.0)
        end = time.monotonic() + 60
        while not client.wait_alive(1.0):
            assert time.monotonic() < end and all(p.alive() for p in procs), "\n".join(p.tail() for p in procs)
    finally:
        if session is not None:
            session.close()
        for p in reversed(procs):
            p.stop()


def test_a_client_waits_for_its_router_unless_its_file_says_otherwise(tmp_path):
    wait = json.loads(make_config(TransportConfig(), "node", "client", ["tcp/127.0.0.1:7447"]).get_json("connect"))
    assert wait["timeout_ms"]["client"] == 30000 and wait["exit_on_failure"]["client"] is True
    own = tmp_path / "own.json5"
    own.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7447"], timeout_ms: {client: 500}}}')
    assert json.loads(
        make_config(TransportConfig(), "node", None, (), (), str(own)).get_json("connect/timeout_ms")
    ) == {"client": 500}
    # a peer never exits for an absent endpoint: nothing to add
    assert json.loads(make_config(TransportConfig(), "node", "peer").get_json("connect/timeout_ms")) is None


def test_shipped_zenoh_configs_are_client_and_router():
    import zenoh

    client = zenoh.Config.from_file(str(zenoh_config_file("client")))
    router = zenoh.Config.from_file(str(zenoh_config_file("router")))
    assert json.loads(client.get_json("mode")) == "client"
    assert json.loads(router.get_json("mode")) == "router"
    assert json.loads(client.get_json("connect/endpoints")) == ["tcp/router:7447"]
    assert json.loads(router.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
