"""Configuration schema (pydantic) and the YAML loader that turns validation errors into actionable messages.

Every section forbids unknown fields, so a typo is an error that names the field, the file and what is allowed.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from .errors import ConfigError

PYBULLET_DATA_PREFIX = "pybullet_data://"


def resolve_resource(path: str, base_dir: str | os.PathLike | None = None) -> Path:
    """Resolve `pybullet_data://...`, absolute, or relative-to-`base_dir` paths to an absolute Path."""
    if path.startswith(PYBULLET_DATA_PREFIX):
        import pybullet_data

        return Path(pybullet_data.getDataPath()) / path[len(PYBULLET_DATA_PREFIX) :]
    p = Path(os.path.expanduser(path))
    if not p.is_absolute() and base_dir is not None:
        p = Path(base_dir) / p
    return p.resolve()


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveList = list[float]


class SelfCollisionConfig(_Section):
    allowed_pairs: list[tuple[str, str]] = Field(
        default_factory=list,
        description="Link pairs never checked against each other (parent/child pairs are always skipped).",
    )
    padding: float = Field(0.0, ge=0.0, le=0.05, description="Minimum distance two links must keep [m].")


class RobotConfig(_Section):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")
    urdf: str = Field(description="URDF path: absolute, relative to the config file, or pybullet_data://<path>.")
    base_link: str | None = Field(None, description="Root of the kinematic tree; default: the URDF's root link.")
    tip_link: str = Field(description="Link whose pose Cartesian goals refer to (e.g. the flange or TCP).")
    joints: list[str] | None = Field(None, description="Active joints in order; default: movable joints base→tip.")
    passive_joints: dict[str, float] = Field(
        default_factory=dict, description="Positions [rad or m] of movable joints that are not planned (gripper)."
    )
    velocity_limits: PositiveList = Field(description="Per active joint [rad/s or m/s].")
    acceleration_limits: PositiveList = Field(description="Per active joint [rad/s^2 or m/s^2].")
    jerk_limits: PositiveList = Field(description="Per active joint [rad/s^3 or m/s^3].")
    home: list[float] | None = Field(None, description="A collision-free rest configuration [rad].")
    self_collision: SelfCollisionConfig = Field(default_factory=SelfCollisionConfig)

    @field_validator("urdf")
    @classmethod
    def _urdf_exists(cls, value: str, info: ValidationInfo) -> str:
        base_dir = (info.context or {}).get("base_dir")
        path = resolve_resource(value, base_dir)
        if not path.is_file():
            raise ValueError(
                f"URDF file not found: {path} (give an absolute path, a path relative to the config file, "
                f"or {PYBULLET_DATA_PREFIX}<path inside pybullet_data>)"
            )
        return str(path)

    @field_validator("velocity_limits", "acceleration_limits", "jerk_limits")
    @classmethod
    def _positive(cls, values: list[float]) -> list[float]:
        for i, v in enumerate(values):
            if not (v > 0.0 and v < float("inf")):
                raise ValueError(f"entry {i} is {v}; every limit must be a finite number > 0")
        return values

    @model_validator(mode="after")
    def _lengths_agree(self) -> RobotConfig:
        n = {len(self.velocity_limits), len(self.acceleration_limits), len(self.jerk_limits)}
        if self.joints is not None:
            n.add(len(self.joints))
        if self.home is not None:
            n.add(len(self.home))
        if len(n) != 1:
            raise ValueError(
                "joints, velocity_limits, acceleration_limits, jerk_limits and home must have one entry per active "
                f"joint; got lengths joints={len(self.joints) if self.joints else '-'}, "
                f"velocity={len(self.velocity_limits)}, acceleration={len(self.acceleration_limits)}, "
                f"jerk={len(self.jerk_limits)}, home={len(self.home) if self.home else '-'}"
            )
        return self


class CollisionConfig(_Section):
    padding: float = Field(0.01, ge=0.0, le=0.2, description="Safety padding around the robot vs. the world [m].")
    map_padding: float | None = Field(
        None,
        ge=0.0,
        le=0.3,
        description="Padding against the occupancy map, where people show up [m]; default: padding. "
        "Planned paths keep this distance from what the cameras see.",
    )
    path_resolution: float = Field(
        0.02,
        gt=0.0,
        le=0.2,
        description="Max displacement of any robot point between two path checks [m]; "
        "at most 2 x padding keeps the unpadded robot collision-free between checks.",
    )
    allowed_contacts: list[tuple[str, str]] = Field(
        default_factory=list, description="[link, object] pairs allowed to touch, e.g. the base on its table."
    )
    broadphase_cell: float = Field(
        0.04, gt=0.0, le=0.5, description="Cell size of the octree broadphase grid [m] (speed only, not accuracy)."
    )
    geometry: Literal["convex_hull"] = Field(
        "convex_hull", description="Link geometry: convex hulls of the URDF collision meshes (as pybullet uses)."
    )


Vec3 = tuple[float, float, float]


class PoseConfig(_Section):
    """A pose in the robot base frame: position [m] and quaternion (x, y, z, w), or eye/target to look at."""

    position: Vec3 | None = None
    quat_xyzw: tuple[float, float, float, float] | None = None
    look_at: Vec3 | None = Field(None, description="Point the camera's optical axis (z) goes through [m].")

    @model_validator(mode="after")
    def _complete(self) -> PoseConfig:
        if self.position is None:
            raise ValueError("position is required")
        if (self.quat_xyzw is None) == (self.look_at is None):
            raise ValueError("give exactly one of quat_xyzw (orientation) or look_at (a point to look at)")
        if self.quat_xyzw is not None and sum(q * q for q in self.quat_xyzw) < 1e-12:
            raise ValueError("quat_xyzw must not be zero")
        if self.look_at is not None and sum((a - b) ** 2 for a, b in zip(self.look_at, self.position)) < 1e-12:
            raise ValueError("look_at must differ from position")
        return self


class SensorConfig(_Section):
    """A depth camera: pinhole intrinsics (optical frame: x right, y down, z forward), pose, rate."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")
    pose: PoseConfig
    width: int = Field(gt=0, le=4096)
    height: int = Field(gt=0, le=4096)
    fov_y_deg: float | None = Field(None, gt=1.0, lt=179.0, description="Vertical field of view; or fx, fy.")
    fx: float | None = Field(None, gt=0.0)
    fy: float | None = Field(None, gt=0.0)
    cx: float | None = None
    cy: float | None = None
    rate_hz: float = Field(30.0, gt=0.0, le=1000.0)
    min_range: float = Field(0.1, ge=0.0, description="Closer returns are dropped [m].")
    max_range: float = Field(4.0, gt=0.0, description="Farther returns are dropped [m].")
    max_points: int | None = Field(None, gt=0, description="Larger clouds are rejected; default width * height.")

    @model_validator(mode="after")
    def _intrinsics(self) -> SensorConfig:
        if (self.fov_y_deg is None) == (self.fx is None and self.fy is None):
            raise ValueError("give either fov_y_deg or fx and fy")
        if self.max_range <= self.min_range:
            raise ValueError(f"max_range ({self.max_range}) must exceed min_range ({self.min_range})")
        return self


