"""SimCamera against the simulator's ground truth: geometry, depth model, tags, clock."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from armvision.camera.base import Camera
from armvision.camera.frames import RGBDFrame, project
from armvision.camera.placement import camera_pose_from_placement
from armvision.errors import SimulationError
from armvision.geometry import inv_T, transform_points
from armvision.perception.tags import pupil_detector
from armvision.sim._mujoco import mujoco
from armvision.sim.camera import (
    SimCamera,
    depth_rms_error,
    realsense_depth_model,
)
from armvision.sim.world import SimWorld

#: (distance m, azimuth deg, height m, pitch deg): the paper's set-up and three others.
PLACEMENTS = [
    (1.0, 0.0, 0.45, 30.0),
    (0.8, 25.0, 0.6, 40.0),
    (1.2, -30.0, 0.35, 20.0),
    (0.9, 10.0, 0.7, 45.0),
]
#: Marker positions in the camera frame, in front of the camera and clear of the arm.
MARKERS_CAM = [(0.0, 0.0, 0.6), (0.15, -0.1, 0.75), (-0.2, -0.05, 0.9), (0.1, 0.08, 0.5)]


def _place(world: SimWorld, distance: float, azimuth: float, height: float, pitch: float):
    T_base_cam = camera_pose_from_placement(
        distance, math.radians(azimuth), height, math.radians(pitch)
    )
    world.set_camera_pose(T_base_cam)
    return T_base_cam


def _red_mask(frame: RGBDFrame) -> np.ndarray:
    c = frame.color.astype(int)
    return (c[..., 0] > 150) & (c[..., 1] < 90) & (c[..., 2] < 90)


def _sphere_depth(intr, uv: np.ndarray, c_cam: np.ndarray, r: float) -> np.ndarray:
    """True z of the first hit of each pixel's ray on a sphere (centre c_cam, radius r)."""
    d = np.column_stack(
        [(uv[:, 0] - intr.ppx) / intr.fx, (uv[:, 1] - intr.ppy) / intr.fy, np.ones(len(uv))]
    )
    dc, dd = d @ c_cam, np.einsum("ij,ij->i", d, d)
    disc = dc**2 - dd * (c_cam @ c_cam - r * r)
    return (dc - np.sqrt(np.maximum(disc, 0.0))) / dd  # d has z = 1, so t is the depth


def test_sim_camera_is_a_camera(camera: SimCamera) -> None:
    assert isinstance(camera, Camera)


def test_intrinsics_are_the_d435i_colour_stream(camera: SimCamera) -> None:
    intr = camera.intrinsics
    assert (intr.width, intr.height) == (640, 480)
    assert intr.fx == pytest.approx(615.0) and intr.fy == pytest.approx(615.0)
    assert (intr.ppx, intr.ppy) == (319.5, 239.5)
    assert intr.vfov_deg == pytest.approx(42.6, abs=0.1)


@pytest.mark.parametrize("placement", PLACEMENTS)
def test_a_known_point_renders_where_the_true_pose_projects_it(
    empty_world: SimWorld, camera: SimCamera, placement: tuple[float, ...]
) -> None:
    """Within 1 px, and its depth matches the true z within Intel's noise model."""
    T_base_cam = _place(empty_world, *placement)
    r = empty_world.marker_radius
    checked = 0
    for p_cam in MARKERS_CAM:
        p_base = transform_points(T_base_cam, p_cam)
        if p_base[2] < 0.03:  # under the table top from this placement
            continue
        empty_world.set_marker(p_base)
        frame = camera.read()
        c_cam = transform_points(inv_T(empty_world.T_base_cam()), p_base)  # true T_cam_base
        uv_true = project(frame.intrinsics, c_cam)[0]
        mask = _red_mask(frame)
        v, u = np.nonzero(mask)
        assert len(u) > 100, f"marker at {p_base} not visible"
        assert np.hypot(u.mean() - uv_true[0], v.mean() - uv_true[1]) < 1.0

        inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        v, u = np.nonzero(inner & (frame.depth > 0))
        z_true = _sphere_depth(frame.intrinsics, np.column_stack([u, v]).astype(float), c_cam, r)
        residual = frame.depth[v, u] - z_true
        sigma = float(np.sqrt(depth_rms_error(c_cam[2]) ** 2 + 0.001**2 / 12))
        assert abs(residual.mean()) < 4 * sigma / math.sqrt(len(u)) + 2e-4
        assert 0.7 * sigma < residual.std() < 1.3 * sigma
        checked += 1
    assert checked >= 3
    empty_world.set_marker(None)


