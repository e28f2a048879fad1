"""The sections of a replanner config (pydantic): robot, collision, perception, planning, controller, transport, scene.

Every section forbids unknown fields, so a typo is an error that names the field and what is allowed.
"""

from __future__ import annotations

import os
from enum import Enum
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

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


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveList = list[float]


class SelfCollisionConfig(Section):
    allowed_pairs: list[tuple[str, str]] = Field(
        default_factory=list,
        description="Link pairs never checked against each other (parent/child pairs are always skipped).",
    )
    padding: float = Field(0.0, ge=0.0, le=0.05, description="Minimum distance two links must keep [m].")


class RobotConfig(Section):
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


class CollisionConfig(Section):
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


class PoseConfig(Section):
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


class SensorConfig(Section):
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


class WorkspaceConfig(Section):
    min: Vec3 = (-0.8, -1.0, -0.05)
    max: Vec3 = (1.2, 1.0, 1.5)

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceConfig:
        if any(a >= b for a, b in zip(self.min, self.max)):
            raise ValueError(f"workspace min {list(self.min)} must be below max {list(self.max)} on every axis")
        return self


class SelfFilterConfig(Section):
    enabled: bool = True
    padding: float = Field(0.03, ge=0.0, le=0.3, description="Points this close to the robot are its own [m].")
    static_objects_padding: float | None = Field(
        0.01, ge=0.0, le=0.3, description="Points this close to a known static object are dropped [m]; null keeps them."
    )
    max_joint_state_age: float = Field(
        0.2, gt=0.0, description="Joint state used must be within this time of the cloud's stamp [s]."
    )


class OutlierConfig(Section):
    method: Literal["neighbours", "statistical", "both", "none"] = "neighbours"
    min_neighbours: int = Field(2, ge=1, le=26, description="Occupied voxels among the 26 around a kept voxel.")
    k: int = Field(8, ge=1, le=64, description="Statistical: neighbours per point.")
    std_ratio: float = Field(1.0, gt=0.0, description="Statistical: keep mean distance <= mean + ratio * std.")


class OccupancyUpdateConfig(Section):
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


class PerceptionConfig(Section):
    """The workspace box is also the crop: the map covers exactly it."""

    resolution: float = Field(0.01, ge=0.002, le=0.2, description="Voxel edge [m].")
    workspace: WorkspaceConfig = Field(default_factory=WorkspaceConfig)
    sensors: list[SensorConfig] = Field(default_factory=list)
    range_filter: bool = True
    downsample: bool = Field(True, description="Filter voxels instead of points (much faster).")
    edge_filter: float | None = Field(
        0.02,
        gt=0.0,
        le=1.0,
        description="Organized clouds: pixels whose depth differs from a neighbour's by more than this share of it "
        "are dropped (mixed pixels at depth edges float in mid-air); null: off.",
    )
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


class CollisionLayer(str, Enum):
    """What a plan's search asks first; FCL checks the path it returns either way."""

    SPHERES = "spheres"  # the fast layer: spheres, then the convex shapes, FCL for what they cannot decide
    FCL = "fcl"  # the exact checker alone

    def __str__(self) -> str:  # the value in messages and f-strings, as on the command line
        return self.value


class PlanningConfig(Section):
    planner: str = Field("RRTConnect", description="Default OMPL planner (see replanner.planning.PLANNERS).")
    deadline: float = Field(1.0, gt=0.0, le=60.0, description="Default planning deadline [s], retries included.")
    attempt_checks: int = Field(
        1000,
        ge=1,
        description="Validity checks of the first attempt before retrying (each planner grows its tree on), each retry "
        "twice as many (counts).",
    )
    retry_planner: str | None = Field(
        "LBKPIECE1", description="The default planner's retries alternate with this one (null: the same again)."
    )
    shortcut_tries: int = Field(10, ge=0, description="Random shortcuts tried after the search (a count).")
    range: float | None = Field(1.5, gt=0.0, description="Planner step [rad]; null: OMPL's default.")
    search_coarseness: float = Field(
        4.0, ge=1.0, le=10.0, description="The search checks motions this much coarser; its path at full resolution."
    )
    tube_radius: float = Field(0.1, gt=0.0, le=1.0, description="Timed curve's max distance from the path [rad].")
    ik_restarts: int = Field(16, ge=1, le=256)
    collision_layer: CollisionLayer = Field(
        CollisionLayer.SPHERES,
        description="What the search asks first: 'spheres' (a conservative sphere model; FCL decides what it cannot "
        "clear and checks the returned path) or 'fcl' alone.",
    )
    position_tolerance: float = Field(0.002, gt=0.0, description="Cartesian goal position tolerance [m].")
    orientation_tolerance: float = Field(0.02, gt=0.0, description="Cartesian goal orientation tolerance [rad].")
    map_margin: float = Field(
        0.0, ge=0.0, le=0.2, description="Extra map padding of plans [m]; half collision.path_resolution: see docs"
    )
    record_jobs: str | None = Field(
        None,
        description="A directory: every job the service plans is kept there with its world and outcome (one .npz "
        "each), for `replanner bench replay DIR`; null: none are kept.",
    )


