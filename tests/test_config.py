"""Configuration: the paper's defaults, TOML, CLI overrides, and errors that name the key."""

from __future__ import annotations

import pytest

from armvision.config import Config, config_to_toml, known_keys, load_config
from armvision.errors import ConfigError


@pytest.fixture(autouse=True)
def no_ambient_config(monkeypatch, tmp_path):
    monkeypatch.delenv("ARMVISION_CONFIG", raising=False)
    monkeypatch.chdir(tmp_path)  # no ./armvision.toml


def test_defaults_are_the_papers_values():
    config = load_config()
    assert config == Config()
    assert (config.tag.family, config.tag.id) == ("tag36h11", 96)
    assert config.tag.offset_ee == (-0.1, 0.0, 0.03)
    assert (config.camera.width, config.camera.height, config.camera.fps) == (640, 480, 30)
    assert (config.robot.moving_time, config.robot.accel_time) == (2.0, 0.3)


def test_toml_file_then_overrides(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text("[tag]\nid = 7\nsize = 0.05\n[robot]\nmoving_time = 3.0\n")
    config = load_config(
        path,
        ["robot.moving_time=1.5", "tag.offset_ee=[-0.09, 0.0, 0.04]", "camera.serial=123456789012"],
    )
    assert config.tag.id == 7 and config.tag.size == 0.05
    assert config.robot.moving_time == 1.5
    assert config.tag.offset_ee == (-0.09, 0.0, 0.04)
    assert config.camera.serial == "123456789012"


def test_environment_variable_and_local_file_are_found(tmp_path, monkeypatch):
    (tmp_path / "armvision.toml").write_text("[tag]\nid = 3\n")
    assert load_config().tag.id == 3
    other = tmp_path / "other.toml"
    other.write_text("[tag]\nid = 4\n")
    monkeypatch.setenv("ARMVISION_CONFIG", str(other))
    assert load_config().tag.id == 4


def test_round_trip_through_toml(tmp_path):
    config = load_config(overrides=["tag.id=5", "robot.accel_time=0.1", "camera.bag=run.bag"])
    path = tmp_path / "saved.toml"
    path.write_text(config_to_toml(config))
    assert load_config(path) == config


@pytest.mark.parametrize(
    ("override", "names"),
    [
        ("tag.sise=0.05", "unknown key 'tag.sise'"),
        ("camera.fps=25", "'camera.fps'"),
        ("robot.moving_time=-1", "'robot.moving_time'"),
        ("robot.accel_time=1.5", "'robot.accel_time'"),
        ("tag.id=abc", "'tag.id'"),
        ("tag.offset_ee=[1, 2]", "'tag.offset_ee"),
        ("robot.gripper_pressure=2", "'robot.gripper_pressure'"),
        ("lighting.lux=3", "unknown key 'lighting'"),
    ],
)
def test_bad_values_and_unknown_keys_name_the_key(override, names):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=[override])
    assert names in str(err.value)


def test_unknown_key_lists_the_known_ones(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text("[robot]\nmovingtime = 1.0\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    message = str(err.value)
    assert str(path) in message and "robot.movingtime" in message
    assert all(key in message for key in known_keys())


def test_file_problems_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[tag\nid = 96\n")
    with pytest.raises(ConfigError, match=r"broken\.toml is not valid TOML"):
        load_config(broken)


def test_malformed_override():
    with pytest.raises(ConfigError, match=r"section\.key=value"):
        load_config(overrides=["robot.moving_time"])
    with pytest.raises(ConfigError, match="is a value, not a section"):
        load_config(overrides=["tag.id=3", "tag.id.x=1"])


def test_config_is_frozen():
    config = load_config()
    with pytest.raises(Exception):  # noqa: B017 - pydantic's frozen error type varies by version
        config.tag.id = 3
