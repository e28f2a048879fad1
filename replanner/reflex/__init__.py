"""The reflex room (issue 16): seed 000's virtual forces and seed 001's kernels, and the swerve that uses them."""

from .forces import ForceField, VertexModel, VoxelMapBuilder, brute_force
from .swerve import Reflex

__all__ = ["ForceField", "Reflex", "VertexModel", "VoxelMapBuilder", "brute_force"]
