"""Are the robot and the cameras still talking? The ages of the inputs the controller needs to move safely."""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError


class Liveness:
    """The newest joint state and when each input was last heard of, on the controller's clock [s].

    Args:
        sensors: camera names whose silence is a fault.
        joint_state_timeout, sensor_timeout: [s] of silence that make an input dead.
    """

    def __init__(self, sensors: tuple[str, ...], joint_state_timeout: float, sensor_timeout: float):
        self.sensors = sensors
        self.joint_state_timeout, self.sensor_timeout = joint_state_timeout, sensor_timeout
        self.last_js = None  # (receipt time, JointState)
        self._seen: dict[str, float] = {}

    def joint_state(self, now: float, js) -> None:
        self.last_js = (now, js)

    def sensor(self, now: float, name: str) -> None:
        self._seen[name] = now

    def seen_all_since(self, t: float) -> bool:
        """Every camera has delivered a frame since time t [s] (True without cameras)."""
        return all(self._seen.get(s, -math.inf) > t for s in self.sensors)

    def silent(self, now: float, ready: bool = False) -> str | None:
        """Why the inputs cannot be trusted now, or None. ready: phrased for refusing a new goal."""
        js = self.last_js
        if js is None or now - js[0] > self.joint_state_timeout:
            if ready:
                return "no recent joint state: the robot is not reporting (check the driver)"
            return f"joint states silent for {now - js[0] if js else math.inf:.2f} s"
        for s in self.sensors:
            age = now - self._seen.get(s, -math.inf)
            if age > self.sensor_timeout:
                if ready:
                    return f"camera {s!r} is silent: its point clouds are needed to move safely"
                return f"camera {s!r} silent for {age:.2f} s"
        return None


def admit_joint_state(stamp: float, q, *, last: float | None, now: float, robot, cfg) -> None:
    """Raise InvalidInputError saying why a decoded joint state cannot be taken as the arm's: a position past its
    limit by more than `cfg.joint_state_limit_slack` [rad], a stamp not newer than the `last` one taken, older
    than `cfg.joint_state_max_age` or ahead of `now` by more than `cfg.joint_state_max_lead` [s]."""
    slack, limits = cfg.joint_state_limit_slack, robot.limits
    over = np.flatnonzero((q < limits.lower - slack) | (q > limits.upper + slack))
    if len(over):
        j = int(over[0])
        raise InvalidInputError(
            f"joint_states: {robot.joint_names[j]} = {q[j]:.4f} rad is outside its limits "
            f"[{limits.lower[j]:.4f}, {limits.upper[j]:.4f}] by more than {slack} rad"
        )
    if stamp < now - cfg.joint_state_max_age:
        raise InvalidInputError(
            f"joint_states: stamp {stamp:.3f} is {now - stamp:.3f} s old (joint_state_max_age "
            f"{cfg.joint_state_max_age} s): check the robot's and the service's clocks"
        )
    if stamp > now + cfg.joint_state_max_lead:
        raise InvalidInputError(
            f"joint_states: stamp {stamp:.3f} is {stamp - now:.3f} s in the future (joint_state_max_lead "
            f"{cfg.joint_state_max_lead} s): check the robot's and the service's clocks"
        )
    if last is not None and stamp <= last:
        raise InvalidInputError(f"joint_states: stamp {stamp:.6f} is not newer than the last one taken ({last:.6f})")


STANDING = 0.05  # [rad/s] a measured arm slower than this on every joint stands


def record_gap(js, timeline) -> np.ndarray:
    """Per joint, how far [rad] the measured arm `js` is from where `timeline` told it to be at the state's stamp."""
    return np.abs(js.position - timeline.state(js.stamp)[0])


def off_record(js, timeline, names, tolerance: float) -> tuple[float | None, str | None]:
    """How far [rad] the measured arm `js` is from where `timeline` told it to be at its stamp (None while both
    stand: before a motion starts the record may still hold an older rest), and why that is too far for the robot
    to be following (beyond `tolerance` [rad]; else None)."""
    if not timeline.moving(js.stamp) and np.abs(js.velocity).max() < STANDING:
        return None, None
    off = record_gap(js, timeline)
    if off.max() <= tolerance:
        return float(off.max()), None
    j = int(np.argmax(off))
    return float(off.max()), (
        f"the robot does not follow its trajectory: {names[j]} is {off[j]:.3f} rad from where it was told to be "
        f"(controller.tracking_tolerance {tolerance} rad): did it refuse one, or stop on its own?"
    )
