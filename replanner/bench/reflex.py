"""`replanner bench reflex`: the setting of Table II of the GPU potential-field paper (virtual forces from Kinect
point clouds on a KUKA LWR) on our CPU cores: a 640x480 depth frame of a person next to the arm, the voxel map
(insertion, robot removal, outliers) and the per-link forces, for 10 / 5 mm voxels and the paper's 4,701 / 2,468
robot vertices; and the experiment of Baumgartner and Klančar's convolution kernels."""

from __future__ import annotations

import os
import time

import numpy as np
import trimesh

from ..config import ReplannerConfig
from ..model.geometry import Box, Cylinder
from ..model.robot import RobotModel
from ..model.transforms import make_transform
from ..perception import CameraModel
from ..perception.camera import look_at
from ..reflex import ForceField, Reflex, VertexModel, VoxelMapBuilder
from ..reflex.kernels import AvoidanceKernels, KernelSpec, NullspaceReflex, OccupancyGrid, attractive_velocity
from ..stats import summary

BOUNDS_LO, EXTENT = (-1.0, -1.0, 0.0), (2.0, 2.0, 1.8)  # the paper's 2000 x 2000 x 1800 mm around the robot
PAPER_GPU_MS = {(0.01, 4701): 11.0, (0.005, 4701): 14.0, (0.01, 2468): 11.0, (0.005, 2468): 11.0}  # Table II
PAPER_CPU_MS = {(0.01, 4701): 1426.0, (0.005, 4701): 5692.0, (0.01, 2468): 755.0, (0.005, 2468): 3009.0}


def person_frame(robot: RobotModel, q, seed: int = 0) -> np.ndarray:
    """A 640x480 depth frame (base-frame points, NaN where no return) of the arm at q and a person beside it: a
    torso, a head and an arm reaching towards the robot, seen by a camera 1.6 m in front of them."""
    from ..sim.camera import PyBulletDepthCamera
    from ..sim.scene import PyBulletScene

    rng = np.random.default_rng(seed)
    sim = PyBulletScene(robot)
    sim.set_q(q)
    y = rng.uniform(0.45, 0.6)
    sim.add("torso", Box(size=(0.25, 0.45, 0.7)), make_transform((0.55, y + 0.15, 0.85)))
    sim.add("head", Cylinder(radius=0.1, length=0.22), make_transform((0.55, y + 0.15, 1.35)))
    sim.add("legs", Box(size=(0.2, 0.35, 0.5)), make_transform((0.55, y + 0.15, 0.25)))
    sim.add("forearm", Cylinder(radius=0.045, length=0.55), make_transform((0.5, y - 0.15, 0.95), (0.707, 0, 0, 0.707)))
    T = look_at((1.9, 0.0, 1.1), (0.3, 0.2, 0.7))
    cam = PyBulletDepthCamera(sim.client, CameraModel.from_fov(640, 480, 60.0), T)
    pts = cam.cloud().astype(np.float64)
    sim.close()
    return pts @ T[:3, :3].T + T[:3, 3]


