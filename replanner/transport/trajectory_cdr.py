"""trajectory_msgs/JointTrajectory in CDR, in bulk: the same bytes as rosbags' serializer, without a Python object
per point (rosbags makes one for each of a long trajectory's thousands of points, inside the monitor's check).

Every point after the first has one layout (CDR aligns to the payload, and each point ends 4 bytes past an 8-byte
boundary), so the points after the first are one numpy record array (`_points_dtype`). The header and the first
point are rosbags' own bytes for these names and frame, patched; anything that does not fit is left to rosbags.
"""

from __future__ import annotations

import struct
from functools import lru_cache

import numpy as np

from .cdr import CDR_LE, JOINT_TRAJECTORY, make_header, split_time, split_times, typestore

_ARRAYS = ("positions", "velocities", "accelerations")


def encode_rosbags(start: float, names, times, q, qd, qdd, frame: str = "") -> bytes:
    """The reference: rosbags' own serializer, one message object per point."""
    ts = typestore()
    P, D = ts.types["trajectory_msgs/msg/JointTrajectoryPoint"], ts.types["builtin_interfaces/msg/Duration"]
    sec, nsec = split_times(times)
    points = [
        P(
            positions=np.asarray(a, np.float64),
            velocities=np.asarray(b, np.float64),
            accelerations=np.asarray(c, np.float64),
            effort=np.zeros(0, np.float64),
            time_from_start=D(sec=int(s), nanosec=int(ns)),
        )
        for a, b, c, s, ns in zip(q, qd, qdd, sec, nsec, strict=True)
    ]
    msg = ts.types[JOINT_TRAJECTORY](header=make_header(start, frame), joint_names=list(names), points=points)
    return bytes(ts.serialize_cdr(msg, JOINT_TRAJECTORY))


@lru_cache(maxsize=16)
def _points_dtype(d: int) -> np.dtype:
    """A point after the first, d joints: each array's count, its doubles (8-aligned: 4 pad bytes after the counts
    of the second and third), the empty effort's count, time_from_start."""
    f8 = ("<f8", (d,))
    return np.dtype(
        {
            "names": ["n_" + a for a in _ARRAYS] + list(_ARRAYS) + ["n_effort", "sec", "nanosec"],
            "formats": ["<u4"] * 3 + [f8] * 3 + ["<u4", "<i4", "<u4"],
            "offsets": [0, 4 + 8 * d, 12 + 16 * d, 4, 12 + 8 * d, 20 + 16 * d, 20 + 24 * d, 24 + 24 * d, 28 + 24 * d],
            "itemsize": 32 + 24 * d,
        }
    )


def _points(d: int, times, q, qd, qdd) -> np.ndarray:
    rec = np.zeros(len(times), _points_dtype(d))
    for name, arr in zip(_ARRAYS, (q, qd, qdd), strict=True):
        rec["n_" + name], rec[name] = d, arr
    rec["sec"], rec["nanosec"] = split_times(times)
    return rec


class _Layout:
    """rosbags' bytes for a header and a first point with these names and frame, and where the first point's
    fields lie in them; checked once against rosbags' bytes for the points after it."""

    def __init__(self, names: tuple[str, ...], frame: str):
        d = self.dof = len(names)
        marks = [np.full((2, d), v) * np.array([[1.0], [-1.0]]) for v in (1.25e-300, 2.5e-300, 3.75e-300)]
        times = np.array([0x1234567 + 0.5, 0x2345678 + 0.25])
        blob = encode_rosbags(0.0, names, times, *marks, frame)
        if blob[:4] != CDR_LE:
            raise RuntimeError("rosbags no longer writes little-endian CDR: the bulk trajectory encoder needs updating")
        first = [blob.find(m[0].astype("<f8").tobytes()) for m in marks]
        sec, nsec = split_times(times)
        t_at = blob.find(struct.pack("<iI", int(sec[0]), int(nsec[0])))
        padded = blob[first[0] - 4 : first[0]] != struct.pack("<I", d)  # a pad between count and doubles
        self.count_at = first[0] - (12 if padded else 8)  # the points' count, then the first point
        self.head, self.first_bytes = blob[: self.count_at + 4], blob[self.count_at + 4 : t_at + 8]
        self.first_at = [f - self.count_at - 4 for f in first] + [t_at - self.count_at - 4]
        if min(first + [t_at]) < 0 or blob[t_at + 8 :] != _points(d, times[1:], *(m[1:] for m in marks)).tobytes():
            raise RuntimeError("rosbags' JointTrajectory bytes are not laid out as the bulk encoder expects")

    def encode(self, start: float, times, q, qd, qdd) -> bytes:
        n, d = len(times), self.dof
        head = bytearray(self.head)
        struct.pack_into("<iI", head, 4, *split_time(start))
        struct.pack_into("<I", head, self.count_at, n)
        if n == 0:
            return bytes(head)
        first = bytearray(self.first_bytes)
        for at, arr in zip(self.first_at[:3], (q, qd, qdd), strict=True):
            first[at : at + 8 * d] = arr[0].astype("<f8").tobytes()
        struct.pack_into("<iI", first, self.first_at[3], *split_time(times[0]))
        return bytes(head) + bytes(first) + _points(d, times[1:], q[1:], qd[1:], qdd[1:]).tobytes()


