"""The secure profile (`replanner certs`): mutual TLS and Zenoh access control, with real processes on loopback,
peer to peer and through `replanner router`. Who is not in the rules can neither command nor feed the service."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
import zenoh
from replanner_services.procs import Proc, replanner_cmd

from replanner.apps.client import Client
from replanner.config import parse_config
from replanner.errors import ConfigError
from replanner.model.robot import RobotModel
from replanner.sections import TransportConfig
from replanner.transport import messages as m
from replanner.transport.keys import Keys
from replanner.transport.refusals import Refusals
from replanner.transport.secure import (
    DEFAULT_IDENTITIES,
    Identity,
    access_rules,
    make_certificates,
    parse_identities,
    write_profile,
)
from replanner.transport.session import free_port, make_config, open_session
from tests.conftest import CONFIGS
from tests.test_service import HOME, Recorder, _wait

W, H = 64, 48  # the test's camera: small organized frames


def _session(path: Path | None, endpoint: str, via_router: bool, tls: dict | None = None) -> zenoh.Session:
    """A session from an identity's generated config, or (path None) a hand-made one: `tls` keys, no access rules."""
    if path is not None:
        mode = "client" if via_router else None
        listen = () if via_router else ("tls/127.0.0.1:0",)  # not the service's port, even with its identity
        return open_session(make_config(TransportConfig(), "node", mode, [endpoint], listen, str(path)))
    conf = make_config(TransportConfig(endpoint=endpoint), "node", "client" if via_router else "peer")
    if via_router:  # a client the router refuses gives up after 5 s, not the 30 s it would wait for a router to start
        conf.insert_json5("connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": 5000}))
    if tls is not None:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return open_session(conf)


class Camera:
    """The authorized sensor: organized frames of no returns at 10 Hz (a live camera looking at nothing)."""

    def __init__(self, session: zenoh.Session, keys: Keys):
        self.pub = session.declare_publisher(keys.cloud("front"))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        nan = np.full((W * H, 3), np.nan, np.float32)
        while not self.stop.wait(0.1):
            self.pub.put(m.encode_cloud(time.time(), nan, "front", width=W, height=H))

    def close(self):
        self.stop.set()
        self.thread.join(2.0)


def _trajectory(names, q0, stamp) -> bytes:
    """0.3 rad on joint 1 in 1 s, starting where the robot stands (a trajectory the robot would follow)."""
    t = np.linspace(0.0, 1.0, 11)
    s = 10 * t**3 - 15 * t**4 + 6 * t**5
    q = np.tile(q0, (len(t), 1))
    q[:, 0] += 0.3 * s
    qd = np.gradient(q, t, axis=0)
    qdd = np.gradient(qd, t, axis=0)
    return m.encode_trajectory(stamp, names, t, q, qd, qdd, "panda_link0")


@pytest.fixture(params=["peer", "router"])
def cell(request, tmp_path):
    via_router = request.param == "router"
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    data = yaml.safe_load((CONFIGS / "panda.yaml").read_text())
    front = data["perception"]["sensors"][0]
    front.update(width=W, height=H)
    data["perception"]["sensors"] = [front]
    data["controller"] = {"speed_separation": {"enabled": False}}
    cfg_path = tmp_path / "panda_secure.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    cfg = parse_config(data, base_dir=CONFIGS)
    keys = Keys("panda")
    certs = tmp_path / "certs"
    ids = [Identity(n, r) for n, r in DEFAULT_IDENTITIES.items()]
    paths = write_profile(certs, keys, ids, endpoint)
    make_certificates(certs, [Identity("visitor", "client")])  # signed by the cell's CA, but in no rule
    make_certificates(tmp_path / "rogue", [Identity("operator", "client")])  # the right name from another CA
    procs = []
    if via_router:
        procs.append(
            Proc("router", replanner_cmd("router", "--zenoh-config", str(paths["router"]), "-l", endpoint), tmp_path)
        )
        joined = ["-m", "client", "-e", endpoint]
    else:
        joined = []
    procs.append(
        Proc(
            "serve",
            replanner_cmd("serve", "-c", str(cfg_path), "-v", "--zenoh-config", str(paths["service"]), *joined),
            tmp_path,
        )
    )
    procs.append(
        Proc(
            "robot",
            replanner_cmd("robot", "--kinematic", "-c", str(cfg_path), "--zenoh-config", str(paths["robot"]), *joined),
            tmp_path,
        )
    )
    opened = []
    camera = None

    def session(path=None, tls=None):
        """An open session, or None where Zenoh refuses to open one (a client that cannot reach its router)."""
        try:
            s = _session(path, endpoint, via_router, tls)
        except ConfigError:
            if path is not None:
                raise
            return None
        opened.append(s)
        return s

    def logs():
        return "\n".join(f"--- {p.name} ---\n{p.tail()}" for p in procs)

    try:
        operator = session(paths["operator"])
        client = Client(operator, "panda", timeout=5.0)
        camera = Camera(session(paths["camera"]), keys)
        robot = RobotModel.from_config(cfg.robot)
        rec = Recorder(operator, keys, robot.joint_names)
        _wait(lambda: list(operator.liveliness().get(keys.alive, timeout=0.5)), 60, "the service's token", None)
        _wait(lambda: rec.js and client.state()["not_ready"] is None, 60, "the service ready for goals", None)
        ns = type("Cell", (), {})()
        ns.keys, ns.paths, ns.certs, ns.client, ns.rec, ns.robot, ns.session = (
            keys,
            paths,
            certs,
            client,
            rec,
            robot,
            session,
        )
        ns.procs, ns.logs, ns.tmp, ns.via_router = procs, logs, tmp_path, via_router
        yield ns
        rec.close()
        client.close()
    except AssertionError as err:
        raise AssertionError(f"{err}\n{logs()}") from None
    finally:
        if camera is not None:  # before its session closes, on every path
            camera.close()
        for s in opened:
            s.close()
        for p in reversed(procs):
            p.stop()


