"""RealSenseCamera without a camera: librealsense's software device, align, filters and recorder.

Synthetic scenes (a tilted wall, two boxes, a patch with no depth) are defined in 3-D in the depth
camera's frame. The depth image is rendered by casting the depth camera's rays, and the expected
aligned depth by casting the colour camera's rays through the extrinsics, both here in numpy,
independently of librealsense. librealsense's aligned depth holds the *depth camera's* z of the
surface each colour pixel sees (align.cpp copies the z16 value), so that is the ground truth.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from armvision.camera.base import Camera
from armvision.camera.frames import Intrinsics
from armvision.camera.realsense import (
    DeviceInfo,
    FrameProcessor,
    RealSenseCamera,
    RecordingEndedError,
    select_device,
)
from armvision.config import CameraConfig
from armvision.errors import HardwareError

Array = NDArray[np.float64]

DEPTH_UNIT = 0.001
# D435i-like streams at 640x480 (values exact in float32, as librealsense stores them). The D435i
# reports zero distortion coefficients for depth (brown_conrady) and colour (inverse_brown_conrady).
DEPTH_INTR = Intrinsics(640, 480, 383.25, 383.25, 319.5, 238.75, "brown_conrady")
COLOR_INTR = Intrinsics(640, 480, 615.5, 615.25, 323.75, 240.25, "inverse_brown_conrady")


def _rot_xy(rx_deg: float, ry_deg: float) -> Array:
    rx, ry = np.radians([rx_deg, ry_deg])
    R_x = np.array([[1, 0, 0], [0, np.cos(rx), -np.sin(rx)], [0, np.sin(rx), np.cos(rx)]])
    R_y = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    return R_y @ R_x


T_COLOR_DEPTH = np.eye(4)
T_COLOR_DEPTH[:3, :3] = _rot_xy(0.2, -0.4)
T_COLOR_DEPTH[:3, 3] = [0.0147, 0.0001, 0.0003]  # the D435i's ~15 mm depth-to-colour offset


# ---- the scene, in the depth camera's frame --------------------------------------------------

WALL_Z0, WALL_DZ_DY = 1.6, 0.2  # wall: Z = 1.6 + 0.2 Y (tilted, so depth varies per pixel)
HOLE = (0.30, 0.45, -0.35, -0.22)  # x0, x1, y0, y1 of a wall patch the sensor gets no depth from


def boxes(z_a: float = 0.80) -> list[tuple[float, tuple[float, float, float, float]]]:
    """Front faces (Z, (x0, x1, y0, y1)) of two boxes facing the camera."""
    return [(z_a, (-0.30, -0.08, -0.15, 0.12)), (1.05, (0.06, 0.28, -0.05, 0.20))]


def cast(o: Array, d: Array, z_a: float = 0.80, hole: bool = True) -> tuple[Array, Array]:
    """Depth-frame Z of the first surface hit by rays o + s d (d (N, 3)), 0 in the hole; and a
    label per ray (0 wall, 1 hole, 2 box A, 3 box B)."""
    s = (WALL_Z0 + WALL_DZ_DY * o[1] - o[2]) / (d[:, 2] - WALL_DZ_DY * d[:, 1])
    p = o + s[:, None] * d
    z, label = p[:, 2].copy(), np.zeros(len(d), int)
    if hole:
        in_hole = (HOLE[0] <= p[:, 0]) & (p[:, 0] <= HOLE[1])
        in_hole &= (HOLE[2] <= p[:, 1]) & (p[:, 1] <= HOLE[3])
        z[in_hole], label[in_hole] = 0.0, 1
    for k, (z_box, (x0, x1, y0, y1)) in enumerate(boxes(z_a)):
        s_box = (z_box - o[2]) / d[:, 2]
        q = o + s_box[:, None] * d
        hit = (x0 <= q[:, 0]) & (q[:, 0] <= x1) & (y0 <= q[:, 1]) & (q[:, 1] <= y1) & (s_box < s)
        s = np.where(hit, s_box, s)
        z[hit], label[hit] = z_box, 2 + k
    return z, label


def pixel_rays(intr: Intrinsics) -> Array:
    """(x, y, 1) through every pixel centre, row by row (pinhole: no distortion coefficients)."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    return np.column_stack(
        [((u - intr.ppx) / intr.fx).ravel(), ((v - intr.ppy) / intr.fy).ravel(), np.ones(u.size)]
    )


