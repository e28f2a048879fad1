"""`replanner bench view`: what the web view costs the service, and how fast it draws with a big map.

serve and robot --kinematic run as processes, and a camera fills the map with about `voxels` voxels. The arm moves
back and forth between two joint goals. Phases without and with a view attached alternate. A phase with a view
runs `CellView` in this process, plus a headless chromium on its page if `browser`. The service's monitor rate is
the growth of `state.checks` per second while MONITORING. The view's rate is its own drawing steps per second.
"""

from __future__ import annotations

import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from replanner.apps.client import Client
from replanner.config import config_path
from replanner.errors import ReplannerError
from replanner.perception.camera import pose_from_config
from replanner.sim.config import load_cell_config
from replanner.stats import summary
from replanner.transport import messages as m
from replanner.transport.session import free_port, node_session

from .procs import Proc, replanner_cmd
from .view import CellView, headless_chromium

A = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
B = [0.9, -0.4, 0.3, -2.0, 0.0, 1.8, 0.785]


def slab(voxels: int, resolution: float, seed: int) -> np.ndarray:
    """Points on a 1-voxel grid filling a slab behind the arm (x < -0.45 m): about `voxels` voxels, off its path."""
    rng = np.random.default_rng(seed)  # jitter within a voxel: points differ by seed, voxels do not
    side = int(np.ceil(np.sqrt(voxels / 4)))
    g = np.arange(side) * resolution
    x, y, z = np.meshgrid(-0.45 - np.arange(4) * resolution, g - g.mean(), 0.2 + g * 0.5, indexing="ij")
    pts = np.stack([x, y, z], -1).reshape(-1, 3)[:voxels]
    return pts + rng.uniform(-0.2, 0.2, pts.shape) * resolution + resolution / 2


def run(
    config: str = "panda",
    *,
    voxels: int = 50_000,
    seconds: float = 20.0,
    rounds: int = 2,
    seed: int = 0,
    browser: bool = False,
) -> dict:
    logs = Path(tempfile.mkdtemp(prefix="replanner-bench-view-"))
    base = load_cell_config(config)
    data = {
        "base": str(config_path(config)),
        "controller": {"speed_separation": {"enabled": False}},
    }
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    data["transport"] = {"endpoint": endpoint}
    sensor = base.perception.sensors[0] if base.perception and base.perception.sensors else None
    if sensor is None:
        raise ReplannerError(f"{config}: bench view needs a camera (perception.sensors) to fill the map")
    data["perception"] = {"sensors": [sensor.model_dump(mode="json", exclude_none=True)]}  # the one camera fed here
    cfg_path = logs / "config.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    cfg = load_cell_config(str(cfg_path))
    procs = [
        Proc("serve", replanner_cmd("serve", "-c", str(cfg_path), "-l", endpoint), logs),
        Proc("robot", replanner_cmd("robot", "--kinematic", "-c", str(cfg_path), "-e", endpoint), logs),
    ]
    session = node_session(endpoint)
    stop = threading.Event()
    try:
        client = Client(session, cfg.robot.name, cfg.transport.namespace, timeout=10.0)
        end = time.monotonic() + 120
        while not client.wait_alive(timeout=1.0):
            if time.monotonic() > end or not all(p.alive() for p in procs):
                raise ReplannerError(f"the service did not start; see {logs}")
        T = pose_from_config(sensor.pose)
        cap = sensor.max_points or sensor.width * sensor.height
        pts = slab(min(voxels, cap), cfg.perception.resolution, seed)
        cloud = ((pts - T[:3, 3]) @ T[:3, :3]).astype(np.float32)
        pub = session.declare_publisher(client.keys.cloud(sensor.name))

        def camera():
            while not stop.wait(1.0 / min(sensor.rate_hz, 5.0)):
                pub.put(m.encode_cloud(time.time(), cloud, sensor.name))

        threading.Thread(target=camera, daemon=True).start()
        end = time.monotonic() + 60
        while client.state()["map_voxels"] < 0.9 * len(pts) or client.state()["not_ready"] is not None:
            if time.monotonic() > end:
                raise ReplannerError(f"the map did not fill: {client.state()['map_voxels']} voxels; see {logs}")
            time.sleep(0.5)

        def mover():
            goals = [A, B]
            i = 0
            while not stop.is_set():
                try:
                    client.send_goal(goals[i % 2], velocity_scale=0.25).wait(60)  # slow: mostly MONITORING
                except ReplannerError as err:  # a refused goal shows as a phase without motion
                    print(f"bench view: {err}", file=sys.stderr, flush=True)
                    stop.wait(1.0)
                i += 1

        threading.Thread(target=mover, daemon=True).start()

        def phase(view_on: bool) -> dict:
            view = chrome = None
            if view_on:
                view = CellView(cfg, session, port=free_port(), map_hz=2.0).start()
                if browser:
                    chrome = headless_chromium(view.url)
                time.sleep(3.0)  # the view's first map and the page's first frames
            rates, samples = [], []
            last = None
            t_end = time.monotonic() + seconds
            while time.monotonic() < t_end:
                st, t = client.state(), time.monotonic()
                if last is not None and st["state"] == "MONITORING" and last[1]["state"] == "MONITORING":
                    rates.append((st["checks"] - last[1]["checks"]) / (t - last[0]))
                last = (t, st)
                if view is not None:
                    samples.append(view.rate)
                time.sleep(0.25)
            out = {"monitor_checks_per_s": summary(rates), "view": view_on}
            if view is not None:
                out["view_updates_per_s"] = summary(samples)
                out["map_voxels_drawn"] = int(len(view.watch.voxels))
                if chrome is not None:
                    chrome.quit()
                view.stop()
            return out

        phases = [phase(on) for _ in range(rounds) for on in (False, True)]
        if any(p["monitor_checks_per_s"]["n"] == 0 for p in phases):
            raise ReplannerError(f"a phase saw no motion (goals failing?); see {logs}")
        without = [p["monitor_checks_per_s"]["median"] for p in phases if not p["view"]]
        with_ = [p["monitor_checks_per_s"]["median"] for p in phases if p["view"]]
        return {
            "robot": cfg.robot.name,
            "map_voxels": client.state()["map_voxels"],
            "seconds_per_phase": seconds,
            "browser": browser,
            "phases": phases,
            "monitor_rate_without_hz": float(np.mean(without)),
            "monitor_rate_with_hz": float(np.mean(with_)),
            "ratio": float(np.mean(with_) / np.mean(without)),
            "view_updates_per_s_median": float(
                np.median([p["view_updates_per_s"]["median"] for p in phases if p["view"]])
            ),
            "bars": {"ratio": 0.95, "view_updates_per_s": 10.0},
            "logs": str(logs),
        }
    finally:
        stop.set()
        session.close()
        for p in procs:
            p.stop()
