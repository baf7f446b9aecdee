"""The real ViperX-300s through the Interbotix ROS 2 Python API (``interbotix_xs_modules``).

This is the only module that imports Interbotix or ROS 2, and nothing imports it until the real
arm is asked for. It needs the Interbotix ROS 2 (humble) stack running:

    ros2 launch interbotix_xsarm_control xsarm_control.launch.py robot_model:=vx300s

Every check (limits, velocity, IK) happens in :class:`ArmBase` before anything is sent; the arm
then gets plain joint commands through ``bot.arm.set_joint_positions`` (the motors run the
time-based trapezoid themselves), never Interbotix's own IK.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import time
from typing import Any

import numpy as np

from armvision.errors import HardwareError
from armvision.robot.base import (
    DEFAULT_ACCEL_TIME_S,
    DEFAULT_MOVING_TIME_S,
    ArmBase,
    Array,
    GripperBase,
    TrapezoidalTrajectory,
)
from armvision.robot.kinematics import VX300S, ArmModel

log = logging.getLogger("armvision.robot")

#: Streaming uses a short, acceleration-free profile so each target is reached by the next one.
STREAM_MOVING_TIME_S = 0.1

_SETUP_HINT = (
    "install the Interbotix ROS 2 humble stack (interbotix_ros_manipulators), then "
    "`source /opt/ros/humble/setup.bash && source ~/interbotix_ws/install/setup.bash` and start "
    "`ros2 launch interbotix_xsarm_control xsarm_control.launch.py robot_model:=vx300s`"
)


def interbotix_available() -> tuple[bool, str]:
    """Whether the Interbotix Python modules can be imported here, and why not."""
    for module in ("rclpy", "interbotix_xs_modules"):
        try:
            if importlib.util.find_spec(module) is None:
                return False, f"Python module '{module}' not found: {_SETUP_HINT}"
        except (ImportError, ValueError) as exc:
            return False, f"cannot look up '{module}': {exc}"
    return True, "interbotix_xs_modules and rclpy importable"


def _connect(
    model: ArmModel,
    group_name: str,
    gripper_name: str,
    moving_time: float,
    accel_time: float,
    gripper_pressure: float,
) -> Any:
    """Start InterbotixManipulatorXS (ROS 2 node + executor thread) for ``model``."""
    try:
        arm_module = importlib.import_module("interbotix_xs_modules.xs_robot.arm")
    except ImportError as exc:
        raise HardwareError(f"cannot use the real arm: {exc}; {_SETUP_HINT}") from None
    try:
        bot = arm_module.InterbotixManipulatorXS(
            robot_model=model.name,
            group_name=group_name,
            gripper_name=gripper_name,
            moving_time=moving_time,
            accel_time=accel_time,
            gripper_pressure=gripper_pressure,
        )
    except Exception as exc:  # the ROS stack reports problems as assorted exceptions
        raise HardwareError(
            f"could not connect to the {model.name} through Interbotix ({exc}); is "
            "xsarm_control running and the arm powered and plugged in?"
        ) from exc
    # Newer Interbotix releases spin their node only after robot_startup().
    try:
        robot = importlib.import_module("interbotix_common_modules.common_robot.robot")
    except ImportError:
        pass
    else:
        robot.robot_startup()
    return bot


class InterbotixGripper(GripperBase):
    """The Interbotix gripper (PWM/current mode): ``grasp`` closes, ``release`` opens."""

    def __init__(self, bot: Any, delay_s: float = 1.0) -> None:
        self._bot = bot
        self.delay_s = delay_s

    def close(self, delay: float | None = None) -> None:
        self._bot.gripper.grasp(delay=self.delay_s if delay is None else delay)

    def open(self, delay: float | None = None) -> None:
        self._bot.gripper.release(delay=self.delay_s if delay is None else delay)

    def get_finger_position(self) -> float:
        """Left finger travel from the centre line, metres (Interbotix ``left_finger`` joint)."""
        core = self._bot.core
        with core.js_mutex:
            return float(core.joint_states.position[core.js_index_map["left_finger"]])


class InterbotixArm(ArmBase):
    """armvision's :class:`Arm` on a real Interbotix arm.

    ``bot`` is an ``InterbotixManipulatorXS``; by default one is started here. Pass your own to
    share a ROS node with other code.
    """

    def __init__(
        self,
        model: ArmModel = VX300S,
        moving_time: float = DEFAULT_MOVING_TIME_S,
        accel_time: float = DEFAULT_ACCEL_TIME_S,
        group_name: str = "arm",
        gripper_name: str = "gripper",
        gripper_pressure: float = 0.5,
        bot: Any = None,
    ) -> None:
        super().__init__(model, moving_time, accel_time)
        if bot is None:
            bot = _connect(
                model, group_name, gripper_name, moving_time, accel_time, gripper_pressure
            )
        self.bot = bot
        self.gripper = InterbotixGripper(bot)
        names = list(bot.arm.group_info.joint_names)
        if names != list(model.joint_names):
            raise HardwareError(
                f"the arm reports joints {names}, expected {list(model.joint_names)} for "
                f"{model.name}: is robot_model set to {model.name} in xsarm_control?"
            )

    @classmethod
    def from_config(cls, robot: Any) -> InterbotixArm:
        """The arm ``config.robot`` describes (timing, group names, gripper pressure)."""
        return cls(
            moving_time=robot.moving_time,
            accel_time=robot.accel_time,
            group_name=robot.group_name,
            gripper_name=robot.gripper_name,
            gripper_pressure=robot.gripper_pressure,
        )

    def _read_joint_positions(self) -> Array:
        core = self.bot.core
        with core.js_mutex:
            position = list(core.joint_states.position)
        return np.array([position[core.js_index_map[name]] for name in self.model.joint_names])

    def _execute(self, trajectory: TrapezoidalTrajectory, blocking: bool) -> None:
        accepted = self.bot.arm.set_joint_positions(
            trajectory.q_goal.tolist(),
            moving_time=trajectory.moving_time,
            accel_time=trajectory.accel_time,
            blocking=blocking,
        )
        if accepted is False:  # our checks are stricter, so this means the two disagree
            raise HardwareError(
                "Interbotix refused a joint command armvision had checked: are the joint limits "
                "in the arm's motor_config the same as the vx300s URDF's?"
            )

    def _stream(self, q: Array) -> None:
        accepted = self.bot.arm.set_joint_positions(
            q.tolist(), moving_time=STREAM_MOVING_TIME_S, accel_time=0.0, blocking=False
        )
        if accepted is False:
            raise HardwareError(
                "Interbotix refused a streamed joint target armvision had checked: are the "
                "joint limits in the arm's motor_config the same as the vx300s URDF's?"
            )

    def shutdown(self) -> None:
        """Stop the ROS node (the arm holds its last pose)."""
        self.bot.shutdown()
        time.sleep(0.1)

    def close(self) -> None:
        """The Arm interface's release: :meth:`shutdown`."""
        self.shutdown()