class WorkspaceConfig(_Section):
    min: Vec3 = (-0.8, -1.0, -0.05)
    max: Vec3 = (1.2, 1.0, 1.5)

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceConfig:
        if any(a >= b for a, b in zip(self.min, self.max)):
            raise ValueError(f"workspace min {list(self.min)} must be below max {list(self.max)} on every axis")
        return self


class SelfFilterConfig(_Section):
    enabled: bool = True
    padding: float = Field(0.03, ge=0.0, le=0.3, description="Points this close to the robot are its own [m].")
    static_objects_padding: float | None = Field(
        0.01, ge=0.0, le=0.3, description="Points this close to a known static object are dropped [m]; null keeps them."
    )
    max_joint_state_age: float = Field(
        0.2, gt=0.0, description="Joint state used must be within this time of the cloud's stamp [s]."
    )


class OutlierConfig(_Section):
    method: Literal["neighbours", "statistical", "both", "none"] = "neighbours"
    min_neighbours: int = Field(2, ge=1, le=26, description="Occupied voxels among the 26 around a kept voxel.")
    k: int = Field(8, ge=1, le=64, description="Statistical: neighbours per point.")
    std_ratio: float = Field(1.0, gt=0.0, description="Statistical: keep mean distance <= mean + ratio * std.")


