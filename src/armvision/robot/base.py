"""The ``Arm`` and ``Gripper`` interfaces and the logic every backend shares.

Names follow the Interbotix Python API (``InterbotixManipulatorXS.arm`` / ``.gripper``) so its
users feel at home; what differs is that every command is checked before anything moves:
joint limits, the velocity the timing implies, and IK (our closed-form solver, not Newton from
three seeds). A command that fails a check returns False, logs why, keeps the reason in
``last_error``, and leaves the arm where it was.

Timing is Interbotix's time-based profile (Dynamixel "Profile Velocity"/"Profile Acceleration"
in time mode): every joint starts and stops together, taking ``moving_time`` seconds, of which
``accel_time`` at each end is spent accelerating and decelerating, a trapezoidal velocity profile.
"""

from __future__ import annotations

import abc
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import make_T, rpy_to_R
from armvision.robot.kinematics import VX300S, ArmModel, fk, ik

Array = NDArray[np.float64]
log = logging.getLogger("armvision.robot")

#: Interbotix's defaults for InterbotixManipulatorXS.
DEFAULT_MOVING_TIME_S = 2.0
DEFAULT_ACCEL_TIME_S = 0.3
#: A joint target this close to a limit is accepted (encoder round-off on the real arm).
_LIMIT_TOLERANCE_RAD = 1e-6
#: A streamed target may move a joint at most velocity limit x this long ahead of the last one.
STREAM_MAX_STEP_S = 0.1


@dataclass(frozen=True)
class TrapezoidalTrajectory:
    """Synchronised joint-space move from ``q_start`` to ``q_goal`` with a trapezoidal profile.

    With T = moving_time and t_a = min(accel_time, T/2), each joint's speed ramps linearly to
    v = d / (T - t_a) over t_a, cruises, and ramps down over the last t_a; d is its displacement.
    """

    q_start: Array
    q_goal: Array
    moving_time: float
    accel_time: float

    @staticmethod
    def plan(
        q_start: ArrayLike, q_goal: ArrayLike, moving_time: float, accel_time: float
    ) -> TrapezoidalTrajectory:
        if not moving_time > 0.0:
            raise ValueError(f"moving_time must be > 0 s, got {moving_time}")
        if accel_time < 0.0:
            raise ValueError(f"accel_time must be >= 0 s, got {accel_time}")
        return TrapezoidalTrajectory(
            np.array(q_start, dtype=float),
            np.array(q_goal, dtype=float),
            float(moving_time),
            float(min(accel_time, moving_time / 2.0)),
        )

    @property
    def peak_velocity(self) -> Array:
        """Cruise speed of each joint, rad/s."""
        return np.abs(self.q_goal - self.q_start) / (self.moving_time - self.accel_time)

    def sample(self, t: float) -> tuple[Array, Array]:
        """Joint positions and velocities ``t`` seconds after the start (clamped to the move)."""
        T, ta = self.moving_time, self.accel_time
        d = self.q_goal - self.q_start
        v = d / (T - ta)
        t = min(max(t, 0.0), T)
        if ta > 0.0 and t < ta:  # accelerating
            s, sd = 0.5 * t * t / ta, t / ta
        elif t <= T - ta:  # cruising
            s, sd = t - 0.5 * ta, 1.0
        else:  # decelerating
            r = T - t
            s, sd = (T - ta) - 0.5 * r * r / ta, r / ta
        return self.q_start + v * s, v * sd


@runtime_checkable
class Gripper(Protocol):
    """The gripper: two fingers on one motor. Positions are one finger's travel, metres.

    ``grasp_confirmed()``: whether the gripper itself senses that it holds something (a
    Dynamixel gripper: its current and the finger gap together), or None when it senses no
    more than its finger position (the caller then judges by the gap; see
    :func:`armvision.tasks.grab.holding`).

    ``open``/``close`` command the fingers and then wait ``delay`` seconds for them to get
    there (or onto an object); ``delay=None`` waits the backend's own time (Interbotix's
    gripper delay, 1 s), ``delay=0`` returns at once so the caller can wait interruptibly.
    """

    def open(self, delay: float | None = None) -> None: ...
    def close(self, delay: float | None = None) -> None: ...
    def grasp(self) -> None: ...
    def release(self) -> None: ...
    def get_finger_position(self) -> float: ...
    def grasp_confirmed(self) -> bool | None: ...


