"""write_snapshot: the files a person looks at, and that they agree with the world's truth."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from armvision.bench.snapshot import false_colour_depth, write_snapshot
from armvision.config import Config
from armvision.errors import SimulationError
from armvision.robot.kinematics import VX300S, fk
from armvision.sim.scene import generate_scene


def test_snapshot_writes_colour_depth_and_ground_truth(tmp_path: Path) -> None:
    record = write_snapshot(Config(), 3, tmp_path / "snap")
    out = tmp_path / "snap"
    color = cv2.imread(str(out / "color.png"))
    depth_vis = cv2.imread(str(out / "depth.png"))
    depth_mm = cv2.imread(str(out / "depth_mm.png"), cv2.IMREAD_UNCHANGED)
    assert color.shape == depth_vis.shape == (480, 640, 3)
    assert depth_mm.dtype == np.uint16 and depth_mm.shape == (480, 640)
    assert 300 < np.median(depth_mm[depth_mm > 0]) < 2000  # the table, in millimetres
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth == json.loads(json.dumps(record))
    assert truth["seed"] == 3 and truth["pose"] == "home"
    assert np.array(truth["joint_positions"]) == pytest.approx(VX300S.home, abs=1e-3)
    assert np.array(truth["T_base_ee"]) == pytest.approx(fk(VX300S.home), abs=1e-3)
    scene = generate_scene(Config(), 3)
    assert [o["name"] for o in truth["objects"]] == [o.name for o in scene.objects]
    assert [o["fill"] for o in truth["objects"]] == [o.fill for o in scene.objects]
    assert truth["intrinsics"]["fx"] == pytest.approx(615.0)


def test_false_colour_depth_marks_missing_depth_black() -> None:
    depth = np.array([[0.0, 0.5, 1.9]], dtype=np.float32)
    rgb = false_colour_depth(depth)
    assert rgb.shape == (1, 3, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].tolist() == [0, 0, 0]
    assert rgb[0, 1].tolist() != rgb[0, 2].tolist()


def test_unwritable_output_directory_is_a_clear_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(SimulationError, match="output directory"):
        write_snapshot(Config(), 0, blocker / "snap")
