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


# --------------------------------------------------------------------------- camera modes


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (["camera.height=1"], "'camera.height'"),  # segfaulted the AprilTag detector
        (["camera.height=2"], "'camera.height'"),
        (["camera.width=1", "camera.height=1"], "'camera.width'"),
        (["camera.width=641"], "'camera.width'"),
        (["camera.width=1280"], "'camera.height'"),  # 1280x480 is no mode
        (["camera.width=1920", "camera.height=1080"], "'camera.width'"),  # colour, not depth
        (["camera.width=1280", "camera.height=720", "camera.fps=60"], "'camera.fps'"),
        (["camera.fps=90"], "'camera.fps'"),
        (
            ["camera.bag=r.bag", "camera.width=1920", "camera.height=1080", "camera.fps=60"],
            "'camera.fps'",
        ),
    ],
)
def test_camera_modes_are_the_d435is(overrides, key):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=overrides)
    message = str(err.value)
    assert key in message
    assert "424x240@6/15/30/60" in message and "1280x720@6/15/30" in message  # the valid modes
    assert "\n" not in message


@pytest.mark.parametrize(
    "overrides",
    [
        ["camera.width=424", "camera.height=240", "camera.fps=60"],
        ["camera.width=848", "camera.height=480", "camera.fps=6"],
        ["camera.width=1280", "camera.height=720", "camera.fps=30"],
        # a recording's depth is aligned to its colour whatever its size
        ["camera.bag=r.bag", "camera.width=1920", "camera.height=1080", "camera.fps=30"],
        ["camera.bag=r.bag", "camera.width=320", "camera.height=180", "camera.fps=60"],
    ],
)
def test_every_d435i_mode_is_accepted(overrides):
    config = load_config(overrides=overrides)
    w, h, fps = (int(o.split("=")[1]) for o in overrides[-3:])
    assert (config.camera.width, config.camera.height, config.camera.fps) == (w, h, fps)


# --------------------------------------------------------------------------- finite, ranges


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("robot.moving_time=inf", "'robot.moving_time'"),
        ("robot.moving_time=nan", "'robot.moving_time'"),
        ("runtime.join_timeout_s=inf", "'runtime.join_timeout_s'"),
        ("runtime.join_timeout_s=1e300", "'runtime.join_timeout_s'"),
        ("runtime.stale_s=1e300", "'runtime.stale_s'"),
        ("tag.offset_ee=[nan, 0.0, 0.03]", "'tag.offset_ee.0'"),
        ("grab.safe_pose=[0.1, inf, 0.65]", "'grab.safe_pose.1'"),
        ("calibration.phase2_heights=[0.1, nan]", "'calibration.phase2_heights.1'"),
        ("follow.height_offset=-inf", "'follow.height_offset'"),
        ("follow.duration_s=1e12", "'follow.duration_s'"),
        ("fusion.adaptive_threshold=1e300", "'fusion.adaptive_threshold'"),
        ("fusion.max_rejections=99999999999", "'fusion.max_rejections'"),
        ("tag.id=587", "'tag.id'"),  # tag36h11 has 587 codes, 0..586
        ("tag.family='tag16h5'", "'tag.id'"),  # 96 is no tag16h5 id
        ("grab.timeout_s=1e300", "'grab.timeout_s'"),
    ],
)
def test_values_are_finite_and_bounded(override, key):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=[override])
    assert key in str(err.value)


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (["sim.depth_min=3.5"], "'sim.depth_max'"),  # default depth_max 3.0
        (["sim.depth_min=1.0", "sim.depth_max=1.0"], "'sim.depth_max'"),
        (["ui.depth_min_m=2.5"], "'ui.depth_max_m'"),  # default depth_max_m 2.0
        (["sim.min_objects=3", "sim.max_objects=2"], "'sim.max_objects'"),
        (["sim.min_objects=4", "sim.max_objects=3"], "'sim.max_objects'"),
        (["robot.moving_time=0.5"], "'robot.accel_time'"),  # default accel 0.3 > half of it
        (["fusion.confirm_hits=6"], "'fusion.confirm_window'"),
        (
            ["sim.camera_distance=0.5", "sim.camera_distance_jitter=0.3"],
            "'sim.camera_distance_jitter'",
        ),
        (["sim.camera_height=0.02"], "'sim.camera_height_jitter'"),  # default jitter 0.05
    ],
)
def test_min_max_pairs_are_ordered(overrides, key):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=overrides)
    assert key in str(err.value)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("sim.depth_noise=1", "'sim.depth_noise'"),
        ("runtime.tag_detection=0", "'runtime.tag_detection'"),
        ("tag.id=true", "'tag.id'"),
        ("robot.moving_time=true", "'robot.moving_time'"),
        ("camera.fps=true", "'camera.fps'"),
        ("camera.serial=true", "'camera.serial'"),
        ("tag.offset_ee=[true, 0.0, 0.0]", "'tag.offset_ee.0'"),
        ("tag.id=3.0", "'tag.id'"),
        ("camera.fps=30.0", "'camera.fps'"),
        ("robot.group_name=3", "'robot.group_name'"),
    ],
)
def test_booleans_and_numbers_are_not_interchangeable(override, key):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=[override])
    assert key in str(err.value)


