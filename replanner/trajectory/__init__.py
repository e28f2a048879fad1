"""The trajectory room: curves around planned paths, jerk-limited time laws, splicing, braking, sampled motions."""

from ..errors import TrajectoryError
from .curve import distance_to_polyline, progress_along
from .generator import TimingReport, Trajectory, TrajectoryGenerator
from .sampled import SampledTrajectory
from .timelaw import Limits, PieceTimingError

__all__ = [
    "Limits",
    "PieceTimingError",
    "SampledTrajectory",
    "TimingReport",
    "Trajectory",
    "TrajectoryError",
    "TrajectoryGenerator",
    "distance_to_polyline",
    "progress_along",
]
