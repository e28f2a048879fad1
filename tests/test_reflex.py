"""The GPU potential-field paper's virtual forces: the compiled sum equals every vertex-voxel pair in float64; the map
keeps what the camera sees of the world, not the robot nor lone outliers."""

from __future__ import annotations

import numpy as np

from replanner.reflex import ForceField, VertexModel, VoxelMapBuilder, brute_force


def test_forces_equal_the_all_pairs_reference(panda):
    rng = np.random.default_rng(0)
    vm = VertexModel.from_robot(panda, 400, seed=1)
    assert len(vm) == 400 and set(vm.links) >= {"panda_link1", "panda_hand"}
    q = panda.home + rng.uniform(-0.3, 0.3, panda.dof)
    P = vm.place(panda, q)
    origins = np.array([panda.link_pose(q, link)[:3, 3] for link in vm.links])
    for r_max, n in ((0.3, 800), (0.12, 3000)):
        voxels = P[rng.integers(len(P), size=n)] + rng.normal(0, 0.15, (n, 3))  # around the arm, some inside r_max
        got = ForceField(r_max, 2.0).compute(P, vm.link, origins, voxels)
        ref = brute_force(P, vm.link, origins, voxels, r_max, 2.0)
        assert np.abs(ref).max() > 1.0  # a case with forces in it
        np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    # pushes away: a single voxel in front of the hand pushes the hand back along the line between them
    hand = vm.links.index("panda_hand")
    centre = P[vm.link == hand].mean(axis=0)
    f = ForceField(0.3).compute(P, vm.link, origins, centre[None] + [0.15, 0.0, 0.0])[hand, :3]
    assert f[0] < 0 and abs(f[0]) > 10 * max(abs(f[1]), abs(f[2]))


def test_the_map_keeps_the_world_without_the_robot_or_outliers(panda):
    q = panda.home
    robot_pts = VertexModel.from_robot(panda, 20000, seed=0).place(panda, q)
    wall = np.stack(np.meshgrid(np.full(1, 0.7), np.linspace(-0.3, 0.3, 80), np.linspace(0.1, 0.9, 100)), -1)
    wall = wall.reshape(-1, 3)
    lone = np.array([[-0.6, 0.6, 1.2], [0.2, -0.8, 1.5]])
    cloud = np.vstack([wall, robot_pts[::3], lone, np.full((5, 3), np.nan), [[5.0, 0.0, 0.5]]])  # out of bounds too
    b = VoxelMapBuilder(0.01, (-1.0, -1.0, 0.0), (2.0, 2.0, 1.8))
    voxels = b.build(cloud, robot_pts)
    assert len(voxels) > 0.9 * 61 * 81  # the wall (x = 0.7, 0.6 x 0.8 m at 1 cm)
    assert np.all(np.abs(voxels[:, 0] - 0.705) < 0.011)  # nothing of the robot, the lone points or the far point
    kept_all = b.build(cloud)  # without the robot's removal its surface is in the map
    assert len(kept_all) > len(voxels) + 500


def test_seed_001_kernels_push_away_from_a_wall_along_its_normal_only():
    """The paper's Fig. 3: points along y in front of a wall (the plane y = 0): only the y velocity is not zero,
    and it pushes away from the wall on either side."""
    from replanner.reflex.kernels import AvoidanceKernels, KernelSpec, OccupancyGrid

    res = 0.01
    X, Z = np.meshgrid(np.arange(-0.5, 0.5, res), np.arange(0.0, 1.0, res), indexing="ij")
    wall = np.stack([X.ravel(), np.full(X.size, 0.005), Z.ravel()], axis=1)
    grid = OccupancyGrid((-1.0, -1.0, 0.0), (2.0, 2.0, 1.5), res).fill(wall)
    for decay in ("linear", "gaussian"):
        k = AvoidanceKernels(KernelSpec(30, 7, decay, 1.0), res)
        ys = np.array([-0.2, -0.1, -0.034, 0.046, 0.1, 0.2])  # off the voxel borders
        v = k.velocities(grid, np.stack([np.full(6, 0.05), ys, np.full(6, 0.5)], axis=1))
        assert np.allclose(v[:, [0, 2]], 0.0, atol=1e-9)
        assert np.all(v[1:3, 1] < 0) and np.all(v[3:5, 1] > 0)  # away on either side, within its reach
        assert v[0, 1] == 0.0 and abs(v[2, 1]) > abs(v[1, 1])  # out of range: nothing; nearer: faster


