"""Recording a running system to MCAP, from a thread of its own.

The stages hand the :class:`Recorder` what they produce (a frame, the encoder reading of a
fusion cycle, detections, a state sample at ``record.state_hz``) through a bounded queue; the
recorder thread turns each into ROS 2 messages (:mod:`armvision.recording.ros`) and armvision's
JSON channels and writes them (:class:`~armvision.recording.writer.McapLog`). A stage never
encodes anything: it puts immutable objects it already has (frames and snapshots are
read-only). With threads (realtime) a full queue drops the item and counts it, so recording
never holds a stage up; in lockstep the simulation waits for room instead (its clock does not
move while it waits, and a complete recording is what makes a replay exact).

When the file cannot be written (disk full, file too large, the drive gone) the recorder says
so once, in one line, and stops; the run goes on.

What is recorded, and on which topic (``armvision.recording.ros.TOPICS``): every frame read
(colour JPEG or PNG, depth 16UC1 mm, CameraInfo); the encoder reading of every fusion cycle
(``/vx300s/joint_states``) and the one each frame's object detector was given; the detections
and tags of every frame a detector ran on; every joint target the arm accepted; the clock's
exact seconds of each frame and cycle; at ``state_hz`` the fused end effector and the tracks
on ``/tf``, the tracks as markers, and the tracks, task, thread health and liquid levels as
JSON; at the start and on change the calibration (``/tf_static`` and JSON), the detectors
switched on, and once the effective configuration. The recorder never reads a device itself:
what it records is what the stages used (a second read of the simulated encoders would draw
new noise and change the run).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from armvision.camera.frames import RGBDFrame
from armvision.config import Config
from armvision.perception.detection import Detection
from armvision.perception.tags import TagDetection
from armvision.recording.writer import McapLog, RecordingError, encode
from armvision.runtime.state import CalibrationStatus, SystemState

if TYPE_CHECKING:
    from armvision.fusion.loop import FusionSnapshot
    from armvision.recording.live import LiveServer

log = logging.getLogger("armvision.recorder")

__all__ = ["Recorder", "RecordingError", "calibration_record", "plain"]

_STOP = object()

#: Topics whose newest message a file started mid-run begins with (and a live viewer that
#: connects late is sent again): what they say holds until the next one.
LATCHED = (
    "/armvision/config",
    "/armvision/camera",
    "/armvision/calibration",
    "/tf_static",
    "/armvision/detectors",
)
#: A live viewer gets the latched topics again every this many state samples.
LIVE_REPEAT = 10


def plain(value: Any) -> Any:
    """JSON-able: numpy to Python, tuples to lists, NaN and infinity to None."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if value is None or isinstance(value, (str, int, bool)):
        return value
    return str(value)


def calibration_record(cal: CalibrationStatus) -> dict[str, Any]:
    """Everything a replay needs to run with ``cal`` again, unrounded."""

    def array(a: Any) -> Any:
        return None if a is None else np.asarray(a, dtype=float).tolist()

    return {
        "source": cal.source,
        "method": cal.method,
        "residual_mm": cal.residual_mm,
        "calibrated": cal.calibrated,
        "T_base_cam": array(cal.T_base_cam),
        "joint_offsets_rad": array(cal.joint_offsets_rad),
        "tag_offset_ee": array(cal.tag_offset_ee),
        "tag_rotation_reference": array(cal.tag_rotation_reference),
    }


def track_record(track: Any, liquid: Any = None) -> dict[str, Any]:
    """A track as the ``/armvision/tracks`` JSON has it (positions unrounded)."""
    return {
        "id": int(track.id),
        "label": track.label,
        "position_m": [float(v) for v in track.p_base],
        "velocity_mps": [float(v) for v in track.v_base],
        "sigma_mm": float(track.sigma_mm),
        "radius_m": track.radius,
        "height_m": track.height,
        "hits": int(track.hits),
        "last_seen": float(track.last_seen),
        "fill": None if liquid is None else liquid.fill,
        "liquid_colour": None if liquid is None or liquid.colour is None else list(liquid.colour),
    }