class OccupancyUpdateConfig(_Section):
    hit: float = Field(0.85, gt=0.0, description="Log-odds added per frame a voxel is hit.")
    miss: float = Field(-0.85, lt=0.0, description="Log-odds added per frame a camera sees through the voxel.")
    clamp_max: float = Field(2.2, gt=0.0, description="Upper clamp; bounds how long clearing takes.")
    clearing: Literal["projection", "none"] = "projection"
    clearing_margin: float = Field(
        0.005,
        ge=0.0,
        description="Depth noise allowance [m]: a voxel is seen through when the measured depth is "
        "beyond its centre by this plus half a voxel.",
    )
    decay_after: float | None = Field(10.0, gt=0.0, description="Voxels not hit for this long are dropped [s].")
    shadow_depth: float = Field(
        0.08,
        ge=0.0,
        le=0.5,
        description="Occupy this much space behind every observed surface, along the "
        "camera's rays [m]: a camera sees no back faces, and what hides behind a surface is likely solid (0: off).",
    )


class PerceptionConfig(_Section):
    """The workspace box is also the crop: the map covers exactly it."""

    resolution: float = Field(0.01, ge=0.002, le=0.2, description="Voxel edge [m].")
    workspace: WorkspaceConfig = Field(default_factory=WorkspaceConfig)
    sensors: list[SensorConfig] = Field(default_factory=list)
    range_filter: bool = True
    downsample: bool = Field(True, description="Filter voxels instead of points (much faster).")
    self_filter: SelfFilterConfig = Field(default_factory=SelfFilterConfig)
    outliers: OutlierConfig = Field(default_factory=OutlierConfig)
    occupancy: OccupancyUpdateConfig = Field(default_factory=OccupancyUpdateConfig)
    max_cells: int = Field(60_000_000, gt=0, description="Cap on workspace cells (memory: 8 bytes per cell).")

    @model_validator(mode="after")
    def _size(self) -> PerceptionConfig:
        cells = 1
        for a, b in zip(self.workspace.min, self.workspace.max):
            cells *= int(round((b - a) / self.resolution)) + 2
        if cells > self.max_cells:
            raise ValueError(
                f"the workspace has {cells:,} cells at {self.resolution} m, more than max_cells={self.max_cells:,}; "
                "shrink the workspace or coarsen the resolution"
            )
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"sensor names must be unique, got {names}")
        return self


class PlanningConfig(_Section):
    planner: str = Field("RRTConnect", description="Default OMPL planner (see replanner.planning.PLANNERS).")
    deadline: float = Field(1.0, gt=0.0, le=60.0, description="Default planning deadline [s], retries included.")
    attempt_time: float = Field(0.25, gt=0.0, description="Time per attempt before retrying with a fresh seed [s].")
    simplify_time: float = Field(0.015, ge=0.0, description="Shortcutting budget inside the deadline [s].")
    range: float | None = Field(1.5, gt=0.0, description="Planner step [rad]; null: OMPL's default.")
    search_coarseness: float = Field(
        4.0,
        ge=1.0,
        le=10.0,
        description="Motions are checked this much coarser while searching; the path found is "
        "checked at collision.path_resolution (and searched again finely if that fails).",
    )
    tube_radius: float = Field(0.1, gt=0.0, le=1.0, description="Timed curve's max distance from the path [rad].")
    ik_restarts: int = Field(16, ge=1, le=256)
    position_tolerance: float = Field(0.002, gt=0.0, description="Cartesian goal position tolerance [m].")
    orientation_tolerance: float = Field(0.02, gt=0.0, description="Cartesian goal orientation tolerance [rad].")


