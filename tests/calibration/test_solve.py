"""Solvers against hand-made ground truth: exact recovery without noise, every method."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tests.calibration.helpers import OFFSET, T_BASE_CAM, joint_samples, samples

from armvision.calibration.solve import DEFAULT_METHOD, METHODS, solve, solve_points, tag_points
from armvision.errors import CalibrationError
from armvision.geometry import inv_T, make_T, pose_error
from armvision.robot.tag_mount import tag_mount


def naive_svd(p_cam, p_base):
    """The textbook R = V U^T without the determinant check."""
    c_cam, c_base = p_cam.mean(0), p_base.mean(0)
    U, _, Vt = np.linalg.svd((p_cam - c_cam).T @ (p_base - c_base))
    return Vt.T @ U.T


def test_solve_points_recovers_a_known_transform_exactly():
    rng = np.random.default_rng(1)
    p_cam = rng.uniform(-0.5, 0.5, (12, 3)) + np.array([0.0, 0.0, 1.0])
    p_base = p_cam @ T_BASE_CAM[:3, :3].T + T_BASE_CAM[:3, 3]
    fit = solve_points(p_cam, p_base)
    np.testing.assert_allclose(fit.T_base_cam, T_BASE_CAM, atol=1e-12)
    assert fit.residuals.max() < 1e-12


@pytest.mark.parametrize("n", [3, 4, 8])
def test_coplanar_points_where_a_naive_svd_reflects(n):
    """Coplanar points (the phase-1 circle is one): H has a zero singular value, and
    V U^T can come out with det -1. solve_points must still return the true rotation."""
    found_reflection = False
    for seed in range(40):
        rng = np.random.default_rng(seed)
        angles = rng.uniform(-math.pi, math.pi, n)
        p_base = np.column_stack([0.4 * np.cos(angles), 0.4 * np.sin(angles), np.full(n, 0.2)])
        R = Rotation.random(random_state=seed).as_matrix()
        T = make_T(R, rng.uniform(-1, 1, 3))
        p_cam = (p_base - T[:3, 3]) @ R  # p_cam = R^T (p_base - t)
        naive = naive_svd(p_cam, p_base)
        found_reflection |= np.linalg.det(naive) < 0
        fit = solve_points(p_cam, p_base)
        assert np.linalg.det(fit.T_base_cam[:3, :3]) == pytest.approx(1.0)
        np.testing.assert_allclose(fit.T_base_cam, T, atol=1e-9)
    assert found_reflection, "the case must include configurations where naive SVD reflects"


def test_reflection_fix_is_on_the_smallest_singular_direction_not_a_sign_flip_of_R():
    """With noise, Umeyama's correction is the least-squares rotation: no other rotation
    (e.g. the naive answer with a column negated) fits better."""
    rng = np.random.default_rng(3)
    angles = rng.uniform(-math.pi, math.pi, 6)
    p_base = np.column_stack([0.4 * np.cos(angles), 0.4 * np.sin(angles), np.full(6, 0.2)])
    p_cam = (p_base - T_BASE_CAM[:3, 3]) @ T_BASE_CAM[:3, :3] + rng.normal(0, 0.002, (6, 3))
    fit = solve_points(p_cam, p_base)
    best = np.sum(fit.residuals**2)
    for _ in range(200):  # random nearby rotations, translation re-solved for each
        R = Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix() @ fit.T_base_cam[:3, :3]
        t = (p_base - p_cam @ R.T).mean(0)
        assert np.sum(np.linalg.norm(p_cam @ R.T + t - p_base, axis=1) ** 2) >= best - 1e-15
    naive = naive_svd(p_cam, p_base)
    if np.linalg.det(naive) < 0:
        flipped = naive.copy()
        flipped[:, 2] *= -1
        t = (p_base - p_cam @ flipped.T).mean(0)
        assert np.sum(np.linalg.norm(p_cam @ flipped.T + t - p_base, axis=1) ** 2) >= best


def test_weights_pick_the_trusted_points():
    rng = np.random.default_rng(4)
    p_cam = rng.uniform(-0.4, 0.4, (10, 3))
    p_base = p_cam @ T_BASE_CAM[:3, :3].T + T_BASE_CAM[:3, 3]
    p_base[0] += [0.05, 0, 0]  # one bad point
    weights = np.ones(10)
    weights[0] = 0.0
    fit = solve_points(p_cam, p_base, weights)
    np.testing.assert_allclose(fit.T_base_cam, T_BASE_CAM, atol=1e-12)
    assert fit.residuals[0] == pytest.approx(0.05)


def test_degenerate_and_bad_input_is_refused():
    line = np.outer(np.linspace(0, 1, 5), [1.0, 2.0, 3.0])
    with pytest.raises(CalibrationError, match="one line"):
        solve_points(line, line + 1)
    with pytest.raises(CalibrationError, match="at least 3"):
        solve_points(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(CalibrationError, match="pair up"):
        solve_points(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(CalibrationError, match="non-finite"):
        solve_points(np.full((4, 3), np.nan), np.zeros((4, 3)))
    with pytest.raises(CalibrationError, match="unknown calibration method"):
        solve(*samples(), method="magic")


@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_recovers_the_camera_without_noise(method):
    q, T_be, T_ct = joint_samples()
    fit = solve(T_be, T_ct, method, OFFSET, joint_positions=q)
    # Matrices, not pose_error: its arccos resolves angles only to ~1e-8 rad near zero.
    np.testing.assert_allclose(fit.T_base_cam, T_BASE_CAM, atol=1e-9)
    np.testing.assert_allclose(fit.offset_ee, OFFSET, atol=1e-9)
    assert fit.max_m < 1e-9


def test_robust_svd_drops_a_bad_sample_and_says_so():
    T_be, T_ct = samples(seed=5)
    rng = np.random.default_rng(5)
    T_ct[:, :3, 3] += rng.normal(0, 0.0005, (len(T_ct), 3))
    T_ct[7, :3, 3] += [0.0, 0.03, 0.0]  # a 3 cm mis-detection
    plain = solve(T_be, T_ct, "svd", OFFSET)
    robust = solve(T_be, T_ct, "robust_svd", OFFSET)
    assert robust.dropped == [7]
    assert "sample 7 dropped" in robust.notes[0]
    assert (
        pose_error(robust.T_base_cam, T_BASE_CAM)[0]
        < 0.5 * pose_error(plain.T_base_cam, T_BASE_CAM)[0]
    )
    assert pose_error(robust.T_base_cam, T_BASE_CAM)[0] < 0.001


def test_joint_refinement_survives_a_wrong_tag_offset():
    """The mount is really 1 cm off what the configuration says: SVD is biased, the joint
    fit finds both the camera and the true offset."""
    true_offset = OFFSET + np.array([0.006, -0.005, 0.006])
    T_be, T_ct = samples(seed=6, offset=true_offset)
    rng = np.random.default_rng(6)
    T_ct[:, :3, 3] += rng.normal(0, 0.0003, (len(T_ct), 3))
    svd = solve(T_be, T_ct, "svd", OFFSET)
    joint = solve(T_be, T_ct, "joint", OFFSET)
    assert pose_error(svd.T_base_cam, T_BASE_CAM)[0] > 0.004
    assert pose_error(joint.T_base_cam, T_BASE_CAM)[0] < 0.001
    np.testing.assert_allclose(joint.offset_ee, true_offset, atol=0.001)


def test_joint_keeps_the_configured_offset_when_orientations_do_not_vary():
    T_be, T_ct = samples()
    T_be[:, :3, :3] = T_be[0, :3, :3]  # every sample with the same ee orientation
    T_ct = np.array([inv_T(T_BASE_CAM) @ T @ tag_mount(OFFSET) for T in T_be])
    fit = solve(T_be, T_ct, "joint", OFFSET)
    np.testing.assert_allclose(fit.offset_ee, OFFSET)
    assert any("too alike" in note for note in fit.notes)


def test_tag_points_pairs_the_centres():
    T_be, T_ct = samples(n=3)
    p_cam, p_base = tag_points(T_be, T_ct, OFFSET)
    for i in range(3):
        np.testing.assert_allclose(p_base[i], (T_be[i] @ tag_mount(OFFSET))[:3, 3])
        np.testing.assert_allclose(p_cam[i], T_ct[i][:3, 3])


def test_joint_kinematic_finds_encoder_zero_offsets():
    """Encoders whose zeros are off by up to 0.3 deg (not the waist: a waist offset is a turn
    of the base that no camera can see). The rigid methods are bent by the offsets; the
    kinematic one recovers the camera, the tag offset and the joint offsets."""
    bias = np.radians([0.0, 0.3, -0.25, 0.2, -0.3, 0.0])
    q, T_be, T_ct = joint_samples(n=24, seed=8, bias=bias)
    joint = solve(T_be, T_ct, "joint", OFFSET)
    kinematic = solve(T_be, T_ct, "joint_kinematic", OFFSET, joint_positions=q)
    assert pose_error(joint.T_base_cam, T_BASE_CAM)[0] > 0.001
    np.testing.assert_allclose(kinematic.T_base_cam, T_BASE_CAM, atol=1e-7)
    np.testing.assert_allclose(kinematic.joint_offsets, bias, atol=1e-7)
    np.testing.assert_allclose(kinematic.offset_ee, OFFSET, atol=1e-7)
    assert any("joint zero offsets" in note for note in kinematic.notes)


def test_joint_kinematic_needs_the_joint_readings():
    T_be, T_ct = samples()
    with pytest.raises(CalibrationError, match="joint readings"):
        solve(T_be, T_ct, "joint_kinematic", OFFSET)
    with pytest.raises(CalibrationError, match=r"\(20, 6\) finite angles"):
        solve(T_be, T_ct, "joint_kinematic", OFFSET, joint_positions=np.zeros((3, 6)))


def test_the_configuration_offers_exactly_the_solvers_there_are():
    """calibration.method is a Literal in config (which must not import OpenCV); keep the two
    lists in step."""
    import typing

    from armvision.config import CalibrationConfig

    offered = typing.get_args(typing.get_type_hints(CalibrationConfig)["method"])
    assert set(offered) == set(METHODS)
    assert CalibrationConfig().method == DEFAULT_METHOD
