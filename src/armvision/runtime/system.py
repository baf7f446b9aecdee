"""The running system: the paper's threads around one arm and one camera.

:class:`System` owns the stages of ARCHITECTURE.md (Runtime):

- **camera**: reads every frame and publishes the newest;
- **tags**: AprilTag poses of the newest frame, the gripper tag's pushed into fusion;
- **objects**: bottles and cups of the newest frame, pushed into fusion (which tracks them);
- **liquid**: the liquid level of every tracked bottle, averaged per track;
- **fusion**: the :class:`~armvision.fusion.loop.FusionLoop` cycle at ``fusion.rate_hz``;
- **motion**: one worker that runs tasks (grab, follow, analyze, home, ...) one at a time
  from a ``queue.Queue``.

The three detection stages can be switched on and off while running (:meth:`set_detector`).
Every stage reports its health (rate, age of its last output, last error) in the state; a
failing stage logs the error, shows it and carries on with the next frame, it never dies
silently. :meth:`System.snapshot` hands out an immutable
:class:`~armvision.runtime.state.SystemState`.

Two ways to run, same stages:

- ``lockstep=False`` (real hardware, or a realtime simulation): each stage is a thread.
- ``lockstep=True`` (a lockstep simulation): no threads; :meth:`pump` runs the stages in time
  order while it advances the simulation, and tasks run on the caller's thread, their waits
  pumping. Repeatable for a seed, and as fast as the machine allows: this is how ``armvision
  demo`` and the evaluations run.

Tasks are functions ``task(ctx, **kwargs)`` taking a :class:`TaskContext`; everything a task
waits for goes through the context, so :meth:`stop_task` (the Stop button) halts the arm at
once and the task ends at its next wait with :class:`TaskStopped`.
"""

from __future__ import annotations

import itertools
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.fusion.drift import DriftMonitor
from armvision.fusion.kalman import DEFAULT_FOCAL_PX
from armvision.fusion.loop import FusionLoop
from armvision.perception.liquid import ContainerGeometry, LiquidLevel, LiquidLevelMeter
from armvision.perception.objects import GeometricDetector
from armvision.perception.tags import TagDetector
from armvision.robot.base import Arm
from armvision.robot.tag_mount import tag_mount
from armvision.runtime.state import (
    CalibrationStatus,
    HealthMeter,
    StateStore,
    SystemState,
    TaskStatus,
    average_levels,
)

Array = NDArray[np.float64]
log = logging.getLogger("armvision.runtime")

DETECTORS = ("tags", "objects", "liquid")
STAGES = ("camera", *DETECTORS, "fusion", "motion")
#: Interbotix's gripper delay: the fingers get where they go (or onto an object) in this time.
GRIPPER_TIME_S = 1.0
#: Longest a task's wait goes without looking at the stop flag (realtime), seconds.
POLL_S = 0.01
#: The fusion thread makes up for at most this much lost time by running cycles back to back.
FUSION_CATCH_UP_S = 0.1


class TaskStopped(ArmvisionError):  # noqa: N818 - control flow, like StopIteration
    """The task was stopped (Stop pressed, or the system shutting down)."""


class TaskError(ArmvisionError):
    """A task could not do what it was asked; the message says why and what to do."""


#: ``task(ctx, **kwargs)``; it may return anything with ``to_dict()`` (its report), and marks
#: a failure with ``ok = False`` and a ``reason``, or by raising an ArmvisionError.
Task = Callable[..., Any]


class _CorrectedEncoders:
    """The arm's encoder readings minus the calibration's estimated joint zero offsets."""

    def __init__(self, arm: Arm, offsets: Array | None) -> None:
        self.arm = arm
        self.offsets = None if offsets is None else np.asarray(offsets, dtype=float)

    def get_joint_positions(self) -> Array:
        q = np.asarray(self.arm.get_joint_positions(), dtype=float)
        return q if self.offsets is None else q - self.offsets


