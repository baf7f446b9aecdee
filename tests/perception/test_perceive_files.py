"""`armvision perceive --color --depth`: perception on one saved RGB-D frame.

The loader (armvision.camera.files) reads back what was written in every depth format; every
bad input is a one-line error with exit status 2; a `sim snapshot` perceived from its files
finds what `perceive --sim` finds on the same seed; the JSON keys are the documented ones.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from armvision.camera.files import FrameFileError, load_depth, load_rgbd
from armvision.camera.frames import Intrinsics
from armvision.cli import main
from armvision.errors import ArmvisionError

H, W = 48, 64
INTR = "60,61,31.5,23.5"

#: The documented keys (README, "Perception on a saved frame"): they stay as they are.
TOP_KEYS = {"source", "tags", "detections", "image"}
SOURCE_KEYS = {
    "kind",
    "color",
    "depth",
    "depth_scale",
    "calibration",
    "joint_positions",
    "size",
    "intrinsics",
}
TAG_KEYS = {
    "id",
    "center",
    "corners",
    "T_cam_tag",
    "distance_m",
    "decision_margin",
    "pose_error_px",
    "depth_refined",
}
DETECTION_KEYS = {
    "label",
    "score",
    "box",
    "center_cam",
    "size",
    "radius",
    "height",
    "axis_cam",
    "fill",
    "fill_confidence",
    "liquid_colour",
    "fill_unknown",
}


@pytest.fixture(autouse=True)
def no_ambient_config(monkeypatch, tmp_path):
    monkeypatch.delenv("ARMVISION_CONFIG", raising=False)
    monkeypatch.chdir(tmp_path)  # no ./armvision.toml


def known_depth_mm() -> np.ndarray:
    """A depth in whole millimetres (so every format holds it exactly), with holes."""
    v, u = np.mgrid[0:H, 0:W]
    depth = (500 + 7 * u + 3 * v).astype(np.uint16)
    depth[5:9, 10:20] = 0
    return depth


def known_color() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


@pytest.fixture
def color_png(tmp_path) -> Path:
    path = tmp_path / "color.png"
    assert cv2.imwrite(str(path), cv2.cvtColor(known_color(), cv2.COLOR_RGB2BGR))
    return path


def write_depth(tmp_path: Path, kind: str) -> tuple[Path, float]:
    """The known depth in one format; its file and the --depth-scale to give."""
    mm = known_depth_mm()
    metres = mm.astype(np.float32) / np.float32(1000.0)
    if kind == "png16":
        path = tmp_path / "depth.png"
        assert cv2.imwrite(str(path), mm)
        return path, 0.001
    if kind == "png16_um":  # a tenth of a millimetre per unit (a D400 at depth_scale 1e-4)
        path = tmp_path / "depth.png"
        assert cv2.imwrite(str(path), mm * 10)
        return path, 0.0001
    if kind == "exr":
        path = tmp_path / "depth.exr"
        assert cv2.imwrite(str(path), metres)
        return path, 123.0  # not applied to float metres
    if kind == "exr3":  # ClearGrasp-style: the depth in all three channels
        path = tmp_path / "depth3.exr"
        assert cv2.imwrite(str(path), np.dstack([metres] * 3))
        return path, 0.001
    if kind == "npy_float":
        path = tmp_path / "depth.npy"
        np.save(path, metres.astype(np.float64))
        return path, 0.001
    if kind == "npy_uint16":
        path = tmp_path / "depth.npy"
        np.save(path, mm)
        return path, 0.001
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["png16", "png16_um", "exr", "exr3", "npy_float", "npy_uint16"])
def test_loader_reads_back_the_depth_and_colour_written(tmp_path, color_png, kind):
    depth_path, scale = write_depth(tmp_path, kind)
    frame = load_rgbd(color_png, depth_path, scale, INTR)
    expected = known_depth_mm().astype(np.float64) / 1000.0
    assert frame.depth.dtype == np.float32 and frame.depth.shape == (H, W)
    np.testing.assert_allclose(frame.depth, expected, atol=1e-6)
    assert np.all(frame.depth[5:9, 10:20] == 0)
    np.testing.assert_array_equal(frame.color, known_color())  # RGB, not OpenCV's BGR
    assert frame.intrinsics == Intrinsics(W, H, 60.0, 61.0, 31.5, 23.5)
    assert frame.intrinsics.model == "none"


def test_not_finite_and_negative_depth_is_no_depth(tmp_path):
    depth = np.full((H, W), 0.8, dtype=np.float32)
    depth[0, :4] = [np.nan, np.inf, -np.inf, -0.5]
    np.save(tmp_path / "d.npy", depth)
    metres, scale = load_depth(tmp_path / "d.npy")
    assert scale is None  # float metres: no scale applied
    assert list(metres[0, :5]) == [0, 0, 0, 0, pytest.approx(0.8)]


def test_intrinsics_from_a_snapshot_json_must_be_at_the_image_size(tmp_path, color_png):
    depth_path, _ = write_depth(tmp_path, "png16")
    truth = tmp_path / "ground_truth.json"
    intr = Intrinsics(W, H, 60.0, 60.0, 31.5, 23.5)
    truth.write_text(json.dumps({"intrinsics": intr.to_dict()}))
    assert load_rgbd(color_png, depth_path, 0.001, str(truth)).intrinsics == intr
    truth.write_text(json.dumps({"intrinsics": {**intr.to_dict(), "width": 640}}))
    with pytest.raises(FrameFileError, match="640x48 but the images are 64x48"):
        load_rgbd(color_png, depth_path, 0.001, str(truth))


def fails(capsys, *argv: str) -> str:
    """Run ``armvision argv``; check exit status 2 and a one-line error; return that line."""
    code = main(list(argv))
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 2, (code, captured.err)
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    assert lines[0].startswith("armvision: error: ")
    return lines[0]


def bad_inputs(tmp_path: Path, color: Path) -> list[tuple[list[str], str]]:
    """(arguments after `perceive --out ...`, what the error line says)."""
    depth, _ = write_depth(tmp_path, "png16")
    (tmp_path / "notes.txt").write_text("not an image")
    np.save(tmp_path / "bool.npy", np.ones((H, W), dtype=bool))
    np.save(tmp_path / "int8.npy", np.ones((H, W), dtype=np.uint8))
    assert cv2.imwrite(str(tmp_path / "depth8.png"), np.full((H, W), 9, np.uint8))
    false_colour = np.zeros((H, W, 3), np.uint8)
    false_colour[..., 0] = 200
    assert cv2.imwrite(str(tmp_path / "false.png"), false_colour)
    assert cv2.imwrite(str(tmp_path / "small.png"), np.zeros((H // 2, W // 2), np.uint16))
    ok = ["--color", str(color), "--depth", str(depth)]
    return [
        ([*ok[:2], "--intrinsics", INTR], "--color needs --depth"),
        (["--depth", str(depth)], "--depth goes with --color"),
        (["--sim", "--intrinsics", INTR], "--intrinsics goes with --color"),
        (["--sim", "--calibration", "c.json"], "--calibration goes with --color or --real"),
        ([*ok], "--color needs --intrinsics"),
        (["--color", "nope.png", "--depth", str(depth), "--intrinsics", INTR], "does not exist"),
        (
            ["--color", str(tmp_path / "notes.txt"), "--depth", str(depth), "--intrinsics", INTR],
            "is not an image OpenCV can read",
        ),
        ([*ok[:3], str(tmp_path / "notes.txt"), "--intrinsics", INTR], "is not an image"),
        ([*ok[:3], str(tmp_path / "depth8.png"), "--intrinsics", INTR], "is 8-bit"),
        ([*ok[:3], str(tmp_path / "false.png"), "--intrinsics", INTR], "not a false-colour"),
        ([*ok[:3], str(tmp_path / "bool.npy"), "--intrinsics", INTR], "holds bool values"),
        ([*ok[:3], str(tmp_path / "int8.npy"), "--intrinsics", INTR], "is 8-bit"),
        ([*ok[:3], str(tmp_path / "notes.txt.npy"), "--intrinsics", INTR], "does not exist"),
        ([*ok[:3], str(tmp_path / "small.png"), "--intrinsics", INTR], "resize or align"),
        ([*ok, "--intrinsics", "60,60,31"], "is not four numbers"),
        ([*ok, "--intrinsics", "a,b,c,d"], "is not four numbers"),
        ([*ok, "--intrinsics", "60,nan,31,23"], "is not four numbers"),
        ([*ok, "--intrinsics", "0,60,31,23"], "must be above 0"),
        ([*ok, "--intrinsics", "600,600,320,240"], "principal point (320, 240) is outside"),
        ([*ok, "--intrinsics", str(tmp_path / "notes.txt")], "is not JSON"),
        ([*ok, "--intrinsics", INTR, "--depth-scale", "0"], "not a positive number"),
        ([*ok, "--intrinsics", INTR, "--depth-scale", "-0.001"], "not a positive number"),
        ([*ok, "--intrinsics", INTR, "--depth-scale", "nan"], "not a positive number"),
        ([*ok, "--intrinsics", INTR, "--calibration", "none.json"], "no calibration at"),
        ([*ok, "--intrinsics", INTR, "--joints", "0,0,0"], "--joints needs --calibration"),
    ]


def test_every_bad_input_is_one_line_with_status_2(capsys, tmp_path, color_png):
    out = str(tmp_path / "out")
    for args, says in bad_inputs(tmp_path, color_png):
        line = fails(capsys, "perceive", "--out", out, *args)
        assert says in line, (args, line)


def test_a_depth_scale_of_the_wrong_type_and_the_loader_errors_are_armvision_errors(tmp_path):
    assert issubclass(FrameFileError, ArmvisionError)
    with pytest.raises(FrameFileError, match="not a positive number"):
        load_depth(tmp_path / "x.png", depth_scale=float("inf"))


def test_exr_with_opencvs_flag_turned_off_says_what_to_do(tmp_path):
    path, _ = write_depth(tmp_path, "exr")
    code = f"from armvision.camera.files import load_depth\nload_depth({str(path)!r})\n"
    env = {**os.environ, "OPENCV_IO_ENABLE_OPENEXR": "0"}
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60
    )
    assert result.returncode != 0
    assert "FrameFileError" in result.stderr
    assert "run with OPENCV_IO_ENABLE_OPENEXR=1 in the environment" in result.stderr


def perceive_json(capsys, *argv: str) -> dict:
    assert main(["perceive", *argv, "--json"]) == 0
    captured = capsys.readouterr()
    record = json.loads(captured.out)  # one JSON object and nothing else on stdout
    return record


def calibration_from_truth(truth: dict, path: Path) -> Path:
    """A calibration file with the simulator's camera pose (what `calibrate --sim` estimates)."""
    path.write_text(
        json.dumps(
            {
                "schema": "armvision.calibration",
                "version": 1,
                "method": "truth",
                "source": "test",
                "T_base_cam": truth["T_base_cam"],
                "residual_rms_mm": 0.0,
                "residual_max_mm": 0.0,
                "residuals_mm": [],
                "tag": {
                    "family": "tag36h11",
                    "id": 96,
                    "size": 0.04,
                    "offset_ee_configured": [0, 0, 0],
                    "offset_ee_estimated": [0, 0, 0],
                },
                "camera": {"serial": "sim", "intrinsics": truth["intrinsics"]},
            }
        )
    )
    return path


