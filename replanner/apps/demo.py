"""Demo metrics from what others report: the simulator's ground truth and the service's published transitions.

Nothing here trusts the pick-and-place client: a cycle is completed when the simulator saw the part set down
in the other bin; a collision is a contact the simulator measured; reactions are the service's transitions.
All stamps are wall-clock seconds of one host (the demo runs its three processes on loopback).
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field

import numpy as np

from ..stats import summary


@dataclass
class Recording:
    """Everything heard on the wire during a run."""

    truth: list[dict] = field(default_factory=list)
    transitions: list[dict] = field(default_factory=list)
    results: list[dict] = field(default_factory=list)
    status: list[dict] = field(default_factory=list)  # {"stamp", "state", "map_voxels"[, "latency"]}
    progress: list[dict] = field(default_factory=list)


class Recorder:
    """Subscribes to the service's transitions, results and status and to the simulator's truth stream."""

    def __init__(self, session, root: str):
        self.rec = Recording()
        self._lock = threading.Lock()
        self._subs = [
            session.declare_subscriber(f"{root}/sim/truth", self._add(self.rec.truth)),
            session.declare_subscriber(f"{root}/transitions", self._add(self.rec.transitions)),
            session.declare_subscriber(f"{root}/results", self._add(self.rec.results)),
            session.declare_subscriber(f"{root}/status", self._status),
            session.declare_subscriber(f"{root}/task/progress", self._add(self.rec.progress)),
        ]

    def _add(self, target: list):
        def cb(sample) -> None:
            try:
                msg = json.loads(sample.payload.to_bytes())
            except ValueError:
                return
            with self._lock:
                target.append(msg)

        return cb

    def _status(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
            item = {"stamp": msg["stamp"], "state": msg["state"], "map_voxels": msg.get("map_voxels", 0)}
            if isinstance(msg.get("rejections"), dict):
                item["rejections"] = sum(msg["rejections"].values())
            if isinstance(msg.get("latency"), dict):
                item["latency"] = msg["latency"]
            if isinstance(msg.get("swerves"), int):
                item["swerves"] = msg["swerves"]
        except (ValueError, KeyError, TypeError):
            return
        with self._lock:
            self.rec.status.append(item)

    def snapshot(self) -> Recording:
        with self._lock:
            r = self.rec
            return Recording(list(r.truth), list(r.transitions), list(r.results), list(r.status), list(r.progress))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


def _stats(values) -> dict:
    return summary(values) if len(values) else {"median": None, "p95": None, "n": 0}


def compute_metrics(rec: Recording, *, safety_distance: float, bins: tuple[str, str], t0: float, t1: float) -> dict:
    """The demo's figures; see the module docstring for where each comes from."""
    truth = sorted(rec.truth, key=lambda e: e["stamp"])
    trans = sorted(rec.transitions, key=lambda e: e["stamp"])
    kinds = lambda k: [e for e in truth if e["kind"] == k]  # noqa: E731
    placed = kinds("placed")
    completed = [
        e for e in placed if e.get("on") in bins and e.get("picked_from") in bins and e["on"] != e["picked_from"]
    ]
    attempted = len({p["cycle"] for p in rec.progress if p.get("step") == "start"})
    minutes = max(t1 - t0, 1e-9) / 60.0
    contacts = kinds("contact")
    clear = [e["clearance"] for e in kinds("clearance") if e.get("clearance") is not None]

    def count(trigger, source=None):
        return sum(1 for t in trans if t["trigger"] == trigger and (source is None or t["from"] == source))

    pending = "MONITORING_WITH_PLANNING_PENDING"
    # reaction: from the obstacle entering the commanded path (truth) to the service leaving MONITORING
    reactions, missed = [], 0
    for e in kinds("entered_path"):
        later = [t for t in trans if t["from"] == "MONITORING" and t["to"] in (pending, "HOLDING")]
        hit = next((t for t in later if e["stamp"] - 1.0 <= t["stamp"] <= e["stamp"] + 3.0), None)
        if hit is None:
            missed += 1
        else:
            reactions.append(hit["stamp"] - e["stamp"])
    replan_lat = []
    for i, t in enumerate(trans):
        if t["trigger"] == "spliced":
            start = next((p for p in reversed(trans[:i]) if p["to"] == pending), None)
            if start is not None:
                replan_lat.append(t["stamp"] - start["stamp"])
    # clearing: the operator gone (truth) -> the service's map back to what it held before the operator came
    clearing, status = [], sorted(rec.status, key=lambda s: s["stamp"])
    for enter, left in zip(kinds("operator_entering"), kinds("operator_left")):
        before = [s["map_voxels"] for s in status if s["stamp"] <= enter["stamp"]]
        if not before:
            continue
        limit = before[-1] + max(20, 0.1 * before[-1])
        back = next((s for s in status if s["stamp"] >= left["stamp"] and s["map_voxels"] <= limit), None)
        if back is not None:
            clearing.append(back["stamp"] - left["stamp"])
    return {
        "cycles_attempted": attempted,
        "cycles_completed": len(completed),
        "completion_rate": len(completed) / attempted if attempted else None,
        "duration_s": round(t1 - t0, 2),
        "cycles_per_minute": round(len(completed) / minutes, 3),
        "collisions": len(contacts),
        "collisions_by_object": {
            o: sum(1 for c in contacts if c["object"] == o) for o in sorted({c["object"] for c in contacts})
        },
        # a contact's first sample is barely a touch: its deepest comes with its end
        "deepest_penetration_m": min(
            [c["depth"] for c in contacts] + [e["deepest"] for e in kinds("contact_end")], default=None
        ),
        "min_clearance_m": round(min(clear), 4) if clear else None,
        "safety_distance_m": safety_distance,
        "intrusions": len(kinds("operator_entering")),
        "intrusions_on_path": len(kinds("entered_path")),
        "replans": {
            "started": count("blocked"),
            "spliced": count("spliced"),
            "cancelled": count("path_clear"),
            "failed": count("brake_and_hold", pending) + count("brake_and_abort", pending),
        },
        "brakes": count("brake_and_hold") + count("brake_and_abort"),
        # the service counts its swerves from its start: the run's are the last count less the first
        "swerves": (swerves[-1] - swerves[0]) if (swerves := [s["swerves"] for s in status if "swerves" in s]) else 0,
        "goals_failed": sum(1 for r in rec.results if r.get("status") != "succeeded"),
        "reaction_s": _stats(reactions),
        "reaction_p99_s": round(float(np.percentile(reactions, 99)), 3) if reactions else None,
        "reactions_missed": missed,
        "cycles_failed": sum(1 for p in rec.progress if p.get("step") == "failed"),
        "service_reaction_time_s": _stats([s["latency"]["reaction_time_s"] for s in status if s.get("latency")]),
        "service_latency_p99_s": {
            stage: _stats(
                [
                    s["latency"][stage]["p99"]
                    for s in status
                    if (s.get("latency") or {}).get(stage, {}).get("p99") is not None
                ]
            )
            for stage in (
                "sensor_to_map",
                "map_to_check",
                "check_to_command",
                "reaction",
                "joint_state_age",
                "replan_plan",
            )
        },
        # a replan's plan itself (the service's own time): the medians of its windows over the run
        "service_replan_plan_median_s": _stats(
            [m for s in status if (m := ((s.get("latency") or {}).get("replan_plan") or {}).get("median")) is not None]
        ),
        "real_time_factor": _stats([e["rtf"] for e in kinds("clearance") if e.get("rtf") is not None]),
        # the sim's own lag on a busy machine: physics skipped, motions that reached it after their start
        "sim_dropped_s": max((e.get("dropped", 0.0) for e in kinds("clearance")), default=0.0),
        "sim_late_starts": max((e.get("late", 0) for e in kinds("clearance")), default=0),
        "replan_s": _stats(replan_lat),
        "clearing_s": _stats(clearing),
    }