class Reaction(str, Enum):
    """What the controller does when the path is blocked while the arm moves."""

    REPLAN = "replan"
    REPLAN_REFLEX = "replan_reflex"
    REFLEX = "reflex"
    STOP_AND_WAIT = "stop_and_wait"
    NONE = "none"

    @property
    def swerves(self) -> bool:
        return self in (Reaction.REFLEX, Reaction.REPLAN_REFLEX)

    @property
    def replans(self) -> bool:
        return self in (Reaction.REPLAN, Reaction.REPLAN_REFLEX)


class AfterBrake(str, Enum):
    """What follows a safety brake."""

    WAIT_AND_RESUME = "wait_and_resume"
    ABORT = "abort"


class SpeedSeparationConfig(Section):
    """Speed and separation monitoring after ISO/TS 15066 (docs/safety.md): S_p = v_h (T_r + T_s) + v_r T_r + S_s +
    C + Z_d + Z_r, with T_r measured, T_s and S_s from the arm's brake, every unknown voxel possibly a person."""

    enabled: bool = Field(True, description="Off: only the path checks and the safety distance guard the arm.")
    plans: bool = Field(
        True,
        description="Plans keep S_p from the map's voxels, timed slower near them; off: plans keep map_padding and "
        "the monitor alone slows the arm near people.",
    )
    approach_speed: float = Field(
        1.6,
        gt=0.0,
        le=5.0,
        description="v_h: how fast a person may approach [m/s] (ISO 13855: 1.6 walking, 2.0 reaching)",
    )
    intrusion_distance: float | None = Field(
        None, ge=0.0, le=1.0, description="C [m]; default from the map's detection capability d: 8 (d - 14 mm), >= 0."
    )
    sensor_uncertainty: float = Field(0.01, ge=0.0, le=0.5, description="Z_d: depth error beyond the voxel itself [m].")
    robot_uncertainty: float = Field(
        0.005, ge=0.0, le=0.5, description="Z_r: position error beyond what the joint states' age implies [m]."
    )
    latency_percentile: float = Field(99.0, ge=50.0, le=100.0, description="T_r is this percentile of the window.")
    latency_window: float = Field(10.0, gt=0.0, le=600.0, description="Seconds of reaction-chain history behind T_r.")
    min_reaction_time: float = Field(
        0.05, ge=0.0, le=2.0, description="T_r is at least this, on top of a camera's frame period [s]."
    )
    range: float = Field(1.5, gt=0.0, le=5.0, description="Voxels farther than this never limit the speed [m].")
    point_spacing: float = Field(0.03, ge=0.005, le=0.2, description="Spacing of the arm's surface samples [m].")
    resume_margin: float = Field(
        0.1, ge=0.0, le=1.0, description="An arm at rest moves on only with this much more than S_p at rest [m]."
    )
    min_speed_share: float = Field(
        0.05, gt=0.0, le=1.0, description="Allowed less than this share of its speed, the arm stops and holds instead."
    )


class ReflexConfig(Section):
    """The reflex (docs/reflex.md): a swerve off the path, away from what the map holds near the arm, spliced onto the
    motion jerk-limited and checked like any path, back onto the path after `ramp` + `hold` + `ramp` of arc."""

    method: Literal["forces", "kernels"] = Field(
        "forces",
        description="forces: the GPU potential-field paper's virtual forces on a vertex model; kernels: Baumgartner "
        "and Klančar's convolution kernels.",
    )
    task: Literal["path", "position"] = Field(
        "path",
        description="The swerve lies in the nullspace of this task: path (never along the path: progress is the "
        "time law's) or position (the hand's position held, the papers' redundant-arm setting).",
    )
    vertices: int = Field(300, ge=50, le=20000, description="forces: vertices of the arm's model.")
    r_max: float = Field(
        0.6,
        gt=0.0,
        le=1.5,
        description="forces: only voxels this close to a vertex push it [m]; beyond the protective separation at rest, "
        "or speed and separation stops the arm before the reflex feels anything.",
    )
    f_max: float = Field(1.0, gt=0.0, description="forces: push of a voxel touching a vertex [N].")
    voxel: float = Field(
        0.03, ge=0.002, le=0.2, description="forces: the map's voxels merged into voxels this size first [m] (cost)."
    )
    mass: float = Field(1.0, gt=0.0, description="forces: the admittance's virtual inertia per joint [kg m^2].")
    damping: float = Field(
        200.0, gt=0.0, description="forces: the admittance's damping per joint [N m s/rad]: q' = tau / damping settled."
    )
    horizon: float = Field(0.4, gt=0.0, le=2.0, description="The swerve's offset: the admittance run this long [s].")
    kernel_length: int = Field(30, ge=2, le=200, description="kernels: samples along each axis (even).")
    kernel_width: int = Field(7, ge=1, le=51, description="kernels: samples across (odd).")
    kernel_decay: Literal["linear", "gaussian"] = Field("gaussian", description="kernels: fall-off.")
    kernel_gain: float = Field(0.05, gt=0.0, description="kernels: [m/s] per unit of kernel sum.")
    max_offset: float = Field(0.3, gt=0.0, le=1.5, description="The swerve's largest joint offset [rad].")
    min_offset: float = Field(0.02, ge=0.0, le=0.5, description="A smaller offset is no swerve [rad].")
    ramp: float = Field(0.25, gt=0.0, le=2.0, description="Arc along the path to the full offset, and back [rad].")
    hold: float = Field(0.3, ge=0.0, le=3.0, description="Arc along the path at the full offset [rad].")
    interval: float = Field(0.3, gt=0.0, le=5.0, description="At most one swerve per this long [s].")
    tries: int = Field(3, ge=1, le=8, description="Offsets tried per swerve: halved after each that collides.")

    @model_validator(mode="after")
    def _kernel_shape(self):
        if self.kernel_length % 2 or self.kernel_width % 2 == 0:
            raise ValueError(
                f"kernel_length must be even and kernel_width odd (the point lies between the two middle samples "
                f"along, on the middle one across); got {self.kernel_length} and {self.kernel_width}"
            )
        if self.min_offset >= self.max_offset:
            raise ValueError(f"min_offset ({self.min_offset}) must be less than max_offset ({self.max_offset})")
        return self