class FrameView:
    """A camera-like view of the running camera stage: :meth:`read` gives the next new frame.

    For code written against the Camera interface (the calibration sampler) while the camera
    thread owns the camera. ``wait`` advances the clock in lockstep mode.
    """

    def __init__(self, system: System) -> None:
        self._system = system
        self._seq = 0
        self.serial = getattr(system.camera, "serial", None)

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
            frame = system.read_frame()
            return frame
        seq, frame = system.store.wait_frame(self._seq, timeout_s)
        if frame is None or seq == self._seq:
            raise ArmvisionError(
                f"no new camera frame within {timeout_s:.1f} s: is the camera running? "
                "(see the camera thread's health)"
            )
        self._seq = seq
        return frame


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
            step = float(getattr(self.system.world, "timestep", 0.0))
            self.system.pump(self.now() + max(seconds, step))
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
        while getattr(arm, "moving", False):
            remaining = getattr(arm, "motion_remaining", lambda: POLL_S)()
            self.sleep(min(max(remaining, 1e-3), 0.05 if self.system.lockstep else POLL_S))
        settle = getattr(arm, "settle_time", 0.0)
        if settle:
            self.sleep(settle)

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
        try:
            action(delay=0.0)  # type: ignore[call-arg]
        except TypeError:  # a gripper without a delay argument waits itself
            action()
            return
        self.sleep(GRIPPER_TIME_S)

    def open_gripper(self) -> None:
        self._gripper(close=False)

    def close_gripper(self) -> None:
        self._gripper(close=True)


class _Job:
    def __init__(self, task_id: int, name: str, fn: Task, kwargs: dict[str, Any]) -> None:
        self.task_id, self.name, self.fn, self.kwargs = task_id, name, fn, kwargs
        self.stop = threading.Event()
        self.done = threading.Event()
        self.status: TaskStatus | None = None


