"""`replanner sim` (physics, operator, ground truth; cameras in a child process) and `replanner cameras`."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import zenoh

from replanner.config import ReplannerConfig


def _wait_for_signal() -> threading.Event:
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    return done


def run_sim(
    cfg: ReplannerConfig,
    conf: zenoh.Config,
    *,
    seed: int,
    gui: bool,
    truth_log: str | None,
    operator: bool,
    cameras_cmd: list[str] | None,
) -> None:
    from replanner.sim.physics import PhysicsSim
    from replanner.transport.session import open_session

    done = _wait_for_signal()
    session = open_session(conf)
    child = None
    try:
        sim = PhysicsSim(cfg, session, seed=seed, gui=gui, truth_log=truth_log, operator=operator).start()
        if cameras_cmd:  # rendering holds the GIL for tens of ms: in the same process it would stall the physics
            child = subprocess.Popen(cameras_cmd)
        print(
            f"replanner: sim of {sim.robot.name} on {sim.keys.root} (seed {seed}, "
            f"operator {'on' if operator else 'off'}, cameras {'on' if cameras_cmd else 'off'}; Ctrl-C stops)",
            file=sys.stderr,
            flush=True,
        )
        while not done.wait(0.5):
            if child is not None and child.poll() is not None:
                print(f"replanner: the camera process exited ({child.returncode})", file=sys.stderr, flush=True)
                break
        sim.stop()
    finally:
        if child is not None and child.poll() is None:
            child.send_signal(signal.SIGINT)
            try:
                child.wait(5)
            except subprocess.TimeoutExpired:
                child.kill()
        session.close()


def run_cameras(cfg: ReplannerConfig, conf: zenoh.Config, *, seed: int) -> None:
    from replanner.sim.cloud_publisher import CloudPublisher
    from replanner.transport.session import open_session
    from replanner.world.scene import scene_from_config

    done = _wait_for_signal()
    session = open_session(conf)
    try:
        sensors = cfg.perception.sensors if cfg.perception else []
        rate = cfg.sim.camera_rate_hz or min((s.rate_hz for s in sensors), default=10.0)
        pub = CloudPublisher(cfg, session, scene_from_config(cfg), rate_hz=rate, mirror_sim=True, seed=seed).start()
        done.wait()
        pub.stop()
    finally:
        session.close()
