"""The running system: the paper's threads around one arm and one camera.

:class:`System` owns these stages:

- **camera**: reads every frame and publishes the newest;
- **tags**: AprilTag poses of the newest frame, the gripper tag's pushed into fusion;
- **objects**: bottles and cups of the newest frame, pushed into fusion (which tracks them);
- **liquid**: the liquid level of every tracked bottle, averaged per track;
- **fusion**: the :class:`~armvision.fusion.loop.FusionLoop` cycle at ``fusion.rate_hz``;
- **motion**: one worker that runs tasks (grab, follow, analyze, home, ...) one at a time
  (:mod:`armvision.runtime.jobs`).

The three detection stages can be switched on and off while running (:meth:`set_detector`).
Every stage reports its health (rate, age of its last output, last error) in the state; a
failing stage logs the error, shows it and carries on with the next frame, it never dies
silently. :meth:`System.snapshot` hands out an immutable
:class:`~armvision.runtime.state.SystemState`.

Two schedules, same stages (the work of each is a method here):

- ``lockstep=False`` (real hardware, or a realtime simulation): each stage is a thread
  (:mod:`armvision.runtime.threads`).
- ``lockstep=True`` (a simulation): no threads; :meth:`pump` runs the stages in time order
  while it advances the simulation, and tasks run on the caller's thread, their waits pumping
  (:mod:`armvision.runtime.lockstep`).

Tasks are functions ``task(ctx, **kwargs)`` taking a
:class:`~armvision.runtime.context.TaskContext`; everything a task waits for goes through
the context, so :meth:`stop_task` (the Stop button) halts the arm at once and the task ends
at its next wait.

One camera pose: the calibration given (:class:`CalibrationStatus`) is the fusion filter's
prior; the pose it refines from the gripper tag (``state.T_base_cam``) is what the object
detector is given with each frame, what fusion maps detections with and what tasks use.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from armvision.camera.base import Camera
from armvision.camera.frames import RGBDFrame
from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.fusion.drift import DriftMonitor
from armvision.fusion.kalman import DEFAULT_FOCAL_PX
from armvision.fusion.loop import FusionLoop
from armvision.perception.detection import FrameContext, ObjectDetector
from armvision.perception.factory import object_detector as configured_object_detector
from armvision.perception.liquid import ContainerGeometry, LiquidLevel, LiquidLevelMeter
from armvision.perception.tags import TagDetector
from armvision.robot.base import Arm, ArmBase
from armvision.robot.tag_mount import tag_mount
from armvision.runtime.context import Task
from armvision.runtime.jobs import Jobs
from armvision.runtime.lockstep import DETECTORS, Lockstep, SimulatedWorld, require_world
from armvision.runtime.planning_scene import DepthView
from armvision.runtime.recorder import Recorder
from armvision.runtime.state import (
    CalibrationStatus,
    HealthMeter,
    StateStore,
    SystemState,
    TaskStatus,
    average_levels,
)
from armvision.runtime.threads import StageThreads

Array = NDArray[np.float64]
log = logging.getLogger("armvision.runtime")

STAGES = ("camera", *DETECTORS, "fusion", "motion")

__all__ = ["DETECTORS", "STAGES", "Closeable", "System"]


@runtime_checkable
class Closeable(Protocol):
    """Something a system owns and releases at :meth:`System.close` (the world, the arm)."""

    def close(self) -> None: ...


class _CorrectedEncoders:
    """The arm's encoder readings minus the calibration's estimated joint zero offsets."""

    def __init__(self, arm: Arm, offsets: Array | None) -> None:
        self.arm = arm
        self.offsets = None if offsets is None else np.asarray(offsets, dtype=float)

    def get_joint_positions(self) -> Array:
        q = np.asarray(self.arm.get_joint_positions(), dtype=float)
        return q if self.offsets is None else q - self.offsets

    def get_joint_velocities(self) -> Array | None:
        """The arm's measured joint velocities (a zero offset changes none of them)."""
        return self.arm.get_joint_velocities()

    def raw(self, q: Any) -> Array:
        """The encoder reading a corrected one came from (the offsets added back)."""
        q = np.array(q, dtype=float)
        return q if self.offsets is None else q + self.offsets


