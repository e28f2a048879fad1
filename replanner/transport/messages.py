"""Message schemas: JSON control messages validated with pydantic, ROS 2 messages in CDR via rosbags."""

from __future__ import annotations

import json
import math
import struct
from functools import lru_cache
from typing import Annotated, Literal, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..errors import InvalidInputError
from ..model.geometry import Box, Cylinder, Mesh, Sphere, shape_to_dict
from ..model.transforms import make_transform
from . import trajectory_cdr
from .cdr import CDR_LE, JOINT_STATE, JOINT_TRAJECTORY, POINT_CLOUD2, make_header, split_time, typestore


class DecodeError(InvalidInputError):
    """A message could not be read; the message says which field and what is expected."""


def _finite(values: list[float], name: str) -> list[float]:
    if any(not math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be finite numbers (no NaN or inf)")
    return values


class _Msg(BaseModel):
    # strict: "0.4" and true are not numbers; NaN and inf are not finite numbers (JSON has neither)
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3, description="[x, y, z]")]
# object names: letters, digits and _ . - (they appear in logs, keys of the map's filters and file names)
Name = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9_.\-]+$")]
Quat = Annotated[list[float], Field(min_length=4, max_length=4, description="[x, y, z, w]")]


class Pose(_Msg):
    position: Vec3 = Field(description="[m] in the robot base frame")
    quat_xyzw: Quat = [0.0, 0.0, 0.0, 1.0]

    @field_validator("position", "quat_xyzw")
    @classmethod
    def _fin(cls, v, info):
        return _finite(list(v), info.field_name)

    def matrix(self) -> np.ndarray:
        return make_transform(self.position, self.quat_xyzw)


class PoseTarget(Pose):
    link: str
    position_tolerance: float | None = Field(None, gt=0.0, description="[m]")
    orientation_tolerance: float | None = Field(None, gt=0.0, description="[rad]")


class GoalRequest(_Msg):
    id: str = Field(min_length=1, max_length=128)
    joints: list[float] | None = Field(None, description="[rad], one per joint, in the service's joint order")
    pose: PoseTarget | None = None
    planner: str | None = None
    deadline: float | None = Field(None, gt=0.0, lt=600.0, description="[s]")
    velocity_scale: float = Field(1.0, gt=0.0, le=1.0)
    acceleration_scale: float = Field(1.0, gt=0.0, le=1.0)
    padding: float | None = Field(
        None, ge=0.0, le=0.2, description="[m] from known objects; null: the service's collision.padding"
    )

    @field_validator("joints")
    @classmethod
    def _fin(cls, v):
        return None if v is None else _finite(v, "joints")


class CancelRequest(_Msg):
    id: str = Field(min_length=1, max_length=128)


class BoxShape(_Msg):
    type: Literal["box"]
    size: Vec3 = Field(description="full edge lengths [m]")


class CylinderShape(_Msg):
    type: Literal["cylinder"]
    radius: float = Field(gt=0.0)
    length: float = Field(gt=0.0)


class SphereShape(_Msg):
    type: Literal["sphere"]
    radius: float = Field(gt=0.0)


class MeshShape(_Msg):
    type: Literal["mesh"]
    vertices: list[Vec3] = Field(min_length=4, max_length=100_000)
    faces: list[Annotated[list[int], Field(min_length=3, max_length=3)]] = Field(min_length=1, max_length=200_000)


ShapeMsg = Annotated[BoxShape | CylinderShape | SphereShape | MeshShape, Field(discriminator="type")]


def shape_from(msg) -> Box | Cylinder | Sphere | Mesh:
    if isinstance(msg, BoxShape):
        return Box(size=tuple(msg.size))
    if isinstance(msg, CylinderShape):
        return Cylinder(radius=msg.radius, length=msg.length)
    if isinstance(msg, SphereShape):
        return Sphere(radius=msg.radius)
    return Mesh(np.asarray(msg.vertices, float), np.asarray(msg.faces, np.int64))


def shape_to_msg(shape) -> dict:
    return {k: v for k, v in shape_to_dict(shape).items() if k != "convex"}  # the protocol's MeshShape has no flag


class SceneAdd(_Msg):
    name: Name
    shape: ShapeMsg
    pose: Pose


class SceneMove(_Msg):
    name: Name
    pose: Pose


class SceneName(_Msg):
    name: Name


