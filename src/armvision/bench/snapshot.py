"""``armvision sim snapshot``: one look at a simulated scene, for people.

Builds the scene for a seed, moves the arm to a pose, renders one RGB-D frame and writes

- ``color.png``: the colour image,
- ``depth.png``: depth in false colour (near red, far blue, no data black),
- ``depth_mm.png``: depth as 16-bit millimetres, like a RealSense recording,
- ``ground_truth.json``: true camera pose and intrinsics, ee and tag poses, joint angles,
  objects with their fill levels, as :meth:`SimWorld.ground_truth` reports them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.config import Config, config_to_dict
from armvision.errors import SimulationError
from armvision.sim.arm import SimArm
from armvision.sim.camera import SimCamera
from armvision.sim.world import SimWorld

DEPTH_COLOUR_RANGE_M = (0.3, 2.0)  # depths mapped onto the colour scale


def false_colour_depth(
    depth: NDArray[np.floating], depth_range: tuple[float, float] = DEPTH_COLOUR_RANGE_M
) -> NDArray[np.uint8]:
    """RGB (H, W, 3) picture of a depth image: turbo colour map, red near, 0 (no data) black."""
    lo, hi = depth_range
    scaled = np.clip((np.asarray(depth, dtype=float) - lo) / (hi - lo), 0.0, 1.0)
    grey = (255.0 * (1.0 - scaled)).astype(np.uint8)  # near = high = warm in TURBO
    bgr = cv2.applyColorMap(grey, cv2.COLORMAP_TURBO)
    bgr[np.asarray(depth) <= 0.0] = 0
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def _write_png(path: Path, image: NDArray[Any]) -> None:
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), image):
        raise SimulationError(f"could not write {path}: is the directory writable?")


def write_snapshot(
    config: Config,
    seed: int,
    out_dir: str | os.PathLike[str],
    pose: Literal["home", "sleep"] = "home",
) -> dict[str, Any]:
    """Render the scene for ``seed`` with the arm at ``pose`` and write the files to ``out_dir``.

    Returns the ground truth as written to ``ground_truth.json`` plus a ``files`` entry listing
    the paths written.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SimulationError(f"cannot create output directory {out}: {exc.strerror}") from None
    with SimWorld(config, seed) as world:
        arm = SimArm(world)
        moved = arm.go_to_home_pose() if pose == "home" else arm.go_to_sleep_pose()
        if not moved:  # pragma: no cover - home and sleep are always within limits
            raise SimulationError(f"the arm could not reach {pose}: {arm.last_error}")
        world.advance(0.5)  # let everything come to rest
        with SimCamera(world) as camera:
            frame = camera.read()
            truth = world.ground_truth()
        intr = frame.intrinsics
        files = {
            "color": out / "color.png",
            "depth": out / "depth.png",
            "depth_mm": out / "depth_mm.png",
            "ground_truth": out / "ground_truth.json",
        }
        _write_png(files["color"], frame.color)
        _write_png(files["depth"], false_colour_depth(frame.depth))
        depth_mm = np.round(frame.depth * 1000.0).astype(np.uint16)
        _write_png(files["depth_mm"], depth_mm)
        record: dict[str, Any] = {
            "seed": int(seed),
            "pose": pose,
            "frame_timestamp": frame.timestamp,
            "intrinsics": intr.to_dict(),
            "depth_unit_m": 0.001,
            **truth.to_dict(),
            "config": config_to_dict(config),
        }
        record["files"] = {k: str(v) for k, v in files.items()}
        with open(files["ground_truth"], "w", encoding="utf-8") as fh:
            json.dump(record, fh, indent=2)
    return record
