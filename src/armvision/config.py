"""Configuration: one tree of frozen dataclasses with the paper's defaults.

Loaded from TOML and overridable from the command line (``--set robot.moving_time=1.5``).
Validation is pydantic's (types, ranges); every problem becomes a :class:`ConfigError` that names
the file and the dotted key, so ``tag.sise = 0.04`` fails with "unknown key 'tag.sise'" instead of
being silently ignored.

Where the file comes from, first match wins: ``--config PATH``, ``$ARMVISION_CONFIG``,
``./armvision.toml``, else the defaults. ``armvision config`` prints the effective tree as TOML.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import tomli_w
from pydantic import (
    AfterValidator,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StringConstraints,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass
from pydantic_core import ErrorDetails

from armvision.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

# extra="forbid": a typo is an error; allow_inf_nan=False: every float is finite (inf and NaN
# would pass the range checks below or fail much later, far from the key).
_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

# Strict scalars: a boolean is not a number (``true`` is not 1) and a number is not a boolean;
# an int stands for a float (``moving_time = 2``), a float never for an int (``id = 3.0``).
# Containers stay lax, so a TOML list fills a tuple field.
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
PositiveFloat = Annotated[Float, Field(gt=0.0)]
Seconds = Annotated[Float, Field(gt=0.0, le=600.0)]  # a wait, timeout or window: 10 min at most
MovingTime = Annotated[Float, Field(gt=0.0, le=60.0)]  # one arm move
# Positions in metres (the arm reaches 0.75 m; nothing it uses lies beyond a metre or two).
Vector3 = tuple[
    Annotated[Float, Field(ge=-2.0, le=2.0)],
    Annotated[Float, Field(ge=-2.0, le=2.0)],
    Annotated[Float, Field(ge=-2.0, le=2.0)],
]


def _usable_text(text: str) -> str:
    if not text.isprintable():
        raise ValueError("must not hold control characters (newline, tab, NUL)")
    return text


def _not_blank(text: str) -> str:
    if not text.strip():
        raise ValueError("must not be blank")
    return _usable_text(text)


# A name, path or address: not blank, one printable line (a NUL in a path makes open() raise).
Text = Annotated[
    str, Strict(), StringConstraints(min_length=1, max_length=4096), AfterValidator(_not_blank)
]
# RealSense serials are digits; accept them unquoted in TOML and on the command line.
SerialNumber = Annotated[
    Text | None,
    BeforeValidator(
        lambda v: (
            str(v) if isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 10**20 else v
        )
    ),
]

ENV_VAR = "ARMVISION_CONFIG"
LOCAL_FILE = "armvision.toml"


def _at_most_half(value: float, info: ValidationInfo, other: str) -> float:
    limit = info.data.get(other)
    if limit is not None and value > limit / 2.0:
        raise ValueError(f"must be at most half of {other} ({limit} s)")
    return value


_Number = TypeVar("_Number", int, float)


def _above(value: _Number, info: ValidationInfo, other: str, *, equal: bool = False) -> _Number:
    """``value`` must exceed (or with ``equal`` at least equal) the field ``other`` before it."""
    low = info.data.get(other)
    if low is not None and (value < low if equal else value <= low):
        raise ValueError(f"must be {'at least' if equal else 'greater than'} {other} ({low})")
    return value


@dataclass(config=_STRICT)
class RobotConfig:
    """The arm. Timing defaults are Interbotix's (InterbotixManipulatorXS)."""

    model: Literal["vx300s"] = "vx300s"
    moving_time: MovingTime = 2.0
    # validate_default: checked against moving_time when only moving_time is set.
    accel_time: Annotated[Float, Field(ge=0.0, le=30.0, validate_default=True)] = 0.3
    gripper_pressure: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.5
    group_name: Text = "arm"
    gripper_name: Text = "gripper"
    # "interbotix": through the Interbotix ROS 2 stack; "dynamixel": the servos directly over
    # the U2D2 on ``port`` at ``baud_rate`` (robot/dynamixel.py, no ROS).
    backend: Literal["interbotix", "dynamixel"] = "interbotix"
    port: Text = "/dev/ttyDXL"
    baud_rate: Annotated[Int, Field(gt=0)] = 1_000_000

    @field_validator("accel_time")
    @classmethod
    def _accel_within_move(cls, accel_time: float, info: ValidationInfo) -> float:
        return _at_most_half(accel_time, info, "moving_time")


#: Codes per AprilTag family (the AprilTag 3 library's tag36h11.c etc.): ids run 0..n-1.
TAG_FAMILY_SIZES = {"tag36h11": 587, "tag25h9": 35, "tag16h5": 30, "tagStandard41h12": 2115}


@dataclass(config=_STRICT)
class TagConfig:
    """The AprilTag on the gripper: the paper's tag36h11 id 96, 10 cm behind and 3 cm above ee."""

    family: Literal["tag36h11", "tag25h9", "tag16h5", "tagStandard41h12"] = "tag36h11"
    id: Annotated[Int, Field(ge=0, validate_default=True)] = 96
    size: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.04  # edge of the black square, metres
    offset_ee: Vector3 = (-0.1, 0.0, 0.03)  # tag centre in the ee frame, metres

    @field_validator("id")
    @classmethod
    def _id_in_family(cls, tag_id: int, info: ValidationInfo) -> int:
        family = info.data.get("family")
        if family is not None and tag_id >= TAG_FAMILY_SIZES[family]:
            raise ValueError(f"tag.family {family} has ids 0 to {TAG_FAMILY_SIZES[family] - 1}")
        return tag_id


