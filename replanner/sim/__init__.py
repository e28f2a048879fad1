"""The simulated cell: pybullet physics, cameras, the operator, ground truth (entry points wire it to Zenoh)."""
