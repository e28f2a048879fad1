"""Shapes covered by spheres, for planning: every point of a shape lies inside one of its spheres, so a check of
the spheres never calls free what the exact shape touches (it may call a near miss a collision: FCL, which
keeps the last word, decides those).

A convex body is halved across its longest extent until its pieces are small: each half is a convex polytope whose
vertices are the body's vertices on that side and the crossings of its edges with the plane, and the farthest
point of a convex polytope from any centre is one of its vertices, so the sphere through the farthest vertex
covers the piece exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.spatial
import trimesh

from ...model.geometry import Box, ConvexHull, Cylinder, Shape, Sphere

TOLERANCE = 0.04  # [m] a sphere may reach beyond its body's face planes: tighter means more spheres
MAX_DEPTH = 10  # halvings of a piece at most
MIN_INNER = 0.01  # [m] smaller inner balls rarely decide a contact
FINE = 0.02  # [m] the finer cover a near miss of the map is looked at again with (its spheres ~5 to one)


@dataclass(frozen=True)
class Spheres:
    """Spheres (centres (K, 3) [m] in the shape's frame, radii (K,) [m]) that cover a shape; none reaches more than
    `excess` [m] beyond the shape's face planes."""

    center: np.ndarray
    radius: np.ndarray
    excess: float = 0.0
    inner_center: np.ndarray | None = None  # spheres wholly inside the shape (a touch of one is a certain contact)
    inner_radius: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.radius)


_COVERS: dict[tuple[Shape, float, int], Spheres] = {}


def cover(shape: Shape, tolerance: float = TOLERANCE, max_depth: int = MAX_DEPTH) -> Spheres:
    """Spheres whose union contains `shape` (a concave mesh through its convex hull: still conservative); pieces
    are halved until their sphere reaches at most `tolerance` [m] beyond the shape's face planes (`max_depth`
    halvings at most: `Spheres.excess` says how far they reach). Computed once per shape (shapes are immutable and
    compare by value: the same part attached again, a planning job's copy of an object, find it)."""
    key = (shape, float(tolerance), int(max_depth))
    hit = _COVERS.get(key)
    if hit is not None:
        return hit
    if len(_COVERS) > 4096:  # a long-running service with many edited objects: start afresh
        _COVERS.clear()
    out = _COVERS[key] = _cover(shape, tolerance, max_depth)
    return out


@dataclass(frozen=True)
class Refined:
    """A finer cover of a shape (`center` (F, 3), `radius` (F,) in its frame) and, per sphere k of its cover, the fine
    spheres that meet it, `index[ptr[k]:ptr[k + 1]]`: a point of the shape near something lies in a sphere of the
    cover that is near it too, and in a fine sphere that meets that one, so only those need a look."""

    center: np.ndarray
    radius: np.ndarray
    ptr: np.ndarray
    index: np.ndarray


_REFINED: dict[tuple[Shape, float], Refined] = {}


def refine(shape: Shape, tolerance: float = FINE) -> Refined:
    """The finer cover of `shape` under its `cover`, computed once per shape."""
    key = (shape, float(tolerance))
    hit = _REFINED.get(key)
    if hit is not None:
        return hit
    if len(_REFINED) > 4096:
        _REFINED.clear()
    coarse, fine = cover(shape), cover(shape, tolerance)
    gap = np.linalg.norm(coarse.center[:, None] - fine.center[None], axis=2)
    meet = gap <= coarse.radius[:, None] + fine.radius[None] + 1e-9  # rounded towards meeting
    ptr = np.concatenate([[0], np.cumsum(meet.sum(axis=1))]).astype(np.int64)
    out = _REFINED[key] = Refined(fine.center, fine.radius, ptr, np.nonzero(meet)[1].astype(np.int64))
    return out