# The D435/D435i's modes, from Intel's "Intel RealSense Product Family D400 Series Datasheet"
# (document 337029), "Image formats on USB 3.x": resolution -> frame rates. The RGB sensor's
# colour stream and the depth (Z16) stream; 90 and 300 FPS depth modes are left out, colour
# stops at 60. RealSenseCamera streams depth at the colour's resolution (enable_stream of both
# with camera.width x camera.height, depth then aligned to colour), so a live camera needs the
# size in both tables; a recording (camera.bag) holds depth already paired with its colour, so
# there any colour mode plays. The simulated camera emulates the live D435i, hence the same set.
D435I_COLOUR_MODES: dict[tuple[int, int], tuple[int, ...]] = {
    (320, 180): (6, 30, 60),
    (320, 240): (6, 30, 60),
    (424, 240): (6, 15, 30, 60),
    (640, 360): (6, 15, 30, 60),
    (640, 480): (6, 15, 30, 60),
    (848, 480): (6, 15, 30, 60),
    (960, 540): (6, 15, 30, 60),
    (1280, 720): (6, 15, 30),
    (1920, 1080): (6, 15, 30),
}
D435I_DEPTH_MODES: dict[tuple[int, int], tuple[int, ...]] = {
    (424, 240): (6, 15, 30, 60, 90),
    (480, 270): (6, 15, 30, 60, 90),
    (640, 360): (6, 15, 30, 60, 90),
    (640, 480): (6, 15, 30, 60, 90),
    (848, 480): (6, 15, 30, 60, 90),
    (1280, 720): (6, 15, 30),
}
#: Colour and depth at the same size and rate: what ``camera.width/height/fps`` may be live.
D435I_MODES: dict[tuple[int, int], tuple[int, ...]] = {
    size: tuple(fps for fps in rates if fps in D435I_DEPTH_MODES.get(size, ()))
    for size, rates in D435I_COLOUR_MODES.items()
    if size in D435I_DEPTH_MODES
}


def _camera_modes(bag: str | None) -> dict[tuple[int, int], tuple[int, ...]]:
    return D435I_MODES if bag is None else D435I_COLOUR_MODES


def _list_modes(modes: dict[tuple[int, int], tuple[int, ...]]) -> str:
    return ", ".join(f"{w}x{h}@{'/'.join(map(str, rates))}" for (w, h), rates in modes.items())


def _mode_error(what: str, bag: str | None) -> ValueError:
    kind = "a recording's colour (camera.bag)" if bag is not None else "colour and aligned depth"
    return ValueError(
        f"{what} is not a D435i mode for {kind}; set camera.width, camera.height and "
        f"camera.fps to one of {_list_modes(_camera_modes(bag))} (WxH@fps)"
    )


@dataclass(config=_STRICT)
class CameraConfig:
    """The RealSense D435i streams: colour and aligned depth at 640x480, 30 FPS.

    ``width`` x ``height`` @ ``fps`` must be a mode the D435i streams (``D435I_MODES``; with a
    ``bag`` any of its colour modes, ``D435I_COLOUR_MODES``).
    """

    serial: SerialNumber = None  # choose one of several cameras; None = the first found
    bag: Text | None = None  # play back a recording (.bag, or .db3 as librealsense 2.59 writes)
    # validate_default: the mode is checked whichever of the three is set.
    width: Annotated[Int, Field(validate_default=True)] = 640
    height: Annotated[Int, Field(validate_default=True)] = 480
    fps: Annotated[Int, Field(validate_default=True)] = 30

    @field_validator("width")
    @classmethod
    def _known_width(cls, width: int, info: ValidationInfo) -> int:
        bag = info.data.get("bag")
        if width not in {w for w, _ in _camera_modes(bag)}:
            raise _mode_error(f"width {width}", bag)
        return width

    @field_validator("height")
    @classmethod
    def _known_size(cls, height: int, info: ValidationInfo) -> int:
        bag, width = info.data.get("bag"), info.data.get("width")
        if width is not None and (width, height) not in _camera_modes(bag):
            raise _mode_error(f"{width}x{height}", bag)
        return height

    @field_validator("fps")
    @classmethod
    def _known_mode(cls, fps: int, info: ValidationInfo) -> int:
        bag, width, height = info.data.get("bag"), info.data.get("width"), info.data.get("height")
        if width is None or height is None:
            if fps not in {f for rates in D435I_COLOUR_MODES.values() for f in rates}:
                raise _mode_error(f"{fps} fps", bag)
        elif fps not in _camera_modes(bag)[(width, height)]:
            raise _mode_error(f"{width}x{height}@{fps}", bag)
        return fps


