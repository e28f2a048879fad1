"""Collision shapes: primitives and convex hulls, their FCL geometry, padding and bounding boxes."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import fcl
import numpy as np
import trimesh

from ..errors import InvalidInputError


@dataclass(frozen=True, kw_only=True)
class Box:
    """Axis-aligned box centred on its frame; `size` = full edge lengths (x, y, z) [m]."""

    size: tuple[float, float, float]

    def __post_init__(self) -> None:
        _check_positive("Box.size", self.size, 3)


@dataclass(frozen=True, kw_only=True)
class Cylinder:
    """Cylinder along the frame's z axis, centred on the frame: Cylinder(radius=[m], length=[m]) (keywords only)."""

    radius: float
    length: float

    def __post_init__(self) -> None:
        _check_positive("Cylinder radius/length", (self.radius, self.length), 2)


@dataclass(frozen=True, kw_only=True)
class Sphere:
    """Sphere centred on the frame [m]."""

    radius: float

    def __post_init__(self) -> None:
        _check_positive("Sphere.radius", (self.radius,), 1)


@dataclass(frozen=True, eq=False)
class Mesh:
    """Triangle mesh in its frame: vertices (V, 3) [m], faces (F, 3) int. Checked as a solid triangle soup."""

    vertices: np.ndarray
    faces: np.ndarray
    convex: bool = False  # True: check its convex hull (faster, conservative)
    _hash: int = field(default=0, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.all(np.isfinite(v)):
            raise InvalidInputError(f"Mesh.vertices must be a finite (V>=4, 3) array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or f.min() < 0 or f.max() >= len(v):
            raise InvalidInputError(f"Mesh.faces must be a (F, 3) int array indexing the {len(v)} vertices")
        v.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "_hash", hash((v.tobytes(), f.tobytes(), self.convex)))

    @classmethod
    def from_file(cls, path: str, scale: float | tuple[float, float, float] = 1.0, convex: bool = False) -> Mesh:
        """Load an OBJ/STL/PLY/... file with trimesh."""
        m = trimesh.load(path, force="mesh")
        return cls(np.asarray(m.vertices) * np.asarray(scale, dtype=float), np.asarray(m.faces), convex)

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Mesh) and hash(self) == hash(other)


@dataclass(frozen=True, eq=False)
class ConvexHull:
    """Convex polytope given by its vertices (V, 3) [m]; faces are computed."""

    vertices: np.ndarray
    faces: np.ndarray

    @classmethod
    def of_points(cls, points: np.ndarray) -> ConvexHull:
        hull = trimesh.convex.convex_hull(np.asarray(points, dtype=np.float64))
        v, f = np.ascontiguousarray(hull.vertices, dtype=np.float64), np.ascontiguousarray(hull.faces, dtype=np.int64)
        v.setflags(write=False)
        f.setflags(write=False)
        return cls(v, f)


Shape = Box | Cylinder | Sphere | Mesh | ConvexHull


def shape_to_dict(shape: Shape) -> dict:
    """A shape as plain JSON data ({"type": "box", "size": [...]}, ...); `shape_from_dict` reads it back."""
    if isinstance(shape, Box):
        return {"type": "box", "size": list(shape.size)}
    if isinstance(shape, Cylinder):
        return {"type": "cylinder", "radius": shape.radius, "length": shape.length}
    if isinstance(shape, Sphere):
        return {"type": "sphere", "radius": shape.radius}
    out = {"type": "mesh", "vertices": np.asarray(shape.vertices).tolist(), "faces": np.asarray(shape.faces).tolist()}
    if isinstance(shape, ConvexHull) or shape.convex:
        out["convex"] = True
    return out


