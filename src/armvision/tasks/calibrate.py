"""Calibrate the camera while the system runs (the operator's Calibrate button).

The same two-phase tag sampling and solve as ``armvision calibrate``
(:func:`armvision.calibration.procedure.calibrate`), run as a task: frames come from the
running camera stage, every move and wait goes through the task context (so Stop ends it at
once, and a lockstep simulation keeps time), progress is reported per pose.

A result that fails the plausibility check (:func:`armvision.calibration.quality.check_quality`:
residual, spread of the samples, tag mount) is refused: the task fails saying why and the
running system keeps its calibration. A plausible one is applied to the running system
(fusion, object detector, joint offsets) and, given ``save_path``, saved there (the previous
file kept as ``.bak`` when it can be); a save that fails does not undo it: the result and the
task's message say it is in use but not saved, and why.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from armvision.calibration import store
from armvision.calibration.procedure import calibrate as run_calibration
from armvision.calibration.procedure import pose_errors
from armvision.calibration.quality import check_quality
from armvision.errors import CalibrationError
from armvision.geometry import as_xyz
from armvision.runtime.build import result_status
from armvision.runtime.context import TaskContext, TaskError

log = logging.getLogger(__name__)


class _TaskArm:
    """The arm as the calibration sampler drives it inside a task.

    Its blocking moves wait through the task context (interruptible by Stop, pumping a
    lockstep simulation); everything else, the raw joint reading included (the calibration
    estimates the encoders' zero offsets from raw readings), is the arm's own.
    """

    def __init__(self, ctx: TaskContext) -> None:
        self._ctx = ctx

    def __getattr__(self, name: str) -> Any:
        return getattr(self._ctx.arm, name)

    def set_joint_positions(
        self,
        joint_positions: ArrayLike,
        moving_time: float | None = None,
        accel_time: float | None = None,
        blocking: bool = True,
    ) -> bool:
        return self._ctx.move_joints(joint_positions, moving_time)


@dataclass(frozen=True)
class CalibrateResult:
    """A finished calibration as the running system took it."""

    method: str
    samples: int
    used: int
    residual_mm: float
    camera_xyz_m: tuple[float, float, float]
    joint_offsets_deg: tuple[float, ...] | None
    saved: str | None
    #: Simulation only: the error of the new camera pose against the simulator's.
    error_mm: float | None = None
    error_deg: float | None = None
    #: Why it was not saved (it is in use all the same), and what else went wrong saving.
    save_error: str | None = None
    warnings: tuple[str, ...] = ()
    ok: bool = True

    def to_dict(self) -> dict[str, Any]:
        def r(v: float | None, n: int = 3) -> float | None:
            return None if v is None else round(float(v), n)

        return {
            "method": self.method,
            "samples": self.samples,
            "used": self.used,
            "residual_mm": r(self.residual_mm),
            "camera_xyz_m": [r(v, 4) for v in self.camera_xyz_m],
            "joint_offsets_deg": None
            if self.joint_offsets_deg is None
            else [r(v, 3) for v in self.joint_offsets_deg],
            "saved": self.saved,
            "error_vs_simulator_mm": r(self.error_mm),
            "error_vs_simulator_deg": r(self.error_deg),
            "save_error": self.save_error,
            "warnings": list(self.warnings),
        }


def calibrate(
    ctx: TaskContext, save_path: str | os.PathLike[str] | None = None, source: str = "armvision ui"
) -> CalibrateResult:
    """Sample, solve, check, switch the running system to the result, save it (module doc)."""
    arm = _TaskArm(ctx)
    ctx.progress(0.0, "moving home to start")
    if not ctx.move_joints(ctx.arm.model.home):
        raise TaskError(f"the arm cannot reach its home pose to start: {ctx.arm.last_error}")

    def progress(done: int, total: int, message: str) -> None:
        ctx.progress(0.95 * done / max(total, 1), message)

    result = run_calibration(
        arm, ctx.camera, ctx.config, wait=ctx.sleep, progress=progress, seed=ctx.task_id
    )
    try:
        check_quality(
            result,
            ctx.config.calibration,
            "the system keeps its previous calibration: fix the cause and press Calibrate again",
        )
    except CalibrationError:
        ctx.progress(0.96, "calibration refused; moving home")
        ctx.move_joints(ctx.arm.model.home)
        raise
    status = result_status(result)
    saved, save_error, warnings = None, None, []
    if save_path is not None:
        ctx.progress(0.96, f"saving to {save_path}")
        try:
            written = store.save(store.record(result, source=source), Path(save_path))
        except CalibrationError as exc:
            save_error = str(exc)
            log.warning("the new calibration is in use but not saved: %s", exc)
            status = dataclasses.replace(status, source=f"{status.source}, not saved")
        else:
            saved = str(written.path)
            status = dataclasses.replace(status, source=f"{saved} (calibrated now)")
            if written.backup_error:
                warnings.append(written.backup_error)
    ctx.system.set_calibration(status)
    world = ctx.system.world
    errors = None if world is None else pose_errors(status.T_base_cam, world.T_base_cam())
    if save_error is not None:
        done = f"calibrated and in use, but not saved: {save_error}"
    elif saved is not None:
        done = f"calibrated, in use and saved to {saved}"
    else:
        done = "calibrated and in use"
    ctx.progress(0.98, "; ".join([done, *warnings, "moving home"]))
    ctx.move_joints(ctx.arm.model.home)
    fit = result.fit
    offsets = None if fit.joint_offsets is None else np.degrees(fit.joint_offsets)
    return CalibrateResult(
        method=result.method,
        samples=len(result.samples),
        used=int(fit.used.sum()),
        residual_mm=1000.0 * float(fit.rms_m),
        camera_xyz_m=as_xyz(status.T_base_cam[:3, 3]),
        joint_offsets_deg=None if offsets is None else tuple(float(v) for v in offsets),
        saved=saved,
        error_mm=None if errors is None else errors["translation_error_mm"],
        error_deg=None if errors is None else errors["rotation_error_deg"],
        save_error=save_error,
        warnings=tuple(warnings),
    )
