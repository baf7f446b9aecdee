"""The whole calibration in simulation, judged against the simulator's camera pose."""

from __future__ import annotations

import dataclasses
import logging
import math
import re

import numpy as np
import pytest

from armvision.bench.system import calibrate_sim
from armvision.calibration.procedure import solve_all
from armvision.calibration.quality import assess, check_quality
from armvision.calibration.sampling import PlannedPose, Sampler, circular_mean, phase1_plan
from armvision.camera.placement import camera_pose_from_placement
from armvision.config import CalibrationConfig, Config, SimConfig, TagConfig
from armvision.errors import CalibrationError
from armvision.geometry import make_T, pose_error
from armvision.robot.tag_mount import R_EE_TAG

# Encoder noise but no zero-offset bias: a waist offset is indistinguishable from a turn of
# the base for any camera-based calibration (see README, "Calibration").
CONFIG = Config(sim=SimConfig(min_objects=0, max_objects=0, encoder_bias_deg=0.0))
OFFSET_EE = np.asarray(CONFIG.tag.offset_ee)
CAMERA = camera_pose_from_placement(1.15, math.radians(25), 0.55, math.radians(22))


@pytest.fixture(scope="module")
def result():
    return calibrate_sim(CONFIG, seed=3, T_base_cam=CAMERA)


def test_the_default_method_finds_the_camera_within_millimetres(result):
    dp, dr = pose_error(result.T_base_cam, CAMERA)
    assert result.method == "joint_kinematic"
    assert dp < 0.003 and math.degrees(dr) < 0.3
    assert result.truth["translation_error_mm"] == pytest.approx(1000 * dp)
    assert len(result.samples) >= CONFIG.calibration.min_samples
    assert 1000 * result.fit.rms_m < 2.0


def test_phase_one_finds_the_camera_azimuth(result):
    assert abs(math.degrees(result.sampling.camera_azimuth) - 25) < 20
    # Poses facing away from the camera were skipped, each with a line that says why.
    assert any("tag seen in 0 of 5 frames" in s for s in result.sampling.skipped)
    phases = {s.phase for s in result.samples}
    assert phases == {1, 2, 3}


def test_every_method_answers_on_the_same_samples(result):
    assert set(result.fits) == set(result.truth["methods"])
    for name, fit in result.fits.items():
        assert not isinstance(fit, str), f"{name} failed: {fit}"
        assert len(fit.residuals) == len(result.samples)
    svd = result.truth["methods"]["svd"]
    assert svd["translation_error_mm"] < 3.0  # the paper's method on our samples


def test_a_mount_one_centimetre_off_still_gives_millimetres(result):
    """The same samples solved with a configured offset 1 cm from the true mount."""
    wrong = np.asarray(CONFIG.tag.offset_ee) + np.array([0.6, -0.6, 0.529]) / 100
    assert np.linalg.norm(wrong - CONFIG.tag.offset_ee) == pytest.approx(0.01, abs=1e-4)
    fits = solve_all(result.samples, wrong, 0.005, 6)
    dp_joint, dr_joint = pose_error(fits["joint"].T_base_cam, CAMERA)
    dp_svd, _ = pose_error(fits["svd"].T_base_cam, CAMERA)
    assert dp_joint < 0.003 and math.degrees(dr_joint) < 0.3
    assert dp_svd > 2 * dp_joint  # the paper's SVD is biased by the wrong mount
    np.testing.assert_allclose(fits["joint"].offset_ee, CONFIG.tag.offset_ee, atol=0.002)


def test_a_tag_the_camera_never_sees_is_a_clear_error():
    config = dataclasses.replace(CONFIG, tag=dataclasses.replace(CONFIG.tag, id=5))
    # The simulation mounts tag 96; the calibration looks for 5.
    world_config = CONFIG
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    with SimWorld(world_config, 0) as world, SimCamera(world) as camera:
        sampler = Sampler(SimArm(world), camera, config.calibration, config.tag, wait=world.advance)
        with pytest.raises(CalibrationError, match=r"tag \(id 5, tag36h11\) was not seen"):
            sampler.run()


def test_an_unreachable_pose_is_skipped_with_a_log_line(caplog):
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    far = PlannedPose(2, 0.0, 0.2, make_T(R_EE_TAG, [1.2, 0.0, 0.2]))
    with SimWorld(CONFIG, 0) as world, SimCamera(world) as camera:
        arm = SimArm(world)
        q_before = arm.get_joint_positions()
        sampler = Sampler(arm, camera, CONFIG.calibration, CONFIG.tag, wait=world.advance)
        with caplog.at_level(logging.INFO, logger="armvision.calibration.sampling"):
            assert sampler.visit(far) is None
        assert "unreachable, skipped" in caplog.text
        assert sampler.skipped == [
            "phase 2 pose at azimuth 0 deg, height 0.20 m: unreachable, skipped"
        ]
        np.testing.assert_allclose(arm.get_joint_positions(), q_before, atol=0.01)


def test_too_few_samples_is_an_error_that_lists_what_went_wrong():
    cal = CalibrationConfig(phase2_azimuths=1, phase2_heights=(0.2,), extra_poses=0, min_samples=12)
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    with SimWorld(CONFIG, 0) as world, SimCamera(world) as camera:
        sampler = Sampler(SimArm(world), camera, cal, TagConfig(), wait=world.advance)
        with pytest.raises(CalibrationError, match=r"good samples, 12 needed.*Skipped: phase 1"):
            sampler.run()


