"""SimArm and SimGripper: the Arm interface over the simulated ViperX-300s in a SimWorld.

All checking (limits, velocity, IK, unreachable targets) is :class:`ArmBase`'s; this backend
only moves joints. A checked :class:`TrapezoidalTrajectory` is sampled before every physics
step and fed to MuJoCo's position servos, with a velocity feed-forward (ctrl = q + kv/kp qd)
that cancels a position servo's lag, as the Dynamixel's profile generator does. In lockstep
mode a blocking move advances the simulation itself; a non-blocking move continues whenever
something else advances the clock (a camera read, another blocking call).

Encoders: readings are the true joint angle plus a fixed per-seed bias (the zero offset of a
servo horn) and fresh Gaussian noise, rounded to the Dynamixel's 4096 counts per turn. The
servos track the *true* angle, so commanded poses are reached exactly while the readings
(and ``get_ee_pose``, which is fk of them) are off by the bias, as the encoder fusion expects.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from armvision.robot.base import ArmBase, Array, GripperBase, TrapezoidalTrajectory
from armvision.robot.kinematics import VX300S
from armvision.sim.world import SimWorld

DYNAMIXEL_COUNTS_PER_TURN = 4096  # X-series position resolution, 0.088 degrees
GRIPPER_DELAY_S = 1.0  # Interbotix's gripper.open/close(delay=1.0)


def quantize_encoder(q: ArrayLike) -> Array:
    """Angles rounded to whole Dynamixel counts (2 pi / 4096 rad)."""
    step = 2.0 * math.pi / DYNAMIXEL_COUNTS_PER_TURN
    return np.round(np.asarray(q, dtype=float) / step) * step


class SimGripper(GripperBase):
    """The simulated gripper: one force-limited servo, two coupled fingers.

    ``open``/``close`` set the target and then, like Interbotix's, wait ``delay`` seconds
    (simulation time) for the fingers to get there or to stop on an object.
    """

    def __init__(self, world: SimWorld, delay: float = GRIPPER_DELAY_S) -> None:
        self.world = world
        self.delay = float(delay)

    def _command(self, finger_target: float, delay: float | None) -> None:
        with self.world.lock:
            self.world.data.ctrl[self.world.gripper_actuator] = finger_target
            now = self.world.time
        self.world.run_until(now + (self.delay if delay is None else float(delay)))

    def open(self, delay: float | None = None) -> None:
        """Fingers fully apart (0.057 m each)."""
        self._command(VX300S.finger_limits[1], delay)

    def close(self, delay: float | None = None) -> None:
        """Fingers together, stopping on whatever is between them."""
        self._command(VX300S.finger_limits[0], delay)

    def get_finger_position(self) -> float:
        """One finger's travel, metres: 0.021 closed .. 0.057 open."""
        return self.world.finger_position()


class SimArm(ArmBase):
    """The Arm interface on a SimWorld (see the module docstring for timing and encoders).

    Defaults come from ``world.config``: ``robot.moving_time``/``accel_time`` and
    ``sim.encoder_noise_deg``/``encoder_bias_deg``. ``settle_time`` is extra simulation
    time a blocking move waits after the profile ends, for the servos to come to rest.
    """

    def __init__(
        self,
        world: SimWorld,
        moving_time: float | None = None,
        accel_time: float | None = None,
        encoder_noise_deg: float | None = None,
        encoder_bias_deg: float | None = None,
        settle_time: float = 0.05,
        seed: int | Sequence[int] | None = None,
    ) -> None:
        robot, sim = world.config.robot, world.config.sim
        super().__init__(
            VX300S,
            robot.moving_time if moving_time is None else moving_time,
            robot.accel_time if accel_time is None else accel_time,
        )
        self.world = world
        self.settle_time = float(settle_time)
        self._rng = np.random.default_rng([world.seed, 0xA53] if seed is None else seed)
        bias = sim.encoder_bias_deg if encoder_bias_deg is None else encoder_bias_deg
        noise = sim.encoder_noise_deg if encoder_noise_deg is None else encoder_noise_deg
        self.encoder_bias = np.radians(bias) * self._rng.uniform(-1.0, 1.0, self.model.dof)
        self.encoder_noise = math.radians(noise)
        m, act = world.model, world.arm_actuators
        kp = m.actuator_gainprm[act, 0]
        kv = -m.actuator_biasprm[act, 2]
        self._lead = kv / kp  # seconds: a position servo lags by kv/kp x velocity
        self._ctrl_lo, self._ctrl_hi = m.actuator_ctrlrange[act, 0], m.actuator_ctrlrange[act, 1]
        self._trajectory: TrapezoidalTrajectory | None = None
        self._t0 = 0.0
        self.gripper = SimGripper(world)
        world.add_controller(self._control)

    def close(self) -> None:
        """Detach from the world (its servos keep holding the last target)."""
        self.world.remove_controller(self._control)

    # ---------------------------------------------------------------- ArmBase hooks

    def _now(self) -> float:
        return self.world.time

    def _read_joint_positions(self) -> Array:
        q_true = self.world.joint_positions()
        noise = self._rng.standard_normal(self.model.dof) * self.encoder_noise
        return quantize_encoder(q_true + self.encoder_bias + noise)

    def _execute(self, trajectory: TrapezoidalTrajectory, blocking: bool) -> None:
        with self.world.lock:
            self._trajectory = trajectory
            self._t0 = self.world.time
        if blocking:
            self.world.run_until(self._t0 + trajectory.moving_time + self.settle_time)

    def _stream(self, q: Array) -> None:
        with self.world.lock:
            self._trajectory = None
            self._set_ctrl(q)

    # ---------------------------------------------------------------- servo loop

    def _set_ctrl(self, ctrl: Array) -> None:
        self.world.data.ctrl[self.world.arm_actuators] = np.clip(ctrl, self._ctrl_lo, self._ctrl_hi)

    def _control(self, t: float) -> None:
        """Called by the world before each physics step: feed the profile to the servos."""
        trajectory = self._trajectory
        if trajectory is None:
            return  # the servos hold the last target
        elapsed = t - self._t0
        if elapsed >= trajectory.moving_time:
            self._set_ctrl(trajectory.q_goal)
            self._trajectory = None
            return
        q, qd = trajectory.sample(elapsed)
        self._set_ctrl(q + self._lead * qd)

    @property
    def moving(self) -> bool:
        """True while a trajectory is being executed."""
        return self._trajectory is not None

    def _halt(self) -> None:
        """Freeze the servo targets where the profile is now (the servos track true angles)."""
        with self.world.lock:
            trajectory = self._trajectory
            if trajectory is not None:
                q, _ = trajectory.sample(self.world.time - self._t0)
                self._trajectory = None
            else:
                q = self.world.joint_positions()
            self._set_ctrl(q)

    def wait_until_idle(self) -> None:
        """Let the current non-blocking move finish (advances time in lockstep mode)."""
        trajectory = self._trajectory
        if trajectory is not None:
            self.world.run_until(self._t0 + trajectory.moving_time + self.settle_time)
