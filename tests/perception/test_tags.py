"""AprilTag poses on synthetic views with known ground truth.

Each view is rendered here by warping the tag texture through the homography K [r1 r2 t] of a
chosen pose T_cam_tag (supersampled 2x, then area-averaged), with a depth image of the same
plane carrying the D435 noise model. The truth is the pose we rendered with, and pupil-apriltags'
own pose estimate serves as an independent cross-check of the PnP.
"""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.errors import PerceptionError
from armvision.geometry import make_T, pose_error, rot_x, rot_y
from armvision.perception.tags import TagDetector, pupil_detector
from armvision.sim.assets import tag_image

INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
TAG_SIZE = 0.04


def render(T_cam_tag, tag_id=96, depth_noise=True, seed=0, intr=INTR):
    """(RGB image, depth image) of one tag (with a plate 1.6x its size) in front of a wall."""
    texture = tag_image(tag_id, pixels_per_cell=32)  # 10 cells: 8 black + a white border each side
    n = texture.shape[0]
    m_per_px = TAG_SIZE / 8 / 32
    A = np.array(
        [
            [m_per_px, 0, (0.5 - n / 2) * m_per_px],
            [0, m_per_px, (0.5 - n / 2) * m_per_px],
            [0, 0, 1],
        ]
    )
    K2 = np.array(
        [[2 * intr.fx, 0, 2 * intr.ppx + 0.5], [0, 2 * intr.fy, 2 * intr.ppy + 0.5], [0, 0, 1]]
    )
    R, t = T_cam_tag[:3, :3], T_cam_tag[:3, 3]
    H = K2 @ np.column_stack([R[:, 0], R[:, 1], t]) @ A
    big = cv2.warpPerspective(
        texture,
        H,
        (2 * intr.width, 2 * intr.height),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=110,
    )
    gray = cv2.resize(big, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
    rgb = np.repeat(gray[:, :, None], 3, axis=2)

    # Depth: the tag plane inside a plate 1.6x the tag, a wall at 2 m elsewhere.
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    rays = np.stack(
        [(u - intr.ppx) / intr.fx, (v - intr.ppy) / intr.fy, np.ones_like(u, float)], -1
    )
    normal = R[:, 2]
    z = (normal @ t) / (rays @ normal)
    p_tag = (rays * z[..., None] - t) @ R  # points in the tag frame
    on_plate = (
        (np.abs(p_tag[..., 0]) < 0.8 * TAG_SIZE)
        & (np.abs(p_tag[..., 1]) < 0.8 * TAG_SIZE)
        & (z > 0)
    )
    depth = np.where(on_plate, z, 2.0)
    if depth_noise:
        rng = np.random.default_rng(seed)
        sigma = depth**2 * 0.08 / (424.0 * 0.050)  # Intel's D435 RMS model
        depth = np.round((depth + rng.normal(size=depth.shape) * sigma) * 1000.0) / 1000.0
    return rgb, depth.astype(np.float32)


def random_pose(rng, distance, max_tilt_deg):
    """Tag facing the camera within max_tilt, at ``distance`` along a ray inside the view."""
    tilt = np.radians(rng.uniform(0, max_tilt_deg))
    axis = rng.normal(size=2)
    axis = np.append(axis / np.linalg.norm(axis), 0.0)
    R = (
        Rotation.from_rotvec(axis * tilt).as_matrix()
        @ Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()
    )
    direction = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.15, 0.15), 1.0])
    return make_T(R, direction / np.linalg.norm(direction) * distance)


@pytest.fixture(scope="module")
def detector():
    return TagDetector(tag_size=TAG_SIZE, ids=[96])


def test_frontal_tag_pose_matches_truth_and_pupil(detector):
    T_true = make_T(rot_x(0.3) @ rot_y(-0.2), [0.05, -0.03, 0.6])
    rgb, _ = render(T_true)
    found = detector.detect_image(rgb, INTR)
    assert [d.id for d in found] == [96]
    det = found[0]
    assert not det.depth_refined
    dp, dr = pose_error(det.T_cam_tag, T_true)
    assert dp < 0.003 and np.degrees(dr) < 2.0
    assert det.pose_error < 0.5  # pixels
    # pupil-apriltags' own pose (orthogonal iteration) agrees: same tag frame convention.
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    pupil = pupil_detector(families="tag36h11").detect(gray, True, INTR.camera_params, TAG_SIZE)[0]
    T_pupil = make_T(pupil.pose_R, np.ravel(pupil.pose_t))
    dp, dr = pose_error(det.T_cam_tag, T_pupil)
    assert dp < 0.002 and np.degrees(dr) < 1.0
    np.testing.assert_allclose(det.center, pupil.center, atol=0.2)  # pixels


