"""replanner: reactive replanning for robot arms that work next to people.

The library takes plain arguments; services (the `replanner` command) read config files and open sessions.
"""

from .config import ReplannerConfig, load_config, parse_config
from .errors import ConfigError, InvalidInputError, ReplannerError, RobotModelError, UnknownNameError, WorldError
from .world.collision import Clearance, CollisionChecker, Contact, PathCheck
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
