"""Collision-aware grasp planning, by hand-worked geometry: the planning scene, the clearance
formula, the candidates around a bottle, the refusal, and joint-space paths."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics
from armvision.config import GrabConfig
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T
from armvision.robot.kinematics import VX300S, fk
from armvision.robot.vx300s import FINGER_PAD_INSET
from armvision.runtime.context import TaskStopped
from armvision.runtime.planning_scene import (
    CONTAINER_RADIUS_MARGIN_M,
    SIGMA_FACTOR,
    TOP_MARGIN_M,
    Body,
    PlanningScene,
    occupancy_from_depth,
)
from armvision.tasks.collision import arm_spheres, clearances, cylinder_distances
from armvision.tasks.grab import corridor_clear
from armvision.tasks.grasp_plan import GraspRefusal, joint_line, plan_grasps
from armvision.tasks.joint_plan import joint_path, path_free, path_times
from armvision.tasks.motion import SPEED_FRACTION


def _track(track_id: int, label: str, p, radius: float, height: float, sigma: float = 1e-3):
    cov = np.eye(6) * sigma**2
    return TrackState(
        track_id, label, True, 0.0, np.array(p, float), np.zeros(3), cov, 5, 0.0,
        ((label, 5.0),), radius, height,
    )  # fmt: skip


def test_cylinder_distance_is_the_hand_worked_one() -> None:
    body = Body((0.0, 0.0), 0.05, 0.0, 0.2, "cup", 1)
    p = np.array(
        [
            [0.15, 0.0, 0.1],  # beside it: 0.1 from the wall
            [0.0, 0.0, 0.3],  # above it: 0.1 over the top
            [0.08, 0.0, 0.24],  # off the rim: hypot(0.03, 0.04) = 0.05
            [0.0, 0.0, 0.1],  # inside, on the axis: 0.05 to the wall, 0.1 to the lids
        ]
    )
    d = cylinder_distances(p, [body])[:, 0]
    assert d == pytest.approx([0.1, 0.1, 0.05, -0.05])


def test_track_bodies_carry_their_uncertainty_and_cells_outside_them() -> None:
    sigma = 0.004
    cup = _track(5, "cup", [0.3, 0.1, 0.05], 0.035, 0.1, sigma)
    can = _track(6, "other", [0.5, 0.1, 0.06], 0.033, 0.12, sigma)
    scene = PlanningScene.build([cup, can], None)
    body, other = scene.bodies
    # A container's fitted radius runs short (its clear wall returns no depth): it grows.
    assert body.radius == pytest.approx(0.035 + CONTAINER_RADIUS_MARGIN_M + SIGMA_FACTOR * sigma)
    assert other.radius == pytest.approx(0.033 + SIGMA_FACTOR * sigma)
    assert body.top == pytest.approx(0.1 + TOP_MARGIN_M + SIGMA_FACTOR * sigma)
    assert body.bottom == 0.0 and body.describe() == "the cup (track 5) at (0.300, 0.100) m"


def test_occupancy_grid_maps_what_no_detection_explains() -> None:
    # A camera 1 m above the table looking straight down; a 10 x 10 cm box 8 cm tall at
    # (0.30, 0.10) that nothing detected, and a detected cylinder at (0.50, -0.10).
    intr = Intrinsics(640, 480, 600.0, 600.0, 319.5, 239.5, "none", (0.0,) * 5)
    T_base_cam = make_T(np.diag([1.0, -1.0, -1.0]), [0.4, 0.0, 1.0])
    v, u = np.mgrid[0:480, 0:640]
    xn, yn = (u - intr.ppx) / intr.fx, (v - intr.ppy) / intr.fy

    def base_xy(depth):  # where a pixel's ray is at that depth, base frame
        return 0.4 + xn * depth, -yn * depth

    depth = np.ones((480, 640))
    bx, by = base_xy(0.92)
    depth[(np.abs(bx - 0.3) < 0.05) & (np.abs(by - 0.1) < 0.05)] = 0.92
    cx, cy = base_xy(0.9)
    depth[np.hypot(cx - 0.5, cy + 0.1) < 0.04] = 0.9
    grid = occupancy_from_depth(depth, intr, T_base_cam, None, [((0.5, -0.1), 0.04, 0.1)], t=1.0)
    assert grid.table_z == pytest.approx(0.0, abs=1e-6)
    assert len(grid.cells) >= 9
    assert np.all(np.abs(grid.cells[:, 0] - 0.3) < 0.06)
    assert np.all(np.abs(grid.cells[:, 1] - 0.1) < 0.06)
    assert grid.tops == pytest.approx(0.08, abs=1e-6)
    # The scene keeps the cells outside every track, as "occupied" bodies.
    cup = _track(7, "cup", [0.3, 0.1, 0.04], 0.03, 0.08)
    scene = PlanningScene.build([cup], grid)
    assert len(scene.cells) < len(grid.cells)
    assert all(np.hypot(c.xy[0] - 0.3, c.xy[1] - 0.1) > 0.03 for c in scene.cells)


BOTTLE = _track(1, "bottle", [0.40, 0.0, 0.1], 0.033, 0.2)
#: A cup in front of the bottle, in the paper's corridor from the base, 4.4 cm apart.
CUP_IN_FRONT = _track(2, "cup", [0.30, 0.05, 0.045], 0.035, 0.09)


def test_a_cup_in_front_is_passed_above_or_around_and_every_step_is_clear() -> None:
    cfg = GrabConfig()
    assert not corridor_clear(BOTTLE, [CUP_IN_FRONT], cfg.standoff)  # the paper's way is shut
    scene = PlanningScene.build([BOTTLE, CUP_IN_FRONT], None)
    found = plan_grasps(BOTTLE, scene, cfg, VX300S)
    assert isinstance(found, list) and found
    best = found[0]
    cup = scene.bodies[1]
    # Independently of the planner's checks: the open pads and the gripper at every executed
    # configuration, and on the joint lines between them, are clear of the cup.
    opened = VX300S.finger_limits[1]
    path = [best.hover, *best.descend, *best.approach]
    Q = np.concatenate([joint_line(a, b) for a, b in itertools.pairwise(path)])
    centres, radii = arm_spheres(Q, opened)
    least, _ = clearances(centres, radii, [cup], None)
    assert least.min() >= cfg.clearance
    # The grasp puts the bottle's axis between the fingertips at the planned height (or, for
    # a shallow grasp, ``ahead`` of the point between them along the heading).
    T_grasp = fk(best.grasp)
    u = np.array([math.cos(best.yaw), math.sin(best.yaw), 0.0])
    assert T_grasp[:3, 3] + best.ahead * u == pytest.approx([0.4, 0.0, best.grasp_z], abs=1e-4)
    assert best.grasp_z >= 0.0 + cfg.grasp_height_fraction * 0.2 - 1e-9
    # The pads at the grasp height pass above the cup, or the approach comes from a side.
    pads_bottom = best.grasp_z - 0.012
    bearing_off = abs(math.remainder(best.yaw - 0.0, 2 * math.pi))
    assert pads_bottom > cup.top + cfg.clearance or bearing_off > math.radians(30)


def test_stop_is_consulted_between_candidates_and_ends_the_plan() -> None:
    """A plan takes seconds on a busy machine: Stop (the task's check) must end it midway."""
    scene = PlanningScene.build([BOTTLE, CUP_IN_FRONT], None)
    calls = []

    def stop() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise TaskStopped("stopped")

    with pytest.raises(TaskStopped):
        plan_grasps(BOTTLE, scene, GrabConfig(), VX300S, stop=stop)
    assert len(calls) == 3  # consulted before each candidate, and nothing after the third


def test_a_surrounded_bottle_is_refused_with_what_blocks_it() -> None:
    ring = [
        _track(10 + k, "cup", [0.4 + 0.075 * math.cos(a), 0.075 * math.sin(a), 0.1], 0.035, 0.2)
        for k, a in enumerate(np.linspace(0.0, 2 * math.pi, 6, endpoint=False))
    ]
    scene = PlanningScene.build([BOTTLE, *ring], None)
    refusal = plan_grasps(BOTTLE, scene, GrabConfig(), VX300S)
    assert isinstance(refusal, GraspRefusal)
    assert refusal.reason.startswith("every approach to bottle 1 at (0.400, 0.000) m is blocked")
    assert "by the cup (track 1" in refusal.reason
    assert (
        sum(n for _, n in refusal.blocked) + refusal.unreachable == GrabConfig().approach_candidates
    )


def test_a_bottle_in_a_tight_cluster_is_taken_from_above_where_no_side_is_free() -> None:
    # Two bottles 7.5 cm away at +-60 degrees (1.5 cm gaps) and a can in front: no approach
    # from the side leaves the fingers room, but above the can and between the two bottles'
    # caps the open fingers fit.
    target = _track(1, "bottle", [0.42, 0.0, 0.1], 0.03, 0.2)
    around = [
        _track(2 + k, "bottle", [0.42 + 0.075 * math.cos(a), 0.075 * math.sin(a), 0.1], 0.03, 0.2)
        for k, a in enumerate(np.radians([60.0, -60.0]))
    ]
    can = _track(5, "other", [0.345, 0.0, 0.06], 0.033, 0.12)
    scene = PlanningScene.build([target, *around, can], None)
    cfg = GrabConfig()
    side_only = plan_grasps(target, scene, cfg, VX300S, allow_top=False)
    assert isinstance(side_only, GraspRefusal)
    assert "from above" not in side_only.reason
    found = plan_grasps(target, scene, cfg, VX300S)
    assert not isinstance(found, GraspRefusal)
    assert all(c.from_above for c in found)
    best = found[0]
    assert best.clearance >= cfg.clearance
    # Pointing down over the bottle, the point between the fingertips below its top.
    T = fk(best.grasp, VX300S)
    assert T[:3, 0] == pytest.approx([0.0, 0.0, -1.0], abs=1e-6)
    assert T[:2, 3] == pytest.approx([0.42, 0.0], abs=1e-6)
    assert target.p_base[2] + 0.05 < T[2, 3] < target.p_base[2] + 0.1
    # Lifted straight up.
    T_lift = fk(best.lift[-1], VX300S)
    assert T_lift[:3, 3] == pytest.approx(T[:3, 3] + [0.0, 0.0, cfg.lift], abs=1e-6)
    # A taller object between the caps blocks the fingers from above too; the refusal says so.
    pole = _track(6, "other", [0.42, 0.075, 0.15], 0.02, 0.3)
    refusal = plan_grasps(
        target, PlanningScene.build([target, *around, can, pole], None), cfg, VX300S
    )
    assert isinstance(refusal, GraspRefusal)
    assert "; from above: blocked by" in refusal.reason
    # grab.top_grasp = false keeps to the side.
    no_top = dataclasses.replace(cfg, top_grasp=False)
    assert isinstance(plan_grasps(target, scene, no_top, VX300S), GraspRefusal)


def test_closing_fingers_are_checked_over_their_whole_travel() -> None:
    # Spheres of several openings are all there: the outermost pad sphere sits at the open
    # finger, the innermost at the finger closed on the bottle.
    q = np.zeros(6)
    closed = 0.033 + FINGER_PAD_INSET
    c_open, _ = arm_spheres(q, VX300S.finger_limits[1])
    c_both, r_both = arm_spheres(q, [VX300S.finger_limits[1], closed])
    assert c_both.shape[1] > c_open.shape[1] and len(r_both) == c_both.shape[1]
    y = np.abs(c_both[0, :, 1])
    assert y.max() == pytest.approx(VX300S.finger_limits[1] - 0.5 * FINGER_PAD_INSET)
    assert np.any(np.isclose(y, closed - 0.5 * FINGER_PAD_INSET))


def _wall(Q: np.ndarray) -> float:
    """A joint-space obstacle: waist within 0.3 rad of zero with the shoulder below 0.5 rad."""
    Q = np.atleast_2d(Q)
    inside = (np.abs(Q[:, 0]) < 0.3) & (Q[:, 1] < 0.5)
    dist = np.where(inside, -0.1, np.maximum(np.abs(Q[:, 0]) - 0.3, Q[:, 1] - 0.5))
    return float(np.min(dist))


def test_joint_path_goes_straight_when_free_and_around_an_obstacle_when_not() -> None:
    a, b = np.array([-1.0, 0.0, 0, 0, 0, 0]), np.array([-0.5, 0.2, 0, 0, 0, 0])
    assert [q.tolist() for q in joint_path(a, b, _wall, 0.0, VX300S, 1.0)] == [
        a.tolist(),
        b.tolist(),
    ]
    goal = np.array([1.0, 0.0, 0, 0, 0, 0])
    path = joint_path(a, goal, _wall, 0.01, VX300S, 2.0)
    assert path is not None and len(path) > 2
    assert path[0].tolist() == a.tolist() and path[-1].tolist() == goal.tolist()
    assert path_free(path, _wall, 0.01)
    assert all(VX300S.within_limits(q) for q in path)
    # Timed within the speed limits: no joint faster than the share of its limit.
    for (q0, q1), t in zip(itertools.pairwise(path), path_times(path, VX300S, 0.3)):
        assert np.all(np.abs(q1 - q0) / (t - 0.3) <= SPEED_FRACTION * VX300S.velocity + 1e-9)


def test_a_far_bottle_in_a_cluster_is_taken_from_above_hovering_just_over_the_tops() -> None:
    # 0.5 m out, bottles 7.5 cm away on either side and a can in front: no side is free, and
    # the arm reaches above the cap pointing down only if the descent starts low: the hover
    # point 6 cm above the tallest top near it (the fingertips, 28.5 mm below that point,
    # 3 cm clear of the tops), not higher.
    target = _track(1, "bottle", [0.5, 0.0, 0.1], 0.03, 0.2)
    around = [
        _track(2 + k, "bottle", [0.5, y, 0.1], 0.03, 0.2) for k, y in enumerate((0.075, -0.075))
    ]
    can = _track(5, "other", [0.425, 0.0, 0.06], 0.033, 0.12)
    scene = PlanningScene.build([target, *around, can], None)
    cfg = GrabConfig()
    assert isinstance(plan_grasps(target, scene, cfg, VX300S, allow_top=False), GraspRefusal)
    found = plan_grasps(target, scene, cfg, VX300S)
    assert not isinstance(found, GraspRefusal), found.reason
    best = found[0]
    assert best.from_above and best.clearance >= cfg.clearance
    T_hover = fk(best.hover, VX300S)
    assert T_hover[:3, 0] == pytest.approx([0.0, 0.0, -1.0], abs=1e-6)
    tallest = max(b.top for b in scene.bodies)  # the tracks' tops, their uncertainty added
    assert tallest < 0.2 + 0.02
    assert T_hover[:3, 3] == pytest.approx([0.5, 0.0, tallest + 0.06], abs=1e-6)
    # The fingers open along the bearing (within 30 degrees), between the neighbours' caps.
    closing = fk(best.grasp, VX300S)[:3, 1]
    assert abs(closing[0]) > math.cos(math.radians(30.0))
