"""The whole calibration in simulation, judged against the simulator's camera pose."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from armvision.calibration.procedure import calibrate_sim, solve_all
from armvision.calibration.sampling import PlannedPose, Sampler, circular_mean, phase1_plan
from armvision.config import CalibrationConfig, Config, SimConfig, TagConfig
from armvision.errors import CalibrationError
from armvision.geometry import make_T, pose_error
from armvision.perception.tags import R_EE_TAG
from armvision.sim.world import camera_pose_from_placement

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
    from armvision.camera.sim import SimCamera
    from armvision.robot.sim import SimArm
    from armvision.sim.world import SimWorld

    with SimWorld(world_config, 0) as world, SimCamera(world) as camera:
        sampler = Sampler(SimArm(world), camera, config.calibration, config.tag, wait=world.advance)
        with pytest.raises(CalibrationError, match=r"tag \(id 5, tag36h11\) was not seen"):
            sampler.run()


def test_an_unreachable_pose_is_skipped_with_a_log_line(caplog):
    from armvision.camera.sim import SimCamera
    from armvision.robot.sim import SimArm
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
    from armvision.camera.sim import SimCamera
    from armvision.robot.sim import SimArm
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
    from armvision.perception.tags import tag_mount

    p_tag, p_cam = np.array([0.3, -0.25, 0.15]), np.array([1.1, 0.3, 0.5])
    for spin in (0.0, 0.7, -1.2):
        T_base_tag = facing_pose(p_tag, p_cam, OFFSET_EE, spin=spin) @ tag_mount(OFFSET_EE)
        np.testing.assert_allclose(T_base_tag[:3, 3], p_tag, atol=1e-12)
        # The tag's z points into the tag, away from the camera that looks at its face.
        away = (p_tag - p_cam) / np.linalg.norm(p_tag - p_cam)
        np.testing.assert_allclose(T_base_tag[:3, 2], away, atol=1e-12)
