"""Depth images of a pybullet world by a compiled z-buffer over triangle meshes: the robot's collision hulls at its
joint positions, every other body's primitive or mesh at its pose. Orders of magnitude cheaper than pybullet's
software renderer, so the simulated cameras run at the rates real ones do."""

from __future__ import annotations

import numba
import numpy as np
import pybullet as pb
import trimesh

from ..model.geometry import shape_to_trimesh
from ..model.robot import RobotModel
from ..perception.camera import CameraModel

CAPSULE_SECTIONS = 16  # the operator's forearm: 16 sides keep its silhouette within a millimetre at its 5 cm radius


def _mesh_of(geometry: int, dims, filename: bytes) -> trimesh.Trimesh | None:
    """The triangles of one pybullet visual shape in its own frame (None: a shape with nothing to draw)."""
    if geometry == pb.GEOM_BOX:
        return trimesh.creation.box(extents=dims)
    if geometry == pb.GEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=2, radius=dims[0])
    if geometry == pb.GEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=dims[1], height=dims[0], sections=32)
    if geometry == pb.GEOM_CAPSULE:
        return trimesh.creation.capsule(height=dims[0], radius=dims[1], count=(CAPSULE_SECTIONS, CAPSULE_SECTIONS))
    if geometry == pb.GEOM_MESH and filename:
        mesh = trimesh.load(filename.decode(), force="mesh")
        mesh.apply_scale(np.asarray(dims, float))
        return mesh
    return None