class ControllerConfig(_Section):
    reaction: Literal["replan", "stop_and_wait", "none"] = Field(
        "replan",
        description="Path blocked while moving: replan on the move (paper 002); brake, wait and plan from rest "
        "(MoveIt-style baseline); or ignore the map once moving (no monitoring; for comparison only).",
    )
    policy: Literal["wait_and_resume", "abort"] = Field(
        "wait_and_resume", description="After a safety brake: hold and resume when clear, or fail the goal."
    )
    safety_distance: float = Field(0.03, ge=0.0, le=0.5, description="Brake when the robot gets this close [m].")
    check_rate_hz: float = Field(150.0, gt=0.0, le=1000.0, description="Max remaining-path checks per second.")
    clear_checks: int = Field(3, ge=1, le=100, description="Clear checks in a row that cancel a pending replan.")
    replan_deadline: float = Field(0.15, gt=0.0, le=10.0, description="Planning budget of a replan while moving [s].")
    splice_margin: float = Field(0.05, ge=0.0, le=1.0, description="Extra lead time before the splice lands [s].")
    pending_timeout: float = Field(1.5, gt=0.0, description="Replanning may go on this long before braking [s].")
    pending_speed_factor: float = Field(
        0.5, gt=0.0, le=1.0, description="While a replan is pending the arm goes on at this share of its speed."
    )
    hold_timeout: float = Field(10.0, gt=0.0, description="wait_and_resume gives up after holding this long [s].")
    hold_replan_interval: float = Field(1.0, gt=0.0, description="While holding, plan anew this often [s].")
    joint_state_timeout: float = Field(0.25, gt=0.0, description="Joint states silent this long: brake, fail [s].")
    sensor_timeout: float = Field(1.0, gt=0.0, description="A configured camera silent this long: brake, fail [s].")
    goal_tolerance: float = Field(0.01, gt=0.0, description="Reached when every joint is this close [rad].")
    settle_timeout: float = Field(1.0, gt=0.0, description="Time after the trajectory's end to reach the goal [s].")
    brake_latency: float = Field(0.01, ge=0.0, le=0.5, description="A brake starts this long after it is decided [s].")
    planning_process: bool = Field(
        True, description="Plan in a child process (a second core; with the GIL a thread shares the monitor's core)."
    )
    driver_rate_hz: float = Field(200.0, gt=0.0, le=2000.0, description="Kinematic driver's joint-state rate [Hz].")


class TransportConfig(_Section):
    namespace: str = Field(
        "replanner",
        pattern=r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$",
        description="First key chunks; keys are <namespace>/@v1/<robot>/...",
    )
    endpoint: str = Field(
        "tcp/127.0.0.1:7448",
        pattern=r"^[a-z]+/.+",
        description="The service listens here (peer mode) and the other replanner processes "
        "connect here, unless listen/connect say otherwise",
    )
    mode: Literal["peer", "client", "router"] = "peer"
    connect: list[str] = Field(
        default_factory=list, description="Zenoh endpoints to connect to, e.g. tcp/10.0.0.2:7447"
    )
    listen: list[str] = Field(default_factory=list, description="Zenoh endpoints to listen on")
    multicast_scouting: bool = Field(False, description="Find peers by UDP multicast (off: fixed endpoints only)")
    status_rate_hz: float = Field(10.0, gt=0.0, le=100.0, description="Rate of the status stream [Hz]")
    trajectory_dt: float = Field(0.01, gt=0.0, le=0.1, description="Sample period of published trajectories [s]")


class SceneObjectConfig(_Section):
    name: str = Field(min_length=1)
    type: Literal["box", "cylinder", "sphere"]
    size: Vec3 | None = None
    radius: float | None = Field(None, gt=0.0)
    length: float | None = Field(None, gt=0.0)
    position: Vec3
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @model_validator(mode="after")
    def _dims(self) -> SceneObjectConfig:
        need = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}[self.type]
        missing = [n for n in need if getattr(self, n) is None]
        if missing:
            raise ValueError(f"a {self.type} needs {', '.join(need)}; missing {', '.join(missing)}")
        return self


class ReplannerConfig(_Section):
    robot: RobotConfig
    collision: CollisionConfig = Field(default_factory=CollisionConfig)
    perception: PerceptionConfig | None = None
    planning: PlanningConfig = Field(default_factory=PlanningConfig)
    controller: ControllerConfig = Field(default_factory=ControllerConfig)
    transport: TransportConfig = Field(default_factory=TransportConfig)
    scene: list[SceneObjectConfig] = Field(default_factory=list, description="Static objects present at start")

    def override(self, changes: Mapping[str, Any], source: str = "override") -> ReplannerConfig:
        """A copy with `changes` merged in and validated, e.g. `cfg.override({"collision": {"padding": 0.0}})`.

        Nested mappings merge key by key; anything else (lists too) replaces. Raises ConfigError naming the field.
        """
        if not isinstance(changes, Mapping):
            raise ConfigError(f"{source}: give a mapping of sections, e.g. {{'collision': {{'padding': 0.0}}}}")
        return parse_config(_merge(self.model_dump(mode="python"), dict(changes)), source, schema=type(self))

    def core(self) -> ReplannerConfig:
        """The service's sections alone (a subclass, such as the simulated cell's, drops its own)."""
        if type(self) is ReplannerConfig:
            return self
        return ReplannerConfig.model_validate(self.model_dump(mode="python", include=set(ReplannerConfig.model_fields)))