def test_ints_stand_for_floats_and_toml_lists_for_tuples(tmp_path):
    path = tmp_path / "ints.toml"
    path.write_text("[robot]\nmoving_time = 3\n[grab]\nsafe_pose = [0, 0, 1]\n")
    config = load_config(path, ["tag.offset_ee=[0, 0, 0]", "sim.depth_max=4"])
    assert config.robot.moving_time == 3.0 and isinstance(config.robot.moving_time, float)
    assert config.grab.safe_pose == (0.0, 0.0, 1.0)
    assert config.tag.offset_ee == (0.0, 0.0, 0.0) and config.sim.depth_max == 4.0


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("calibration.file=", "'calibration.file'"),
        ('calibration.file=""', "'calibration.file'"),
        ('calibration.file="a\\u0000b"', "'calibration.file'"),  # open() would raise
        ('camera.bag=""', "'camera.bag'"),
        ('robot.group_name=""', "'robot.group_name'"),
        ('ui.host=""', "'ui.host'"),
        ('ui.token="a\\nb"', "'ui.token'"),
        ('ui.allowed_hosts=[""]', "'ui.allowed_hosts.0'"),
    ],
)
def test_strings_are_usable(override, key):
    with pytest.raises(ConfigError) as err:
        load_config(overrides=[override])
    assert key in str(err.value) and "\n" not in str(err.value)


def test_file_that_is_not_utf8_or_has_a_huge_number(tmp_path):
    latin = tmp_path / "latin1.toml"
    latin.write_bytes(b'[ui]\ntoken = "caf\xe9"\n')
    with pytest.raises(ConfigError, match=r"latin1\.toml is not valid UTF-8") as err:
        load_config(latin)
    assert "\n" not in str(err.value)
    huge = tmp_path / "huge.toml"
    huge.write_text("[tag]\nid = " + "9" * 5000 + "\n")
    with pytest.raises(ConfigError, match=r"huge\.toml"):
        load_config(huge)
    with pytest.raises(ConfigError, match=r"'tag\.id'"):
        load_config(overrides=["tag.id=" + "9" * 5000])


def test_override_values_stay_on_one_line_and_keys_have_no_empty_parts():
    with pytest.raises(ConfigError, match="one line"):
        load_config(overrides=["robot.moving_time=1\nrobot.accel_time=0.1"])
    for bad in ("robot..moving_time=1", ".moving_time=1", "robot.=1"):
        with pytest.raises(ConfigError, match="empty"):
            load_config(overrides=[bad])
