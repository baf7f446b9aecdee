"""Replaying a recording through perception, fusion and tracking, and what changed.

:func:`replay` builds a :class:`~armvision.runtime.system.System` on a
:class:`~armvision.recording.sources.RecordedCamera` and a
:class:`~armvision.recording.sources.RecordedArm` and drives it through the recording's events
in the order they were written: every recorded fusion cycle is a fusion step at its time with
its encoder reading, every recorded frame is read and given to the tag, object and liquid
stages that are due (the lockstep schedule's rule, at the configured rates), a recorded
calibration or detector switch is applied where it happened. Nothing is random and no clock
but the recording's is read, so a replay is deterministic; with the recording's own
configuration a lockstep-recorded run comes out as it was recorded (up to what JPEG and
millimetre depth change in the frames). After each fusion step that has a recorded state
sample at its time, the tracks are compared with the recorded ones: :class:`ReplayReport`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from armvision.config import Config, config_from_dict
from armvision.errors import ArmvisionError
from armvision.recording import ros
from armvision.recording.reader import Recording
from armvision.recording.sources import RecordedArm, RecordedCamera
from armvision.runtime.lockstep import DETECTORS
from armvision.runtime.recorder import Recorder
from armvision.runtime.state import CalibrationStatus

_EVENT_TOPICS = (
    ros.CLOCK_TOPIC,
    ros.FRAME_CLOCK_TOPIC,
    ros.JOINTS_TOPIC,
    ros.DEPTH_TOPIC,
    "/armvision/calibration",
    "/armvision/detectors",
    "/armvision/tracks",
    "/armvision/detections",
)


#: clock topic -> the events whose exact seconds it gives
_CLOCKS = {ros.CLOCK_TOPIC: ros.JOINTS_TOPIC, ros.FRAME_CLOCK_TOPIC: ros.DEPTH_TOPIC}


def recorded_config(recording: Recording) -> Config:
    """The effective configuration the recording was made with."""
    msg = recording.first("/armvision/config")
    if msg is None:
        raise ArmvisionError(f"{recording.path} holds no configuration (/armvision/config)")
    return config_from_dict(msg.value, f"{recording.path} (/armvision/config)")


def calibration_from_record(record: dict[str, Any]) -> CalibrationStatus:
    """A :class:`CalibrationStatus` from the recorder's calibration JSON."""

    def array(key: str) -> np.ndarray | None:
        value = record.get(key)
        return None if value is None else np.asarray(value, dtype=float)

    T_base_cam = array("T_base_cam")
    if T_base_cam is None or T_base_cam.shape != (4, 4):
        raise ArmvisionError("a recorded calibration has no 4x4 T_base_cam")
    return CalibrationStatus(
        source=str(record.get("source", "recording")),
        method=str(record.get("method", "")),
        residual_mm=record.get("residual_mm"),
        T_base_cam=T_base_cam,
        joint_offsets_rad=array("joint_offsets_rad"),
        calibrated=bool(record.get("calibrated", True)),
        tag_offset_ee=array("tag_offset_ee"),
        tag_rotation_reference=array("tag_rotation_reference"),
    )


