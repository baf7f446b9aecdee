"""The running system's state, handed out as immutable snapshots.

Producers (the camera, detector, fusion and motion threads) each replace their own piece under
one lock; :class:`StateStore.snapshot` assembles a :class:`SystemState` from the pieces at
that moment, with each thread's :class:`ThreadHealth` worked out for the same instant. Nothing
in a snapshot changes afterwards (frames and arrays are read-only), so a UI or a task can keep
one as long as it likes without locking.
"""

from __future__ import annotations

import functools
import math
import threading
import time
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from armvision.camera.frames import RGBDFrame
from armvision.fusion.drift import DriftStatus
from armvision.fusion.loop import FusionSnapshot
from armvision.fusion.tracker import TrackState
from armvision.perception.detection import Detection
from armvision.perception.liquid import LiquidLevel
from armvision.perception.tags import TagDetection
from armvision.runtime.planning_scene import DepthView, OccupancyGrid, PlanningScene

TaskPhase = Literal["idle", "queued", "running", "succeeded", "failed", "stopped"]

#: Rates are counted over this many seconds of history.
RATE_WINDOW_S = 2.0
#: A detection belongs to the nearest track of its label within this distance, metres.
ASSOCIATION_M = 0.05


@dataclass(frozen=True)
class ThreadHealth:
    """One thread at one instant.

    ``rate_hz``: outputs per second over the last ``RATE_WINDOW_S``; ``age_s``: seconds since
    its last output (None before the first); ``outputs``/``errors``: counts since start;
    ``last_error``: the newest failure, kept until the next success; ``stale``: enabled and
    alive but silent for longer than the runtime's ``stale_s``.
    """

    name: str
    enabled: bool
    alive: bool
    rate_hz: float
    age_s: float | None
    outputs: int
    errors: int
    last_error: str | None
    stale: bool

    @property
    def ok(self) -> bool:
        """Running (or switched off on purpose) and producing without errors."""
        if not self.enabled:
            return self.alive
        return self.alive and not self.stale and self.last_error is None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "enabled": self.enabled,
            "alive": self.alive,
            "rate_hz": round(self.rate_hz, 2),
            "age_s": None if self.age_s is None else round(self.age_s, 3),
            "outputs": self.outputs,
            "errors": self.errors,
            "last_error": self.last_error,
            "stale": self.stale,
            "ok": self.ok,
        }


class HealthMeter:
    """Counts one thread's outputs and errors (thread-safe); :meth:`health` reads it out."""

    def __init__(self, name: str, clock: Any = time.monotonic) -> None:
        self.name = name
        self.clock = clock
        self._lock = threading.Lock()
        self._times: deque[float] = deque()
        self._outputs = 0
        self._errors = 0
        self._last_output: float | None = None
        self._last_error: str | None = None

    def tick(self) -> None:
        """One output produced now."""
        now = self.clock()
        with self._lock:
            self._outputs += 1
            self._last_output = now
            self._last_error = None
            self._times.append(now)
            while self._times and self._times[0] < now - RATE_WINDOW_S:
                self._times.popleft()

    @property
    def last_error(self) -> str | None:
        """The newest failure, until the next success."""
        with self._lock:
            return self._last_error

    def error(self, message: str) -> None:
        with self._lock:
            self._errors += 1
            self._last_error = message

    def health(self, enabled: bool, alive: bool, stale_s: float) -> ThreadHealth:
        now = self.clock()
        with self._lock:
            while self._times and self._times[0] < now - RATE_WINDOW_S:
                self._times.popleft()
            n = len(self._times)
            if n >= 2:
                # Intervals over the span they cover, up to now (a stalled thread's rate falls).
                span = max(now - self._times[0], self._times[-1] - self._times[0])
                rate = (n - 1) / span if span > 0 else 0.0
            else:
                rate = 0.0
            age = None if self._last_output is None else max(now - self._last_output, 0.0)
            stale = enabled and alive and math.isfinite(stale_s) and (age is None or age > stale_s)
            return ThreadHealth(
                self.name,
                enabled,
                alive,
                rate,
                age,
                self._outputs,
                self._errors,
                self._last_error,
                stale,
            )