def nearest(record: dict, center) -> dict:
    return min(
        record["detections"],
        key=lambda d: np.linalg.norm(np.subtract(d["center_cam"], center)),
    )


def test_a_sim_snapshot_perceived_from_its_files_matches_perceive_sim(capsys, tmp_path):
    from armvision.bench.snapshot import write_snapshot
    from armvision.config import load_config

    seed = 3
    write_snapshot(load_config(None), seed, tmp_path / "snap", pose="sleep")  # as perceive --sim
    snap = tmp_path / "snap"
    truth_path = snap / "ground_truth.json"
    truth = json.loads(truth_path.read_text())
    calibration = calibration_from_truth(truth, tmp_path / "calibration.json")

    sim = perceive_json(capsys, "--sim", "--seed", str(seed), "--out", str(tmp_path / "s"))
    files = perceive_json(
        capsys,
        "--color",
        str(snap / "color.png"),
        "--depth",
        str(snap / "depth_mm.png"),
        "--calibration",
        str(calibration),  # intrinsics from it, too
        "--joints",
        str(truth_path),
        "--out",
        str(tmp_path / "f"),
    )
    assert len(sim["detections"]) >= 3
    assert len(files["detections"]) == len(sim["detections"])
    for det in sim["detections"]:
        match = nearest(files, det["center_cam"])
        assert match["label"] == det["label"]
        assert np.linalg.norm(np.subtract(match["center_cam"], det["center_cam"])) < 0.001
    assert [t["id"] for t in files["tags"]] == [t["id"] for t in sim["tags"]] == [96]

    # The documented keys, and what the source says about the files.
    assert set(files) == TOP_KEYS and set(sim) == TOP_KEYS | {"ground_truth"}
    assert set(files["source"]) == SOURCE_KEYS
    assert set(files["tags"][0]) == TAG_KEYS
    assert all(set(d) == DETECTION_KEYS for d in files["detections"] + sim["detections"])
    source = files["source"]
    assert source["kind"] == "files" and source["size"] == [640, 480]
    assert source["depth_scale"] == 0.001 and source["calibration"] == str(calibration)
    assert source["intrinsics"]["fx"] == pytest.approx(truth["intrinsics"]["fx"])
    assert Path(files["image"]).name == "annotated.png" and Path(files["image"]).is_file()
    written = json.loads((tmp_path / "f" / "detections.json").read_text())
    assert written == files

    # Without a camera pose (no table prior, no self-mask) the containers are still found.
    bare = perceive_json(
        capsys,
        "--color",
        str(snap / "color.png"),
        "--depth",
        str(snap / "depth_mm.png"),
        "--intrinsics",
        str(truth_path),
        "--out",
        str(tmp_path / "b"),
    )
    assert bare["source"]["calibration"] is None
    for det in sim["detections"]:
        match = nearest(bare, det["center_cam"])
        assert match["label"] == det["label"]
        assert np.linalg.norm(np.subtract(match["center_cam"], det["center_cam"])) < 0.001