@dataclasses.dataclass
class TrackChange:
    """One track id over the compared samples: in how many of them it was recorded and
    replayed, the largest position difference where both had it, the labels each had last."""

    id: int
    recorded: int = 0
    replayed: int = 0
    both: int = 0
    max_diff_mm: float = 0.0
    recorded_label: str | None = None
    replayed_label: str | None = None
    differs_at: list[float] = dataclasses.field(default_factory=list)  # samples with one only

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclasses.dataclass
class ReplayReport:
    """What a replay did and how it compares with the recording."""

    path: str
    frames: int = 0
    cycles: int = 0
    recorded_s: float = 0.0
    wall_s: float = 0.0
    samples: int = 0  # recorded state samples compared
    tracks: dict[int, TrackChange] = dataclasses.field(default_factory=dict)
    detections_recorded: int = 0
    detections_replayed: int = 0
    truncated: bool = False
    recorded_to: str | None = None
    recording_error: str | None = None

    @property
    def max_diff_mm(self) -> float:
        return max((c.max_diff_mm for c in self.tracks.values()), default=0.0)

    @property
    def same_tracks(self) -> bool:
        """Every track id in every compared sample of both, with the same label."""
        return all(
            c.recorded == c.replayed == c.both and c.recorded_label == c.replayed_label
            for c in self.tracks.values()
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "frames": self.frames,
            "cycles": self.cycles,
            "recorded_s": self.recorded_s,
            "wall_s": self.wall_s,
            "samples": self.samples,
            "same_tracks": self.same_tracks,
            "max_diff_mm": self.max_diff_mm,
            "tracks": [c.to_dict() for c in self.tracks.values()],
            "detections_recorded": self.detections_recorded,
            "detections_replayed": self.detections_replayed,
            "truncated": self.truncated,
            "recorded_to": self.recorded_to,
            "recording_error": self.recording_error,
        }

    def table(self) -> str:
        lines = [
            f"replayed {self.path}: {self.frames} frames, {self.cycles} fusion cycles, "
            f"{self.recorded_s:.1f} s recorded, in {self.wall_s:.1f} s"
            + (
                " (the file ends early: a killed recording, read up to its last chunk)"
                if self.truncated
                else ""
            ),
            f"detections: {self.detections_recorded} recorded, {self.detections_replayed} replayed",
            f"tracks over {self.samples} recorded state samples:",
            "  track  recorded  replayed  both  max diff mm  label (recorded -> replayed)",
        ]
        for c in sorted(self.tracks.values(), key=lambda c: c.id):
            label = c.recorded_label or "-"
            if c.replayed_label != c.recorded_label:
                label += f" -> {c.replayed_label or '-'}"
            lines.append(
                f"  {c.id:>5}  {c.recorded:>8}  {c.replayed:>8}  {c.both:>4}  "
                f"{c.max_diff_mm:>11.3f}  {label}"
            )
        verdict = (
            f"same tracks, positions within {self.max_diff_mm:.3f} mm"
            if self.same_tracks
            else f"tracks changed (largest position difference {self.max_diff_mm:.3f} mm)"
        )
        lines.append(verdict)
        if self.recorded_to:
            lines.append(f"recorded the replay to {self.recorded_to}")
        if self.recording_error:
            lines.append(self.recording_error)
        return "\n".join(lines)


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def replay(
    path: str | Path,
    config: Config | None = None,
    *,
    calibration: CalibrationStatus | None = None,
    record_to: str | Path | None = None,
    realtime: bool = False,
    notify: Callable[[str], None] | None = None,
) -> ReplayReport:
    """Re-run perception, fusion and tracking on the recording at ``path`` (see the module
    docstring). ``config``: default the recording's own; ``calibration``: default the
    recorded one; ``record_to``: record the replay too; ``realtime``: at the recording's pace
    (default: as fast as it goes)."""
    from armvision.runtime.system import System

    recording = Recording(path)
    config = recorded_config(recording) if config is None else config
    first_cal = recording.first("/armvision/calibration")
    if calibration is None:
        if first_cal is None:
            raise ArmvisionError(f"{path} holds no calibration: pass one (--calibration FILE)")
        calibration = calibration_from_record(first_cal.value)
    clock = _Clock()
    arm = RecordedArm(path, clock)
    # The reading each frame's object detector was given, by the frame's time.
    frame_joints = {
        msg.log_ns: np.asarray(msg.value.position, dtype=float)
        for msg in recording.messages([ros.FRAME_JOINTS_TOPIC])
    }
    camera = RecordedCamera(path)
    system = System(config, arm, camera, calibration, clock=clock)
    report = ReplayReport(str(path))
    recorder = None
    if record_to is not None:
        recorder = Recorder(record_to, config, wait=True, notify=notify).open()
    half_frame = 0.5 / float(config.camera.fps)
    due: dict[str, float] | None = None
    first_t: float | None = None
    own_calibration_seen = False
    wall_start = time.monotonic()
    camera.start()
    try:
        exact: dict[str, dict[int, float]] = {ros.JOINTS_TOPIC: {}, ros.DEPTH_TOPIC: {}}
        for msg in recording.messages(_EVENT_TOPICS):
            if msg.topic in _CLOCKS:  # the clock's seconds of the cycle or frame that follows
                exact[_CLOCKS[msg.topic]][msg.log_ns] = float(msg.value["t"])
                continue
            t = exact[msg.topic].pop(msg.log_ns, None) if msg.topic in exact else None
            if t is None:
                t = msg.t if msg.topic.startswith("/armvision/") else _stamp(msg)
            if first_t is None:
                first_t = t
                clock.t = t
                if recorder is not None:
                    system.attach_recorder(recorder)
            clock.t = max(clock.t, t)
            if realtime:
                delay = wall_start + (clock.t - first_t) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            if msg.topic == ros.JOINTS_TOPIC:
                arm.hold(np.asarray(msg.value.position, dtype=float))
                system.guard("fusion", system.fusion_step)
                arm.hold(None)
                report.cycles += 1
                if due is None:
                    due = dict.fromkeys(DETECTORS, clock.t)
            elif msg.topic == ros.DEPTH_TOPIC:
                if due is None:
                    due = dict.fromkeys(DETECTORS, clock.t)
                arm.hold(frame_joints.get(msg.log_ns))
                report.detections_replayed += _frame(system, due, half_frame, t)
                arm.hold(None)
                report.frames += 1
            elif msg.topic == "/armvision/calibration":
                if own_calibration_seen:
                    system.set_calibration(calibration_from_record(msg.value))
                own_calibration_seen = True
            elif msg.topic == "/armvision/detectors":
                for name, on in msg.value.items():
                    if name in DETECTORS:
                        system.enabled[name] = bool(on)
            elif msg.topic == "/armvision/detections":
                report.detections_recorded += len(msg.value)
            elif msg.topic == "/armvision/tracks":
                _compare(report, system, msg)
        report.truncated = recording.truncated
        report.recorded_s = 0.0 if first_t is None else clock.t - first_t
    finally:
        camera.stop()
        system.detach_recorder()
        system.close()
    report.wall_s = time.monotonic() - wall_start
    if recorder is not None:
        report.recorded_to = str(recorder.path)
        report.recording_error = recorder.error
    return report