def render_depth_units(z_a: float = 0.80, hole: bool = True) -> NDArray[np.uint16]:
    z, _ = cast(np.zeros(3), pixel_rays(DEPTH_INTR), z_a, hole)
    return np.round(z / DEPTH_UNIT).astype(np.uint16).reshape(DEPTH_INTR.height, -1)


def expected_aligned(z_a: float = 0.80, hole: bool = True) -> tuple[Array, Array, Array]:
    """What each colour pixel sees: depth-frame Z, label, and a mask of pixels far (>= 9 px) from
    any depth edge, where librealsense's splatting and occlusion shadows cannot reach."""
    R, t = T_COLOR_DEPTH[:3, :3], T_COLOR_DEPTH[:3, 3]
    o_depth = R.T @ -t  # the colour camera's centre in the depth frame
    z, label = cast(o_depth, pixel_rays(COLOR_INTR) @ R, z_a, hole)  # rows: R.T @ d
    shape = (COLOR_INTR.height, COLOR_INTR.width)
    z, label = z.reshape(shape), label.reshape(shape)
    edges = np.zeros(shape, np.uint8)
    edges[:, 1:] |= label[:, 1:] != label[:, :-1]
    edges[1:, :] |= label[1:, :] != label[:-1, :]
    # Occlusion shadows are f b (1/z_near - 1/z_far) ~ 6 px wide here; keep 9 px away.
    near_edge = cv2.dilate(edges, np.ones((19, 19), np.uint8)).astype(bool)
    return z, label, ~near_edge


def random_color(seed: int) -> NDArray[np.uint8]:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (COLOR_INTR.height, COLOR_INTR.width, 3), dtype=np.uint8)


@pytest.fixture
def rig() -> Any:
    from tests.camera.rs_rig import SoftwareRig

    rig = SoftwareRig(DEPTH_INTR, COLOR_INTR, T_COLOR_DEPTH, DEPTH_UNIT)
    rig.start()
    yield rig
    rig.stop()


# ---- alignment and conversion through librealsense ------------------------------------------


def test_aligned_metric_depth_matches_ray_cast_ground_truth(rig: Any) -> None:
    color = random_color(1)
    frameset = rig.frameset(render_depth_units(), color)
    number, timestamp_ms = rig.frame_number, rig.frame_number * 1000.0 / 30
    frame = FrameProcessor(DEPTH_UNIT).process(frameset, index=3)

    assert frame.depth.dtype == np.float32 and frame.depth.shape == (480, 640)
    assert frame.color.dtype == np.uint8 and np.array_equal(frame.color, color)
    assert frame.intrinsics == COLOR_INTR
    assert frame.timestamp == pytest.approx(timestamp_ms / 1000.0) and frame.index == 3
    assert [f.get_frame_number() for f in frameset] == [number, number]

    z_true, label, far_from_edges = expected_aligned()
    assert far_from_edges.mean() > 0.7  # the comparison covers most of the image
    for k, name in enumerate(["wall", "hole", "box A", "box B"]):
        region = far_from_edges & (label == k)
        assert region.sum() > 500, f"{name} should be in view of the colour camera"
        error = np.abs(frame.depth[region] - z_true[region])
        if name == "wall":
            # z16 rounding (half a unit) plus the wall's slope across one depth pixel (~1.3 mm).
            assert error.max() <= DEPTH_UNIT + WALL_DZ_DY * WALL_Z0 / DEPTH_INTR.fy * 1.6
        else:  # boxes at exact millimetres, the hole exactly 0 ("no data")
            assert error.max() <= 1e-6, name
    # Box A (0.8 m) appears ~11 px right of where it would be without the 15 mm offset, so the
    # 9 px margin would not hide an alignment that ignored the extrinsics.


def test_depth_scale_converts_units_to_metres(rig: Any) -> None:
    # The same z16 values read as 0.1 mm units give a tenth of the metres.
    frameset = rig.frameset(render_depth_units(), random_color(2))
    frame = FrameProcessor(0.0001).process(frameset, 0)
    _, label, far = expected_aligned()
    box_b = far & (label == 3)
    assert np.allclose(frame.depth[box_b], 0.105, atol=1e-7)


def test_hole_filling_fills_the_patch_without_depth(rig: Any) -> None:
    frameset = rig.frameset(render_depth_units(), random_color(3))
    frame = FrameProcessor(DEPTH_UNIT, hole_filling=True).process(frameset, 0)
    z_wall, _, _ = expected_aligned(hole=False)
    _, label, far = expected_aligned()
    hole = far & (label == 1)
    assert hole.sum() > 500
    assert np.all(frame.depth[hole] > 0.0)
    # Filled from the surrounding wall, whose depth varies by a few cm across the patch.
    assert np.abs(frame.depth[hole] - z_wall[hole]).max() < 0.05


