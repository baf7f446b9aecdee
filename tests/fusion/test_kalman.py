"""Kalman filters against independent references: filterpy, hand-worked cases, Monte Carlo
and synthetic motions whose truth is known."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.integrate import quad_vec
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from armvision.camera.frames import depth_rms_error
from armvision.config import FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.kalman import (
    EEFilter,
    Measurement,
    MotionFilter,
    PaperKF,
    camera_point_covariance,
    encoder_covariance,
    encoder_joint_variance,
    joseph_update,
    motion_model,
    point_jacobian,
)
from armvision.geometry import inv_T, make_T, rpy_to_R, skew
from armvision.robot.kinematics import VX300S, fk, jacobian_space

T_BASE_CAM = make_T(rpy_to_R(-2.1, 0.05, 1.6), [1.0, 0.02, 0.45])
T_EE_TAG = make_T(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [-0.1, 0, 0.03])


# --------------------------------------------------------------------------- the paper's filter


def test_paper_kf_matches_filterpy_step_by_step():
    """Same A, C1, C2, R, Q in filterpy's KalmanFilter: equal x and P after every step."""
    dt = 0.01
    paper = PaperKF(T_BASE_CAM, dt=dt)
    ref = KalmanFilter(dim_x=7, dim_z=4)
    ref.x = paper.x.reshape(7, 1).copy()
    ref.P = paper.P.copy()
    ref.F = paper.A.copy()
    ref.Q = paper.Q.copy()
    rng = np.random.default_rng(3)
    T_cam_base = inv_T(T_BASE_CAM)
    for k in range(400):
        t = k * dt
        p_true = np.array([0.35 + 0.1 * math.sin(t), 0.1 * math.cos(2 * t), 0.2 + 0.05 * t])
        p_enc = p_true + rng.normal(0.0, 0.002, 3)
        p_cam = T_cam_base[:3, :3] @ p_true + T_cam_base[:3, 3] + rng.normal(0.0, 0.001, 3)
        use_cam, use_enc = k % 3 == 0, k % 3 != 0 or k % 7 == 0  # alternate, sometimes both
        paper.step(p_base=p_enc if use_enc else None, p_cam=p_cam if use_cam else None)
        ref.predict()
        if use_enc:
            ref.update(np.append(p_enc, 1.0).reshape(4, 1), R=paper.R1, H=paper.C1)
        if use_cam:
            ref.update(np.append(p_cam, 1.0).reshape(4, 1), R=paper.R2, H=paper.C2)
        np.testing.assert_allclose(paper.x, ref.x.ravel(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(paper.P, ref.P, rtol=0, atol=1e-9)
    assert abs(paper.x[3] - 1.0) < 1e-9  # the homogeneous coordinate stays 1
    assert np.linalg.norm(paper.position - p_true) < 0.01


def test_paper_kf_matrices_are_the_papers():
    paper = PaperKF(T_BASE_CAM, dt=0.02)
    A = np.eye(7)
    A[0, 4] = A[1, 5] = A[2, 6] = 0.02
    np.testing.assert_array_equal(paper.A, A)
    np.testing.assert_array_equal(paper.C1, np.hstack([np.eye(4), np.zeros((4, 3))]))
    np.testing.assert_allclose(paper.C2[:, :4], np.linalg.inv(T_BASE_CAM), atol=1e-12)
    np.testing.assert_array_equal(paper.R2, np.diag([1e-4, 1e-4, 1e-4, 1e-12]))
    assert paper.Q[3].tolist() == [0.0] * 7  # no noise on the homogeneous coordinate
    with pytest.raises(FusionError, match="dt"):
        PaperKF(T_BASE_CAM, dt=0.0)
    with pytest.raises(FusionError, match="shape"):
        PaperKF(np.eye(3))


# --------------------------------------------------------------------------- building blocks


def test_joseph_update_hand_worked_scalar():
    # x = 0, P = 4, z = 2, H = 1, R = 1: K = 0.8, x = 1.6, P = 0.2^2 * 4 + 0.8^2 * 1 = 0.8.
    x, P, S = joseph_update(np.zeros(1), np.array([[4.0]]), np.array([2.0]), np.eye(1), np.eye(1))
    assert x[0] == pytest.approx(1.6)
    assert P[0, 0] == pytest.approx(0.8)
    assert S[0, 0] == pytest.approx(5.0)


def test_joseph_update_keeps_the_covariance_symmetric_positive_definite():
    """The paper's 1e-12 variance next to 1e-4 ones, 2000 updates with random geometry."""
    rng = np.random.default_rng(0)
    x, P = np.zeros(7), np.diag([1.0, 1.0, 1.0, 1e-12, 1.0, 1.0, 1.0])
    R = np.diag([1e-4, 1e-4, 1e-4, 1e-12])
    motion = np.ix_([0, 1, 2, 4, 5, 6], [0, 1, 2, 4, 5, 6])
    F, Q = motion_model(0.01, 2, 0.1)
    for _ in range(2000):
        P[motion] = F @ P[motion] @ F.T + Q
        H = np.hstack([make_T(Rotation.random(random_state=rng).as_matrix()), np.zeros((4, 3))])
        x, P, _ = joseph_update(x, P, rng.normal(0, 0.01, 4), H, R)
        assert np.array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > -1e-18


@pytest.mark.parametrize("order", [2, 3])
def test_motion_model_is_the_integral_of_the_white_noise_model(order):
    """Q = int_0^dt F(s) G q G^T F(s)^T ds (Bar-Shalom 6.2), integrated numerically."""
    dt, density = 0.37, 1.7
    F, Q = motion_model(dt, order, density)

    def F1(s: float) -> np.ndarray:
        return motion_model(s, order, density)[0][::3, ::3]  # one axis

    G = np.zeros((order, 1))
    G[-1, 0] = 1.0
    Q1, _ = quad_vec(lambda s: F1(s) @ G @ G.T @ F1(s).T * density**2, 0.0, dt)
    np.testing.assert_allclose(Q[::3, ::3], Q1, rtol=1e-9)
    np.testing.assert_allclose(F[::3, ::3], F1(dt))
    assert F[0, 3] == pytest.approx(dt) and F[1, 1] == 1.0 and F[0, 1] == 0.0


def test_point_jacobian_is_fk_and_the_space_jacobian_at_the_ee_point():
    """Against kinematics.fk / jacobian_space and a finite difference of fk."""
    rng = np.random.default_rng(7)
    for q in rng.uniform(VX300S.lower, VX300S.upper, (20, 6)):
        T, Jv, Jw = point_jacobian(q)
        J = jacobian_space(q)
        np.testing.assert_allclose(T, fk(q), atol=1e-12)
        np.testing.assert_allclose(Jw, J[:3], atol=1e-12)
        np.testing.assert_allclose(Jv, J[3:] - skew(T[:3, 3]) @ J[:3], atol=1e-12)
        h = 1e-7
        fd = np.column_stack(
            [(fk(q + h * e)[:3, 3] - fk(q - h * e)[:3, 3]) / (2 * h) for e in np.eye(6)]
        )
        np.testing.assert_allclose(Jv, fd, atol=1e-7)


def test_encoder_covariance_matches_monte_carlo_through_forward_kinematics():
    """Joint noise pushed through fk (20000 samples) has the covariance Jv S Jv^T."""
    rng = np.random.default_rng(1)
    q = np.array([0.3, -0.4, 0.5, 0.2, 0.8, -0.3])
    sigma = math.radians(0.1)
    _, Jv, _ = point_jacobian(q)
    samples = fk(q + rng.normal(0.0, sigma, (20000, 6)))[:, :3, 3]
    empirical = np.cov(samples.T)
    predicted = encoder_covariance(Jv, sigma**2)
    assert np.linalg.norm(empirical - predicted) < 0.05 * np.linalg.norm(predicted)
    # Counts of 2 pi / 4096 add step^2 / 12 to each joint's variance.
    step = 2 * math.pi / 4096
    assert encoder_joint_variance(sigma) == pytest.approx(sigma**2 + step**2 / 12)


def test_camera_point_covariance_hand_worked():
    z, s_px, f = 0.8, 0.5, 615.0
    cov = camera_point_covariance([0.0, 0.0, z], s_px, f, depth_scale=1.0)
    lateral = z * s_px / f
    along = float(depth_rms_error(z))  # 0.8^2 * 0.08 / (424 * 0.05) = 2.4 mm
    np.testing.assert_allclose(cov, np.diag([lateral**2, lateral**2, along**2]), atol=1e-15)
    # Off-axis: the largest eigenvector is the viewing ray, stretched from z to range.
    p = np.array([0.3, -0.2, 0.7])
    w, v = np.linalg.eigh(camera_point_covariance(p, s_px, f))
    assert abs(v[:, -1] @ p) / np.linalg.norm(p) == pytest.approx(1.0)
    r = np.linalg.norm(p)
    assert math.sqrt(w[-1]) == pytest.approx(float(depth_rms_error(0.7)) * r / 0.7)
    assert math.sqrt(w[0]) == pytest.approx(r * s_px / f)


# --------------------------------------------------------------------------- the motion filter


def _position(source: str, z: np.ndarray, sigma: float, n: int = 6) -> Measurement:
    H = np.zeros((3, n))
    H[:, :3] = np.eye(3)
    return Measurement(source, z, H, np.eye(3) * sigma**2)


def test_motion_filter_is_consistent_on_a_static_point():
    """NEES over 200 Monte Carlo runs averages 3 (chi-square, 3 dof) and errors shrink."""
    rng = np.random.default_rng(2)
    sigma, truth = 0.003, np.array([0.4, -0.1, 0.05])
    nees, final_errors = [], []
    for _ in range(200):
        # The truth is still: a model with (almost) no motion noise is the right model.
        f = MotionFilter(noise_density=1e-9, adaptive=False)
        z0 = truth + rng.normal(0, sigma, 3)
        P0 = np.diag([sigma**2] * 3 + [1e-14] * 3)
        f.initialize(0.0, np.concatenate([z0, np.zeros(3)]), P0)
        for k in range(1, 50):
            f.predict(k * 0.033)
            f.update([_position("camera", truth + rng.normal(0, sigma, 3), sigma)])
        e = f.x[:3] - truth
        nees.append(e @ np.linalg.solve(f.P[:3, :3], e))
        final_errors.append(np.linalg.norm(e))
    lo, hi = chi2.ppf([0.005, 0.995], 3 * 200) / 200  # two-sided 99 % interval of the mean
    assert lo < np.mean(nees) < hi
    assert np.sqrt(np.mean(np.square(final_errors))) < sigma * math.sqrt(3) / 3


def test_gate_rejects_an_outlier_and_counts_it():
    rng = np.random.default_rng(4)
    f = MotionFilter(noise_density=0.01)
    truth = np.array([0.3, 0.0, 0.1])
    f.initialize(0.0, np.concatenate([truth, np.zeros(3)]), np.eye(6) * 1e-6)
    for k in range(1, 20):
        f.predict(k * 0.01)
        f.update([_position("camera", truth + rng.normal(0, 0.001, 3), 0.001)])
    f.predict(0.2)
    before = f.x.copy()
    accepted = f.update([_position("camera", truth + np.array([0.1, 0.0, 0.0]), 0.001)])
    assert accepted == [False]
    assert f.stats.rejected == {"camera": 1}
    assert np.linalg.norm(f.x[:3] - before[:3]) < 1e-6


def test_a_run_of_rejections_restarts_the_filter_on_the_source():
    """An object put down 20 cm away: after max_rejections the track jumps to it."""
    f = MotionFilter(noise_density=0.01, max_rejections=4)
    f.initialize(0.0, np.zeros(6), np.eye(6) * 1e-6)
    moved = np.array([0.2, 0.0, 0.0])
    results = []
    for k in range(1, 8):
        f.predict(k * 0.033)
        results.append(f.update([_position("camera", moved, 0.002)])[0])
    assert results[:3] == [False, False, False] and all(results[3:])
    assert f.stats.restarts == 1
    assert np.linalg.norm(f.x[:3] - moved) < 0.002


def test_adaptive_process_noise_follows_a_manoeuvre_and_settles_after():
    """Still, then 3 m/s^2 for 0.4 s, then cruising, with low nominal process noise: adaptive
    noise follows the manoeuvre after its onset where fixed noise keeps losing it, and is back
    to nominal once the motion is smooth again."""
    rng = np.random.default_rng(5)
    dt, sigma = 0.01, 0.001

    def truth(t: float) -> np.ndarray:
        a, t0, t1 = 3.0, 1.0, 1.4
        if t < t0:
            x = 0.0
        elif t < t1:
            x = 0.5 * a * (t - t0) ** 2
        else:
            x = 0.5 * a * (t1 - t0) ** 2 + a * (t1 - t0) * (t - t1)
        return np.array([x, 0.0, 0.0])

    noise = rng.normal(0, sigma, (300, 3))
    errors, restarts = {}, {}
    for adaptive in (False, True):
        f = MotionFilter(noise_density=0.05, adaptive=adaptive, gate_probability=0.9999)
        f.initialize(0.0, np.zeros(6), np.eye(6) * 1e-6)
        err, scales = [], []
        for k in range(1, 300):
            t = k * dt
            f.predict(t)
            f.update([_position("encoders", truth(t) + noise[k], sigma)])
            err.append(np.linalg.norm(f.x[:3] - truth(t)))
            scales.append(f.q_scale)
        errors[adaptive], restarts[adaptive] = np.array(err), f.stats.restarts
        if adaptive:
            assert max(scales[100:140]) > 10.0  # raised during the manoeuvre
            assert scales[-1] == 1.0  # back to nominal while cruising

    def rmse(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e**2)))

    # Both lose the onset (the gate cannot tell it from an outlier) and restart once ...
    assert restarts[True] == 1 < restarts[False]
    # ... then adaptive noise follows the rest of the manoeuvre, fixed noise does not.
    assert rmse(errors[True][120:200]) < 0.5 * rmse(errors[False][120:200])
    assert rmse(errors[True][120:200]) < 2 * sigma
    # Still and cruising, both are the same smooth filter.
    assert rmse(errors[True][:99]) == pytest.approx(rmse(errors[False][:99]))
    assert rmse(errors[True][220:]) < 1.5 * sigma


