"""`replanner bench perception`: 640x480 organised clouds of a seeded scene through the whole pipeline."""

from __future__ import annotations

import time

import numpy as np

from ..config import ReplannerConfig
from ..errors import ConfigError
from ..model.geometry import Box
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..perception import CameraModel, CloudFrame, Perception, pose_from_config
from ..stats import summary
from ..world.occupancy import voxel_keys
from ..world.scene import World
from .scenes import add_table, operator_boxes, tabletop_clutter


def _sim(cfg: ReplannerConfig, robot: RobotModel, world: World):
    from ..sim.camera import PyBulletDepthCamera
    from ..sim.scene import PyBulletScene

    sim = PyBulletScene(robot)
    for o in world.objects.values():
        sim.add(o.name, o.shape, o.pose)
    sensor = cfg.perception.sensors[0]
    cam = PyBulletDepthCamera(sim.client, CameraModel.from_config(sensor), pose_from_config(sensor.pose))
    return sim, cam, sensor


def run(
    cfg: ReplannerConfig, *, seed: int = 0, frames: int = 40, warmup: int = 3, reference_frames: int = 1, progress=None
) -> dict:
    """Time `frames` frames (after `warmup` untimed ones) of the first configured sensor; inputs fixed by `seed`."""
    if cfg.perception is None or not cfg.perception.sensors:
        raise ConfigError("the config has no perception section with a sensor; add one (see configs/panda.yaml)")
    rng = np.random.default_rng(seed)
    robot = RobotModel.from_config(cfg.robot)
    world = World(robot)
    add_table(world)
    for name, (shape, pose) in tabletop_clutter(rng).items():
        world.add(name, shape, pose)
    sim, cam, sensor = _sim(cfg, robot, world)
    per = Perception(cfg.perception, robot, world, broadphase_cell=cfg.collision.broadphase_cell)
    rate = sensor.rate_hz
    # the arm sways while a person walks past; clouds are rendered first, so rendering is not timed
    phase = rng.uniform(0, 2 * np.pi, robot.dof)
    n_total = warmup + frames
    clouds, qs = [], []
    for i in range(n_total):
        q = np.clip(robot.home + 0.25 * np.sin(2 * np.pi * i / n_total + phase), robot.limits.lower, robot.limits.upper)
        sim.set_q(q)
        for name, (shape, pose) in operator_boxes(i / (n_total - 1)).items():
            sim.move(name, pose) if name in sim.objects else sim.add(name, shape, pose)
        clouds.append(cam.cloud())
        qs.append(q)
        if progress:
            progress(i, n_total + 1)
    reports = []
    for i, (pts, q) in enumerate(zip(clouds, qs)):
        stamp = (i + 1) / rate
        per.add_joint_state(stamp, q)
        reports.append(per.integrate(CloudFrame(sensor.name, stamp, pts, organized=True)))
    timed = reports[warmup:]
    totals = [r.total_ms for r in timed]
    stages = list(timed[0].timings_ms)
    count_stages = list(timed[0].counts)

    # the reference: OctoMap's own ray-cast insertion of the same cloud (in the base frame, from the sensor)
    import octomap

    T = cam.T_base_camera
    ref_ms = []
    for pts in clouds[:reference_frames]:
        finite = pts[np.isfinite(pts[:, 2])].astype(np.float64)
        tree = octomap.OcTree(cfg.perception.resolution)
        t0 = time.perf_counter()
        tree.insertPointCloud(finite @ T[:3, :3].T + T[:3, 3], T[:3, 3].copy(), maxrange=sensor.max_range)
        ref_ms.append((time.perf_counter() - t0) * 1e3)

    clearing = clearing_frames(cfg, robot, sim, cam, sensor, per)
    sim.close()
    return {
        "bench": "perception",
        "robot": robot.name,
        "seed": seed,
        "sensor": {"name": sensor.name, "width": sensor.width, "height": sensor.height, "rate_hz": rate},
        "resolution_m": cfg.perception.resolution,
        "frames": len(timed),
        "warmup_frames": warmup,
        "ms_per_frame": summary(totals),
        "ms_per_stage": {s: summary([r.timings_ms[s] for r in timed]) for s in stages},
        "count_out_per_stage_median": {s: int(np.median([r.counts.get(s, 0) for r in timed])) for s in count_stages},
        "occupied_voxels_median": int(np.median([r.occupied for r in timed])),
        "bar_ms_median": 1000.0 / 30.0,
        "reference_octomap_insert_ms": summary(ref_ms),
        "clearing": clearing,
    }


def clearing_frames(cfg, robot, sim, cam, sensor, per: Perception, box_frames: int = 10) -> dict:
    """A box stands in view for `box_frames` frames and is removed: frames until none of its voxels is left."""
    res = cfg.perception.resolution
    box, pose = Box(size=(0.12, 0.12, 0.3)), make_transform((0.7, 0.35, 0.15))  # on the table, in full view
    sim.add("intruder", box, pose)
    stamp = max(s.last_stamp for s in per.sensors.values())
    q = robot.home
    sim.set_q(q)
    for name in [n for n in sim.objects if n.startswith("operator")]:
        sim.remove(name)
    lo = voxel_keys(pose[:3, 3] - np.array(box.size) / 2 - 1e-6, res)
    hi = voxel_keys(pose[:3, 3] + np.array(box.size) / 2 + 1e-6, res)

    def box_voxels() -> int:
        keys = per.world.occupancy.keys
        return int(np.all((keys >= lo) & (keys <= hi), axis=1).sum())

    def frame() -> None:
        nonlocal stamp
        stamp += 1.0 / sensor.rate_hz
        per.add_joint_state(stamp, q)
        per.integrate(CloudFrame(sensor.name, stamp, cam.cloud(), organized=True))

    for _ in range(box_frames):
        frame()
    seen = box_voxels()
    sim.remove("intruder")
    frames = 0
    while box_voxels() and frames < 30:
        frame()
        frames += 1
    return {"box_voxels_mapped": seen, "frames_to_clear_measured": frames, "frames_to_clear_bound": per.frames_to_clear}