def _still(cell, seconds=1.0) -> float:
    """How far the robot moved [rad] over `seconds` (by its own joint states)."""
    t0 = time.time()
    q0 = cell.rec.latest()[1]
    time.sleep(seconds)
    assert cell.rec.latest()[0] > t0, "the robot's joint states stopped"
    return float(np.abs(cell.rec.latest()[1] - q0).max())


def _asks(session, key, payload=b"{}") -> list:
    return list(session.get(key, payload=payload, timeout=2.0))


def test_only_the_cells_identities_play_their_parts(cell):
    keys, names = cell.keys, list(cell.robot.joint_names)
    assert cell.client.send_goal(HOME).wait(30)["status"] == "succeeded", cell.logs()
    state0 = cell.client.state()
    goal = json.dumps({"id": "intruder", "joints": [0.5, 0.0, 0.0, -1.8, 0.0, 1.8, 0.785]}).encode()
    ca = str(cell.certs / "ca.pem")
    outsiders = {
        "no certificate": cell.session(tls={"root_ca_certificate": ca}),
        "another CA's certificate": cell.session(
            tls={
                "root_ca_certificate": ca,
                "enable_mtls": True,
                **{f"{side}_private_key": str(cell.tmp / "rogue" / "operator.key") for side in ("listen", "connect")},
                **{f"{side}_certificate": str(cell.tmp / "rogue" / "operator.pem") for side in ("listen", "connect")},
            }
        ),
        "the CA's certificate of no role": cell.session(
            tls={
                "root_ca_certificate": ca,
                "enable_mtls": True,
                **{f"{side}_private_key": str(cell.certs / "visitor.key") for side in ("listen", "connect")},
                **{f"{side}_certificate": str(cell.certs / "visitor.pem") for side in ("listen", "connect")},
            }
        ),
    }
    others = {"a sensor": cell.session(cell.paths["camera"]), "a client": cell.session(cell.paths["operator"])}
    time.sleep(1.0)
    outsiders = {who: s for who, s in outsiders.items() if s is not None}  # refused at the door: nothing to try
    for who, s in outsiders.items():
        assert _asks(s, keys.goal, goal) == [], f"{who} reached the goal key"
        assert list(s.liveliness().get(keys.alive, timeout=1.0)) == [], f"{who} sees the service"
    assert _asks(others["a sensor"], keys.goal, goal) == [], "a sensor reached the goal key"
    # nobody but the service moves the robot; nobody but the robot feeds joint states, nobody but sensors clouds
    q_now = cell.rec.latest()[1]
    far = np.array(q_now) + 0.5
    for who, s in {**outsiders, **others}.items():
        s.put(keys.trajectory, _trajectory(names, q_now, time.time()))
        s.put(keys.joint_states, m.encode_joint_state(time.time(), names, far))
        s.put(keys.joint_states, m.encode_joint_state(time.time(), names + names[:1], list(far) + [0.0]))  # would count
        if who != "a sensor":
            s.put(keys.cloud("rear"), m.encode_cloud(time.time(), np.zeros((10, 3), np.float32), "rear"))
    assert _still(cell) < 1e-9, "a trajectory from someone other than the service moved the robot"
    state = cell.client.state()
    spoofed = {k: n for k, n in state["rejections"].items() if k != "clouds/front"}  # the cell's own camera may lag
    assert spoofed == {k: n for k, n in state0["rejections"].items() if k != "clouds/front"}, (
        "a spoofed joint state or cloud reached the service"
    )
    assert np.abs(np.array(state["position"]) - q_now).max() < 1e-6
    assert state["state"] == "WAITING" and state["goal_id"] == state0["goal_id"]
    # the same messages from the right identities do arrive: the rules, not the network, stopped them
    cam = cell.session(cell.paths["camera"])
    rob = cell.session(cell.paths["robot"])
    time.sleep(1.0)
    cam.put(keys.cloud("rear"), m.encode_cloud(time.time(), np.zeros((10, 3), np.float32), "rear"))
    rob.put(keys.joint_states, m.encode_joint_state(time.time(), names + names[:1], list(far) + [0.0]))
    _wait(
        lambda: {"clouds/rear", "joint_states"} <= set(cell.client.state()["rejections"]),
        5,
        "the controls (a sensor's cloud, the robot's joint state)",
        None,
    )
    svc = cell.session(cell.paths["service"])
    time.sleep(1.0)
    svc.put(keys.trajectory, _trajectory(names, cell.rec.latest()[1], time.time()))
    _wait(lambda: abs(cell.rec.latest()[1][0] - q_now[0]) > 0.1, 5, "the robot to follow the service's identity")
    # where the rules were enforced, what was refused is logged and counted: by the router, or by each peer
    refused = cell.client.state()["access_refused"]
    print("the service refused:", refused)
    if cell.via_router:
        router = cell.procs[0]
        assert router.name == "router"
        shown = SimpleNamespace(logs=lambda: router.tail(80))
        said = f"refused: Put from operator on {keys.trajectory}"
        _wait(lambda: said in router.tail(400), 5, "the router's log", shown)
        assert f"refused: Put from camera on {keys.joint_states}" in router.tail(400), router.tail(60)
        router.stop()
        assert "the router refused" in router.tail(5), router.tail(5)
    else:
        assert any(k.endswith(f"Put (ingress) on {keys.joint_states}") for k in refused), refused
        robot = next(p for p in cell.procs if p.name == "robot")
        _wait(lambda: f"on {keys.trajectory} (ingress" in robot.tail(400), 5, "the robot's log of what it refused")
        robot.stop()
        assert "refused" in robot.tail(5) and "by access control" in robot.tail(5), robot.tail(5)


