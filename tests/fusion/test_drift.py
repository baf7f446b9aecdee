"""The camera-moved check: hand-made sightings with a known camera shift, then the simulation
with a real calibration and a camera moved 2 cm or turned 1 degree afterwards."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from armvision.calibration.sampling import facing_pose
from armvision.camera.placement import camera_pose_from_placement
from armvision.config import CalibrationConfig, Config
from armvision.fusion.drift import DriftMonitor, facing, rotation_reference
from armvision.geometry import inv_T, make_T
from armvision.robot.kinematics import fk, ik
from armvision.robot.tag_mount import tag_mount

T_BASE_CAM = camera_pose_from_placement(1.0, 0.0, 0.45, math.radians(30.0))
T_EE_TAG = tag_mount((-0.1, 0.0, 0.03))
OFFSET = np.array([-0.1, 0.0, 0.03])
TAG_AT = np.array([0.35, 0.0, 0.25])
# Joints that show the tag face-on to the camera (its orientation counts only then).
Q, _ok = ik(facing_pose(TAG_AT, T_BASE_CAM[:3, 3], OFFSET))
assert _ok


def _seen(q, T_base_cam_true):
    """T_cam_tag as a camera really at ``T_base_cam_true`` sees the tag at joints ``q``."""
    return inv_T(T_base_cam_true) @ fk(q) @ T_EE_TAG


def _feed(monitor, T_true, t0, seconds, q=Q, hz=30.0):
    t = t0
    while t < t0 + seconds:
        monitor.observe(t, q, _seen(q, T_true))
        t += 1.0 / hz
    return t


def test_agreement_is_zero_and_a_known_shift_is_measured() -> None:
    monitor = DriftMonitor(CalibrationConfig(), T_BASE_CAM, T_EE_TAG)
    t = _feed(monitor, T_BASE_CAM, 0.0, 2.0)
    assert monitor.status.translation_mm == pytest.approx(0.0, abs=1e-6)
    assert not monitor.status.drifted and monitor.status.refusal() is None
    moved = T_BASE_CAM.copy()
    moved[:3, 3] += [0.0, 0.012, -0.016]  # 20 mm
    t = _feed(monitor, moved, t, 1.2)  # the window median has turned, not yet for 1 s
    assert monitor.status.translation_mm == pytest.approx(20.0, abs=1e-6)
    assert not monitor.status.drifted
    t = _feed(monitor, moved, t, 1.5)
    status = monitor.status
    assert status.drifted and status.rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert "has moved" in status.refusal() and "20 mm" in status.refusal()
    _feed(monitor, T_BASE_CAM, t, 3.0)  # put back: cleared the same way
    assert not monitor.status.drifted


def test_a_turn_shows_in_the_rotation_and_small_errors_are_absorbed() -> None:
    cfg = CalibrationConfig()
    turned = T_BASE_CAM @ make_T(Rotation.from_euler("z", 2.5, degrees=True).as_matrix(), [0, 0, 0])
    # Against a calibration whose own samples agreed (zero reference): the turn is seen.
    monitor = DriftMonitor(cfg, T_BASE_CAM, T_EE_TAG, np.zeros(3))
    _feed(monitor, turned, 0.0, 3.0)
    assert monitor.status.rotation_deg == pytest.approx(2.5, abs=1e-6)
    assert monitor.status.drifted
    # Without a reference (a bare transform) the first sightings set it; a turn after is seen.
    learner = DriftMonitor(cfg, T_BASE_CAM, T_EE_TAG)
    t = _feed(learner, T_BASE_CAM @ make_T(np.eye(3), [0, 0, 0]), 0.0, 2.0)
    assert learner.status.rotation_deg == pytest.approx(0.0, abs=1e-6)
    _feed(learner, turned, t, 3.0)
    assert learner.status.drifted and learner.status.rotation_deg == pytest.approx(2.5, abs=1e-6)
    nudged = T_BASE_CAM.copy()
    nudged[:3, 3] += [0.004, 0.0, 0.0]  # 4 mm: the filter's job, not an alarm
    quiet = DriftMonitor(cfg, T_BASE_CAM, T_EE_TAG)
    _feed(quiet, nudged, 0.0, 5.0)
    assert quiet.status.translation_mm == pytest.approx(4.0, abs=1e-6)
    assert not quiet.status.drifted


def test_fast_motion_few_samples_and_outliers_do_not_alarm() -> None:
    cfg = CalibrationConfig()
    moved = T_BASE_CAM.copy()
    moved[:3, 3] += [0.03, 0.0, 0.0]
    monitor = DriftMonitor(cfg, T_BASE_CAM, T_EE_TAG)
    for k in range(200):  # moving at 0.3 m/s: skipped
        monitor.observe(k / 30, Q, _seen(Q, moved), speed_mps=0.3)
    assert monitor.status.samples == 0 and not monitor.status.drifted
    for k in range(cfg.drift_min_samples - 1):  # too few to judge
        monitor.observe(10 + k / 30, Q, _seen(Q, moved))
    assert monitor.status.translation_mm is None and not monitor.status.drifted
    rng = np.random.default_rng(0)
    calm = DriftMonitor(cfg, T_BASE_CAM, T_EE_TAG)
    for k in range(300):  # one sighting in four is a wild one (a flipped pose, a bad frame)
        T = moved if rng.random() < 0.25 else T_BASE_CAM
        calm.observe(k / 30, Q, _seen(Q, T))
    assert not calm.status.drifted


def test_the_rotation_reference_removes_what_the_calibration_already_saw() -> None:
    bias = make_T(Rotation.from_euler("x", 0.8, degrees=True).as_matrix(), [0, 0, 0])
    rng = np.random.default_rng(1)
    qs = [Q + rng.normal(0, 0.05, 6) for _ in range(12)]
    # Every sighting carries the same 0.8 deg orientation error in the camera's frame (what a
    # calibration fitted to tag positions keeps of the camera's rotation).
    samples = [(q, bias @ _seen(q, T_BASE_CAM)) for q in qs]
    reference = rotation_reference(T_BASE_CAM, T_EE_TAG, samples)
    assert math.degrees(np.linalg.norm(reference)) == pytest.approx(0.8, abs=1e-6)
    monitor = DriftMonitor(CalibrationConfig(), T_BASE_CAM, T_EE_TAG, reference)
    for k in range(90):
        monitor.observe(k / 30, Q, bias @ _seen(Q, T_BASE_CAM))
    assert monitor.status.rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert rotation_reference(T_BASE_CAM, T_EE_TAG, []) is None


def test_an_oblique_tag_counts_for_its_position_only() -> None:
    """Seen more than 40 degrees off face-on, a tag's orientation is not trusted."""
    tilt = (np.array([0.0, 0.0, 1.0]), math.radians(60.0))  # turned 60 deg to the side
    q_oblique, ok = ik(facing_pose(TAG_AT, T_BASE_CAM[:3, 3], OFFSET, tilt=tilt))
    assert ok and not facing(_seen(q_oblique, T_BASE_CAM)) and facing(_seen(Q, T_BASE_CAM))
    turned = T_BASE_CAM @ make_T(Rotation.from_euler("z", 3.0, degrees=True).as_matrix(), [0, 0, 0])
    monitor = DriftMonitor(CalibrationConfig(), T_BASE_CAM, T_EE_TAG, np.zeros(3))
    _feed(monitor, turned, 0.0, 3.0, q=q_oblique)
    assert monitor.status.rotation_deg is None and monitor.status.measured
    seen = [(q_oblique, _seen(q_oblique, T_BASE_CAM))]
    assert rotation_reference(T_BASE_CAM, T_EE_TAG, seen) is None


