"""``armvision info`` and ``armvision config``: which backends work here, and the effective
configuration."""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from dataclasses import asdict, dataclass

from armvision import __version__
from armvision.config import (
    Config,
    config_to_toml,
    find_config_file,
)
from armvision.errors import ArmvisionError


@dataclass(frozen=True)
class BackendStatus:
    """Whether one backend can be used on this machine, and why (not)."""

    name: str
    usable: bool
    detail: str


# Rendering is probed in a child process: a broken GL stack can abort the interpreter, and
# MUJOCO_GL is read once, at import.
_MUJOCO_PROBE = """
import mujoco
model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size="0.1"/></worldbody></mujoco>')
renderer = mujoco.Renderer(model, 48, 64)
data = mujoco.MjData(model)
mujoco.mj_forward(model, data)
renderer.update_scene(data)
image = renderer.render()
renderer.close()
print(mujoco.__version__, image.shape[1], image.shape[0])
"""


def check_mujoco(timeout_s: float = 60.0) -> BackendStatus:
    """Can MuJoCo render offscreen here (the simulated camera needs it)?"""
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    try:
        result = subprocess.run(
            [sys.executable, "-c", _MUJOCO_PROBE],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return BackendStatus("mujoco", False, f"rendering test hung for {timeout_s:.0f} s")
    if result.returncode != 0:
        lines = (result.stderr or result.stdout).strip().splitlines()
        why = lines[-1] if lines else f"exit status {result.returncode}"
        if "No module named 'mujoco'" in why:
            return BackendStatus("mujoco", False, "not installed: pip install mujoco")
        return BackendStatus(
            "mujoco",
            False,
            f"cannot render with MUJOCO_GL={env['MUJOCO_GL']} ({why}); install libegl1 "
            "libgl1-mesa-dri (make setup does) or try MUJOCO_GL=osmesa",
        )
    version = result.stdout.split()[0]
    return BackendStatus(
        "mujoco",
        True,
        f"MuJoCo {version}, offscreen rendering with MUJOCO_GL={env['MUJOCO_GL']} works",
    )


def realsense_missing(machine: str) -> str:
    """Why the camera is unavailable when pyrealsense2 is not installed, and what to do.

    On aarch64 PyPI has pyrealsense2 wheels for some Python versions only (3.10 and 3.12, not
    3.11 or 3.13, when the README's table was made), and `make setup` leaves it out where pip
    finds none, so there the way out may be a source build."""
    if machine in ("aarch64", "arm64"):
        return (
            "pyrealsense2 not installed; PyPI's aarch64 wheels cover some Python versions only "
            "(`make check-wheels` lists them) and `make setup` leaves it out where there is "
            "none: pip install 'armvision[realsense]' on one of those, or build librealsense "
            "with -DBUILD_PYTHON_BINDINGS=ON"
        )
    return "pyrealsense2 not installed: pip install 'armvision[realsense]'"


def check_realsense() -> BackendStatus:
    """Is pyrealsense2 installed, and which cameras are connected?"""
    from armvision.camera.realsense import connected_devices

    try:
        version, devices = connected_devices()
    except ArmvisionError as exc:
        if str(exc).startswith("cannot use a RealSense camera:"):  # _import_rs: not importable
            why = realsense_missing(platform.machine())
        else:
            why = str(exc)
        return BackendStatus("realsense", False, why)
    if not devices:
        return BackendStatus(
            "realsense",
            False,
            f"pyrealsense2 {version} installed; no RealSense camera connected"
            " (plug it into a USB 3 port)",
        )
    found = [f"{d.name} serial {d.serial} on USB {d.usb_type or '?'}" for d in devices]
    return BackendStatus("realsense", True, f"pyrealsense2 {version}: " + "; ".join(found))


def check_interbotix() -> BackendStatus:
    """Are the Interbotix ROS 2 Python modules importable (needed for the real arm)?"""
    from armvision.robot.interbotix import interbotix_available

    usable, detail = interbotix_available()
    return BackendStatus("interbotix", usable, detail)


def check_dynamixel(config: Config) -> BackendStatus:
    """U2D2 ports and the arm's servo IDs 1-9 on them (the Dynamixel backend, no ROS)."""
    from armvision.robot.dynamixel import scan

    usable, detail = scan(baud_rate=config.robot.baud_rate)
    return BackendStatus("dynamixel", usable, detail)


def check_object_detector(config: Config) -> BackendStatus:
    """Which object detector the configuration chooses, and whether it can be built here."""
    from armvision.perception.factory import describe_detector

    usable, detail = describe_detector(config.perception)
    return BackendStatus("objects", usable, detail)


def cmd_info(args: argparse.Namespace, config: Config) -> int:
    statuses = [check_mujoco(), check_realsense(), check_interbotix(), check_dynamixel(config)]
    objects = check_object_detector(config)
    config_file = find_config_file(args.config)
    report = {
        "version": __version__,
        "python": platform.python_version(),
        "platform": f"{platform.system()} {platform.machine()}",
        "config": str(config_file) if config_file else "defaults",
        "backends": [asdict(s) for s in statuses],
        "objects": asdict(objects),
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"armvision {__version__} (Python {report['python']}, {report['platform']})")
    print(f"config: {report['config']}")
    width = max(len(s.name) for s in statuses)
    for s in statuses:
        print(f"  {s.name:<{width}}  {'yes' if s.usable else 'no ':<3}  {s.detail}")
    print(f"objects: {objects.detail}")
    return 0


def cmd_config(args: argparse.Namespace, config: Config) -> int:
    print(config_to_toml(config), end="")
    return 0