class PyBulletMeshes:
    """The triangles a depth camera sees in one pybullet client, posed as the client holds them now.

    Args:
        client: the pybullet client.
        robot: the robot model; its body `robot_body` is drawn as its collision hulls, at the joint positions pybullet
            holds, posed by the model's forward kinematics (the robot's base at the origin, as every sim loads it).
    """

    def __init__(self, client: int, robot: RobotModel, robot_body: int):
        self.client, self.robot, self.robot_body = client, robot, robot_body
        self._joints = [self._joint_index(name) for name in robot.joint_names]
        self._links = np.array([robot.link_index(b.link) for b in robot.bodies], np.int64)
        self._T_link_body = np.stack([b.T_link_body for b in robot.bodies])
        meshes = [shape_to_trimesh(b.shape) for b in robot.bodies]
        self._robot = self._stack(meshes)
        self._bodies: tuple[int, ...] = ()
        self._others: tuple | None = None
        tiny = CameraModel(1, 1, 1.0, 1.0, 0.0, 0.0)
        render_depth(self.posed(), tiny, np.eye(4), 0.05, 1.0)  # the z-buffer compiles (or loads) now

    def _joint_index(self, name: str) -> int:
        for j in range(pb.getNumJoints(self.robot_body, physicsClientId=self.client)):
            if pb.getJointInfo(self.robot_body, j, physicsClientId=self.client)[1].decode() == name:
                return j
        raise KeyError(f"the pybullet robot has no joint {name!r}")

    @staticmethod
    def _stack(meshes: list[trimesh.Trimesh]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices (V, 3), triangles (T, 3) into them and each vertex's mesh (V,), all meshes in one."""
        verts, tris, owner, at = [], [], [], 0
        for i, m in enumerate(meshes):
            verts.append(np.asarray(m.vertices, np.float64))
            tris.append(np.asarray(m.faces, np.int64) + at)
            owner.append(np.full(len(m.vertices), i, np.int64))
            at += len(m.vertices)
        if not meshes:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
        return np.concatenate(verts), np.concatenate(tris), np.concatenate(owner)

    def _other_bodies(self) -> tuple:
        """(body ids, their meshes stacked): every body but the robot's, read again when bodies come or go."""
        c = self.client
        bodies = tuple(pb.getBodyUniqueId(i, physicsClientId=c) for i in range(pb.getNumBodies(physicsClientId=c)))
        if bodies != self._bodies or self._others is None:
            ids, meshes, frames = [], [], []
            for b in bodies:
                if b == self.robot_body:
                    continue
                for v in pb.getVisualShapeData(b, physicsClientId=c):
                    mesh = _mesh_of(v[2], v[3], v[4])
                    if mesh is None or v[1] != -1:
                        continue  # the cell's other bodies have a base only
                    T = np.eye(4)
                    T[:3, :3] = np.asarray(pb.getMatrixFromQuaternion(v[6]), float).reshape(3, 3)
                    T[:3, 3] = v[5]
                    ids.append(b)
                    meshes.append(mesh)
                    frames.append(T)
            self._bodies = bodies
            self._others = (np.array(ids, np.int64), self._stack(meshes), np.array(frames).reshape(-1, 4, 4))
        return self._others

    def posed(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, triangles, owner, poses (M, 4, 4)): the meshes and each mesh's pose in the base frame now."""
        c = self.client
        q = np.array([s[0] for s in pb.getJointStates(self.robot_body, self._joints, physicsClientId=c)], float)
        links = self.robot.fk(q)
        robot_poses = links[self._links] @ self._T_link_body
        ids, (v, t, o), frames = self._other_bodies()
        poses = np.empty((len(ids), 4, 4))
        for k, b in enumerate(ids):
            p, quat = pb.getBasePositionAndOrientation(int(b), physicsClientId=c)
            poses[k] = np.eye(4)
            poses[k, :3, :3] = np.asarray(pb.getMatrixFromQuaternion(quat), float).reshape(3, 3)
            poses[k, :3, 3] = p
        poses = poses @ frames
        rv, rt, ro = self._robot
        nr = len(robot_poses)
        return (
            np.concatenate([rv, v]),
            np.concatenate([rt, t + len(rv)]),
            np.concatenate([ro, o + nr]),
            np.concatenate([robot_poses, poses]),
        )


def render_depth(
    meshes: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    camera: CameraModel,
    T_base_camera: np.ndarray,
    near: float,
    far: float,
) -> np.ndarray:
    """(H, W) float32 depth along the optical axis [m] of posed meshes (`PyBulletMeshes.posed`) seen by `camera`
    at T_base_camera (optical frame); NaN where nothing lies within [near, far]."""
    verts, tris, owner, poses = meshes
    T = np.linalg.inv(T_base_camera) @ poses  # each mesh's pose in the camera's frame
    out = np.full((camera.height, camera.width), np.inf)
    _zbuffer(
        np.ascontiguousarray(verts, np.float64),
        np.ascontiguousarray(tris, np.int64),
        np.ascontiguousarray(owner, np.int64),
        np.ascontiguousarray(T, np.float64),
        float(camera.fx),
        float(camera.fy),
        float(camera.cx),
        float(camera.cy),
        float(near),
        out,
    )
    out[out > far] = np.inf
    out[np.isinf(out)] = np.nan
    return out.astype(np.float32)


@numba.njit(cache=True, nogil=True)
def _zbuffer(verts, tris, owner, T, fx, fy, cx, cy, near, out):
    """out (H, W, inf where empty) = the nearest camera z of the triangles at each pixel centre (integer u, v);
    triangles are clipped at z = near."""
    n = verts.shape[0]
    P = np.empty((n, 3))
    for i in range(n):
        m = owner[i]
        x, y, z = verts[i, 0], verts[i, 1], verts[i, 2]
        for r in range(3):
            P[i, r] = T[m, r, 0] * x + T[m, r, 1] * y + T[m, r, 2] * z + T[m, r, 3]
    poly = np.empty((4, 3))
    for k in range(tris.shape[0]):
        a, b, c = tris[k, 0], tris[k, 1], tris[k, 2]
        if P[a, 2] < near and P[b, 2] < near and P[c, 2] < near:
            continue
        m = 0  # the triangle clipped to z >= near (Sutherland-Hodgman against one plane): 3 or 4 corners
        for e in range(3):
            i = tris[k, e]
            j = tris[k, (e + 1) % 3]
            zi, zj = P[i, 2], P[j, 2]
            if zi >= near:
                poly[m, 0], poly[m, 1], poly[m, 2] = P[i, 0], P[i, 1], zi
                m += 1
            if (zi >= near) != (zj >= near):
                f = (near - zi) / (zj - zi)
                poly[m, 0] = P[i, 0] + f * (P[j, 0] - P[i, 0])
                poly[m, 1] = P[i, 1] + f * (P[j, 1] - P[i, 1])
                poly[m, 2] = near
                m += 1
        for s in range(1, m - 1):
            _triangle(poly, 0, s, s + 1, fx, fy, cx, cy, out)


@numba.njit(cache=True, nogil=True, inline="always")
def _triangle(poly, i, j, k, fx, fy, cx, cy, out):
    """Rasterise one triangle of camera points poly[i], poly[j], poly[k] (z >= near > 0) into the z-buffer: 1 / z
    is linear in the image, so it is interpolated there."""
    H, W = out.shape
    u0, v0, w0 = fx * poly[i, 0] / poly[i, 2] + cx, fy * poly[i, 1] / poly[i, 2] + cy, 1.0 / poly[i, 2]
    u1, v1, w1 = fx * poly[j, 0] / poly[j, 2] + cx, fy * poly[j, 1] / poly[j, 2] + cy, 1.0 / poly[j, 2]
    u2, v2, w2 = fx * poly[k, 0] / poly[k, 2] + cx, fy * poly[k, 1] / poly[k, 2] + cy, 1.0 / poly[k, 2]
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    if area == 0.0:
        return
    lo_u = max(int(np.ceil(min(u0, u1, u2))), 0)
    hi_u = min(int(np.floor(max(u0, u1, u2))), W - 1)
    lo_v = max(int(np.ceil(min(v0, v1, v2))), 0)
    hi_v = min(int(np.floor(max(v0, v1, v2))), H - 1)
    inv = 1.0 / area
    for v in range(lo_v, hi_v + 1):
        for u in range(lo_u, hi_u + 1):
            l0 = ((u1 - u) * (v2 - v) - (u2 - u) * (v1 - v)) * inv
            l1 = ((u2 - u) * (v0 - v) - (u0 - u) * (v2 - v)) * inv
            l2 = 1.0 - l0 - l1
            if l0 < 0.0 or l1 < 0.0 or l2 < 0.0:
                continue
            z = 1.0 / (l0 * w0 + l1 * w1 + l2 * w2)
            if z < out[v, u]:
                out[v, u] = z
