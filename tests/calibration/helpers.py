"""Synthetic calibration samples shared by the calibration tests."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from armvision.calibration.procedure import CalibrationResult, solve_all
from armvision.calibration.sampling import Sample, SamplingResult
from armvision.camera.frames import Intrinsics
from armvision.config import TagConfig
from armvision.geometry import inv_T, make_T
from armvision.robot.kinematics import fk
from armvision.robot.tag_mount import tag_mount

T_BASE_CAM = make_T(
    Rotation.from_euler("zyx", [170, 25, -100], degrees=True).as_matrix(), [1.05, -0.2, 0.48]
)
OFFSET = np.array([-0.1, 0.0, 0.03])


def joint_samples(n=20, seed=0, offset=OFFSET, T_base_cam=T_BASE_CAM, bias=0.0):
    """Noise-free samples at random in-limit joint positions, read by encoders whose zeros
    are off by ``bias`` (rad): ``(q_read, T_base_ee from q_read, T_cam_tag)``."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.8, 0.8, (n, 6))
    T_ct = np.array([inv_T(T_base_cam) @ fk(qi) @ tag_mount(offset) for qi in q])
    q_read = q + bias
    return q_read, np.array([fk(qi) for qi in q_read]), T_ct


def samples(n=20, seed=0, offset=OFFSET, T_base_cam=T_BASE_CAM):
    """Noise-free samples at random in-limit joint positions: ``(T_base_ee, T_cam_tag)``."""
    _, T_be, T_ct = joint_samples(n, seed, offset, T_base_cam)
    return T_be, T_ct


def make_result(T_base_cam=T_BASE_CAM, seed=0) -> CalibrationResult:
    T_be, T_ct = samples(n=10, seed=seed, T_base_cam=T_base_cam)
    sample_list = tuple(
        Sample(2, 0.1 * i, 0.2, np.zeros(6), T_be[i], T_ct[i], 5, 5, 0.0003, 80.0)
        for i in range(len(T_be))
    )
    fits = solve_all(sample_list, OFFSET, 0.005, 6)
    sampling = SamplingResult(sample_list, 0.0, np.array([1.0, 0.0, 0.45]), ("a skipped pose",))
    return CalibrationResult(
        "joint",
        fits["joint"],
        fits,
        sampling,
        TagConfig(),
        Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5),
        "123456789012",
    )
