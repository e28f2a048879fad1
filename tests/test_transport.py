"""Keys, Zenoh session configs and message codecs, without a running service."""

from __future__ import annotations

import json

import numpy as np
import pytest

from replanner.errors import ConfigError, InvalidInputError
from replanner.sections import TransportConfig
from replanner.transport import messages as m
from replanner.transport import trajectory_cdr
from replanner.transport.keys import KEYS, Keys
from replanner.transport.session import make_config

NAMES = [f"j{i}" for i in range(7)]


def test_keys_are_versioned_and_validated():
    k = Keys("panda", "lab/cell3")
    assert k.goal == "lab/cell3/@v1/panda/goal"
    assert k.scene_add == "lab/cell3/@v1/panda/scene/add"
    assert k.cloud("front") == "lab/cell3/@v1/panda/clouds/front"
    assert len(KEYS) == 20
    for bad in ("pan da", "a/*", "", "x/"):
        with pytest.raises(InvalidInputError, match="letters, digits"):
            Keys(bad)


def _conf(**kw) -> dict:
    return json.loads(str(make_config(TransportConfig(), **kw)))


def test_session_config_defaults_are_loopback_peers_without_multicast():
    serve = _conf(role="service")
    assert serve["mode"] == "peer" and serve["listen"]["endpoints"] == ["tcp/127.0.0.1:7448"]
    assert serve["scouting"]["multicast"]["enabled"] is False
    node = _conf(role="node")
    assert node["connect"]["endpoints"] == ["tcp/127.0.0.1:7448"]
    assert node["listen"]["endpoints"] == ["tcp/127.0.0.1:0"]
    client = _conf(role="service", mode="client", connect=["tcp/10.0.0.2:7447"])
    assert client["mode"] == "client" and client["connect"]["endpoints"] == ["tcp/10.0.0.2:7447"]


def test_session_config_errors_say_what_to_change(tmp_path):
    with pytest.raises(ConfigError, match="--mode must be peer, client or router"):
        _conf(role="node", mode="server")
    with pytest.raises(ConfigError, match="a Zenoh client cannot listen"):
        _conf(role="service", mode="client", listen=["tcp/127.0.0.1:7000"])
    bad = tmp_path / "z.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(ConfigError, match="z.json5: not a usable Zenoh JSON5 config"):
        _conf(role="node", zenoh_file=str(bad))


def test_zenoh_json5_file_is_used_and_flags_override_it(tmp_path):
    f = tmp_path / "router.json5"
    f.write_text('{ mode: "router", listen: { endpoints: ["tcp/127.0.0.1:7999"] } }')
    conf = _conf(role="service", zenoh_file=str(f))
    assert conf["mode"] == "router" and conf["listen"]["endpoints"] == ["tcp/127.0.0.1:7999"]
    conf = _conf(role="service", zenoh_file=str(f), mode="peer", listen=["tcp/127.0.0.1:7998"])
    assert conf["mode"] == "peer" and conf["listen"]["endpoints"] == ["tcp/127.0.0.1:7998"]


def test_cdr_round_trips():
    q = np.linspace(-1, 1, 7)
    stamp, q2, qd = m.decode_joint_state(m.encode_joint_state(12.25, NAMES, q, q * 2), NAMES[::-1])
    assert stamp == 12.25 and np.array_equal(q2, q[::-1]) and np.array_equal(qd, 2 * q[::-1])
    t = np.array([0.0, 0.01, 0.02])
    Q = np.arange(21.0).reshape(3, 7)
    start, t2, Q2, Qd, Qdd = m.decode_trajectory(m.encode_trajectory(5.5, NAMES, t, Q, Q, Q), NAMES)
    assert start == 5.5 and np.allclose(t2, t) and np.array_equal(Q2, Q) and np.array_equal(Qdd, Q)
    pts = np.random.default_rng(0).normal(size=(12, 3)).astype(np.float32)
    stamp, p2, w, h = m.decode_cloud(m.encode_cloud(3.0, pts, "cam", width=4, height=3))
    assert (stamp, w, h) == (3.0, 4, 3) and np.array_equal(p2, pts)


