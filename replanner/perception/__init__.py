"""Point clouds to a live, self-filtered, self-clearing occupancy map."""

from .camera import CameraModel, look_at, pose_from_config
from .pipeline import CloudFrame, CloudRejected, FrameReport, Perception

__all__ = ["CameraModel", "CloudFrame", "CloudRejected", "FrameReport", "Perception", "look_at", "pose_from_config"]