def test_an_uncalibrated_monitor_never_alarms() -> None:
    monitor = DriftMonitor(CalibrationConfig(), T_BASE_CAM, T_EE_TAG, active=False)
    moved = T_BASE_CAM.copy()
    moved[:3, 3] += [0.1, 0.0, 0.0]
    _feed(monitor, moved, 0.0, 5.0)
    assert not monitor.status.drifted and monitor.status.samples == 0


# --------------------------------------------------------------------------- simulation


@pytest.fixture(scope="module")
def calibrated():
    """A real gripper-tag calibration (empty table), then a bench with a bottle on it."""
    from armvision.bench.system import calibrate_empty_table

    config = Config()
    status, _ = calibrate_empty_table(config, seed=2)
    return config, status


def _show_tag(system, config, p):
    cam = system.world.T_base_cam()[:3, 3]
    T = facing_pose(np.array(p), cam, np.array(config.tag.offset_ee))
    status = system.run_task("show", lambda ctx: ctx.move_pose(T, moving_time=1.5))
    assert status.phase == "succeeded"


def _time_to_drift(system, limit_s: float) -> float | None:
    t0 = system.clock()
    while system.clock() - t0 < limit_s:
        system.pump(system.clock() + 0.25)
        if system.snapshot().drift.drifted:
            return system.clock() - t0
    return None


@pytest.mark.parametrize(
    "move",
    [
        ("moved 2 cm", make_T(np.eye(3), [0.012, -0.010, 0.013])),
        (
            "turned 1 deg",
            make_T(
                Rotation.from_rotvec(np.radians(1.0) * np.array([0.6, 0.8, 0.0])).as_matrix(),
                [0, 0, 0],
            ),
        ),
    ],
    ids=["2cm", "1deg"],
)
def test_a_camera_moved_after_calibration_is_reported_and_grab_refuses(calibrated, move) -> None:
    from armvision.bench.system import sim_system
    from armvision.sim.scene import bench_scene
    from armvision.tasks.grab import grab

    config, calibration = calibrated
    label, delta = move
    system = sim_system(config, seed=2, scene=bench_scene(config), calibration=calibration)
    system.start()
    try:
        _show_tag(system, config, [0.32, 0.05, 0.25])
        system.pump(system.clock() + 3.0)
        before = system.snapshot().drift
        assert before.measured and not before.drifted
        assert before.translation_mm < 3.0, before
        T_true = system.world.T_base_cam()
        system.world.set_camera_pose(T_true @ delta)  # knocked, in the camera's own frame
        seconds = _time_to_drift(system, 5.0)
        assert seconds is not None, f"{label}: not reported within 5 s ({system.snapshot().drift})"
        drift = system.snapshot().drift
        status = system.run_task("grab", grab)
        assert status.phase == "failed"
        assert status.error.startswith("the camera has moved since calibration")
        assert "recalibrate" in status.error
        q = system.world.joint_positions()
        system.pump(system.clock() + 0.5)
        assert np.allclose(system.world.joint_positions(), q, atol=0.01)  # nothing moved
        assert drift.translation_mm > config.calibration.drift_mm or (
            drift.rotation_deg > config.calibration.drift_deg
        )
    finally:
        system.close()
