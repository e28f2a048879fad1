"""The perception pipeline on clouds rendered by pybullet: clearing, self-filter, outliers, fusion, bad input."""

from __future__ import annotations

import time

import fcl
import numpy as np
import pytest

from replanner.model.geometry import Box, padded_geometry, sample_surface
from replanner.model.transforms import make_transform
from replanner.perception import CloudFrame, CloudRejected
from replanner.world.occupancy import voxel_keys
from tests.perception_helpers import Rig, config_dict


@pytest.fixture
def rig(panda):
    r = Rig(robot=panda)
    yield r
    r.close()


def test_removed_box_is_cleared_within_the_bound(rig):
    center, size = (0.7, 0.35, 0.15), (0.12, 0.12, 0.3)
    rig.sim.add("box", Box(size=size), make_transform(center))
    for _ in range(10):
        rig.frame()
    seen = rig.voxels_in(center, np.add(size, 0.02))
    assert seen > 50
    rig.sim.remove("box")
    frames = 0
    while rig.voxels_in(center, np.add(size, 0.02)) and frames < 10:
        rig.frame()
        frames += 1
    print(f"box of {seen} voxels cleared after {frames} frames (bound {rig.perception.frames_to_clear})")
    assert frames <= rig.perception.frames_to_clear <= 5


def test_a_new_obstacle_is_in_the_map_after_one_frame(rig):
    rig.frame()
    center, size = (0.6, -0.3, 0.2), (0.1, 0.1, 0.4)
    assert rig.voxels_in(center, size) == 0
    rig.sim.add("box", Box(size=size), make_transform(center))
    rig.frame()
    assert rig.voxels_in(center, np.add(size, 0.02)) > 30


def _in_map(occ, points) -> np.ndarray:
    keys = {tuple(k) for k in occ.keys} if occ is not None else set()
    return np.array([tuple(k) in keys for k in voxel_keys(points, 0.01)])


def test_self_filter_removes_the_robot_and_keeps_what_is_near_it(panda):
    rig = Rig(config_dict(outliers={"method": "none"}, occupancy={"clearing": "none"}), robot=panda)
    per, cam = rig.perception, rig.cameras["front"]
    pad = rig.cfg.perception.self_filter.padding
    res = rig.cfg.perception.resolution
    rng = np.random.default_rng(3)
    T_cam = cam.T_base_camera
    robot_total = robot_kept = near_total = near_lost = 0
    configs = attempts = 0
    while configs < 50 and attempts < 1000:
        attempts += 1
        q = panda.random_q(rng)
        T = panda.fk(q)
        surface = []
        for b in panda.bodies:
            Tb = T[panda.link_index(b.link)] @ b.T_link_body
            surface.append(sample_surface(b.shape, 150, rng) @ Tb[:3, :3].T + Tb[:3, 3])
        surface = np.vstack(surface)
        if np.sort(surface[:, 2])[len(panda.bodies) * 20] < 0.02:
            continue  # the arm (not just its base) dips into the table: pick another
        configs += 1
        # candidates around the arm, kept if FCL puts them padding + 1 voxel or farther from every link
        cand = surface[rng.integers(len(surface), size=600)] + rng.normal(0, 0.06, (600, 3))
        dist = np.full(len(cand), np.inf)
        ball = fcl.CollisionObject(fcl.Sphere(1e-6))
        links = []
        for b in panda.bodies:
            Tb = T[panda.link_index(b.link)] @ b.T_link_body
            links.append(fcl.CollisionObject(padded_geometry(b.shape, 0.0)[0], fcl.Transform(Tb[:3, :3], Tb[:3, 3])))
        for i, p in enumerate(cand):
            ball.setTranslation(p)
            dist[i] = min(fcl.distance(ball, o, fcl.DistanceRequest()) for o in links)
        in_map_box = np.all((cand >= per.grid.lo) & (cand <= per.grid.hi), axis=1)  # the map covers the workspace
        near = cand[(dist >= pad + res) & (dist < pad + res + 0.05) & (cand[:, 2] > 0.03) & in_map_box]
        cloud = np.vstack([surface, near])
        sensor_pts = ((cloud - T_cam[:3, 3]) @ T_cam[:3, :3]).astype(np.float32)
        per.clear()
        rig.stamp += 0.05
        per.add_joint_state(rig.stamp, q)
        per.integrate(CloudFrame("front", rig.stamp, sensor_pts))
        occ = rig.world.occupancy
        robot_total += len(surface)
        robot_kept += int(_in_map(occ, surface).sum())
        near_total += len(near)
        near_lost += int((~_in_map(occ, near)).sum())
    rig.close()
    assert configs == 50
    removed = 1 - robot_kept / robot_total
    print(
        f"{configs} configurations: {removed:.4%} of {robot_total} robot surface points removed; "
        f"{near_total - near_lost} of {near_total} points >= padding + 1 voxel away kept"
    )
    assert removed >= 0.99
    assert near_total > 1000 and near_lost == 0


