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


def test_shipped_zenoh_configs_are_client_and_router():
    import zenoh

    client = zenoh.Config.from_file(str(zenoh_config_file("client")))
    router = zenoh.Config.from_file(str(zenoh_config_file("router")))
    assert json.loads(client.get_json("mode")) == "client"
    assert json.loads(router.get_json("mode")) == "router"
    assert json.loads(client.get_json("connect/endpoints")) == ["tcp/router:7447"]
    assert json.loads(router.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