@dataclass(config=_STRICT)
class SimConfig:
    """The simulated workspace (MuJoCo): camera placement, scene, sensor noise and physics.

    The camera stands in front of the robot like the paper's set-up: ``camera_distance``
    horizontally from the base axis at ``camera_azimuth_deg`` (0 = on the base's +x axis),
    ``camera_height`` above the table top, facing the base and pitched down by
    ``camera_pitch_deg``. With ``randomize_camera`` every seed adds a uniform offset within
    the ``*_jitter`` ranges (plus, minus); the jittered distance stays beyond 0.3 m and the
    jittered height above the table top.

    ``profile`` picks the scenes: ``"default"`` (1-4 bottles and cups, well apart),
    ``"cluttered"`` (more objects close together, partly hidden, with distractors that are
    neither bottle nor cup, and more bottle and cup families), the harder bench, or
    ``"sort"`` (2-4 bottles whose liquid shows, with fills on both sides of
    ``sort.fill_threshold``, among distractors, clear of the ``place.zones``: the sorting bench).
    """

    profile: Literal["default", "cluttered", "sort"] = "default"
    camera_distance: Annotated[Float, Field(gt=0.3, le=3.0)] = 1.0
    camera_azimuth_deg: Annotated[Float, Field(ge=-180.0, le=180.0)] = 0.0
    camera_height: Annotated[Float, Field(ge=0.0, le=2.0)] = 0.45
    camera_pitch_deg: Annotated[Float, Field(ge=0.0, le=89.0)] = 30.0
    randomize_camera: Bool = False
    # validate_default (distance, height): checked against the placement when only that is set.
    camera_distance_jitter: Annotated[Float, Field(ge=0.0, le=1.0, validate_default=True)] = 0.1
    camera_azimuth_jitter_deg: Annotated[Float, Field(ge=0.0, le=180.0)] = 10.0
    camera_height_jitter: Annotated[Float, Field(ge=0.0, le=1.0, validate_default=True)] = 0.05
    camera_pitch_jitter_deg: Annotated[Float, Field(ge=0.0, le=45.0)] = 5.0
    min_objects: Annotated[Int, Field(ge=0, le=4)] = 1
    max_objects: Annotated[Int, Field(ge=0, le=4, validate_default=True)] = 4
    loose_tags: Annotated[Int, Field(ge=0, le=4)] = 0  # extra tags lying on the table
    # The simulated arm: "sim" (SimArm on the MuJoCo servos) or "dynamixel-emulated" (the
    # Dynamixel driver over a Protocol 2.0 bus emulator on a pty, backed by the same servos).
    arm: Literal["sim", "dynamixel-emulated"] = "sim"
    depth_noise: Bool = True  # Intel's RMS model, quantisation, edge and range dropouts
    depth_min: Annotated[Float, Field(gt=0.0, le=10.0)] = 0.28  # D435 minimum at 640x480, m
    # z16 in millimetres ends at 65.535 m; validate_default: checked against depth_min.
    depth_max: Annotated[Float, Field(gt=0.0, le=65.0, validate_default=True)] = 3.0
    encoder_noise_deg: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.1  # per reading, 1 sigma
    encoder_bias_deg: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.3  # per joint and seed
    timestep: Annotated[Float, Field(gt=0.0, le=0.01)] = 0.002  # physics step, seconds
    # Random light direction, brightness and ambient per seed (see sim.scene.random_lighting);
    # off by default so the default scenes keep their fixed lighting.
    randomize_lighting: Bool = False
    # The real D435's habits (armvision.sim.camera, measured in armvision.eval.clear_depth on
    # ClearGrasp's real D435 frames): depth on clear plastic (geoms with alpha < 1) missing,
    # seen behind or wrong in these shares, speckle holes, flying pixels at depth edges, and
    # per-frame exposure and white-balance gains (1 sigma). None: on in the cluttered profile,
    # off in the default one (whose frames stay as they were).
    camera_effects: Bool | None = None
    clear_missing: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.52
    clear_behind: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.32
    # validate_default: the three shares may not add up to more than 1.
    clear_wrong: Annotated[Float, Field(ge=0.0, le=1.0, validate_default=True)] = 0.06
    speckle_holes: Annotated[Float, Field(ge=0.0, le=0.05)] = 0.001  # share of pixels
    flying_pixels: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.72  # share of edge pixels
    exposure_jitter: Annotated[Float, Field(ge=0.0, le=0.5)] = 0.03
    white_balance_jitter: Annotated[Float, Field(ge=0.0, le=0.5)] = 0.02

    @property
    def camera_effects_on(self) -> bool:
        """``camera_effects``, or for None whether the profile is a cluttered one."""
        if self.camera_effects is None:
            return self.profile in ("cluttered", "sort")
        return self.camera_effects

    @field_validator("clear_wrong")
    @classmethod
    def _clear_shares(cls, wrong: float, info: ValidationInfo) -> float:
        total = wrong + info.data.get("clear_missing", 0.0) + info.data.get("clear_behind", 0.0)
        if total > 1.0:
            raise ValueError(f"clear_missing + clear_behind + this must be at most 1 (got {total})")
        return wrong

    @field_validator("camera_distance_jitter")
    @classmethod
    def _distance_stays_out(cls, jitter: float, info: ValidationInfo) -> float:
        distance = info.data.get("camera_distance")
        if distance is not None and distance - jitter <= 0.3:
            raise ValueError(
                f"camera_distance ({distance} m) minus this must stay above 0.3 m (the base)"
            )
        return jitter

    @field_validator("camera_height_jitter")
    @classmethod
    def _height_stays_up(cls, jitter: float, info: ValidationInfo) -> float:
        height = info.data.get("camera_height")
        if height is not None and height - jitter < 0.0:
            raise ValueError(
                f"must be at most camera_height ({height} m): the camera stays above the table"
            )
        return jitter

    @field_validator("max_objects")
    @classmethod
    def _max_at_least_min(cls, max_objects: int, info: ValidationInfo) -> int:
        return _above(max_objects, info, "min_objects", equal=True)

    @field_validator("depth_max")
    @classmethod
    def _depth_range(cls, depth_max: float, info: ValidationInfo) -> float:
        return _above(depth_max, info, "depth_min")