def test_attached_part_and_static_objects_are_not_obstacles(rig):
    rig.world.add("crate", Box(size=(0.2, 0.3, 0.25)), make_transform((0.55, -0.35, 0.125)))
    rig.sim.add("crate", Box(size=(0.2, 0.3, 0.25)), make_transform((0.55, -0.35, 0.125)))
    part = Box(size=(0.05, 0.05, 0.2))
    rig.world.attach_new("part", part, "panda_grasptarget", make_transform((0, 0, 0.05)))
    pose = rig.robot.link_pose(rig.q, "panda_grasptarget") @ make_transform((0, 0, 0.05))
    rig.sim.add("part", part, pose)
    rig.frame()
    assert rig.voxels_in((0.55, -0.35, 0.125), (0.22, 0.32, 0.27)) == 0
    assert rig.voxels_in(pose[:3, 3], (0.1, 0.1, 0.25)) == 0


def test_a_frame_taken_before_a_release_still_filters_the_carried_part(rig):
    """Frames arrive late: one rendered while the part was carried is filtered as it was, not as the scene is."""
    part = Box(size=(0.05, 0.05, 0.2))
    rig.world.attach_new("part", part, "panda_grasptarget", make_transform((0, 0, 0.05)))
    carried = rig.robot.link_pose(rig.q, "panda_grasptarget") @ make_transform((0, 0, 0.05))
    rig.sim.add("part", part, carried)
    taken = time.time()
    cloud = rig.cameras["front"].cloud()
    time.sleep(0.01)
    rig.world.detach("part", rig.q)  # let go, then put down 30 cm away, after the frame was taken
    rig.world.move("part", make_transform((0.5, 0.3, 0.1)))
    rig.perception.add_joint_state(taken, rig.q)
    rig.perception.integrate(CloudFrame("front", taken, cloud, organized=True))
    assert rig.voxels_in(carried[:3, 3], (0.1, 0.1, 0.25)) == 0
    # the same picture stamped after the part was let go shows something unknown there: it is mapped
    later = time.time()
    rig.perception.add_joint_state(later, rig.q)
    rig.perception.integrate(CloudFrame("front", later, cloud, organized=True))
    assert rig.voxels_in(carried[:3, 3], (0.1, 0.1, 0.25)) > 10


@pytest.mark.parametrize("method", ["neighbours", "statistical"])
def test_salt_noise_is_removed_and_a_small_box_survives(panda, method):
    rig = Rig(config_dict(outliers={"method": method}), robot=panda)
    center, size = (0.6, -0.35, 0.05), (0.1, 0.1, 0.1)
    rig.sim.add("box", Box(size=size), make_transform(center))
    clean = rig.cameras["front"].cloud()
    rng = np.random.default_rng(1)
    noisy = clean.copy()
    n = len(noisy) // 100  # 1 % of the cloud
    idx = rng.choice(len(noisy), n, replace=False)
    cam = rig.cameras["front"].camera
    u, v = rng.uniform(0, cam.width, n), rng.uniform(0, cam.height, n)
    depth = rng.uniform(0.5, 2.5, n)
    noisy[idx] = np.column_stack([(u - cam.cx) / cam.fx * depth, (v - cam.cy) / cam.fy * depth, depth])
    rig.stamp += 1 / 30
    rig.perception.add_joint_state(rig.stamp, rig.q)
    rig.perception.integrate(CloudFrame("front", rig.stamp, noisy, organized=True))
    occ = rig.world.occupancy
    T = rig.cameras["front"].T_base_camera
    noise_world = noisy[idx] @ T[:3, :3].T + T[:3, 3]
    clean_world = clean[np.isfinite(clean[:, 2])] @ T[:3, :3].T + T[:3, 3]
    clean_keys = {tuple(k) for k in voxel_keys(clean_world, 0.01)}
    isolated = np.array(
        [
            not any(
                (k[0] + dx, k[1] + dy, k[2] + dz) in clean_keys
                for dx in (-2, -1, 0, 1, 2)
                for dy in (-2, -1, 0, 1, 2)
                for dz in (-2, -1, 0, 1, 2)
            )
            for k in voxel_keys(noise_world, 0.01)
        ]
    )
    inside = np.all((noise_world >= rig.perception.grid.lo) & (noise_world <= rig.perception.grid.hi), axis=1)
    survivors = _in_map(occ, noise_world[isolated & inside])
    box_voxels = rig.voxels_in(center, np.add(size, 0.02))
    rig.close()
    print(f"{method}: {survivors.sum()} of {len(survivors)} isolated noise voxels survive; box has {box_voxels} voxels")
    assert len(survivors) > 200
    assert survivors.mean() <= 0.01
    assert box_voxels >= 40


