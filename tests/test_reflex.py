"""Seed 000's virtual forces: the compiled sum equals every vertex-voxel pair in float64; the map keeps what the
camera sees of the world, not the robot nor lone outliers."""

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
