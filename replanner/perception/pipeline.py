"""Point clouds in, occupancy out: the perception pipeline of one robot's workspace, for any number of sensors.

Per frame: range filter (NaN, inf, too near, too far) → transform to the base frame → crop to the workspace
→ voxel grid → robot self-filter at the joint state nearest the cloud's stamp → outliers → log-odds hits;
voxels the camera sees through (projected into its depth image) get misses; voxels not hit for a while decay.
The occupied voxels are then swapped into the world as one immutable `OccupancyMap`.

A rejected frame raises `CloudRejected` before anything changes: the map and the sensor's state stay intact.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidInputError
from ..model.kinematics import kernel_array
from ..model.robot import RobotModel
from ..model.transforms import check_transform
from ..sections import PerceptionConfig, SensorConfig
from ..world.occupancy import OccupancyMap
from ..world.scene import World
from .camera import CameraModel, pose_from_config
from .filters import SelfFilter, VoxelGrid, finite_in_range, jump_edges, statistical_outliers
from .grid import LogOddsGrid
from .jointstate import JointStateBuffer
from .kernels import in_sorted, shadow_cells, union_sorted, voxelize, warm_up

log = logging.getLogger(__name__)


class CloudRejected(InvalidInputError):
    """A point cloud was not integrated; the message says why and what to change."""


@dataclass(frozen=True, eq=False)
class CloudFrame:
    """One point cloud from one sensor.

    Args:
        sensor: configured sensor name.
        stamp: acquisition time [s] (same clock as the joint states).
        points: (N, 3) float32 (or float64) in the sensor's optical frame [m]; NaN where there was no return.
        T_base_sensor: sensor pose in the base frame; default: the configured pose.
        organized: points are the rows of the sensor's width x height image (gives the depth image for free).
        depth: (height, width) depth image [m] the cloud came from, if not organized.
    """

    sensor: str
    stamp: float
    points: np.ndarray
    T_base_sensor: np.ndarray | None = None
    organized: bool = False
    depth: np.ndarray | None = None


@dataclass
class FrameReport:
    """What one frame did: points or voxels out of each stage, time per stage [ms], map changes."""

    sensor: str
    stamp: float
    counts: dict[str, int] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    hits: int = 0
    misses: int = 0
    decayed: int = 0
    occupied: int = 0

    @property
    def total_ms(self) -> float:
        return sum(self.timings_ms.values())


class _Sensor:
    def __init__(self, cfg: SensorConfig):
        self.cfg = cfg
        self.camera = CameraModel.from_config(cfg)
        self.T_base_sensor = pose_from_config(cfg.pose)
        self.max_points = cfg.max_points or cfg.width * cfg.height
        self.last_stamp = -math.inf
        self.frames = 0
        self.rejected = 0


class Perception:
    """Integrates clouds into a log-odds map over the workspace and publishes it into `world`.

    Args:
        cfg: the perception config section.
        robot: the robot (for the self-filter).
        world: where the occupancy map is published; its attachments are self-filtered too.
        broadphase_cell: cell [m] of the published maps' broadphase grid (collision.broadphase_cell).
    """

    def __init__(self, cfg: PerceptionConfig, robot: RobotModel, world: World, *, broadphase_cell: float = 0.04):
        warm_up()
        self.cfg = cfg
        self.robot = robot
        self.world = world
        self.grid = VoxelGrid(cfg.workspace.min, cfg.workspace.max, cfg.resolution)
        self.map = LogOddsGrid(self.grid, cfg.occupancy)
        self.sensors = {s.name: _Sensor(s) for s in cfg.sensors}
        self.joint_states = JointStateBuffer(robot.dof)
        sf = cfg.self_filter
        self.self_filter = SelfFilter(robot, sf.padding, sf.static_objects_padding, self.grid) if sf.enabled else None
        # inferred voxels stay two voxels clear of known surfaces too: next to one, no camera could clear them
        static = None if sf.static_objects_padding is None else sf.static_objects_padding + 2 * cfg.resolution
        self._shadow_filter = SelfFilter(robot, sf.padding, static, self.grid) if sf.enabled else None
        # what lies inside the arm itself is no obstacle: the space is the arm's (cameras cannot see behind it)
        self._inside_arm = SelfFilter(robot, 0.5 * cfg.resolution, None) if sf.enabled else None
        self._broadphase_cell = broadphase_cell
        self._filtered_version = -1
        self._subscribers: list[Callable[[str, float], None]] = []
        self._serial = 0
        self._published = np.zeros(0, dtype=np.int64)
        self._cells_out = np.zeros(0, dtype=np.int64)  # the active voxels of the last map (sorted flat indices)

    @classmethod
    def from_config(cls, cfg, robot: RobotModel, world: World) -> Perception:
        """From a whole validated config (its perception and collision sections)."""
        return cls(cfg.perception, robot, world, broadphase_cell=cfg.collision.broadphase_cell)

    def subscribe(self, on_map: Callable[[str, float], None]) -> None:
        """on_map(sensor, stamp) after each integrated frame (from the integrating thread; it must not block)."""
        self._subscribers.append(on_map)

    @property
    def frames_to_clear(self) -> int:
        """Frames in which a camera sees through a vacated voxel before it is gone (the clearing bound)."""
        return self.map.frames_to_clear

    def add_joint_state(self, stamp: float, q) -> None:
        self.joint_states.add(stamp, q)

    def clear(self) -> None:
        """Forget every voxel and publish an empty map."""
        self.map.clear()
        self._published = np.zeros(0, dtype=np.int64)
        self.world.set_occupancy(OccupancyMap.empty(self.cfg.resolution, broadphase_cell=self._broadphase_cell))

    # ------------------------------------------------------------------ validation
    def _reject(self, sensor: _Sensor | None, message: str):
        if sensor is not None:
            sensor.rejected += 1
        raise CloudRejected(message)

    def _validate(self, frame: CloudFrame) -> tuple[_Sensor, np.ndarray, np.ndarray, np.ndarray | None]:
        if not isinstance(frame, CloudFrame):
            raise CloudRejected(f"expected a CloudFrame, got {type(frame).__name__}")
        sensor = self.sensors.get(frame.sensor)
        if sensor is None:
            self._reject(
                None,
                f"unknown sensor {frame.sensor!r}; configured sensors: {', '.join(sorted(self.sensors)) or 'none'}",
            )
        name = frame.sensor
        try:
            stamp = float(frame.stamp)
        except (TypeError, ValueError):
            stamp = math.nan
        if not math.isfinite(stamp):
            self._reject(sensor, f"{name}: stamp must be a finite time in seconds, got {frame.stamp!r}")
        if stamp <= sensor.last_stamp:
            self._reject(
                sensor,
                f"{name}: stamp {stamp:.6f} is not newer than the last frame's {sensor.last_stamp:.6f}"
                " (timestamps must increase per sensor)",
            )
        pts = frame.points
        if not isinstance(pts, np.ndarray) or pts.ndim != 2 or pts.shape[1] != 3:
            shape = getattr(pts, "shape", type(pts).__name__)
            self._reject(sensor, f"{name}: points must be an (N, 3) array of x, y, z in metres, got {shape}")
        if pts.dtype not in (np.float32, np.float64):
            self._reject(sensor, f"{name}: points must be float32 (or float64), got {pts.dtype}")
        n = len(pts)
        if n == 0:
            self._reject(sensor, f"{name}: the cloud is empty")
        if n > sensor.max_points:
            self._reject(
                sensor,
                f"{name}: the cloud has {n} points, more than max_points={sensor.max_points} for this "
                f"sensor ({sensor.cfg.width}x{sensor.cfg.height}); check the sensor's resolution in the config",
            )
        if frame.organized and n != sensor.cfg.width * sensor.cfg.height:
            self._reject(
                sensor,
                f"{name}: an organized cloud must have width*height = "
                f"{sensor.cfg.width * sensor.cfg.height} points, got {n}",
            )
        try:
            T = (
                sensor.T_base_sensor
                if frame.T_base_sensor is None
                else check_transform(frame.T_base_sensor, "T_base_sensor")
            )
        except InvalidInputError as err:
            self._reject(sensor, f"{name}: {err}")
        depth = frame.depth
        if depth is not None:
            depth = np.asarray(depth)
            if depth.shape != (sensor.cfg.height, sensor.cfg.width) or depth.dtype.kind != "f":
                self._reject(
                    sensor,
                    f"{name}: depth must be a float ({sensor.cfg.height}, {sensor.cfg.width}) image [m], "
                    f"got {depth.dtype} {depth.shape}",
                )
        return sensor, pts.astype(np.float32, copy=False), T, depth

    def _joint_state_for(self, sensor: _Sensor, stamp: float) -> np.ndarray:
        hit = self.joint_states.nearest(stamp)
        age = self.cfg.self_filter.max_joint_state_age
        if hit is None:
            self._reject(
                sensor,
                f"{sensor.cfg.name}: no joint state yet; the self-filter needs the robot's "
                "configuration (publish joint states, or disable perception.self_filter)",
            )
        if abs(hit[0] - stamp) > age:
            self._reject(
                sensor,
                f"{sensor.cfg.name}: the nearest joint state is {abs(hit[0] - stamp):.3f} s from the "
                f"cloud's stamp, more than self_filter.max_joint_state_age={age} s",
            )
        return hit[1]

    # ------------------------------------------------------------------ the pipeline
    def integrate(self, frame: CloudFrame) -> FrameReport:
        """Run one cloud through the pipeline and publish the new map. Raises CloudRejected on bad input."""
        t_prev = time.perf_counter()
        sensor, pts, T, depth = self._validate(frame)
        stamp = float(frame.stamp)
        q = self._joint_state_for(sensor, stamp) if self.self_filter is not None else None
        snapshot = self.world.snapshot()
        then = self.world.scene_at(stamp)  # a frame in flight while a part was let go still shows it carried
        cfg = self.cfg
        rep = FrameReport(sensor.cfg.name, stamp)
        rep.counts["input"] = len(pts)

        def lap(stage: str) -> None:
            nonlocal t_prev
            now = time.perf_counter()
            rep.timings_ms[stage] = (now - t_prev) * 1e3
            t_prev = now

        if frame.organized and depth is None and cfg.edge_filter is not None:
            c = sensor.cfg
            edge, clear_depth = jump_edges(pts[:, 2].reshape(c.height, c.width), cfg.edge_filter)
            if edge.any():  # no hits at depth edges; their rays clear up to the nearer side
                pts = pts.copy()
                pts[edge.ravel()] = np.nan
                depth = clear_depth
            rep.counts["edges"] = int(edge.sum())
        lap("validate")
        # an organized frame of no returns is a live camera seeing nothing (NaN never clears: too far or too near)
        seeing = frame.organized or depth is not None
        ok = None  # the per-point range mask: only a cloud that is not organized needs it (for clearing)
        if cfg.downsample:
            flat, rep.counts["range"], rep.counts["crop"] = self._voxelize(pts, T, sensor, cfg.range_filter)
            if rep.counts["range"] == 0 and not seeing and not np.isfinite(pts).any():
                self._reject(sensor, f"{sensor.cfg.name}: the cloud has no finite point (all NaN or inf)")
            if not frame.organized and depth is None:
                ok = self._in_range(pts, T, sensor, cfg.range_filter)
            work = self.grid.centers(flat)
            rep.counts["voxels"] = len(flat)
            lap("voxel_grid")
        else:
            # rows x, y, z of the base-frame cloud: contiguous rows make every test below a cheap vector op
            W = T[:3, :3].astype(np.float32) @ pts.T + T[:3, 3:4].astype(np.float32)
            ok = self._in_range(pts, T, sensor, cfg.range_filter, W)
            rep.counts["range"] = int(ok.sum())
            if rep.counts["range"] == 0 and not seeing and not np.isfinite(pts).any():
                self._reject(sensor, f"{sensor.cfg.name}: the cloud has no finite point (all NaN or inf)")
            lap("range")
            lo, hi = self.grid.lo, self.grid.hi
            for axis in range(3):
                ok &= (W[axis] >= lo[axis]) & (W[axis] <= hi[axis])
            idx = np.flatnonzero(ok)
            rep.counts["crop"] = len(idx)
            lap("transform_crop")
            flat = self.grid.flat_rows(W[:, idx]) if len(idx) else np.zeros(0, dtype=np.int64)
            work = W[:, idx].T
            rep.counts["points"] = len(flat)
            lap("voxel_grid")
        if len(flat):
            # outliers first: their statistics must be the scene's, not those of what the self-filter leaves
            voxels = flat if cfg.downsample else self.grid.unique(flat)
            keep = self._outlier_mask(voxels)
            if cfg.downsample:
                flat, work = flat[keep], work[keep]
            elif not keep.all():
                inlier = np.isin(flat, voxels[keep])
                flat, work = flat[inlier], work[inlier]
            rep.counts["outliers"] = len(flat)
            lap("outliers")
            if self.self_filter is not None:
                keep = self._known_mask(self.self_filter, work, q, snapshot, then, flat if cfg.downsample else None)
                flat, work = flat[keep], work[keep]
            if not cfg.downsample:
                flat = self.grid.unique(flat)
            rep.counts["self_filter"] = len(flat)
            lap("self_filter")
            shadow = self._shadow(flat, T[:3, 3], q, snapshot, then)
            rep.counts["shadow"] = len(shadow)
            lap("shadow")
        else:
            flat = shadow = np.zeros(0, dtype=np.int64)
        hits = flat
        hit_now = union_sorted(hits, shadow) if len(shadow) else hits
        misses = self._seen_through(sensor, T, pts, ok, frame.organized, depth, hit_now)
        self.map.update(hits, misses, stamp, shadow)
        if self.self_filter is not None and snapshot.version != self._filtered_version and len(self.map.active):
            # the scene changed (an object added, moved, attached): what is now known is no obstacle
            self._filtered_version = snapshot.version
            active = self.map.active
            known = ~self.self_filter.keep_mask(self.grid.centers(active), q, snapshot, active)
            if known.any():
                self.map.forget(self.map.active[known])
        if self._inside_arm is not None and q is not None and len(self.map.active):
            inside = ~self._inside_arm.keep_mask(self.grid.centers(self.map.active), q, then)
            if inside.any():
                self.map.forget(self.map.active[inside])
                rep.counts["inside_arm"] = int(inside.sum())
        rep.decayed = self.map.decay(stamp)
        rep.hits, rep.misses = len(hits), len(misses)
        lap("occupancy")
        self._publish(stamp)
        rep.occupied = len(self.map.active)
        lap("publish")
        sensor.last_stamp = stamp
        sensor.frames += 1
        for cb in list(self._subscribers):
            cb(sensor.cfg.name, stamp)
        return rep

    def _voxelize(self, pts: np.ndarray, T: np.ndarray, sensor, range_filter: bool) -> tuple[np.ndarray, int, int]:
        """Sorted unique workspace cells of the frame's points in range; and how many were in range, in the crop."""
        g, c = self.grid, sensor.cfg
        r2min, r2max = (c.min_range**2, c.max_range**2) if range_filter else (-1.0, np.inf)
        out = self._cells_out if len(self._cells_out) >= len(pts) else np.empty(len(pts), dtype=np.int64)
        self._cells_out = out
        n_range, n_crop, m = voxelize(
            np.ascontiguousarray(pts, dtype=np.float32),
            T[:3, :3].astype(np.float32),
            T[:3, 3].astype(np.float32),
            np.float32(r2min),
            np.float32(r2max),
            g.lo.astype(np.float32),
            g.hi.astype(np.float32),
            (g.key_lo * g.resolution).astype(np.float64),
            1.0 / g.resolution,
            int(g.strides[0]),
            int(g.strides[1]),
            g.scratch,
            out,
        )
        return np.sort(out[:m]), int(n_range), int(n_crop)

    @staticmethod
    def _in_range(pts: np.ndarray, T: np.ndarray, sensor, range_filter: bool, W: np.ndarray | None = None):
        if W is None:
            W = T[:3, :3].astype(np.float32) @ pts.T + T[:3, 3:4].astype(np.float32)
        if range_filter:
            return finite_in_range(W, T[:3, 3], sensor.cfg.min_range, sensor.cfg.max_range)
        return np.isfinite(W).all(axis=0)

    @staticmethod
    def _known_mask(sf: SelfFilter, pts: np.ndarray, q, now, then, cells: np.ndarray | None = None) -> np.ndarray:
        """Keep mask: neither the robot nor a known object, as the scene is now and as it was at the stamp.

        cells: the points' grid cells when the points are those cells' centres."""
        keep = sf.keep_mask(pts, q, now, cells)
        if then.version != now.version and keep.any():
            keep[keep] = sf.keep_mask(pts[keep], q, then, None if cells is None else cells[keep])
        return keep

    def _shadow(self, surface: np.ndarray, origin: np.ndarray, q, snapshot, then) -> np.ndarray:
        """Voxels just behind the observed surface voxels along the camera's rays (occluded, likely solid)."""
        depth = self.cfg.occupancy.shadow_depth
        if depth <= 0 or not len(surface):
            return np.zeros(0, dtype=np.int64)
        g = self.grid
        flat = shadow_cells(
            g.keys(surface),
            kernel_array(origin),
            g.resolution,
            int(round(depth / g.resolution)),
            g.lo,
            g.hi,
            g.key_lo,
            int(g.strides[0]),
            int(g.strides[1]),
            g.scratch,
        )
        if not len(flat):
            return flat
        if self._shadow_filter is not None:  # a shadow never covers the robot or known objects
            flat = flat[self._known_mask(self._shadow_filter, self.grid.centers(flat), q, snapshot, then, flat)]
        return flat

    def _outlier_mask(self, voxels: np.ndarray) -> np.ndarray:
        """Keep mask over unique voxels: enough occupied neighbours and/or PCL's statistical test."""
        method, o = self.cfg.outliers.method, self.cfg.outliers
        keep = np.ones(len(voxels), dtype=bool)
        if method in ("neighbours", "both") and len(voxels):
            keep &= self.grid.neighbour_counts(voxels) >= o.min_neighbours
        if method in ("statistical", "both") and len(voxels):
            keep &= statistical_outliers(self.grid.centers(voxels), o.k, o.std_ratio)
        return keep

    def _seen_through(self, sensor, T, pts, ok, organized, depth, hits) -> np.ndarray:
        """Occupied voxels (not hit now) that this camera sees through: its depth there is well behind them."""
        active = self.map.active
        if self.cfg.occupancy.clearing != "projection" or not len(active):
            return np.zeros(0, dtype=np.int64)
        cam = sensor.camera
        if depth is None:
            if organized:
                depth = np.where(np.isfinite(pts[:, 2]), pts[:, 2], np.nan).reshape(cam.height, cam.width)
            else:
                depth = cam.render_depth(pts[ok])
        cand = active[~in_sorted(active, hits)] if len(hits) else active
        centers = self.grid.centers(cand)
        pc = (centers - T[:3, 3]) @ T[:3, :3]  # base → optical frame
        u, v, inside = cam.project(pc)
        idx = np.flatnonzero(inside)
        measured = depth[v[idx], u[idx]]
        # half a voxel for its depth along the ray plus noise; a surface inside the voxel makes it a hit anyway
        margin = self.cfg.occupancy.clearing_margin + self.cfg.resolution / 2
        with np.errstate(invalid="ignore"):
            through = measured > pc[idx, 2] + margin  # NaN (no return) never clears
        return cand[idx[through]]

    def _publish(self, stamp: float) -> None:
        active, before = self.map.active, self._published
        new = active[~in_sorted(active, before)]
        self._serial += 1
        occ = OccupancyMap(
            self.grid.keys(active),
            self.cfg.resolution,
            broadphase_cell=self._broadphase_cell,
            stamp=stamp,
            trusted=True,
            serial=self._serial,
            added=self.grid.keys(new),
        )
        self._published = active
        self.world.set_occupancy(occ)
