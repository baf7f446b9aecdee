"""The robot's self-mask: link capsules placed by forward kinematics, points inside dropped."""

from __future__ import annotations

import numpy as np

from armvision.geometry import inv_T, make_T, rot_x, transform_points
from armvision.perception.selfmask import arm_capsules_base, segment_distances, self_mask
from armvision.robot.kinematics import VX300S, fk


def test_arm_capsules_follow_forward_kinematics() -> None:
    """A capsule end at the home ee position, moved by all six joints, lands on fk(q)."""
    q = np.array([0.4, -0.6, 0.8, 0.3, 0.5, -0.2])
    capsules = (((0.0, 0.0, 0.0), tuple(VX300S.M[:3, 3]), 0.01, 6),)
    _, b, _ = arm_capsules_base(q, capsules)
    assert np.allclose(b[0], fk(q)[:3, 3], atol=1e-12)


def test_segment_distances() -> None:
    a, b = np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    p = np.array([[0.5, 2.0, 0.0], [-3.0, 4.0, 0.0], [1.0, 0.0, 0.5]])
    np.testing.assert_allclose(segment_distances(p, a, b)[:, 0], [2.0, 5.0, 0.5])


def test_self_mask_drops_the_gripper_the_base_and_the_far_table() -> None:
    """Points (camera frame) on the end effector, on the base, on the table beside the arm
    and beyond the workspace: only the table beside the arm is kept; without joint angles
    the end effector is kept (only the base, which does not move, is known)."""
    T_base_cam = make_T(rot_x(-2.0), [0.9, 0.0, 0.5])
    q = np.array([0.5, 0.2, -0.1, 0.0, 0.4, 0.0])
    p_base = np.array(
        [
            fk(q)[:3, 3],  # the end effector
            [0.0, 0.0, 0.06],  # the base
            [0.3, -0.45, 0.0],  # the table beside the arm
            [1.2, 0.4, 0.0],  # beyond the 0.85 m workspace
        ]
    )
    p_cam = transform_points(inv_T(T_base_cam), p_base)
    kw = {"workspace_radius": 0.85, "margin": 0.02}
    assert self_mask(p_cam, T_base_cam, q, **kw).tolist() == [False, False, True, False]
    assert self_mask(p_cam, T_base_cam, None, **kw).tolist() == [True, False, True, False]
    assert self_mask(np.empty((0, 3)), T_base_cam, q, **kw).shape == (0,)


def test_self_mask_is_the_distance_to_every_capsule_by_brute_force() -> None:
    """20 000 random points around the arm at a random pose: kept exactly when within the
    workspace and farther than radius + margin from every capsule's segment, as the
    distances of :func:`segment_distances` to all capsules at once say (points within 1e-9 m
    of a limit left out of the comparison)."""
    rng = np.random.default_rng(11)
    T_base_cam = make_T(rot_x(-2.1), [0.8, 0.1, 0.55])
    q = rng.uniform(-0.8, 0.8, 6)
    p_base = rng.uniform([-0.3, -0.9, -0.05], [0.95, 0.9, 0.7], (20_000, 3))
    margin, workspace = 0.02, 0.85
    a, b, radii = arm_capsules_base(q)
    distances = segment_distances(p_base, a, b) - (radii + margin)
    reach = np.hypot(p_base[:, 0], p_base[:, 1]) - workspace
    want = (reach < 0) & (distances >= 0).all(axis=1)
    clear = (np.abs(reach) > 1e-9) & (np.abs(distances) > 1e-9).all(axis=1)
    in_capsule = (reach < 0) & (distances < 0).any(axis=1) & clear
    assert in_capsule.sum() > 200 and (want & clear).sum() > 1000
    got = self_mask(
        transform_points(inv_T(T_base_cam), p_base),
        T_base_cam,
        q,
        workspace_radius=workspace,
        margin=margin,
    )
    np.testing.assert_array_equal(got[clear], want[clear])