@dataclass(frozen=True)
class LiquidEstimate:
    """A tracked bottle's liquid level, averaged over its last measurements.

    ``fill`` 0..1 (confidence-weighted mean of the measurements that read a level), ``fill_std``
    their spread; both None when every measurement of the window was **unknown** (the meter
    could not see the liquid: an opaque wall, a hidden body), ``unknown`` then says why (the
    newest one's reason). ``confidence`` the mean confidence of all the measurements (an
    unknown one counts 0), ``colour`` the median liquid RGB (None if it looked empty),
    ``samples`` how many were averaged, ``unknown_samples`` how many of the window were
    unknown, ``t`` the newest one's frame time, ``latest`` the newest measurement itself.
    """

    track_id: int
    fill: float | None
    fill_std: float | None
    confidence: float
    colour: tuple[int, int, int] | None
    samples: int
    t: float
    latest: LiquidLevel = field(repr=False)
    unknown_samples: int = 0
    unknown: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "track_id": self.track_id,
            "fill": None if self.fill is None else round(self.fill, 4),
            "fill_std": None if self.fill_std is None else round(self.fill_std, 4),
            "confidence": round(self.confidence, 3),
            "colour": None if self.colour is None else list(self.colour),
            "samples": self.samples,
            "unknown_samples": self.unknown_samples,
            "unknown": self.unknown,
            "t": self.t,
        }


def average_levels(track_id: int, levels: list[tuple[float, LiquidLevel]]) -> LiquidEstimate:
    """Confidence-weighted average of (frame time, measurement) pairs, oldest first; the
    unknown measurements (``fill`` None) are left out of the average and counted."""
    known = [lv for _, lv in levels if lv.fill is not None]
    unknown = [lv for _, lv in levels if lv.fill is None]
    mean_conf = float(np.mean([lv.confidence for _, lv in levels]))
    newest_t, newest = levels[-1]
    if not known:
        return LiquidEstimate(
            track_id, None, None, mean_conf, None, 0, newest_t, newest, len(unknown),
            unknown[-1].unknown or "the liquid could not be seen",
        )  # fmt: skip
    fills = np.array([lv.fill for lv in known], dtype=float)
    conf = np.array([max(lv.confidence, 1e-3) for lv in known])
    fill = float(np.average(fills, weights=conf))
    std = float(math.sqrt(np.average((fills - fill) ** 2, weights=conf)))
    colours = [lv.colour for lv in known if lv.colour is not None]
    colour: tuple[int, int, int] | None = None
    if len(colours) * 2 > len(known):
        r, g, b = (int(c) for c in np.median(np.array(colours), axis=0))
        colour = (r, g, b)
    return LiquidEstimate(
        track_id, fill, std, mean_conf, colour, len(known), newest_t, newest, len(unknown)
    )


@dataclass(frozen=True)
class TaskStatus:
    """The motion worker's current (or last) task.

    ``phase``: idle, queued, running, then succeeded / failed / stopped. ``progress`` 0..1 and
    ``message`` as the task reports them; ``result`` its report (a JSON-able dict) when it
    ended; ``error`` a readable reason when it failed or was stopped.
    """

    name: str | None = None
    phase: TaskPhase = "idle"
    progress: float = 0.0
    message: str = ""
    started: float | None = None
    finished: float | None = None
    result: Mapping[str, Any] | None = None
    error: str | None = None
    task_id: int = 0

    @property
    def active(self) -> bool:
        return self.phase in ("queued", "running")

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.task_id,
            "name": self.name,
            "phase": self.phase,
            "progress": round(self.progress, 3),
            "message": self.message,
            "started": self.started,
            "finished": self.finished,
            "result": None if self.result is None else dict(self.result),
            "error": self.error,
        }