def _stamp(msg: Any) -> float:
    return ros.seconds(msg.value.header.stamp)


def _frame(system: Any, due: dict[str, float], half_frame: float, t: float) -> int:
    """Read the next recorded frame and run the detectors due (as lockstep does); how many
    objects the object detector found in it."""
    frame = system.read_frame()
    if abs(frame.timestamp - t) > 1e-6:
        raise ArmvisionError(
            f"the recording's frames are out of step ({frame.timestamp:.6f} s read at "
            f"{t:.6f} s): is the file damaged?"
        )
    now = frame.timestamp
    found = 0
    for name, work in (("tags", system.tags_once), ("objects", system.objects_once)):
        if system.enabled[name] and due[name] <= now + half_frame:
            system.guard(name, lambda work=work: work(frame))
            due[name] = now + 1.0 / system.rates[name] - half_frame
            if name == "objects":
                state = system.store.snapshot(
                    now, system.fusion.snapshot(), {}, system.enabled, system.calibration
                )
                found = len(state.detections)
    if system.enabled["liquid"] and due["liquid"] <= now + half_frame:
        system.guard("liquid", system.liquid_once)
        due["liquid"] = now + 1.0 / system.rates["liquid"] - half_frame
    for name in DETECTORS:
        if not system.enabled[name]:
            due[name] = now
    return found


def _compare(report: ReplayReport, system: Any, msg: Any) -> None:
    """The recorded tracks of one state sample against the replay's at the same time."""
    snapshot = system.fusion.snapshot()
    if not math.isclose(snapshot.time, msg.value["t"], abs_tol=1e-6):
        return  # a sample of a cycle the replay has not run (not expected)
    report.samples += 1
    recorded = {int(tr["id"]): tr for tr in msg.value["tracks"]}
    replayed = {tr.id: tr for tr in snapshot.tracks}
    for track_id in recorded.keys() | replayed.keys():
        change = report.tracks.setdefault(track_id, TrackChange(track_id))
        rec, rep = recorded.get(track_id), replayed.get(track_id)
        if rec is not None:
            change.recorded += 1
            change.recorded_label = rec["label"]
        if rep is not None:
            change.replayed += 1
            change.replayed_label = rep.label
        if (rec is None) != (rep is None) and len(change.differs_at) < 10:
            change.differs_at.append(float(msg.value["t"]))
        if rec is not None and rep is not None:
            change.both += 1
            diff = 1000.0 * float(np.linalg.norm(np.asarray(rec["position_m"]) - rep.p_base))
            change.max_diff_mm = max(change.max_diff_mm, diff)
