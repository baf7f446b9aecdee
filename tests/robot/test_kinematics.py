"""ViperX-300s kinematics against independent references.

Forward kinematics is checked against a composition of the URDF joint origins (DEVELOPERS.md),
not against M and Slist, and against modern_robotics; IK answers are verified with that URDF
composition too, so a bug shared by our fk and ik cannot hide.
"""

from __future__ import annotations

import modern_robotics as mr
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from armvision.geometry import make_T, pose_error, rot_y, rot_z, rotation_between, skew
from armvision.robot.kinematics import (
    ORIENTATION_TOLERANCE_RAD,
    POSITION_TOLERANCE_M,
    VX300S,
    _sphere_directions,
    fk,
    ik,
    ik_solutions,
    jacobian_space,
    point_jacobian,
)

# (parent-to-child translation, joint axis) from the vx300s URDF, base_link to gripper_link.
URDF_JOINTS = [
    ((0.0, 0.0, 0.079), (0, 0, 1)),  # waist
    ((0.0, 0.0, 0.04805), (0, 1, 0)),  # shoulder
    ((0.05955, 0.0, 0.3), (0, 1, 0)),  # elbow
    ((0.2, 0.0, 0.0), (1, 0, 0)),  # forearm_roll
    ((0.1, 0.0, 0.0), (0, 1, 0)),  # wrist_angle
    ((0.069744, 0.0, 0.0), (1, 0, 0)),  # wrist_rotate -> gripper_link
]
GRIPPER_TO_EE = (0.1072, 0.0, 0.0)  # gripper_link -> ee_gripper_link (via ee_arm_link)


def urdf_fk(q: np.ndarray) -> np.ndarray:
    """T_base_ee by chaining URDF joint frames: T = prod(Trans(origin_i) Rot(axis_i, q_i))."""
    T = np.eye(4)
    for (origin, axis), angle in zip(URDF_JOINTS, q):
        T = T @ make_T(p=origin) @ make_T(Rotation.from_rotvec(np.array(axis) * angle).as_matrix())
    return T @ make_T(p=GRIPPER_TO_EE)