def shape_from_dict(d) -> Shape:
    """The shape `shape_to_dict` wrote; InvalidInputError naming what is wrong with anything else."""
    kind = d.get("type") if isinstance(d, dict) else None
    try:
        if kind == "box":
            return Box(size=tuple(float(v) for v in d["size"]))
        if kind == "cylinder":
            return Cylinder(radius=float(d["radius"]), length=float(d["length"]))
        if kind == "sphere":
            return Sphere(radius=float(d["radius"]))
        if kind == "mesh":
            return Mesh(np.asarray(d["vertices"], float), np.asarray(d["faces"], np.int64), bool(d.get("convex")))
    except (KeyError, TypeError, ValueError) as err:
        raise InvalidInputError(f"shape {kind}: missing or malformed field ({err!r}) in {str(d)[:120]}") from None
    raise InvalidInputError(f"shape type must be box, cylinder, sphere or mesh, got {str(d)[:120]}")


def _check_positive(name: str, values, n: int) -> None:
    a = np.asarray(values, dtype=float)
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise InvalidInputError(f"{name} must be {n} finite numbers > 0 [m], got {list(values)}")


@lru_cache(maxsize=1)
def padding_directions() -> np.ndarray:
    """Vertices of a polytope that contains the unit sphere (icosphere scaled by 1/inradius)."""
    ico = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    centers = ico.triangles.mean(axis=1)
    normals = ico.face_normals
    inradius = float(np.min(np.einsum("ij,ij->i", centers, normals)))
    return np.asarray(ico.vertices) / inradius


def padded(shape: Shape, padding: float) -> Shape:
    """A shape that contains every point within `padding` [m] of `shape` (conservative at corners)."""
    if padding <= 0:
        return shape
    if isinstance(shape, Sphere):
        return Sphere(radius=shape.radius + padding)
    if isinstance(shape, Box):
        return Box(size=tuple(s + 2 * padding for s in shape.size))
    if isinstance(shape, Cylinder):
        return Cylinder(radius=shape.radius + padding, length=shape.length + 2 * padding)
    if isinstance(shape, ConvexHull) or (isinstance(shape, Mesh) and shape.convex):
        pts = (shape.vertices[:, None, :] + padding * padding_directions()[None]).reshape(-1, 3)
        return ConvexHull.of_points(pts)
    # a concave mesh is padded through its convex hull: conservative, never optimistic
    return padded(ConvexHull.of_points(shape.vertices), padding)


def to_fcl(shape: Shape) -> fcl.CollisionGeometry:
    """FCL geometry of a shape (convex shapes as fcl.Convex, concave meshes as a BVH of triangles)."""
    if isinstance(shape, Box):
        return fcl.Box(*shape.size)
    if isinstance(shape, Sphere):
        return fcl.Sphere(shape.radius)
    if isinstance(shape, Cylinder):
        return fcl.Cylinder(shape.radius, shape.length)
    if isinstance(shape, Mesh) and shape.convex:
        shape = ConvexHull.of_points(shape.vertices)
    if isinstance(shape, ConvexHull):
        faces = np.hstack([np.full((len(shape.faces), 1), 3), shape.faces]).ravel()
        return fcl.Convex(np.ascontiguousarray(shape.vertices), len(shape.faces), faces)
    if isinstance(shape, Mesh):
        bvh = fcl.BVHModel()
        bvh.beginModel(len(shape.vertices), len(shape.faces))
        bvh.addSubModel(shape.vertices, shape.faces)
        bvh.endModel()
        return bvh
    raise InvalidInputError(f"unsupported shape type {type(shape).__name__}")


@lru_cache(maxsize=4096)
def padded_geometry(shape: Shape, padding: float) -> tuple[fcl.CollisionGeometry, tuple[np.ndarray, np.ndarray]]:
    """FCL geometry and local box (center, half extents) of `shape` padded by `padding` [m], memoised."""
    p = _padded(shape, padding)
    return to_fcl(p), local_box(p)