@dataclass(config=_STRICT)
class CalibrationConfig:
    """Camera-to-robot calibration: the paper's two-phase tag sampling and the solver.

    Phase 1 shows the tag at ``phase1_poses`` azimuths on a circle of ``radius`` at
    ``phase1_height``, tilted ``phase1_tilt_deg`` to face outwards; phase 2 at
    ``phase2_azimuths`` azimuths across the half circle facing the camera times
    ``phase2_heights``, turned toward the camera; ``extra_poses`` more with random tilts (up
    to ``extra_tilt_deg``) give the rotation-based solvers orientation diversity. Each pose
    averages ``detections_per_pose`` frames after ``settle_s``. ``method`` is the solver
    (see ``armvision.calibration.solve.METHODS``); ``file`` where the result is kept.
    """

    radius: Annotated[Float, Field(gt=0.1, le=0.75)] = 0.4
    phase1_height: Annotated[Float, Field(ge=0.02, le=0.7)] = 0.2
    phase1_poses: Annotated[Int, Field(ge=3, le=32)] = 8
    phase1_tilt_deg: Annotated[Float, Field(ge=0.0, le=90.0)] = 60.0
    phase2_azimuths: Annotated[Int, Field(ge=1, le=16)] = 4
    phase2_heights: Annotated[tuple[Float, ...], Field(max_length=16)] = (0.1, 0.2, 0.3)
    extra_poses: Annotated[Int, Field(ge=0, le=100)] = 8
    extra_tilt_deg: Annotated[Float, Field(ge=0.0, le=60.0)] = 30.0
    detections_per_pose: Annotated[Int, Field(ge=1, le=100)] = 5
    settle_s: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.5
    moving_time: MovingTime = 2.0
    min_samples: Annotated[Int, Field(ge=3, le=1000)] = 6
    method: Literal[
        "svd",
        "robust_svd",
        "joint",
        "joint_kinematic",
        "tsai",
        "park",
        "horaud",
        "andreff",
        "daniilidis",
        "shah",
        "li",
    ] = "joint_kinematic"  # see README, "Calibration", for why
    # robust solvers: residuals above this (and 3 sigma) drop
    outlier_mm: Annotated[Float, Field(gt=0.0, le=1000.0)] = 5.0
    file: Text = "calibration.json"  # relative paths are taken from the working directory
    # Plausibility of a new calibration (refused unless forced): RMS residual of the fit, the
    # spread of the tag positions sampled (RMS distance from their centroid), and how far the
    # estimated tag mount may lie from tag.offset_ee.
    max_residual_rms_mm: Annotated[Float, Field(gt=0.0, le=1000.0)] = 5.0
    min_sample_spread_m: Annotated[Float, Field(gt=0.0, le=2.0)] = 0.08
    max_tag_offset_error_mm: Annotated[Float, Field(gt=0.0, le=1000.0)] = 25.0
    # Drift: the gripper tag as the camera sees it against where the encoders put it. A
    # disagreement over drift_mm or drift_deg (median over drift_window_s, at least
    # drift_min_samples detections) held for drift_persist_s marks the calibration drifted.
    drift_mm: Annotated[Float, Field(gt=0.0, le=1000.0)] = 8.0
    drift_deg: Annotated[Float, Field(gt=0.0, le=180.0)] = 1.5
    drift_window_s: Seconds = 2.0
    drift_min_samples: Annotated[Int, Field(ge=1, le=1000)] = 10
    drift_persist_s: Annotated[Float, Field(ge=0.0, le=600.0)] = 1.0

    @field_validator("phase2_heights")
    @classmethod
    def _heights_sane(cls, heights: tuple[float, ...]) -> tuple[float, ...]:
        if not heights:
            raise ValueError("give at least one height")
        if any(not 0.0 <= h <= 0.7 for h in heights):
            raise ValueError("heights must be between 0 and 0.7 m above the base")
        return heights


@dataclass(config=_STRICT)
class FusionConfig:
    """Kalman fusion of camera and encoders, and multi-object tracking (armvision.fusion).

    The fusion loop runs at ``rate_hz`` (the paper's 100 Hz). Motion is constant velocity
    (``motion_model = "cv"``, white-noise acceleration of density ``accel_noise`` m/s^1.5) or
    constant acceleration (``"ca"``, white-noise jerk ``jerk_noise`` m/s^2.5). The process noise
    grows (up to ``adaptive_max_scale`` x) while the fading average of the normalised innovation
    squared (weight ``adaptive_fading`` for the newest) exceeds ``adaptive_threshold``.
    Measurements are gated at ``gate_probability`` of the chi-square distribution; after
    ``max_rejections`` gated in a row from one source the filter restarts from that source.
    Measurements up to ``history_s`` older than the state are inserted and replayed.

    With ``joint_velocities`` the end-effector filter also fuses the joint velocities the arm
    measures, where its backend measures them (the Dynamixel driver's Present_Velocity; SimArm
    and Interbotix give none), as the end effector's velocity Jv(q) qd, with
    ``velocity_noise_deg_s`` per joint (1 sigma; Present_Velocity counts 0.229 rev/min = 1.37
    deg/s).

    Sensor models: encoders ``encoder_noise_deg`` per reading and a fixed zero offset of up to
    ``encoder_bias_deg`` per joint, estimated as joint-space bias states (``encoder_bias =
    "joint"``), as a random-walk Cartesian offset (``"cartesian"``: prior
    ``cartesian_bias_sigma`` m, walk ``cartesian_bias_walk`` m/sqrt(s)) or not at all
    (``"none"``). The camera: ``camera_pixel_sigma`` px across the viewing ray, Intel's depth RMS
    x ``camera_depth_scale`` along it, at least ``camera_sigma_floor`` m, the tag's rotation
    ``tag_rotation_sigma_deg``. With ``estimate_camera_pose`` the filter also refines the
    calibration, whose error is about ``calibration_translation_error`` m and
    ``calibration_rotation_error_deg``. Objects: accel noise ``object_accel_noise``, at least
    ``object_sigma_floor`` m per detection; a track is confirmed after ``confirm_hits`` hits
    in ``confirm_window`` frames and dropped ``drop_after_s`` seconds after it was last seen;
    a detection the gate leaves over joins a leftover track within ``reassociation_radius`` m.
    """

    rate_hz: Annotated[Float, Field(gt=0.0, le=2000.0)] = 100.0
    motion_model: Literal["cv", "ca"] = "cv"
    accel_noise: Annotated[Float, Field(gt=0.0, le=100.0)] = 0.1
    jerk_noise: Annotated[Float, Field(gt=0.0, le=1000.0)] = 2.0
    adaptive_noise: Bool = True
    adaptive_fading: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.1
    adaptive_threshold: Annotated[Float, Field(ge=1.0, le=1000.0)] = 2.0
    adaptive_max_scale: Annotated[Float, Field(ge=1.0, le=1e6)] = 1000.0
    gate_probability: Annotated[Float, Field(gt=0.5, lt=1.0)] = 0.999
    max_rejections: Annotated[Int, Field(ge=1, le=1000)] = 5
    history_s: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.5
    encoder_noise_deg: Annotated[Float, Field(gt=0.0, le=10.0)] = 0.1
    joint_velocities: Bool = True
    velocity_noise_deg_s: Annotated[Float, Field(gt=0.0, le=100.0)] = 2.0
    encoder_bias: Literal["joint", "cartesian", "none"] = "joint"
    encoder_bias_deg: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.3
    cartesian_bias_sigma: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.003
    cartesian_bias_walk: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.001
    estimate_camera_pose: Bool = True
    calibration_translation_error: Annotated[Float, Field(ge=0.0, le=0.1)] = 0.002
    calibration_rotation_error_deg: Annotated[Float, Field(ge=0.0, le=10.0)] = 0.2
    camera_pixel_sigma: Annotated[Float, Field(gt=0.0, le=100.0)] = 0.5
    camera_depth_scale: Annotated[Float, Field(ge=0.0, le=100.0)] = 0.3
    camera_sigma_floor: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.0005
    tag_rotation_sigma_deg: Annotated[Float, Field(gt=0.0, le=180.0)] = 0.5
    object_accel_noise: Annotated[Float, Field(gt=0.0, le=100.0)] = 0.05
    object_sigma_floor: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.002
    confirm_hits: Annotated[Int, Field(ge=1, le=1000)] = 3
    # validate_default: the check against confirm_hits runs when only confirm_hits is set.
    confirm_window: Annotated[Int, Field(ge=1, le=1000, validate_default=True)] = 5
    drop_after_s: Seconds = 1.0
    reassociation_radius: Annotated[Float, Field(ge=0.0, le=0.5)] = 0.04

    @field_validator("confirm_window")
    @classmethod
    def _window_holds_hits(cls, confirm_window: int, info: ValidationInfo) -> int:
        return _above(confirm_window, info, "confirm_hits", equal=True)


