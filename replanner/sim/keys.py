"""The simulated cell's key expressions, under a robot's root: what clients of `replanner sim` talk to."""

from __future__ import annotations

SIM_KEYS = ("truth", "bodies", "gripper", "state")  # streams: truth, bodies; queries: gripper, state


def sim_keys(root: str) -> dict[str, str]:
    """`<root>/sim/<name>` for each of SIM_KEYS; `root` as in `Keys.root`."""
    return {k: f"{root}/sim/{k}" for k in SIM_KEYS}
