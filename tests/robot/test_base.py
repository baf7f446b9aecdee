"""The shared Arm logic: trapezoidal timing, limit and velocity checks, IK before moving.

``RecordingArm`` is a minimal test backend: it jumps to each accepted goal and records what it
was asked to execute, so a refused command is visible as nothing recorded.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from armvision.geometry import make_T, pose_error, rpy_to_R
from armvision.robot.base import Arm, ArmBase, GripperBase, TrapezoidalTrajectory
from armvision.robot.kinematics import VX300S, fk


class RecordingGripper(GripperBase):
    def __init__(self) -> None:
        self.position = 0.057

    def open(self, delay: float | None = None) -> None:
        self.position = 0.057

    def close(self, delay: float | None = None) -> None:
        self.position = 0.021

    def get_finger_position(self) -> float:
        return self.position


class RecordingArm(ArmBase):
    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.q = np.zeros(6)
        self.executed: list[TrapezoidalTrajectory] = []
        self.streamed: list[np.ndarray] = []
        self.clock = 0.0
        self.gripper = RecordingGripper()

    def _read_joint_positions(self):
        return self.q.copy()

    def _execute(self, trajectory, blocking):
        self.executed.append(trajectory)
        self.q = trajectory.q_goal.copy()

    def _stream(self, q):
        self.streamed.append(q)
        self.q = q.copy()

    def _now(self):
        return self.clock


def test_trajectory_is_the_hand_worked_trapezoid():
    # 1 rad in 2 s with 0.5 s ramps: cruise speed 1 / 1.5 rad/s.
    traj = TrapezoidalTrajectory.plan([0.0], [1.0], moving_time=2.0, accel_time=0.5)
    v = 1.0 / 1.5
    cases = {
        0.0: (0.0, 0.0),
        0.25: (0.5 * v * 0.25**2 / 0.5, v * 0.5),  # accelerating: v t^2 / (2 ta)
        0.5: (v * 0.25, v),
        1.0: (v * 0.75, v),  # cruising: v (t - ta / 2)
        1.75: (1.0 - 0.5 * v * 0.25**2 / 0.5, v * 0.5),
        2.0: (1.0, 0.0),
        3.0: (1.0, 0.0),
    }
    for t, (pos, vel) in cases.items():
        q, qd = traj.sample(t)
        assert q[0] == pytest.approx(pos, abs=1e-12), t
        assert qd[0] == pytest.approx(vel, abs=1e-12), t
    assert traj.peak_velocity[0] == pytest.approx(v)


def test_trajectory_is_continuous_and_synchronised():
    traj = TrapezoidalTrajectory.plan(np.zeros(6), [1.0, -0.5, 0.2, 0, 2.0, -1.0], 1.5, 0.3)
    ts = np.linspace(0.0, 1.5, 3001)
    Q = np.array([traj.sample(t)[0] for t in ts])
    assert np.max(np.abs(np.diff(Q, axis=0))) < 2.0 / 1.2 * (ts[1] - ts[0]) + 1e-12
    # every joint covers the same fraction of its way at every instant
    frac = Q[:, [0, 1, 4]] / np.array([1.0, -0.5, 2.0])
    np.testing.assert_allclose(frac, frac[:, :1].repeat(3, axis=1), atol=1e-12)


def test_accel_time_longer_than_half_the_move_becomes_a_triangle():
    traj = TrapezoidalTrajectory.plan([0.0], [1.0], moving_time=1.0, accel_time=0.8)
    assert traj.accel_time == 0.5
    assert traj.sample(0.5)[0][0] == pytest.approx(0.5)


def test_recording_arm_satisfies_the_arm_protocol():
    arm = RecordingArm()
    assert isinstance(arm, Arm)
    arm.gripper.grasp()
    assert arm.gripper.get_finger_position() == pytest.approx(0.021)
    arm.gripper.release()
    assert arm.gripper.get_finger_position() == pytest.approx(0.057)


def test_joint_limits_refuse_without_moving():
    arm = RecordingArm()
    q = np.zeros(6)
    q[1] = 1.3  # shoulder upper limit is 1.256637
    assert arm.set_joint_positions(q) is False
    assert arm.executed == []
    assert "shoulder" in arm.last_error
    np.testing.assert_array_equal(arm.get_joint_positions(), np.zeros(6))


def test_velocity_limit_names_the_joint_and_the_moving_time_needed():
    arm = RecordingArm()
    arm.q[0] = -3.0
    goal = np.zeros(6)
    goal[0] = 3.0
    # 6 rad with 0.3 s ramps in 2 s: cruise 6 / 1.7 = 3.53 rad/s > pi.
    assert arm.set_joint_positions(goal, moving_time=2.0) is False
    assert "waist" in arm.last_error
    assert f"{6 / math.pi + 0.3:.2f}" in arm.last_error
    assert arm.executed == []
    assert arm.set_joint_positions(goal, moving_time=2.3) is True
    np.testing.assert_array_equal(arm.get_joint_positions(), goal)


def test_home_and_sleep_use_the_default_timing():
    arm = RecordingArm(moving_time=1.5, accel_time=0.2)
    assert arm.go_to_sleep_pose()
    assert arm.executed[-1].moving_time == 1.5 and arm.executed[-1].accel_time == 0.2
    np.testing.assert_array_equal(arm.get_joint_positions(), VX300S.sleep)
    assert arm.go_to_home_pose(moving_time=3.0)
    assert arm.executed[-1].moving_time == 3.0
    np.testing.assert_array_equal(arm.get_joint_positions(), VX300S.home)


def test_bad_timing_is_refused():
    with pytest.raises(ValueError, match="accel_time"):
        RecordingArm(moving_time=1.0, accel_time=0.6)
    arm = RecordingArm()
    assert arm.set_joint_positions(np.full(6, 0.1), moving_time=-1.0) is False
    assert arm.executed == []


def test_ee_pose_reached_through_ik_and_unreachable_pose_does_not_move():
    arm = RecordingArm()
    T_target = make_T(rpy_to_R(0.0, 0.6, 0.3), [0.35, 0.1, 0.2])
    assert arm.set_ee_pose_matrix(T_target)
    dp, dr = pose_error(arm.get_ee_pose(), T_target)
    assert dp < 1e-6 and dr < 1e-6
    n = len(arm.executed)
    assert arm.set_ee_pose_matrix(make_T(p=[1.5, 0.0, 0.3])) is False
    assert "unreachable" in arm.last_error
    assert len(arm.executed) == n


def test_ee_pose_components_default_yaw_faces_the_target():
    arm = RecordingArm()
    assert arm.set_ee_pose_components(x=0.3, y=0.3, z=0.25, pitch=0.5)
    T = arm.get_ee_pose()
    np.testing.assert_allclose(T[:3, 3], [0.3, 0.3, 0.25], atol=1e-6)
    np.testing.assert_allclose(T[:3, :3], rpy_to_R(0.0, 0.5, math.atan2(0.3, 0.3)), atol=1e-6)


def test_ee_pose_with_unreachable_orientation_needs_position_priority():
    arm = RecordingArm()
    T_target = make_T(rpy_to_R(0.0, 0.0, math.pi), [0.3, 0.0, 0.1])  # pointing at the base
    assert arm.set_ee_pose_matrix(T_target) is False
    assert "position_priority" in arm.last_error
    assert arm.set_ee_pose_matrix(T_target, position_priority=True)
    assert np.linalg.norm(fk(arm.q)[:3, 3] - T_target[:3, 3]) < 1e-4


def test_stream_targets_are_limited_by_velocity_and_elapsed_time():
    arm = RecordingArm()
    step = np.zeros(6)
    step[2] = 0.1  # pi rad/s allows 0.105 rad in 1/30 s
    arm.clock = 0.0
    assert arm.stream_joint_targets(step)
    arm.clock = 1.0 / 30.0
    assert arm.stream_joint_targets(step * 2)
    arm.clock += 1.0 / 30.0
    assert arm.stream_joint_targets(step * 4) is False  # 0.2 rad in 33 ms is too fast
    assert "elbow" in arm.last_error
    assert len(arm.streamed) == 2
    out_of_limits = np.zeros(6)
    out_of_limits[4] = 2.5
    assert arm.stream_joint_targets(out_of_limits) is False
    # A full move clears the stream history; the next target is judged from the encoders.
    assert arm.set_joint_positions(np.zeros(6))
    arm.clock += 10.0
    assert arm.stream_joint_targets(step)