@dataclass(config=_STRICT)
class RuntimeConfig:
    """The running system's threads (armvision.runtime): how often each stage works.

    The camera thread reads every frame (``camera.fps``); the tag, object and liquid threads
    take the newest frame at most ``tag_hz``, ``object_hz``, ``liquid_hz`` times a second
    (each is as fast as its detector allows below that). ``liquid_window`` measurements per
    track are averaged. A thread with no output for ``stale_s`` is reported stale. Starting
    and stopping a thread may take at most ``join_timeout_s``.
    """

    tag_hz: Annotated[Float, Field(gt=0.0, le=120.0)] = 30.0
    object_hz: Annotated[Float, Field(gt=0.0, le=120.0)] = 10.0
    liquid_hz: Annotated[Float, Field(gt=0.0, le=60.0)] = 2.0
    liquid_window: Annotated[Int, Field(ge=1, le=100)] = 8
    tag_detection: Bool = True
    object_detection: Bool = True
    liquid_detection: Bool = True
    stale_s: Seconds = 1.0
    join_timeout_s: Seconds = 3.0


@dataclass(config=_STRICT)
class GrabConfig:
    """The grasp (armvision.tasks.grab), the paper's sequence and safety rules.

    Start at ``safe_pose`` (x, y, z in the base frame, gripper level, open); approach through a
    waypoint ``standoff`` m short of the bottle on the line from the base; grasp at
    ``grasp_height_fraction`` of the bottle's estimated height; lift ``lift`` m. Abort if the
    bottle is nearer than ``min_base_distance`` m to the base axis. An unreachable move is
    tried ``retries`` more times after ``retry_delay_s``; the whole task gives up after
    ``timeout_s``. Each move takes ``moving_time`` s (Interbotix's default timing otherwise).

    ``planner``: ``collision`` (default) chooses among ``approach_candidates`` approach
    directions all around the bottle the free one with the best clearance and reach, checked
    against the planning scene with ``clearance`` m to spare, and plans in joint space (OMPL's
    RRT-Connect, up to ``plan_time_s`` per query) where no straight move is free; ``paper``
    is the paper's straight approach from the base, the baseline. ``top_grasp``: where no
    approach from the side is free, the collision-aware planner tries grasps from above, by
    the cap (the gripper pointing down).
    """

    safe_pose: Vector3 = (0.1, 0.0, 0.65)
    standoff: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.15
    grasp_height_fraction: Annotated[Float, Field(gt=0.0, lt=1.0)] = 0.45
    lift: Annotated[Float, Field(gt=0.0, le=0.5)] = 0.10
    min_base_distance: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.05
    retries: Annotated[Int, Field(ge=0, le=10)] = 2
    retry_delay_s: Annotated[Float, Field(ge=0.0, le=60.0)] = 0.5
    timeout_s: Annotated[Float, Field(gt=0.0, le=3600.0)] = 30.0
    moving_time: MovingTime = 1.5
    track_wait_s: Seconds = 10.0
    planner: Literal["collision", "paper"] = "collision"
    clearance: Annotated[Float, Field(ge=0.0, le=0.1)] = 0.01
    approach_candidates: Annotated[Int, Field(ge=4, le=360)] = 24
    plan_time_s: Annotated[Float, Field(gt=0.0, le=60.0)] = 2.0
    top_grasp: Bool = True


@dataclass(config=_STRICT)
class FollowConfig:
    """Following a tag or a bottle (armvision.tasks.follow).

    A servo loop at ``rate_hz`` streams joint targets from damped least-squares differential
    IK (damping ``damping``), with the end effector's speed and acceleration limited to
    ``max_speed`` m/s and ``max_accel`` m/s^2, keeping ``standoff`` m from the target on the
    line from the base at the target's height plus ``height_offset``. It stops after
    ``duration_s`` or when the target has not been seen for ``lost_timeout_s``. ``tag_id`` is
    the tag to follow (a tag other than the gripper's).
    """

    rate_hz: Annotated[Float, Field(ge=1.0, le=200.0)] = 50.0
    duration_s: Annotated[Float, Field(gt=0.0, le=86400.0)] = 20.0  # a day at most
    tag_id: Annotated[Int, Field(ge=0, lt=max(TAG_FAMILY_SIZES.values()))] = 0
    standoff: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.12
    height_offset: Annotated[Float, Field(ge=-1.0, le=1.0)] = 0.10
    gain: Annotated[Float, Field(gt=0.0, le=100.0)] = 4.0
    damping: Annotated[Float, Field(gt=0.0, le=10.0)] = 0.05
    max_speed: Annotated[Float, Field(gt=0.0, le=5.0)] = 0.25
    max_accel: Annotated[Float, Field(gt=0.0, le=50.0)] = 1.0
    lost_timeout_s: Seconds = 0.5


