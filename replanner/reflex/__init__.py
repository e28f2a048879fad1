"""The reflex room (issue 16): seed 000's virtual forces from a voxel map on a vertex model of the robot."""

from .forces import ForceField, VertexModel, VoxelMapBuilder, brute_force

__all__ = ["ForceField", "VertexModel", "VoxelMapBuilder", "brute_force"]
