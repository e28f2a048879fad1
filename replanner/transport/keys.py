"""Key expressions: everything of one robot lives under `<namespace>/@v1/<robot>/`."""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import InvalidInputError

VERSION = "@v1"
_CHUNK = re.compile(r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")


@dataclass(frozen=True)
class Keys:
    """The keys of one robot's service. `namespace` may have several chunks (e.g. "lab/cell3")."""

    robot: str
    namespace: str = "replanner"

    def __post_init__(self) -> None:
        for name, value in (("robot", self.robot), ("namespace", self.namespace)):
            if not isinstance(value, str) or not _CHUNK.match(value):
                raise InvalidInputError(f"{name} {value!r} must be letters, digits, '_' or '-' (chunks split by '/')")

    @property
    def root(self) -> str:
        return f"{self.namespace}/{VERSION}/{self.robot}"

    def __getattr__(self, item: str) -> str:  # keys.goal, keys.scene_add -> ".../goal", ".../scene/add"
        if item.startswith("_") or item not in KEYS:
            raise AttributeError(item)
        return f"{self.root}/{KEYS[item]}"

    def cloud(self, sensor: str) -> str:
        return f"{self.root}/clouds/{sensor}"


# name -> suffix; queryables (requests) first, then streams
KEYS = {
    "goal": "goal",
    "cancel": "cancel",
    "state": "state",
    "scene_add": "scene/add",
    "scene_move": "scene/move",
    "scene_remove": "scene/remove",
    "scene_attach": "scene/attach",
    "scene_detach": "scene/detach",
    "scene_list": "scene/list",
    "map_get": "map/get",
    "map_clear": "map/clear",
    "status": "status",
    "transitions": "transitions",
    "results": "results",
    "trajectory": "trajectory",
    "joint_states": "joint_states",
    "clouds": "clouds/*",
    "alive": "alive",
    "rejections": "rejections",
    "latency": "latency",
}


# the simulated cell's keys, under a robot's root: what clients of `replanner sim` talk to (streams: truth,
# bodies; queries: gripper, state); here so that the secure profile's rules can name them
SIM_KEYS = ("truth", "bodies", "gripper", "state")


def sim_keys(root: str) -> dict[str, str]:
    """`<root>/sim/<name>` for each of SIM_KEYS; `root` as in `Keys.root`."""
    return {k: f"{root}/sim/{k}" for k in SIM_KEYS}
