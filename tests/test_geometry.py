"""SE(3) helpers against hand-worked cases and scipy."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from armvision.geometry import (
    R_to_rpy,
    adjoint,
    cross3,
    inv_T,
    make_T,
    pose_error,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle,
    rotation_between,
    rpy_to_R,
    transform_points,
)


def test_elementary_rotations_by_hand():
    np.testing.assert_allclose(rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rot_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot_x(np.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def test_rpy_is_fixed_axis_roll_then_pitch_then_yaw():
    r, p, y = 0.3, -0.4, 1.2
    np.testing.assert_allclose(rpy_to_R(r, p, y), rot_z(y) @ rot_y(p) @ rot_x(r), atol=1e-15)
    np.testing.assert_allclose(R_to_rpy(rpy_to_R(r, p, y)), [r, p, y], atol=1e-12)


def test_inverse_and_composition_follow_the_frame_convention():
    rng = np.random.default_rng(0)
    T_a_b = make_T(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
    T_b_c = make_T(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
    np.testing.assert_allclose(inv_T(T_a_b), np.linalg.inv(T_a_b), atol=1e-12)
    batch = np.stack([T_a_b, T_b_c])
    np.testing.assert_allclose(inv_T(batch), np.linalg.inv(batch), atol=1e-12)
    p_c = rng.normal(size=(5, 3))
    p_a = transform_points(T_a_b @ T_b_c, p_c)
    np.testing.assert_allclose(p_a, transform_points(T_a_b, transform_points(T_b_c, p_c)))


def test_pose_error_and_rotation_angle():
    T_a = make_T(rot_z(0.1), [1.0, 2.0, 3.0])
    T_b = make_T(rot_z(0.1) @ rot_x(0.25), [1.0, 2.0, 3.5])
    dp, dr = pose_error(T_a, T_b)
    assert np.isclose(dp, 0.5) and np.isclose(dr, 0.25)
    assert np.isclose(rotation_angle(rot_y(np.pi)), np.pi)


def test_rotation_between_directions():
    rng = np.random.default_rng(1)
    for _ in range(50):
        a, b = rng.normal(size=3), rng.normal(size=3)
        R = rotation_between(a, b)
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        cos = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
        assert np.isclose(rotation_angle(R), np.arccos(cos))  # the smallest such rotation
    R = rotation_between([1, 0, 0], [-1, 0, 0])
    np.testing.assert_allclose(R @ [1, 0, 0], [-1, 0, 0], atol=1e-12)


def test_adjoint_maps_twists_between_frames():
    rng = np.random.default_rng(2)
    T_a_b = make_T(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
    w, v = rng.normal(size=3), rng.normal(size=3)
    V_b = np.zeros((4, 4))
    V_b[:3, :3] = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    V_b[:3, 3] = v
    V_a = T_a_b @ V_b @ np.linalg.inv(T_a_b)  # [V_a] = T [V_b] T^-1
    twist_a = adjoint(T_a_b) @ np.concatenate([w, v])
    np.testing.assert_allclose(twist_a, [V_a[2, 1], V_a[0, 2], V_a[1, 0], *V_a[:3, 3]], atol=1e-12)


def test_cross3_is_the_cross_product() -> None:
    rng = np.random.default_rng(11)
    for a, b in rng.normal(size=(50, 2, 3)):
        np.testing.assert_allclose(cross3(a, b), np.cross(a, b), rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(cross3([1, 0, 0], [0, 1, 0]), [0.0, 0.0, 1.0])  # x × y = z
