"""What a running task sees: :class:`TaskContext` (time, state, motion, the camera, Stop).

Tasks are functions ``task(ctx, **kwargs)``. Everything a task waits for goes through the
context, so Stop (:meth:`~armvision.runtime.system.System.stop_task`) halts the arm at once
and the task ends at its next wait with :class:`TaskStopped`. In lockstep mode the waits
advance the simulation (they pump the stages); with threads they sleep on the stop flag.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.robot.base import Arm
from armvision.runtime.state import SystemState

if TYPE_CHECKING:
    from armvision.runtime.system import System

Array = NDArray[np.float64]
log = logging.getLogger("armvision.runtime")

#: Interbotix's gripper delay: the fingers get where they go (or onto an object) in this time.
GRIPPER_TIME_S = 1.0
#: Longest a task's wait goes without looking at the stop flag (realtime), seconds.
POLL_S = 0.01


class TaskStopped(ArmvisionError):  # noqa: N818 - control flow, like StopIteration
    """The task was stopped (Stop pressed, or the system shutting down)."""


class TaskError(ArmvisionError):
    """A task could not do what it was asked; the message says why and what to do."""


#: ``task(ctx, **kwargs)``; it returns a :class:`TaskReport` (or a JSON-able mapping, or
#: nothing), and marks a failure with ``ok = False``, or by raising an ArmvisionError.
Task = Callable[..., Any]


@runtime_checkable
class TaskReport(Protocol):
    """What a task returns: whether it did what it was asked and a JSON-able report; a failed
    one says why in ``to_dict()["reason"]``."""

    @property
    def ok(self) -> bool: ...
    def to_dict(self) -> dict[str, Any]: ...


class FrameView:
    """A camera-like view of the running camera stage: :meth:`read` gives the next new frame.

    For code written against the Camera interface (the calibration sampler) while the camera
    thread owns the camera. ``wait`` advances the clock in lockstep mode.
    """

    def __init__(self, system: System) -> None:
        self._system = system
        self._seq = 0
        self.serial = system.camera.serial

    @property
    def intrinsics(self) -> Intrinsics:
        return self._system.camera.intrinsics

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def __enter__(self) -> FrameView:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def read(self, timeout_s: float = 1.0) -> RGBDFrame:
        system = self._system
        if system.lockstep:
            return system.read_frame()
        seq, newest = system.store.wait_frame(self._seq, timeout_s)
        if newest is None or seq == self._seq:
            raise ArmvisionError(
                f"no new camera frame within {timeout_s:.1f} s: is the camera running? "
                "(see the camera thread's health)"
            )
        self._seq = seq
        return newest


class TaskContext:
    """What a running task may use; every wait checks for Stop.

    ``arm``: the Arm (commands are checked by it); ``camera``: a :class:`FrameView`;
    ``config``: the configuration. Motions are started without blocking and waited for here,
    so Stop interrupts them.
    """

    def __init__(self, system: System, task_id: int, stop: threading.Event) -> None:
        self.system = system
        self.task_id = task_id
        self._stop = stop
        self.config: Config = system.config
        self.arm: Arm = system.arm
        self.camera = FrameView(system)

    # ---------------------------------------------------------------- time and state

    def now(self) -> float:
        return self.system.clock()

    def state(self) -> SystemState:
        return self.system.snapshot()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def check(self) -> None:
        """Raise :class:`TaskStopped` if Stop was pressed."""
        if self._stop.is_set():
            raise TaskStopped("stopped")

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (pumping the stages in lockstep); stops early on Stop."""
        self.check()
        if seconds <= 0.0:
            return
        if self.system.lockstep:
            # At least one physics step, so a wait for "a moment" always moves the clock.
            self.system.pump(self.now() + max(seconds, self.system.timestep))
        else:
            self._stop.wait(seconds)
        self.check()

    def wait_until(
        self, condition: Callable[[], bool], timeout_s: float, poll_s: float = 0.05
    ) -> bool:
        """Wait until ``condition()`` holds (True) or ``timeout_s`` passes (False)."""
        deadline = self.now() + timeout_s
        while True:
            if condition():
                return True
            remaining = deadline - self.now()
            if remaining <= 0.0:
                return False
            self.sleep(min(poll_s, remaining))

    def require_aim(self) -> None:
        """Refuse (TaskError) to aim at what the camera sees when that would miss: no
        calibration yet, or the camera has moved since it was calibrated."""
        state = self.state()
        if not state.calibration.calibrated:
            raise TaskError("not calibrated: calibrate first (Calibrate, or armvision calibrate)")
        refusal = state.drift.refusal()
        if refusal is not None:
            raise TaskError(refusal)

    def progress(self, fraction: float, message: str) -> None:
        """Report how far the task is (0..1) and what it is doing."""
        self.check()
        log.info("task %d: %3.0f%% %s", self.task_id, 100 * fraction, message)
        self.system.store.set_task(progress=float(np.clip(fraction, 0.0, 1.0)), message=message)

    def joint_positions(self) -> Array:
        """The encoder reading corrected by the calibration's joint offsets, rad."""
        return self.system.encoders.get_joint_positions()

    # ---------------------------------------------------------------- motion

    def wait_motion(self) -> None:
        """Wait for the current move to end (Stop halts the arm and raises TaskStopped)."""
        arm = self.arm
        while arm.moving:
            remaining = arm.motion_remaining()
            self.sleep(min(max(remaining, 1e-3), 0.05 if self.system.lockstep else POLL_S))
        if arm.settle_time:
            self.sleep(arm.settle_time)

    def _move(self, command: Callable[[], bool]) -> bool:
        self.check()
        ok = command()
        if self._stop.is_set():  # Stop arrived while the command was being issued
            self.system.halt_arm()
            raise TaskStopped("stopped")
        if ok:
            self.wait_motion()
        return bool(ok)

    def move_joints(self, q: ArrayLike, moving_time: float | None = None) -> bool:
        """Move to joint positions and wait; False (``arm.last_error`` says why) if refused."""
        return self._move(lambda: self.arm.set_joint_positions(q, moving_time, blocking=False))

    def move_pose(
        self,
        T_base_ee: ArrayLike,
        moving_time: float | None = None,
        position_priority: bool = False,
        custom_guess: ArrayLike | None = None,
    ) -> bool:
        """Move the end effector to ``T_base_ee`` and wait; False if unreachable or refused."""
        return self._move(
            lambda: self.arm.set_ee_pose_matrix(
                T_base_ee,
                custom_guess=custom_guess,
                moving_time=moving_time,
                blocking=False,
                position_priority=position_priority,
            )
        )

    def stream(self, q: ArrayLike) -> bool:
        """One servo-loop joint target (no wait); False if the arm refused it."""
        self.check()
        return bool(self.arm.stream_joint_targets(q))

    def _gripper(self, close: bool) -> None:
        self.check()
        gripper = self.arm.gripper
        action = gripper.close if close else gripper.open
        action(delay=0.0)  # returns at once; the wait here is one Stop can end
        self.sleep(GRIPPER_TIME_S)

    def open_gripper(self) -> None:
        self._gripper(close=False)

    def close_gripper(self) -> None:
        self._gripper(close=True)