def run(cfg: ReplannerConfig, *, seed: int = 0, n: int = 30, r_max: float = 0.3, progress=None) -> dict:
    """Time map creation and force computation `n` times per row (after one untimed warm-up)."""
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(seed)
    q = robot.home + rng.uniform(-0.3, 0.3, robot.dof) * 0.5
    cloud = person_frame(robot, q, seed)
    origins_of, removal_of = {}, {}
    area = sum(trimesh.Trimesh(b.shape.vertices, b.shape.faces, process=False).area for b in robot.bodies)
    rows = []
    field = ForceField(r_max=r_max)
    for k, (size, count) in enumerate(PAPER_GPU_MS):
        vm = VertexModel.from_robot(robot, count, seed)
        if vm.links not in origins_of:
            origins_of[vm.links] = np.array([robot.link_pose(q, link)[:3, 3] for link in vm.links])
        origins = origins_of[vm.links]
        builder = VoxelMapBuilder(size, BOUNDS_LO, EXTENT)
        # the robot's own voxels: its surface sampled at half a voxel, so none of them is missed
        if size not in removal_of:
            removal_of[size] = VertexModel.from_robot(robot, int(4 * area / size**2), seed)
        removal = removal_of[size]
        map_ms, force_ms = [], []
        for i in range(n + 1):
            t0 = time.perf_counter()
            voxels = builder.build(cloud, removal.place(robot, q))
            t1 = time.perf_counter()
            verts = vm.place(robot, q)
            forces = field.compute(verts, vm.link, origins, voxels)
            t2 = time.perf_counter()
            if i:  # the first compiles and warms up
                map_ms.append((t1 - t0) * 1e3)
                force_ms.append((t2 - t1) * 1e3)
        pairs = int(_pairs(verts, voxels, r_max))
        rows.append(
            {
                "voxel_mm": size * 1e3,
                "vertices": len(vm),
                "voxels": len(voxels),
                "pairs_within_r_max": pairs,
                "map_creation_ms": summary(map_ms),
                "force_computation_ms": summary(force_ms),
                "paper_gpu_ms": PAPER_GPU_MS[(size, count)],
                "paper_cpu_ms": PAPER_CPU_MS[(size, count)],
                "largest_link_force_N": float(np.linalg.norm(forces[:, :3], axis=1).max()),
            }
        )
        if progress:
            progress(k + 1, len(PAPER_GPU_MS))
    kernel = kernel_timing(cfg, seed=seed)
    wall = [reach_past_wall(cfg, avoid) for avoid in (True, False)]
    return {
        "bench": "reflex",
        "swerve": swerve_timing(cfg, cloud, q, seed=seed),
        "seed_001_kernels": kernel,
        "seed_001_wall": wall,
        "robot": robot.name,
        "seed": seed,
        "setting": "the GPU potential-field paper's Table II: workspace 2000 x 2000 x 1800 mm, r_max 300 mm, "
        "a 640x480 depth frame",
        "r_max_m": r_max,
        "frame_points": int(np.isfinite(cloud).all(axis=1).sum()),
        "cores": os.cpu_count(),
        "exact": "every vertex-voxel pair within r_max, float64 (tests/test_reflex.py: equal to all pairs)",
        "rows": rows,
        "bar_force_ms_median": 14.0,
    }


def swerve_timing(cfg: ReplannerConfig, cloud: np.ndarray, q, *, seed: int = 0, n: int = 50) -> dict:
    """The reflex in the loop: ms per swerve direction (`Reflex.offset_ahead`: 4 points of the path ahead, one
    compiled force call or one kernel grid) for the controller's `reflex` config, both methods, the person frame's
    voxels at the map's resolution, against the control period (1 / check_rate_hz)."""
    from ..trajectory import TrajectoryGenerator

    robot = RobotModel.from_config(cfg.robot)
    res = cfg.perception.resolution if cfg.perception is not None else 0.01
    voxels = VoxelMapBuilder(res, BOUNDS_LO, EXTENT).build(cloud)
    q = np.asarray(q, dtype=float)
    toward = q + np.r_[0.6, np.zeros(robot.dof - 1)]  # a path past the person
    traj = TrajectoryGenerator(robot).time(np.stack([q, toward]))
    out = {}
    for method in ("forces", "kernels"):
        reflex = Reflex(robot, cfg.controller.reflex.model_copy(update={"method": method}), seed)
        ms, offsets = [], []
        for i in range(n + 1):
            t = (i % 10) / 10 * traj.duration * 0.5
            t0 = time.perf_counter()
            dq = reflex.offset_ahead(traj, t, voxels, res)
            if i:
                ms.append((time.perf_counter() - t0) * 1e3)
                offsets.append(0.0 if dq is None else float(np.abs(dq).max()))
        out[method] = {"ms": summary(ms), "largest_offset_rad": max(offsets)}
    return {
        "voxels": len(voxels),
        "voxel_mm": res * 1e3,
        "vertices": cfg.controller.reflex.vertices,
        "r_max_m": cfg.controller.reflex.r_max,
        "control_period_ms": 1e3 / cfg.controller.check_rate_hz,
        **out,
    }


