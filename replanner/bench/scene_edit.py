"""`replanner bench scene-edit`: a box added to the scene (a known object, as scene/add does) onto the path of a
moving arm; pybullet, the oracle, says whether the arm ever went into it. Simulated time: the same on any machine."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from ..config import ReplannerConfig
from ..control import Goal, GoalStatus
from ..model.geometry import Box
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..sim.scene import PyBulletScene
from ..sim.stepped import SteppedSim
from .scenes import table

A = np.array([-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
B = np.array([1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
CONTACT = 0.001  # pybullet reports distances up to its 1 mm collision margin short: deeper is a contact


def small_camera(cfg: ReplannerConfig) -> ReplannerConfig:
    front = cfg.perception.sensors[0].model_dump(mode="python")
    front.update(width=240, height=180, max_points=None)
    return cfg.override({"perception": {"sensors": [front]}})


class Oracle:
    """pybullet's verdict on the arm and one box (its own world, apart from the simulation's)."""

    def __init__(self, robot: RobotModel):
        self.scene = PyBulletScene(robot, room=False)
        self.box = None

    def place(self, box) -> None:
        if self.box is not None:
            self.scene.remove("box")
        self.scene.add(*box)
        self.box = box

    def depths(self, qs: np.ndarray) -> np.ndarray:
        """Penetration [m] (negative) of the arm into the box at each configuration; 0 where they do not touch."""
        body = self.scene.objects["box"]
        out = np.zeros(len(qs))
        for i, q in enumerate(qs):
            self.scene.set_q(q)
            for p in pb.getClosestPoints(self.scene.body, body, 0.0, physicsClientId=self.scene.client):
                out[i] = min(out[i], p[8] + CONTACT)
        return out

    def close(self) -> None:
        self.scene.close()


def box_ahead(
    sim: SteppedSim,
    robot: RobotModel,
    oracle: Oracle,
    rng: np.random.Generator,
    min_lead: float,
    max_lead: float = np.inf,
):
    """A seeded box where the hand will be a seeded time later, such that the motion as it stands would first touch
    it between `min_lead` and `max_lead` [s] from now (a box dropped onto the arm itself cannot be avoided)."""
    start, traj = sim.timeline.active(sim.t)
    ts = np.arange(sim.t, start + traj.duration, 0.01)
    qs = np.array([traj.state_at(t - start)[0] for t in ts])
    for _ in range(200):
        ahead = float(rng.uniform(max(0.05, min_lead), min(1.2, max_lead + 0.3)))  # [s] of travel to the hand's spot
        size = float(rng.uniform(0.08, 0.16))
        q_then = traj.state_at(min(sim.t - start + ahead, traj.duration))[0]
        box = ("box", Box(size=(size, size, size)), make_transform(robot.link_pose(q_then, "panda_hand")[:3, 3]))
        oracle.place(box)
        hits = np.flatnonzero(oracle.depths(qs[: int((ahead + 0.1) / 0.01)]) < 0)
        if len(hits) and min_lead <= ts[hits[0]] - sim.t <= max_lead:
            return box, float(ts[hits[0]] - sim.t)
    raise RuntimeError("no box fits ahead of the arm")


def run(
    cfg: ReplannerConfig,
    *,
    seed: int = 0,
    runs: int = 20,
    velocity_scale: float = 0.35,
    min_lead: float = 0.3,
    progress=None,
) -> dict:
    """Each run: the arm swings A -> B; at a seeded moment a seeded box is added where its hand will be a seeded time
    later, at least `min_lead` [s] before the motion as it stands would touch it. The run ends when the goal does:
    replanned around the box, or failed with a reason."""
    cfg = small_camera(cfg)
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(seed)
    rows = []
    oracle = Oracle(robot)
    for k in range(runs):
        sim = SteppedSim(cfg, [table()], robot=robot, seed=seed + k)
        try:
            start = sim.controller.submit(Goal.joints("start", A))
            sim.run_until(lambda start=start: start.result is not None, 30, "the start")
            h = sim.controller.submit(Goal.joints("across", B, velocity_scale=velocity_scale))
            sim.run_for(float(rng.uniform(0.2, 1.0)))
            box, ahead = box_ahead(sim, robot, oracle, rng, min_lead)
            t_edit = sim.t
            sim.world.add(*box)  # what the service's scene/add does
            sim.add_obstacle(*box)  # and it is there for the cameras too (perception knows it: it is no obstacle voxel)
            sim.run_until(lambda h=h: h.result is not None, 60, "the result")
            ts = np.arange(t_edit, sim.t, 0.005)
            qs = np.array([sim.timeline.state(t)[0] for t in ts])
            rows.append(
                {
                    "run": k,
                    "status": h.result.status.value,
                    "reason": h.result.reason,
                    "deepest_m": float(oracle.depths(qs).min()),
                    "box_size_m": round(box[1].size[0], 3),
                    "time_to_contact_s": round(ahead, 3),
                    "path": [t.dest for t in sim.controller.transitions if t.stamp >= t_edit],
                }
            )
        finally:
            sim.close()
        if progress:
            progress(k + 1, runs)
    oracle.close()
    through = [r for r in rows if r["deepest_m"] < 0]
    return {
        "bench": "scene-edit",
        "robot": robot.name,
        "seed": seed,
        "runs": runs,
        "passed_through": len(through),
        "replanned": sum(r["status"] == GoalStatus.SUCCEEDED.value for r in rows),
        "failed_with_reason": sum(r["status"] == GoalStatus.FAILED.value and bool(r["reason"]) for r in rows),
        "rows": rows,
        "min_lead_s": min_lead,
        "oracle": "pybullet closest points every 5 ms of the executed motion after the edit (1 mm margin)",
    }