def random_configs(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(VX300S.lower, VX300S.upper, size=(n, 6))


def assert_reaches(q: np.ndarray, T_target: np.ndarray) -> None:
    dp, dr = pose_error(urdf_fk(q), T_target)
    assert dp <= POSITION_TOLERANCE_M, f"position off by {dp * 1000:.3f} mm"
    assert dr <= ORIENTATION_TOLERANCE_RAD, f"orientation off by {np.degrees(dr):.4f} deg"
    assert VX300S.within_limits(q)


def test_fk_matches_urdf_joint_chain():
    for q in random_configs(300, seed=1):
        np.testing.assert_allclose(fk(q), urdf_fk(q), atol=1e-12)


def test_fk_home_is_M_and_sleep_is_folded():
    np.testing.assert_allclose(fk(np.zeros(6)), VX300S.M, atol=1e-15)
    np.testing.assert_allclose(fk(VX300S.home), urdf_fk(np.zeros(6)), atol=1e-12)
    # Hand-worked: sleep tucks the gripper back over the base, low and inside 0.2 m.
    p_sleep = fk(VX300S.sleep)[:3, 3]
    assert np.hypot(p_sleep[0], p_sleep[1]) < 0.2 and p_sleep[2] < 0.25


def test_fk_batch_equals_single_and_modern_robotics():
    Q = random_configs(50, seed=2)
    T_batch = fk(Q)
    for q, T in zip(Q, T_batch):
        np.testing.assert_allclose(T, fk(q), atol=1e-14)
        np.testing.assert_allclose(T, mr.FKinSpace(VX300S.M, VX300S.Slist.T, q), atol=1e-12)


def test_fk_rejects_wrong_joint_count():
    with pytest.raises(ValueError, match="6 joints"):
        fk(np.zeros(5))


def test_space_jacobian_matches_modern_robotics_and_finite_differences():
    for q in random_configs(20, seed=3):
        J = jacobian_space(q)
        np.testing.assert_allclose(J, mr.JacobianSpace(VX300S.Slist.T, q), atol=1e-12)
        # Column i is the spatial twist of d/dq_i: [V] = dT/dq_i T^-1.
        T = fk(q)
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = 1e-7
            dT = (fk(q + dq) - fk(q - dq)) / 2e-7
            V = dT @ np.linalg.inv(T)
            twist = np.array([V[2, 1], V[0, 2], V[1, 0], *V[:3, 3]])
            np.testing.assert_allclose(J[:, i], twist, atol=1e-6)


def test_point_jacobian_is_fk_and_its_finite_differences():
    """The ee point's Jacobian (the one fusion and the follow servo use) against central
    differences of fk at random joint vectors: Jv columns are dp/dq_i, Jw columns omega_i
    with [omega_i] = dR/dq_i R^T; and against the space Jacobian, Jv = J_v,s - [p] J_w."""
    h = 1e-7
    for q in random_configs(50, seed=5):
        T, Jv, Jw = point_jacobian(q)
        np.testing.assert_allclose(T, fk(q), atol=1e-12)
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = h
            T0, T1 = fk(q - dq), fk(q + dq)
            np.testing.assert_allclose(Jv[:, i], (T1[:3, 3] - T0[:3, 3]) / (2 * h), atol=1e-7)
            W = (T1[:3, :3] - T0[:3, :3]) / (2 * h) @ T[:3, :3].T
            np.testing.assert_allclose(Jw[:, i], [W[2, 1], W[0, 2], W[1, 0]], atol=1e-7)
        J = jacobian_space(q)
        np.testing.assert_allclose(Jw, J[:3], atol=1e-12)
        np.testing.assert_allclose(Jv, J[3:] - skew(T[:3, 3]) @ J[:3], atol=1e-12)


def test_ik_round_trip_on_10000_random_configurations():
    Q = random_configs(10_000, seed=4)
    targets = fk(Q)
    ok_count = 0
    for T in targets:
        q, ok = ik(T)
        if ok:
            ok_count += 1
            assert_reaches(q, T)
    assert ok_count / len(targets) >= 0.995, f"IK succeeded on {ok_count} of {len(targets)}"


def test_ik_returns_the_solution_nearest_the_seed():
    for q_true in random_configs(200, seed=5):
        T = fk(q_true)
        # Seeded with the configuration itself, IK gives it back.
        q, ok = ik(T, q_seed=q_true)
        assert ok
        np.testing.assert_allclose(q, q_true, atol=1e-7)
        # Seeded elsewhere, the answer is the closest of all solutions.
        seed = np.random.default_rng(int(q_true[0] * 1e6) % 2**32).uniform(
            VX300S.lower, VX300S.upper
        )
        q, ok = ik(T, q_seed=seed)
        assert ok
        distances = [np.linalg.norm(s - seed) for s in ik_solutions(T, seed)]
        assert np.linalg.norm(q - seed) == pytest.approx(min(distances))


def test_ik_finds_several_distinct_solutions_for_a_generic_pose():
    T = fk(np.array([0.3, -0.2, 0.4, 0.5, 0.6, -0.3]))
    solutions = ik_solutions(T)
    assert len(solutions) >= 2
    for q in solutions:
        assert_reaches(q, T)


def test_ik_never_reports_ok_for_unreachable_targets():
    rng = np.random.default_rng(6)
    for _ in range(200):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        # Farther than the arm's full length (0.3059 + 0.3 + 0.1769 m from the shoulder).
        p = np.array([0.0, 0.0, 0.12705]) + direction * rng.uniform(0.8, 2.0)
        T = make_T(Rotation.random(random_state=rng).as_matrix(), p)
        seed = rng.uniform(VX300S.lower, VX300S.upper)
        q, ok = ik(T, q_seed=seed)
        assert not ok
        np.testing.assert_array_equal(q, seed)  # nothing to move to: the seed comes back


def test_ik_respects_joint_limits():
    """Targets made from configurations beyond the limits: any answer must be within limits."""
    rng = np.random.default_rng(7)
    span = VX300S.upper - VX300S.lower
    refused = 0
    for _ in range(500):
        q_out = rng.uniform(VX300S.lower - 0.3 * span, VX300S.upper + 0.3 * span)
        q_out[[0, 3, 5]] = np.clip(q_out[[0, 3, 5]], -3.0, 3.0)  # full-turn joints can't exceed
        T = fk(q_out)
        q, ok = ik(T)
        if ok:
            assert_reaches(q, T)
        else:
            refused += 1
    assert refused > 0  # some of these poses are truly out of limits


def test_ik_position_priority_reaches_position_with_nearest_orientation():
    directions = _sphere_directions(40_000)
    cases = [
        ((0.3, 0.0, 0.1), rot_z(np.pi)),  # gripper pointing back at the base
        ((0.6, 0.1, 0.05), rot_y(-np.pi / 2)),  # far out, pointing up
        ((0.2, 0.0, 0.05), np.eye(3)),  # close and low, level
    ]
    for p, R in cases:
        T = make_T(R, p)
        _, ok_full = ik(T)
        assert not ok_full, "this orientation is meant to be unreachable"
        q, ok = ik(T, position_priority=True)
        assert ok
        dp, dr = pose_error(urdf_fk(q), T)
        assert dp <= POSITION_TOLERANCE_M
        # Brute force over ~1 degree-spaced approach directions: the best reachable one.
        x = R[:, 0]
        order = np.argsort(-(directions @ x))
        best = next(
            np.arccos(np.clip(directions[k] @ x, -1, 1))
            for k in order
            if ik_solutions(make_T(rotation_between(x, directions[k]) @ R, p))
        )
        assert dr <= best + np.radians(1.0)


def test_ik_position_priority_keeps_exact_answer_when_reachable_and_refuses_far_targets():
    q_true = np.array([0.2, 0.1, -0.3, 0.4, 0.5, 0.6])
    q, ok = ik(fk(q_true), q_seed=q_true, position_priority=True)
    assert ok
    np.testing.assert_allclose(q, q_true, atol=1e-7)
    _, ok = ik(make_T(p=(2.0, 0.0, 0.0)), position_priority=True)
    assert not ok


def test_ik_rejects_malformed_targets():
    with pytest.raises(ValueError):
        ik(np.eye(3))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ValueError):
        ik(bad)
