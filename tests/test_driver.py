"""The kinematic driver: follows what it is sent from the given start times; reports at its rate."""

from __future__ import annotations

import time

import numpy as np

from replanner.control import KinematicDriver, Timeline
from replanner.trajectory.generator import TrajectoryGenerator


def test_timeline_replaces_from_the_start_time(panda):
    gen = TrajectoryGenerator(panda)
    a = gen.time(np.array([panda.home, panda.home + 0.3]))
    b = gen.time(np.array([a.state_at(0.2)[0], panda.home - 0.2]))
    tl = Timeline(panda.home)
    np.testing.assert_allclose(tl.state(5.0)[0], panda.home)  # nothing sent: at rest
    tl.add(a, 10.0)
    np.testing.assert_allclose(tl.state(10.1)[0], a.state_at(0.1)[0])
    tl.add(b, 10.2)
    np.testing.assert_allclose(tl.state(10.1)[0], a.state_at(0.1)[0])  # before the switch: the old one
    np.testing.assert_allclose(tl.state(10.3)[0], b.state_at(0.1)[0])
    np.testing.assert_allclose(tl.state(99.0)[0], panda.home - 0.2)  # after the end: holds the end


def test_driver_reports_at_its_rate(panda):
    got = []
    drv = KinematicDriver(panda.home, rate_hz=200, on_state=got.append).start()
    time.sleep(0.5)
    drv.stop()
    stamps = np.array([s.stamp for s in got])
    assert 80 <= len(got) <= 110
    assert np.median(np.diff(stamps)) < 0.007