def test_constant_acceleration_model_follows_steady_acceleration_without_lag():
    """x = t^2 / 2 (1 m/s^2): the CA model's error stays at the noise level, CV lags."""
    rng = np.random.default_rng(6)
    sigma, errors = 0.001, {}
    for order in (2, 3):
        f = MotionFilter(order=order, noise_density=0.05, adaptive=False, gate_probability=None)
        f.initialize(0.0, np.zeros(3 * order), np.eye(3 * order) * 1e-6)
        err = []
        for k in range(1, 200):
            t = k * 0.01
            truth = np.array([0.5 * t * t, 0.0, 0.0])
            f.predict(t)
            f.update([_position("encoders", truth + rng.normal(0, sigma, 3), sigma, 3 * order)])
            err.append(f.x[0] - truth[0])
        errors[order] = np.array(err[100:])
    assert abs(np.mean(errors[3])) < 0.3 * sigma  # no lag
    assert np.mean(errors[2]) < -1.5 * sigma  # behind the target
    ee = EEFilter(FusionConfig(motion_model="ca"), T_BASE_CAM, T_EE_TAG)
    assert ee.core.n == 9 + 6 + 6


# --------------------------------------------------------------------------- the ee filter


def _synthetic_run(seed: int, seconds: float = 12.0):
    """A smooth joint-space motion with truth, biased noisy encoders and a miscalibrated,
    noisy camera seeing the tag (truth from fk: no rendering)."""
    rng = np.random.default_rng(seed)
    dt = 0.01
    t = np.arange(0.0, seconds, dt)
    q_mid = np.array([0.0, -0.2, 0.3, 0.0, 1.1, 0.0])
    amp = np.array([0.35, 0.15, 0.15, 0.3, 0.25, 0.4])
    freq = rng.uniform(0.08, 0.25, 6)
    phase = rng.uniform(0, 2 * math.pi, 6)
    q_true = q_mid + amp * np.sin(2 * math.pi * freq * t[:, None] + phase)
    bias = np.radians(0.3) * rng.uniform(-1, 1, 6)
    q_enc = q_true + bias + rng.normal(0, math.radians(0.1), q_true.shape)
    q_enc = np.round(q_enc / (2 * math.pi / 4096)) * (2 * math.pi / 4096)
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    dT = make_T(
        Rotation.from_rotvec(math.radians(0.2) * axis / np.linalg.norm(axis)).as_matrix(),
        0.002 * direction / np.linalg.norm(direction),
    )
    T_est = T_BASE_CAM @ dT
    T_cam_base = inv_T(T_BASE_CAM)
    frames = []
    for k in range(0, len(t), 3):  # ~33 Hz
        T_cam_tag = T_cam_base @ fk(q_true[k]) @ T_EE_TAG
        noise = make_T(
            Rotation.from_rotvec(rng.normal(0, math.radians(0.4), 3)).as_matrix(),
            rng.normal(0, 0.0005, 3),
        )
        frames.append((t[k], T_cam_tag @ noise))
    p_true = fk(q_true)[:, :3, 3]
    return t, q_enc, frames, p_true, T_est, bias