def test_the_phase_one_plan_is_the_papers():
    plan = phase1_plan(CalibrationConfig())
    azimuths = [p.azimuth for p in plan]
    expected = np.arange(-math.pi, math.pi, math.pi / 4)
    np.testing.assert_allclose(azimuths, expected, atol=2e-3)  # -pi nudged inside the waist limit
    for pose in plan:
        p = pose.T_base_ee[:3, 3]
        assert math.hypot(p[0], p[1]) == pytest.approx(0.4)
        assert p[2] == pytest.approx(0.2)
        # The tag (facing +z_ee) is tilted pi/3 from straight up, towards the outside.
        z = pose.T_base_ee[:3, 2]
        assert math.degrees(math.acos(z[2])) == pytest.approx(60.0)
        outward = np.array([math.cos(pose.azimuth), math.sin(pose.azimuth), 0.0])
        assert z @ outward == pytest.approx(math.sin(math.pi / 3))


def test_circular_mean_wraps():
    assert circular_mean([math.radians(170), math.radians(-170)]) == pytest.approx(math.pi)
    assert circular_mean([-0.2, 0.0, 0.2]) == pytest.approx(0.0, abs=1e-12)


def test_facing_pose_puts_the_tag_centre_in_place_facing_the_camera():
    from armvision.calibration.sampling import facing_pose
    from armvision.robot.tag_mount import tag_mount

    p_tag, p_cam = np.array([0.3, -0.25, 0.15]), np.array([1.1, 0.3, 0.5])
    for spin in (0.0, 0.7, -1.2):
        T_base_tag = facing_pose(p_tag, p_cam, OFFSET_EE, spin=spin) @ tag_mount(OFFSET_EE)
        np.testing.assert_allclose(T_base_tag[:3, 3], p_tag, atol=1e-12)
        # The tag's z points into the tag, away from the camera that looks at its face.
        away = (p_tag - p_cam) / np.linalg.norm(p_tag - p_cam)
        np.testing.assert_allclose(T_base_tag[:3, 2], away, atol=1e-12)


# ---------------------------------------------------------------- plausibility (quality.py)


def resolved(result, samples, tag=None):
    """``result`` solved again on ``samples`` (told about ``tag``, default its own)."""
    tag = tag or result.tag
    cal = CONFIG.calibration
    fits = solve_all(samples, tag.offset_ee, cal.outlier_mm / 1000, cal.min_samples)
    assert not isinstance(fits[result.method], str), fits[result.method]
    sampling = dataclasses.replace(result.sampling, samples=samples)
    return dataclasses.replace(
        result, fit=fits[result.method], fits=fits, sampling=sampling, tag=tag
    )


def test_a_normal_simulated_calibration_is_plausible_with_margin(result):
    quality = check_quality(result, CONFIG.calibration, "rerun")
    assert quality.ok and quality.problems == ()
    assert quality.residual_rms_mm < 0.3 * CONFIG.calibration.max_residual_rms_mm
    assert quality.sample_spread_m > 2 * CONFIG.calibration.min_sample_spread_m
    assert quality.tag_offset_error_mm < 0.1 * CONFIG.calibration.max_tag_offset_error_mm


def test_a_wrong_tag_size_is_refused_for_its_residual(result):
    """The real samples as a tag.size 25 % too large would have measured them: every detected
    distance 25 % longer, which no rigid transform explains."""
    scaled = tuple(
        dataclasses.replace(s, T_cam_tag=make_T(s.T_cam_tag[:3, :3], 1.25 * s.T_cam_tag[:3, 3]))
        for s in result.samples
    )
    wrong = resolved(result, scaled)
    with pytest.raises(CalibrationError) as info:
        check_quality(wrong, CONFIG.calibration, "rerun, or pass --force to keep it")
    message = str(info.value)
    assert re.match(
        r"calibration refused: residual \d+\.\d mm RMS exceeds calibration\.max_residual_rms_mm"
        r" = 5 \(is the tag loose, or tag\.size wrong\?\).*; rerun, or pass --force to keep it$",
        message,
    ), message
    assert "\n" not in message
    quality = check_quality(wrong, CONFIG.calibration, "rerun", force=True)
    assert quality.residual_rms_mm > 10 and not quality.ok


def test_a_tag_mount_far_from_the_configured_offset_is_refused(result):
    """Told the tag is 4 cm from where it is mounted: the fit finds the real mount (small
    residual), the offset check sees the disagreement."""
    told = np.asarray(CONFIG.tag.offset_ee) + np.array([0.03, 0.0, 0.03])
    wrong = resolved(result, result.samples, TagConfig(offset_ee=tuple(told)))
    quality = assess(wrong, CONFIG.calibration)
    assert quality.residual_rms_mm < 2.0
    assert quality.tag_offset_error_mm == pytest.approx(42.4, abs=3)
    (problem,) = quality.problems
    assert "from tag.offset_ee, more than calibration.max_tag_offset_error_mm = 25" in problem


def test_samples_bunched_in_one_place_are_refused_for_their_spread(result):
    """Exact samples around one real pose (joints within 0.03 rad): a tiny residual, but
    nothing to fix the rotation by."""
    from armvision.robot.kinematics import fk
    from armvision.robot.tag_mount import tag_mount

    rng = np.random.default_rng(0)
    base = result.samples[0]
    T_cam_base = np.linalg.inv(result.T_base_cam)
    bunched = []
    for _ in range(10):
        q = base.joint_positions + rng.uniform(-0.03, 0.03, 6)
        T_ct = T_cam_base @ fk(q) @ tag_mount(CONFIG.tag.offset_ee)
        bunched.append(
            dataclasses.replace(base, joint_positions=q, T_base_ee=fk(q), T_cam_tag=T_ct)
        )
    quality = assess(resolved(result, tuple(bunched)), CONFIG.calibration)
    assert quality.sample_spread_m < 0.03
    assert any(
        p.startswith("the tag positions spread only")
        and "calibration.min_sample_spread_m = 0.08" in p
        for p in quality.problems
    ), quality.problems
