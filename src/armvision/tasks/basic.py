"""The one-step tasks behind the operator's Home, Sleep and gripper buttons.

Each is a task like grab or follow (``task(ctx)``, run by the motion worker), so Stop
interrupts it and the UI shows it as any other task.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armvision.runtime.context import TaskContext, TaskError


@dataclass(frozen=True)
class MoveResult:
    """Where a named pose move ended: ``pose``, the joint reading in degrees, seconds taken."""

    pose: str
    joints_deg: tuple[float, ...]
    duration_s: float
    ok: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {
            "pose": self.pose,
            "joints_deg": [round(v, 2) for v in self.joints_deg],
            "duration_s": round(self.duration_s, 2),
        }


@dataclass(frozen=True)
class GripperResult:
    """The gripper after an open or close: ``action`` and the finger position, metres."""

    action: str
    finger_m: float | None
    ok: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {
            "action": self.action,
            "finger_mm": None if self.finger_m is None else round(1000 * self.finger_m, 1),
        }


def _named_pose(ctx: TaskContext, pose: str) -> MoveResult:
    model = ctx.arm.model
    q = np.asarray(getattr(model, pose), dtype=float)
    start = ctx.now()
    ctx.progress(0.0, f"moving to the {pose} pose")
    if not ctx.move_joints(q):
        raise TaskError(f"the arm refused the {pose} pose: {ctx.arm.last_error}")
    joints = np.degrees(ctx.joint_positions())
    return MoveResult(pose, tuple(float(v) for v in joints), ctx.now() - start)


def home(ctx: TaskContext) -> MoveResult:
    """All joints to zero (Interbotix's home pose)."""
    return _named_pose(ctx, "home")


def sleep(ctx: TaskContext) -> MoveResult:
    """The folded rest pose."""
    return _named_pose(ctx, "sleep")


def _gripper(ctx: TaskContext, close: bool) -> GripperResult:
    action = "close" if close else "open"
    ctx.progress(0.0, f"{'closing' if close else 'opening'} the gripper")
    if close:
        ctx.close_gripper()
    else:
        ctx.open_gripper()
    return GripperResult(action, ctx.state().finger_position)


def gripper_open(ctx: TaskContext) -> GripperResult:
    return _gripper(ctx, close=False)


def gripper_close(ctx: TaskContext) -> GripperResult:
    return _gripper(ctx, close=True)