def _run_filter(ee: EEFilter, t, q_enc, frames, latency: float = 0.0):
    """Encoders every tick; each tag pose once ``latency`` seconds have passed since its frame."""
    out = []
    pending = list(frames)
    for k in range(len(t)):
        if ee.use_encoders:
            ee.update_encoders(t[k], q_enc[k])
        while ee.use_camera and pending and pending[0][0] <= t[k] - latency + 1e-9:
            ee.update_camera(*pending.pop(0))
        out.append(ee.estimate(t[k]).p_base if ee.time is not None else np.full(3, np.nan))
    for frame in pending if ee.use_camera else ():  # the last ones arrive after the end
        ee.update_camera(*frame)
    return np.array(out)


def test_fused_filter_beats_each_source_on_a_biased_synthetic_motion():
    """Truth from fk; encoders biased (zero offsets up to 0.3 deg), camera miscalibrated (2 mm,
    0.2 deg): on every one of five seeds the fused RMSE is below the better single-source
    filter, and pooled over them by at least 20 %. (Per seed the margin depends on how the
    two biases happen to fall; the acceptance in the simulator is ``armvision eval fusion``.)
    """
    config = FusionConfig()
    squared = {"fused": [], "best single": []}
    for seed in range(5):
        t, q_enc, frames, p_true, T_est, _ = _synthetic_run(seed, seconds=10.0)
        rmse = {}
        for name, kw in {
            "fused": {},
            "camera": {"use_encoders": False},
            "encoders": {"use_camera": False},
        }.items():
            est = _run_filter(EEFilter(config, T_est, T_EE_TAG, **kw), t, q_enc, frames)
            ok = np.all(np.isfinite(est), axis=1)
            rmse[name] = math.sqrt(np.mean(np.sum((est[ok] - p_true[ok]) ** 2, axis=1)))
        best = min(rmse["camera"], rmse["encoders"])
        assert rmse["fused"] < best, (seed, rmse)
        squared["fused"].append(rmse["fused"] ** 2)
        squared["best single"].append(best**2)
    pooled = {k: math.sqrt(np.mean(v)) for k, v in squared.items()}
    assert pooled["fused"] < 0.8 * pooled["best single"], pooled


