"""The simulated bench: a :class:`~armvision.runtime.system.System` on a fresh SimWorld, and
calibration in the simulation as a user would do it, compared with the simulator's truth.

This package sits above the runtime and the tasks: it wires the simulation in, and nothing
below it knows that the arm or the camera is simulated.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from armvision.calibration.procedure import CalibrationResult, calibrate, pose_errors
from armvision.calibration.quality import check_quality
from armvision.calibration.sampling import Progress
from armvision.camera.base import Camera
from armvision.config import Config, TagConfig
from armvision.robot.base import Arm
from armvision.runtime.build import result_status
from armvision.runtime.recorder import Recorder, RecordingArm, RecordingCamera
from armvision.runtime.state import CalibrationStatus
from armvision.runtime.system import System
from armvision.sim.arm import SimArm
from armvision.sim.camera import SimCamera
from armvision.sim.scene import SceneSpec
from armvision.sim.world import SimWorld

Array = NDArray[np.float64]


def calibrate_sim(
    config: Config,
    seed: int,
    T_base_cam: Array | None = None,
    calibration_tag: TagConfig | None = None,
    progress: Progress | None = None,
    recorder: Recorder | None = None,
) -> CalibrationResult:
    """Calibrate in a fresh lockstep simulation of ``seed`` and compare with the truth.

    ``T_base_cam`` places the simulated camera (default: the configured placement);
    ``calibration_tag`` is the tag the calibration is *told* about, when it should differ
    from the one the simulation mounts (``config.tag``), e.g. a mis-measured offset.
    ``recorder``: every frame the procedure reads is recorded, with the encoders.
    """
    told = config if calibration_tag is None else dataclasses.replace(config, tag=calibration_tag)
    with SimWorld(config, seed) as world:
        if T_base_cam is not None:
            world.set_camera_pose(T_base_cam)
        arm = SimArm(world)
        try:
            with SimCamera(world) as sim_camera:
                camera: Camera = sim_camera
                moved: Arm = arm
                if recorder is not None:
                    camera = RecordingCamera(sim_camera, recorder)
                    moved = cast(Arm, RecordingArm(arm, recorder))
                result = calibrate(
                    moved, camera, told, wait=world.advance, progress=progress, seed=seed
                )
        finally:
            arm.close()
        T_true = world.T_base_cam()
    truth = {
        "T_base_cam": T_true.tolist(),
        "tag_offset_ee": list(config.tag.offset_ee),
        "encoder_bias_deg": np.degrees(arm.encoder_bias).tolist(),
        "methods": {
            name: pose_errors(fit.T_base_cam, T_true)
            for name, fit in result.fits.items()
            if not isinstance(fit, str)
        },
    }
    truth.update(truth["methods"][result.method])
    return dataclasses.replace(result, truth=truth)


def calibrate_empty_table(config: Config, seed: int, T_base_cam: np.ndarray | None = None):
    """Calibrate in the simulation as a user would: an empty table, the same camera placement
    (``T_base_cam``, default the configured one) and the same arm (encoder offsets of
    ``seed``). Returns (CalibrationStatus, CalibrationResult with the truth filled in);
    CalibrationError if the result fails the plausibility check, as ``armvision calibrate``."""
    empty = dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, min_objects=0, max_objects=0, loose_tags=0)
    )
    result = calibrate_sim(empty, seed, T_base_cam=T_base_cam)
    check_quality(result, config.calibration, "check tag.* and calibration.* and run again")
    return result_status(result), result


def sim_truth_calibration(T_base_cam: np.ndarray) -> CalibrationStatus:
    """The simulator's true camera pose, for tests that are not about calibration."""
    return CalibrationStatus("simulator truth", "none", None, np.asarray(T_base_cam, dtype=float))


#: The emulated bus's packet latency: its servos share the machine's cores with everything else.
EMULATED_BUS_LATENCY_MS = 100.0
#: ... and in lockstep, where waiting costs no simulated time: an emulator thread starved of the
#: CPU for a few hundred ms by other jobs must not read as three lost state reads (a lost
#: contact), or a run would depend on the machine's load (eval grab saw it with 5 jobs on 2 cores).
LOCKSTEP_BUS_LATENCY_MS = 1000.0


def sim_arm(world: SimWorld, arm_seed: int | Sequence[int] | None) -> tuple[Arm, tuple]:
    """``config.sim.arm``: SimArm, or the Dynamixel driver over the servo-bus emulator (the
    emulator too, for the system to close). In lockstep the driver reads on demand and waits
    by advancing the world, so runs stay repeatable."""
    if world.config.sim.arm != "dynamixel-emulated":
        return SimArm(world, seed=arm_seed), ()
    from armvision.robot.dynamixel import DynamixelArm
    from armvision.sim.servo_bus import ServoBusEmulator

    bus = ServoBusEmulator(world).start()
    robot = world.config.robot
    lockstep = world.mode == "lockstep"
    try:
        arm = DynamixelArm(
            bus.port,
            moving_time=robot.moving_time,
            accel_time=robot.accel_time,
            gripper_pressure=robot.gripper_pressure,
            latency_ms=LOCKSTEP_BUS_LATENCY_MS if lockstep else EMULATED_BUS_LATENCY_MS,
            state_rate_hz=0.0 if lockstep else 200.0,
            clock=lambda: world.time,
            sleep=world.advance if lockstep else None,
        )
    except BaseException:
        bus.close()
        raise
    return arm, (bus,)


def sim_system(
    config: Config,
    seed: int = 0,
    *,
    mode: Literal["lockstep", "realtime"] = "lockstep",
    scene: SceneSpec | None = None,
    calibration: CalibrationStatus | None = None,
    arm_seed: int | Sequence[int] | None = None,
    **detectors,
) -> System:
    """A System on a fresh SimWorld of ``seed`` (``scene`` overrides the seed's scene).

    Without ``calibration`` the system runs with the simulator's true camera pose (say so in
    anything you report). ``arm_seed`` draws the arm's encoder zero offsets (default: from
    ``seed``); give the one a calibration was made with to keep "the same arm" across scenes.
    The system owns the world, the arm and the camera.
    """
    world = SimWorld(config, seed, mode=mode, scene=scene)
    arm, bus = sim_arm(world, arm_seed)
    camera = SimCamera(world)
    if calibration is None:
        calibration = sim_truth_calibration(world.T_base_cam())
    return System(
        config,
        arm,
        camera,
        calibration,
        clock=lambda: world.time,
        lockstep=mode == "lockstep",
        world=world,
        owns=(arm, *bus, world),
        **detectors,
    )


def sim_world(system: System) -> SimWorld:
    """The SimWorld under a system :func:`sim_system` built (its truth for reports)."""
    world = system.world
    if not isinstance(world, SimWorld):
        raise TypeError("this system does not run on the simulated bench")
    return world