def padded_vertices(shape: Shape, padding: float) -> np.ndarray:
    """Vertices (M, 3) of the hull FCL is given for `shape` padded by `padding` [m] (none for a primitive)."""
    p = _padded(shape, padding)
    return p.vertices if isinstance(p, ConvexHull) else np.zeros((0, 3))


@lru_cache(maxsize=4096)
def _padded(shape: Shape, padding: float) -> Shape:
    return padded(shape, padding)


def local_box(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box of the shape in its own frame as (center (3,), half extents (3,)) [m]."""
    if isinstance(shape, Box):
        return np.zeros(3), np.asarray(shape.size, dtype=float) / 2
    if isinstance(shape, Sphere):
        return np.zeros(3), np.full(3, shape.radius)
    if isinstance(shape, Cylinder):
        return np.zeros(3), np.array([shape.radius, shape.radius, shape.length / 2])
    lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


def bounding_radius(shape: Shape) -> float:
    """Radius [m] of a ball around the frame origin that contains the shape."""
    if isinstance(shape, Sphere):
        return shape.radius
    if isinstance(shape, Box):
        return float(np.linalg.norm(shape.size) / 2)
    if isinstance(shape, Cylinder):
        return float(np.hypot(shape.radius, shape.length / 2))
    return float(np.linalg.norm(shape.vertices, axis=1).max())


def sample_surface(shape: Shape, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points on the surface of the shape in its frame (used by tests and the self-filter)."""
    mesh = shape_to_trimesh(shape)
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=int(rng.integers(2**31)))
    return np.asarray(pts)


def shape_to_trimesh(shape: Shape) -> trimesh.Trimesh:
    """Triangle mesh of a shape in its frame."""
    if isinstance(shape, Box):
        return trimesh.creation.box(extents=shape.size)
    if isinstance(shape, Sphere):
        return trimesh.creation.icosphere(subdivisions=2, radius=shape.radius)
    if isinstance(shape, Cylinder):
        return trimesh.creation.cylinder(radius=shape.radius, height=shape.length, sections=32)
    return trimesh.Trimesh(shape.vertices, shape.faces, process=False)


def encloses_base(shape: Shape, pose: np.ndarray, margin: float = 0.001) -> bool:
    """Does the shape at `pose` (base frame) hold the base frame's origin more than `margin` [m] inside it (an
    object around the robot, or a typo of its size)? A mesh counts by its convex hull."""
    p = -pose[:3, :3].T @ pose[:3, 3]  # the origin in the shape's frame
    if isinstance(shape, Box):
        return bool(np.all(np.abs(p) < np.asarray(shape.size) / 2 - margin))
    if isinstance(shape, Sphere):
        return bool(np.linalg.norm(p) < shape.radius - margin)
    if isinstance(shape, Cylinder):
        return bool(np.hypot(p[0], p[1]) < shape.radius - margin and abs(p[2]) < shape.length / 2 - margin)
    hull = trimesh.Trimesh(shape.vertices, process=False).convex_hull
    return bool(hull.nearest.signed_distance(p[None])[0] > margin)


def gap_to_links(robot, q, links, shape: Shape, pose: np.ndarray) -> float:
    """Distance [m] from a shape at `pose` to the nearest collision body of `links` (and the links rigidly fixed to
    them) at configuration q; 0 when they touch."""
    frames = {robot.link_frame_index(n) for n in links}
    near = [b for b in robot.bodies if robot.link_frame_index(b.link) in frames]
    if not near:
        return math.inf
    o = fcl.CollisionObject(to_fcl(shape), fcl.Transform(pose[:3, :3], pose[:3, 3]))
    best = math.inf
    for b in near:
        T = robot.link_pose(q, b.link) @ b.T_link_body
        other = fcl.CollisionObject(to_fcl(b.shape), fcl.Transform(T[:3, :3], T[:3, 3]))
        best = min(best, max(0.0, fcl.distance(o, other, fcl.DistanceRequest(), fcl.DistanceResult())))
    return best
