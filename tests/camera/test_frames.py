"""Projection with librealsense's distortion models (camera/frames.py) against pyrealsense2 itself.

The reference is librealsense's rs2_project_point_to_pixel / rs2_deproject_pixel_to_point as
compiled into pyrealsense2 (float32 arithmetic), called one point at a time.
"""

from __future__ import annotations

import numpy as np
import pytest

from armvision.camera.frames import (
    DISTORTION_MODELS,
    Intrinsics,
    deproject,
    deproject_image,
    distort,
    project,
    undistort,
)
from armvision.camera.realsense import intrinsics_to_rs

rs = pytest.importorskip("pyrealsense2", reason="pyrealsense2 is not installed")

# Realistic coefficients: D435i colour calibrations report Brown-Conrady terms of this size
# ([k1, k2, p1, p2, k3]); T265-style fisheye Kannala-Brandt [k1..k4]; an F-theta field of view.
BROWN = (-0.0557, 0.0652, -0.00069, 0.00056, -0.0207)
COEFFS = {
    "none": (0.0,) * 5,
    "brown_conrady": BROWN,
    "inverse_brown_conrady": BROWN,
    "modified_brown_conrady": BROWN,
    "kannala_brandt4": (-0.0057, 0.0404, -0.0380, 0.0064, 0.0),
    "ftheta": (0.92, 0.0, 0.0, 0.0, 0.0),
}
#: Models whose librealsense deprojection inverts the projection (see frames.py).
INVERTIBLE = ("none", "brown_conrady", "inverse_brown_conrady", "kannala_brandt4")
#: Round-trip tolerance in normalised coordinates: librealsense's Kannala-Brandt Newton loop stops
#: at |f| < FLT_EPSILON (1.2e-7), the Brown-Conrady fixed point converges to float64 precision.
ROUND_TRIP_TOL = {"kannala_brandt4": 2e-7}
N = 1000


def rs_intrinsics(model: str) -> tuple[Intrinsics, object]:
    """D435i colour-like intrinsics at 640x480, as pyrealsense2 holds them and as Intrinsics."""
    rs_intr = rs.intrinsics()
    rs_intr.width, rs_intr.height = 640, 480
    rs_intr.fx, rs_intr.fy, rs_intr.ppx, rs_intr.ppy = 615.2, 614.8, 321.4, 238.9
    rs_intr.model = getattr(rs.distortion, model)
    rs_intr.coeffs = list(COEFFS[model])
    return Intrinsics.from_rs(rs_intr), rs_intr  # from_rs: the float32 values librealsense uses


def points_in_view(rng: np.random.Generator, n: int) -> np.ndarray:
    """Points 0.2-4 m away inside the D435i colour field of view (about 69 x 42 degrees)."""
    z = rng.uniform(0.2, 4.0, n)
    return np.column_stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.42, 0.42, n) * z, z])


def test_every_librealsense_model_is_covered() -> None:
    names = {m for m in dir(rs.distortion) if not m.startswith("_") and m not in ("name", "value")}
    assert names == set(DISTORTION_MODELS) == set(COEFFS)


@pytest.mark.parametrize("model", DISTORTION_MODELS)
def test_project_matches_pyrealsense2(model: str) -> None:
    intr, rs_intr = rs_intrinsics(model)
    p_cam = points_in_view(np.random.default_rng(1), N)
    expected = np.array([rs.rs2_project_point_to_pixel(rs_intr, list(p)) for p in p_cam])
    assert np.abs(project(intr, p_cam) - expected).max() < 1e-3


@pytest.mark.parametrize("model", DISTORTION_MODELS)
def test_deproject_matches_pyrealsense2(model: str) -> None:
    intr, rs_intr = rs_intrinsics(model)
    rng = np.random.default_rng(2)
    uv = rng.uniform([-0.5, -0.5], [639.5, 479.5], (N, 2))
    depth = rng.uniform(0.2, 4.0, N)
    expected = np.array(
        [rs.rs2_deproject_pixel_to_point(rs_intr, list(q), float(z)) for q, z in zip(uv, depth)]
    )
    assert np.abs(deproject(intr, uv, depth) - expected).max() < 1e-6