@dataclasses.dataclass
class _Counts:
    frames: int = 0
    joint_states: int = 0
    states: int = 0
    dropped: int = 0
    encode_s: float = 0.0  # the recorder thread's time on frames (encoding and writing)


class RecordingCamera:
    """A camera whose every frame is also recorded (for runs without a System: the
    calibration procedure; :class:`RecordingArm` records its encoder readings)."""

    def __init__(self, camera: Any, recorder: Recorder) -> None:
        self.camera = camera
        self.recorder = recorder

    @property
    def serial(self) -> str | None:
        return self.camera.serial

    @property
    def intrinsics(self) -> Any:
        return self.camera.intrinsics

    def start(self) -> None:
        self.camera.start()

    def stop(self) -> None:
        self.camera.stop()

    def read(self, timeout_s: float = 1.0) -> RGBDFrame:
        frame: RGBDFrame = self.camera.read(timeout_s)
        self.recorder.frame(frame)
        return frame

    def __enter__(self) -> RecordingCamera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class _Emitter:
    """``write(topic, t, message)`` to the recorder's live view and file."""

    def __init__(self, recorder: Recorder) -> None:
        self.write = recorder._emit


class RecordingArm:
    """An arm whose every encoder reading is also recorded (``/armvision/frame_joint_states``,
    stamped with the newest frame's time); everything else is the arm's own."""

    def __init__(self, arm: Any, recorder: Recorder) -> None:
        self._arm = arm
        self._recorder = recorder

    def get_joint_positions(self) -> Any:
        q = self._arm.get_joint_positions()
        self._recorder.frame_joints(self._recorder.last_t, q)
        return q

    def __getattr__(self, name: str) -> Any:
        return getattr(self._arm, name)


