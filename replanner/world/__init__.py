"""The world room: what the robot moves among. Static and attached objects (the `World`, edited copy-on-write), the
occupancy map of one moment and its voxel volume."""

from .occupancy import OccupancyMap
from .scene import Attachment, World, WorldObject, WorldSnapshot
from .volume import VoxelVolume

__all__ = ["Attachment", "OccupancyMap", "VoxelVolume", "World", "WorldObject", "WorldSnapshot"]