class ControllerConfig(Section):
    reaction: Reaction = Field(
        Reaction.REPLAN,
        description="Path blocked while moving: replan on the move (the KineoWorks reactive-planning paper); the same "
        "with a reflex that swerves off the path at once (replan_reflex); the reflex alone, back onto the same path "
        "(reflex); brake, wait and plan from rest (MoveIt-style baseline); or ignore the map once moving (no "
        "monitoring; for comparison only).",
    )
    policy: AfterBrake = Field(
        AfterBrake.WAIT_AND_RESUME, description="After a safety brake: hold and resume when clear, or fail the goal."
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
    hold_replan_interval: float = Field(
        1.0, gt=0.0, description="While holding, plan anew this often [s] (reaction replan: the first at once)."
    )
    joint_state_timeout: float = Field(0.25, gt=0.0, description="Joint states silent this long: brake, fail [s].")
    robot_watchdog: float = Field(
        1.0, gt=0.0, le=10.0, description="`replanner robot` brakes when the service is silent this long [s]."
    )
    robot_stall_after: float = Field(
        0.25, gt=0.0, le=10.0, description="`replanner robot` not stepped this long [s] stalled: it brakes."
    )
    joint_state_limit_slack: float = Field(
        0.02, ge=0.0, le=0.5, description="A measured position this far past its limit is refused [rad]."
    )
    joint_state_max_age: float = Field(
        2.0, gt=0.0, le=60.0, description="A joint state stamped longer ago than this is refused [s] (clocks)."
    )
    joint_state_max_lead: float = Field(
        0.5, gt=0.0, le=60.0, description="A joint state stamped this far in the future is refused [s] (clocks)."
    )
    sensor_timeout: float = Field(1.0, gt=0.0, description="A configured camera silent this long: brake, fail [s].")
    goal_tolerance: float = Field(0.01, gt=0.0, description="Reached when every joint is this close [rad].")
    tracking_tolerance: float = Field(
        0.25, gt=0.0, le=3.0, description="A joint this far from its command [rad]: the robot does not follow: fail."
    )
    settle_timeout: float = Field(1.0, gt=0.0, description="Time after the trajectory's end to reach the goal [s].")
    brake_latency: float = Field(0.01, ge=0.0, le=0.5, description="A brake starts this long after it is decided [s].")
    start_lead: float = Field(
        0.05, ge=0.0, le=1.0, description="A motion from rest starts this long after it is sent [s] (to reach it)."
    )
    planning_process: bool = Field(
        True, description="Plan in a child process (a second core; with the GIL a thread shares the monitor's core)."
    )
    driver_rate_hz: float = Field(200.0, gt=0.0, le=2000.0, description="Kinematic driver's joint-state rate [Hz].")
    gil_switch_interval: float = Field(
        0.0005,
        ge=0.0001,
        le=0.005,
        description="How long a Python thread may hold the interpreter while the monitor waits [s] "
        "(CPython's default is 0.005; set for the whole process when a controller is built).",
    )
    speed_separation: SpeedSeparationConfig = Field(default_factory=SpeedSeparationConfig)
    reflex: ReflexConfig = Field(default_factory=ReflexConfig)


class TransportConfig(Section):
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


class SceneObjectConfig(Section):
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
