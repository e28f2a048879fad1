"""The whole config (`ReplannerConfig`) and the YAML loader that turns validation errors into actionable messages.

Every section forbids unknown fields, so a typo is an error that names the field, the file and what is allowed.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, Field, ValidationError

from .errors import ConfigError
from .sections import (  # the sections, importable from here as before
    CollisionConfig,
    ControllerConfig,
    PerceptionConfig,
    PlanningConfig,
    RobotConfig,
    SceneObjectConfig,
    Section,
    TransportConfig,
)


class ReplannerConfig(Section):
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