def refined(placed: list[tuple[Shape, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The finer covers of shapes placed in frames (shape, T_frame_shape), stacked: centres (F, 3) in their frames,
    radii (F,), and per sphere of the stacked covers the fine ones that meet it, index[ptr[k]:ptr[k + 1]]."""
    center, radius, ptr, index, nf, ne = [], [], [], [], 0, 0
    for shape, T in placed:
        rf = refine(shape)
        center.append(rf.center @ T[:3, :3].T + T[:3, 3])
        radius.append(rf.radius)
        ptr.append(rf.ptr[:-1] + ne)
        index.append(rf.index + nf)
        nf, ne = nf + len(rf.radius), ne + len(rf.index)
    return (
        np.ascontiguousarray(np.concatenate(center)).reshape(-1, 3),
        np.concatenate(radius),
        np.concatenate([*ptr, [ne]]).astype(np.int64),
        np.concatenate(index).astype(np.int64),
    )


def _cover(shape: Shape, tolerance: float, max_depth: int) -> Spheres:
    if isinstance(shape, Sphere):
        return Spheres(np.zeros((1, 3)), np.array([shape.radius]), 0.0, np.zeros((1, 3)), np.array([shape.radius]))
    if isinstance(shape, Cylinder):  # its exact polytope does not exist: a prism around it does
        ring = np.linspace(0.0, 2 * np.pi, 17)[:-1]
        r = shape.radius / np.cos(np.pi / 16)
        xy = np.stack([r * np.cos(ring), r * np.sin(ring)], axis=1)
        pts = np.concatenate([np.c_[xy, np.full(16, z)] for z in (-shape.length / 2, shape.length / 2)])
    elif isinstance(shape, Box):
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        pts = corners * np.asarray(shape.size) / 2
    else:
        pts = shape.vertices
    # inside the hull is inside the shape only for convex shapes (a mesh's hull covers its dents)
    exact_hull = isinstance(shape, ConvexHull | Box)
    pts = np.asarray(pts, dtype=np.float64)
    body = ConvexHull.of_points(pts)
    mesh = trimesh.Trimesh(body.vertices, body.faces, process=False)
    normals = np.asarray(mesh.face_normals)
    planes = np.c_[normals, -np.einsum("ij,ij->i", normals, body.vertices[body.faces[:, 0]])]
    centers, radii = [], []
    _halve(body.vertices, planes, tolerance, max_depth, centers, radii)
    center, radius = np.array(centers), np.array(radii)
    excess = float((center @ planes[:, :3].T + planes[:, 3] + radius[:, None]).max(axis=1).max())
    inner_c, inner_r = (None, None) if exact_hull is False else _inner(center, body.vertices, planes)
    return Spheres(center, radius, max(excess, 0.0), inner_c, inner_r)


def _inner(center: np.ndarray, vertices: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Balls inside a convex polytope (its face `planes`): at the cover's centres and the centroid, each as large as
    its distance to the nearest face; those under MIN_INNER [m] are dropped."""
    c = np.vstack([center, vertices.mean(axis=0)])
    r = -(c @ planes[:, :3].T + planes[:, 3]).max(axis=1)
    keep = r >= MIN_INNER
    return c[keep], r[keep]


def _halve(pts: np.ndarray, planes: np.ndarray, tol: float, depth: int, centers: list, radii: list) -> None:
    """Cover the convex hull of `pts`: one sphere if it stays within `tol` of the body's face `planes` (unit normal,
    offset), else both halves across its longest extent."""
    c = (pts.min(axis=0) + pts.max(axis=0)) / 2
    r = float(np.linalg.norm(pts - c, axis=1).max())
    if float((planes[:, :3] @ c + planes[:, 3]).max()) + r <= tol or r <= tol or depth == 0 or len(pts) < 4:
        centers.append(c)
        radii.append(r)
        return
    try:  # qhull itself: trimesh's hull (normals, winding) costs ~4x and only the edges are read
        hull = scipy.spatial.ConvexHull(pts)
    except (scipy.spatial.QhullError, ValueError):  # flat or degenerate: its bounding sphere is all there is
        centers.append(c)
        radii.append(r)
        return
    v, tri = pts[hull.vertices], hull.simplices
    edges = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0)
    axis = int(np.argmax(np.ptp(v, axis=0)))
    plane = c[axis]
    a, b = pts[edges[:, 0]], pts[edges[:, 1]]
    cross = (a[:, axis] - plane) * (b[:, axis] - plane) < 0
    t = (plane - a[cross, axis]) / (b[cross, axis] - a[cross, axis])
    cut = a[cross] + t[:, None] * (b[cross] - a[cross])  # where the plane cuts the hull's edges
    for side in (v[:, axis] <= plane, v[:, axis] >= plane):
        _halve(np.concatenate([v[side], cut]), planes, tol, depth - 1, centers, radii)
