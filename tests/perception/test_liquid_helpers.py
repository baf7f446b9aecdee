"""The liquid meter's array helpers against numpy and hand-worked geometry.

The meter's per-bottle work is many small array operations; these helpers do some of them
with fewer numpy calls. Each must give exactly what the plain formulation gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.geometry import cross3
from armvision.perception.liquid import (
    _RAY_MISS,
    LiquidLevelMeter,
    _Frame3D,
    _hypot_below,
    _median,
    _rgb_length,
    plane_basis,
    unit_ring,
)

INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)


def test_rgb_length_is_numpys_norm_exactly() -> None:
    """Hand-worked: (3, 4, 0) has length 5, (1, 2, 2) 3; on random float32 RGB differences the
    same bits as ``np.linalg.norm(axis=-1)``, in 2-D and 3-D layouts."""
    assert _rgb_length(np.array([[3.0, 4.0, 0.0], [1.0, 2.0, 2.0]], np.float32)).tolist() == [
        5.0,
        3.0,
    ]
    rng = np.random.default_rng(1)
    for shape in ((40, 17, 3), (12, 2, 9, 3)):
        d = rng.normal(0.0, 40.0, shape).astype(np.float32)
        got = _rgb_length(d)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, np.linalg.norm(d, axis=-1))


@pytest.mark.parametrize("n", [1, 2, 7, 8, 21])
@pytest.mark.parametrize("axis", [1, 2])
def test_median_is_numpys_median_exactly(n: int, axis: int) -> None:
    """Odd and even lengths, along a middle or the last axis: the same values as
    ``np.median``; hand-worked, the median of 1, 5, 2, 4 is 3 and of 1, 5, 2 is 2."""
    assert _median(np.array([[1.0, 5.0, 2.0, 4.0]]), axis=1).tolist() == [3.0]
    assert _median(np.array([[1.0, 5.0, 2.0]]), axis=1).tolist() == [2.0]
    rng = np.random.default_rng(n)
    shape = [6, 5, 3]
    shape[axis] = n
    a = rng.normal(0.0, 30.0, shape).astype(np.float32)
    got = _median(a, axis=axis)
    assert got.dtype == a.dtype
    np.testing.assert_array_equal(got, np.median(a, axis=axis))


def test_median_of_nothing_is_nan_as_numpys() -> None:
    with pytest.warns(RuntimeWarning):
        assert np.isnan(_median(np.zeros((3, 0)), axis=1)).all()


def test_hypot_below_is_numpys_hypot_exactly() -> None:
    """Hand-worked: (3, 4) is 5 long, so below 5.000001 and not below 5; on random values,
    ones placed at the limit to a few ulp and NaN, the same as ``np.hypot(a, b) < limit``."""
    assert _hypot_below(np.array([3.0]), np.array([4.0]), 5.000001).tolist() == [True]
    assert _hypot_below(np.array([3.0]), np.array([4.0]), 5.0).tolist() == [False]
    rng = np.random.default_rng(3)
    a, b = rng.normal(0.0, 0.03, 5000), rng.normal(0.0, 0.03, 5000)
    limit = 0.035
    angle = rng.uniform(0.0, 2.0 * np.pi, 500)
    ulps = rng.integers(-4, 5, 500) * np.spacing(limit)
    a[:500], b[:500] = (limit + ulps) * np.cos(angle), (limit + ulps) * np.sin(angle)
    a[500] = np.nan
    np.testing.assert_array_equal(_hypot_below(a, b, limit), np.hypot(a, b) < limit)


def _upright_bottle() -> _Frame3D:
    """A bottle r 30 mm, 0.2 m tall, its foot 0.6 m ahead and 0.2 m below a camera pitched
    down 20 degrees; axes as the meter builds them."""
    pitch = np.radians(20.0)
    up = np.array([0.0, -np.cos(pitch), -np.sin(pitch)])  # the table normal, camera frame
    foot = np.array([0.03, 0.0, 0.6])
    foot = foot - (up @ foot + 0.2) * up  # onto the table up . p + 0.2 = 0
    away = foot - (up @ foot) * up
    away /= np.linalg.norm(away)
    return _Frame3D(foot, up, away, cross3(away, up), 0.03, 0.2)


def test_rays_are_the_lines_of_sight_near_the_axis() -> None:
    """Every pixel of the box whose line of sight passes within 0.8 r of the bottle's axis
    (horizontally: the distance between the ray and the axis line, minimised by brute force
    along the ray), in row order, and no other; each with that distance over r."""
    bf = _upright_bottle()
    meter = LiquidLevelMeter()
    depth = np.full((480, 640), 0.8, np.float32)
    frame = RGBDFrame(np.zeros((480, 640, 3), np.uint8), depth, INTR, 0.0, 0)
    box = (250, 150, 400, 420)
    rays = meter._rays(frame, box, bf, 0.028, stride=3)
    v, u = np.mgrid[box[1] : box[3] : 3, box[0] : box[2] : 3]
    d = np.stack([(u - INTR.ppx) / INTR.fx, (v - INTR.ppy) / INTR.fy, np.ones(u.shape)], -1)
    d = d.reshape(-1, 3)

    def horizontal_distance(z: np.ndarray) -> np.ndarray:
        """Distance from the axis line, perpendicular to it, of each ray's points at z."""
        offsets = z[..., None] * d[:, None, :] - bf.foot
        return np.linalg.norm(offsets - (offsets @ bf.up)[..., None] * bf.up, axis=-1)

    # Along each ray: 1 mm steps of depth, then 0.01 mm steps around the closest.
    coarse = np.linspace(0.3, 1.2, 901)
    best = coarse[np.argmin(horizontal_distance(np.broadcast_to(coarse, (len(d), 901))), 1)]
    fine = best[:, None] + np.linspace(-0.001, 0.001, 201)
    miss = horizontal_distance(fine).min(axis=1) / bf.radius
    near = miss < _RAY_MISS
    assert 100 < near.sum() < len(miss)  # the test sees both kinds
    # A ray within rounding of the threshold could go either way; none is.
    assert np.min(np.abs(miss - _RAY_MISS)) > 1e-5
    assert len(rays.miss) == near.sum()
    np.testing.assert_allclose(rays.miss, miss[near], atol=1e-4)
    assert rays.valid.all()


def test_table_basis_is_kept_per_normal() -> None:
    """The box fit's plane basis and ring: :func:`plane_basis` and :func:`unit_ring` of the
    normal, the same arrays again for the same normal, new ones for another."""
    meter = LiquidLevelMeter()
    up = _upright_bottle().up
    e1, e2, ring = meter._table_basis(up)
    for got, want in zip((e1, e2, ring), (*plane_basis(up), unit_ring(up))):
        np.testing.assert_array_equal(got, want)
    assert meter._table_basis(up.copy())[2] is ring
    other = np.array([0.0, -1.0, 0.0])
    np.testing.assert_array_equal(meter._table_basis(other)[2], unit_ring(other))
