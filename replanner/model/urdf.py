"""URDF reading for the robot model: parse the file, find its meshes, turn collision elements into shapes."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yourdfpy

from ..errors import RobotModelError
from .geometry import Box, ConvexHull, Cylinder, Mesh, Shape, Sphere


@dataclass(frozen=True)
class CollisionBody:
    """One collision shape rigidly fixed to a link; `T_link_body` places the shape in the link frame."""

    link: str
    shape: Shape
    T_link_body: np.ndarray


def load_urdf(path: Path) -> yourdfpy.Robot:
    """The parsed robot description (links, joints) of a URDF file, without loading meshes."""
    if not path.is_file():
        raise RobotModelError(f"URDF file not found: {path}")
    try:
        urdf = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=False, load_collision_meshes=False)
    except Exception as err:  # yourdfpy raises several types for malformed XML
        raise RobotModelError(f"cannot parse URDF {path}: {err}") from err
    return urdf.robot


def resolve_mesh(filename: str, urdf_dir: Path) -> Path:
    """Find a mesh referenced by a URDF (package://, file://, relative or absolute)."""
    name = filename.removeprefix("file://")
    candidates: list[Path] = []
    if name.startswith("package://"):
        rest = name[len("package://") :]
        parts = Path(rest).parts
        candidates += [urdf_dir / rest, urdf_dir.parent / rest]
        if len(parts) > 1:  # package://<pkg>/meshes/... next to the URDF or one level up
            candidates += [urdf_dir / Path(*parts[1:]), urdf_dir.parent / Path(*parts[1:])]
    else:
        p = Path(name)
        candidates += [p] if p.is_absolute() else [urdf_dir / p]
    for c in candidates:
        if c.is_file():
            return c
    raise RobotModelError(
        f"mesh {filename!r} referenced by the URDF not found; looked in: {', '.join(str(c) for c in candidates)}"
    )


def collision_bodies(
    links_by_name: Mapping[str, yourdfpy.Link], link_names: Iterable[str], urdf_dir: Path
) -> list[CollisionBody]:
    """The collision elements of the named links as `CollisionBody`s, in link order (meshes as convex hulls)."""
    bodies = []
    for link in link_names:
        for c in links_by_name[link].collisions:
            g = c.geometry
            T = np.eye(4) if c.origin is None else np.asarray(c.origin, dtype=float)
            if g.box is not None:
                shape: Shape = Box(size=tuple(float(s) for s in g.box.size))
            elif g.cylinder is not None:
                shape = Cylinder(radius=float(g.cylinder.radius), length=float(g.cylinder.length))
            elif g.sphere is not None:
                shape = Sphere(radius=float(g.sphere.radius))
            elif g.mesh is not None:
                path = resolve_mesh(g.mesh.filename, urdf_dir)
                scale = 1.0 if g.mesh.scale is None else np.asarray(g.mesh.scale, dtype=float)
                mesh = Mesh.from_file(str(path), scale=scale)
                # the hull is baked into the link frame: pybullet checks the same hull of the same mesh
                pts = mesh.vertices @ T[:3, :3].T + T[:3, 3]
                shape, T = ConvexHull.of_points(pts), np.eye(4)
            else:
                continue
            T.setflags(write=False)
            bodies.append(CollisionBody(link, shape, T))
    return bodies