_Z = "zenoh::net::routing::interceptor::access_control"
_ROBOT, _OP = "4770b799d937b5eb311631d2a3f19967", "c06924706957d35706e0981da6a15c36"


def _line(thread: int, body: str) -> str:
    return f"2026-11-29T18:09:23.305093Z TRACE rx-0 ThreadId({thread:02d}) {_Z}: {body}\n"


def test_refusals_count_messages_refused_not_the_verdicts_zenoh_caches():
    """Lines as Zenoh 1.x writes them (taken from a router's log): a caching block states a verdict for each of 9
    actions on a key, in order (computed, nothing refused yet); what follows it, or a cached result, is a message
    refused."""
    r = Refusals()
    key = "replanner/@v1/panda/trajectory"
    via = f"{_ROBOT} on Interface(lo)+CertCommonName(robot)+Transport(Tls)+{_ROBOT}"
    block = [_line(8, f"ACL (ingress): caching permissions for `{key}` ...")]
    for what in ("Query", "Reply", "Put", "Delete", "Declare/Undeclare Subscriber", "Declare/Undeclare Queryable"):
        block.append(_line(8, f"{via} is unauthorized to {what} (ingress) on {key}"))
    block.insert(3, _line(9, "ACL (egress): caching permissions for `other` ..."))  # another thread's block
    for what in ("Declare/Undeclare Liveliness Token", "Liveliness Query", "Declare Liveliness Subscriber"):
        block.append(_line(8, f"{via} is unauthorized to {what} (ingress) on {key}"))
    assert all(r.feed(x) for x in block)
    assert r.total == 0 and r.table() == {}
    op = f"{_OP} on Interface(lo)+CertCommonName(operator)+Transport(Tls)+{_OP}"
    r.feed(_line(8, f"{op} is unauthorized to Put (ingress) on {key}"))
    r.feed(_line(8, f"{op} is authorized to Put (ingress) on replanner/@v1/panda/goal"))
    r.feed(_line(10, f"Using cached result: {_OP} is unauthorized to Put (ingress) on {key}"))
    r.feed(_line(10, f"Using cached result: {_ROBOT} is unauthorized to Query (ingress) on x"))
    assert r.table() == {f"operator: Put (ingress) on {key}": 2, "robot: Query (ingress) on x": 1}
    assert r.total == 3
    # a session in no rule has no subject: its caching block has no lines, and what its thread says next is a message
    r.feed(_line(9, f"{op} is unauthorized to Query (ingress) on {key}"))
    r.feed(_line(11, "ACL (ingress): caching permissions for `replanner/@v1/panda/alive` ..."))
    r.feed(_line(11, f"{op} is unauthorized to Put (ingress) on {key}"))
    assert r.table()[f"operator: Put (ingress) on {key}"] == 3 and r.table()[f"operator: Query (ingress) on {key}"] == 1
    assert r.total == 5
    r.feed(f"\x1b[2m2026\x1b[0m  INFO acc-0 ThreadId(05) {_Z}: e00da70d did not match any configured ACL subject.")
    assert r.no_role == {"e00da70d": 1}
    assert not r.feed("replanner: kinematic panda on replanner/@v1/panda (Ctrl-C stops)\n")  # passed on


