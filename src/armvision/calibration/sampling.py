"""The paper's two-phase tag sampling, on any Arm and Camera.

Phase 1 finds the camera: the gripper shows its tag at ``phase1_poses`` azimuths (-pi to 3pi/4
for the default 8) on a circle of radius 0.4 m at 0.2 m height, pitched down pi/3 so the tag on
top of the gripper faces outwards and up; the camera's azimuth is the circular mean
``atan2(sum sin, sum cos)`` of the azimuths where the tag was seen.

Phase 2 samples for the solve: 4 azimuths spread evenly over [theta_cam - pi/2, theta_cam +
pi/2] times the heights 0.1, 0.2, 0.3 m, each pose turned so the tag faces the camera. The paper
aims at the azimuth only; we aim at a rough camera position when phase 1 saw the tag at three
or more poses (a rigid fit of those), else at a point ``NOMINAL_CAMERA_DISTANCE`` out along the
azimuth. ``extra_poses`` more, with random tilts and turns of the tag, give the rotation-based
solvers the orientation diversity they need.

At each pose the arm settles, then ``detections_per_pose`` frames are read; the tag pose is
the mean of the detections (positions averaged, rotations by scipy's quaternion mean) and the
ee pose is forward kinematics of the mean joint reading over the same frames. A pose the arm
cannot reach is skipped with a log line (a different turn of the tag about its normal is tried
first); a pose where the tag is seen in fewer than half the frames is skipped too.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from armvision.calibration.solve import solve_points, tag_points
from armvision.camera.base import Camera
from armvision.config import CalibrationConfig, TagConfig
from armvision.errors import CalibrationError
from armvision.geometry import inv_T, make_T, rot_y, rot_z
from armvision.perception.tags import TagDetector
from armvision.robot.base import Arm
from armvision.robot.kinematics import VX300S, fk, ik
from armvision.robot.tag_mount import tag_mount

log = logging.getLogger(__name__)
Array = NDArray[np.float64]

#: Where phase 2 aims when phase 1 saw too little for a rough fit: this far out along the
#: camera's azimuth, at ``NOMINAL_CAMERA_HEIGHT`` (the paper's tripod, roughly).
NOMINAL_CAMERA_DISTANCE = 1.0
NOMINAL_CAMERA_HEIGHT = 0.45
#: The waist stops 1e-5 rad short of +-pi; azimuths there are moved in by this much.
_AZIMUTH_MARGIN = 1e-3
#: Turns of the tag about its own normal tried, in order, when a pose is out of reach.
_SPINS_DEG = (0.0, 30.0, -30.0, 60.0, -60.0, 90.0, -90.0)

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class PlannedPose:
    """A target of the plan: ``T_base_ee`` to reach, with where it came from."""

    phase: int  # 1, 2, or 3 for the extra poses
    azimuth: float
    height: float
    T_base_ee: Array = field(repr=False)


@dataclass(frozen=True, eq=False)
class Sample:
    """One accepted pose: where the kinematics and the camera each put the tag.

    ``T_base_ee`` from the mean joint reading, ``T_cam_tag`` the mean detection;
    ``detections`` of ``frames`` frames saw the tag; ``spread_m`` the largest distance of a
    single detection's centre from the mean (a sign of vibration or noise).
    """

    phase: int
    azimuth: float
    height: float
    joint_positions: Array
    T_base_ee: Array
    T_cam_tag: Array
    detections: int
    frames: int
    spread_m: float
    decision_margin: float

    def to_dict(self) -> dict:
        return {
            "phase": self.phase,
            "azimuth": self.azimuth,
            "height": self.height,
            "joint_positions": self.joint_positions.tolist(),
            "T_base_ee": self.T_base_ee.tolist(),
            "T_cam_tag": self.T_cam_tag.tolist(),
            "detections": self.detections,
            "frames": self.frames,
            "spread_m": self.spread_m,
            "decision_margin": self.decision_margin,
        }

    @classmethod
    def from_dict(cls, data: dict) -> Sample:
        return cls(
            phase=int(data["phase"]),
            azimuth=float(data["azimuth"]),
            height=float(data["height"]),
            joint_positions=np.asarray(data["joint_positions"], dtype=float),
            T_base_ee=np.asarray(data["T_base_ee"], dtype=float),
            T_cam_tag=np.asarray(data["T_cam_tag"], dtype=float),
            detections=int(data["detections"]),
            frames=int(data["frames"]),
            spread_m=float(data["spread_m"]),
            decision_margin=float(data["decision_margin"]),
        )


@dataclass(frozen=True, eq=False)
class SamplingResult:
    """Everything the sampling found: the samples, the camera estimate, what was skipped."""

    samples: tuple[Sample, ...]
    camera_azimuth: float
    camera_position_estimate: Array
    skipped: tuple[str, ...]


def _clamp_azimuth(azimuth: float) -> float:
    wrapped = math.atan2(math.sin(azimuth), math.cos(azimuth))
    limit = math.pi - _AZIMUTH_MARGIN
    return min(max(wrapped, -limit), limit)


def phase1_plan(cfg: CalibrationConfig) -> list[PlannedPose]:
    """The paper's phase 1: azimuths -pi + k 2pi/n, tag pitched ``phase1_tilt_deg`` outwards.

    With the ee's z axis (the tag's face) tilted outwards by the pitch: ``R = Rz(az) Ry(tilt)``,
    so the gripper points outwards and down by the same angle.
    """
    poses = []
    tilt = math.radians(cfg.phase1_tilt_deg)
    for k in range(cfg.phase1_poses):
        az = _clamp_azimuth(-math.pi + k * 2.0 * math.pi / cfg.phase1_poses)
        p = [cfg.radius * math.cos(az), cfg.radius * math.sin(az), cfg.phase1_height]
        poses.append(PlannedPose(1, az, cfg.phase1_height, make_T(rot_z(az) @ rot_y(tilt), p)))
    return poses


def circular_mean(angles: Sequence[float]) -> float:
    """``atan2(sum sin, sum cos)``: the paper's camera azimuth from the azimuths that saw it."""
    a = np.asarray(angles, dtype=float)
    return float(math.atan2(np.sin(a).sum(), np.cos(a).sum()))