POINTS = (  # Baumgartner and Klančar's points of interest: a point on each moving link of the arm
    ("panda_link3", (0.0, 0.0, 0.0)),
    ("panda_link4", (0.0, 0.0, 0.0)),
    ("panda_link5", (0.0, 0.0, -0.1)),
    ("panda_link6", (0.0, 0.0, 0.0)),
    ("panda_link7", (0.0, 0.0, 0.0)),
    ("panda_hand", (0.0, 0.0, 0.05)),
)


def kernel_timing(cfg: ReplannerConfig, *, seed: int = 0, n: int = 200, spec: KernelSpec | None = None) -> dict:
    """Baumgartner and Klančar's kernels: ms per update (grid from the person frame's voxels once; per update: the
    points of interest, their avoidance velocities, the joint velocities of equation 3) at 10 mm."""
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(seed)
    q = robot.home + rng.uniform(-0.15, 0.15, robot.dof)
    spec = spec or KernelSpec()
    voxels = VoxelMapBuilder(0.01, BOUNDS_LO, EXTENT).build(person_frame(robot, q, seed))
    grid = OccupancyGrid(BOUNDS_LO, EXTENT, 0.01).fill(voxels)
    kernels = AvoidanceKernels(spec, 0.01)
    reflex = NullspaceReflex(robot, robot.tip_link, POINTS)
    goal = robot.link_pose(q, robot.tip_link)[:3, 3] + [0.1, 0.0, 0.0]
    ms = []
    for i in range(n + 1):
        t0 = time.perf_counter()
        p = reflex.poi_positions(q)
        x = robot.link_pose(q, robot.tip_link)[:3, 3]
        reflex.joint_velocity(q, attractive_velocity(x, goal, 0.2), kernels.velocities(grid, p))
        if i:
            ms.append((time.perf_counter() - t0) * 1e3)
    return {
        "points_of_interest": len(POINTS),
        "kernel": {"length": spec.length, "width": spec.width, "decay": spec.decay, "voxel_mm": 10.0},
        "samples_per_update": 3 * len(POINTS) * spec.length * spec.width**2,
        "update_ms": summary(ms),
    }


def reach_past_wall(cfg: ReplannerConfig, avoid: bool, spec: KernelSpec | None = None, steps: int = 1200) -> dict:
    """Baumgartner and Klančar's experiment on the kinematic Panda: the hand reaches past the end of a wall (y = 0.15
    m, x < 0.2 m) to (0.4, 0.45, 0.25) by the attractive field; joint 4 (a point of interest) with or without its
    avoidance velocity. Integrated at 100 Hz from the home configuration."""
    robot = RobotModel.from_config(cfg.robot)
    spec, res, wall_y, goal = spec or KernelSpec(), 0.01, 0.15, np.array([0.4, 0.45, 0.25])
    X, Y, Z = np.meshgrid(np.arange(-0.4, 0.2, res), [wall_y], np.arange(0.3, 1.0, res), indexing="ij")
    grid = OccupancyGrid(BOUNDS_LO, EXTENT, res).fill(np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1))
    kernels = AvoidanceKernels(spec, res)
    reflex = NullspaceReflex(robot, robot.tip_link, (("panda_link4", (0.0, 0.0, 0.0)),), w_mid=0.2)
    q, closest = robot.home.copy(), np.inf
    for _ in range(steps):
        x, p = robot.link_pose(q, robot.tip_link)[:3, 3], reflex.poi_positions(q)
        closest = min(closest, abs(p[0, 1] - wall_y))
        qd = reflex.joint_velocity(q, attractive_velocity(x, goal, 0.2), kernels.velocities(grid, p), avoid)
        q = np.clip(q + 0.01 * qd, robot.limits.lower, robot.limits.upper)
    x, p = robot.link_pose(q, robot.tip_link)[:3, 3], reflex.poi_positions(q)
    return {
        "avoidance": avoid,
        "goal_error_m": float(np.linalg.norm(x - goal)),
        "joint4_final_distance_m": float(abs(p[0, 1] - wall_y)),
        "joint4_closest_m": float(closest),
    }


def _pairs(verts: np.ndarray, voxels: np.ndarray, r_max: float) -> int:
    from scipy.spatial import cKDTree

    if not len(voxels):
        return 0
    return int(sum(len(x) for x in cKDTree(voxels).query_ball_point(verts, r_max)))