def test_certs_command_and_bad_identities(tmp_path):
    with pytest.raises(ConfigError, match="NAME:ROLE"):
        parse_identities(["picker:boss"])
    with pytest.raises(ConfigError, match="NAME:ROLE"):
        parse_identities(["pick/er:client"])
    with pytest.raises(ConfigError, match="TLS only"):
        write_profile(tmp_path / "x", Keys("panda"), [Identity("a", "client")], "tcp/127.0.0.1:7447")
    with pytest.raises(ConfigError, match="must differ"):
        write_profile(tmp_path / "x", Keys("panda"), [Identity("a", "client"), Identity("a", "robot")])
    rules = access_rules(Keys("panda"), parse_identities(["picker:client", "arm:robot"]), "service")
    assert rules["default_permission"] == "deny"
    assert {s["id"]: s["cert_common_names"] for s in rules["subjects"]} == {"client": ["picker"], "robot": ["arm"]}
    import subprocess

    out = subprocess.run(
        replanner_cmd("certs", str(tmp_path / "c"), "-i", "picker:client", "-i", "svc:service", "--host", "cell.local"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "picker" in out.stdout and (tmp_path / "c" / "picker.json5").exists()
    conf = json.loads((tmp_path / "c" / "svc.json5").read_text().split("\n", 1)[1])
    assert conf["transport"]["link"]["tls"]["enable_mtls"] is True
    assert conf["transport"]["link"]["protocols"] == ["tls"]
    zenoh.Config.from_file(str(tmp_path / "c" / "picker.json5"))  # Zenoh reads what we wrote


def test_security_doc_commands_run(tmp_path):
    """docs/security.md's commands, block by block, in a fresh directory (`docker` lines aside: no engine here)."""
    import re
    import shlex
    import subprocess

    doc = (Path(__file__).resolve().parents[1] / "docs" / "security.md").read_text()
    blocks = re.findall(r"```sh\n(.*?)```", doc, re.S)
    assert len(blocks) >= 4
    port = str(free_port())
    keys = Keys("panda")
    ran = 0
    for block in blocks:
        procs = []
        try:
            for line in block.strip().splitlines():
                line = line.replace("7447", port)
                argv = shlex.split(line.rstrip("&"))
                if argv[0] == "docker":
                    continue
                assert argv[0] == "replanner", line
                if line.endswith("&"):
                    procs.append(Proc(f"{argv[1]}{len(procs)}", replanner_cmd(*argv[1:]), tmp_path, cwd=tmp_path))
                    continue
                if procs:  # the block's processes are up before its first client command
                    via_router = "-m" in line
                    probe = _session(tmp_path / "cell-certs" / "operator.json5", f"tls/127.0.0.1:{port}", via_router)
                    try:
                        _wait(
                            lambda p=probe: list(p.liveliness().get(keys.alive, timeout=0.5)),
                            60,
                            f"the service for {line!r}\n" + "\n".join(p.tail() for p in procs),
                        )
                    finally:
                        probe.close()
                out = subprocess.run(
                    replanner_cmd(*argv[1:]), cwd=tmp_path, capture_output=True, text=True, timeout=120
                )
                assert out.returncode == 0, f"{line}\n{out.stdout}\n{out.stderr}"
                ran += 1
        finally:
            for p in reversed(procs):
                p.stop()
    assert ran >= 5
