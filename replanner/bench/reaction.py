"""`replanner bench reaction`: a box dropped into the arm's path at a known time; how fast the arm reacts."""

from __future__ import annotations

import sys
import threading
import time
import traceback

import numpy as np
import pybullet as pb

from ..config import ReplannerConfig
from ..control import Goal, GoalRejected, GoalStatus, State
from ..model.geometry import Box
from ..model.transforms import make_transform
from ..sim.kinematic import KinematicSim
from ..sim.scene import PyBulletScene
from ..stats import summary
from .scenes import TABLE_SIZE

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])


def _small_cameras(cfg: ReplannerConfig, width: int, height: int) -> ReplannerConfig:
    """The first camera only, rendered at width x height (in-process rendering holds the GIL)."""
    sensor = cfg.perception.sensors[0].model_dump(mode="python")
    sensor.update(width=width, height=height, max_points=None)
    return cfg.override({"perception": {"sensors": [sensor]}})


def run(
    cfg: ReplannerConfig,
    *,
    seed: int = 0,
    runs: int = 20,
    velocity_scale: float = 0.4,
    camera_rate: float = 15.0,
    time_to_contact=(0.7, 1.3),
    speed_separation: bool = False,
    progress=None,
) -> dict:
    """Each run drops a box on the arm's path where its first link would touch it `time_to_contact` [s] later
    (seeded), and measures.

    speed_separation: False measures the replanning chain (the box is an object; speed and separation would stop
    the arm for anything this close, as it must for a person); True runs the config as it is.
    """
    cfg = _small_cameras(cfg, 320, 240)
    if not speed_separation:
        cfg = cfg.override({"controller": {"speed_separation": {"enabled": False}}})
    rng = np.random.default_rng(seed)
    table = ("table", Box(size=TABLE_SIZE), make_transform((0.3, 0.0, -TABLE_SIZE[2] / 2)))
    sim = KinematicSim(cfg, [table], camera_rate=camera_rate, seed=seed).start()
    probe = PyBulletScene(sim.robot, room=False)  # where the box would first touch the arm: ground truth, off-scene
    ctl = sim.controller
    rows = []
    try:
        for k in range(runs):
            home = _accepted(ctl, Goal.joints(f"to-start-{k}", A))
            if home.wait(60) is None or home.result.status != GoalStatus.SUCCEEDED:
                raise RuntimeError(f"run {k}: could not return to the start: {home.result}; {_stuck(ctl)}")
            size = rng.uniform(0.08, 0.16)
            delay = rng.uniform(0.2, 0.4)
            seen = {}

            lo, hi = np.zeros(3), np.zeros(3)

            def hook(now, lo=lo, hi=hi, seen=seen):
                occ = sim.world.occupancy
                if "map" not in seen and "drop" in seen and occ is not None and len(occ):
                    if np.all((occ.centers >= lo) & (occ.centers <= hi), axis=1).sum() >= 3:
                        seen["map"] = now

            sim.frame_hooks.append(hook)
            n_before = len(ctl.transitions)
            log_before = len(ctl.events_log)
            h = ctl.submit(Goal.joints(f"across-{k}", B, velocity_scale=velocity_scale))
            t_end = time.monotonic() + 5
            while ctl.state != State.MONITORING.value and time.monotonic() < t_end:
                time.sleep(0.002)
            time.sleep(delay)
            now = time.monotonic()
            start, traj = sim.driver.timeline.active(now)
            center, ahead = _drop(probe, sim.robot, traj, now - start, size, time_to_contact, rng)
            lo[:], hi[:] = center - size / 2 - 0.011, center + size / 2 + 0.011
            seen["drop"] = time.monotonic()
            sim.add_obstacle("intruder", Box(size=(size, size, size)), make_transform(center))
            res = h.wait(30)
            sim.frame_hooks.remove(hook)
            trans = ctl.transitions[n_before:]
            log = ctl.events_log[log_before:]
            t_drop = seen["drop"]
            pending = next((t.stamp for t in trans if t.dest == State.PENDING.value and t.stamp >= t_drop), None)
            spliced = next((t.stamp for t in trans if t.trigger == "spliced" and pending and t.stamp >= pending), None)
            sent = next(
                (e[2] for e in log if e[1] == "plan_sent" and e[2]["spliced"] and pending and e[0] >= pending), None
            )
            landed = sent and sent["land"]
            braked = any(e[1] == "brake" and e[0] >= t_drop for e in log)
            clearance = _min_distance(sim, t_drop, time.monotonic())
            rows.append(
                {
                    "run": k,
                    "status": res.status.value if res else "timeout",
                    "drop_to_map_ms": _ms(seen.get("map"), t_drop),
                    "map_to_pending_ms": _ms(pending, seen.get("map")),
                    "pending_to_spliced_ms": _ms(spliced, pending),
                    "pending_to_landed_ms": _ms(landed, pending),
                    "replan_plan_ms": sent and sent["plan_time"] * 1e3,  # the planner's own part of pending -> spliced
                    "replanned_without_stopping": bool(spliced)
                    and not braked
                    and res is not None
                    and res.status == GoalStatus.SUCCEEDED,
                    "braked": braked,
                    "min_clearance_m": clearance,
                    "time_to_contact_s": ahead - (t_drop - now),  # the draw took a few ms of the arm's travel
                    "path": [(round(t.stamp - t_drop, 3), t.dest, t.reason) for t in trans],
                    "plan_errors": [e[2]["error"] for e in log if e[1] == "plan_error"],
                }
            )
            sim.remove_obstacle("intruder")
            time.sleep(0.3)
            sim.perception.clear()  # a fresh map for each run: voxels the arm itself hides would linger
            if progress:
                progress(k, runs)
    finally:
        probe.close()
        sim.stop()
    out = _summary(rows, seed, runs, velocity_scale, camera_rate, time_to_contact)
    out["speed_separation"] = (
        "on (as configured)" if speed_separation else "off: the box is an object; this measures the replanning chain"
    )
    return out


