"""The liquid meter's array helpers against numpy and hand-worked geometry.

The meter's per-bottle work is many small array operations; these helpers do some of them
with fewer numpy calls. Each must give exactly what the plain formulation gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.errors import PerceptionError
from armvision.geometry import cross3
from armvision.perception.liquid import (
    _RAY_MISS,
    LiquidLevelMeter,
    _Frame3D,
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


def _rays_numpy(meter, depth, box, bf, r_liq, stride):
    """The rays' fields written as whole-array numpy over every pixel of the box (the
    meter's own formulation before it was compiled), then the rays near the axis kept."""
    x0, y0, x1, y1 = box
    v, u = np.mgrid[y0:y1:stride, x0:x1:stride]
    d = np.stack([(u - INTR.ppx) / INTR.fx, (v - INTR.ppy) / INTR.fy, np.ones(u.shape)], -1)
    d = d.reshape(-1, 3)
    da, dl, du = d @ bf.away, d @ bf.lateral, d @ bf.up
    fa, fl, fu = bf.foot @ bf.away, bf.foot @ bf.lateral, bf.foot @ bf.up
    z_near = (da * fa + dl * fl) / (da**2 + dl**2)
    miss = np.hypot(z_near * da - fa, z_near * dl - fl) / bf.radius
    z = depth[y0:y1:stride, x0:x1:stride].ravel().astype(float)

    def chord(radius):  # the ray's depths where it crosses the cylinder of this radius
        qa, qb = da**2 + dl**2, -2.0 * (da * fa + dl * fl)
        disc = qb**2 - 4.0 * qa * (fa**2 + fl**2 - radius**2)
        root = np.sqrt(np.maximum(disc, 0.0))
        return (-qb - root) / (2 * qa), (-qb + root) / (2 * qa), disc > 0

    near_z, _, hit = chord(bf.radius)
    front = np.where(hit, near_z, np.inf)
    a, b, hit_liq = chord(r_liq)
    s_low = np.where(hit_liq, np.maximum(np.minimum(a * du, b * du) - fu, meter.base), np.nan)
    height = z * du - fu
    valid = z > 0
    on = (
        valid
        & (np.hypot(z * da - fa, z * dl - fl) < bf.radius + meter.surface_tol)
        & (height > meter.base + 0.002)
        & (height < bf.top + meter.surface_tol)
    )
    keep = miss < _RAY_MISS
    fields = {
        "s_low": s_low,
        "height": height,
        "s_axis": z_near * du - fu,
        "miss": miss,
        "valid": valid,
        "on_bottle": on,
        "before": valid & ~on & (z < front - meter.occluder_m),
        "at_wall": on & (z < front + meter.wall_band),
        "hits_liquid_cylinder": hit_liq,
    }
    return {name: value[keep] for name, value in fields.items()}


def test_rays_say_what_each_depth_shows_as_whole_array_numpy_does() -> None:
    """On a depth image with the table, the bottle's front wall, points in front of it and
    holes, every field of the compiled rays equals the whole-array numpy formulation's
    (floats to 1e-9 m, the flags exactly; none of the points within rounding of a limit)."""
    bf = _upright_bottle()
    meter = LiquidLevelMeter()
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.45, 0.9, (480, 640)).astype(np.float32)
    depth[rng.random((480, 640)) < 0.1] = 0.0  # holes
    frame = RGBDFrame(np.zeros((480, 640, 3), np.uint8), depth, INTR, 0.0, 0)
    box = (250, 150, 400, 420)
    for stride in (1, 2):
        rays = meter._rays(frame, box, bf, 0.028, stride=stride)
        want = _rays_numpy(meter, depth, box, bf, 0.028, stride)
        assert want["on_bottle"].sum() > 20 and want["before"].sum() > 20
        assert want["at_wall"].sum() > 5 and (~want["valid"]).sum() > 20
        for name, value in want.items():
            got = getattr(rays, name)
            if value.dtype == bool:
                np.testing.assert_array_equal(got, value, err_msg=name)
            else:
                np.testing.assert_allclose(got, value, rtol=0, atol=1e-9, err_msg=name)


def test_rays_of_a_depth_image_not_aligned_to_colour_are_an_error() -> None:
    """The rays index the depth image with the colour box: a depth image of another size is
    refused with the fix, not read past its end."""
    frame = RGBDFrame(
        np.zeros((480, 640, 3), np.uint8), np.ones((240, 320), np.float32), INTR, 0.0, 0
    )
    with pytest.raises(PerceptionError, match="align depth to colour"):
        LiquidLevelMeter()._rays(frame, (250, 150, 400, 420), _upright_bottle(), 0.028)


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


def test_a_line_of_sight_along_the_bottles_axis_is_no_error() -> None:
    """Seen from straight above its axis, every line of sight comes horizontally closest to
    the axis at the camera (a miss of 0), and the one through the principal point runs down
    the axis: its closest approach is 0 / 0, which numpy's arithmetic makes NaN (no error),
    so it is left out as numpy would leave it. 440 of the box's 441 rays, each missing by 0."""
    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    up, away, lateral = np.eye(3)[2] * -1.0, np.eye(3)[0], np.eye(3)[1]
    bf = _Frame3D(np.array([0.0, 0.0, 0.8]), up, away, lateral, 0.03, 0.2)
    depth = np.full((480, 640), 0.6, np.float32)
    frame = RGBDFrame(np.zeros((480, 640, 3), np.uint8), depth, intr, 0.0, 0)
    rays = LiquidLevelMeter()._rays(frame, (310, 230, 331, 251), bf, 0.028)
    assert len(rays.miss) == 21 * 21 - 1
    assert (rays.miss == 0.0).all()
