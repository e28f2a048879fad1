"""replanner: reactive replanning for robot arms that work next to people.

The rooms, in pipeline order: perception → world → monitor → planning → trajectory → control, built together by
`replanner.stack.build_stack(cfg)`, all standing on model (robot, kinematics) and collision (one Checker); transport
holds the wire formats. This top level holds the light part: the config, the errors, the robot model, the world and
the collision checker. The library takes plain arguments; services (the `replanner` command) read config files and
open sessions.
"""

from .cache_dirs import use_kernel_cache

use_kernel_cache()  # before any kernel is defined: numba reads its cache directory then

from .collision import Clearance, CollisionChecker, Contact, ContactKind, PathCheck  # noqa: E402
from .config import ReplannerConfig, load_config, parse_config  # noqa: E402
from .errors import (  # noqa: E402
    ConfigError,
    InvalidInputError,
    ReplannerError,
    RobotModelError,
    TrajectoryError,
    UnknownNameError,
    WorldError,
)
from .model import Box, Cylinder, JointLimits, Mesh, RobotModel, Sphere, make_transform  # noqa: E402
from .world import OccupancyMap, World  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "Box",
    "Clearance",
    "CollisionChecker",
    "ConfigError",
    "Contact",
    "ContactKind",
    "Cylinder",
    "InvalidInputError",
    "JointLimits",
    "Mesh",
    "OccupancyMap",
    "PathCheck",
    "ReplannerConfig",
    "ReplannerError",
    "RobotModel",
    "RobotModelError",
    "Sphere",
    "TrajectoryError",
    "UnknownNameError",
    "World",
    "WorldError",
    "load_config",
    "make_transform",
    "parse_config",
]