def test_late_camera_measurements_are_replayed_to_the_in_order_result():
    t, q_enc, frames, _, T_est, _ = _synthetic_run(7, seconds=3.0)
    config = FusionConfig()
    late_filter = EEFilter(config, T_est, T_EE_TAG)
    # Tag poses arrive 5 ticks (50 ms) after their frame, behind newer encoder readings.
    in_order_filter = EEFilter(config, T_est, T_EE_TAG)
    _run_filter(in_order_filter, t, q_enc, frames)
    _run_filter(late_filter, t, q_enc, frames, latency=0.05)
    assert late_filter.stats.late_replayed > 50
    # Once every late pose is in, the estimate is the in-order one.
    a, b = late_filter.estimate(), in_order_filter.estimate()
    np.testing.assert_allclose(a.p_base, b.p_base, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.cov, b.cov, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.encoder_bias, b.encoder_bias, rtol=0, atol=1e-9)
    # Older than history_s: dropped and counted, the state untouched.
    before = late_filter.estimate().p_base.copy()
    late_filter.update_camera(t[-1] - 2 * config.history_s, frames[-1][1])
    assert late_filter.stats.late_dropped == 1
    np.testing.assert_array_equal(late_filter.estimate().p_base, before)


def test_same_time_measurements_are_one_update_whatever_their_arrival_order():
    t, q_enc, frames, _, T_est, _ = _synthetic_run(8, seconds=1.0)
    config = FusionConfig()
    a, b = EEFilter(config, T_est, T_EE_TAG), EEFilter(config, T_est, T_EE_TAG)
    a.update_encoders(t[0], q_enc[0])  # both start from the same first measurement
    b.update_encoders(t[0], q_enc[0])
    for k in range(3, len(t), 3):  # camera frames on encoder ticks: both present together
        t_frame, T_cam_tag = frames[k // 3]
        a.update_encoders(t[k], q_enc[k])
        a.update_camera(t_frame, T_cam_tag)
        b.update_camera(t_frame, T_cam_tag)
        b.update_encoders(t[k], q_enc[k])
    np.testing.assert_allclose(a.estimate().p_base, b.estimate().p_base, atol=1e-12)
    np.testing.assert_allclose(a.estimate().cov, b.estimate().cov, atol=1e-15)


def test_ee_filter_estimate_is_read_only_and_carries_the_biases():
    t, q_enc, frames, _, T_est, _ = _synthetic_run(9, seconds=1.0)
    ee = EEFilter(FusionConfig(), T_est, T_EE_TAG)
    _run_filter(ee, t, q_enc, frames)
    est = ee.estimate()
    assert est.encoder_bias.shape == (6,) and est.camera_correction.shape == (6,)
    assert est.cov.shape == (6, 6) and est.sigma_mm > 0
    with pytest.raises(ValueError):
        est.p_base[0] = 1.0
    T = ee.T_base_ee(q_enc[-1])
    np.testing.assert_allclose(T[:3, 3], est.p_base)


def test_bad_input_raises_fusion_errors_that_say_what_is_wrong():
    ee = EEFilter(FusionConfig(), T_BASE_CAM, T_EE_TAG)
    with pytest.raises(FusionError, match=r"shape \(6,\)"):
        ee.update_encoders(0.0, np.zeros(5))
    with pytest.raises(FusionError, match="non-finite"):
        ee.update_encoders(0.0, [0, 0, np.nan, 0, 0, 0])
    with pytest.raises(FusionError, match="finite time"):
        ee.update_encoders(math.inf, np.zeros(6))
    with pytest.raises(FusionError, match="shape"):
        ee.update_camera(0.0, np.eye(3))
    with pytest.raises(FusionError, match="no measurement"):
        ee.estimate()
    with pytest.raises(FusionError, match="without the camera"):
        EEFilter(FusionConfig(), T_BASE_CAM, T_EE_TAG, use_camera=False).update_camera(
            0.0, np.eye(4)
        )
    with pytest.raises(FusionError, match="at least one source"):
        EEFilter(FusionConfig(), T_BASE_CAM, T_EE_TAG, use_camera=False, use_encoders=False)
    f = MotionFilter()
    f.initialize(1.0, np.zeros(6), np.eye(6))
    with pytest.raises(FusionError, match="back in time"):
        f.predict(0.5)


def test_config_rejects_bad_fusion_values():
    from armvision.config import load_config
    from armvision.errors import ConfigError

    with pytest.raises(ConfigError, match=r"fusion\.confirm_window"):
        load_config(None, ["fusion.confirm_hits=6"])
    with pytest.raises(ConfigError, match=r"fusion\.gate_probability"):
        load_config(None, ["fusion.gate_probability=1.5"])
    with pytest.raises(ConfigError, match=r"fusion\.motion_model"):
        load_config(None, ["fusion.motion_model=jerky"])
    assert load_config(None, ["fusion.rate_hz=50"]).fusion.rate_hz == 50.0
    assert VX300S.dof == 6


def test_the_tag_orientation_corrects_the_camera_only_from_face_on_sightings():
    """A tag seen at a slant has its orientation degrees off (its position is not), so only
    sightings within 40 deg of facing the camera may turn the camera correction: an oblique
    sighting whose orientation is 0.5 deg wrong (within the gate) leaves the filter where the
    true one does; a face-on one with the same error turns the correction."""
    from armvision.fusion.drift import facing

    def view_angle(T_cam_tag):
        ray = T_cam_tag[:3, 3] / np.linalg.norm(T_cam_tag[:3, 3])
        return math.degrees(math.acos(abs(T_cam_tag[:3, 2] @ ray)))

    poses = {}
    for wrist in np.linspace(-1.5, 1.5, 61):
        for roll in np.linspace(-1.5, 1.5, 13):
            q = np.array([0.1, -0.3, 0.4, roll, wrist, 0.0])
            T_cam_tag = inv_T(T_BASE_CAM) @ fk(q, VX300S) @ T_EE_TAG
            angle = view_angle(T_cam_tag)
            if angle < 20 and "face-on" not in poses:
                poses["face-on"] = (q, T_cam_tag)
            if 55 < angle < 70 and "oblique" not in poses:
                poses["oblique"] = (q, T_cam_tag)
    assert set(poses) == {"face-on", "oblique"}
    assert facing(poses["face-on"][1]) and not facing(poses["oblique"][1])
    # Turned 0.5 deg about the line from the tag to the end effector: the end effector's point,
    # and so the position measurement, stay the same; only the orientation is wrong.
    lever = inv_T(T_EE_TAG)[:3, 3]
    wrong = np.eye(4)
    wrong[:3, :3] = Rotation.from_rotvec(
        math.radians(0.5) * lever / np.linalg.norm(lever)
    ).as_matrix()
    turned = {}
    for name, (q, T_cam_tag) in poses.items():
        corrections = []
        for seen in (T_cam_tag, T_cam_tag @ wrong):
            ee = EEFilter(FusionConfig(), T_BASE_CAM, T_EE_TAG)
            ee.update_encoders(0.0, q)
            ee.update_encoders(0.01, q)
            ee.update_camera(0.005, seen)
            ee.update_encoders(0.02, q)
            corrections.append(ee.estimate().camera_correction[:3])
        turned[name] = float(np.linalg.norm(corrections[1] - corrections[0]))
    assert turned["oblique"] < 1e-12, turned  # the same to rounding
    assert turned["face-on"] > math.radians(0.01), turned