@dataclass(config=_STRICT)
class AnalyzeConfig:
    """Liquid-level analysis of a bottle (armvision.tasks.analyze).

    ``frames`` measurements in distinct frames are averaged (weighted by confidence); below
    ``min_confidence`` on average, when the bottle is seen smaller than ``min_box_height_px``
    pixels, or when fewer than ``frames`` measurements come in time, the view is poor and (with
    ``allow_pick``) the bottle is picked up, stood on the table where its centre is as near
    ``present_distance`` m from the camera as the field of view and the arm's reach allow (with
    the simulator's default camera, 1 m away and 0.45 m up, the nearest is ~0.55 m), measured
    there and put back. ``timeout_s`` bounds finding and measuring the bottle, the pick and
    presentation included; a bottle that was moved is always put back.
    """

    frames: Annotated[Int, Field(ge=1, le=100)] = 8
    min_confidence: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.5
    min_box_height_px: Annotated[Float, Field(ge=0.0, le=10000.0)] = 60.0  # above 1080: always pick
    allow_pick: Bool = True
    present_distance: Annotated[Float, Field(gt=0.0, le=3.0)] = 0.55
    timeout_s: Annotated[Float, Field(gt=0.0, le=3600.0)] = 60.0


@dataclass(config=_STRICT)
class PerceptionConfig:
    """Which object detector finds the bottles and cups (armvision.perception.factory).

    ``detector``: ``geometric`` (depth alone, no weights), ``onnx`` (the ONNX model ``model``
    run by ONNX Runtime: an SSD-MobileNet-v2 or a YOLOv8/YOLO11 export), ``jetson``
    (jetson-inference's detectNet on a Jetson; ``model`` is its network name or model file,
    default ssd-mobilenet-v2) or ``hybrid`` (the ONNX model names the objects, the geometric
    fit places and sizes them; objects the network does not name are reported as "other").
    ``labels``: a labels.txt (one class name a line, line = class id) naming bottle and cup;
    without it COCO's ids per model kind (SSD with background: bottle 44, cup 47; YOLO: 39,
    41). Network boxes scoring below ``score_threshold`` are dropped, then duplicates
    overlapping more than ``nms_iou`` (ONNX).
    """

    detector: Literal["geometric", "onnx", "jetson", "hybrid"] = "geometric"
    # validate_default: checked against the detector when only that is set.
    model: Annotated[Text | None, Field(validate_default=True)] = None
    labels: Text | None = None
    score_threshold: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.5
    nms_iou: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.45

    @field_validator("model")
    @classmethod
    def _model_needed(cls, model: str | None, info: ValidationInfo) -> str | None:
        detector = info.data.get("detector")
        if model is None and detector in ("onnx", "hybrid"):
            raise ValueError(
                f'detector {detector!r} needs an ONNX model file (perception.model = "PATH")'
            )
        return model


#: A zone's rectangle on the table: (x_min, y_min, x_max, y_max), base frame, metres.
ZoneRect = tuple[
    Annotated[Float, Field(ge=-1.0, le=1.0)],
    Annotated[Float, Field(ge=-1.0, le=1.0)],
    Annotated[Float, Field(ge=-1.0, le=1.0)],
    Annotated[Float, Field(ge=-1.0, le=1.0)],
]
ZoneName = Annotated[
    str, Strict(), StringConstraints(min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_-]+$")
]
#: Zones on the simulated bench, either side of where its objects stand (reachable, in view).
DEFAULT_ZONES: dict[str, tuple[float, float, float, float]] = {
    "empty": (0.0, -0.38, 0.30, -0.22),
    "full": (0.0, 0.22, 0.30, 0.38),
}


@dataclass(config=_STRICT)
class PlaceConfig:
    """Setting a held bottle down (armvision.tasks.place).

    ``zones``: named rectangles on the table, ``[x_min, y_min, x_max, y_max]`` in the base
    frame (metres; TOML ``[place.zones]`` with ``empty = [0.0, -0.38, 0.30, -0.22]``); a zone
    must be at least 8 cm each way (room for a bottle). A spot is free when it keeps
    ``clearance`` m to every other object of the planning scene. Afterwards the bottle must be
    tracked within ``tolerance`` m of the asked spot, standing (its tracked height within
    ``height_tolerance`` of the held bottle's), seen within ``verify_s`` seconds.
    """

    zones: dict[ZoneName, ZoneRect] = dataclasses.field(default_factory=lambda: dict(DEFAULT_ZONES))
    clearance: Annotated[Float, Field(ge=0.0, le=0.2)] = 0.03
    tolerance: Annotated[Float, Field(gt=0.0, le=0.2)] = 0.02
    height_tolerance: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.3
    verify_s: Seconds = 3.0

    @field_validator("zones")
    @classmethod
    def _zones(
        cls, zones: dict[str, tuple[float, float, float, float]]
    ) -> dict[str, tuple[float, float, float, float]]:
        for name, (x0, y0, x1, y1) in zones.items():
            if x1 - x0 < 0.08 or y1 - y0 < 0.08:
                raise ValueError(
                    f"zone {name!r} must be [x_min, y_min, x_max, y_max] with each side at "
                    f"least 0.08 m, not {[x0, y0, x1, y1]}"
                )
        return zones


