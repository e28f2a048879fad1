"""The reflex room: what the arm does in the moments before a replan lands. The virtual forces of the GPU
potential-field paper (Kinect point clouds on a KUKA LWR), the convolution kernels of Baumgartner and Klančar, and the
swerve that uses them."""

from .forces import ForceField, VertexModel, VoxelMapBuilder, brute_force
from .swerve import Reflex

__all__ = ["ForceField", "Reflex", "VertexModel", "VoxelMapBuilder", "brute_force"]
