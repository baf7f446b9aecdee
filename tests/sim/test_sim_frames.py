"""Pinhole projection and deprojection (camera/frames.py)."""

from __future__ import annotations

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, deproject, deproject_image, project

INTR = Intrinsics(640, 480, 615.0, 612.0, 321.3, 238.7)


def test_optical_axis_projects_to_principal_point() -> None:
    assert project(INTR, [[0.0, 0.0, 2.0]]) == pytest.approx(np.array([[321.3, 238.7]]))


def test_project_formula_on_a_known_point() -> None:
    uv = project(INTR, [0.1, -0.05, 0.5])[0]
    assert uv == pytest.approx([615.0 * 0.2 + 321.3, 612.0 * -0.1 + 238.7])


def test_deproject_inverts_project() -> None:
    rng = np.random.default_rng(0)
    p_cam = np.column_stack(
        [rng.uniform(-0.5, 0.5, 100), rng.uniform(-0.4, 0.4, 100), rng.uniform(0.3, 3.0, 100)]
    )
    uv = project(INTR, p_cam)
    assert deproject(INTR, uv, p_cam[:, 2]) == pytest.approx(p_cam, abs=1e-12)


def test_points_behind_the_camera_do_not_project() -> None:
    assert np.all(np.isnan(project(INTR, [[0.0, 0.0, -1.0], [0.1, 0.0, 0.0]])))


def test_deproject_image_gives_one_point_per_pixel_in_row_order() -> None:
    depth = np.full((3, 4), 2.0)
    points = deproject_image(Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0), depth)
    assert points.shape == (12, 3)
    assert points[1] == pytest.approx([(1 - 1.5) * 2.0 / 2.0, (0 - 1.0) * 2.0 / 2.0, 2.0])


def test_camera_matrix_and_fields_of_view() -> None:
    intr = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
    assert pytest.approx(np.array([[615, 0, 319.5], [0, 615, 239.5], [0, 0, 1]])) == intr.K
    assert intr.vfov_deg == pytest.approx(42.6, abs=0.1)
    assert intr.hfov_deg == pytest.approx(54.9, abs=0.1)
