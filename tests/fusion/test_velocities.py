"""Measured joint velocities in the end-effector filter: with a fake arm whose motion is known
exactly, and through the Dynamixel driver over the servo-bus emulator against the simulator's
true end effector."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from armvision.config import Config, FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.kalman import EEFilter
from armvision.fusion.loop import FusionLoop
from armvision.geometry import make_T, rpy_to_R
from armvision.robot.kinematics import point_jacobian

T_BASE_CAM = make_T(rpy_to_R(-2.1, 0.0, math.pi / 2), [1.0, 0.0, 0.45])
T_EE_TAG = make_T(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [-0.1, 0, 0.03])


def _q(t: float) -> np.ndarray:
    """A motion that changes speed all the time: the waist and the wrist swing at 2 rad/s^2."""
    return np.array([0.5 * math.sin(2 * t), -0.3, 0.4, 0.0, 0.9 + 0.3 * math.sin(2 * t), 0.0])


def _qd(t: float) -> np.ndarray:
    return np.array([math.cos(2 * t), 0.0, 0.0, 0.0, 0.6 * math.cos(2 * t), 0.0])


def _v_true(t: float) -> np.ndarray:
    """The end effector's true velocity, Jv(q) qd, worked from the motion."""
    _, Jv, _ = point_jacobian(_q(t))
    return Jv @ _qd(t)


def _velocity_errors(use: bool, give: bool) -> np.ndarray:
    """|v_est - v_true| at every 100 Hz tick after the first 0.5 s, encoders rounded to counts."""
    config = dataclasses.replace(FusionConfig(), joint_velocities=use)
    f = EEFilter(config, T_BASE_CAM, T_EE_TAG, use_camera=False)
    rng = np.random.default_rng(3)
    count = 2 * math.pi / 4096
    lsb = 0.229 * 2 * math.pi / 60  # Present_Velocity's unit, rad/s
    errors = []
    for k in range(300):
        t = 0.01 * k
        q = np.round(_q(t) / count) * count
        qd = np.round((_qd(t) + rng.normal(0.0, lsb, 6)) / lsb) * lsb if give else None
        f.update_encoders(t, q, qd)
        if t >= 0.5:
            errors.append(np.linalg.norm(np.asarray(f.estimate().v_base) - _v_true(t)))
    return np.array(errors)


def test_measured_velocities_make_the_filters_velocity_follow_the_true_one() -> None:
    without = _velocity_errors(use=True, give=False)
    measured = _velocity_errors(use=True, give=True)
    # Differencing counts lags the changing speed; the measured ones are the speed itself.
    assert np.sqrt(np.mean(measured**2)) < 0.6 * np.sqrt(np.mean(without**2))
    # Below the noise of one joint's reading mapped to the gripper (1 count of 0.024 rad/s at
    # ~0.5 m, 12 mm/s, on each of six joints: ~30 mm/s together).
    assert np.sqrt(np.mean(measured**2)) < 0.02


def test_fusion_joint_velocities_off_ignores_them() -> None:
    assert np.array_equal(
        _velocity_errors(use=False, give=True), _velocity_errors(use=True, give=False)
    )


def test_bad_joint_velocities_are_refused_with_what_was_wrong_and_nothing_fused() -> None:
    f = EEFilter(FusionConfig(), T_BASE_CAM, T_EE_TAG, use_camera=False)
    with pytest.raises(FusionError, match=r"joint velocities must have shape \(6,\), got \(5,\)"):
        f.update_encoders(0.0, _q(0.0), np.zeros(5))
    with pytest.raises(FusionError, match="joint velocities has non-finite values"):
        f.update_encoders(0.0, _q(0.0), [math.nan] * 6)
    assert f.time is None and f.joints_at(0.0) is None


def test_the_loop_passes_the_arms_measured_velocities_to_the_filter() -> None:
    class Arm:
        def __init__(self) -> None:
            self.t = 0.0

        def get_joint_positions(self) -> np.ndarray:
            return _q(self.t)

        def get_joint_velocities(self) -> np.ndarray:
            return _qd(self.t)

    def error(use: bool) -> float:
        arm = Arm()
        config = dataclasses.replace(FusionConfig(), joint_velocities=use)
        loop = FusionLoop(config, arm, T_BASE_CAM, T_EE_TAG, clock=lambda: arm.t)
        errors = []
        for k in range(100):
            arm.t = 0.01 * k
            ee = loop.step().ee
            assert ee is not None
            errors.append(np.linalg.norm(np.asarray(ee.v_base) - _v_true(arm.t)))
        return float(np.sqrt(np.mean(np.square(errors[20:]))))

    assert error(True) < 0.5 * error(False)


def test_through_the_dynamixel_driver_the_fused_velocity_is_the_simulated_one() -> None:
    # The driver over the emulator in lockstep: Present_Velocity of every servo fused by the
    # loop; the truth is the simulated end effector, differenced a tick either side.
    pytest.importorskip("dynamixel_sdk")
    from armvision.bench.system import sim_arm
    from armvision.robot.dynamixel import DynamixelArm
    from armvision.sim.world import SimWorld

    c = Config()
    config = dataclasses.replace(
        c,
        sim=dataclasses.replace(
            c.sim, arm="dynamixel-emulated", min_objects=0, max_objects=0, loose_tags=0
        ),
    )
    with SimWorld(config, 0) as world:
        arm, owned = sim_arm(world, None)
        try:
            assert isinstance(arm, DynamixelArm)
            loops = {
                use: FusionLoop(
                    dataclasses.replace(config.fusion, joint_velocities=use),
                    arm,
                    T_BASE_CAM,
                    T_EE_TAG,
                    clock=lambda: world.time,
                )
                for use in (True, False)
            }
            assert arm.set_joint_positions([-0.4, -0.3, 0.3, 0.0, 0.6, 0.0], moving_time=1.0)
            goal = np.array([0.4, 0.1, 0.0, 0.0, 0.9, 0.0])
            assert arm.set_joint_positions(goal, moving_time=1.2, accel_time=0.4, blocking=False)
            truth, est = [], {True: [], False: []}
            t0 = world.time
            while world.time < t0 + 1.4:
                world.run_until(world.time + 0.01)
                truth.append(world.T_base_ee()[:3, 3])
                for use, loop in loops.items():
                    ee = loop.step().ee
                    assert ee is not None
                    est[use].append(np.asarray(ee.v_base))
            assert np.abs(world.joint_positions() - goal).max() < 0.01
        finally:
            arm.close()
            for thing in owned:
                thing.close()
    p = np.array(truth)
    v_true = (p[2:] - p[:-2]) / 0.02
    rms = {
        use: float(np.sqrt(np.mean(np.sum((np.array(v)[1:-1] - v_true) ** 2, axis=1))))
        for use, v in est.items()
    }
    # Mid-move the gripper goes at ~0.5 m/s; the measured velocities follow it, differenced
    # positions lag each change of speed.
    assert float(np.max(np.linalg.norm(v_true, axis=1))) > 0.3
    assert rms[True] < 0.5 * rms[False]
    assert rms[True] < 0.03
