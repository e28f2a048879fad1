"""Configuration schema (pydantic) and the YAML loader that turns validation errors into actionable messages.

Every section forbids unknown fields, so a typo is an error that names the field, the file and what is allowed.
"""

from __future__ import annotations

import os
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
    path_resolution: float = Field(
        0.01, gt=0.0, le=0.2, description="Max displacement of any robot point between two path checks [m]."
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


class ReplannerConfig(_Section):
    robot: RobotConfig
    collision: CollisionConfig = Field(default_factory=CollisionConfig)


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


def parse_config(data: Any, source: str = "<config>", base_dir: str | os.PathLike | None = None) -> ReplannerConfig:
    """Validate an already-parsed mapping; `base_dir` anchors relative paths."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping with a 'robot' section", source=source)
    try:
        return ReplannerConfig.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as err:
        first = err.errors()[0]
        raise ConfigError(
            format_validation_error(err, ReplannerConfig, source), source=source, field=_format_loc(tuple(first["loc"]))
        ) from None


def load_config(path: str | os.PathLike) -> ReplannerConfig:
    """Read and validate a YAML config file; errors name the file, the field and what is allowed."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(
            f"config file not found: {p} (pass an existing YAML file, e.g. configs/panda.yaml)", source=str(p)
        )
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as err:
        raise ConfigError(f"{p}: not valid YAML: {err}", source=str(p)) from None
    return parse_config(data, source=str(p), base_dir=p.parent.resolve())
