"""The armvision command as a user runs it: help, info, config, and one-line errors."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

from armvision.config import load_config

ARMVISION = [sys.executable, "-m", "armvision.cli"]


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "ARMVISION_CONFIG"}
    return subprocess.run(
        [*ARMVISION, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120
    )


def test_help_lists_the_commands():
    result = run("--help")
    assert result.returncode == 0
    assert "info" in result.stdout and "config" in result.stdout


def test_info_reports_every_backend_with_a_reason(tmp_path):
    result = run("info", "--json", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    from armvision import __version__

    assert report["version"] == __version__
    backends = {b["name"]: b for b in report["backends"]}
    assert set(backends) == {"mujoco", "realsense", "interbotix", "dynamixel"}
    for backend in backends.values():
        assert backend["detail"]  # a one-line reason either way
    # make setup installs MuJoCo and the EGL libraries, so rendering must work.
    assert backends["mujoco"]["usable"], backends["mujoco"]["detail"]
    has_ros = all(importlib.util.find_spec(m) for m in ("rclpy", "interbotix_xs_modules"))
    assert backends["interbotix"]["usable"] == has_ros
    if not has_ros:
        assert "source /opt/ros/humble/setup.bash" in backends["interbotix"]["detail"]
    text = run("info", cwd=tmp_path)
    assert text.returncode == 0 and "mujoco" in text.stdout


def test_info_without_pyrealsense2_says_what_to_do_for_the_machine(monkeypatch):
    from armvision.cli import info

    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # makes `import pyrealsense2` fail
    for machine, expected in [
        ("x86_64", "pyrealsense2 not installed: pip install 'armvision[realsense]'"),
        ("aarch64", "aarch64 wheels cover some Python versions only"),
    ]:
        monkeypatch.setattr(info.platform, "machine", lambda m=machine: m)
        status = info.check_realsense()
        assert not status.usable
        assert expected in status.detail
    assert "-DBUILD_PYTHON_BINDINGS=ON" in status.detail


def test_config_prints_loadable_toml_with_overrides(tmp_path):
    result = run("--set", "tag.id=12", "--set", "robot.moving_time=1.25", "config", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    saved = tmp_path / "armvision.toml"
    saved.write_text(result.stdout)
    config = load_config(saved)
    assert config.tag.id == 12 and config.robot.moving_time == 1.25


def test_errors_are_one_line_without_traceback(tmp_path):
    result = run("--set", "tag.idd=3", "info", cwd=tmp_path)
    assert result.returncode == 2
    assert "unknown key 'tag.idd'" in result.stderr
    assert "Traceback" not in result.stderr
    missing = run("--config", str(tmp_path / "nope.toml"), "config", cwd=tmp_path)
    assert missing.returncode == 2 and "nope.toml does not exist" in missing.stderr


def test_a_camera_mode_the_d435i_lacks_is_a_config_error_not_a_crash(tmp_path):
    # camera.height 1 or 2 used to segfault the AprilTag detector (exit status 139, no message).
    result = run("--set", "camera.height=1", "perceive", "--out", str(tmp_path / "p"), cwd=tmp_path)
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert "'camera.height'" in result.stderr and "640x480@6/15/30/60" in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.splitlines()) == 1


def test_usage_errors_are_one_line_in_a_real_process(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[tag]\n")
    result = run("--config", str(bad), "info", cwd=tmp_path)
    assert result.returncode == 2 and "not valid UTF-8" in result.stderr
    port = run("ui", "--port", "70000", cwd=tmp_path)  # used to listen on 4464 (wrapped)
    assert port.returncode == 2 and "argument --port" in port.stderr
    for failed in (result, port):
        assert len(failed.stderr.splitlines()) == 1 and "Traceback" not in failed.stderr


def test_profile_selects_the_simulated_scenes_of_every_evaluation() -> None:
    from armvision.cli.main import PROFILED_EVALS, build_parser, overrides
    from armvision.config import load_config

    parser = build_parser()
    for name in PROFILED_EVALS:
        args = parser.parse_args(
            ["--set", "sim.profile=default", "eval", name, "--profile", "cluttered"]
        )
        assert load_config(None, overrides(args)).sim.profile == "cluttered"
        args = parser.parse_args(["eval", name])
        assert load_config(None, overrides(args)).sim.profile == "default"
