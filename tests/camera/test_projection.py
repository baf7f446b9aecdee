"""Projection helpers checked against :func:`project`, librealsense's formula (itself checked
against pyrealsense2 in test_frames.py, which needs pyrealsense2)."""

from __future__ import annotations

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, project, project_xyz

MODELS = ["none", "brown_conrady", "inverse_brown_conrady", "kannala_brandt4"]


@pytest.mark.parametrize("model", MODELS)
def test_project_xyz_is_project_on_coordinate_grids(model: str) -> None:
    """project_xyz on broadcast coordinate arrays gives project's pixels, NaN behind."""
    coeffs = (0.0,) * 5 if model == "none" else (0.1, -0.05, 0.002, -0.001, 0.01)
    intr = Intrinsics(640, 480, 610.0, 612.0, 321.0, 238.0, model, coeffs)
    rng = np.random.default_rng(5)
    x = rng.uniform(-0.3, 0.3, (7, 1))
    y = rng.uniform(-0.2, 0.2, (1, 9))
    z = rng.uniform(0.4, 1.5, (7, 9))
    z[0, 0] = -0.1
    u, v = project_xyz(intr, x, y, z)
    X, Y = np.broadcast_arrays(x, y)
    expected = project(intr, np.column_stack([X.ravel(), Y.ravel(), z.ravel()]))
    np.testing.assert_allclose(u.ravel(), expected[:, 0], rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(v.ravel(), expected[:, 1], rtol=1e-12, equal_nan=True)
    assert np.isnan(u[0, 0]) and np.isnan(v[0, 0])
