"""A trajectory given as points, e.g. a received JointTrajectory: quintic Hermite pieces between the points."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BPoly

from ..errors import InvalidInputError


class SampledTrajectory:
    """Points (time [s], q, qd, qdd) joined by quintic Hermite pieces (scipy's Bernstein polynomials).

    Position, velocity and acceleration are continuous and exact at the points; between points sampled every
    10 ms from a jerk-limited trajectory, positions differ from it by about 1e-5 rad. Before the first point the
    state is the first point's; after the last, the arm rests at the last position.
    """

    def __init__(self, times, q, qd, qdd):
        self.times = np.asarray(times, dtype=float)
        self.q, self.qd, self.qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        n = len(self.times)
        if self.times.ndim != 1 or n < 1:
            raise InvalidInputError(f"a sampled trajectory needs at least one time, got shape {self.times.shape}")
        if self.q.ndim != 2 or len(self.q) != n or self.q.shape != self.qd.shape or self.q.shape != self.qdd.shape:
            raise InvalidInputError(
                f"times ({n}), q {self.q.shape}, qd {self.qd.shape} and qdd {self.qdd.shape} must describe the "
                "same points, one row per time"
            )
        if n > 1 and not np.all(np.diff(self.times) > 0):
            raise InvalidInputError("the times of a sampled trajectory must increase strictly")
        self._poly = None
        if n > 1:
            # Bernstein coefficients of each quintic Hermite piece, all at once (from_derivatives loops per piece)
            h = np.diff(self.times)[:, None]
            p0, v0, a0 = self.q[:-1], self.qd[:-1] * h, self.qdd[:-1] * h * h
            p1, v1, a1 = self.q[1:], self.qd[1:] * h, self.qdd[1:] * h * h
            c = np.stack([p0, p0 + v0 / 5, p0 + 2 * v0 / 5 + a0 / 20, p1 - 2 * v1 / 5 + a1 / 20, p1 - v1 / 5, p1])
            self._poly = BPoly(c, self.times)
            self._d1 = self._poly.derivative(1)
            self._d2 = self._poly.derivative(2)

    @classmethod
    def from_message(cls, data: bytes, joint_names) -> tuple[float, SampledTrajectory]:
        """(start [s], trajectory) of a JointTrajectory CDR message; raises InvalidInputError."""
        from ..transport.messages import decode_trajectory

        start, t, q, qd, qdd = decode_trajectory(data, joint_names)
        return start, cls(t, q, qd, qdd)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q_dot, q_ddot) at time t [s]."""
        ts = self.times
        if self._poly is None or t <= ts[0]:
            return self.q[0].copy(), self.qd[0].copy(), self.qdd[0].copy()
        if t >= ts[-1]:
            return self.q[-1].copy(), np.zeros_like(self.q[-1]), np.zeros_like(self.q[-1])
        return self._poly(t), self._d1(t), self._d2(t)
