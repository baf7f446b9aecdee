"""The fusion loop: the 100 Hz thread that fuses encoders and camera and tracks objects.

:class:`FusionLoop` owns one :class:`~armvision.fusion.kalman.EEFilter` and one
:class:`~armvision.fusion.tracker.MultiObjectTracker`. Each cycle (:meth:`FusionLoop.step`)
it

1. reads the arm's encoders (``arm.get_joint_positions()``, and the joint velocities the arm
   measured with them, ``arm.get_joint_velocities()``, where it measures them) and stamps
   them with ``clock()``;
2. takes every camera result pushed since the last cycle by other threads
   (:meth:`~FusionLoop.push_tag` for the gripper tag, :meth:`~FusionLoop.push_detections`
   for bottles and cups), oldest first, each stamped with its frame's capture time;
3. fuses them (camera results are older than the encoder reading; the filter inserts and
   replays them, see :class:`~armvision.fusion.kalman.EEFilter`); object detections are
   mapped into the base frame with the newest camera pose, the calibration as refined by the
   end-effector filter (``fusion.estimate_camera_pose``);
4. compares each gripper-tag sighting with the encoders of its capture time
   (:class:`~armvision.fusion.drift.DriftMonitor`: has the camera moved since calibration?);
5. publishes an immutable :class:`FusionSnapshot` (:meth:`~FusionLoop.snapshot`).

:meth:`~FusionLoop.start` runs the cycle on a thread at ``config.fusion.rate_hz``;
:meth:`~FusionLoop.stop` ends it. A failure in the thread stops the loop and is reported in
the snapshot's ``error`` (and logged), never lost. Without the thread, call :meth:`step` from
your own loop: that is how lockstep simulations and tests drive it.

Every time pushed in must be on the ``clock``'s time base (simulation time for a SimWorld,
``time.monotonic`` by default): convert a RealSense frame's timestamp before pushing it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from armvision.config import CalibrationConfig, Config, FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.drift import DriftMonitor, DriftStatus
from armvision.fusion.kalman import (
    DEFAULT_FOCAL_PX,
    EEEstimate,
    EEFilter,
    FilterStats,
    as_array,
    as_time,
)
from armvision.fusion.tracker import (
    DetectionLike,
    MultiObjectTracker,
    ObjectMeasurement,
    TrackState,
    measurement_from_detection,
)
from armvision.perception.selfmask import segment_distances
from armvision.robot.kinematics import fk

log = logging.getLogger("armvision.fusion")

#: The end effector's speed at a tag sighting is taken over this interval, seconds.
DRIFT_SPEED_DT_S = 0.05
#: The finger pads along the gripper's x axis, m from ``ee_gripper_link`` (the point between
#: the fingertips): 38.6 mm behind it to 29.5 mm ahead (the pads of the simulated ViperX-300s,
#: ``sim/data/vx300s.xml``, sized like the real fingers).
FINGER_SPAN_M = (-0.0386, 0.0295)
#: An object whose axis passes this near the pads is in the gripper, m: a bottle's radius
#: (up to 3 cm on the bench) and 2 cm. Not the detection's own fitted radius: that is what the
#: gripper changes, and a rule on it would take a frame in one run and leave it in its replay.
GRIPPER_COVER_RADIUS_M = 0.05
#: ... and whose top is at most this far below the gripper's point, m.
GRIPPER_COVER_MARGIN_M = 0.02
#: The height an object of unknown height is taken to span about its centre, m.
UNKNOWN_HALF_HEIGHT_M = 0.1


def in_gripper(m: ObjectMeasurement, T_base_ee: np.ndarray) -> bool:
    """Is the object of ``m`` (base frame) between or at the fingers of the gripper at
    ``T_base_ee`` (``ee_gripper_link``)?

    Its fit is then a fit to what the gripper leaves of it, and that moves as the gripper
    comes in and the fingers close (the demo's grabbed bottle fitted with 8-16 mm of its 24 mm
    radius, its centre millimetres off, and millimetres apart again between the raw and the
    JPEG colour of one frame): the fusion loop does not fuse it, and its track holds where it
    was last seen whole (the grab's own checks say whether the gripper holds it).
    """
    x_ee, p_ee = T_base_ee[:3, 0], T_base_ee[:3, 3]
    a, b = ((p_ee + s * x_ee)[None, :2] for s in FINGER_SPAN_M)  # the pads, seen from above
    across = float(segment_distances(m.p_base[None, :2], a, b)[0, 0])
    half = 0.5 * m.height if m.height is not None else UNKNOWN_HALF_HEIGHT_M
    below_top = m.p_base[2] + half + GRIPPER_COVER_MARGIN_M - p_ee[2]
    above_foot = p_ee[2] - (m.p_base[2] - half)
    return across < GRIPPER_COVER_RADIUS_M and below_top > 0.0 and above_foot > 0.0


@dataclass(frozen=True)
class FusionSnapshot:
    """What the fusion loop knows at ``time`` (clock seconds); immutable, safe to share.

    ``ee``: the fused end effector predicted to ``time`` (None until the first reading);
    ``T_base_ee``: a full pose, the fused position with the orientation of the encoders
    corrected by the estimated joint offsets (None like ``ee``); ``tracks``: confirmed object
    tracks, predicted to ``time``, by id; ``joint_positions``: the encoder reading of this
    cycle; ``cycles``: cycles run; ``overruns``: cycles that started late by more than a
    period; ``error``: why the thread stopped, if it failed; ``ee_stats``: the filter's
    counters (updates, gated, replayed, dropped); ``drift``: the camera against the encoders
    (has the camera moved since calibration?); ``T_base_cam``: the camera pose the loop
    maps detections with, the calibration (its prior) as the end-effector filter refines it
    from the gripper tag; the one camera pose every consumer of a snapshot should use.
    """

    time: float
    ee: EEEstimate | None
    T_base_ee: np.ndarray | None
    tracks: tuple[TrackState, ...]
    joint_positions: np.ndarray | None
    cycles: int
    overruns: int
    running: bool
    error: str | None
    ee_stats: FilterStats
    drift: DriftStatus = dataclasses.field(default_factory=DriftStatus)
    T_base_cam: np.ndarray | None = None


class JointReader(Protocol):
    """What the loop asks of an arm (the Arm interface has both): its encoder reading, rad,
    and the joint velocities measured with it, rad/s, or None if the arm measures none."""

    def get_joint_positions(self) -> ArrayLike: ...
    def get_joint_velocities(self) -> ArrayLike | None: ...


class FusionLoop:
    """Fuse an arm's encoders with camera results at a fixed rate (see the module docstring).

    ``arm``: anything with ``get_joint_positions()`` (the Arm interface). ``T_base_cam``: the
    camera calibration; ``T_ee_tag``: the gripper tag's mount. ``clock``: seconds on the time
    base of every pushed timestamp. ``focal_px``: the colour camera's focal length. The drift
    thresholds come from ``config.calibration`` when ``config`` is the whole tree.
    """

    def __init__(
        self,
        config: Config | FusionConfig,
        arm: JointReader,
        T_base_cam: ArrayLike,
        T_ee_tag: ArrayLike,
        clock: Callable[[], float] = time.monotonic,
        focal_px: float = DEFAULT_FOCAL_PX,
        drift: DriftMonitor | None = None,
    ) -> None:
        self.config = config.fusion if isinstance(config, Config) else config
        if not all(
            callable(getattr(arm, name, None))
            for name in ("get_joint_positions", "get_joint_velocities")
        ):
            raise FusionError(
                "arm must have get_joint_positions() and get_joint_velocities() (the Arm interface)"
            )
        self.arm = arm
        self.clock = clock
        self.focal_px = float(focal_px)
        self.T_base_cam = as_array("T_base_cam", T_base_cam, (4, 4)).copy()
        self.ee_filter = EEFilter(self.config, self.T_base_cam, T_ee_tag, focal_px=focal_px)
        self.tracker = MultiObjectTracker(self.config)
        if drift is None:
            cal = config.calibration if isinstance(config, Config) else CalibrationConfig()
            drift = DriftMonitor(cal, self.T_base_cam, T_ee_tag)
        self.drift = drift
        self._lock = threading.Lock()  # guards the pending queues and the snapshot
        self._pending_tags: list[tuple[float, np.ndarray]] = []
        self._pending_objects: list[tuple[float, list, bool]] = []
        self._cycles = 0
        self._overruns = 0
        self._error: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._snapshot = self._make_snapshot(None, None)

    # ---------------------------------------------------------------- producers (any thread)

    def push_tag(self, t: float, T_cam_tag: ArrayLike) -> None:
        """A gripper-tag pose seen in a frame captured at ``t`` (clock seconds)."""
        item = (as_time("t", t), as_array("T_cam_tag", T_cam_tag, (4, 4)).copy())
        with self._lock:
            self._pending_tags.append(item)

    def push_detections(self, t: float, detections: Sequence[DetectionLike]) -> None:
        """Every bottle/cup detection (camera frame) of the frame captured at ``t``.

        Push an empty list for a processed frame with nothing in it, so tracks count a miss.
        The loop maps them into the base frame when it fuses them, with its newest camera pose
        (the calibration as refined by the end-effector filter, when it estimates it).
        """
        t = as_time("t", t)
        items = list(detections)
        for d in items:
            if not hasattr(d, "center_cam") or not hasattr(d, "label"):
                raise FusionError(
                    f"expected perception Detections (center_cam, label), got {type(d).__name__}"
                )
        with self._lock:
            self._pending_objects.append((t, items, False))

    def push_object_measurements(self, t: float, measurements: Sequence[ObjectMeasurement]) -> None:
        """Like :meth:`push_detections` with measurements already in the base frame."""
        t = as_time("t", t)
        items = list(measurements)
        for m in items:
            if not isinstance(m, ObjectMeasurement):
                raise FusionError(f"expected ObjectMeasurement, got {type(m).__name__}")
        with self._lock:
            self._pending_objects.append((t, items, True))

    # ---------------------------------------------------------------- the cycle

    def step(self) -> FusionSnapshot:
        """One fusion cycle (see the module docstring); returns and publishes the snapshot."""
        t = float(self.clock())
        q = np.asarray(self.arm.get_joint_positions(), dtype=float)
        qd = self.arm.get_joint_velocities()
        with self._lock:
            tags, self._pending_tags = self._pending_tags, []
            objects, self._pending_objects = self._pending_objects, []
        self.ee_filter.update_encoders(t, q, qd)
        for t_tag, T_cam_tag in sorted(tags, key=lambda item: item[0]):
            self.ee_filter.update_camera(t_tag, T_cam_tag)
            self._check_drift(t_tag, T_cam_tag)
        if objects:
            T_base_cam = self.ee_filter.T_base_cam_refined()
            for t_frame, items, in_base in sorted(objects, key=lambda item: item[0]):
                measurements = (
                    items
                    if in_base
                    else [
                        measurement_from_detection(d, T_base_cam, self.config, self.focal_px)
                        for d in items
                    ]
                )
                q_frame = self.ee_filter.joints_at(t_frame)
                if q_frame is not None:
                    T_ee = fk(q_frame)
                    measurements = [m for m in measurements if not in_gripper(m, T_ee)]
                self.tracker.update(t_frame, measurements)
        self._cycles += 1
        snapshot = self._make_snapshot(t, q)
        with self._lock:
            self._snapshot = snapshot
        return snapshot

    def _check_drift(self, t: float, T_cam_tag: np.ndarray) -> None:
        """Compare a tag sighting with the encoders of its capture time; the end effector's
        speed then comes from the readings 50 ms apart (the filter's own velocity is what a
        moved camera upsets)."""
        q = self.ee_filter.joints_at(t)
        q_before = self.ee_filter.joints_at(t - DRIFT_SPEED_DT_S)
        if q is None:
            return
        speed = math.inf
        if q_before is not None:
            p, p_before = fk(q)[:3, 3], fk(q_before)[:3, 3]
            speed = float(np.linalg.norm(p - p_before)) / DRIFT_SPEED_DT_S
        self.drift.observe(t, q, T_cam_tag, speed)

    def _make_snapshot(self, t: float | None, q: np.ndarray | None) -> FusionSnapshot:
        ee = self.ee_filter.estimate(t) if self.ee_filter.time is not None else None
        T_base_ee = None
        if ee is not None and q is not None:
            T_base_ee = self.ee_filter.T_base_ee(q)
            T_base_ee[:3, 3] = ee.p_base
            T_base_ee.flags.writeable = False
        q_out = None
        if q is not None:
            q_out = q.copy()
            q_out.flags.writeable = False
        tracks = tuple(self.tracker.tracks(t)) if t is not None else ()
        stats = self.ee_filter.stats
        return FusionSnapshot(
            time=math.nan if t is None else t,
            ee=ee,
            T_base_ee=T_base_ee,
            tracks=tracks,
            joint_positions=q_out,
            cycles=self._cycles,
            overruns=self._overruns,
            running=self.running,
            error=self._error,
            ee_stats=FilterStats(
                stats.updates,
                dict(stats.rejected),
                stats.restarts,
                stats.late_replayed,
                stats.late_dropped,
            ),
            drift=self.drift.status,
            T_base_cam=_read_only(self.ee_filter.T_base_cam_refined()),
        )

    def snapshot(self) -> FusionSnapshot:
        """The newest published snapshot (immutable)."""
        with self._lock:
            return self._snapshot

    # ---------------------------------------------------------------- the thread

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Run :meth:`step` on a thread at ``rate_hz`` (wall-clock) until :meth:`stop`."""
        if self.running:
            return
        self._stop.clear()
        self._error = None
        self._thread = threading.Thread(target=self._run, name="fusion", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (waits up to ``timeout_s``); the last snapshot stays readable."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            if self._thread.is_alive():
                log.warning("fusion thread did not stop within %.1f s", timeout_s)
            self._thread = None
        snapshot = self.snapshot()
        with self._lock:
            self._snapshot = _replace_running(snapshot, False, self._error)

    def __enter__(self) -> FusionLoop:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        period = 1.0 / self.config.rate_hz
        next_time = time.monotonic()
        try:
            while not self._stop.is_set():
                self.step()
                next_time += period
                delay = next_time - time.monotonic()
                if delay < -period:  # more than a cycle behind: count it, do not try to catch up
                    self._overruns += 1
                    next_time = time.monotonic()
                elif delay > 0:
                    self._stop.wait(delay)
        except Exception as exc:  # reported in the snapshot, not lost with the thread
            self._error = f"{type(exc).__name__}: {exc}"
            log.exception("fusion loop failed")
            snapshot = self.snapshot()
            with self._lock:
                self._snapshot = _replace_running(snapshot, False, self._error)


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def _replace_running(snapshot: FusionSnapshot, running: bool, error: str | None) -> FusionSnapshot:
    return dataclasses.replace(snapshot, running=running, error=error)