@dataclass(frozen=True)
class CalibrationStatus:
    """Which calibration the system runs with: where from, how good.

    ``calibrated`` False: no calibration yet; ``T_base_cam`` is then only the nominal camera
    placement, good for looking, not for moving to what the camera sees. ``tag_offset_ee``:
    the gripper tag's mount as the calibration estimated it (None: as configured);
    ``tag_rotation_reference``: the tag-orientation disagreement seen over the calibration's
    samples (rotation vector, rad; see :func:`armvision.fusion.drift.rotation_reference`).
    """

    source: str
    method: str
    residual_mm: float | None
    T_base_cam: np.ndarray
    joint_offsets_rad: np.ndarray | None = None
    calibrated: bool = True
    tag_offset_ee: np.ndarray | None = None
    tag_rotation_reference: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "calibrated": self.calibrated,
            "source": self.source,
            "method": self.method,
            "residual_mm": None if self.residual_mm is None else round(self.residual_mm, 3),
            "T_base_cam": self.T_base_cam.tolist(),
            "joint_offsets_deg": (
                None
                if self.joint_offsets_rad is None
                else np.degrees(self.joint_offsets_rad).round(4).tolist()
            ),
        }


@dataclass(frozen=True)
class SystemState:
    """Everything the system knows at ``time`` (its clock's seconds). Immutable.

    ``frame``: the newest camera frame; ``tags``/``tags_time``: the tags of the newest frame
    the tag thread processed and that frame's time; ``detections``/``detections_frame``:
    bottles and cups of the newest frame the object thread processed, and that frame (boxes
    refer to it); ``liquid``: per confirmed bottle track id; ``fusion``: the fusion loop's
    snapshot (end effector, tracks); ``health`` per thread; ``detectors``: which detection
    threads are on; ``task``: the motion worker; ``finger_position``: the gripper, metres.
    """

    time: float
    frame: RGBDFrame | None
    tags: tuple[TagDetection, ...]
    tags_time: float | None
    detections: tuple[Detection, ...]
    detections_frame: RGBDFrame | None
    liquid: Mapping[int, LiquidEstimate]
    fusion: FusionSnapshot
    health: Mapping[str, ThreadHealth]
    detectors: Mapping[str, bool]
    task: TaskStatus
    calibration: CalibrationStatus
    finger_position: float | None
    depth_view: DepthView | None = None

    @property
    def occupancy(self) -> OccupancyGrid | None:
        """The occupancy grid of the newest object frame (built when first asked for)."""
        return None if self.depth_view is None else self.depth_view.grid

    @functools.cached_property
    def planning_scene(self) -> PlanningScene:
        """What the arm must keep clear of now: the table, every confirmed track with its
        uncertainty, the occupancy grid of the newest object frame and the arm's links (see
        :mod:`armvision.runtime.planning_scene`)."""
        return PlanningScene.build(self.tracks, self.occupancy, self.fusion.joint_positions)

    @property
    def T_base_cam(self) -> np.ndarray:
        """The camera pose the system works with now: the calibration (``calibration.T_base_cam``,
        its prior) as the fusion loop refines it from the gripper tag. Detections, tracks and
        every task map the camera into the base frame with this one pose."""
        refined = self.fusion.T_base_cam
        return self.calibration.T_base_cam if refined is None else refined

    @property
    def drift(self) -> DriftStatus:
        """Has the camera moved since calibration (the gripper tag against the encoders)?"""
        return self.fusion.drift

    @property
    def tracks(self) -> tuple[TrackState, ...]:
        """Confirmed object tracks (from the fusion snapshot)."""
        return self.fusion.tracks

    def track(self, track_id: int) -> TrackState | None:
        return next((t for t in self.fusion.tracks if t.id == track_id), None)

    def track_of(self, detection: Detection, within: float = ASSOCIATION_M) -> TrackState | None:
        """The confirmed track of the detection's label nearest to it (in the base frame, by
        the camera pose the system works with), if within ``within`` metres."""
        T = self.T_base_cam
        p = T[:3, :3] @ np.asarray(detection.center_cam, dtype=float) + T[:3, 3]
        same = [t for t in self.fusion.tracks if t.label == detection.label]
        if not same:
            return None
        dist = [float(np.linalg.norm(t.p_base - p)) for t in same]
        k = int(np.argmin(dist))
        return same[k] if dist[k] <= within else None

    def bottles(self) -> list[TrackState]:
        """Confirmed bottle tracks, nearest the base first."""
        return sorted(
            (t for t in self.fusion.tracks if t.label == "bottle"),
            key=lambda t: float(np.hypot(t.p_base[0], t.p_base[1])),
        )