@dataclass(config=_STRICT)
class SortConfig:
    """Sorting the bottles on the table into zones (armvision.tasks.sort).

    ``by = "fill"``: a bottle measured below ``fill_threshold`` (0..1 of its body) goes to the
    zone ``below``, any other to ``above``. ``by = "colour"``: to the zone ``colours`` maps its
    liquid's colour name to (:data:`armvision.tasks.colour.COLOUR_PALETTE`; ``"*"`` for any
    other colour); a colour without a zone is skipped. Zone names are ``place.zones``'.
    """

    by: Literal["fill", "colour"] = "fill"
    fill_threshold: Annotated[Float, Field(gt=0.0, lt=1.0)] = 0.3
    below: ZoneName = "empty"
    above: ZoneName = "full"
    colours: dict[ZoneName | Literal["*"], ZoneName] = dataclasses.field(default_factory=dict)


def _token_text(token: str) -> str:
    if any(c.isspace() for c in token):
        raise ValueError("must not hold spaces or other whitespace")
    return _usable_text(token)


@dataclass(config=_STRICT)
class UIConfig:
    """The operator web UI (``armvision ui``, armvision.ui).

    It listens on ``host``:``port``; on any address but the loopback every request and socket
    must carry ``token`` (empty: a random one is made and printed at start; the environment
    variable ``ARMVISION_UI_TOKEN`` overrides this key, which keeps it out of files). The
    state is pushed ``state_hz`` times a second, video at most ``video_fps`` frames a second as
    JPEG of ``jpeg_quality``; the depth view maps ``depth_min_m``..``depth_max_m`` onto its
    colours. ``follow_duration_s`` is the follow buttons' default length. ``foxglove``: serve
    the recording's channels live to Foxglove on ``foxglove_host``:``foxglove_port``.
    """

    host: Text = "127.0.0.1"
    port: Annotated[Int, Field(ge=0, le=65535)] = 8000
    token: Annotated[str, Strict(), Field(max_length=4096), AfterValidator(_token_text)] = ""
    # Host names (or addresses) the page may be opened by, besides the bound address, the
    # loopback names and this machine's host name; a request naming any other Host is refused
    # (DNS rebinding).
    allowed_hosts: Annotated[tuple[Text, ...], Field(max_length=256)] = ()
    state_hz: Annotated[Float, Field(ge=1.0, le=60.0)] = 15.0
    video_fps: Annotated[Float, Field(ge=1.0, le=60.0)] = 15.0
    jpeg_quality: Annotated[Int, Field(ge=10, le=100)] = 80
    depth_min_m: Annotated[Float, Field(ge=0.0, le=65.0)] = 0.2
    # validate_default: checked against depth_min_m when only that is set.
    depth_max_m: Annotated[Float, Field(gt=0.0, le=65.0, validate_default=True)] = 2.0
    follow_duration_s: Annotated[Float, Field(gt=0.0, le=86400.0)] = 60.0
    # The recording's channels live to Foxglove (the Foxglove SDK's WebSocket server, which
    # has no access token: it listens on foxglove_host, the loopback unless you change it).
    foxglove: Bool = False
    foxglove_host: Text = "127.0.0.1"
    foxglove_port: Annotated[Int, Field(ge=0, le=65535)] = 8765

    @field_validator("depth_max_m")
    @classmethod
    def _depth_range(cls, depth_max_m: float, info: ValidationInfo) -> float:
        return _above(depth_max_m, info, "depth_min_m")


@dataclass(config=_STRICT)
class RecordConfig:
    """Recording runs to MCAP (``--record PATH``, the UI's Record; armvision.runtime.recorder).

    ``dir``: where the UI's Record button writes (``run-<date>-<time>.mcap``); ``queue``: items
    (a frame, a joint reading, a state sample) waiting for the recorder thread: a realtime run
    drops what does not fit (counted) rather than wait, a lockstep run waits; ``state_hz``:
    tracks, transforms, markers, task, health and liquid samples a second; colour frames are
    ``color_format`` (``jpeg`` of ``jpeg_quality``, or lossless ``png``); ``compression`` and
    ``chunk_kib`` are the MCAP chunks' (a killed run keeps every complete chunk).
    """

    dir: Text = "recordings"
    queue: Annotated[Int, Field(ge=1, le=100_000)] = 256
    state_hz: Annotated[Float, Field(gt=0.0, le=100.0)] = 10.0
    color_format: Literal["jpeg", "png"] = "jpeg"
    # 95: a lockstep run replays to within 1 mm of its tracks (90 gives about 1.1 mm).
    jpeg_quality: Annotated[Int, Field(ge=10, le=100)] = 95
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    chunk_kib: Annotated[Int, Field(ge=16, le=65536)] = 1024


@dataclass(config=_STRICT)
class Config:
    """The whole tree; every section has the paper's defaults."""

    robot: RobotConfig = dataclasses.field(default_factory=RobotConfig)
    tag: TagConfig = dataclasses.field(default_factory=TagConfig)
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    sim: SimConfig = dataclasses.field(default_factory=SimConfig)
    calibration: CalibrationConfig = dataclasses.field(default_factory=CalibrationConfig)
    fusion: FusionConfig = dataclasses.field(default_factory=FusionConfig)
    runtime: RuntimeConfig = dataclasses.field(default_factory=RuntimeConfig)
    grab: GrabConfig = dataclasses.field(default_factory=GrabConfig)
    follow: FollowConfig = dataclasses.field(default_factory=FollowConfig)
    analyze: AnalyzeConfig = dataclasses.field(default_factory=AnalyzeConfig)
    place: PlaceConfig = dataclasses.field(default_factory=PlaceConfig)
    sort: SortConfig = dataclasses.field(default_factory=SortConfig)

    @model_validator(mode="after")
    def _sort_zones_exist(self) -> Config:
        zones = self.place.zones
        named = [("sort.below", self.sort.below), ("sort.above", self.sort.above)]
        named += [(f"sort.colours.{k}", v) for k, v in self.sort.colours.items()]
        for key, zone in named:
            if zone not in zones:
                raise ValueError(
                    f"'{key}' names zone {zone!r}, which 'place.zones' does not define "
                    f"(zones: {', '.join(sorted(zones)) or 'none'})"
                )
        return self

    perception: PerceptionConfig = dataclasses.field(default_factory=PerceptionConfig)
    ui: UIConfig = dataclasses.field(default_factory=UIConfig)
    record: RecordConfig = dataclasses.field(default_factory=RecordConfig)