def plot_timeline(rec: Recording, path: str, *, t0: float, safety_distance: float, title: str = "") -> None:
    """State, clearance to the operator and obstacle events over time, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    states = ["WAITING", "PLANNING", "MONITORING", "MONITORING_WITH_PLANNING_PENDING", "HOLDING"]
    short = ["waiting", "planning", "monitoring", "replanning", "holding"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True, gridspec_kw={"height_ratios": [1, 1.3]})
    trans = sorted(rec.transitions, key=lambda e: e["stamp"])
    if trans:
        xs = [t["stamp"] - t0 for t in trans]
        ys = [states.index(t["to"]) if t["to"] in states else 0 for t in trans]
        ax1.step(xs, ys, where="post", color="tab:blue", lw=1.2)
    ax1.set_yticks(range(len(states)), short)
    ax1.set_ylabel("service state")
    truth = sorted(rec.truth, key=lambda e: e["stamp"])
    cl = [
        (e["stamp"] - t0, e["clearance"]) for e in truth if e["kind"] == "clearance" and e.get("clearance") is not None
    ]
    if cl:
        x, y = zip(*cl)
        ax2.plot(x, np.minimum(y, 0.5), ".", ms=2, color="tab:green", label="clearance to the operator (truth)")
    ax2.axhline(safety_distance, color="tab:orange", ls="--", lw=1, label=f"safety distance {safety_distance} m")
    enter = [e for e in truth if e["kind"] == "operator_entering"]
    left = [e for e in truth if e["kind"] == "operator_left"]
    for i, e in enumerate(enter):
        end = next((l["stamp"] for l in left if l["stamp"] >= e["stamp"]), truth[-1]["stamp"])
        for ax in (ax1, ax2):
            ax.axvspan(
                e["stamp"] - t0,
                end - t0,
                color="grey",
                alpha=0.15,
                lw=0,
                label="operator in the cell" if i == 0 and ax is ax2 else None,
            )
    for i, e in enumerate(x for x in truth if x["kind"] == "entered_path"):
        ax2.axvline(
            e["stamp"] - t0, color="tab:purple", lw=0.8, label="on the planned path (truth)" if i == 0 else None
        )
    for i, e in enumerate(x for x in truth if x["kind"] == "contact"):
        ax2.plot(e["stamp"] - t0, 0, "x", color="red", ms=8, label="collision" if i == 0 else None)
    ax2.set_ylim(-0.02, 0.5)
    ax2.set_ylabel("clearance [m]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="upper right", fontsize=7, ncol=2)
    if title:
        ax1.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