@runtime_checkable
class Arm(Protocol):
    """Everything armvision asks of an arm, simulated or real; a new backend implements this
    (most of it comes with :class:`ArmBase`, which leaves three hooks to write).

    ``model``: its kinematics; ``gripper``; ``last_error``: why the last command was refused
    (None if it was not); ``get_joint_velocities()``: the velocities measured with the last
    position reading, or None when the backend measures none. Commands are checked before
    anything moves and return False, with
    the arm where it was, when a check fails. ``blocking=False`` starts a move and returns; the
    runtime then polls ``moving`` / ``motion_remaining()`` and waits ``settle_time`` more, so
    that Stop (``halt()``) can end any wait. ``close()`` releases the backend's connection.
    """

    model: ArmModel
    gripper: Gripper
    last_error: str | None
    #: Seconds the servos take to come to rest after a move's profile ends.
    settle_time: float

    @property
    def moving(self) -> bool: ...
    def motion_remaining(self) -> float: ...
    def halt(self) -> None: ...
    def close(self) -> None: ...

    def go_to_home_pose(
        self,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool: ...
    def go_to_sleep_pose(
        self,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool: ...
    def set_joint_positions(
        self,
        joint_positions: ArrayLike,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool: ...
    def set_ee_pose_matrix(
        self,
        T_base_ee: ArrayLike,
        custom_guess: ArrayLike | None = None,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
        position_priority: bool = False,
    ) -> bool: ...
    def set_ee_pose_components(
        self,
        x: float = 0.0,
        y: float = 0.0,
        z: float = 0.0,
        roll: float = 0.0,
        pitch: float = 0.0,
        yaw: float | None = None,
        custom_guess: ArrayLike | None = None,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
        position_priority: bool = False,
    ) -> bool: ...
    def get_joint_positions(self) -> Array: ...
    def get_joint_velocities(self) -> Array | None: ...
    def get_ee_pose(self) -> Array: ...
    def stream_joint_targets(self, joint_positions: ArrayLike) -> bool: ...


class GripperBase(abc.ABC):
    """Shared gripper behaviour: ``close``/``grasp`` and ``open``/``release`` are the same act."""

    def grasp(self) -> None:
        """Close the fingers (on an object, if there is one between them)."""
        self.close()

    def release(self) -> None:
        """Open the fingers."""
        self.open()

    @abc.abstractmethod
    def open(self, delay: float | None = None) -> None: ...

    @abc.abstractmethod
    def close(self, delay: float | None = None) -> None: ...

    @abc.abstractmethod
    def get_finger_position(self) -> float: ...

    def grasp_confirmed(self) -> bool | None:
        """None: this gripper senses nothing but its finger position (the default)."""
        return None


class ArmBase(abc.ABC):
    """Checks and timing shared by every arm backend; subclasses only move joints.

    A backend implements three things: read the joint encoders, execute a checked
    :class:`TrapezoidalTrajectory`, and accept one streamed joint target.
    """

    gripper: Gripper
    #: A real arm's moves end when their profile does (Interbotix waits the same way).
    settle_time: float = 0.0
    #: Told every joint target the arm accepts (a checked move's goal, a streamed target), rad:
    #: a recording's commanded joints. Never lets an exception through to the motion.
    command_listener: Callable[[Array], None] | None = None

    def __init__(
        self,
        model: ArmModel = VX300S,
        moving_time: float = DEFAULT_MOVING_TIME_S,
        accel_time: float = DEFAULT_ACCEL_TIME_S,
    ) -> None:
        self.model = model
        self.moving_time = DEFAULT_MOVING_TIME_S
        self.accel_time = DEFAULT_ACCEL_TIME_S
        self.set_trajectory_time(moving_time, accel_time)
        self.last_error: str | None = None
        self._last_stream: tuple[float, Array] | None = None
        self._motion_end = -math.inf  # _now() at which the current move's profile ends

    # ---------------------------------------------------------------- backend hooks

    @abc.abstractmethod
    def _read_joint_positions(self) -> Array:
        """Current joint angles from the encoders, rad."""

    @abc.abstractmethod
    def _execute(self, trajectory: TrapezoidalTrajectory, blocking: bool) -> None:
        """Carry out a move that has passed every check."""

    @abc.abstractmethod
    def _stream(self, q: Array) -> None:
        """Send one joint target for a servo loop, without waiting."""

    def _now(self) -> float:
        """The clock servo-loop step limits are measured on (a simulation overrides it)."""
        return time.monotonic()

    def close(self) -> None:  # noqa: B027 - a hook with nothing to do by default, not abstract
        """Release the backend's connection (default: nothing to release)."""

    # ---------------------------------------------------------------- queries

    def get_joint_positions(self) -> Array:
        """Joint angles from the encoders, rad, in ``model.joint_names`` order."""
        return np.array(self._read_joint_positions(), dtype=float)

    def get_joint_velocities(self) -> Array | None:
        """The joint velocities measured with the last :meth:`get_joint_positions` reading,
        rad/s, or None when the backend measures none (the default: SimArm, Interbotix)."""
        return None

    def get_ee_pose(self) -> Array:
        """``T_base_ee`` from the encoder readings and forward kinematics."""
        return fk(self.get_joint_positions(), self.model)

    # ---------------------------------------------------------------- commands

    def set_trajectory_time(
        self, moving_time: float | None = None, accel_time: float | None = None
    ) -> None:
        """Default timing of later moves (Interbotix ``set_trajectory_time``)."""
        moving = self.moving_time if moving_time is None else float(moving_time)
        accel = self.accel_time if accel_time is None else float(accel_time)
        if not (math.isfinite(moving) and moving > 0.0):
            raise ValueError(f"moving_time must be a positive number of seconds, got {moving_time}")
        if not (math.isfinite(accel) and 0.0 <= accel <= moving / 2.0):
            raise ValueError(
                f"accel_time must be between 0 and moving_time/2 = {moving / 2:.3f} s, got {accel}"
            )
        self.moving_time, self.accel_time = moving, accel

    def _fail(self, reason: str) -> bool:
        self.last_error = reason
        log.warning("%s: not moving. %s", type(self).__name__, reason)
        return False

    def check_joint_target(
        self,
        joint_positions: ArrayLike,
        moving_time: float | None = None,
        accel_time: float | None = None,
    ) -> TrapezoidalTrajectory | str:
        """The trajectory to ``joint_positions`` if it passes every check, else why not."""
        q_goal = np.asarray(joint_positions, dtype=float)
        if q_goal.shape != (self.model.dof,):
            return f"expected {self.model.dof} joint positions, got shape {q_goal.shape}"
        if not np.all(np.isfinite(q_goal)):
            return f"joint target {q_goal.tolist()} is not finite"
        if not self.model.within_limits(q_goal, slack=_LIMIT_TOLERANCE_RAD):
            return "joint limits: " + "; ".join(self.model.limit_violations(q_goal))
        q_goal = np.clip(q_goal, self.model.lower, self.model.upper)
        moving = self.moving_time if moving_time is None else float(moving_time)
        accel = self.accel_time if accel_time is None else float(accel_time)
        if not (math.isfinite(moving) and moving > 0.0 and math.isfinite(accel) and accel >= 0.0):
            return f"bad timing: moving_time={moving_time}, accel_time={accel_time}"
        trajectory = TrapezoidalTrajectory.plan(self.get_joint_positions(), q_goal, moving, accel)
        too_fast = trajectory.peak_velocity > self.model.velocity
        if np.any(too_fast):
            # Shortest moving_time that keeps every joint within its velocity limit.
            d = np.abs(trajectory.q_goal - trajectory.q_start)
            needed = float(np.max(d / self.model.velocity)) + trajectory.accel_time
            names = [n for n, f in zip(self.model.joint_names, too_fast) if f]
            return (
                f"velocity limit: {', '.join(names)} would exceed {self.model.velocity.max():.2f}"
                f" rad/s in {moving:.2f} s; use moving_time >= {needed:.2f} s"
            )
        return trajectory

    def set_joint_positions(
        self,
        joint_positions: ArrayLike,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool:
        """Move to ``joint_positions`` (rad); False, without moving, if a check fails."""
        checked = self.check_joint_target(joint_positions, moving_time, accel_time)
        if isinstance(checked, str):
            return self._fail(checked)
        self.last_error = None
        self._last_stream = None
        self._motion_end = self._now() + checked.moving_time
        self._commanded(checked.q_goal)
        self._execute(checked, blocking)
        return True

    def _commanded(self, q: Array) -> None:
        listener = self.command_listener
        if listener is not None:
            try:
                listener(np.array(q, dtype=float))
            except Exception:  # a listener's fault must not stop the arm
                log.exception("the joint command listener failed")

    @property
    def moving(self) -> bool:
        """True until the last commanded move's profile has ended (on the arm's clock)."""
        return self._now() < self._motion_end

    def motion_remaining(self) -> float:
        """Seconds until the last commanded move's profile ends (0 when it has)."""
        return max(self._motion_end - self._now(), 0.0)

    def halt(self) -> None:
        """Stop where the arm is now: cancel the move in progress and hold the current pose.

        For a Stop button: takes effect at once and does not wait. The gripper is left as it
        is, so a held object stays held.
        """
        self._last_stream = None
        self._motion_end = -math.inf
        self._halt()

    def _halt(self) -> None:
        """Hold the current position (default: stream the encoder reading as the target)."""
        self._stream(np.clip(self.get_joint_positions(), self.model.lower, self.model.upper))

    def go_to_home_pose(
        self,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool:
        """All joints to zero: the arm straight out, gripper level."""
        return self.set_joint_positions(self.model.home, moving_time, accel_time, blocking)

    def go_to_sleep_pose(
        self,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool:
        """The folded rest pose the arm is powered down in."""
        return self.set_joint_positions(self.model.sleep, moving_time, accel_time, blocking)

    def set_ee_pose_matrix(
        self,
        T_base_ee: ArrayLike,
        custom_guess: ArrayLike | None = None,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
        position_priority: bool = False,
    ) -> bool:
        """Move the end effector to ``T_base_ee``; False, without moving, if it is unreachable.

        IK picks the solution nearest ``custom_guess`` (default: the current joints), so the
        arm takes the shortest way. ``position_priority`` accepts the nearest reachable
        orientation when the asked one cannot be reached.
        """
        T_base_ee = np.asarray(T_base_ee, dtype=float)
        if T_base_ee.shape != (4, 4) or not np.all(np.isfinite(T_base_ee)):
            return self._fail("the target pose must be a finite 4x4 matrix")
        seed = self.get_joint_positions() if custom_guess is None else custom_guess
        q, ok = ik(T_base_ee, seed, self.model, position_priority=position_priority)
        if not ok:
            p = T_base_ee[:3, 3]
            kind = "position" if position_priority else "pose"
            return self._fail(
                f"unreachable {kind}: no joint solution within limits reaches"
                f" x={p[0]:.3f} y={p[1]:.3f} z={p[2]:.3f} m"
                + ("" if position_priority else " with this orientation (try position_priority)")
            )
        return self.set_joint_positions(q, moving_time, accel_time, blocking)

    def set_ee_pose_components(
        self,
        x: float = 0.0,
        y: float = 0.0,
        z: float = 0.0,
        roll: float = 0.0,
        pitch: float = 0.0,
        yaw: float | None = None,
        custom_guess: ArrayLike | None = None,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
        position_priority: bool = False,
    ) -> bool:
        """Interbotix's pose by components; ``yaw=None`` faces the target (atan2(y, x))."""
        if yaw is None:
            yaw = math.atan2(y, x)
        T_base_ee = make_T(rpy_to_R(roll, pitch, yaw), [x, y, z])
        return self.set_ee_pose_matrix(
            T_base_ee, custom_guess, moving_time, accel_time, blocking, position_priority
        )

    def stream_joint_targets(self, joint_positions: ArrayLike) -> bool:
        """Send a servo-loop target without waiting; False (nothing sent) if it fails a check.

        Each target must lie within the joint limits and within velocity limit x elapsed time
        (at most ``STREAM_MAX_STEP_S``) of the previous one, so a stale or runaway loop cannot
        make the arm jump.
        """
        q = np.asarray(joint_positions, dtype=float)
        if q.shape != (self.model.dof,) or not np.all(np.isfinite(q)):
            return self._fail(f"stream target must be {self.model.dof} finite joint angles")
        if not self.model.within_limits(q, slack=_LIMIT_TOLERANCE_RAD):
            return self._fail("joint limits: " + "; ".join(self.model.limit_violations(q)))
        now = self._now()
        if self._last_stream is None:
            dt, q_prev = STREAM_MAX_STEP_S, self.get_joint_positions()
        else:
            t_prev, q_prev = self._last_stream
            dt = min(max(now - t_prev, 0.0), STREAM_MAX_STEP_S)
        step = np.abs(q - q_prev)
        allowed = self.model.velocity * max(dt, 1e-3) + _LIMIT_TOLERANCE_RAD
        if np.any(step > allowed):
            j = int(np.argmax(step / allowed))
            return self._fail(
                f"stream step too large: {self.model.joint_names[j]} moves {step[j]:.3f} rad in"
                f" {dt * 1000:.0f} ms (limit {self.model.velocity[j]:.2f} rad/s)"
            )
        q = np.clip(q, self.model.lower, self.model.upper)
        self._last_stream = (now, q)
        self.last_error = None
        self._commanded(q)
        self._stream(q)
        return True