_ADAPTER = TypeAdapter(Config)


def _parse_value(text: str) -> Any:
    """An override value parsed as TOML (numbers, booleans, [lists]); bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except (ValueError, RecursionError):  # TOMLDecodeError; an int too long to convert
        return text


def _clean(text: str, limit: int | None = None) -> str:
    """``text`` fit for a one-line message: control characters escaped, at most ``limit``."""
    if not text.isprintable():
        text = text.encode("unicode_escape", "backslashreplace").decode("ascii")
    if limit is not None and len(text) > limit:
        text = text[: limit - 3] + "..."
    return text


def _show(value: Any, limit: int = 60) -> str:
    """A short ``repr`` of a (possibly huge or nested) input value for an error message."""
    try:
        text = repr(value)
    except ValueError:  # holds an int with more digits than Python turns into text
        text = f"a {type(value).__name__} holding a huge integer"
    return _clean(text, limit)


def known_keys(cls: type | None = None, prefix: str = "") -> list[str]:
    """Every dotted key the configuration accepts, e.g. ``robot.moving_time``."""
    cls = Config if cls is None else cls
    hints = typing.get_type_hints(cls)
    keys: list[str] = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            keys += known_keys(hints[f.name], f"{prefix}{f.name}.")
        else:
            keys.append(prefix + f.name)
    return keys


def apply_override(data: dict[str, Any], assignment: str) -> None:
    """Apply one ``section.key=value`` assignment to a raw config dict, in place."""
    key, sep, value = assignment.partition("=")
    key = key.strip()
    shown = _show(assignment, 80)
    if not sep or not key:
        raise ConfigError(f"override {shown} must look like section.key=value")
    if "\n" in assignment or "\r" in assignment:
        raise ConfigError(f"override {shown}: the key and value must be on one line")
    if any(not part.strip() for part in key.split(".")):
        raise ConfigError(f"override {shown}: the key has an empty part (write section.key)")
    *parents, leaf = (part.strip() for part in key.split("."))
    node = data
    for part in parents:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"override {shown}: {_show(part)} is a value, not a section")
        node = child
    node[leaf] = _parse_value(value.strip())


def _describe(error: ErrorDetails) -> str:
    key = _clean(".".join(str(part) for part in error["loc"]), 120) or "(top level)"
    if error["type"] in ("unexpected_keyword_argument", "extra_forbidden"):
        return f"unknown key '{key}'"
    if error["type"] == "missing_argument":
        return f"'{key}' is required"
    msg = _clean(error["msg"].removeprefix("Value error, "))  # our own validators' messages
    if not error["loc"]:  # a check across sections: its message names the keys it concerns
        return msg
    return f"'{key}': {msg} (got {_show(error.get('input'))})"


def config_from_dict(data: dict[str, Any], source: str = "configuration") -> Config:
    """Validate a raw dict (as read from TOML) into a :class:`Config`, or raise ConfigError."""
    try:
        return _ADAPTER.validate_python(data)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        message = f"{_clean(source)}: " + "; ".join(_describe(e) for e in errors)
        if any(e["type"] in ("unexpected_keyword_argument", "extra_forbidden") for e in errors):
            message += f". Known keys: {', '.join(known_keys())}"
        raise ConfigError(message) from None


def find_config_file(explicit: str | os.PathLike[str] | None = None) -> Path | None:
    """The config file to use: explicit path, then $ARMVISION_CONFIG, then ./armvision.toml."""
    if explicit is not None:
        return Path(explicit)
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR])
    local = Path(LOCAL_FILE)
    return local if local.is_file() else None


def load_config(
    path: str | os.PathLike[str] | None = None, overrides: list[str] | tuple[str, ...] = ()
) -> Config:
    """Load the configuration: defaults, then the TOML file (if any), then ``overrides``."""
    file = find_config_file(path)
    data: dict[str, Any] = {}
    source = "defaults"
    if file is not None:
        source = str(file)
        name = _clean(source)
        try:
            with open(file, "rb") as fh:
                data = tomllib.load(fh)
        except FileNotFoundError:
            raise ConfigError(
                f"config file {name} does not exist (write one with `armvision config > {name}`)"
            ) from None
        except UnicodeDecodeError as exc:
            raise ConfigError(
                f"{name} is not valid UTF-8 (byte {exc.start}): TOML files are UTF-8, save it so"
            ) from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{name} is not valid TOML: {_clean(str(exc))}") from None
        except (ValueError, RecursionError) as exc:  # an int too long to convert, deep nesting
            raise ConfigError(f"{name} is not usable TOML: {_clean(str(exc), 200)}") from None
        except OSError as exc:
            raise ConfigError(f"cannot read config file {name}: {exc.strerror}") from None
    for assignment in overrides:
        apply_override(data, assignment)
    if overrides:
        source += " with --set " + " ".join(overrides)
    return config_from_dict(data, source)


def config_to_dict(config: Config) -> dict[str, Any]:
    """Plain nested dict of ``config`` (tuples as lists), for JSON and TOML output."""

    def plain(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value

    return plain(dataclasses.asdict(config))


def config_to_toml(config: Config) -> str:
    """``config`` as TOML that :func:`load_config` reads back; unset optional keys are omitted."""

    def drop_none(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: drop_none(v) for k, v in value.items() if v is not None}
        return value

    return tomli_w.dumps(drop_none(config_to_dict(config)))
