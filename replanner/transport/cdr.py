"""What every ROS 2 message codec here shares: rosbags' type store, the type names, stamps to the nanosecond."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

CDR_LE = b"\x00\x01\x00\x00"  # the encapsulation header of little-endian CDR
JOINT_STATE = "sensor_msgs/msg/JointState"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"


@lru_cache(maxsize=1)
def typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def split_times(t) -> tuple[np.ndarray, np.ndarray]:
    """(sec, nanosec) of times [s], to the nearest nanosecond (2.9999999999 s is 3 s and 0 ns, not 2 s)."""
    t = np.asarray(t, np.float64)
    sec = np.floor(t).astype(np.int64)
    nsec = np.rint((t - sec) * 1e9).astype(np.int64)
    carry = nsec >= 1_000_000_000
    return sec + carry, np.where(carry, 0, nsec)


def split_time(t: float) -> tuple[int, int]:
    sec, nsec = split_times(np.array([t]))
    return int(sec[0]), int(nsec[0])


def make_header(t: float, frame: str):
    """A std_msgs/Header at time t [s] in `frame`."""
    ts = typestore()
    sec, nsec = split_time(t)
    return ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame
    )
