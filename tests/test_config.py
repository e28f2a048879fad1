"""Bad configuration files fail with a message that names the field, the file and what is allowed."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

from replanner.config import ReplannerConfig, load_config
from replanner.errors import ConfigError, RobotModelError, UnknownNameError
from replanner.model.robot import RobotModel
from replanner.sim.config import load_cell_config
from tests.conftest import CONFIGS


def _write(tmp_path, data) -> str:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return str(path)


@pytest.fixture
def panda_dict():
    return yaml.safe_load((CONFIGS / "panda.yaml").read_text())


@pytest.mark.parametrize("name", ["panda.yaml", "iiwa.yaml"])
def test_shipped_profiles_load(name):
    cfg = load_config(CONFIGS / name)
    robot = RobotModel.from_config(cfg.robot)
    assert robot.dof == 7 and len(robot.limits.jerk) == 7
    assert load_config(name.removesuffix(".yaml")) == cfg  # a profile by name, from any directory


def test_the_cell_config_is_the_service_config_plus_sim():
    cell = load_cell_config("demo")
    assert cell.sim.task.bins == ("bin_a", "bin_b")
    assert type(cell.core()) is ReplannerConfig and "sim" not in cell.core().model_dump()
    with pytest.raises(ConfigError, match="load_cell_config"):
        load_config("demo")  # the service's schema names the sim section's reader


def test_override_validates_and_names_the_field():
    cfg = load_config("panda")
    assert cfg.override({"collision": {"padding": 0.0}}).collision.padding == 0.0
    assert cfg.collision.padding == 0.01  # a copy
    with pytest.raises(ConfigError, match=r"collision\.padding"):
        cfg.override({"collision": {"padding": -1}})
    with pytest.raises(ConfigError, match="unknown field 'pading'"):
        cfg.override({"collision": {"pading": 0.0}})


def test_unknown_profile_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="panda"):
        load_config("pandas")


def test_unknown_field_names_field_file_and_allowed_fields(tmp_path, panda_dict):
    panda_dict["robot"]["velocity_limit"] = panda_dict["robot"].pop("velocity_limits")
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert path in msg
    assert "robot.velocity_limit" in msg and "unknown field" in msg
    assert "velocity_limits" in msg  # the allowed names are listed


def test_unknown_section(tmp_path, panda_dict):
    panda_dict["colision"] = {}
    with pytest.raises(ConfigError, match=r"colision.*allowed fields here: robot, collision"):
        load_config(_write(tmp_path, panda_dict))


def test_negative_limit_names_the_entry(tmp_path, panda_dict):
    panda_dict["robot"]["jerk_limits"][2] = -5.0
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert path in msg and "robot.jerk_limits" in msg and "entry 2 is -5.0" in msg and "> 0" in msg


def test_missing_urdf_names_the_file_and_how_to_write_it(tmp_path, panda_dict):
    panda_dict["robot"]["urdf"] = "robots/nothing_here.urdf"
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert path in msg and "robot.urdf" in msg and "nothing_here.urdf" in msg and "pybullet_data://" in msg


def test_relative_urdf_path_is_relative_to_the_config_file(tmp_path, panda_dict):
    import pybullet_data

    shutil.copytree(f"{pybullet_data.getDataPath()}/franka_panda", tmp_path / "franka")
    panda_dict["robot"]["urdf"] = "franka/panda.urdf"
    cfg = load_config(_write(tmp_path, panda_dict))
    assert cfg.robot.urdf == str(tmp_path / "franka" / "panda.urdf")
    assert RobotModel.from_config(cfg.robot).dof == 7


def test_wrong_lengths(tmp_path, panda_dict):
    panda_dict["robot"]["acceleration_limits"] = [1.0, 2.0]
    with pytest.raises(ConfigError, match=r"one entry per active joint.*acceleration=2"):
        load_config(_write(tmp_path, panda_dict))


@pytest.mark.parametrize(
    "section,key,value,expect",
    [
        ("collision", "padding", -0.01, "collision.padding"),
        ("collision", "padding", "lots", "collision.padding"),
        ("collision", "path_resolution", 0, "collision.path_resolution"),
        ("collision", "geometry", "spheres", "collision.geometry"),
        ("robot", "tip_link", None, "robot.tip_link"),
    ],
)
def test_bad_values(tmp_path, panda_dict, section, key, value, expect):
    panda_dict[section][key] = value
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert expect in str(err.value) and path in str(err.value)


def test_missing_required_field(tmp_path, panda_dict):
    del panda_dict["robot"]["jerk_limits"]
    with pytest.raises(ConfigError, match=r"robot.jerk_limits: required field is missing"):
        load_config(_write(tmp_path, panda_dict))


def test_not_yaml_and_not_a_file(tmp_path):
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(_write(tmp_path, "robot: [unclosed"))
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="top level must be a mapping"):
        load_config(_write(tmp_path, "- just\n- a list\n"))


def test_unknown_link_and_joint_names_list_the_valid_ones(tmp_path, panda_dict):
    panda_dict["robot"]["tip_link"] = "panda_flange"
    cfg = load_config(_write(tmp_path, panda_dict))
    with pytest.raises(UnknownNameError) as err:
        RobotModel.from_config(cfg.robot)
    assert "panda_flange" in str(err.value) and "panda_hand" in str(err.value)
    panda_dict["robot"]["tip_link"] = "panda_hand"
    panda_dict["robot"]["joints"][3] = "panda_joint44"
    cfg = load_config(_write(tmp_path, panda_dict))
    with pytest.raises(UnknownNameError, match="panda_joint44.*panda_joint4"):
        RobotModel.from_config(cfg.robot)


def test_bad_self_collision_pair_and_allowed_contact(tmp_path, panda_dict, panda):
    panda_dict["robot"]["self_collision"]["allowed_pairs"] = [["panda_link5", "panda_link77"]]
    cfg = load_config(_write(tmp_path, panda_dict))
    with pytest.raises(UnknownNameError, match="panda_link77"):
        RobotModel.from_config(cfg.robot)


def test_broken_urdf_is_a_robot_model_error(tmp_path, panda_dict):
    bad = tmp_path / "bad.urdf"
    bad.write_text("this is not XML <<<")
    panda_dict["robot"]["urdf"] = str(bad)
    cfg = load_config(_write(tmp_path, panda_dict))
    with pytest.raises(RobotModelError, match="bad.urdf"):
        RobotModel.from_config(cfg.robot)


def test_config_models_are_frozen(panda_cfg):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="frozen"):
        panda_cfg.collision.padding = 0.5
    assert np.isclose(panda_cfg.collision.padding, 0.01)


def test_perception_section_loads_with_two_sensors(panda_cfg):
    p = panda_cfg.perception
    assert [s.name for s in p.sensors] == ["front", "side"] and p.resolution == 0.01


@pytest.mark.parametrize(
    "edit,expect",
    [
        (lambda p: p["sensors"][0].pop("fov_y_deg"), "either fov_y_deg or fx and fy"),
        (lambda p: p["sensors"][0]["pose"].pop("look_at"), "exactly one of quat_xyzw"),
        (lambda p: p["sensors"][0].update(width=-640), "perception.sensors[0].width"),
        (lambda p: p["sensors"][1].update(name="front"), "sensor names must be unique"),
        (lambda p: p["workspace"].update(min=[2.0, -1.0, 0.0]), "must be below max"),
        (lambda p: p.update(resolution=0.002), "max_cells"),
        (lambda p: p["outliers"].update(method="median"), "perception.outliers.method"),
        (lambda p: p["occupancy"].update(miss=0.4), "perception.occupancy.miss"),
        (lambda p: p["sensors"][0].update(min_range=5.0), "must exceed min_range"),
    ],
)
def test_bad_perception_configs(tmp_path, panda_dict, edit, expect):
    edit(panda_dict["perception"])
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert expect in str(err.value) and path in str(err.value), str(err.value)


@pytest.mark.parametrize(
    "operator,expect",
    [
        ({"linger": [2.0, 1.0]}, "linger must be [min, max]"),
        ({"lead_time": [-0.5, 1.0]}, "lead_time must be [min, max]"),
        ({"reach_region": [[0.6, 0.4, 0.1], [0.9, -0.4, 0.5]]}, "reach_region must be"),
        ({"goal_margin": -0.1}, "sim.operator.goal_margin"),
    ],
)
def test_bad_operator_script(tmp_path, panda_dict, operator, expect):
    panda_dict["sim"] = {"operator": operator}
    path = _write(tmp_path, panda_dict)
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    assert expect in str(err.value) and "sim.operator" in str(err.value) and path in str(err.value)
