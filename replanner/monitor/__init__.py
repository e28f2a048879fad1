"""The monitor room: checks of the remaining motion (map, scene, safety distance, stop region), typed verdicts."""

from .checks import Check, MapPathCheck, MotionView, SafetyDistanceCheck, ScenePathCheck, StopRegionCheck, Verdict
from .monitor import Monitor, MonitorStats, Report, build_monitor

__all__ = [
    "Check",
    "MapPathCheck",
    "Monitor",
    "MonitorStats",
    "MotionView",
    "Report",
    "SafetyDistanceCheck",
    "ScenePathCheck",
    "StopRegionCheck",
    "Verdict",
    "build_monitor",
]