def _drop(probe: PyBulletScene, robot, traj, t: float, size: float, time_to_contact, rng, tries: int = 50):
    """A box centre near where the hand will be, such that the first link to touch it on the rest of `traj` (from
    its time t) does so within `time_to_contact` [s]; and that time. Seeded draws, a fixed number of them."""
    lo, hi = time_to_contact
    ts = np.arange(t, traj.duration, 0.01)
    Q = traj.evaluate(ts, order=0)[0]
    box = probe.add("box", Box(size=(size, size, size)), np.eye(4))
    best = None
    try:
        for _ in range(tries):
            ahead = rng.uniform(lo, hi)
            q_then = traj.state_at(min(t + ahead, traj.duration))[0]
            center = robot.link_pose(q_then, "panda_hand")[:3, 3] + rng.uniform(-0.03, 0.03, 3)
            probe.move("box", make_transform(center))
            first = np.inf
            for k, q in enumerate(Q):
                probe.set_q(q)
                if pb.getClosestPoints(probe.body, box, 0.0, physicsClientId=probe.client):
                    first = ts[k] - t
                    break
            if lo <= first <= hi:
                return center, float(first)
            if best is None or abs(first - (lo + hi) / 2) < abs(best[1] - (lo + hi) / 2):
                best = (center, float(first))
    finally:
        probe.remove("box")
    raise RuntimeError(f"no drop within {tries} draws touches the path {lo}-{hi} s ahead (closest: {best[1]:.2f} s)")


def _accepted(ctl, goal: Goal, tries: int = 120):
    """The handle of `goal` once the controller accepts it: a goal it rejects as not ready (a camera silent longer than
    its timeout, as on a machine busy with other work) is asked again, `tries` times half a second apart."""
    for _ in range(tries):
        handle = ctl.submit(goal)
        try:
            handle.accepted(30.0)
            return handle
        except GoalRejected as err:
            reason = str(err)
        time.sleep(0.5)  # waiting on the cameras' process, not deciding anything
    raise RuntimeError(f"the controller rejected {goal.id!r} {tries} times, the last: {reason}")


def _stuck(ctl) -> str:
    """What the controller was doing: its last transitions, how long its step has run, where its thread is."""
    last = [(t.dest, t.reason) for t in ctl.transitions[-4:]]
    frames = sys._current_frames()
    where = [
        "".join(traceback.format_stack(frames[t.ident])[-8:])
        for t in threading.enumerate()
        if t.name == "controller" and t.ident in frames
    ]
    return f"last transitions {last}; its step has run {ctl.inbox.stuck_for():.1f} s; its thread at:\n" + (
        "\n".join(where) or "(no controller thread)"
    )


def _ms(a, b):
    return None if a is None or b is None else (a - b) * 1e3


def _min_distance(sim: KinematicSim, t0: float, t1: float) -> float:
    """Ground truth from pybullet: the smallest distance between the robot and the box over the run."""
    best = np.inf
    for t in np.arange(t0, t1, 0.01):
        q, _ = sim.driver.timeline.state(t)
        pts = sim.closest_points(q, "intruder", 0.5)
        if pts:
            best = min(best, min(p[8] for p in pts))
    return float(best)


def _summary(rows, seed, runs, velocity_scale, camera_rate, time_to_contact) -> dict:
    def col(name):
        return [r[name] for r in rows if r[name] is not None]

    return {
        "bench": "reaction",
        "seed": seed,
        "runs": runs,
        "velocity_scale": velocity_scale,
        "time_to_contact_s": list(time_to_contact),
        "camera": {"width": 320, "height": 240, "rate_hz": camera_rate},
        "between_runs": "the box is removed and the map cleared",
        "drop_to_map_ms": summary(col("drop_to_map_ms")),
        "map_to_pending_ms": summary(col("map_to_pending_ms")),
        "pending_to_spliced_ms": summary(col("pending_to_spliced_ms")),
        "pending_to_landed_ms": summary(col("pending_to_landed_ms")),
        "replan_plan_ms": summary(col("replan_plan_ms")),
        "replanned_without_stopping": sum(r["replanned_without_stopping"] for r in rows),
        "braked": sum(r["braked"] for r in rows),
        "succeeded": sum(r["status"] == "succeeded" for r in rows),
        "min_clearance_m": float(min(r["min_clearance_m"] for r in rows)),
        "bar_pending_to_spliced_ms_median": 200.0,
        "rows": rows,
    }
