"""The shared fits: one plane fit in the variants its three callers use, circles, depth rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, deproject
from armvision.perception.fitting import (
    fit_circle_geometric,
    fit_circle_kasa,
    fit_plane,
    solve3,
    unit_depth_rays,
)

INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)


def _plane_points(rng, normal, offset, n, noise):
    """``n`` points of the plane normal . p + offset = 0 (around the foot of the origin)."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    uv = rng.uniform(-0.5, 0.5, (n, 2))
    points = uv[:, :1] * e1 + uv[:, 1:] * e2 - offset * normal
    return normal, points + rng.normal(0, noise, points.shape)


def test_ransac_finds_a_plane_among_outliers() -> None:
    rng = np.random.default_rng(1)
    normal, on_plane = _plane_points(rng, [0.0, -0.87, -0.5], 0.5, 3000, 0.002)
    outliers = rng.uniform(-1, 1, (1000, 3)) + np.array([0.0, 0.0, 1.0])
    points = np.concatenate([on_plane, outliers])
    plane = fit_plane(points, 0.008, rng=rng, hypotheses=64)
    assert plane is not None
    assert plane.normal @ normal > math.cos(math.radians(0.5))  # toward the camera
    assert plane.offset == pytest.approx(0.5, abs=0.002)
    assert plane.inliers[:3000].mean() > 0.99
    assert plane.inliers[3000:].mean() < 0.05
    assert plane.rms == pytest.approx(0.002, rel=0.2)


def test_the_normal_prior_skips_a_bigger_wall() -> None:
    """A wall holding more points than the table: with the table's expected normal and a tilt
    limit the table is found (the liquid meter's use), without them the wall."""
    rng = np.random.default_rng(4)
    up = np.array([0.0, -1.0, 0.0])
    table_n, table = _plane_points(rng, [0.0, -0.9, -0.45], 0.4, 1000, 0.001)
    _, wall = _plane_points(rng, [0.0, 0.0, -1.0], 1.2, 2000, 0.001)
    points = np.concatenate([table, wall])
    found = fit_plane(
        points,
        0.006,
        rng=np.random.default_rng(0),
        normal_prior=up,
        max_tilt_rad=math.acos(0.5),
        max_scored=1500,
        refits=2,
        toward=up,
    )
    assert found is not None
    assert found.normal @ table_n > math.cos(math.radians(0.5))
    assert found.normal[1] < 0.0  # faces the camera's up
    assert found.inliers[:1000].mean() > 0.99 and found.inliers[1000:].mean() < 0.05
    assert found.fitted >= 990  # the last least-squares fit used the table's points
    plain = fit_plane(points, 0.006, rng=np.random.default_rng(0))
    assert plain is not None and abs(plain.normal[2]) > 0.999  # the wall


def test_the_robust_refit_drops_speckle_without_ransac() -> None:
    """The tag plate's variant: no RANSAC, a refit within 3 x MAD drops the speckle."""
    rng = np.random.default_rng(2)
    normal, points = _plane_points(rng, [0.1, -0.3, -1.0], 0.6, 400, 0.0005)
    points[:20] += normal * rng.uniform(0.02, 0.05, (20, 1))  # speckle in front
    plane = fit_plane(points, 0.004, refits=2, robust=True)
    assert plane is not None
    assert not plane.inliers[:20].any() and plane.inliers[20:].mean() > 0.99
    assert plane.normal @ normal > math.cos(math.radians(0.2))
    assert plane.offset == pytest.approx(0.6, abs=0.0005)
    assert plane.rms < 0.001
    once = fit_plane(points, 0.004, refits=1, robust=True)  # one fit still has the speckle
    assert once is not None and abs(once.offset - 0.6) > abs(plane.offset - 0.6)