@pytest.mark.parametrize("option", ["spatial_filter", "temporal_filter"])
def test_spatial_and_temporal_filters_reduce_depth_noise(rig: Any, option: str) -> None:
    rng = np.random.default_rng(4)
    clean = render_depth_units(hole=False).astype(float)
    plain, filtered = FrameProcessor(DEPTH_UNIT), FrameProcessor(DEPTH_UNIT, **{option: True})
    z_true, label, far = expected_aligned(hole=False)
    wall = far & (label == 0)
    for i in range(4):  # the temporal filter needs a few frames of history
        noisy = np.round(clean + rng.normal(0.0, 4.0, clean.shape)).astype(np.uint16)
        frameset = rig.frameset(noisy, random_color(10 + i))
        frame_plain = plain.process(frameset, i)
        frame_filtered = filtered.process(frameset, i)
    noise_plain = np.std(frame_plain.depth[wall] - z_true[wall])
    noise_filtered = np.std(frame_filtered.depth[wall] - z_true[wall])
    assert noise_plain == pytest.approx(0.004, rel=0.25)  # the injected 4 mm
    assert noise_filtered < 0.75 * noise_plain


# ---- recording and playback -------------------------------------------------------------------

RECORDED_COLOR_INTR = Intrinsics(
    640, 480, 615.5, 615.25, 323.75, 240.25, "inverse_brown_conrady",
    (0.125, -0.25, 0.0009765625, -0.00048828125, 0.0625),
)  # fmt: skip
BOX_A_Z = [0.80, 0.82, 0.85, 0.90]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A .db3 recording of 4 synthetic frames, and the frames the live software device gave."""
    import pyrealsense2 as rs
    from tests.camera.rs_rig import SoftwareRig

    path = tmp_path_factory.mktemp("rec") / "synthetic.db3"  # librealsense 2.59 writes .db3
    images = [(render_depth_units(z), random_color(30 + i)) for i, z in enumerate(BOX_A_Z)]

    rec_rig = SoftwareRig(DEPTH_INTR, RECORDED_COLOR_INTR, T_COLOR_DEPTH, DEPTH_UNIT)
    recorder = rs.recorder(str(path), rec_rig.device)
    rec_rig.start(recorder)
    times_ms = []
    for depth, color in images:
        number, timestamp_ms = rec_rig.next_stamp()
        rec_rig.inject(depth, color, number, timestamp_ms)
        times_ms.append(timestamp_ms)
    rec_rig.stop()
    del recorder  # closes the file

    live_rig = SoftwareRig(DEPTH_INTR, RECORDED_COLOR_INTR, T_COLOR_DEPTH, DEPTH_UNIT)
    live_rig.start()
    processor = FrameProcessor(DEPTH_UNIT)
    live = [processor.process(live_rig.frameset(d, c), i) for i, (d, c) in enumerate(images)]
    live_rig.stop()
    return {"path": path, "images": images, "times_ms": times_ms, "live": live}


def test_recording_plays_back_the_same_frames(recording: dict[str, Any]) -> None:
    camera = RealSenseCamera(bag=recording["path"])
    with camera:
        # After start: Python 3.11's Protocol isinstance reads .intrinsics, known once started.
        assert isinstance(camera, Camera)
        assert camera.intrinsics == RECORDED_COLOR_INTR
        assert camera.depth_scale == pytest.approx(DEPTH_UNIT)
        frames = [camera.read(timeout_s=2.0) for _ in recording["images"]]
        with pytest.raises(RecordingEndedError, match="no more frames"):
            camera.read(timeout_s=2.0)
    for i, frame in enumerate(frames):
        (_, color), live = recording["images"][i], recording["live"][i]
        assert frame.index == i
        assert frame.timestamp == pytest.approx(recording["times_ms"][i] / 1000.0)
        assert np.array_equal(frame.color, color)  # pixel-exact
        assert frame.intrinsics == RECORDED_COLOR_INTR
        # The recording stores the extrinsics and intrinsics in its own precision, which moves a
        # few splat boundaries of align by a pixel: a handful of pixels then differ by one unit.
        difference = np.abs(frame.depth - live.depth)
        assert difference.max() <= DEPTH_UNIT * 1.0001
        assert np.mean(difference > 0) < 0.001
        # Box A moved between frames: the recording keeps each frame's own depth.
        region = (frame.depth > BOX_A_Z[i] - 0.001) & (frame.depth < BOX_A_Z[i] + 0.001)
        assert region.sum() > 2000


def test_recording_can_be_read_from_another_thread(recording: dict[str, Any]) -> None:
    # The runtime reads cameras on their own thread; pyrealsense2 releases the GIL while waiting.
    frames: list[Any] = []
    with RealSenseCamera(bag=recording["path"]) as camera:
        reader = threading.Thread(target=lambda: frames.extend(camera.read(2.0) for _ in range(4)))
        reader.start()
        reader.join(timeout=10.0)
        assert not reader.is_alive()
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert np.array_equal(frames[3].color, recording["images"][3][1])


def test_from_config_plays_back_the_configured_file(recording: dict[str, Any]) -> None:
    config = CameraConfig(bag=str(recording["path"]))
    with RealSenseCamera.from_config(config, hole_filling=True) as camera:
        frame = camera.read(timeout_s=2.0)
    assert camera.hole_filling and frame.color.shape == (480, 640, 3)


def test_a_recording_in_another_mode_is_refused(recording: dict[str, Any]) -> None:
    camera = RealSenseCamera(width=1280, height=720, bag=recording["path"])
    with pytest.raises(HardwareError, match=r"640x480, not 1280x720: set camera.width"):
        camera.start()


# ---- errors that say what to do ---------------------------------------------------------------


def test_no_camera_says_to_plug_it_in() -> None:
    import pyrealsense2 as rs

    if len(rs.context().query_devices()) > 0:
        pytest.skip("a RealSense camera is connected here")
    with pytest.raises(HardwareError, match="no RealSense camera found: plug the D435i"):
        RealSenseCamera().start()


def test_missing_recording_names_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.bag"
    with pytest.raises(HardwareError, match=r"nowhere\.bag.* does not exist"):
        RealSenseCamera(bag=missing).start()


@pytest.mark.parametrize("name", ["corrupt.bag", "corrupt.db3"])
def test_corrupt_recording_names_the_file(tmp_path: Path, name: str) -> None:
    corrupt = tmp_path / name
    corrupt.write_bytes(b"not a recording " * 64)
    with pytest.raises(HardwareError, match=rf"cannot play back .*{name}.*not a readable"):
        RealSenseCamera(bag=corrupt).start()


def test_reading_before_start_says_to_start() -> None:
    camera = RealSenseCamera(bag="unused.db3")
    with pytest.raises(HardwareError, match="not started"):
        camera.read()
    with pytest.raises(HardwareError, match="not started"):
        _ = camera.intrinsics


def test_recording_and_playing_back_at_once_is_refused() -> None:
    with pytest.raises(HardwareError, match="not both"):
        RealSenseCamera(bag="a.db3", record_to="b.db3")


DEVICES = [
    DeviceInfo("111111111111", "Intel RealSense D435I", "3.2"),
    DeviceInfo("222222222222", "Intel RealSense D435I", "2.1"),
]


def test_select_device_takes_the_first_or_the_serial() -> None:
    assert select_device(DEVICES, None) is DEVICES[0]
    assert select_device(DEVICES[:1], "111111111111") is DEVICES[0]
    assert select_device([DeviceInfo("9", "D435", None)], None).serial == "9"


def test_select_device_lists_the_serials_there_are() -> None:
    with pytest.raises(HardwareError, match=r"serial number 333.*111111111111.*222222222222"):
        select_device(DEVICES, "333")


def test_select_device_refuses_usb2() -> None:
    with pytest.raises(HardwareError, match=r"USB 2\.1.*USB 3 port"):
        select_device(DEVICES, "222222222222")


def test_select_device_with_no_devices_says_to_plug_in() -> None:
    with pytest.raises(HardwareError, match="plug the D435i into a USB 3 port"):
        select_device([], None)


def test_missing_pyrealsense2_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # makes `import pyrealsense2` fail
    with pytest.raises(HardwareError, match="pip install pyrealsense2"):
        RealSenseCamera()


def test_modules_import_without_pyrealsense2() -> None:
    code = (
        "import sys; sys.modules['pyrealsense2'] = None\n"
        "import armvision.camera.frames, armvision.camera.realsense\n"
        "from armvision.camera.frames import Intrinsics, project\n"
        "print(project(Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0, 'brown_conrady'), [[0, 0, 1]]))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "[[1.5 1. ]]" in result.stdout
