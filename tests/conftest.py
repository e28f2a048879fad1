from __future__ import annotations

from pathlib import Path

import pytest

from replanner.config import load_config
from replanner.model.robot import RobotModel

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


@pytest.fixture(scope="session")
def panda_cfg():
    return load_config(CONFIGS / "panda.yaml")


@pytest.fixture(scope="session")
def iiwa_cfg():
    return load_config(CONFIGS / "iiwa.yaml")


@pytest.fixture(scope="session")
def panda(panda_cfg) -> RobotModel:
    return RobotModel.from_config(panda_cfg.robot)


@pytest.fixture(scope="session")
def iiwa(iiwa_cfg) -> RobotModel:
    return RobotModel.from_config(iiwa_cfg.robot)


@pytest.fixture(scope="session", params=["panda", "iiwa"])
def profile(request, panda_cfg, iiwa_cfg, panda, iiwa):
    """(config, robot) of each shipped profile."""
    return (panda_cfg, panda) if request.param == "panda" else (iiwa_cfg, iiwa)