def facing_pose(
    p_base_tag: Array,
    p_base_camera: Array,
    offset_ee: Array,
    spin: float = 0.0,
    tilt: tuple[Array, float] | None = None,
) -> Array:
    """``T_base_ee`` that puts the tag centre at ``p_base_tag`` facing ``p_base_camera``.

    The tag faces +z_ee, so z_ee points at the camera; x_ee (the gripper's direction) is the
    horizontal direction away from the base made orthogonal to z, then turned by ``spin``
    about z. ``tilt`` (axis, angle) tips the face away from the camera for diversity.
    """
    z = np.asarray(p_base_camera, float) - np.asarray(p_base_tag, float)
    z /= np.linalg.norm(z)
    if tilt is not None:
        axis, angle = tilt
        z = Rotation.from_rotvec(np.asarray(axis) * angle).apply(z)
    outward = np.array([p_base_tag[0], p_base_tag[1], 0.0])
    if np.linalg.norm(outward) < 1e-6 or abs(np.dot(outward / np.linalg.norm(outward), z)) > 0.99:
        outward = np.array([0.0, 0.0, -1.0])
    x = outward - np.dot(outward, z) * z
    x /= np.linalg.norm(x)
    R_base_ee = np.column_stack([x, np.cross(z, x), z]) @ rot_z(spin)
    # The ee sits where the tag centre, offset_ee out in the ee frame, lands on p_base_tag.
    return make_T(R_base_ee, np.asarray(p_base_tag, float) - R_base_ee @ np.asarray(offset_ee))