class System:
    """The threads (or lockstep stages) around one arm and one camera; see the module doc.

    ``calibration``: the camera pose and joint offsets to run with. ``clock``: seconds on the
    camera's time base (simulation time for a simulation). ``world``: the SimWorld, needed for
    ``lockstep``. Detectors default to the configured tag detector, the geometric object
    detector and the liquid meter. Use as a context manager: :meth:`start`, :meth:`close`.
    """

    def __init__(
        self,
        config: Config,
        arm: Arm,
        camera: Any,
        calibration: CalibrationStatus,
        *,
        clock: Callable[[], float] = time.monotonic,
        lockstep: bool = False,
        world: Any = None,
        tag_detector: Any = None,
        object_detector: Any = None,
        liquid_meter: Any = None,
        owns: tuple[Any, ...] = (),
    ) -> None:
        if lockstep and world is None:
            raise ArmvisionError("lockstep mode needs the SimWorld whose clock it advances")
        self.config = config
        self.arm = arm
        self.camera = camera
        self.calibration = calibration
        self.clock = clock
        self.lockstep = lockstep
        self.world = world
        self._owns = owns
        rt = config.runtime
        self.T_base_cam = np.asarray(calibration.T_base_cam, dtype=float)
        self.T_ee_tag = tag_mount(config.tag.offset_ee)
        self.tag_detector = tag_detector or TagDetector.from_config(config.tag)
        self.object_detector = object_detector or GeometricDetector(self.T_base_cam)
        self.liquid_meter = liquid_meter or LiquidLevelMeter()
        self.encoders = _CorrectedEncoders(arm, calibration.joint_offsets_rad)
        self.fusion = self._fusion_loop()
        self.store = StateStore()
        self.enabled = {
            "tags": rt.tag_detection,
            "objects": rt.object_detection,
            "liquid": rt.liquid_detection,
        }
        self.meters = {name: HealthMeter(name, clock) for name in STAGES}
        self._rates = {"tags": rt.tag_hz, "objects": rt.object_hz, "liquid": rt.liquid_hz}
        self._levels: dict[int, deque[tuple[float, LiquidLevel]]] = {}
        self._threads: dict[str, threading.Thread] = {}
        self.fusion_stalls = 0  # times the fusion thread fell more than FUSION_CATCH_UP_S behind
        self.stuck: tuple[str, ...] = ()  # threads that did not end at close()
        self._stop = threading.Event()
        self._started = False
        self._closed = False
        self._jobs: queue.Queue[_Job | None] = queue.Queue()
        self._current: _Job | None = None
        self._pending: list[_Job] = []
        self._submitted: dict[int, _Job] = {}
        self._job_lock = threading.Lock()
        self._ids = itertools.count(1)
        # lockstep schedule
        self._next_fusion = 0.0
        self._due = dict.fromkeys(DETECTORS, 0.0)

    # ---------------------------------------------------------------- life cycle

    def start(self) -> System:
        """Start the stages (threads, or the lockstep schedule)."""
        if self._started:
            return self
        if self._closed:
            raise ArmvisionError("this System was closed; build a new one")
        self._started = True
        if self.lockstep:
            self.camera.start()
            now = self.clock()
            self._next_fusion = now
            self._due = dict.fromkeys(DETECTORS, now)
            self.fusion.step()
            self.meters["fusion"].tick()
            return self
        ready = threading.Event()
        spawn = [
            ("camera", lambda: self._camera_thread(ready)),
            ("tags", lambda: self._detector_thread("tags", self._tags_once)),
            ("objects", lambda: self._detector_thread("objects", self._objects_once)),
            ("liquid", self._liquid_thread),
            ("fusion", self._fusion_thread),
            ("motion", self._motion_thread),
        ]
        for name, target in spawn:
            thread = threading.Thread(target=target, name=f"armvision-{name}", daemon=True)
            self._threads[name] = thread
            thread.start()
        if not ready.wait(self.config.runtime.join_timeout_s + 5.0):
            log.warning("the camera did not deliver a first frame in time; carrying on")
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
        self._stop.set()
        self._jobs.put(None)
        timeout = self.config.runtime.join_timeout_s
        for thread in self._threads.values():
            thread.join(timeout=timeout)
        self.stuck = tuple(name for name, t in self._threads.items() if t.is_alive())
        if self.lockstep:
            self.camera.stop()
        if not self.stuck:
            self._release()
            return
        log.error(
            "the %s thread(s) did not stop within %.1f s (a hung camera or arm call?); what "
            "they use is released once they end",
            ", ".join(self.stuck),
            timeout,
        )
        stuck = [self._threads[name] for name in self.stuck]

        def release_later() -> None:
            for thread in stuck:
                thread.join()
            self._release()

        threading.Thread(target=release_later, name="armvision-closer", daemon=True).start()

    def _release(self) -> None:
        for thing in self._owns:
            for method in ("close", "stop", "shutdown"):
                if callable(getattr(thing, method, None)):
                    try:
                        getattr(thing, method)()
                    except Exception:  # closing must go on for the rest
                        log.exception("closing %s failed", type(thing).__name__)
                    break

    def __enter__(self) -> System:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

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
                thread = self._threads.get(name)
                alive = thread is not None and thread.is_alive()
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
        drift = DriftMonitor(
            self.config.calibration,
            self.T_base_cam,
            self.T_ee_tag if cal.tag_offset_ee is None else tag_mount(cal.tag_offset_ee),
            cal.tag_rotation_reference,
            active=cal.calibrated,  # the nominal placement of an uncalibrated camera is no claim
        )
        return FusionLoop(
            self.config,
            self.encoders,
            self.T_base_cam,
            self.T_ee_tag,
            clock=self.clock,
            focal_px=focal_px,
            drift=drift,
        )

    def set_calibration(self, calibration: CalibrationStatus) -> None:
        """Run with a new calibration from now on (a recalibration while running).

        The fusion loop starts afresh with the new camera pose (tracks measured with the old
        one would sit where the old pose put them; they are found again within a few frames),
        the geometric detector's table model and the encoder offsets follow.
        """
        T_base_cam = np.asarray(calibration.T_base_cam, dtype=float)
        if T_base_cam.shape != (4, 4) or not np.all(np.isfinite(T_base_cam)):
            raise ArmvisionError("a calibration needs a finite 4x4 T_base_cam")
        self.calibration = calibration
        self.T_base_cam = T_base_cam
        self.encoders.offsets = (
            None
            if calibration.joint_offsets_rad is None
            else np.asarray(calibration.joint_offsets_rad, dtype=float)
        )
        if isinstance(self.object_detector, GeometricDetector):
            self.object_detector.T_base_cam = T_base_cam
        self.fusion = self._fusion_loop()  # the fusion stage picks it up at its next cycle
        self._levels.clear()
        self.store.keep_liquid(set())

    def set_detector(self, name: str, enabled: bool) -> None:
        """Switch the tag, object or liquid stage on or off."""
        if name not in DETECTORS:
            raise ArmvisionError(f"no detector {name!r}; the detectors are {', '.join(DETECTORS)}")
        self.enabled[name] = bool(enabled)
        if name == "tags" and not enabled:
            self.store.set(tags=())
        if name == "objects" and not enabled:
            self.store.set(detections=())

    # ---------------------------------------------------------------- the stages' work

    def _tags_once(self, frame: RGBDFrame) -> None:
        found = self.tag_detector.detect(frame)
        tags = [t for t in found if _finite(t.T_cam_tag, t.center)]
        for tag in tags:
            if tag.id == self.config.tag.id:
                self.fusion.push_tag(frame.timestamp, tag.T_cam_tag)
        self.store.set(tags=tuple(tags), tags_time=frame.timestamp)
        _reject_non_finite("tag detector", "tag", len(found) - len(tags))

    def _objects_once(self, frame: RGBDFrame) -> None:
        detector = self.object_detector
        if isinstance(detector, GeometricDetector):
            found = detector.detect(frame, self.encoders.get_joint_positions())
        else:
            found = detector.detect(frame)
        detections = [d for d in found if _finite(d.center_cam, d.box, d.radius, d.height, d.score)]
        self.fusion.push_detections(frame.timestamp, detections)
        self.store.set(detections=tuple(detections), detections_frame=frame)
        _reject_non_finite("object detector", "detection", len(found) - len(detections))

    def _liquid_once(self) -> bool:
        """Measure every bottle of the newest object detections; False if nothing to do."""
        state = self.store.snapshot(
            self.clock(), self.fusion.snapshot(), {}, self.enabled, self.calibration
        )
        frame = state.detections_frame
        bottles = [t for t in state.tracks if t.label == "bottle"]
        self.store.keep_liquid({t.id for t in bottles})
        for track_id in list(self._levels):
            if track_id not in {t.id for t in bottles}:
                del self._levels[track_id]
        if frame is None or not bottles:
            return False
        measured = False
        for det in state.detections:
            track = state.track_of(det) if det.label == "bottle" else None
            if track is None:
                continue
            geometry = ContainerGeometry(tuple(det.center_cam), det.radius, det.height)
            level = self.liquid_meter.measure(frame, det.box, geometry)
            track_id = track.id
            history = self._levels.setdefault(
                track_id, deque(maxlen=self.config.runtime.liquid_window)
            )
            if history and history[-1][0] >= frame.timestamp:
                continue  # this frame was measured already
            history.append((frame.timestamp, level))
            self.store.set_liquid(track_id, average_levels(track_id, list(history)))
            measured = True
        return measured

    # ---------------------------------------------------------------- threads

    def _guard(self, name: str, work: Callable[[], bool | None]) -> None:
        """Run one unit of a stage's work, counting output and keeping its error."""
        try:
            if work() is not False:
                self.meters[name].tick()
        except Exception as exc:
            message = f"{type(exc).__name__}: {exc}"
            if self.meters[name].last_error != message:
                log.warning("%s stage: %s", name, message)
            self.meters[name].error(message)
            self._stop.wait(0.2)  # no busy loop on a persistent fault

    def _camera_thread(self, ready: threading.Event) -> None:
        try:  # the renderer's GL context belongs to the thread that made it
            self.camera.start()
        except Exception as exc:
            self.meters["camera"].error(f"{type(exc).__name__}: {exc}")
            log.error("camera could not start: %s", exc)
            ready.set()
            return

        def once() -> None:
            self.store.set_frame(self.camera.read(timeout_s=2.0))
            ready.set()

        try:
            while not self._stop.is_set():
                self._guard("camera", once)
        finally:
            try:
                self.camera.stop()
            except Exception:
                log.exception("stopping the camera failed")

    def _detector_thread(self, name: str, work: Callable[[RGBDFrame], None]) -> None:
        seq = 0
        next_time = time.monotonic()
        while not self._stop.is_set():
            if not self.enabled[name]:
                self._stop.wait(0.05)
                continue
            new_seq, frame = self.store.wait_frame(seq, 0.5)
            if frame is None or new_seq == seq:
                continue
            seq = new_seq
            self._guard(name, lambda f=frame: work(f))
            next_time = max(next_time + 1.0 / self._rates[name], time.monotonic() - 1.0)
            delay = next_time - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)

    def _liquid_thread(self) -> None:
        period = 1.0 / self._rates["liquid"]
        while not self._stop.is_set():
            if self.enabled["liquid"]:
                self._guard("liquid", self._liquid_once)
            self._stop.wait(period)

    def _fusion_thread(self) -> None:
        """Cycles on a fixed grid of 1/rate_hz. A cycle that starts late (another thread held
        the interpreter) is followed by the missed ones at once, up to FUSION_CATCH_UP_S of
        them, so the rate holds on average; a longer stall is skipped and counted."""
        period = 1.0 / self.config.fusion.rate_hz
        next_time = time.monotonic()
        while not self._stop.is_set():
            self._guard("fusion", self.fusion.step)
            next_time += period
            delay = next_time - time.monotonic()
            if delay < -FUSION_CATCH_UP_S:
                self.fusion_stalls += 1
                next_time = time.monotonic()
            elif delay > 0:
                self._stop.wait(delay)

    def _motion_thread(self) -> None:
        while not self._stop.is_set():
            job = self._jobs.get()
            if job is None:
                break
            try:
                self._run_job(job)
            except Exception as exc:  # the worker outlives any task: the next one must run
                log.exception("the motion worker failed on task %s", job.name)
                with self._job_lock:
                    self._current = None
                message = f"internal error ({type(exc).__name__}: {exc})"
                self.meters["motion"].error(message)
                if not job.done.is_set():
                    self._finish(
                        job,
                        TaskStatus(
                            name=job.name,
                            phase="failed",
                            error=message,
                            task_id=job.task_id,
                            finished=self.clock(),
                        ),
                    )

    # ---------------------------------------------------------------- lockstep

    def read_frame(self) -> RGBDFrame:
        """Lockstep: the next camera frame (advancing the clock to it), published."""
        frame = self.camera.read()
        self.store.set_frame(frame)
        self.meters["camera"].tick()
        return frame

    def pump(self, until: float) -> None:
        """Lockstep: run every stage in time order while the simulation advances to ``until``.

        Fusion cycles fall every 1/``fusion.rate_hz``; a frame is read (rendered) only when an
        enabled detector is due, at most at its configured rate.
        """
        if not self.lockstep:
            raise ArmvisionError("pump() is for lockstep mode; threads run by themselves")
        if not self._started:
            self.start()
        fusion_period = 1.0 / self.config.fusion.rate_hz
        half_frame = 0.5 / float(self.config.camera.fps)
        if self._next_fusion < self.clock() - fusion_period:
            # The clock moved outside pump() (a blocking arm call): the cycles that time held
            # are gone, as on a stalled thread; replaying them all at one instant would only
            # stack identical encoder readings into the filter.
            self.fusion_stalls += 1
            self._next_fusion = self.clock()
        while True:
            due = [self._due[n] for n in DETECTORS if self.enabled[n]]
            frame_due = min(due) if due else math.inf
            t = min(self._next_fusion, frame_due)
            if t > until:
                break
            if frame_due < self._next_fusion:
                self.world.run_until(max(frame_due, self.clock()))
                frame = self.read_frame()
                now = frame.timestamp
                for name, work in (("tags", self._tags_once), ("objects", self._objects_once)):
                    if self.enabled[name] and self._due[name] <= now + half_frame:
                        self._guard(name, lambda w=work, f=frame: w(f))
                        self._due[name] = now + 1.0 / self._rates[name] - half_frame
                if self.enabled["liquid"] and self._due["liquid"] <= now + half_frame:
                    self._guard("liquid", self._liquid_once)
                    self._due["liquid"] = now + 1.0 / self._rates["liquid"] - half_frame
                for name in DETECTORS:  # a disabled detector is due when switched back on
                    if not self.enabled[name]:
                        self._due[name] = now
            else:
                self.world.run_until(self._next_fusion)
                self._guard("fusion", self.fusion.step)
                self._next_fusion += fusion_period
        if until > self.clock():
            self.world.run_until(until)

    # ---------------------------------------------------------------- tasks

    def submit(self, name: str, fn: Task, **kwargs: Any) -> int:
        """Queue a task for the motion worker; its id. Lockstep: runs it now, to the end."""
        if self._closed:
            raise ArmvisionError("the system is shut down")
        job = _Job(next(self._ids), name, fn, kwargs)
        if self.lockstep:
            self._submitted[job.task_id] = job
            self._run_job(job)
            return job.task_id
        if not self._started:
            raise ArmvisionError("start() the system before submitting tasks")
        with self._job_lock:
            self._pending.append(job)
            self._submitted[job.task_id] = job
        if self._current is None:
            self.store.set_task(TaskStatus(name=name, phase="queued", task_id=job.task_id))
        self._jobs.put(job)
        return job.task_id

    def run_task(self, name: str, fn: Task, timeout_s: float | None = None, **kwargs: Any):
        """Run a task to its end and return its final :class:`TaskStatus`."""
        task_id = self.submit(name, fn, **kwargs)
        return self.wait_task(task_id, timeout_s)

    def wait_task(self, task_id: int, timeout_s: float | None = None) -> TaskStatus:
        """Wait for task ``task_id`` to end (realtime); its final status."""
        job = self._submitted.get(task_id)
        if job is None:
            raise ArmvisionError(f"no task {task_id}")
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        # Short waits, so Ctrl-C reaches the caller at once.
        while not job.done.wait(0.2):
            if deadline is not None and time.monotonic() > deadline:
                raise ArmvisionError(
                    f"task {task_id} ({job.name}) did not end within {timeout_s} s"
                )
        assert job.status is not None
        return job.status

    def stop_task(self) -> None:
        """Stop: the arm halts where it is now, the running task ends, queued ones are dropped."""
        with self._job_lock:
            current = self._current
            pending, self._pending = self._pending, []
        for job in pending:
            job.stop.set()
        if current is not None:
            current.stop.set()
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

    def _run_job(self, job: _Job) -> None:
        with self._job_lock:
            if job in self._pending:
                self._pending.remove(job)
            if job.stop.is_set():  # stopped while queued
                status = TaskStatus(
                    name=job.name,
                    phase="stopped",
                    error="stopped before it started",
                    task_id=job.task_id,
                    finished=self.clock(),
                )
                self._finish(job, status)
                return
            self._current = job
        started = self.clock()
        self.store.set_task(
            TaskStatus(name=job.name, phase="running", started=started, task_id=job.task_id)
        )
        ctx = TaskContext(self, job.task_id, job.stop)
        phase, error, result = "succeeded", None, None
        halt_error = None
        try:
            value = job.fn(ctx, **job.kwargs)
            result = value.to_dict() if hasattr(value, "to_dict") else value
            if getattr(value, "ok", True) is False:
                phase = "failed"
                error = getattr(value, "reason", "") or "the task did not succeed"
        except TaskStopped:
            phase, error = "stopped", "stopped by the operator"
            halt_error = self.halt_arm()
            if halt_error is not None:
                error += f"; {halt_error}"
        except ArmvisionError as exc:
            phase, error = "failed", str(exc)
            log.warning("task %s failed: %s", job.name, exc)
        except Exception as exc:  # a bug: say so readably, keep the traceback in the log
            phase, error = "failed", f"internal error ({type(exc).__name__}: {exc})"
            log.exception("task %s crashed", job.name)
        finally:
            with self._job_lock:
                self._current = None
        current = self.store.task()
        status = TaskStatus(
            name=job.name,
            phase=phase,  # type: ignore[arg-type]
            progress=1.0 if phase == "succeeded" else current.progress,
            message=current.message if current.task_id == job.task_id else "",
            started=started,
            finished=self.clock(),
            result=result if isinstance(result, Mapping) else None,
            error=error,
            task_id=job.task_id,
        )
        self._finish(job, status)
        self.meters["motion"].tick()
        if halt_error is not None:  # kept in the motion stage's health until the next task
            self.meters["motion"].error(halt_error)

    def _finish(self, job: _Job, status: TaskStatus) -> None:
        self.store.set_task(status)
        job.status = status
        job.done.set()


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