def test_depth_noise_on_the_table_follows_intels_rms_model(
    empty_world: SimWorld, camera: SimCamera
) -> None:
    _place(empty_world, 1.0, 0.0, 0.45, 30.0)
    frame = camera.read()
    z_true = camera.render_true_depth()
    table = (z_true > 0.5) & (z_true < 1.5) & (frame.depth > 0)
    table[:300] = False  # the lower part of the image is table only
    normalised = (frame.depth[table] - z_true[table]) / depth_rms_error(z_true[table])
    assert table.sum() > 50_000
    assert abs(normalised.mean()) < 0.05
    assert normalised.std() == pytest.approx(1.0, abs=0.1)
    # Every depth is a whole number of millimetres.
    mm = frame.depth[frame.depth > 0] * 1000.0
    assert np.abs(mm - np.round(mm)).max() < 1e-3


def test_depth_is_zero_at_discontinuities_and_out_of_range(
    empty_world: SimWorld, camera: SimCamera
) -> None:
    T_base_cam = _place(empty_world, 1.0, 0.0, 0.45, 30.0)
    empty_world.set_marker(transform_points(T_base_cam, [0.0, 0.0, 0.6]))
    frame = camera.read()
    mask = _red_mask(frame).astype(np.uint8)
    rim = mask.astype(bool) & ~cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)
    assert (frame.depth[rim] == 0).mean() > 0.9  # the silhouette has no depth
    z_true = camera.render_true_depth()
    assert np.all(frame.depth[z_true > 3.0] == 0)  # beyond the far limit (the far floor)
    empty_world.set_marker(None)
    # 20 cm above the table looking straight down: closer than the 0.28 m minimum.
    _place(empty_world, 0.4, 0.0, 0.2, 89.0)
    assert np.all(camera.read().depth == 0)


def test_depth_model_without_noise_is_quantised_truth() -> None:
    z = np.full((4, 5), 0.7534)
    assert realsense_depth_model(z, None) == pytest.approx(np.full((4, 5), 0.753))
    assert realsense_depth_model(np.full((2, 2), 0.2), None).max() == 0.0


def test_depth_rms_error_formula() -> None:
    # Intel: z^2 * 0.08 / (424 px * 0.05 m), about 3.8 mm at 1 m and 15 mm at 2 m.
    assert depth_rms_error(1.0) == pytest.approx(0.08 / (424 * 0.05))
    assert depth_rms_error(2.0) == pytest.approx(4 * depth_rms_error(1.0))


def test_gripper_tag_is_detected_where_the_true_pose_puts_its_corners(
    empty_world: SimWorld, camera: SimCamera
) -> None:
    _place(empty_world, 1.0, 0.0, 0.45, 30.0)  # the arm sleeps: its tag faces the camera
    frame = camera.read()
    gray = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY)
    tag_size = empty_world.config.tag.size
    detector = pupil_detector(families="tag36h11")
    detections = detector.detect(
        gray,
        estimate_tag_pose=True,
        tag_size=tag_size,
        camera_params=frame.intrinsics.camera_params,
    )
    assert [d.tag_id for d in detections] == [96]
    det = detections[0]
    T_cam_tag = inv_T(empty_world.T_base_cam()) @ empty_world.T_base_tag()
    h = tag_size / 2
    corners_tag = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    uv_true = project(frame.intrinsics, transform_points(T_cam_tag, corners_tag))
    assert np.abs(det.corners - uv_true).max() < 1.0  # AprilTag's corner order
    assert det.pose_t.ravel() == pytest.approx(T_cam_tag[:3, 3], abs=0.01)
    angle = np.arccos((np.trace(det.pose_R.T @ T_cam_tag[:3, :3]) - 1) / 2)
    assert math.degrees(angle) < 5.0


def test_frames_come_every_frame_period_of_simulation_time(
    empty_world: SimWorld, camera: SimCamera
) -> None:
    first = camera.read()
    second = camera.read()
    assert second.index == first.index + 1
    assert second.timestamp - first.timestamp == pytest.approx(1 / 30, abs=empty_world.timestep)
    assert empty_world.time == second.timestamp
    empty_world.advance(1.0)  # frames taken meanwhile are dropped: the next is the newest
    third = camera.read()
    assert third.index == second.index + 1
    assert 0.0 <= third.timestamp - empty_world.time + 0.0 < 1e-9
    assert third.timestamp - second.timestamp == pytest.approx(1.0, abs=1 / 30 + 0.002)
    assert first.color.dtype == np.uint8 and first.color.shape == (480, 640, 3)
    assert first.depth.dtype == np.float32 and first.depth.shape == (480, 640)


def test_read_before_start_says_what_to_do(empty_world: SimWorld) -> None:
    with pytest.raises(SimulationError, match="start"):
        SimCamera(empty_world).read()


def test_missing_opengl_is_an_error_naming_mujoco_gl(
    empty_world: SimWorld, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_gl(*args: object) -> None:
        raise RuntimeError("eglInitialize failed")

    monkeypatch.setattr(mujoco, "GLContext", no_gl)
    with pytest.raises(SimulationError, match="MUJOCO_GL"):
        SimCamera(empty_world).start()