class System:
    """The stages (threads, or the lockstep schedule) around one arm and one camera.

    ``calibration``: the camera pose and joint offsets to start from. ``clock``: seconds on
    the camera's time base (simulation time for a simulation). ``world``: the simulation, if
    this is one: ``lockstep`` advances its clock, reports compare with its truth. Detectors
    default to the configured tag detector, the configured object detector
    (``[perception]``, :func:`~armvision.perception.factory.object_detector`) and the liquid
    meter. ``owns``: what :meth:`close` releases.
    Use as a context manager: :meth:`start`, :meth:`close`.
    """

    def __init__(
        self,
        config: Config,
        arm: Arm,
        camera: Camera,
        calibration: CalibrationStatus,
        *,
        clock: Callable[[], float] = time.monotonic,
        lockstep: bool = False,
        world: SimulatedWorld | None = None,
        tag_detector: TagDetector | None = None,
        object_detector: ObjectDetector | None = None,
        liquid_meter: LiquidLevelMeter | None = None,
        owns: tuple[Closeable, ...] = (),
    ) -> None:
        self.config = config
        self.arm = arm
        self.camera = camera
        self.clock = clock
        self.lockstep = lockstep
        self.world = world
        self._lockstep = Lockstep(self, require_world(world)) if lockstep else None
        self._threads = StageThreads(self)
        self._owns = owns
        rt = config.runtime
        self.calibration = calibration
        self.T_ee_tag = tag_mount(config.tag.offset_ee)
        self.tag_detector = tag_detector or TagDetector.from_config(config.tag)
        self.object_detector: ObjectDetector = object_detector or configured_object_detector(
            config.perception
        )
        self.liquid_meter = liquid_meter or LiquidLevelMeter()
        self.encoders = _CorrectedEncoders(arm, calibration.joint_offsets_rad)
        self.fusion = self._fusion_loop()
        self.store = StateStore()
        self.jobs = Jobs(self)
        self.enabled = {
            "tags": rt.tag_detection,
            "objects": rt.object_detection,
            "liquid": rt.liquid_detection,
        }
        self.meters = {name: HealthMeter(name, clock) for name in STAGES}
        self.rates = {"tags": rt.tag_hz, "objects": rt.object_hz, "liquid": rt.liquid_hz}
        self._levels: dict[int, deque[tuple[float, LiquidLevel]]] = {}
        self.fusion_stalls = 0  # times the fusion stage fell more than a cycle behind
        self.stuck: tuple[str, ...] = ()  # threads that did not end at close()
        self.stopping = threading.Event()  # set by close(): every stage ends
        self.recorder: Recorder | None = None  # attach_recorder(): the run is being recorded
        self._started = False
        self._closed = False

    @property
    def T_base_cam(self) -> Array:
        """The camera pose the system works with now: the calibration as fusion refines it
        (``SystemState.T_base_cam`` of a snapshot taken now)."""
        refined = self.fusion.snapshot().T_base_cam
        return np.asarray(self.calibration.T_base_cam if refined is None else refined)

    # ---------------------------------------------------------------- life cycle

    def start(self) -> System:
        """Start the stages (threads, or the lockstep schedule)."""
        if self._started:
            return self
        if self._closed:
            raise ArmvisionError("this System was closed; build a new one")
        self._started = True
        if self._lockstep is not None:
            self._lockstep.start()
        else:
            self._threads.start()
        return self

    def close(self) -> None:
        """Stop any task (the arm halts where it is), end every thread, release what it owns.

        A thread that does not end within ``runtime.join_timeout_s`` (a camera read that hangs
        in its driver) is not pulled from under: what the system owns (the simulation, the
        arm) is released only once that thread has ended, by a closer thread that waits for it;
        :attr:`stuck` names such threads.
        """
        if self._closed:
            return
        self._closed = True
        self.stop_task()
        self.stopping.set()
        self.jobs.close()
        timeout = self.config.runtime.join_timeout_s
        self.stuck = self._threads.join(timeout)
        if self.lockstep:
            self.camera.stop()
        self.detach_recorder()
        if not self.stuck:
            self._release()
            return
        log.error(
            "the %s thread(s) did not stop within %.1f s (a hung camera or arm call?); what "
            "they use is released once they end",
            ", ".join(self.stuck),
            timeout,
        )

        def release_later() -> None:
            self._threads.join(None)
            self._release()

        threading.Thread(target=release_later, name="armvision-closer", daemon=True).start()

    def _release(self) -> None:
        for thing in self._owns:
            try:
                thing.close()
            except Exception:  # closing must go on for the rest
                log.exception("closing %s failed", type(thing).__name__)

    def __enter__(self) -> System:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- recording

    def attach_recorder(self, recorder: Recorder) -> None:
        """Record the run from now on to ``recorder`` (opened; see
        :mod:`armvision.runtime.recorder`): the configuration, calibration and detectors now,
        then what every stage produces. One recorder at a time: a previous one is stopped."""
        self.detach_recorder()
        recorder.start_of_run(self.clock(), self)
        self.recorder = recorder
        if isinstance(self.arm, ArmBase):  # the joint targets the arm accepts
            self.arm.command_listener = lambda q: recorder.command(self.clock(), q)

    def detach_recorder(self) -> Recorder | None:
        """Stop recording (the file is finished); the recorder that was attached, if any."""
        recorder, self.recorder = self.recorder, None
        if isinstance(self.arm, ArmBase):
            self.arm.command_listener = None
        if recorder is not None:
            recorder.stop()
        return recorder

    def publish_frame(self, frame: RGBDFrame) -> None:
        """A camera frame for the stages (and the recording)."""
        self.store.set_frame(frame)
        if (recorder := self.recorder) is not None:
            recorder.frame(frame)

    # ---------------------------------------------------------------- state

    def snapshot(self) -> SystemState:
        """The whole state now (immutable)."""
        stale = self.config.runtime.stale_s
        health = {}
        for name in STAGES:
            enabled = self.enabled.get(name, True)
            if self.lockstep:
                alive = self._started and not self._closed
            else:
                alive = self._threads.alive(name)
            # An idle motion worker has no output to be late with.
            health[name] = self.meters[name].health(
                enabled, alive, math.inf if name == "motion" else stale
            )
        try:
            finger = float(self.arm.gripper.get_finger_position())
        except Exception:  # a gripper that cannot be read now is not a reason to fail
            finger = None
        return self.store.snapshot(
            self.clock(), self.fusion.snapshot(), health, self.enabled, self.calibration, finger
        )

    def _fusion_loop(self) -> FusionLoop:
        try:
            focal_px = float(self.camera.intrinsics.fx)
        except ArmvisionError:  # a RealSense knows its intrinsics only once started
            focal_px = DEFAULT_FOCAL_PX
        cal = self.calibration
        T_base_cam = np.asarray(cal.T_base_cam, dtype=float)
        drift = DriftMonitor(
            self.config.calibration,
            T_base_cam,
            self.T_ee_tag if cal.tag_offset_ee is None else tag_mount(cal.tag_offset_ee),
            cal.tag_rotation_reference,
            active=cal.calibrated,  # the nominal placement of an uncalibrated camera is no claim
        )
        return FusionLoop(
            self.config,
            self.encoders,
            T_base_cam,
            self.T_ee_tag,
            clock=self.clock,
            focal_px=focal_px,
            drift=drift,
        )

    def set_calibration(self, calibration: CalibrationStatus) -> None:
        """Run with a new calibration from now on (a recalibration while running).

        The fusion loop starts afresh with the new camera pose as its prior (tracks measured
        with the old one would sit where the old pose put them; they are found again within a
        few frames); the object detector gets the new pose with its next frame; the encoder
        offsets follow.
        """
        T_base_cam = np.asarray(calibration.T_base_cam, dtype=float)
        if T_base_cam.shape != (4, 4) or not np.all(np.isfinite(T_base_cam)):
            raise ArmvisionError("a calibration needs a finite 4x4 T_base_cam")
        self.calibration = calibration
        self.encoders.offsets = (
            None
            if calibration.joint_offsets_rad is None
            else np.asarray(calibration.joint_offsets_rad, dtype=float)
        )
        self.fusion = self._fusion_loop()  # the fusion stage picks it up at its next cycle
        self._levels.clear()
        self.store.keep_liquid(set())
        if (recorder := self.recorder) is not None:
            recorder.calibration(self.clock(), calibration)

    def set_detector(self, name: str, enabled: bool) -> None:
        """Switch the tag, object or liquid stage on or off."""
        if name not in DETECTORS:
            raise ArmvisionError(f"no detector {name!r}; the detectors are {', '.join(DETECTORS)}")
        self.enabled[name] = bool(enabled)
        if (recorder := self.recorder) is not None:
            recorder.detectors(self.clock(), self.enabled)
        if name == "tags" and not enabled:
            self.store.set(tags=())
        if name == "objects" and not enabled:
            self.store.set(detections=())

    # ---------------------------------------------------------------- the stages' work

    def fusion_step(self) -> None:
        """One fusion cycle (the fusion stage's unit of work)."""
        snapshot = self.fusion.step()
        if (recorder := self.recorder) is not None:
            recorder.fusion(self, snapshot)

    def tags_once(self, frame: RGBDFrame) -> None:
        """The tag stage on one frame: every tag published, the gripper tag's pose fused."""
        found = self.tag_detector.detect(frame)
        tags = [t for t in found if _finite(t.T_cam_tag, t.center)]
        for tag in tags:
            if tag.id == self.config.tag.id:
                self.fusion.push_tag(frame.timestamp, tag.T_cam_tag)
        self.store.set(tags=tuple(tags), tags_time=frame.timestamp)
        if (recorder := self.recorder) is not None:
            recorder.tags(frame.timestamp, tuple(tags))
        _reject_non_finite("tag detector", "tag", len(found) - len(tags))

    def objects_once(self, frame: RGBDFrame) -> None:
        """The object stage on one frame, told the camera pose fusion holds and the joints."""
        context = FrameContext(
            T_base_cam=self.T_base_cam, joint_positions=self.encoders.get_joint_positions()
        )
        if (recorder := self.recorder) is not None:  # the reading the detector is given
            recorder.frame_joints(frame.timestamp, self.encoders.raw(context.joint_positions))
        found = self.object_detector.detect(frame, context)
        detections = [d for d in found if _finite(d.center_cam, d.box, d.radius, d.height, d.score)]
        self.fusion.push_detections(frame.timestamp, detections)
        T = np.asarray(context.T_base_cam, dtype=float)
        objects = []
        for d in detections:
            p_base = T[:3, :3] @ np.asarray(d.center_cam, dtype=float) + T[:3, 3]
            xy = (float(p_base[0]), float(p_base[1]))
            objects.append((xy, float(d.radius), float(p_base[2] + 0.5 * d.height)))
        joints = context.joint_positions
        view = DepthView(
            np.asarray(frame.depth),
            frame.intrinsics,
            T,
            None if joints is None else np.asarray(joints, dtype=float),
            tuple(objects),
            frame.timestamp,
        )
        self.store.set(detections=tuple(detections), detections_frame=frame, depth_view=view)
        if (recorder := self.recorder) is not None:
            recorder.detections(frame.timestamp, tuple(detections))
        _reject_non_finite("object detector", "detection", len(found) - len(detections))

    def liquid_once(self) -> bool:
        """Measure every bottle of the newest object detections; False if nothing to do."""
        state = self.store.snapshot(
            self.clock(), self.fusion.snapshot(), {}, self.enabled, self.calibration
        )
        frame = state.detections_frame
        bottles = {t.id for t in state.tracks if t.label == "bottle"}
        self.store.keep_liquid(bottles)
        for track_id in list(self._levels):
            if track_id not in bottles:
                del self._levels[track_id]
        if frame is None or not bottles:
            return False
        measured = False
        for det in state.detections:
            track = state.track_of(det) if det.label == "bottle" else None
            if track is not None:
                measured |= self._measure_liquid(frame, det, track.id)
        return measured

    def _measure_liquid(self, frame: RGBDFrame, det: Any, track_id: int) -> bool:
        """One bottle's level in ``frame``, added to its track's window; False if this frame
        was measured already."""
        history = self._levels.setdefault(track_id, deque(maxlen=self.config.runtime.liquid_window))
        if history and history[-1][0] >= frame.timestamp:
            return False  # this frame was measured already
        geometry = ContainerGeometry.of(det)
        level = self.liquid_meter.measure(frame, det.box, geometry)
        history.append((frame.timestamp, level))
        self.store.set_liquid(track_id, average_levels(track_id, list(history)))
        return True

    def guard(self, name: str, work: Callable[[], object]) -> None:
        """Run one unit of a stage's work, counting output and keeping its error."""
        try:
            if work() is not False:
                self.meters[name].tick()
        except Exception as exc:
            message = f"{type(exc).__name__}: {exc}"
            if self.meters[name].last_error != message:
                log.warning("%s stage: %s", name, message)
            self.meters[name].error(message)
            self.stopping.wait(0.2)  # no busy loop on a persistent fault

    # ---------------------------------------------------------------- lockstep

    def read_frame(self) -> RGBDFrame:
        """Lockstep: the next camera frame (advancing the clock to it), published."""
        frame = self.camera.read()
        self.publish_frame(frame)
        self.meters["camera"].tick()
        return frame

    def pump(self, until: float) -> None:
        """Lockstep: run every stage in time order while the simulation advances to ``until``
        (see :class:`~armvision.runtime.lockstep.Lockstep`)."""
        if self._lockstep is None:
            raise ArmvisionError("pump() is for lockstep mode; threads run by themselves")
        if not self._started:
            self.start()
        self._lockstep.pump(until)

    @property
    def timestep(self) -> float:
        """Lockstep: the simulation's step, the least a wait advances the clock (0 otherwise)."""
        return 0.0 if self._lockstep is None else float(self._lockstep.world.timestep)

    # ---------------------------------------------------------------- tasks

    def submit(self, name: str, fn: Task, **kwargs: Any) -> int:
        """Queue a task for the motion worker; its id. Lockstep: runs it now, to the end."""
        if self._closed:
            raise ArmvisionError("the system is shut down")
        if not self.lockstep and not self._started:
            raise ArmvisionError("start() the system before submitting tasks")
        job = self.jobs.new(name, fn, kwargs)
        if self.lockstep:
            self.jobs.run(job)
        else:
            self.jobs.enqueue(job)
        return job.task_id

    def run_task(
        self, name: str, fn: Task, timeout_s: float | None = None, **kwargs: Any
    ) -> TaskStatus:
        """Run a task to its end and return its final :class:`TaskStatus`."""
        task_id = self.submit(name, fn, **kwargs)
        return self.wait_task(task_id, timeout_s)

    def wait_task(self, task_id: int, timeout_s: float | None = None) -> TaskStatus:
        """Wait for task ``task_id`` to end (realtime); its final status."""
        return self.jobs.wait(task_id, timeout_s)

    def last_status(self, name: str) -> TaskStatus | None:
        """The final status of the newest task named ``name`` that ended, or None."""
        return self.jobs.last.get(name)

    def stop_task(self) -> None:
        """Stop: the arm halts where it is now, the running task ends, queued ones are dropped."""
        self.jobs.stop()
        self.halt_arm()

    def halt_arm(self) -> str | None:
        """Halt the arm where it is; None, or why that failed (logged, and kept as the motion
        stage's error). Never raises: Stop must end the task whatever the arm does."""
        try:
            self.arm.halt()
            return None
        except Exception as exc:
            message = (
                f"halting the arm failed ({type(exc).__name__}: {exc}): check the arm "
                "(power, cable, driver) and use its emergency stop if it still moves"
            )
            log.error("%s", message)
            self.meters["motion"].error(message)
            return message


def _finite(*values: Any) -> bool:
    """Every number in ``values`` (scalars, sequences, arrays) is finite."""
    try:
        return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)
    except (TypeError, ValueError):
        return False


def _reject_non_finite(stage: str, what: str, dropped: int) -> None:
    """A stage's results with NaN or inf are its own fault: dropped before fusion sees them
    and reported as this stage's error (the good ones of the frame went on)."""
    if dropped:
        raise ArmvisionError(
            f"the {stage} gave {dropped} {what}(s) with non-finite values; they were dropped"
            " (a detector bug or a corrupt frame: see the log)"
        )