@lru_cache(maxsize=16)
def _layout(names: tuple[str, ...], frame: str) -> _Layout:
    return _Layout(names, frame)


def encode(start: float, names, times, q, qd, qdd, frame: str = "") -> bytes:
    """CDR bytes of a JointTrajectory (positions, velocities and accelerations per point, no effort): rosbags' bytes."""
    names = tuple(names)
    times = np.asarray(times, np.float64)
    arrs = [np.asarray(a, np.float64) for a in (q, qd, qdd)]
    if times.ndim != 1 or any(a.shape != (len(times), len(names)) for a in arrs) or not names:
        return encode_rosbags(start, names, times, q, qd, qdd, frame)  # rosbags says what is wrong
    return _layout(names, frame).encode(start, times, *arrs)


def _u32(data: bytes, at: int) -> int:
    return struct.unpack_from("<I", data, at)[0]


def _string(data: bytes, at: int) -> tuple[str, int]:
    """A CDR string at the 4-aligned `at`: (text, the offset after it)."""
    n = _u32(data, at)
    if n < 1 or at + 4 + n > len(data) or data[at + 3 + n] != 0:
        raise ValueError("a string runs past the end or is not terminated")
    return data[at + 4 : at + 3 + n].decode(), at + 4 + n


def _align(at: int, k: int) -> int:
    return 4 + -(-(at - 4) // k) * k  # offsets count from the end of the encapsulation header


def decode(data: bytes):
    """(stamp [s], joint names, times, q, qd, qdd) of a JointTrajectory in the layout `encode` writes, or None for
    anything else (other layouts, effort, missing arrays, foreign bytes: rosbags reads those and says what is wrong).
    """
    try:
        if data[:4] != CDR_LE:
            return None
        sec0, nsec0 = struct.unpack_from("<iI", data, 4)
        _, at = _string(data, 12)
        count, at = _u32(data, _align(at, 4)), _align(at, 4) + 4
        names = []
        for _ in range(count):
            name, at = _string(data, _align(at, 4))
            names.append(name)
        at = _align(at, 4)
        n, d = _u32(data, at), len(names)
        at += 4
        if d == 0 or n == 0:
            return None
        first = []
        for _ in _ARRAYS:
            if _u32(data, at) != d:
                return None
            at = _align(at + 4, 8)
            first.append(np.frombuffer(data, "<f8", d, at))
            at += 8 * d
        if _u32(data, at) != 0:
            return None
        t0 = struct.unpack_from("<iI", data, at + 4)
        at += 12
    except (struct.error, ValueError, UnicodeDecodeError):
        return None
    dt = _points_dtype(d)
    if (at - 4) % 8 != 4 or len(data) != at + (n - 1) * dt.itemsize:
        return None
    rec = np.frombuffer(data, dt, n - 1, at)
    if any(np.any(rec["n_" + a] != d) for a in _ARRAYS) or np.any(rec["n_effort"] != 0):
        return None
    arrs = [np.vstack([f[None], rec[a]]) for f, a in zip(first, _ARRAYS, strict=True)]
    times = np.concatenate([[t0[0] + t0[1] * 1e-9], rec["sec"] + rec["nanosec"] * 1e-9])
    return sec0 + nsec0 * 1e-9, names, times, *arrs
