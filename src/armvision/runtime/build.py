"""Building a :class:`~armvision.runtime.system.System` on the real arm, and the runtime's view of a
calibration (:class:`~armvision.runtime.state.CalibrationStatus`) from a file or a fresh result.

Hardware modules (pyrealsense2, interbotix, dynamixel_sdk) are imported only by
:func:`real_system`; the simulated bench builds its systems in :mod:`armvision.bench.system`.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from armvision.calibration.store import StoredCalibration, load
from armvision.camera.placement import nominal_camera_pose
from armvision.config import Config
from armvision.errors import CalibrationError
from armvision.fusion.drift import rotation_reference
from armvision.robot.tag_mount import tag_mount
from armvision.runtime.state import CalibrationStatus
from armvision.runtime.system import System


def _drift_references(
    T_base_cam: np.ndarray, offset_ee, joint_offsets, samples
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(tag mount offset, rotation reference) for the drift monitor from a calibration's
    estimated tag offset and samples, with the joint readings corrected as the runtime does."""
    offset = None
    if offset_ee is not None:
        offset = np.asarray(offset_ee, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            offset = None
    if offset is None or not samples:
        return offset, None
    q_offsets = np.zeros(6) if joint_offsets is None else np.asarray(joint_offsets, dtype=float)
    pairs = [(np.asarray(s.joint_positions) - q_offsets, s.T_cam_tag) for s in samples]
    return offset, rotation_reference(T_base_cam, tag_mount(offset), pairs)


def calibration_status(stored: StoredCalibration) -> CalibrationStatus:
    """What the runtime needs from a saved calibration."""
    offsets = None if stored.joint_offsets is None else np.asarray(stored.joint_offsets)
    T_base_cam = np.asarray(stored.T_base_cam, dtype=float)
    tag_offset, reference = _drift_references(
        T_base_cam, stored.tag.get("offset_ee_estimated"), offsets, stored.samples
    )
    return CalibrationStatus(
        source=str(stored.path) if stored.path is not None else stored.source,
        method=stored.method,
        residual_mm=float(stored.residual_rms_mm),
        T_base_cam=T_base_cam,
        joint_offsets_rad=offsets,
        tag_offset_ee=tag_offset,
        tag_rotation_reference=reference,
    )


def result_status(result) -> CalibrationStatus:
    """The runtime's view of a fresh :class:`~armvision.calibration.procedure.CalibrationResult`."""
    fit = result.fit
    T_base_cam = np.asarray(fit.T_base_cam, dtype=float)
    offsets = None if fit.joint_offsets is None else np.asarray(fit.joint_offsets)
    tag_offset, reference = _drift_references(T_base_cam, fit.offset_ee, offsets, result.samples)
    return CalibrationStatus(
        source=f"calibrated now ({len(result.samples)} samples)",
        method=result.method,
        residual_mm=1000.0 * float(fit.rms_m),
        T_base_cam=T_base_cam,
        joint_offsets_rad=offsets,
        tag_offset_ee=tag_offset,
        tag_rotation_reference=reference,
    )


def uncalibrated(config: Config) -> CalibrationStatus:
    """No calibration yet: the nominal camera placement (``sim.camera_*``), marked so that
    nothing moves the arm to what the camera sees until a calibration is made."""
    return CalibrationStatus(
        "not calibrated", "none", None, nominal_camera_pose(config.sim), calibrated=False
    )


def load_calibration(path: str | os.PathLike[str]) -> CalibrationStatus:
    """A saved calibration for the runtime; CalibrationError saying what to do if unusable."""
    path = Path(path)
    if not path.exists():
        raise CalibrationError(
            f"no calibration at {path}: run `armvision calibrate --real` first "
            "(or pass --calibration PATH)"
        )
    return calibration_status(load(path))


def real_system(
    config: Config, calibration_path: str | os.PathLike[str], allow_uncalibrated: bool = False
) -> System:
    """A System on the real arm (``robot.backend``: Interbotix's ROS 2 stack, or the Dynamixel
    bus directly) and the RealSense camera (threads, wall clock).

    With no file at ``calibration_path`` it is an error, unless ``allow_uncalibrated`` (the UI,
    whose Calibrate makes one): then it runs :func:`uncalibrated`.
    """
    if allow_uncalibrated and not Path(calibration_path).exists():
        calibration = uncalibrated(config)
    else:
        calibration = load_calibration(calibration_path)
    from armvision.camera.realsense import RealSenseCamera
    from armvision.robot.base import Arm

    arm: Arm
    if config.robot.backend == "dynamixel":
        from armvision.robot.dynamixel import DynamixelArm

        arm = DynamixelArm.from_config(config.robot)
    else:
        from armvision.robot.interbotix import InterbotixArm

        arm = InterbotixArm.from_config(config.robot)
    camera = RealSenseCamera.from_config(config.camera)
    # RealSense frame timestamps are host-clock milliseconds since the epoch (global time).
    return System(config, arm, camera, calibration, clock=time.time, owns=(arm,))
