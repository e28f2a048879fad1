"""The monitor room: checks of the remaining motion (map, scene, safety distance, stop region, speed and separation)."""

from .checks import Check, MapPathCheck, MotionView, SafetyDistanceCheck, ScenePathCheck, StopRegionCheck, Verdict
from .monitor import Monitor, MonitorStats, Report, build_monitor
from .ssm import SeparationTerms, SpeedSeparationCheck, protective_separation, safe_speed_scale

__all__ = [
    "Check",
    "MapPathCheck",
    "Monitor",
    "MonitorStats",
    "MotionView",
    "Report",
    "SafetyDistanceCheck",
    "SeparationTerms",
    "SpeedSeparationCheck",
    "ScenePathCheck",
    "StopRegionCheck",
    "Verdict",
    "build_monitor",
    "protective_separation",
    "safe_speed_scale",
]
