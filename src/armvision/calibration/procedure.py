"""The whole calibration: sample, solve by every method, keep the configured one.

:func:`calibrate` works on any Arm and Camera; :func:`calibrate_sim` builds a simulated
workspace for a seed and adds the truth (the simulator's camera pose) to the result, which is
how ``armvision calibrate --sim`` and ``armvision eval calibration`` measure the error.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.calibration.sampling import Progress, Sample, Sampler, SamplingResult
from armvision.calibration.solve import METHODS, Fit, solve
from armvision.camera.base import Camera
from armvision.camera.frames import Intrinsics
from armvision.config import Config, TagConfig
from armvision.errors import CalibrationError
from armvision.geometry import pose_error
from armvision.perception.tags import TagDetector
from armvision.robot.base import Arm

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """The chosen fit, every method's fit (or why it failed), and the samples behind them.

    ``truth`` is filled only in simulation: the true camera pose and each method's error.
    """

    method: str
    fit: Fit
    fits: dict[str, Fit | str]
    sampling: SamplingResult
    tag: TagConfig
    intrinsics: Intrinsics | None = None
    camera_serial: str | None = None
    truth: dict[str, Any] | None = field(default=None)

    @property
    def T_base_cam(self) -> Array:
        return self.fit.T_base_cam

    @property
    def samples(self) -> tuple[Sample, ...]:
        return self.sampling.samples


def solve_all(
    samples: tuple[Sample, ...], offset_ee, outlier_m: float, min_samples: int
) -> dict[str, Fit | str]:
    """Every method in :data:`METHODS` on the same samples; a failure is kept as its message."""
    T_base_ee = np.array([s.T_base_ee for s in samples])
    T_cam_tag = np.array([s.T_cam_tag for s in samples])
    q = np.array([s.joint_positions for s in samples])
    fits: dict[str, Fit | str] = {}
    for name in METHODS:
        try:
            fits[name] = solve(T_base_ee, T_cam_tag, name, offset_ee, outlier_m, min_samples, q)
        except CalibrationError as exc:
            fits[name] = str(exc)
    return fits


def calibrate(
    arm: Arm,
    camera: Camera,
    config: Config,
    detector: TagDetector | None = None,
    wait: Callable[[float], None] = time.sleep,
    progress: Progress | None = None,
    seed: int = 0,
) -> CalibrationResult:
    """Run the two-phase sampling and solve; CalibrationError if the chosen method fails."""
    cal = config.calibration
    sampler = Sampler(arm, camera, cal, config.tag, detector, wait, progress, seed)
    sampling = sampler.run()
    fits = solve_all(sampling.samples, config.tag.offset_ee, cal.outlier_mm / 1000, cal.min_samples)
    chosen = fits[cal.method]
    if isinstance(chosen, str):
        raise CalibrationError(f"calibration method {cal.method!r} failed: {chosen}")
    if int(chosen.used.sum()) < cal.min_samples:
        raise CalibrationError(
            f"only {int(chosen.used.sum())} samples agree with each other ({cal.min_samples}"
            f" needed, calibration.min_samples); dropped: {'; '.join(chosen.notes)}"
        )
    return CalibrationResult(
        cal.method,
        chosen,
        fits,
        sampling,
        config.tag,
        camera.intrinsics,
        getattr(camera, "serial", None),
    )


def pose_errors(T_base_cam_est: Array, T_base_cam_true: Array) -> dict[str, float]:
    """Translation (mm) and rotation (deg) error of an estimated camera pose."""
    dp, dr = pose_error(T_base_cam_est, T_base_cam_true)
    return {"translation_error_mm": 1000.0 * float(dp), "rotation_error_deg": math.degrees(dr)}
