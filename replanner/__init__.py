"""replanner: reactive replanning for robot arms that work next to people.

The library takes plain arguments; services (the `replanner` command) read config files and open sessions.
"""

from .collision import Clearance, CollisionChecker, Contact, PathCheck
from .config import ReplannerConfig, load_config, parse_config
from .errors import (
    ConfigError,
    InvalidInputError,
    ReplannerError,
    RobotModelError,
    UnknownNameError,
    WorldError,
)
from .geometry import Box, Cylinder, Mesh, Sphere
from .occupancy import OccupancyMap
from .robot import JointLimits, RobotModel
from .transforms import make_transform
from .world import World

__version__ = "0.1.0"

__all__ = [
    "Box",
    "Clearance",
    "CollisionChecker",
    "ConfigError",
    "Contact",
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
    "UnknownNameError",
    "World",
    "WorldError",
    "load_config",
    "make_transform",
    "parse_config",
]
