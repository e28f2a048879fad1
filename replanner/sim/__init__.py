"""Simulation with pybullet: scenes, depth cameras. Every function takes the pybullet client id explicitly."""