def test_seed_001_experiment_keeps_joint_4_further_from_the_wall_and_reaches_the_goal():
    from replanner.bench.reflex import reach_past_wall
    from replanner.config import load_config

    cfg = load_config("panda")
    with_, without = reach_past_wall(cfg, True), reach_past_wall(cfg, False)
    print(with_, without)
    assert with_["goal_error_m"] < 0.005 and without["goal_error_m"] < 0.005  # the task is reached either way
    assert with_["joint4_final_distance_m"] > without["joint4_final_distance_m"] + 0.05
    assert with_["joint4_closest_m"] > without["joint4_closest_m"]


def _box_voxels(centre, half=0.05, res=0.01) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, res)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + centre


def test_the_swerve_is_seed_000s_torque_through_the_admittance_in_the_nullspace(panda):
    """Reflex.pushes (all configurations in one compiled call) against the all-pairs forces, the link Jacobians
    and the admittance's closed form, one configuration at a time."""
    from replanner.reflex import Reflex
    from replanner.sections import ReflexConfig

    cfg = ReflexConfig(vertices=300, r_max=0.3, mass=2.0, damping=150.0, horizon=0.3, voxel=0.01)  # no merging
    r = Reflex(panda, cfg)
    rng = np.random.default_rng(4)
    Q = panda.home + rng.uniform(-0.4, 0.4, (3, panda.dof))
    tangents = rng.normal(size=(3, panda.dof))
    voxels = _box_voxels(panda.link_pose(Q[0], "panda_link5")[:3, 3] + [0.12, 0.05, 0.0])
    got = r.pushes(Q, tangents, voxels, 0.01)
    for q, tangent, g in zip(Q, tangents, got):
        P = r.model.place(panda, q)
        origins = np.array([panda.link_pose(q, link)[:3, 3] for link in r.model.links])
        W = brute_force(P, r.model.link, origins, voxels, cfg.r_max, cfg.f_max)
        tau = sum(panda.jacobian(q, link).T @ w for link, w in zip(r.model.links, W))
        T, M, D = cfg.horizon, cfg.mass, cfg.damping
        dq = tau / D * (T - M / D * (1 - np.exp(-D * T / M)))
        t = tangent / np.linalg.norm(tangent)
        want = dq - t * (t @ dq)  # nothing along the path: progress is the time law's
        np.testing.assert_allclose(g, want, rtol=1e-6, atol=1e-12)
        assert abs(g @ t) < 1e-9
    assert np.abs(got[0]).max() > 1e-3  # a case with a push in it


def test_a_swerve_moves_the_arm_away_from_what_is_near_it(panda):
    """The capped offset at q leaves the arm farther from a box over the elbow (both methods along the path, the
    forces with the hand held too); with the hand's position as the task the hand stays (to first order)."""
    from replanner.reflex import Reflex
    from replanner.sections import ReflexConfig

    q = np.array([0.0, 0.3, 0.0, -1.8, 0.0, 2.1, 0.785])
    box = _box_voxels(panda.link_pose(q, "panda_link4")[:3, 3] + [0.0, 0.0, 0.14])
    tangent = np.eye(panda.dof)[0]
    hand = panda.link_pose(q, "panda_hand")[:3, 3]
    for method in ("forces", "kernels"):
        for task in ("path", "position"):
            r = Reflex(panda, ReflexConfig(method=method, task=task, max_offset=0.1))
            dq = r.offset(q, tangent, box, 0.01)
            assert dq is not None and np.abs(dq).max() <= 0.1 + 1e-12, (method, task)
            before, after = (VertexModel.place(r.model, panda, x) for x in (q, q + dq))
            gap = [np.linalg.norm(v[:, None] - box[None], axis=2).min() for v in (before, after)]
            if (method, task) != ("kernels", "position"):  # the kernels' N J+ can turn a push around (docs/reflex.md)
                assert gap[1] > gap[0] + 0.005, (method, task, gap)
            if task == "position":
                assert np.linalg.norm(panda.link_pose(q + dq, "panda_hand")[:3, 3] - hand) < 0.02
    far = box + [0.0, 0.0, 1.0]  # nothing within reach: no swerve
    assert Reflex(panda, ReflexConfig()).offset(q, tangent, far, 0.01) is None
