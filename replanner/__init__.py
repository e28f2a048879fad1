"""replanner: reactive replanning for robot arms that work next to people.

The rooms, in pipeline order: perception → world → monitor → planning → trajectory → control, built together by
`replanner.stack.build_stack(cfg)`; transport holds the wire formats. This top level holds the light part: the
config, the errors and the world (robot model, scene, collision checker). The library takes plain arguments;
services (the `replanner` command) read config files and open sessions.
"""

from .cache_dirs import use_kernel_cache

use_kernel_cache()  # before any kernel is defined: numba reads its cache directory then

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
from .world.collision import Clearance, CollisionChecker, Contact, ContactKind, PathCheck  # noqa: E402
from .world.geometry import Box, Cylinder, Mesh, Sphere  # noqa: E402
from .world.occupancy import OccupancyMap  # noqa: E402
from .world.robot import JointLimits, RobotModel  # noqa: E402
from .world.scene import World  # noqa: E402
from .world.transforms import make_transform  # noqa: E402

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