def test_two_cameras_fuse_and_one_does_not_clear_what_it_cannot_see(rig):
    # box A is seen by both cameras; box B by the front camera only (a board hides it from the side camera)
    a_center, a_size = (0.55, -0.45, 0.1), (0.12, 0.12, 0.2)
    b_center, b_size = (0.75, 0.05, 0.1), (0.1, 0.1, 0.2)
    rig.sim.add("a", Box(size=a_size), make_transform(a_center))
    rig.sim.add("b", Box(size=b_size), make_transform(b_center))
    rig.sim.add("board", Box(size=(0.5, 0.02, 0.5)), make_transform((0.75, 0.35, 0.25)))
    rig.frame("front")
    front_only = rig.voxels_in(a_center, np.add(a_size, 0.02))
    rig.frame("side")
    both = rig.voxels_in(a_center, np.add(a_size, 0.02))
    assert front_only > 20 and both > front_only + 20  # the side camera adds the faces it sees
    b_seen = rig.voxels_in(b_center, np.add(b_size, 0.02))
    assert b_seen > 20
    for _ in range(8):
        rig.frame("side")
    assert rig.voxels_in(b_center, np.add(b_size, 0.02)) == b_seen  # hidden from it: not cleared by it
    rig.sim.remove("b")
    for _ in range(rig.perception.frames_to_clear):
        rig.frame("front")
    assert rig.voxels_in(b_center, np.add(b_size, 0.02)) == 0  # the camera that sees the gap clears it


def test_voxels_no_sensor_sees_decay(panda):
    rig = Rig(config_dict(occupancy={"decay_after": 0.5}), robot=panda)
    center, size = (0.6, 0.3, 0.15), (0.12, 0.12, 0.3)
    rig.sim.add("box", Box(size=size), make_transform(center))
    rig.frame()
    assert rig.voxels_in(center, np.add(size, 0.02)) > 20
    away = make_transform((1.6, 0.0, 1.2)) @ make_transform((0, 0, 0), (1.0, 0.0, 0.0, 0.0))  # looking up
    rig.frame(T_base_sensor=away)
    assert rig.voxels_in(center, np.add(size, 0.02)) > 20  # not seen, not yet old
    rig.stamp += 0.6
    rig.frame(T_base_sensor=away)
    assert rig.voxels_in(center, np.add(size, 0.02)) == 0
    rig.close()


def test_self_filter_uses_the_joint_state_nearest_the_cloud(rig):
    bent = rig.robot.home.copy()
    bent[0] = 1.2
    rig.set_q(bent)
    cloud = rig.cameras["front"].cloud()
    per = rig.perception
    per.add_joint_state(1.00, rig.robot.home)  # an old state, far from the pose in the cloud
    per.add_joint_state(1.10, bent)
    per.add_joint_state(1.30, rig.robot.home)
    per.integrate(CloudFrame("front", 1.11, cloud, organized=True))
    hand = rig.robot.link_pose(bent, "panda_hand")[:3, 3]
    assert rig.voxels_in(hand, (0.25, 0.25, 0.25)) == 0
    with pytest.raises(CloudRejected, match="max_joint_state_age"):
        per.integrate(CloudFrame("front", 2.0, cloud, organized=True))


