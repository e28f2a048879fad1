"""The simulated cell end to end: `replanner sim` under physics, and a short `replanner demo` (three processes)."""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest

from replanner.apps.client import Client
from replanner.apps.demo import Recording, compute_metrics
from replanner.apps.pick_place import Gripper
from replanner.transport import messages as m
from tests.service_helpers import Proc, free_port, node_session, replanner_cmd

pytestmark = pytest.mark.slow
NAMES = [f"panda_joint{i}" for i in range(1, 8)]


def test_sim_arm_follows_goals_under_physics_and_reports_truth(tmp_path):
    """serve (static objects only) + sim without cameras or operator: goals succeed, joint states >= 100 Hz."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    serve = Proc("serve", replanner_cmd("serve", "-c", "demo", "--no-cameras", "-l", endpoint), tmp_path)
    sim = Proc(
        "sim",
        replanner_cmd(
            "sim", "-c", "demo", "--no-cameras", "--no-operator", "-e", endpoint, "--log", str(tmp_path / "t")
        ),
        tmp_path,
    )
    session = node_session(endpoint)
    try:
        client = Client(session, "panda", timeout=10.0)
        end = time.monotonic() + 60
        while not (client.wait_alive(1.0) and client.state()["position"] is not None):
            assert time.monotonic() < end and serve.alive() and sim.alive(), serve.tail() + sim.tail()
        stamps = []
        sub = session.declare_subscriber(
            client.keys.joint_states, lambda s: stamps.append(m.decode_joint_state(s.payload.to_bytes(), NAMES)[0])
        )
        end = time.monotonic() + 30  # the subscription reaches the sim through the router: on a busy machine, slowly
        while not stamps:
            assert time.monotonic() < end, "no joint state reached a new subscriber in 30 s" + sim.tail()
            time.sleep(0.05)
        goal = [0.3, -0.4, 0.1, -2.0, 0.0, 1.7, 0.9]
        res = client.send_goal(joints=goal).wait(30)
        sub.undeclare()
        assert res is not None and res["status"] == "succeeded", (res, serve.tail())
        st = client.state()
        assert np.abs(np.array(st["position"]) - goal).max() < 0.01  # pybullet's measured joints
        dt = np.diff(stamps)
        assert len(stamps) / (stamps[-1] - stamps[0]) >= 100, (
            f"joint-state rate {len(stamps) / (stamps[-1] - stamps[0])}"
        )
        assert dt.min() > 0
        g = Gripper(session, client.keys.root)
        part = g.state()
        assert part["part_in"] == "bin_a" and not part["grasped"]
        with pytest.raises(Exception, match="no part within"):
            g.grasp()  # the tip is far from the part: a clear error, and the sim goes on
        with pytest.raises(Exception, match="unknown command"):
            g.command("fly")
    finally:
        session.close()
        sim.stop()
        serve.stop()
    truth = [json.loads(line) for line in (tmp_path / "t").read_text().splitlines()]
    assert truth[0]["kind"] == "start" and truth[-1]["kind"] == "stop"
    assert not [e for e in truth if e["kind"] == "contact"], "the arm touched something on a free path"


def test_short_demo_end_to_end(tmp_path):
    """Three processes on loopback, two cycles, the operator steps in; metrics come from the sim's truth."""
    out = tmp_path / "out.json"
    plot = tmp_path / "timeline.png"
    r = subprocess.run(
        replanner_cmd(
            "demo", "--cycles", "2", "--seed", "7", "--json", str(out), "--plot", str(plot), "--log-dir", str(tmp_path)
        ),
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    met = json.loads(out.read_text())
    logs = "\n".join((tmp_path / f).read_text()[-2000:] for f in ("pick-and-place.log", "serve.log"))
    assert met["cycles_completed"] == 2 and met["cycles_attempted"] == 2, (met, logs)
    assert met["intrusions"] >= 1, met
    assert "operator" not in met["collisions_by_object"], met
    assert plot.stat().st_size > 10_000
    assert "cycles completed" in r.stdout


def test_a_short_soak_samples_every_process(tmp_path):
    """The CI's soak: the demo looping until a sample counts 5 cycles, sampled every 5 s (at most 6 minutes; the
    hour-long one is run by hand). A cycle takes its motions' time, so 5 cycles span more than 5 samples."""
    out, plot = tmp_path / "soak.json", tmp_path / "soak.png"
    r = subprocess.run(
        replanner_cmd(
            "soak",
            "--minutes",
            "6",
            "--cycles",
            "5",
            "--every",
            "5",
            "--json",
            str(out),
            "--plot",
            str(plot),
            "--log-dir",
            str(tmp_path),
        ),  # fmt: skip
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    res = json.loads(out.read_text())
    assert len(res["samples"]) >= 5 and res["cycles"] >= 5 and not res["crashed"], res["samples"]
    last = res["samples"][-1]
    assert {"serve", "sim", "pick-and-place", "serve child 0"} <= set(last["rss_mb"]), last
    assert res["collisions"] == 0, res["metrics"]["collisions_by_object"]
    assert set(res["growth"]) >= {"serve", "sim"} and plot.stat().st_size > 10_000


def test_metrics_come_from_truth_and_transitions():
    """A cycle counts only when the sim saw the part set down in the other bin; reactions pair with truth."""
    rec = Recording(
        truth=[
            {"stamp": 10.0, "kind": "operator_entering"},
            {"stamp": 10.5, "kind": "entered_path"},
            {"stamp": 11.0, "kind": "clearance", "clearance": 0.12},
            {"stamp": 11.5, "kind": "clearance", "clearance": 0.05},
            {"stamp": 12.0, "kind": "operator_left"},
            {"stamp": 13.0, "kind": "placed", "on": "bin_b", "picked_from": "bin_a"},
            {"stamp": 14.0, "kind": "placed", "on": "bin_b", "picked_from": "bin_b"},  # not moved: no cycle
            {"stamp": 15.0, "kind": "contact", "object": "operator", "depth": -0.001},
            {"stamp": 15.4, "kind": "contact_end", "object": "operator", "deepest": -0.03},
        ],
        transitions=[
            {"stamp": 10.6, "from": "MONITORING", "to": "MONITORING_WITH_PLANNING_PENDING", "trigger": "blocked"},
            {"stamp": 10.75, "from": "MONITORING_WITH_PLANNING_PENDING", "to": "MONITORING", "trigger": "spliced"},
        ],
        status=[{"stamp": 9.9, "map_voxels": 5}, {"stamp": 12.1, "map_voxels": 400}, {"stamp": 12.4, "map_voxels": 6}],
        progress=[{"cycle": 1, "step": "start"}, {"cycle": 2, "step": "start"}],
    )
    met = compute_metrics(rec, safety_distance=0.03, bins=("bin_a", "bin_b"), t0=0.0, t1=60.0)
    assert met["cycles_attempted"] == 2 and met["cycles_completed"] == 1 and met["cycles_per_minute"] == 1.0
    assert met["collisions"] == 1 and met["collisions_by_object"] == {"operator": 1}
    assert met["deepest_penetration_m"] == -0.03  # the episode's deepest, not its first touch
    assert met["min_clearance_m"] == 0.05
    assert met["replans"] == {"started": 1, "spliced": 1, "cancelled": 0, "failed": 0}
    assert met["reaction_s"]["n"] == 1 and abs(met["reaction_s"]["median"] - 0.1) < 1e-9
    assert abs(met["replan_s"]["median"] - 0.15) < 1e-9
    assert abs(met["clearing_s"]["median"] - 0.4) < 1e-9
