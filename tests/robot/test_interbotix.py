"""The Interbotix adapter, against a FAKE of InterbotixManipulatorXS (tests/fakes/interbotix.py).

The fake is not the real library: it follows the method signatures of Interbotix's ROS 2 humble
Python API and records every call, so these tests check what the real arm would be sent.
"""

from __future__ import annotations

import subprocess
import sys
import types

import numpy as np
import pytest
from tests.fakes.interbotix import FakeInterbotixManipulatorXS

from armvision.errors import HardwareError
from armvision.geometry import make_T, pose_error, rpy_to_R
from armvision.robot.base import Arm
from armvision.robot.interbotix import STREAM_MOVING_TIME_S, InterbotixArm, interbotix_available
from armvision.robot.kinematics import VX300S, fk


@pytest.fixture
def bot():
    return FakeInterbotixManipulatorXS("vx300s")


def test_adapter_is_an_arm_and_sends_checked_joint_commands(bot):
    arm = InterbotixArm(bot=bot)
    assert isinstance(arm, Arm)
    q = np.array([0.1, -0.2, 0.3, 0.0, 0.4, -0.1])
    assert arm.set_joint_positions(q, moving_time=1.5, accel_time=0.25, blocking=False)
    name, sent, moving, accel, blocking = bot.calls[-1]
    assert name == "set_joint_positions"
    np.testing.assert_allclose(sent, q)
    assert (moving, accel, blocking) == (1.5, 0.25, False)
    np.testing.assert_allclose(arm.get_joint_positions(), q)
    np.testing.assert_allclose(arm.get_ee_pose(), fk(q))


def test_ee_pose_goes_through_our_ik_never_interbotix_ik(bot):
    arm = InterbotixArm(bot=bot)
    T_target = make_T(rpy_to_R(0.2, 0.5, -0.4), [0.3, -0.15, 0.25])
    assert arm.set_ee_pose_matrix(T_target)
    dp, dr = pose_error(fk(np.array(bot.calls[-1][1])), T_target)
    assert dp < 1e-4 and dr < 1e-4


def test_refused_commands_send_nothing(bot):
    arm = InterbotixArm(bot=bot)
    assert arm.set_ee_pose_matrix(make_T(p=[1.2, 0.0, 0.5])) is False
    q = np.zeros(6)
    q[2] = 1.7  # elbow upper limit is 1.605703
    assert arm.set_joint_positions(q) is False
    assert bot.calls == []


def test_home_sleep_and_streaming(bot):
    arm = InterbotixArm(bot=bot)
    assert arm.go_to_sleep_pose()
    np.testing.assert_allclose(arm.get_joint_positions(), VX300S.sleep)
    assert arm.go_to_home_pose()
    np.testing.assert_allclose(arm.get_joint_positions(), VX300S.home)
    target = np.array([0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert arm.stream_joint_targets(target)
    _, sent, moving, accel, blocking = bot.calls[-1]
    np.testing.assert_allclose(sent, target)
    assert (moving, accel, blocking) == (STREAM_MOVING_TIME_S, 0.0, False)


def test_gripper_maps_to_grasp_and_release(bot):
    arm = InterbotixArm(bot=bot)
    arm.gripper.close()
    assert bot.calls[-1] == ("grasp", 1.0)
    assert arm.gripper.get_finger_position() == pytest.approx(0.021)
    arm.gripper.release()
    assert bot.calls[-1] == ("release", 1.0)
    assert arm.gripper.get_finger_position() == pytest.approx(0.057)


def test_wrong_robot_model_is_a_clear_error():
    bot = FakeInterbotixManipulatorXS(
        "wx250", joint_names=["waist", "shoulder", "elbow", "wrist_angle", "wrist_rotate"]
    )
    with pytest.raises(HardwareError, match="robot_model"):
        InterbotixArm(bot=bot)


def test_disagreement_with_interbotix_limits_is_an_error(bot):
    arm = InterbotixArm(bot=bot)
    bot.arm.group_info.joint_upper_limits[0] = 0.1  # a motor_config narrower than the URDF
    with pytest.raises(HardwareError, match="motor_config"):
        arm.set_joint_positions([0.5, 0, 0, 0, 0, 0])


def test_connects_through_the_interbotix_module_when_present(monkeypatch):
    modules = {
        "interbotix_xs_modules": types.ModuleType("interbotix_xs_modules"),
        "interbotix_xs_modules.xs_robot": types.ModuleType("interbotix_xs_modules.xs_robot"),
        "interbotix_xs_modules.xs_robot.arm": types.ModuleType(
            "interbotix_xs_modules.xs_robot.arm"
        ),
    }
    modules[
        "interbotix_xs_modules.xs_robot.arm"
    ].InterbotixManipulatorXS = FakeInterbotixManipulatorXS
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    arm = InterbotixArm(moving_time=1.0, accel_time=0.2)
    assert arm.bot.robot_model == "vx300s"
    assert (arm.bot.arm.moving_time, arm.bot.arm.accel_time) == (1.0, 0.2)


def test_missing_interbotix_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "interbotix_xs_modules", None)  # import fails
    with pytest.raises(HardwareError, match="ros2 launch interbotix_xsarm_control"):
        InterbotixArm()
    usable, detail = interbotix_available()
    assert not usable and "humble" in detail


def test_importing_armvision_loads_no_hardware_sdk():
    code = (
        "import sys, armvision, armvision.config, armvision.geometry, armvision.robot, "
        "armvision.robot.base, armvision.robot.interbotix, armvision.cli\n"
        "sdks = ('rclpy', 'interbotix_xs_modules', 'pyrealsense2')\n"
        "bad = [m for m in sdks if m in sys.modules]\n"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