def test_wrong_cdr_is_a_decode_error_naming_the_type():
    js = m.encode_joint_state(1.0, NAMES, np.zeros(7))
    with pytest.raises(m.DecodeError, match="PointCloud2"):
        m.decode_cloud(js)
    with pytest.raises(m.DecodeError, match="JointState"):
        m.decode_joint_state(js[: len(js) // 2], NAMES)


def test_cloud_with_other_fields_is_read_by_offset():
    """A PointCloud2 with x, y, z, rgb (16-byte points), as RealSense drivers publish."""
    ts = m.typestore()
    F = ts.types["sensor_msgs/msg/PointField"]
    pts = np.random.default_rng(1).normal(size=(5, 3)).astype(np.float32)
    raw = np.zeros((5, 4), np.float32)
    raw[:, :3] = pts
    msg = ts.types[m.POINT_CLOUD2](
        header=m.make_header(1.0, "cam"),
        height=1,
        width=5,
        fields=[F(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(["x", "y", "z", "rgb"])],
        is_bigendian=False,
        point_step=16,
        row_step=80,
        data=raw.view(np.uint8).ravel(),
        is_dense=True,
    )
    _, p2, _, _ = m.decode_cloud(bytes(ts.serialize_cdr(msg, m.POINT_CLOUD2)))
    assert np.array_equal(p2, pts)


def test_json_requests_name_the_field():
    with pytest.raises(m.DecodeError, match=r"goal: pose.position: List should have at least 3 items"):
        m.parse_json(m.GoalRequest, b'{"id": "a", "pose": {"link": "l", "position": [1, 2]}}', "goal")
    with pytest.raises(m.DecodeError, match="velocity_scale"):
        m.parse_json(m.GoalRequest, b'{"id": "a", "joints": [0], "velocity_scale": 0}', "goal")
    assert m.parse_json(m.Empty, b"", "state") == m.Empty()


def test_fast_joint_state_encoder_writes_rosbags_bytes():
    """The 250 Hz encoder patches a rosbags-made template: the bytes must be exactly rosbags' own."""
    rng = np.random.default_rng(3)
    for n in (1, 7, 9):
        names = [f"joint_{i}" for i in range(n)]
        for _ in range(50):
            t, p, v = rng.uniform(0, 2e9), rng.normal(size=n), rng.normal(size=n)
            assert m.encode_joint_state(t, names, p, v) == m.encode_joint_state_rosbags(t, names, p, v)
            assert m.encode_joint_state(t, names, p, frame="base") == m.encode_joint_state_rosbags(
                t, names, p, None, "base"
            )


def test_bulk_trajectory_codec_writes_and_reads_rosbags_bytes():
    """A slowed trajectory has thousands of points: written and read in bulk, the bytes must be rosbags' own."""
    rng = np.random.default_rng(5)
    ts = m.typestore()
    for n_pts in (1, 2, 3, 250):
        for dof in (1, 6, 7):
            names = [f"joint_{'x' * int(rng.integers(0, 6))}{i}" for i in range(dof)]
            frame = "f" * int(rng.integers(0, 9))
            t = np.sort(rng.uniform(0.0, 30.0, n_pts))
            t[0] = 2.9999999999999996  # the nearest nanosecond is 3 s, not 2 s and 1e9 ns
            t = np.sort(t)
            q, qd, qdd = (rng.normal(size=(n_pts, dof)) for _ in range(3))
            start = float(rng.uniform(0, 2e9))
            blob = m.encode_trajectory(start, names, t, q, qd, qdd, frame)
            assert blob == trajectory_cdr.encode_rosbags(start, names, t, q, qd, qdd, frame)
            ref = ts.deserialize_cdr(blob, m.JOINT_TRAJECTORY)
            got_start, got_t, got_q, got_qd, got_qdd = m.decode_trajectory(blob, names[::-1])
            assert got_start == ref.header.stamp.sec + ref.header.stamp.nanosec * 1e-9
            ref_t = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in ref.points]
            assert np.array_equal(got_t, ref_t) and np.abs(got_t - t).max() < 1e-9
            for got, sent in ((got_q, q), (got_qd, qd), (got_qdd, qdd)):
                assert np.array_equal(got, sent[:, ::-1])


def test_trajectories_in_other_layouts_are_read_by_rosbags_or_refused_with_the_field():
    ts = m.typestore()
    P, D = ts.types["trajectory_msgs/msg/JointTrajectoryPoint"], ts.types["builtin_interfaces/msg/Duration"]

    def blob(points):
        msg = ts.types[m.JOINT_TRAJECTORY](header=m.make_header(4.0, ""), joint_names=list(NAMES), points=points)
        return bytes(ts.serialize_cdr(msg, m.JOINT_TRAJECTORY))

    def point(k, vel=True, effort=0, n=7):
        z = np.zeros(0)
        return P(
            positions=np.full(n, float(k)),
            velocities=np.full(n, 0.5) if vel else z,
            accelerations=z,
            effort=np.ones(effort),
            time_from_start=D(sec=k, nanosec=0),
        )

    # another client's trajectory: no accelerations, efforts, a point without velocities
    start, t, q, qd, qdd = m.decode_trajectory(blob([point(0, effort=7), point(1, vel=False), point(2)]), NAMES)
    assert start == 4.0 and np.array_equal(t, [0, 1, 2]) and np.array_equal(q[:, 3], [0, 1, 2])
    assert np.array_equal(qd[:, 0], [0.5, 0.0, 0.5]) and not qdd.any()
    with pytest.raises(m.DecodeError, match="every point needs 7 positions"):
        m.decode_trajectory(blob([point(0), point(1, n=6)]), NAMES)
    with pytest.raises(m.DecodeError, match="no points"):
        m.decode_trajectory(blob([]), NAMES)
    good = m.encode_trajectory(1.0, NAMES, np.arange(5) * 0.1, *(np.zeros((5, 7)),) * 3)
    for cut in (len(good) - 1, len(good) - 200, 40, 3):
        with pytest.raises(m.DecodeError, match="not a CDR-encoded trajectory_msgs/msg/JointTrajectory"):
            m.decode_trajectory(good[:cut], NAMES)