def test_no_plane_is_none() -> None:
    assert fit_plane(np.zeros((2, 3)), 0.01) is None
    rng = np.random.default_rng(3)
    _, wall = _plane_points(rng, [0.0, 0.0, -1.0], 1.0, 200, 0.0005)
    # Only walls, but a table is asked for: no hypothesis is within the tilt limit.
    assert fit_plane(wall, 0.006, rng=rng, normal_prior=np.array([0.0, -1.0, 0.0])) is None


def test_circle_fit_on_a_noisy_half_arc() -> None:
    """The camera sees half a cylinder: the fit must find the centre, not the arc's centroid."""
    rng = np.random.default_rng(2)
    center, radius = np.array([0.1, 0.7]), 0.03
    angles = rng.uniform(np.pi, 2 * np.pi, 400)  # the half facing the origin (the camera)
    xy = center + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    xy += rng.normal(0, 0.002, xy.shape)
    c0, r0 = fit_circle_kasa(xy)
    c, r, _ = fit_circle_geometric(xy, c0, r0, 0.004)
    assert np.linalg.norm(c - center) < 0.002
    assert r == pytest.approx(radius, abs=0.002)
    assert np.linalg.norm(xy.mean(axis=0) - center) > 0.015  # the centroid would be far off


def test_circles_of_other_sizes_and_supports_are_found() -> None:
    """Half arcs of 12 to 45 mm seen with 40 to 300 points, each fitted with the detector's
    stopping rule (8 iterations, 20 um): near the circle the points were drawn from."""
    rng = np.random.default_rng(5)
    truth = [((0.1, 0.7), 0.03, 300), ((-0.2, 0.6), 0.045, 40), ((0.0, 0.9), 0.012, 120)]
    scales = [0.003, 0.002, 0.004]
    for (center, radius, n), scale in zip(truth, scales):
        angles = rng.uniform(np.pi, 2 * np.pi, n)
        xy = np.asarray(center) + radius * np.column_stack([np.cos(angles), np.sin(angles)])
        xy += rng.normal(0, 0.0015, xy.shape)
        c0, r0 = fit_circle_kasa(xy)
        c, r, res = fit_circle_geometric(xy, c0, r0, scale, iterations=8, tolerance=2e-5)
        assert np.linalg.norm(c - center) < 0.004
        assert r == pytest.approx(radius, abs=0.004)
        np.testing.assert_allclose(res, np.hypot(*(xy - c).T) - r, atol=1e-12)


def test_solve3_agrees_with_numpy_and_refuses_a_singular_system() -> None:
    rng = np.random.default_rng(6)
    for _ in range(20):
        M = rng.normal(size=(12, 3)) * [1.0, 1e-3, 1e3]  # unknowns of very different scales
        A, b = M.T @ M, rng.normal(size=3)
        np.testing.assert_allclose(solve3(A, b), np.linalg.solve(A, b), rtol=1e-9)
    assert solve3(np.zeros((3, 3)), np.ones(3)) is None
    rank2 = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert solve3(rank2, np.ones(3)) is None


def test_kasa_fit_is_exact_on_a_circle_far_from_the_origin() -> None:
    """Solved about the points' mean: a circle 2 m away is as exact as one at the origin."""
    angles = np.linspace(0.0, 2.0, 30)
    xy = np.array([2.0, -1.5]) + 0.02 * np.column_stack([np.cos(angles), np.sin(angles)])
    c, r = fit_circle_kasa(xy)
    np.testing.assert_allclose(c, [2.0, -1.5], atol=1e-9)
    assert r == pytest.approx(0.02, abs=1e-9)


def test_unit_depth_rays_are_deprojected_pixels_at_one_metre() -> None:
    rays, flat = unit_depth_rays(INTR, 2)
    assert len(rays) == len(flat) == 320 * 240
    rows, cols = np.divmod(flat[[0, 1000, -1]], INTR.width)
    expected = deproject(INTR, np.column_stack([cols, rows]).astype(float), np.ones(3))
    np.testing.assert_allclose(rays[[0, 1000, -1]], expected, atol=1e-12)
    assert unit_depth_rays(INTR, 2)[0] is rays  # cached
