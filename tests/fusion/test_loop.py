"""The fusion loop: one cycle at a time with a fake clock and arm (truth known), and the
thread, with only coarse timing checks."""

from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np
import pytest

from armvision.config import Config, FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.loop import FusionLoop
from armvision.geometry import inv_T, make_T, rpy_to_R
from armvision.robot.kinematics import fk

T_BASE_CAM = make_T(rpy_to_R(-2.1, 0.0, math.pi / 2), [1.0, 0.0, 0.45])
T_EE_TAG = make_T(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [-0.1, 0, 0.03])


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class FakeArm:
    """Joint angles moving smoothly in time; readings exact (the truth is fk of them)."""

    def __init__(self, clock) -> None:
        self.clock = clock
        self.fail = False

    def q_true(self, t: float) -> np.ndarray:
        return np.array([0.2 * math.sin(t), -0.3, 0.4, 0.0, 0.9 + 0.1 * math.cos(t), 0.0])

    def get_joint_positions(self) -> np.ndarray:
        if self.fail:
            raise RuntimeError("servo bus timeout")
        return self.q_true(self.clock())

    def get_joint_velocities(self) -> None:
        return None  # like SimArm and Interbotix: positions only


class Detection:
    """What the loop reads from a perception Detection."""

    def __init__(self, center_cam, label="bottle", score=0.9) -> None:
        self.center_cam, self.label, self.score = np.asarray(center_cam), label, score


def test_cycles_fuse_encoders_tags_and_detections_into_immutable_snapshots():
    clock = FakeClock()
    arm = FakeArm(clock)
    loop = FusionLoop(Config(), arm, T_BASE_CAM, T_EE_TAG, clock=clock)
    assert loop.snapshot().ee is None and loop.snapshot().cycles == 0
    T_cam_base = inv_T(T_BASE_CAM)
    bottle_base = np.array([0.4, -0.1, 0.1])
    for k in range(200):
        clock.t = k * 0.01
        if k % 3 == 0:  # a camera frame captured 20 ms ago, processed now
            t_frame = max(clock.t - 0.02, 0.0)
            loop.push_tag(t_frame, T_cam_base @ fk(arm.q_true(t_frame)) @ T_EE_TAG)
            p_cam = T_cam_base[:3, :3] @ bottle_base + T_cam_base[:3, 3]
            loop.push_detections(t_frame, [Detection(p_cam)])
        snap = loop.step()
    assert snap.cycles == 200 and snap.time == pytest.approx(1.99)
    truth = fk(arm.q_true(clock.t))
    assert np.linalg.norm(snap.ee.p_base - truth[:3, 3]) < 0.001
    assert np.linalg.norm(snap.T_base_ee[:3, 3] - truth[:3, 3]) < 0.001
    assert np.allclose(snap.T_base_ee[:3, :3], truth[:3, :3], atol=0.01)
    assert snap.ee_stats.late_replayed > 0  # the tags came in late and were replayed
    assert [tr.id for tr in snap.tracks] == [1]
    assert np.linalg.norm(snap.tracks[0].p_base - bottle_base) < 0.002
    assert snap.tracks[0].label == "bottle" and snap.tracks[0].confirmed
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.cycles = 0  # type: ignore[misc]
    with pytest.raises(ValueError):
        snap.ee.p_base[0] = 0.0
    with pytest.raises(ValueError):
        snap.tracks[0].cov[0, 0] = 0.0
    assert loop.snapshot() is snap