def test_depth_refinement_meets_the_accuracy_target_and_beats_pnp(detector):
    rng = np.random.default_rng(1)
    errors = {"pnp": ([], []), "depth": ([], [])}
    plain = TagDetector(tag_size=TAG_SIZE, ids=[96], refine_with_depth=False)
    for i in range(30):
        T_true = random_pose(rng, rng.uniform(0.5, 1.2), max_tilt_deg=50)
        rgb, depth = render(T_true, seed=i)
        frame = RGBDFrame(rgb, depth, INTR, 0.0, i)
        for name, det in (("pnp", plain), ("depth", detector)):
            found = det.detect(frame)
            assert len(found) == 1, f"tag not found in view {i}"
            assert found[0].depth_refined == (name == "depth")
            dp, dr = pose_error(found[0].T_cam_tag, T_true)
            errors[name][0].append(dp)
            errors[name][1].append(np.degrees(dr))
    pos_depth, rot_depth = np.median(errors["depth"][0]), np.median(errors["depth"][1])
    assert pos_depth <= 0.005 and rot_depth <= 2.0, (pos_depth, rot_depth)
    assert pos_depth < np.median(errors["pnp"][0])


def test_depth_rejects_flipped_solutions_on_near_frontal_tags(detector):
    rng = np.random.default_rng(2)
    plain = TagDetector(tag_size=TAG_SIZE, ids=[96], refine_with_depth=False)
    worst_plain, worst_depth = 0.0, 0.0
    for i in range(30):
        T_true = random_pose(rng, rng.uniform(0.9, 1.2), max_tilt_deg=12)
        rgb, depth = render(T_true, seed=100 + i)
        rgb = np.clip(rgb + np.random.default_rng(i).normal(0, 4, rgb.shape), 0, 255).astype(
            np.uint8
        )
        frame = RGBDFrame(rgb, depth, INTR, 0.0, i)
        worst_plain = max(
            worst_plain, np.degrees(pose_error(plain.detect(frame)[0].T_cam_tag, T_true)[1])
        )
        worst_depth = max(
            worst_depth, np.degrees(pose_error(detector.detect(frame)[0].T_cam_tag, T_true)[1])
        )
    assert worst_depth < 6.0
    assert worst_depth < worst_plain


def test_ids_filter_and_missing_depth_fall_back_to_pnp():
    T_true = make_T(np.eye(3), [0.0, 0.0, 0.7])
    rgb, depth = render(T_true, tag_id=5)
    assert TagDetector(tag_size=TAG_SIZE, ids=[96]).detect_image(rgb, INTR, depth) == []
    found = TagDetector(tag_size=TAG_SIZE).detect_image(rgb, INTR, np.zeros_like(depth))
    assert [d.id for d in found] == [5] and not found[0].depth_refined


def test_settings_and_bad_input_give_clear_errors():
    det = TagDetector(decode_sharpening=0.25)
    assert det._detector.tag_detector_ptr.contents.decode_sharpening == pytest.approx(0.25)
    with pytest.raises(PerceptionError, match="family"):
        TagDetector(family="tag36h10")
    with pytest.raises(PerceptionError, match="tag_size"):
        TagDetector(tag_size=0.0)
    with pytest.raises(PerceptionError, match="8-bit"):
        det.detect_image(np.zeros((10, 10), np.float32), INTR)
    with pytest.raises(PerceptionError, match="align depth to colour"):
        det.detect_image(np.zeros((480, 640), np.uint8), INTR, np.zeros((240, 320), np.float32))


def test_detectors_are_freed_without_crashing():
    """pupil-apriltags frees tag families before the detector using them; ours must not crash."""
    code = (
        "import numpy as np\n"
        "from armvision.perception.tags import TagDetector, pupil_detector\n"
        "image = np.full((120, 160), 200, np.uint8)\n"
        "for i in range(40):\n"
        "    TagDetector().detect_image(image, None)\n"
        "    pupil_detector(families='tag36h11').detect(image)\n"
        "print('ok')\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "ok"