class SceneAttach(_Msg):
    name: Name
    link: str
    touch_links: list[str] | None = None
    support: list[str] = Field(default_factory=list, description="static objects it may touch until it left them")


class MapGet(_Msg):
    min: Vec3 | None = Field(None, description="corner of a box [m]: only voxels inside it are returned")
    max: Vec3 | None = None
    encoding: Literal["json", "float32"] = Field(
        "json", description="voxels as JSON lists, or as base64 of little-endian float32 x, y, z (big maps: cheaper)"
    )

    @field_validator("min", "max")
    @classmethod
    def _finite_corner(cls, v, info):
        return None if v is None else _finite(v, info.field_name)

    @model_validator(mode="after")
    def _ordered(self):
        if (self.min is None) != (self.max is None):
            raise ValueError("give both min and max (a box), or neither (the whole map)")
        if self.min is not None and any(a > b for a, b in zip(self.min, self.max)):
            raise ValueError(f"min {self.min} must be <= max {self.max} on every axis")
        return self


class Empty(_Msg):
    pass


def parse_json(model: type[_Msg], payload: bytes | None, what: str):
    """Decode and validate a JSON request; DecodeError names the field and what is wrong."""
    if not payload:
        if model is Empty:
            return Empty()
        raise DecodeError(f"{what}: empty payload; send a JSON object ({_fields(model)})")
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DecodeError(f"{what}: not valid JSON ({err})") from None
    except RecursionError:
        raise DecodeError(f"{what}: JSON nested too deeply (no request nests more than a few levels)") from None
    if not isinstance(data, dict):
        raise DecodeError(f"{what}: the payload must be a JSON object ({_fields(model)}), got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as err:
        parts = []
        for e in err.errors():
            loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
            msg = e["msg"].removeprefix("Value error, ")
            if e["type"] in ("float_type", "int_type"):
                msg += " (a JSON number: not a string, not true or false)"
            elif e["type"] == "string_pattern_mismatch" and e["loc"][-1] == "name":
                msg = "names are 1-128 letters, digits, '_', '.' or '-'"
            if e["type"] == "extra_forbidden":
                msg = f"unknown field; allowed: {_allowed_at(model, e['loc'][:-1]) or _fields(model)}"
            parts.append(f"{loc}: {msg}")
        raise DecodeError(f"{what}: " + "; ".join(parts)) from None


def _fields(model) -> str:
    return ", ".join(model.model_fields)


def _models_in(annotation) -> list[type[BaseModel]]:
    """The message models an annotation may hold (through Optional, Annotated, list and unions)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in get_args(annotation) for m in _models_in(arg)]


def _allowed_at(model: type[BaseModel], loc: tuple) -> str | None:
    """The fields allowed in the object at `loc` (a validation error's location) inside `model`."""
    models = [model]
    for part in loc:
        if isinstance(part, int):
            continue  # an index into a list: the same models
        nxt = []
        for mdl in models:
            if part in mdl.model_fields:
                nxt += _models_in(mdl.model_fields[part].annotation)
            elif "type" in mdl.model_fields and part in get_args(mdl.model_fields["type"].annotation):
                nxt.append(mdl)  # a tagged union's member, named by its tag
        models = nxt
    return _fields(models[0]) if len(models) == 1 else None


def dumps(obj) -> bytes:
    return json.dumps(obj, separators=(",", ":"), default=_default).encode()


def _default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.floating | np.integer):
        return o.item()
    raise TypeError(type(o).__name__)


# ------------------------------------------------------------------------------------- ROS 2 CDR
def _time_of(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _decode(data: bytes, typename: str, what: str):
    try:
        return typestore().deserialize_cdr(bytes(data), typename)
    except Exception as err:  # rosbags raises several types on truncated or foreign bytes
        raise DecodeError(f"{what}: not a CDR-encoded {typename} ({type(err).__name__}: {err})") from None


def encode_joint_state(stamp: float, names, position, velocity=None, frame: str = "") -> bytes:
    """CDR bytes of a sensor_msgs/JointState; the same bytes as rosbags' serializer, without its per-message
    objects (joint states stream at hundreds of Hz)."""
    pos = np.asarray(position, np.float64)
    vel = None if velocity is None else np.asarray(velocity, np.float64)
    names = tuple(names)
    if pos.shape != (len(names),) or (vel is not None and vel.shape != pos.shape):
        return encode_joint_state_rosbags(stamp, names, pos, vel, frame)  # rosbags says what is wrong
    blob, pos_at, vel_at = _joint_state_layout(names, frame, vel is not None)
    out = bytearray(blob)
    struct.pack_into("<iI", out, 4, *split_time(stamp))
    out[pos_at : pos_at + 8 * len(names)] = pos.astype("<f8").tobytes()
    if vel is not None:
        out[vel_at : vel_at + 8 * len(names)] = vel.astype("<f8").tobytes()
    return bytes(out)


@lru_cache(maxsize=16)
def _joint_state_layout(names: tuple[str, ...], frame: str, with_velocity: bool) -> tuple[bytes, int, int]:
    """rosbags' bytes for these names, and where the position and velocity arrays start in them."""
    n = len(names)
    mark_p, mark_v = np.full(n, 1.25e-300), np.full(n, -3.5e-300)  # values no header byte run can imitate
    blob = encode_joint_state_rosbags(0.0, names, mark_p, mark_v if with_velocity else None, frame)
    if blob[:4] != CDR_LE:
        raise RuntimeError("rosbags no longer writes little-endian CDR: the fast JointState encoder needs updating")
    return blob, blob.find(mark_p.astype("<f8").tobytes()), blob.find(mark_v.astype("<f8").tobytes())


def encode_joint_state_rosbags(stamp: float, names, position, velocity=None, frame: str = "") -> bytes:
    """The reference: rosbags' own serializer (slow; `encode_joint_state` writes the same bytes)."""
    ts = typestore()
    msg = ts.types[JOINT_STATE](
        header=make_header(stamp, frame),
        name=list(names),
        position=np.asarray(position, np.float64),
        velocity=np.asarray(velocity if velocity is not None else [], np.float64),
        effort=np.zeros(0, np.float64),
    )
    return bytes(ts.serialize_cdr(msg, JOINT_STATE))


def decode_joint_state(data: bytes, joint_names, frames=None) -> tuple[float, np.ndarray, np.ndarray | None]:
    """(stamp [s], q in `joint_names` order, qd or None). DecodeErrors say what is wrong: missing or duplicate
    names, arrays of the wrong length, NaN or inf anywhere, an impossible stamp, a frame_id not in `frames`
    (None: any)."""
    msg = _decode(data, JOINT_STATE, "joint_states")
    names = list(msg.name)
    pos = np.asarray(msg.position, np.float64)
    if len(pos) != len(names):
        raise DecodeError(f"joint_states: {len(names)} names but {len(pos)} positions")
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise DecodeError(f"joint_states: joints {twice} are named more than once")
    missing = [n for n in joint_names if n not in names]
    if missing:
        raise DecodeError(f"joint_states: joints {missing} are missing; names given: {names}")
    for field in ("velocity", "effort"):
        arr = np.asarray(getattr(msg, field), np.float64)
        if len(arr) not in (0, len(names)):
            raise DecodeError(f"joint_states: {len(arr)} {field} values for {len(names)} names (give none or one each)")
        if not np.all(np.isfinite(arr)):
            raise DecodeError(f"joint_states: {field} contains NaN or inf")
    idx = [names.index(n) for n in joint_names]
    q = pos[idx]
    if not np.all(np.isfinite(q)):
        raise DecodeError("joint_states: positions contain NaN or inf")
    st = msg.header.stamp
    if st.sec < 0 or not 0 <= st.nanosec < 1_000_000_000:
        raise DecodeError(
            f"joint_states: stamp sec={st.sec} nanosec={st.nanosec} is not a time (sec >= 0, nanosec < 1e9)"
        )
    if frames is not None and msg.header.frame_id not in frames:
        raise DecodeError(f"joint_states: frame_id {msg.header.frame_id!r} is not one of {sorted(frames)}")
    vel = np.asarray(msg.velocity, np.float64)
    qd = vel[idx] if len(vel) == len(names) else None
    return _time_of(st), q, qd


def encode_trajectory(start: float, names, times, q, qd, qdd, frame: str = "") -> bytes:
    """CDR bytes of a trajectory_msgs/JointTrajectory starting at `start` [s]: rosbags' bytes, written in bulk."""
    return trajectory_cdr.encode(start, names, times, q, qd, qdd, frame)


def decode_trajectory(data: bytes, joint_names):
    """(start [s], times (n,), q, qd, qdd (n, dof)) in `joint_names` order."""
    fast = trajectory_cdr.decode(bytes(data))
    if fast is not None:
        start, names, times, q, qd, qdd = fast
    else:  # any other layout (effort, missing arrays) or foreign bytes: rosbags reads it or says what is wrong
        start, names, times, q, qd, qdd = _decode_trajectory_rosbags(data)
    missing = [n for n in joint_names if n not in names]
    if missing:
        raise DecodeError(f"trajectory: joints {missing} are missing; names given: {names}")
    if not len(times):
        raise DecodeError("trajectory: no points")
    idx = [names.index(n) for n in joint_names]
    q, qd, qdd = q[:, idx], qd[:, idx], qdd[:, idx]
    if np.any(np.diff(times) <= 0) or not np.all(np.isfinite(q)):
        raise DecodeError("trajectory: times must increase and positions be finite")
    return start, times, q, qd, qdd


def _decode_trajectory_rosbags(data: bytes):
    msg = _decode(data, JOINT_TRAJECTORY, "trajectory")
    names = list(msg.joint_names)
    d = len(names)
    if not msg.points:
        return _time_of(msg.header.stamp), names, np.zeros(0), *(np.zeros((0, d)) for _ in range(3))

    def arr(field: str, fill: bool) -> np.ndarray:
        rows = [np.asarray(getattr(p, field), np.float64) for p in msg.points]
        if any(len(r) != d and not (fill and len(r) == 0) for r in rows):
            raise DecodeError(f"trajectory: every point needs {d} {field} (one per joint name)")
        return np.array([r if len(r) else np.zeros(d) for r in rows])

    times = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    return (
        _time_of(msg.header.stamp),
        names,
        times,
        arr("positions", False),
        arr("velocities", True),
        arr("accelerations", True),
    )


def encode_cloud(stamp: float, points: np.ndarray, frame: str = "", width: int | None = None, height: int = 1) -> bytes:
    """A PointCloud2 with float32 fields x, y, z (organised when height > 1; NaN where there was no return)."""
    ts = typestore()
    pts = np.ascontiguousarray(points, np.float32)
    width = width if width is not None else len(pts) // max(height, 1)
    F = ts.types["sensor_msgs/msg/PointField"]
    fields = [F(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    msg = ts.types[POINT_CLOUD2](
        header=make_header(stamp, frame),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=False,
        point_step=12,
        row_step=12 * width,
        data=pts.view(np.uint8).reshape(-1),
        is_dense=False,
    )
    return bytes(ts.serialize_cdr(msg, POINT_CLOUD2))


def decode_cloud(data: bytes, what: str = "cloud") -> tuple[float, np.ndarray, int, int]:
    """(stamp, points (N, 3) float32, width, height) from a PointCloud2 with float32 x, y, z fields."""
    msg = _decode(data, POINT_CLOUD2, what)
    offs = {f.name: (f.offset, f.datatype) for f in msg.fields}
    if any(n not in offs or offs[n][1] != 7 for n in "xyz"):
        raise DecodeError(f"{what}: needs float32 (datatype 7) fields x, y, z; got {sorted(offs)}")
    if msg.is_bigendian:
        raise DecodeError(f"{what}: big-endian clouds are not supported")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    raw = np.asarray(msg.data, np.uint8)
    if step < 12 or len(raw) != n * step:
        raise DecodeError(f"{what}: {len(raw)} data bytes for {n} points of {step} bytes")
    if int(msg.row_step) != int(msg.width) * step:
        raise DecodeError(f"{what}: row_step {msg.row_step} is not width x point_step = {int(msg.width) * step}")
    if any(offs[c][0] + 4 > step for c in "xyz"):
        raise DecodeError(f"{what}: fields x, y, z at offsets {[offs[c][0] for c in 'xyz']} overrun point_step {step}")
    rows = raw.reshape(n, step)
    o = offs["x"][0]
    if offs["y"][0] == o + 4 and offs["z"][0] == o + 8:  # the usual layout: x, y, z side by side, one copy
        pts = rows[:, o : o + 12].copy().view(np.float32)
    else:
        pts = np.stack([rows[:, offs[c][0] : offs[c][0] + 4].copy().view(np.float32)[:, 0] for c in "xyz"], axis=1)
    return _time_of(msg.header.stamp), pts, int(msg.width), int(msg.height)