class Recorder:
    """Records one system's run to ``path`` (see the module docstring), and publishes it to
    ``live`` (a Foxglove server) if given; ``path`` None: live only, until :meth:`start_file`.

    ``wait``: block a producer while the queue is full (lockstep) instead of dropping.
    ``notify``: called once with the one-line message when recording stops on an error.
    :meth:`open` the file (RecordingError if it cannot be), hand it to
    :meth:`System.attach_recorder <armvision.runtime.system.System.attach_recorder>`;
    :meth:`stop` finishes it.
    """

    def __init__(
        self,
        path: str | Path | None,
        config: Config,
        *,
        wait: bool = False,
        notify: Callable[[str], None] | None = None,
        live: LiveServer | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.live = live
        self._latched: dict[str, tuple[float, bytes]] = {}
        self._live_error: str | None = None
        self.config = config
        self.settings = config.record
        self.wait = wait
        self.notify = notify or (lambda message: log.error("%s", message))
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=self.settings.queue)
        self._log: McapLog | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.counts = _Counts()
        self.error: str | None = None
        self.started_wall: float | None = None
        self.stopped = threading.Event()
        self._next_state = -math.inf
        self._camera_written = False
        self.joint_names: tuple[str, ...] = ()
        self.last_t = 0.0  # the newest frame's time

    # ---------------------------------------------------------------- life

    def open(self) -> Recorder:
        """Create the file (RecordingError saying what to do if it cannot be) and start the
        thread."""
        if self.path is not None:
            self._log = self._new_log(self.path)
        self.started_wall = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="armvision-recorder", daemon=True)
        self._thread.start()
        return self

    def _new_log(self, path: Path) -> McapLog:
        return McapLog(path, self.settings.compression, self.settings.chunk_kib * 1024)

    @property
    def active(self) -> bool:
        """Writing a file now."""
        log_ = self._log
        return (
            log_ is not None
            and not log_.closed
            and not self.stopped.is_set()
            and self.error is None
        )

    def start_file(self, path: str | Path) -> None:
        """Start writing a file (a live-only recorder, or one whose file ended): it begins with
        the configuration, camera, calibration and detectors as they are now. RecordingError
        if the file cannot be made, or one is being written."""
        if self.active:
            raise RecordingError(f"already recording to {self.path}")
        new = self._new_log(Path(path))
        opened = threading.Event()
        try:
            self._queue.put(("open_file", new, opened), timeout=5.0)
        except queue.Full:
            new.abandon()
            raise RecordingError("the recorder is behind: try again in a moment") from None
        opened.wait(10.0)

    def stop_file(self, timeout_s: float = 30.0) -> None:
        """Finish the file being written (the live view goes on)."""
        closed = threading.Event()
        try:
            self._queue.put(("close_file", closed), timeout=5.0)
        except queue.Full:
            raise RecordingError("the recorder is behind: try again in a moment") from None
        closed.wait(timeout_s)

    def stop(self, timeout_s: float = 30.0) -> None:
        """Write what is queued, finish the file and end the thread."""
        if self._thread is None or self.stopped.is_set():
            self.stopped.set()
            return
        self.stopped.set()  # producers put nothing more
        self._queue.put(_STOP)
        self._thread.join(timeout_s)

    def status(self) -> dict[str, Any]:
        """For the UI and the health channel: where, how much, dropped, the error."""
        c = self.counts
        log_ = self._log
        return {
            "path": None if self.path is None else str(self.path),
            "live": None if self.live is None else self.live.url(),
            "active": self.active,
            "frames": c.frames,
            "joint_states": c.joint_states,
            "dropped": c.dropped,
            "bytes": 0 if log_ is None else log_.bytes_written,
            "seconds": 0.0 if self.started_wall is None else time.monotonic() - self.started_wall,
            "error": self.error,
        }

    # ---------------------------------------------------------------- producers (the stages)

    def _put(self, item: tuple[Any, ...]) -> None:
        if self.stopped.is_set() or (self.error is not None and self.live is None):
            return
        if not self.wait:
            try:
                self._queue.put_nowait(item)
            except queue.Full:
                with self._lock:
                    self.counts.dropped += 1
            return
        while (self.error is None or self.live is not None) and not self.stopped.is_set():
            try:
                self._queue.put(item, timeout=0.5)
                return
            except queue.Full:
                continue

    def start_of_run(self, t: float, system: Any) -> None:
        """The configuration, the calibration and the detectors switched on, at the start."""
        model = getattr(system.arm, "model", None)
        self.joint_names = tuple(model.joint_names) if model is not None else ()
        self._put(("json", "/armvision/config", t, plain(dataclasses.asdict(self.config))))
        self.calibration(t, system.calibration)
        self.detectors(t, system.enabled)

    def begin(self, t: float, joint_names: tuple[str, ...] = ()) -> None:
        """The start of a run without a System (calibrate, perceive): the configuration."""
        self.joint_names = tuple(joint_names)
        self._put(("json", "/armvision/config", t, plain(dataclasses.asdict(self.config))))

    def frame(self, frame: RGBDFrame) -> None:
        self.last_t = max(self.last_t, float(frame.timestamp))
        self._put(("frame", frame))

    def frame_joints(self, t: float, q_raw: Any) -> None:
        """The encoder reading (raw) the object detector was given with the frame of ``t``."""
        self._put(("frame_joints", t, np.array(q_raw, dtype=float)))

    def fusion(self, system: Any, snapshot: FusionSnapshot) -> None:
        """A fusion cycle: its encoder reading (raw, before the calibration's joint offsets),
        and a state sample when one is due."""
        t = float(snapshot.time)
        if snapshot.joint_positions is not None:
            self.joints(t, system.encoders.raw(snapshot.joint_positions))
        if t >= self._next_state:
            self._next_state = max(self._next_state + 1.0 / self.settings.state_hz, t)
            self.state_sample(system.snapshot(), system.fusion_stalls)

    def command(self, t: float, q: Any) -> None:
        """A joint target the arm accepted at ``t`` (a move's goal, a streamed target)."""
        self._put(("command", t, np.array(q, dtype=float)))

    def joints(self, t: float, q_raw: Any) -> None:
        """A fusion cycle's encoder reading (raw) at ``t``."""
        self._put(("joints", t, np.array(q_raw, dtype=float)))

    def state_sample(self, state: SystemState, fusion_stalls: int = 0) -> None:
        """A state sample: transforms, markers, tracks, task, health and liquid levels."""
        self._put(("state", state, fusion_stalls))

    def detections(self, t: float, detections: tuple[Detection, ...]) -> None:
        self._put(("json", "/armvision/detections", t, [d.to_dict() for d in detections]))

    def tags(self, t: float, tags: tuple[TagDetection, ...]) -> None:
        records = [
            {"id": int(tag.id), "center": [float(v) for v in tag.center],
             "T_cam_tag": np.asarray(tag.T_cam_tag, dtype=float).tolist(),
             "decision_margin": float(tag.decision_margin)}
            for tag in tags
        ]  # fmt: skip
        self._put(("json", "/armvision/tags", t, records))

    def json(self, topic: str, t: float, value: Any) -> None:
        """A JSON message on one of armvision's topics."""
        self._put(("json", topic, t, plain(value)))

    def calibration(self, t: float, cal: CalibrationStatus) -> None:
        self._put(("calibration", t, cal))

    def detectors(self, t: float, enabled: dict[str, bool]) -> None:
        self._put(("json", "/armvision/detectors", t, dict(enabled)))

    # ---------------------------------------------------------------- the thread

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                break
            if item[0] in ("open_file", "close_file"):
                self._file_command(item)
                continue
            if self.error is not None and self.live is None:
                continue  # stopped on an error: what is left is let go
            try:
                self._write(item)
            except RecordingError as exc:
                self._fail(str(exc))
            except Exception as exc:  # a bug must not end the recording thread silently
                log.exception("recording a %s failed", item[0])
                self._fail(f"recording stopped: {type(exc).__name__}: {exc} (see the log)")
        if self._log is not None and self.error is None:
            try:
                self._log.close()
            except RecordingError as exc:
                self._fail(str(exc))
        if self.live is not None:
            self.live.close()

    def _file_command(self, item: tuple[Any, ...]) -> None:
        """Start or finish a file from the recorder thread (the one that writes)."""
        if item[0] == "close_file":
            if self._log is not None and not self._log.closed and self.error is None:
                try:
                    self._log.close()
                except RecordingError as exc:
                    self._fail(str(exc))
            item[1].set()
            return
        new, opened = item[1], item[2]
        self._log, self.path, self.error = new, new.path, None
        self.counts = _Counts()
        self.started_wall = time.monotonic()
        try:
            for topic, (t, data) in self._latched.items():
                new.write_encoded(topic, t, data)
        except RecordingError as exc:
            self._fail(str(exc))
        opened.set()

    def _emit(self, topic: str, t: float, message: Any) -> None:
        """Encode one message and hand it to the live view and the file."""
        data = encode(topic, message)
        if topic in LATCHED:
            self._latched[topic] = (t, data)
        if self.live is not None:
            self._publish(topic, t, data)
        log_ = self._log
        if log_ is not None and not log_.closed and self.error is None:
            log_.write_encoded(topic, t, data)

    def _publish(self, topic: str, t: float, data: bytes) -> None:
        assert self.live is not None
        try:
            self.live.publish(topic, t, data)
        except Exception as exc:  # the live view is a convenience: the recording goes on
            message = f"the Foxglove live view failed: {type(exc).__name__}: {exc}"
            if message != self._live_error:
                log.warning("%s", message)
            self._live_error = message

    def _fail(self, message: str) -> None:
        self.error = message
        if self._log is not None:
            self._log.abandon()
        self.notify(message)

    def _write(self, item: tuple[Any, ...]) -> None:
        from armvision.recording import ros

        out = _Emitter(self)
        kind = item[0]
        if kind == "frame":
            started = time.perf_counter()
            frame = item[1]
            t = float(frame.timestamp)
            if not self._camera_written:
                self._camera_written = True
                out.write("/armvision/camera", t, {"intrinsics": frame.intrinsics.to_dict()})
            out.write(ros.FRAME_CLOCK_TOPIC, t, {"t": t})
            out.write(ros.INFO_TOPIC, t, ros.camera_info(frame.intrinsics, t))
            out.write(
                ros.COLOR_TOPIC,
                t,
                ros.compressed_color(
                    frame.color, t, self.settings.jpeg_quality, self.settings.color_format
                ),
            )
            out.write(ros.DEPTH_TOPIC, t, ros.depth_image(frame.depth, t))
            self.counts.frames += 1
            self.counts.encode_s += time.perf_counter() - started
        elif kind == "frame_joints":
            t = item[1]
            out.write(ros.FRAME_JOINTS_TOPIC, t, ros.joint_state(t, self.joint_names, item[2]))
        elif kind == "command":
            t = item[1]
            out.write(ros.COMMANDS_TOPIC, t, ros.joint_state(t, self.joint_names, item[2]))
        elif kind == "joints":
            out.write(ros.CLOCK_TOPIC, item[1], {"t": float(item[1])})
            out.write(
                ros.JOINTS_TOPIC, item[1], ros.joint_state(item[1], self.joint_names, item[2])
            )
            self.counts.joint_states += 1
        elif kind == "state":
            self._write_state(out, item[1], item[2])
            self.counts.states += 1
            if self.live is not None and self.counts.states % LIVE_REPEAT == 0:
                for topic, (t, data) in self._latched.items():  # for viewers that came late
                    self._publish(topic, t, data)
        elif kind == "calibration":
            t, cal = item[1], item[2]
            out.write("/armvision/calibration", t, plain(calibration_record(cal)))
            transform = ros.transform(t, ros.BASE_FRAME, ros.CAMERA_FRAME, cal.T_base_cam)
            out.write("/tf_static", t, ros.tf_message([transform]))
        elif kind == "json":
            out.write(item[1], item[2], item[3])

    def _write_state(self, out: _Emitter, state: SystemState, stalls: int) -> None:
        from armvision.recording import ros

        t = float(state.time)
        tracks = [track_record(tr, state.liquid.get(tr.id)) for tr in state.tracks]
        transforms = []
        if state.fusion.T_base_ee is not None:
            transforms.append(
                ros.transform(t, ros.BASE_FRAME, ros.EE_FRAME, state.fusion.T_base_ee)
            )
        for tr in tracks:
            T = np.eye(4)
            T[:3, 3] = tr["position_m"]
            transforms.append(
                ros.transform(t, ros.BASE_FRAME, ros.TRACK_FRAME.format(id=tr["id"]), T)
            )
        if transforms:
            out.write("/tf", t, ros.tf_message(transforms))
        out.write("/armvision/markers", t, ros.track_markers(t, tracks))
        out.write(
            "/armvision/planning_scene", t, ros.scene_markers(t, state.planning_scene.to_dict())
        )
        out.write(
            "/armvision/tracks",
            t,
            plain({"t": t, "tracks": tracks, "T_base_cam": np.asarray(state.T_base_cam)}),
        )
        out.write("/armvision/task", t, plain(state.task.to_dict()))
        health = {name: h.to_dict() for name, h in state.health.items()}
        out.write(
            "/armvision/health",
            t,
            plain({"threads": health, "fusion_stalls": stalls, "recorder": self.status()}),
        )
        if state.liquid:
            out.write(
                "/armvision/liquid",
                t,
                plain({str(k): v.to_dict() for k, v in state.liquid.items()}),
            )
