"""replanner: reactive replanning for robot arms that work next to people.

The rooms, in pipeline order: perception → world → monitor → planning → trajectory → control, built together by
`replanner.stack.build_stack(cfg)`; transport holds the wire formats. This top level holds the light part: the
config, the errors and the world (robot model, scene, collision checker). The library takes plain arguments;
services (the `replanner` command) read config files and open sessions.
"""

from .config import ReplannerConfig, load_config, parse_config
from .errors import (
    ConfigError,
    InvalidInputError,
    ReplannerError,
    RobotModelError,
    TrajectoryError,
    UnknownNameError,
    WorldError,
)
from .world.collision import Clearance, CollisionChecker, Contact, ContactKind, PathCheck
from .world.geometry import Box, Cylinder, Mesh, Sphere
from .world.occupancy import OccupancyMap
from .world.robot import JointLimits, RobotModel
from .world.scene import World
from .world.transforms import make_transform

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
