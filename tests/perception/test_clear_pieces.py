"""A clear cup seen only in pieces: what a D435 returns on clear plastic (ClearGrasp's real
frames: no depth over half of it, the table behind over a third, the true surface on the
rest), built here on an exact depth image of a table and a cylinder, so the answer is known
by construction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tests.perception.helpers import TiltedBench

from armvision.camera.frames import RGBDFrame
from armvision.perception.geometric import (
    GeometricDetector,
    _behind_front,
    _seen_through,
    _Standing,
)

BENCH = TiltedBench()  # the camera 0.45 m above the table, 35 degrees down
FOOT = BENCH.table_point(340.0, 330.0)  # where the cup stands
RADIUS, CUP_HEIGHT = 0.036, 0.10


def _table_and_cup() -> tuple[np.ndarray, np.ndarray]:
    """Exact depth of the table alone and of the cup's near wall (0 where it is not)."""
    near, _ = BENCH.cylinder(FOOT, RADIUS)
    h = BENCH.heights(near)
    on = (h >= 0.0) & (h <= CUP_HEIGHT)
    return BENCH.table_depth(), np.where(on, near, 0.0)


def _frame(missing: float, behind: float) -> RGBDFrame:
    """The cup's wall in 6-pixel blocks: no depth on ``missing`` of them, the table behind
    on ``behind``, the true wall on the rest (each block's kind drawn at random)."""
    rng = np.random.default_rng(5)
    table, cup = _table_and_cup()
    draws = rng.uniform(size=(BENCH.INTR.height // 6 + 1, BENCH.INTR.width // 6 + 1))
    kind = np.kron(draws, np.ones((6, 6)))[: BENCH.INTR.height, : BENCH.INTR.width]
    depth = table.copy()
    wall = cup > 0
    depth[wall & (kind < missing)] = 0.0
    true = wall & (kind >= missing + behind)
    depth[true] = cup[true]
    return BENCH.frame(depth)


def test_a_clear_cup_seen_in_patches_is_one_cup_behind_them() -> None:
    frame = _frame(missing=0.55, behind=0.33)
    assert GeometricDetector(fragment_min_points=0).detect(frame) == []  # no cluster: pieces
    found = GeometricDetector().detect(frame)
    assert [d.label for d in found] == ["cup"]
    off = found[0].center_cam - FOOT
    error = float(np.linalg.norm(off - (off @ BENCH.up) * BENCH.up))
    assert error < 0.015  # across the table; its height is the highest patch's
    assert found[0].radius == GeometricDetector().fragment_radius


def test_the_same_patches_over_a_seen_table_are_not_a_cup() -> None:
    """Patches standing over table that returns depth all round are no clear plastic: the
    pieces rule needs the missing depth, so nothing is reported."""
    assert GeometricDetector().detect(_frame(missing=0.0, behind=0.88)) == []


def test_a_front_arc_puts_the_centre_on_its_bisector_behind_its_median() -> None:
    """Points on the near half of a circle about (0.1, 0.7) seen from the origin: the centre
    is found on the bearing between the outermost ones, 0.7 r beyond their median range."""
    center, r = np.array([0.1, 0.7]), 0.035
    toward = -center / np.linalg.norm(center)
    base = math.atan2(toward[1], toward[0])
    angles = base + np.linspace(-1.2, 1.2, 41)
    points = center + r * np.column_stack([np.cos(angles), np.sin(angles)])
    got = _behind_front(points, r)
    assert abs(math.atan2(got[1], got[0]) - math.atan2(center[1], center[0])) < 1e-3
    assert abs(np.linalg.norm(got) - np.linalg.norm(center)) < 0.15 * r


def _cup_with_liquid(level: float, wall_missing: float, behind: float = 0.3) -> RGBDFrame:
    """The cup holding liquid up to ``level``: below it the liquid shows through the wall in
    6-pixel blocks (no depth on 55 %, the table on ``behind``, the wall's depth on the
    rest); above it the clear wall returns no depth on ``wall_missing`` of the blocks and
    the table behind on the rest."""
    rng = np.random.default_rng(8)
    table, cup = _table_and_cup()
    near, _ = BENCH.cylinder(FOOT, RADIUS)
    h = BENCH.heights(near)
    draws = rng.uniform(size=(BENCH.INTR.height // 6 + 1, BENCH.INTR.width // 6 + 1))
    kind = np.kron(draws, np.ones((6, 6)))[: BENCH.INTR.height, : BENCH.INTR.width]
    depth = table.copy()
    liquid = (cup > 0) & (h <= level)
    depth[liquid & (kind < 0.55)] = 0.0
    seen = liquid & (kind >= 0.55 + behind)
    depth[seen] = cup[seen]
    depth[(cup > 0) & (h > level) & (kind < wall_missing)] = 0.0
    return BENCH.frame(depth)


@pytest.mark.parametrize(("level", "behind"), [(0.045, 0.3), (0.025, 0.0)])
def test_a_clear_cup_seen_by_its_liquid_is_as_tall_as_its_clear_wall(
    level: float, behind: float
) -> None:
    """Liquid 4.5 cm deep in the 10 cm cup, or 2.5 cm: lower than ``min_object_height``, the
    lowest object the detector reports (there the liquid returns its depth wherever it is
    not missing: with the table behind on 30 %, too few pieces are left to judge). The
    pieces stand lower than any cup, but the wall above
    returns no depth over half of it, so they are a cup whose top is where that stops
    (overshooting by up to the inside seen over the rim, never short of the liquid). With
    the wall above returning the table behind, the low pieces are not a cup."""
    found = GeometricDetector().detect(_cup_with_liquid(level, 0.55, behind))
    assert [d.label for d in found] == ["cup"]
    assert 0.085 <= found[0].height <= 0.135
    foot = found[0].center_cam - 0.5 * found[0].height * found[0].axis_cam
    off = foot - FOOT
    assert float(np.linalg.norm(off - (off @ BENCH.up) * BENCH.up)) < 0.015
    assert GeometricDetector().detect(_cup_with_liquid(level, 0.0, behind)) == []


def _march(uw: np.ndarray, h: np.ndarray, cam_h: float, cyl: _Standing, beyond: bool) -> bool:
    """Whether points marched along the sight line to (uw, h) (and on past it to the table,
    with ``beyond``) fall inside the solid cylinder: the brute-force answer."""
    t = np.linspace(0.0, 4.0 if beyond else 1.0, 8001)[1:]
    if not beyond:
        t = t[t < 1.0]
    pu, ph = t[:, None] * uw, cam_h + t * (h - cam_h)
    inside = (np.hypot(*(pu - cyl.center).T) <= cyl.radius) & (ph <= cyl.height) & (ph >= 0.0)
    return bool(inside.any())


def test_sight_lines_through_a_cylinder_match_marching_along_them() -> None:
    """_seen_through against stepping along each sight line from a camera 0.5 m above the
    table: the same answer for 600 random points, before them and carried on past them,
    wherever a millimetre larger or smaller cylinder would not change the marched one."""
    rng = np.random.default_rng(3)
    cyl = _Standing(np.array([0.05, 0.6]), 0.035, 0.12)
    uw = np.column_stack([rng.uniform(-0.05, 0.15, 600), rng.uniform(0.5, 0.85, 600)])
    h = rng.uniform(0.0, 0.2, 600)
    bigger = _Standing(cyl.center, cyl.radius + 0.001, cyl.height + 0.001)
    smaller = _Standing(cyl.center, cyl.radius - 0.001, cyl.height - 0.001)
    for beyond in (False, True):
        got = _seen_through(uw, h, 0.5, [cyl], beyond)
        judged = 0
        for i in range(len(uw)):
            hi = _march(uw[i], h[i], 0.5, bigger, beyond)
            if hi == _march(uw[i], h[i], 0.5, smaller, beyond):
                judged += 1
                assert got[i] == hi, (beyond, uw[i], h[i])
        assert judged > 550 and 0.05 < got.mean() < 0.5


def test_a_point_straight_behind_a_cylinder_is_hidden_one_beside_it_is_not() -> None:
    """Hand-worked: camera 0.5 m up over the origin, a 10 cm-tall cylinder of 3 cm radius at
    (0, 0.5). A point on the table at (0, 0.7): its sight line is at height 0.5 - 0.5 *
    0.47/0.7 = 0.164 m where it enters the cylinder and 0.5 - 0.5 * 0.53/0.7 = 0.121 m where
    it leaves, above the top: not hidden. At (0, 0.62) it leaves at 0.5 - 0.5 * 0.53/0.62 =
    0.073 m: hidden. At (0.06, 0.62) it passes 4.8 cm beside the axis: not hidden; by a
    cylinder of 5 cm radius it is. Carried on past a point at 0.2 m height at (0, 0.4), the
    sight line meets the cylinder at 0.5 - 0.3 * 0.47/0.4 = 0.147 m and leaves at 0.5 - 0.3 *
    0.53/0.4 = 0.1025 m, both above its top: not hidden; from 0.15 m high it is."""
    cyl = [_Standing(np.array([0.0, 0.5]), 0.03, 0.10)]
    wider = [_Standing(np.array([0.0, 0.5]), 0.05, 0.10)]
    uw = np.array([[0.0, 0.7], [0.0, 0.62], [0.06, 0.62]])
    assert _seen_through(uw, np.zeros(3), 0.5, cyl).tolist() == [False, True, False]
    assert _seen_through(uw[2:], np.zeros(1), 0.5, wider).tolist() == [True]
    before = np.array([[0.0, 0.4], [0.0, 0.4]])
    heights = np.array([0.2, 0.15])
    assert _seen_through(before, heights, 0.5, cyl).tolist() == [False, False]
    assert _seen_through(before, heights, 0.5, cyl, True).tolist() == [False, True]


def test_what_a_nearer_object_blanks_is_not_counted_as_clear() -> None:
    """An opaque can, 12 cm tall, standing 12 cm behind a clear bottle-sized cylinder of
    the same radius, 22 cm tall, 1 cm to one side: where the clear one stands, the depth
    image has no depth (the D435 on clear plastic). Counted as the can's, its whole front
    reads as clear; the samples whose line of sight passes through the nearer cylinder are
    left out, too few are left to judge it by, and it is not called clear (0)."""
    foot_front = BENCH.table_point(330.0, 330.0)
    foot_can = foot_front + np.array([0.01, 0.0, 0.0]) + 0.12 * np.cross(BENCH.up, [1.0, 0, 0])
    can = BENCH.vessel(foot_can, 0.035, 0.12, lid=True)
    near, _ = BENCH.cylinder(foot_front, 0.035)
    blank = (BENCH.heights(near) >= 0.0) & (BENCH.heights(near) <= 0.22)
    frame = BENCH.frame(np.where(blank, 0.0, can))
    det = GeometricDetector()
    det.detect(frame)
    normal, offset = det.last_plane
    e1, e2 = det._plane_axes(normal)
    uw = lambda p: np.array([p @ e1, p @ e2])  # noqa: E731 - a projection, named once
    assert np.linalg.norm(uw(foot_can)) > np.linalg.norm(uw(foot_front)) + 0.1  # behind it
    front = _Standing(uw(foot_front), 0.035, 0.22)
    args = (frame, uw(foot_can), 0.035, 0.12, normal, offset, e1, e2)
    assert det._see_through(*args) > 0.3  # the clear one's blank counted as the can's
    assert det._see_through(*args, [front]) == 0.0