def phase2_plan(
    cfg: CalibrationConfig,
    camera_azimuth: float,
    p_base_camera: Array,
    offset_ee: Array,
    rng: np.random.Generator,
) -> list[PlannedPose]:
    """Phase 2 (azimuths x heights, tag facing the camera) and the extra, tilted poses."""
    poses = []
    n = cfg.phase2_azimuths
    azimuths = (
        [camera_azimuth]
        if n == 1
        else np.linspace(camera_azimuth - math.pi / 2, camera_azimuth + math.pi / 2, n)
    )
    for az in azimuths:
        az = _clamp_azimuth(float(az))
        for h in cfg.phase2_heights:
            p = np.array([cfg.radius * math.cos(az), cfg.radius * math.sin(az), h])
            poses.append(PlannedPose(2, az, h, facing_pose(p, p_base_camera, offset_ee)))
    tilt_max = math.radians(cfg.extra_tilt_deg)
    lo, hi = min(cfg.phase2_heights), max(cfg.phase2_heights)
    for _ in range(cfg.extra_poses):
        az = _clamp_azimuth(camera_azimuth + rng.uniform(-math.pi / 3, math.pi / 3))
        r = cfg.radius * rng.uniform(0.75, 1.2)
        h = rng.uniform(lo, hi)
        p = np.array([r * math.cos(az), r * math.sin(az), h])
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        pose = facing_pose(
            p,
            p_base_camera,
            offset_ee,
            spin=rng.uniform(-math.pi / 2, math.pi / 2),
            tilt=(axis, rng.uniform(0.3, 1.0) * tilt_max),
        )
        poses.append(PlannedPose(3, az, h, pose))
    return poses


