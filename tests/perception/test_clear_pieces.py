"""A clear cup seen only in pieces: what a D435 returns on clear plastic (ClearGrasp's real
frames: no depth over half of it, the table behind over a third, the true surface on the
rest), built here on an exact depth image of a table and a cylinder, so the answer is known
by construction."""

from __future__ import annotations

import math

import numpy as np

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.perception.geometric import GeometricDetector, _behind_front

INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
PITCH = math.radians(35.0)  # the camera looks down this much, 0.45 m above the table
HEIGHT = 0.45
UP = np.array([0.0, -math.cos(PITCH), -math.sin(PITCH)])  # the table's normal, camera frame
RADIUS, CUP_HEIGHT = 0.036, 0.10


def _table_point(u: float, v: float) -> np.ndarray:
    ray = np.array([(u - INTR.ppx) / INTR.fx, (v - INTR.ppy) / INTR.fy, 1.0])
    return ray * (-HEIGHT / float(ray @ UP))


FOOT = _table_point(340.0, 330.0)


def _table_and_cup(radius: float = RADIUS) -> tuple[np.ndarray, np.ndarray]:
    """Exact depth of the table alone and of the cup's near wall (0 where it is not)."""
    u, v = np.meshgrid(np.arange(INTR.width), np.arange(INTR.height))
    rays = np.stack([(u - INTR.ppx) / INTR.fx, (v - INTR.ppy) / INTR.fy, np.ones(u.shape)], -1)
    along = rays @ UP
    with np.errstate(divide="ignore"):
        table = np.where(along < -1e-3, -HEIGHT / along, 0.0)
    # The ray t r meets the vertical cylinder |(t r - F) off the axis| = R at the smaller
    # root of |r_o|^2 t^2 - 2 (r_o . F_o) t + |F_o|^2 - R^2 = 0 (r_o, F_o: off-axis parts).
    r_o = rays - along[..., None] * UP
    f_o = FOOT - (FOOT @ UP) * UP
    a = np.einsum("...i,...i", r_o, r_o)
    b = r_o @ f_o
    disc = b**2 - a * (f_o @ f_o - radius**2)
    t = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0.0))) / a, 0.0)
    h = t * along + HEIGHT  # height above the table of the hit
    on = (disc > 0) & (h >= 0.0) & (h <= CUP_HEIGHT)
    return table, np.where(on, t, 0.0)


def _frame(missing: float, behind: float, radius: float = RADIUS) -> RGBDFrame:
    """The cup's wall in 6-pixel blocks: no depth on ``missing`` of them, the table behind
    on ``behind``, the true wall on the rest (each block's kind drawn at random)."""
    rng = np.random.default_rng(5)
    table, cup = _table_and_cup(radius)
    draws = rng.uniform(size=(INTR.height // 6 + 1, INTR.width // 6 + 1))
    kind = np.kron(draws, np.ones((6, 6)))[: INTR.height, : INTR.width]
    depth = table.copy()
    wall = cup > 0
    depth[wall & (kind < missing)] = 0.0
    true = wall & (kind >= missing + behind)
    depth[true] = cup[true]
    color = np.full((INTR.height, INTR.width, 3), 128, np.uint8)
    return RGBDFrame(
        color=color, depth=depth.astype(np.float32), intrinsics=INTR, timestamp=0.0, index=0
    )


def test_a_clear_cup_seen_in_patches_is_one_cup_behind_them() -> None:
    frame = _frame(missing=0.55, behind=0.33)
    assert GeometricDetector(fragment_min_points=0).detect(frame) == []  # no cluster: pieces
    found = GeometricDetector().detect(frame)
    assert [d.label for d in found] == ["cup"]
    off = found[0].center_cam - FOOT
    error = float(np.linalg.norm(off - (off @ UP) * UP))
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
