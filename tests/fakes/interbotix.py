"""A FAKE of Interbotix's ROS 2 Python API, for testing ``armvision.robot.interbotix`` without ROS.

This is not the real library. Its classes and method signatures follow
``interbotix_xs_modules.xs_robot.arm.InterbotixManipulatorXS`` (ROS 2 humble): ``bot.core``
with ``joint_states`` / ``js_index_map`` / ``js_mutex``, ``bot.arm`` with ``group_info``,
``set_joint_positions(joint_positions, moving_time=None, accel_time=None, blocking=True) -> bool``,
``go_to_home_pose``, ``go_to_sleep_pose``, ``set_ee_pose_matrix``, ``get_joint_commands``,
``set_trajectory_time``, and ``bot.gripper`` with ``grasp(delay)`` / ``release(delay)``.
Motion is instantaneous: a command sets the joint states to its goal, and every call is
recorded in ``bot.calls`` so tests can check what the real arm would have been sent.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

from armvision.robot.kinematics import VX300S


@dataclass
class FakeJointState:
    """sensor_msgs/JointState, the fields Interbotix reads."""

    name: list[str]
    position: list[float]
    velocity: list[float] = field(default_factory=list)
    effort: list[float] = field(default_factory=list)


@dataclass
class FakeGroupInfo:
    """interbotix_xs_msgs/srv/RobotInfo response for the 'arm' group."""

    joint_names: list[str]
    num_joints: int
    joint_lower_limits: list[float]
    joint_upper_limits: list[float]
    joint_velocity_limits: list[float]
    joint_sleep_positions: list[float]
    profile_type: str = "time"
    mode: str = "position"


class FakeCore:
    """InterbotixRobotXSCore: the joint-state cache the real one fills from /joint_states."""

    def __init__(self, joint_names: list[str]) -> None:
        names = [*joint_names, "left_finger", "right_finger"]
        self.joint_states = FakeJointState(names, [0.0] * len(joint_names) + [0.057, -0.057])
        self.js_index_map = {name: i for i, name in enumerate(names)}
        self.js_mutex = threading.Lock()

    def set_positions(self, names: list[str], values: list[float]) -> None:
        with self.js_mutex:
            for name, value in zip(names, values):
                self.joint_states.position[self.js_index_map[name]] = float(value)


class FakeArm:
    """InterbotixArmXSInterface with the real method signatures and its own limit check."""

    def __init__(
        self,
        core: FakeCore,
        group_info: FakeGroupInfo,
        calls: list,
        moving_time: float = 2.0,
        accel_time: float = 0.3,
    ) -> None:
        self.core = core
        self.group_info = group_info
        self.calls = calls
        self.moving_time, self.accel_time = moving_time, accel_time
        self.joint_commands = [0.0] * group_info.num_joints

    def set_trajectory_time(self, moving_time: float = None, accel_time: float = None) -> None:
        if moving_time is not None:
            self.moving_time = moving_time
        if accel_time is not None:
            self.accel_time = accel_time

    def check_joint_limits(self, positions: list[float]) -> bool:
        # The real one truncates to mrad and compares average speed with the velocity limit.
        theta = [int(x * 1000) / 1000.0 for x in positions]
        for i, value in enumerate(theta):
            if (
                not self.group_info.joint_lower_limits[i]
                <= value
                <= self.group_info.joint_upper_limits[i]
            ):
                return False
            if (
                abs(value - self.joint_commands[i]) / self.moving_time
                > self.group_info.joint_velocity_limits[i]
            ):
                return False
        return True

    def set_joint_positions(
        self,
        joint_positions: list[float],
        moving_time: float = None,
        accel_time: float = None,
        blocking: bool = True,
    ) -> bool:
        self.calls.append(
            ("set_joint_positions", list(joint_positions), moving_time, accel_time, blocking)
        )
        self.set_trajectory_time(moving_time, accel_time)
        if not self.check_joint_limits(joint_positions):
            return False
        self.joint_commands = list(joint_positions)
        self.core.set_positions(self.group_info.joint_names, joint_positions)
        return True

    def go_to_home_pose(
        self, moving_time: float = None, accel_time: float = None, blocking: bool = True
    ) -> None:
        self.calls.append(("go_to_home_pose", moving_time, accel_time, blocking))
        self.joint_commands = [0.0] * self.group_info.num_joints
        self.core.set_positions(self.group_info.joint_names, self.joint_commands)

    def go_to_sleep_pose(
        self, moving_time: float = None, accel_time: float = None, blocking: bool = True
    ) -> None:
        self.calls.append(("go_to_sleep_pose", moving_time, accel_time, blocking))
        self.joint_commands = list(self.group_info.joint_sleep_positions)
        self.core.set_positions(self.group_info.joint_names, self.joint_commands)

    def set_ee_pose_matrix(
        self,
        T_sd: Any,
        custom_guess: list[float] = None,
        execute: bool = True,
        moving_time: float = None,
        accel_time: float = None,
        blocking: bool = True,
    ) -> tuple[list[float], bool]:
        # armvision must never rely on Interbotix's IK; a call here is a test failure.
        raise AssertionError("armvision called Interbotix's set_ee_pose_matrix")

    def get_joint_commands(self) -> list[float]:
        return list(self.joint_commands)


class FakeGripper:
    """InterbotixGripperXSInterface: grasp closes, release opens (PWM mode)."""

    def __init__(self, core: FakeCore, calls: list, gripper_pressure: float = 0.5) -> None:
        self.core = core
        self.calls = calls
        self.gripper_pressure = gripper_pressure

    def set_pressure(self, pressure: float) -> None:
        self.gripper_pressure = pressure

    def grasp(self, delay: float = 1.0) -> None:
        self.calls.append(("grasp", delay))
        self.core.set_positions(["left_finger", "right_finger"], [0.021, -0.021])

    def release(self, delay: float = 1.0) -> None:
        self.calls.append(("release", delay))
        self.core.set_positions(["left_finger", "right_finger"], [0.057, -0.057])


class FakeInterbotixManipulatorXS:
    """InterbotixManipulatorXS(robot_model, group_name, gripper_name, ...) of the real API."""

    def __init__(
        self,
        robot_model: str,
        group_name: str = "arm",
        gripper_name: str = "gripper",
        robot_name: str = None,
        moving_time: float = 2.0,
        accel_time: float = 0.3,
        gripper_pressure: float = 0.5,
        gripper_pressure_lower_limit: int = 150,
        gripper_pressure_upper_limit: int = 350,
        joint_state_topic: str = "joint_states",
        logging_level: Any = None,
        node_name: str = "robot_manipulation",
        start_on_init: bool = True,
        args: Any = None,
        joint_names: list[str] | None = None,
    ) -> None:
        names = list(joint_names or VX300S.joint_names)
        self.robot_model = robot_model
        self.calls: list = []
        self.core = FakeCore(names)
        info = FakeGroupInfo(
            joint_names=names,
            num_joints=len(names),
            joint_lower_limits=VX300S.lower.tolist(),
            joint_upper_limits=VX300S.upper.tolist(),
            joint_velocity_limits=[math.pi] * len(names),
            joint_sleep_positions=VX300S.sleep.tolist(),
        )
        self.arm = FakeArm(self.core, info, self.calls, moving_time, accel_time)
        self.gripper = FakeGripper(self.core, self.calls, gripper_pressure)
        self.shut_down = False

    def shutdown(self) -> None:
        self.shut_down = True