@dataclass
class _Pieces:
    frame: RGBDFrame | None = None
    tags: tuple[TagDetection, ...] = ()
    tags_time: float | None = None
    detections: tuple[Detection, ...] = ()
    detections_frame: RGBDFrame | None = None
    liquid: dict[int, LiquidEstimate] = field(default_factory=dict)
    task: TaskStatus = field(default_factory=TaskStatus)
    depth_view: DepthView | None = None


class StateStore:
    """The one place producers write to and readers take snapshots from (one lock)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pieces = _Pieces()
        self._changed = threading.Condition(self._lock)
        self._frame_seq = 0

    def set_frame(self, frame: RGBDFrame) -> None:
        _read_only(frame)
        with self._changed:
            self._pieces.frame = frame
            self._frame_seq += 1
            self._changed.notify_all()

    def wait_frame(self, after_seq: int, timeout_s: float) -> tuple[int, RGBDFrame | None]:
        """The newest frame once there is one newer than ``after_seq`` (or at the timeout)."""
        with self._changed:
            self._changed.wait_for(lambda: self._frame_seq > after_seq, timeout=timeout_s)
            return self._frame_seq, self._pieces.frame

    def set(self, **pieces: Any) -> None:
        """Replace pieces: tags, tags_time, detections, detections_frame, depth_view."""
        with self._lock:
            for key, value in pieces.items():
                if not hasattr(self._pieces, key) or key in ("frame", "liquid", "task"):
                    raise KeyError(f"not a settable piece of state: {key}")
                setattr(self._pieces, key, value)

    def set_liquid(self, track_id: int, estimate: LiquidEstimate | None) -> None:
        with self._lock:
            liquid = dict(self._pieces.liquid)
            if estimate is None:
                liquid.pop(track_id, None)
            else:
                liquid[track_id] = estimate
            self._pieces.liquid = liquid

    def keep_liquid(self, track_ids: Collection[int]) -> None:
        """Forget the liquid estimates of tracks that no longer exist."""
        with self._lock:
            self._pieces.liquid = {k: v for k, v in self._pieces.liquid.items() if k in track_ids}

    def task(self) -> TaskStatus:
        with self._lock:
            return self._pieces.task

    def set_task(self, status: TaskStatus | None = None, **changes: Any) -> TaskStatus:
        """Replace the task status (whole, or the named fields of the current one)."""
        with self._lock:
            base = self._pieces.task if status is None else status
            self._pieces.task = replace(base, **changes) if changes else base
            return self._pieces.task

    def snapshot(
        self,
        time_s: float,
        fusion: FusionSnapshot,
        health: Mapping[str, ThreadHealth],
        detectors: Mapping[str, bool],
        calibration: CalibrationStatus,
        finger_position: float | None = None,
    ) -> SystemState:
        with self._lock:
            p = self._pieces
            return SystemState(
                time=time_s,
                frame=p.frame,
                tags=p.tags,
                tags_time=p.tags_time,
                detections=p.detections,
                detections_frame=p.detections_frame,
                liquid=MappingProxyType(dict(p.liquid)),
                fusion=fusion,
                health=MappingProxyType(dict(health)),
                detectors=MappingProxyType(dict(detectors)),
                task=p.task,
                calibration=calibration,
                finger_position=finger_position,
                depth_view=p.depth_view,
            )


def _read_only(frame: RGBDFrame) -> None:
    for name in ("color", "depth"):
        array = getattr(frame, name, None)
        if isinstance(array, np.ndarray):
            array.flags.writeable = False
