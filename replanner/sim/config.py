"""The simulated cell's config: the core sections plus `sim:` (rates, noise, the operator's script, the task).

The service reads the core sections only; the simulator, the cameras, the pick-and-place client and the demo read
this schema, so one YAML file (configs/demo.yaml) describes the whole cell.
"""

from __future__ import annotations

import os

from pydantic import Field, model_validator

from ..config import ReplannerConfig, load_config
from ..sections import Section, Vec3

Range = tuple[float, float]


class NoiseConfig(Section):
    """A structured-light camera's faults (Kinect-like): what the perception's filters must cope with. Off unless a
    cell's config turns them on (configs/demo.yaml does)."""

    depth_sigma: float = Field(0.0, ge=0.0, le=0.1, description="Depth noise at 1 m, growing with range^2 [m].")
    dropout: float = Field(0.0, ge=0.0, le=0.5, description="Share of pixels with no return.")
    outliers: float = Field(0.0, ge=0.0, le=0.1, description="Share of pixels at a random depth.")
    flying: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="Share of pixels at a depth edge (a 5 % jump to a neighbour) that return a depth between the "
        "two sides: points in mid-air.",
    )


class OperatorConfig(Section):
    enabled: bool = True
    stand: Vec3 = Field((0.45, -1.0, 0.3), description="Where the operator's shoulder is [m, base frame].")
    first_after: float = Field(3.0, ge=0.0, description="First intrusion this long after the start [s].")
    interval: Range = Field((2.0, 5.0), description="Pause between the end of one intrusion and the next [s].")
    in_path_probability: float = Field(0.75, ge=0.0, le=1.0, description="Share of intrusions aimed at the path.")
    lead_time: Range = Field(
        (0.7, 1.4), description="An aimed hand arrives this long before the arm would come within stop_distance [s]."
    )
    goal_margin: float = Field(
        0.15,
        ge=0.0,
        description="An aimed hand keeps this far from where the motion ends: no path avoids a hand on the goal [m].",
    )
    reach_region: tuple[Vec3, Vec3] = Field(
        ((0.2, -0.6, 0.1), (0.7, -0.15, 0.5)),
        description="Corners (min, max) of the box an unaimed hand reaches into [m, base frame].",
    )
    aim_patience: float = Field(
        3.0, ge=0.0, description="An aimed intrusion waits this long for a motion it can meet, then goes anywhere [s]."
    )
    linger: Range = Field((1.0, 2.5), description="The hand stays this long [s].")
    speed: float = Field(1.0, gt=0.0, le=3.0, description="Hand speed in and out [m/s].")
    arm_radius: float = Field(0.05, gt=0.0, le=0.3, description="Forearm capsule radius [m].")
    arm_length: float = Field(0.35, gt=0.0, le=1.5, description="Forearm capsule length [m].")
    stop_distance: float = Field(
        0.06, ge=0.0, le=0.5, description="The hand stops rather than come this close to the arm by itself [m]."
    )
    keep_off_arm: float = Field(
        0.12,
        ge=0.0,
        description="Entries whose way in passes closer than this to the arm's current pose are not made [m].",
    )

    @model_validator(mode="after")
    def _ordered(self) -> OperatorConfig:
        for name in ("interval", "lead_time", "linger"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ValueError(f"{name} must be [min, max] with 0 <= min <= max, got [{lo}, {hi}]")
        lo, hi = self.reach_region
        if any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"reach_region must be [[min x, y, z], [max x, y, z]] with min < max, got {[lo, hi]}")
        return self


class TaskConfig(Section):
    part_size: Vec3 = Field((0.03, 0.03, 0.06), description="The carried part, a box [m].")
    bins: tuple[str, str] = Field(("bin_a", "bin_b"), description="Scene objects (bin floors) parts rest on.")
    grasp_gap: float = Field(0.02, gt=0.0, le=0.1, description="Suction: the tip stops this far above the part [m].")
    approach_height: float = Field(0.12, gt=0.0, le=0.5, description="Pre-grasp/place height above the part [m].")
    place_gap: float = Field(0.015, ge=0.0, le=0.1, description="A placed part is let go this far above the floor [m].")
    velocity_scale: float = Field(0.5, gt=0.0, le=1.0, description="Share of the joint speed limits the task uses.")


class SimConfig(Section):
    physics_hz: float = Field(1000.0, ge=100.0, le=5000.0, description="pybullet steps per second.")
    joint_state_hz: float = Field(250.0, ge=50.0, le=1000.0, description="Joint-state rate of the simulated arm [Hz].")
    camera_rate_hz: float | None = Field(None, gt=0.0, le=60.0, description="Overrides every camera's rate_hz.")
    truth_rate_hz: float = Field(100.0, gt=0.0, le=1000.0, description="Ground-truth clearance samples [Hz].")
    path_check_hz: float = Field(20.0, gt=0.0, le=200.0, description="Ground truth: obstacle on the planned path [Hz].")
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    operator: OperatorConfig = Field(default_factory=OperatorConfig)
    task: TaskConfig = Field(default_factory=TaskConfig)


class CellConfig(ReplannerConfig):
    """A whole simulated cell: the service's sections and the simulator's."""

    sim: SimConfig = Field(default_factory=SimConfig)


def load_cell_config(source: str | os.PathLike) -> CellConfig:
    """Read and validate a cell config: a YAML file or a shipped profile name (e.g. "demo")."""
    return load_config(source, schema=CellConfig)