def test_clear_empties_the_map(rig):
    rig.sim.add("box", Box(size=(0.1, 0.1, 0.3)), make_transform((0.6, 0.3, 0.15)))
    rig.frame()
    assert len(rig.world.occupancy) > 0
    rig.perception.clear()
    assert len(rig.world.occupancy) == 0 and rig.world.occupancy.tree is None


def _bad_frames(rig):
    sensor = rig.cfg.perception.sensors[0]
    n = sensor.width * sensor.height
    ok = rig.cameras["front"].cloud()
    not_rigid = np.eye(4)
    not_rigid[:3, :3] *= 1.5
    return {
        "wrong shape": (CloudFrame("front", 10.0, ok[:, :2]), "(N, 3)"),
        "wrong dtype": (CloudFrame("front", 10.0, ok.astype(np.int16)), "float32"),
        "not an array": (CloudFrame("front", 10.0, ok.tolist()), "(N, 3)"),
        "all NaN": (CloudFrame("front", 10.0, np.full((100, 3), np.nan, np.float32)), "no finite point"),
        "empty": (CloudFrame("front", 10.0, np.zeros((0, 3), np.float32)), "empty"),
        "pose not rigid": (CloudFrame("front", 10.0, ok, T_base_sensor=not_rigid), "not a rigid transform"),
        "time going backwards": (CloudFrame("front", 0.001, ok), "not newer"),
        "NaN stamp": (CloudFrame("front", float("nan"), ok), "finite time"),
        "10x larger": (CloudFrame("front", 10.0, np.zeros((10 * n, 3), np.float32)), "max_points"),
        "unknown sensor": (CloudFrame("ceiling", 10.0, ok), "configured sensors: front, side"),
        "organized size": (CloudFrame("front", 10.0, ok[:-5], organized=True), "width*height"),
        "depth shape": (CloudFrame("front", 10.0, ok, depth=np.zeros((3, 3), np.float32)), "depth must be"),
        "joint state too old": (CloudFrame("front", 50.0, ok), "max_joint_state_age"),
    }


def test_bad_clouds_are_rejected_and_leave_the_map_unchanged(rig):
    rig.sim.add("box", Box(size=(0.1, 0.1, 0.3)), make_transform((0.6, 0.3, 0.15)))
    rig.frame()
    rig.perception.add_joint_state(10.0, rig.q)
    before = rig.world.occupancy
    active = rig.perception.map.active.copy()
    sensor = rig.perception.sensors["front"]
    last = sensor.last_stamp
    cases = _bad_frames(rig)
    for name, (frame, expect) in cases.items():
        with pytest.raises(CloudRejected) as err:
            rig.perception.integrate(frame)
        assert expect in str(err.value), (name, str(err.value))
        assert rig.world.occupancy is before, name
        np.testing.assert_array_equal(rig.perception.map.active, active)
        assert sensor.last_stamp == last
    assert sensor.rejected == len(cases) - 1  # the unknown sensor is not counted against "front"
    rig.stamp = 10.0
    rig.frame()  # and the pipeline still works


def test_an_organized_frame_of_no_returns_is_a_live_camera_that_clears_nothing(rig):
    """A camera looking at empty space (or covered) sends an organized frame of NaN: taken (the camera is alive),
    nothing added, nothing cleared (NaN is no return: too far, or something too near the lens)."""
    rig.sim.add("box", Box(size=(0.1, 0.1, 0.3)), make_transform((0.6, 0.3, 0.15)))
    rig.frame()
    active = rig.perception.map.active.copy()
    assert len(active)
    sensor = rig.cfg.perception.sensors[0]
    blank = np.full((sensor.width * sensor.height, 3), np.nan, np.float32)
    rig.stamp += 1.0
    rig.perception.add_joint_state(rig.stamp, rig.q)
    rep = rig.perception.integrate(CloudFrame("front", rig.stamp, blank, organized=True))
    assert rep.counts["input"] == len(blank) and rig.perception.sensors["front"].last_stamp == rig.stamp
    np.testing.assert_array_equal(rig.perception.map.active, active)
    rig.perception.add_joint_state(rig.stamp + 1.0, rig.q)
    with pytest.raises(CloudRejected, match="no finite point"):  # a list of NaN points says nothing at all
        rig.perception.integrate(CloudFrame("front", rig.stamp + 1.0, blank[:100]))


