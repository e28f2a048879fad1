"""The fast layer of the collision checker: spheres that cover the robot, the convex shapes FCL is given, compiled;
what they cannot decide for certain goes to the exact checker."""

from .checker import FastChecker

__all__ = ["FastChecker"]