def _model_at(model: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The pydantic model class reached by following `loc` field names from `model`."""
    current: Any = model
    for part in loc:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return None
        if not isinstance(part, str) or part not in current.model_fields:
            return None
        current = current.model_fields[part].annotation
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def format_validation_error(err: ValidationError, model: type[BaseModel], source: str) -> str:
    """One line per problem: `<file>: <field>: <what is wrong>; <what is allowed>`."""
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        field = _format_loc(loc)
        if e["type"] == "extra_forbidden":
            parent = _model_at(model, loc[:-1])
            allowed = ", ".join(parent.model_fields) if parent else "see docs"
            lines.append(f"{source}: {field}: unknown field {loc[-1]!r}; allowed fields here: {allowed}")
        elif e["type"] == "missing":
            lines.append(f"{source}: {field}: required field is missing")
        else:
            msg = e["msg"].removeprefix("Value error, ")
            shown = e.get("input")
            got = "" if isinstance(shown, dict) else f" (got {shown!r})"
            lines.append(f"{source}: {field}: {msg}{got}")
    return "\n".join(lines)


def parse_config(
    data: Any,
    source: str = "<config>",
    base_dir: str | os.PathLike | None = None,
    *,
    schema: type[ReplannerConfig] = ReplannerConfig,
) -> ReplannerConfig:
    """Validate an already-parsed mapping against `schema`; `base_dir` anchors relative paths."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping with a 'robot' section", source=source)
    try:
        return schema.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as err:
        first = err.errors()[0]
        message = format_validation_error(err, schema, source)
        if "sim" in data and "sim" not in schema.model_fields:
            message += (
                "\n(the 'sim' section is the simulated cell's: read it with replanner.sim.config.load_cell_config)"
            )
        raise ConfigError(message, source=source, field=_format_loc(tuple(first["loc"]))) from None


def profiles() -> list[str]:
    """Names of the shipped config profiles (configs/*.yaml), e.g. panda, iiwa, demo."""
    folder = resources.files("replanner_configs")
    return sorted(p.name.removesuffix(".yaml") for p in folder.iterdir() if p.name.endswith(".yaml"))


def config_path(source: str | os.PathLike) -> Path:
    """The YAML file of `source`: an existing path, or the file of a shipped profile name."""
    p = Path(source)
    if p.is_file():
        return p
    name = str(source)
    if name in profiles():
        return Path(str(resources.files("replanner_configs") / f"{name}.yaml"))
    raise ConfigError(
        f"config file not found: {p} (pass an existing YAML file, or a shipped profile: {', '.join(profiles())})",
        source=str(p),
    )


def load_config(source: str | os.PathLike, *, schema: type[ReplannerConfig] = ReplannerConfig) -> ReplannerConfig:
    """Read and validate a YAML config file or a shipped profile by name; errors name the file and the field.

    `base: other.yaml` inherits from another file (relative to this one); mappings merge key by key.
    """
    p = config_path(source)
    data = _read_yaml(p)
    base_dir = p.parent.resolve()
    seen = [p.resolve()]
    while isinstance(data, dict) and "base" in data:
        ref = data.pop("base")
        if not isinstance(ref, str):
            raise ConfigError(f"{p}: base: give the path of another config file (got {ref!r})", source=str(p))
        bp = Path(ref) if Path(ref).is_absolute() else base_dir / ref
        if not bp.is_file():
            raise ConfigError(f"{p}: base: file not found: {bp}", source=str(p), field="base")
        if bp.resolve() in seen:
            raise ConfigError(f"{p}: base: {bp} is included twice (a cycle)", source=str(p), field="base")
        seen.append(bp.resolve())
        base = _read_yaml(bp)
        data = _merge(base, data)
        base_dir = bp.parent.resolve()  # relative paths of the merged file: the base's (profiles live together)
    return parse_config(data, source=str(p), base_dir=base_dir, schema=schema)


def _read_yaml(p: Path) -> Any:
    try:
        return yaml.safe_load(p.read_text())
    except yaml.YAMLError as err:
        raise ConfigError(f"{p}: not valid YAML: {err}", source=str(p)) from None


def _merge(base: Any, over: Any) -> Any:
    """`over` on top of `base`: mappings merge key by key, anything else (lists too) is replaced."""
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for k, v in over.items():
            out[k] = _merge(base.get(k), v) if k in base else v
        return out
    return over