@pytest.mark.parametrize("model", DISTORTION_MODELS)
def test_deproject_image_uses_the_same_model(model: str) -> None:
    intr, rs_intr = rs_intrinsics(model)
    depth = np.random.default_rng(3).uniform(0.3, 3.0, (480, 640))
    depth[::7, ::5] = 0.0  # "no data" pixels stay at the origin
    points = deproject_image(intr, depth)
    assert points.shape == (480 * 640, 3)
    assert np.all(points[depth.ravel() == 0.0] == 0.0)
    v, u = np.mgrid[0:480, 0:640]
    uv = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    assert np.array_equal(points, deproject(intr, uv, depth.ravel()))
    sample = np.random.default_rng(4).choice(480 * 640, 200, replace=False)
    expected = np.array(
        [
            rs.rs2_deproject_pixel_to_point(rs_intr, list(uv[i]), float(depth.ravel()[i]))
            for i in sample
        ]
    )
    assert np.abs(points[sample] - expected).max() < 1e-6


@pytest.mark.parametrize("model", INVERTIBLE)
def test_deproject_inverts_project(model: str) -> None:
    intr, _ = rs_intrinsics(model)
    tol = ROUND_TRIP_TOL.get(model, 1e-10)
    p_cam = points_in_view(np.random.default_rng(5), N)
    uv = project(intr, p_cam)
    assert np.abs(deproject(intr, uv, p_cam[:, 2]) - p_cam).max() < tol * 4.0  # z <= 4 m
    assert np.abs(project(intr, deproject(intr, uv, p_cam[:, 2])) - uv).max() < tol * 1000.0


@pytest.mark.parametrize("model", INVERTIBLE)
def test_undistort_inverts_distort(model: str) -> None:
    intr, _ = rs_intrinsics(model)
    rng = np.random.default_rng(6)
    x, y = rng.uniform(-0.6, 0.6, N), rng.uniform(-0.42, 0.42, N)
    x_u, y_u = undistort(intr, *distort(intr, x, y))
    tol = ROUND_TRIP_TOL.get(model, 1e-10)
    assert np.abs(x_u - x).max() < tol and np.abs(y_u - y).max() < tol


def test_librealsense_quirks_are_kept() -> None:
    # modified_brown_conrady is distorted on projection but not undistorted on deprojection;
    # ftheta's deprojection is not the exact inverse of its projection (rsutil.h, both).
    for model in ("modified_brown_conrady", "ftheta"):
        intr, _ = rs_intrinsics(model)
        uv = project(intr, [[0.4, 0.3, 1.0]])
        assert np.abs(deproject(intr, uv, [1.0])[0, :2] - [0.4, 0.3]).max() > 1e-3
    mbc, _ = rs_intrinsics("modified_brown_conrady")
    pinhole = Intrinsics(mbc.width, mbc.height, mbc.fx, mbc.fy, mbc.ppx, mbc.ppy)
    uv = np.array([[10.0, 20.0], [600.0, 400.0]])
    assert np.array_equal(deproject(mbc, uv, [1.0, 2.0]), deproject(pinhole, uv, [1.0, 2.0]))


def test_points_behind_the_camera_do_not_project_with_distortion() -> None:
    intr, _ = rs_intrinsics("brown_conrady")
    assert np.all(np.isnan(project(intr, [[0.0, 0.0, -1.0], [0.1, 0.0, 0.0]])))


def test_optical_axis_maps_to_principal_point_in_every_model() -> None:
    for model in DISTORTION_MODELS:
        intr, _ = rs_intrinsics(model)
        assert project(intr, [[0.0, 0.0, 2.0]])[0] == pytest.approx([intr.ppx, intr.ppy])
        assert deproject(intr, [[intr.ppx, intr.ppy]], [2.0])[0] == pytest.approx([0, 0, 2.0])


def test_unknown_model_is_refused() -> None:
    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0, "fisheye_opencv")
    with pytest.raises(NotImplementedError, match="fisheye_opencv"):
        project(intr, [[0.0, 0.0, 1.0]])


def test_rs_intrinsics_round_trip() -> None:
    intr, rs_intr = rs_intrinsics("inverse_brown_conrady")
    back = intrinsics_to_rs(intr)
    assert back.model == rs.distortion.inverse_brown_conrady
    assert Intrinsics.from_rs(back) == intr
    assert (back.fx, back.ppy, list(back.coeffs)) == (rs_intr.fx, rs_intr.ppy, rs_intr.coeffs)


def test_coefficients_become_a_hashable_tuple() -> None:
    intr = Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0, "brown_conrady", [0.1, 0, 0, 0, 0])  # type: ignore[arg-type]
    assert intr.coeffs == (0.1, 0.0, 0.0, 0.0, 0.0) and hash(intr) == hash(intr)