def test_the_readable_table(capsys, tmp_path, color_png):
    depth, _ = write_depth(tmp_path, "npy_float")
    code = main(
        ["perceive", "--color", str(color_png), "--depth", str(depth), "--intrinsics", INTR]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "64x48, fx=60.0 fy=61.0 cx=31.5 cy=23.5" in out and "float metres" in out
    assert "0 tag(s)" in out and "wrote perceive/annotated.png and perceive/detections.json" in out


# The real-data folder beside the project (../shared/realdata), or $ARMVISION_REALDATA.
REALDATA = Path(
    os.environ.get("ARMVISION_REALDATA") or Path(__file__).parents[3] / "shared/realdata"
)
CLEARGRASP = REALDATA / "cleargrasp_real_d435" / "000000080-transparent"
POSECNN = REALDATA / "posecnn_ycb_demo" / "000000"


@pytest.mark.skipif(
    not (CLEARGRASP.parent.is_dir() and POSECNN.parent.is_dir()),
    reason="the real RGB-D frames (evaluation-only licence) are not on this machine",
)
def test_real_frames_cleargrasp_exr_and_posecnn_png(capsys, tmp_path):
    clear = perceive_json(
        capsys,
        "--color",
        f"{CLEARGRASP}-rgb-img.jpg",
        "--depth",
        f"{CLEARGRASP}-depth-img.exr",
        "--intrinsics",
        "921,921,642,359",
        "--out",
        str(tmp_path / "c"),
    )
    assert clear["source"]["size"] == [1280, 720] and clear["source"]["depth_scale"] is None
    assert sum(d["label"] == "bottle" for d in clear["detections"]) >= 2
    for det in clear["detections"]:
        assert 0.4 < det["center_cam"][2] < 1.0  # the table is 0.5-0.9 m away
    ycb = perceive_json(
        capsys,
        "--color",
        f"{POSECNN}-color.png",
        "--depth",
        f"{POSECNN}-depth.png",
        "--intrinsics",
        "618.017,618.003,312.377,232.375",
        "--out",
        str(tmp_path / "y"),
    )
    assert ycb["source"]["size"] == [640, 480] and ycb["source"]["depth_scale"] == 0.001
    assert any(d["label"] == "bottle" for d in ycb["detections"])  # the mustard bottle
    for det in ycb["detections"]:
        assert 0.5 < det["center_cam"][2] < 0.9