def test_the_thread_runs_at_about_its_rate_and_stops():
    clock = time.monotonic
    arm = FakeArm(clock)
    config = FusionConfig(rate_hz=200.0)
    loop = FusionLoop(config, arm, T_BASE_CAM, T_EE_TAG, clock=clock)
    stop_pushing = threading.Event()

    def camera_thread() -> None:  # pushes tag poses from another thread meanwhile
        T_cam_base = inv_T(T_BASE_CAM)
        while not stop_pushing.is_set():
            t = clock()
            loop.push_tag(t, T_cam_base @ fk(arm.q_true(t)) @ T_EE_TAG)
            time.sleep(0.03)

    pusher = threading.Thread(target=camera_thread)
    with loop:
        pusher.start()
        time.sleep(0.5)
        running = loop.snapshot()
        stop_pushing.set()
        pusher.join()
    stopped = loop.snapshot()
    assert running.running and running.error is None
    assert 20 <= running.cycles <= 150  # 200 Hz for 0.5 s, coarse: a busy machine is slow
    assert not stopped.running and not loop.running
    assert stopped.ee is not None and stopped.ee_stats.updates > 20
    truth = fk(arm.q_true(stopped.time))[:3, 3]
    assert np.linalg.norm(stopped.ee.p_base - truth) < 0.002


def test_a_failure_in_the_thread_is_reported_not_lost():
    clock = time.monotonic
    arm = FakeArm(clock)
    loop = FusionLoop(FusionConfig(), arm, T_BASE_CAM, T_EE_TAG, clock=clock)
    loop.start()
    time.sleep(0.05)
    arm.fail = True
    deadline = time.monotonic() + 2.0
    while loop.running and time.monotonic() < deadline:
        time.sleep(0.01)
    snap = loop.snapshot()
    assert not snap.running and not loop.running
    assert "servo bus timeout" in snap.error
    loop.stop()
    assert "servo bus timeout" in loop.snapshot().error


def test_bad_arguments_raise_fusion_errors():
    clock = FakeClock()
    with pytest.raises(FusionError, match="get_joint_positions"):
        FusionLoop(FusionConfig(), object(), T_BASE_CAM, T_EE_TAG, clock=clock)
    loop = FusionLoop(FusionConfig(), FakeArm(clock), T_BASE_CAM, T_EE_TAG, clock=clock)
    with pytest.raises(FusionError, match="T_cam_tag"):
        loop.push_tag(0.0, np.eye(3))
    with pytest.raises(FusionError, match="Detection"):
        loop.push_detections(0.0, [np.zeros(3)])
    with pytest.raises(FusionError, match="ObjectMeasurement"):
        loop.push_object_measurements(0.0, [np.zeros(3)])


def test_an_object_at_the_fingers_is_not_fused_and_one_beside_them_is() -> None:
    """Hand-worked: the gripper at home points along +x with its fingertips' point at
    (0.536, 0, 0.427) and its pads from 0.498 to 0.566 m along x. A bottle 0.2 m tall whose
    top (0.50 m) is above the gripper's point is in the gripper when its axis is within 5 cm
    of the pads (4 cm ahead of their tips, between them, 4.9 cm beside them), not at 6 cm;
    nor when its top is 3 cm below the gripper's point or its foot above it."""
    from armvision.fusion.loop import in_gripper
    from armvision.fusion.tracker import ObjectMeasurement

    T_home = fk(np.zeros(6))
    np.testing.assert_allclose(T_home[:3, 3], [0.536494, 0.0, 0.42705], atol=1e-9)

    def bottle(x: float, y: float, z_centre: float) -> ObjectMeasurement:
        return ObjectMeasurement([x, y, z_centre], np.eye(3) * 1e-6, "bottle", height=0.2)

    assert in_gripper(bottle(0.566 + 0.04, 0.0, 0.40), T_home)
    assert in_gripper(bottle(0.52, 0.0, 0.40), T_home)  # between the pads
    assert in_gripper(bottle(0.50, 0.049, 0.40), T_home)  # beside the pads
    assert not in_gripper(bottle(0.566 + 0.06, 0.0, 0.40), T_home)
    assert not in_gripper(bottle(0.52, 0.06, 0.40), T_home)
    assert not in_gripper(bottle(0.52, 0.0, 0.40 - 0.1 - 0.03), T_home)  # top 3 cm below
    assert not in_gripper(bottle(0.52, 0.0, 0.427 + 0.1 + 0.01), T_home)  # foot above