class Sampler:
    """Runs the plan on an arm and a camera; see the module docstring.

    ``wait(seconds)`` lets time pass for settling: ``time.sleep`` on hardware, the world's
    ``advance`` in a lockstep simulation. ``progress(done, total, message)`` is called after
    every pose.
    """

    def __init__(
        self,
        arm: Arm,
        camera: Camera,
        calibration: CalibrationConfig,
        tag: TagConfig,
        detector: TagDetector | None = None,
        wait: Callable[[float], None] = time.sleep,
        progress: Progress | None = None,
        seed: int = 0,
    ) -> None:
        self.arm = arm
        self.camera = camera
        self.cfg = calibration
        self.tag = tag
        self.detector = detector or TagDetector.from_config(tag, ids=[tag.id])
        self.wait = wait
        self.progress = progress
        self.rng = np.random.default_rng(seed)
        self.offset_ee = np.asarray(tag.offset_ee, dtype=float)
        self.skipped: list[str] = []
        self._done = 0
        self._total = cfg_total(calibration)

    # ------------------------------------------------------------------ one pose

    def _reach(self, pose: PlannedPose) -> bool:
        """Move to the pose, or to the same tag position with the tag turned about its normal."""
        q_now = self.arm.get_joint_positions()
        T_ee_tag = tag_mount(self.offset_ee)
        for spin in _SPINS_DEG:
            turn = make_T(rot_z(math.radians(spin)), np.zeros(3))
            # Spin about the tag's normal (through the tag centre), which keeps it facing.
            T = pose.T_base_ee @ T_ee_tag @ turn @ inv_T(T_ee_tag)
            q, ok = ik(T, q_now, VX300S)
            if ok and self.arm.set_joint_positions(q, moving_time=self.cfg.moving_time):
                return True
        return False

    def measure(self) -> tuple[int, Array | None, Array, float, float]:
        """Read frames at the current pose: detections, mean T_cam_tag, mean joints, spread."""
        positions, rotations, margins, joints = [], [], [], []
        for _ in range(self.cfg.detections_per_pose):
            frame = self.camera.read()
            joints.append(self.arm.get_joint_positions())
            found = [d for d in self.detector.detect(frame) if d.id == self.tag.id]
            if found:
                best = max(found, key=lambda d: d.decision_margin)
                positions.append(best.T_cam_tag[:3, 3])
                rotations.append(best.T_cam_tag[:3, :3])
                margins.append(best.decision_margin)
        q_mean = np.mean(joints, axis=0)
        if not positions:
            return 0, None, q_mean, math.nan, math.nan
        p = np.mean(positions, axis=0)
        R = Rotation.from_matrix(np.array(rotations)).mean().as_matrix()
        spread = float(np.max(np.linalg.norm(np.array(positions) - p, axis=1)))
        return len(positions), make_T(R, p), q_mean, spread, float(np.mean(margins))

    def visit(self, pose: PlannedPose) -> Sample | None:
        """Reach, settle, measure one pose; None (and a log line) when it gives no sample."""
        where = (
            f"phase {pose.phase} pose at azimuth {math.degrees(pose.azimuth):.0f} deg,"
            f" height {pose.height:.2f} m"
        )
        self._done += 1
        if not self._reach(pose):
            self._skip(f"{where}: unreachable, skipped")
            return None
        self.wait(self.cfg.settle_s)
        n, T_cam_tag, q, spread, margin = self.measure()
        frames = self.cfg.detections_per_pose
        if T_cam_tag is None or n < max(1, (frames + 1) // 2):
            self._skip(f"{where}: tag seen in {n} of {frames} frames, skipped")
            return None
        self._report(f"{where}: tag seen in {n}/{frames} frames")
        return Sample(
            phase=pose.phase,
            azimuth=pose.azimuth,
            height=pose.height,
            joint_positions=q,
            T_base_ee=fk(q, VX300S),
            T_cam_tag=T_cam_tag,
            detections=n,
            frames=frames,
            spread_m=spread,
            decision_margin=margin,
        )

    def _skip(self, message: str) -> None:
        log.info("calibration: %s", message)
        self.skipped.append(message)
        self._report(message)

    def _report(self, message: str) -> None:
        if self.progress is not None:
            self.progress(min(self._done, self._total), self._total, message)

    # ------------------------------------------------------------------ the plan

    def camera_estimate(self, phase1: list[Sample]) -> tuple[float, Array]:
        """Phase 1's answer: the camera's azimuth and a rough position to aim phase 2 at."""
        if not phase1:
            raise CalibrationError(
                f"the tag (id {self.tag.id}, {self.tag.family}) was not seen from any of the"
                f" {self.cfg.phase1_poses} phase-1 poses: check that the camera looks at the"
                " arm, the tag id and family in the configuration, and the lighting"
            )
        azimuth = circular_mean([s.azimuth for s in phase1])
        nominal = np.array(
            [
                NOMINAL_CAMERA_DISTANCE * math.cos(azimuth),
                NOMINAL_CAMERA_DISTANCE * math.sin(azimuth),
                NOMINAL_CAMERA_HEIGHT,
            ]
        )
        if len(phase1) < 3:
            return azimuth, nominal
        p_cam, p_base = tag_points(
            np.array([s.T_base_ee for s in phase1]),
            np.array([s.T_cam_tag for s in phase1]),
            self.offset_ee,
        )
        try:
            rough = solve_points(p_cam, p_base).T_base_cam[:3, 3]
        except CalibrationError:
            return azimuth, nominal
        # Trust the rough fit only if it is in the direction phase 1 says and not absurd.
        bearing = math.atan2(rough[1], rough[0])
        if abs(math.remainder(bearing - azimuth, 2 * math.pi)) > math.pi / 3 or not (
            0.3 < np.linalg.norm(rough[:2]) < 4.0
        ):
            return azimuth, nominal
        return azimuth, rough

    def run(self) -> SamplingResult:
        """Both phases (and the extra poses); CalibrationError when too few samples remain."""
        phase1 = [s for s in map(self.visit, phase1_plan(self.cfg)) if s is not None]
        azimuth, p_camera = self.camera_estimate(phase1)
        log.info(
            "calibration: camera azimuth %.1f deg, aiming at %s",
            math.degrees(azimuth),
            np.round(p_camera, 2).tolist(),
        )
        plan = phase2_plan(self.cfg, azimuth, p_camera, self.offset_ee, self.rng)
        later = [s for s in map(self.visit, plan) if s is not None]
        samples = tuple(phase1 + later)
        if len(samples) < self.cfg.min_samples:
            raise CalibrationError(
                f"only {len(samples)} good samples, {self.cfg.min_samples} needed"
                f" (calibration.min_samples). Skipped: {'; '.join(self.skipped) or 'none'}."
                " Check that the camera sees the whole workspace in front of the arm and that"
                " nothing blocks the arm."
            )
        return SamplingResult(samples, azimuth, p_camera, tuple(self.skipped))


def cfg_total(cfg: CalibrationConfig) -> int:
    """How many poses the plan visits."""
    return cfg.phase1_poses + cfg.phase2_azimuths * len(cfg.phase2_heights) + cfg.extra_poses