def test_no_joint_state_yet_is_rejected(panda):
    rig = Rig(robot=panda)
    cloud = rig.cameras["front"].cloud()
    with pytest.raises(CloudRejected, match="no joint state yet"):
        rig.perception.integrate(CloudFrame("front", 1.0, cloud, organized=True))
    rig.close()


def test_shadows_fill_space_behind_surfaces_but_never_the_robot(rig):
    center, size = (0.55, -0.3, 0.15), (0.12, 0.12, 0.3)
    rig.sim.add("box", Box(size=size), make_transform(center))
    rep = rig.frame()
    assert rep.counts["shadow"] > 0
    occ = rig.world.occupancy
    T = rig.cameras["front"].T_base_camera
    # voxels behind the front face, inside the box: no camera saw them, the shadow put them there
    depth_from_cam = np.linalg.norm(occ.centers - T[:3, 3], axis=1)
    inside = np.all(np.abs(occ.centers - center) <= np.array(size) / 2 - 0.015, axis=1)
    assert inside.sum() > 20 and depth_from_cam[inside].min() > 0
    robot_pts = []
    T_links = rig.robot.fk(rig.q)
    for b in rig.robot.bodies:
        Tb = T_links[rig.robot.link_index(b.link)] @ b.T_link_body
        robot_pts.append(b.shape.vertices @ Tb[:3, :3].T + Tb[:3, 3])
    assert not _in_map(occ, np.vstack(robot_pts)).any()


@pytest.mark.parametrize("edge_filter", [0.02, None])
def test_a_noisy_camera_leaves_no_voxel_near_the_arm(edge_filter):
    """The demo cell seen by both of its cameras with every fault of sim.noise (mixed pixels at depth edges, noise
    growing with range squared, dropouts, stray points), the arm above a bin and nothing else in the cell: the
    filters keep every frame's map free of voxels within 0.5 m of the arm. Without the edge filter the mixed pixels
    between a bin's wall and the table stay in the map (the test can see them)."""
    from replanner.model.robot import RobotModel
    from replanner.perception import CameraModel, Perception, pose_from_config
    from replanner.sim.camera import PyBulletDepthCamera
    from replanner.sim.cloud_publisher import depth_noise
    from replanner.sim.config import load_cell_config
    from replanner.sim.scene import PyBulletScene
    from replanner.world.scene import World, scene_from_config

    cfg = load_cell_config("demo").override({"perception": {"edge_filter": edge_filter}})
    robot = RobotModel.from_config(cfg.robot)
    world, sim = World(robot), PyBulletScene(robot)
    for name, shape, pose in scene_from_config(cfg):
        world.add(name, shape, pose)
        sim.add(name, shape, pose)
    meshes = sim.meshes()
    cams = [
        (s.name, PyBulletDepthCamera(sim.client, CameraModel.from_config(s), pose_from_config(s.pose), meshes=meshes))
        for s in cfg.perception.sensors
    ]
    per = Perception.from_config(cfg, robot, world)
    q = np.array([0.29, 0.52, 0.68, -1.83, -0.4, 2.21, 1.93])  # the hand above bin_b
    sim.set_q(q)
    arm = np.vstack([p @ T[:3, :3].T + T[:3, 3] for p, T in _arm_surface(world, robot, q)])
    rng, stamp, near = np.random.default_rng(5), 0.0, []
    for _ in range(30):
        for name, cam in cams:
            stamp += 1.0 / 60.0
            per.add_joint_state(stamp, q)
            depth = depth_noise(cam.depth(), cfg.sim.noise, rng)
            per.integrate(CloudFrame(name, stamp, cam.camera.depth_to_points(depth), organized=True))
            occ = world.snapshot().occupancy
            d = np.full(1, np.inf) if occ is None or not len(occ) else occ.kdtree.query(arm)[0]
            near.append(int((d < 0.5).sum()))
    sim.close()
    if edge_filter is None:
        assert max(near) > 0
    else:
        assert max(near) == 0, near


def _arm_surface(world, robot, q):
    from replanner.collision.exact import CollisionChecker

    bp = CollisionChecker(robot, world).body_poses(q)
    rng = np.random.default_rng(0)
    return [(sample_surface(shape, 400, rng), T) for shape, T in zip(bp.shapes, bp.poses)]
