"""Analyse a bottle's liquid: fill, colour and confidence, averaged over several frames.

1. **A confirmed bottle track**: ``track_id``, or the bottle nearest the base; waited for up to
   ``grab.track_wait_s`` (the same wait as the grasp's).
2. **In place.** Every new frame the object stage processes (never one frame twice, none older
   than this step) gives one measurement, when the frame has a bottle detection within
   :data:`~armvision.runtime.state.ASSOCIATION_M` of where the track last saw the
   bottle (a stale or lost track is replaced by the nearest fresh bottle track:
   ``_Analyze.follow``): the system's
   :class:`~armvision.perception.liquid.LiquidLevelMeter` on that detection's box with its
   cylinder (centre, radius, height), as the liquid stage measures. ``analyze.frames`` of
   them are averaged, weighted by confidence
   (:func:`~armvision.runtime.state.average_levels`). The view is **poor** when fewer come
   within :func:`measure_window` seconds, when their mean confidence is below
   ``analyze.min_confidence``, or when the bottle's median box is shorter than
   ``analyze.min_box_height_px`` pixels.
3. **Presented** (poor view and ``analyze.allow_pick``): the bottle is grasped and lifted
   (:func:`~armvision.tasks.grab.grab`), carried above everything else on the table, stood on
   the table at the :func:`presentation_spot`, released, and the gripper backs off and rises
   out of the way; then it is measured as in 2, with the radius the closed gripper measured
   and the box projected from that geometry (:func:`bottle_box`); then it is grasped again
   where it was released, carried back, stood where it was and released, and the arm returns
   to the grasp's safe start pose. The presented result counts when enough frames came and
   their mean confidence reaches ``min_confidence`` (the box size is not judged again: the
   spot makes it as large as the arm and the field of view allow).

Why on the table and not held up in the air: the liquid meter finds "up" and the bottle's
foot from the table plane around the bottle's foot in depth, and the object detector fits
cylinders standing on the table; a bottle held in the air would be measured against the table
far below it. Standing the bottle on the table nearer the camera, in full view, with nothing
in front of it and (where possible) nothing behind it, keeps every assumption of the meter
true and removes what makes a view poor: distance (few pixels), other objects in front or
behind, the image border. Releasing it takes the fingers off its sides, where the meter looks
for the wall's silhouette and the background beside it.

Why the gripper's radius: the object detector fits the circle of what returns depth, and a
clear bottle's wall returns none, so for a clear bottle its radius is the liquid's or the
cap's, 3-10 mm short (measured on the simulator), and the meter then looks for the shoulder's
silhouette edges too far in. Closed on the bottle, each finger stands :data:`PAD_INSET_M`
outside the bottle's wall, so the finger position gives the radius to ~1 mm.

Measured on the simulator (default camera placement and lighting, object stage at 5 Hz, 8
frames, true camera pose): in place 3.2 points MAE (max 7.5, mostly too low: the radius
above) over 16 lone bottles of random size, fill 10-90 % and liquid; presented (view forced
poor) 1.0 points MAE (max 1.7) over 8 of them, and 0.4 (max 1.2) over the default scenes of
seeds 0-9 (2-4 bottles and cups), every bottle put back within 8 mm of where it stood,
upright, nothing else moved. Picking and presenting takes 40-50 s of arm time (the grasp
~11 s, carrying, releasing and backing off ~12 s each way).

Units: metres, seconds, pixels for boxes; positions in the base frame unless named ``_cam``.
The timeout ``analyze.timeout_s`` bounds finding and measuring; once the bottle has been
moved it is always put back (Stop still halts everything at once: TaskStopped propagates,
the arm halts where it is, the gripper as it was).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame, project
from armvision.config import AnalyzeConfig, GrabConfig
from armvision.errors import PerceptionError
from armvision.fusion.tracker import TrackState
from armvision.geometry import inv_T, make_T, rpy_to_R
from armvision.perception.liquid import ContainerGeometry, LiquidLevel
from armvision.perception.objects import BOTTLE_BODY_FRACTION, Detection
from armvision.robot.kinematics import ArmModel, ik
from armvision.runtime.state import ASSOCIATION_M, LiquidEstimate, SystemState, average_levels
from armvision.runtime.system import TaskContext
from armvision.tasks.grab import (
    GRASP_MARGIN_M,
    GRIPPER_HALF_WIDTH_M,
    HOVER_CLEARANCE_M,
    GrabResult,
    grab,
    safe_start_pose,
)
from armvision.tasks.motion import SEGMENT_TIME_S, level_pose, motion_seed, paced_time, unflipped_ik

Array = NDArray[np.float64]
Box = tuple[float, float, float, float]

#: Interbotix vx300s fingers: each pad sits this far inboard of the finger joint's coordinate
#: (pads 17 mm apart at the closed 0.021 m), so closed on a bottle finger = radius + this, m.
PAD_INSET_M = 0.0125
#: A finger-measured radius outside this range is not believed (the track's is used), m.
RADIUS_RANGE_M = (0.01, 0.07)
#: The measurement window is this many object-stage periods per frame asked for, ...
WINDOW_PERIODS_PER_FRAME = 3.0
#: ... and at least this long, seconds.
MIN_WINDOW_S = 3.0
#: A track without a detection for this long is stale: its position is a prediction, s.
STALE_S = 0.5
#: A lost track is taken up again by the bottle track nearest where it was, within this, m.
REACQUIRE_M = 0.08
#: A deadline with less than this left has passed, seconds.
MIN_WAIT_S = 1e-3
#: Releasing, the gripper backs off until its fingertips are this far from the bottle, m.
BACKOFF_MARGIN_M = 0.02
#: While carried, the held bottle's bottom stays this far above every other object's top, m.
CARRY_CLEARANCE_M = 0.04
#: The bottle is released this far above the table (it drops onto it), m.
RELEASE_HEIGHT_M = 0.004
#: Carrying speed along straight lines (a gentle ride for the liquid), m/s.
CARRY_SPEED_M_S = 0.15
#: Straight moves are split into segments at most this long, m.
SEGMENT_M = 0.06
#: With the gripper empty, a point the arm cannot reach level is reached pitched down up to
#: this (near the base a level gripper cannot reach low points), degrees. A held bottle is
#: always carried level, so it stays upright.
EMPTY_MAX_PITCH_DEG = 90
#: The presentation spot keeps this free gap to every other object (room for a finger), m.
SPOT_CLEARANCE_M = 0.06
#: Nothing may stand within this of the line of sight from the camera to the spot, m.
SIGHT_MARGIN_M = 0.015
#: Objects up to this far behind the bottle (seen from the camera) are its background, m ...
BACKGROUND_M = 0.4
#: ... and a spot with one beside the bottle in the image costs this much in the choice of
#: spot (as 1 m further from ``present_distance``): the liquid meter compares the bottle
#: with what it sees beside it, and edges there move its shoulder.
CLUTTER_PENALTY = 1.0
#: The bottle's projected box must stay this far inside the image at the spot, pixels.
IMAGE_MARGIN_PX = 12.0
#: Nearest the camera a spot may be (the D435's minimum depth at 640x480 is ~0.28 m), m.
MIN_RANGE_M = 0.32
#: Spot candidates: distances from the base axis (m) and bearings (rad) tried.
SPOT_DISTANCES_M = np.arange(0.22, 0.601, 0.02)
SPOT_BEARINGS_RAD = np.radians(np.arange(-70.0, 70.1, 5.0))

#: Apparent liquid colours and their names (sRGB). The name reported is the nearest entry in
#: CIELAB with lightness counted at half weight, so a dim room shifts a name less than a hue
#: does. It names the colour as the camera sees it through the wall, not the drink.
COLOUR_PALETTE: dict[str, tuple[int, int, int]] = {
    "white": (235, 235, 230),
    "grey": (128, 128, 128),
    "black": (30, 30, 30),
    "red": (190, 35, 40),
    "dark red": (120, 40, 60),
    "orange": (225, 130, 40),
    "amber": (195, 140, 80),
    "yellow": (225, 200, 60),
    "brown": (110, 70, 40),
    "green": (60, 140, 60),
    "blue": (50, 90, 190),
    "light blue": (140, 175, 215),
    "purple": (120, 60, 140),
}
#: Weight of CIELAB lightness against a and b when naming a colour (:func:`colour_name`).
LIGHTNESS_WEIGHT = 0.5


@dataclass(frozen=True)
class AnalyzeResult:
    """What the analysis found. ``ok`` when a trustworthy measurement was made.

    ``fill`` 0..1 of the body's inner height (the meter's definition), ``fill_std`` the
    confidence-weighted spread of the frames; ``colour`` the liquid's median RGB as seen (None
    when it looked empty) and ``colour_name`` the nearest :data:`COLOUR_PALETTE` name;
    ``confidence`` the frames' mean confidence 0..1; ``frames`` how many were averaged;
    ``picked`` whether the bottle was picked and presented; ``position`` the bottle's centre
    (x, y, z) in the base frame where it stood at the start (and stands again at the end);
    ``box_height_px`` its median box height in the frames averaged; ``view`` "in place" or
    "presented"; ``duration_s`` from start to end (clock seconds). When ``ok`` is False the
    numbers are those of the last measurement made, if any, and ``reason`` says what failed.
    """

    ok: bool
    reason: str
    track_id: int | None = None
    fill: float | None = None
    fill_std: float | None = None
    colour: tuple[int, int, int] | None = None
    colour_name: str | None = None
    confidence: float | None = None
    frames: int = 0
    picked: bool = False
    position: tuple[float, float, float] | None = None
    box_height_px: float | None = None
    view: str | None = None
    duration_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        def rounded(v: float | None, digits: int) -> float | None:
            return None if v is None else round(float(v), digits)

        return {
            "ok": self.ok,
            "reason": self.reason,
            "track_id": self.track_id,
            "fill": rounded(self.fill, 4),
            "fill_pct": rounded(None if self.fill is None else 100.0 * self.fill, 1),
            "fill_std": rounded(self.fill_std, 4),
            "colour": None if self.colour is None else list(self.colour),
            "colour_name": self.colour_name,
            "confidence": rounded(self.confidence, 3),
            "frames": self.frames,
            "picked": self.picked,
            "position": None if self.position is None else [round(v, 4) for v in self.position],
            "box_height_px": rounded(self.box_height_px, 1),
            "view": self.view,
            "duration_s": round(self.duration_s, 3),
        }


# --------------------------------------------------------------------------- pure helpers


def _lab(rgb: ArrayLike) -> Array:
    """CIELAB (L 0..100, a, b) of sRGB colours (N, 3) uint8, by OpenCV's D65 conversion."""
    pixels = np.asarray(rgb, dtype=np.float32).reshape(1, -1, 3) / 255.0
    return cv2.cvtColor(pixels, cv2.COLOR_RGB2Lab).reshape(-1, 3).astype(float)


_PALETTE_NAMES = tuple(COLOUR_PALETTE)
_PALETTE_LAB = _lab(list(COLOUR_PALETTE.values()))


def colour_name(rgb: ArrayLike | None) -> str | None:
    """The :data:`COLOUR_PALETTE` name nearest ``rgb`` (0..255) in CIELAB, lightness at
    :data:`LIGHTNESS_WEIGHT`; None for None. E.g. (126, 153, 180) -> "light blue"."""
    if rgb is None:
        return None
    d = _PALETTE_LAB - _lab([rgb])[0]
    d[:, 0] *= LIGHTNESS_WEIGHT
    return _PALETTE_NAMES[int(np.argmin(np.einsum("ij,ij->i", d, d)))]


def bottle_box(
    intr: Intrinsics,
    T_cam_base: ArrayLike,
    p_base_foot: ArrayLike,
    radius: float,
    height: float,
    body_fraction: float = BOTTLE_BODY_FRACTION,
) -> Box:
    """Pixel box (x0, y0, x1, y1) of an upright bottle standing at ``p_base_foot``.

    The bottle as the liquid meter models it: a cylinder of ``radius`` from the foot up to
    ``body_fraction`` of ``height``, then a neck and cap of about half the radius; the box
    bounds the projection of rings of 24 points at the foot, the shoulder and the top.
    """
    ang = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
    circle = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
    foot = np.asarray(p_base_foot, dtype=float)
    rings = [
        foot + circle * (scale * radius) + [0.0, 0.0, frac * height]
        for frac, scale in ((0.0, 1.0), (body_fraction, 1.0), (1.0, 0.5))
    ]
    T = np.asarray(T_cam_base, dtype=float)
    pts_cam = np.concatenate(rings) @ T[:3, :3].T + T[:3, 3]
    uv = project(intr, pts_cam)
    return (
        float(uv[:, 0].min()),
        float(uv[:, 1].min()),
        float(uv[:, 0].max()) + 1.0,
        float(uv[:, 1].max()) + 1.0,
    )


def _segment_distance(p: Array, a: Array, b: Array) -> float:
    """Distance from point ``p`` to the segment a-b (2-D)."""
    ab = b - a
    s = float(np.clip((p - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + s * ab)))


@dataclass(frozen=True)
class Obstacle:
    """Another object on the table: centre (x, y) in the base frame, radius, top height, m."""

    xy: tuple[float, float]
    radius: float
    top: float


@dataclass(frozen=True)
class Spot:
    """Where to stand the bottle for the camera: (x, y) in the base frame, the gripper's yaw
    there (facing it from the base), its distance from the camera's centre (m) and its
    projected box (pixels)."""

    xy: tuple[float, float]
    yaw: float
    distance: float
    box: Box


def _reachable(p: ArrayLike, yaw: float, max_pitch_deg: int, model: ArmModel) -> bool:
    """Whether the gripper reaches ``p`` facing ``yaw``, pitched down at most
    ``max_pitch_deg`` (5 degree steps), with the wrist unflipped."""
    return any(
        unflipped_ik(make_T(rpy_to_R(0.0, math.radians(pitch), yaw), p), model.home, model)
        is not None
        for pitch in range(0, max_pitch_deg + 1, 5)
    )


def presentation_spot(
    T_base_cam: ArrayLike,
    intr: Intrinsics,
    radius: float,
    height: float,
    table_z: float,
    grasp_offset: float,
    obstacles: Sequence[Obstacle],
    present_distance: float,
    standoff: float,
    model: ArmModel,
    carry_z: float,
) -> Spot | None:
    """The spot on the table where the camera sees the bottle best; None if there is none.

    Candidates: :data:`SPOT_DISTANCES_M` from the base axis at :data:`SPOT_BEARINGS_RAD`. A
    candidate counts when (1) the bottle's projected box (:func:`bottle_box`) lies inside the
    image by :data:`IMAGE_MARGIN_PX` and its centre is at least :data:`MIN_RANGE_M` from the
    camera; (2) it is :data:`SPOT_CLEARANCE_M` clear of every obstacle; (3) no obstacle stands
    within :data:`SIGHT_MARGIN_M` of the line of sight from the camera to it (in plan view, so
    any height counts as blocking); (4) the open gripper's corridor from ``standoff`` short of
    it is clear (as the grasp requires); (5) the arm reaches, facing it from the base, the
    grasp pose ``grasp_offset`` above the table and the carry pose at ``carry_z`` with the
    gripper level (it holds the bottle there), and the back-off point (:data:`BACKOFF_MARGIN_M`
    behind the bottle) at the grasp height and :data:`HOVER_CLEARANCE_M` above the bottle,
    pitched down if need be. The best is the one whose distance from the camera is nearest
    ``present_distance``, then the one nearest the image centre, preferring those seen
    against bare table (:func:`_bare_background`).
    """
    T_base_cam = np.asarray(T_base_cam, dtype=float)
    T_cam_base = inv_T(T_base_cam)
    p_cam = T_base_cam[:3, 3]
    best: tuple[float, Spot] | None = None
    for d in SPOT_DISTANCES_M:
        for yaw in SPOT_BEARINGS_RAD:
            xy = np.array([d * math.cos(yaw), d * math.sin(yaw)])
            centre = np.array([xy[0], xy[1], table_z + 0.5 * height])
            distance = float(np.linalg.norm(centre - p_cam))
            if distance < MIN_RANGE_M or (T_cam_base[:3, :3] @ centre + T_cam_base[:3, 3])[2] <= 0:
                continue
            box = bottle_box(intr, T_cam_base, [xy[0], xy[1], table_z], radius, height)
            m = IMAGE_MARGIN_PX
            if box[0] < m or box[1] < m or box[2] > intr.width - m or box[3] > intr.height - m:
                continue
            if not _clear(xy, radius, yaw, float(d), standoff, p_cam[:2], obstacles):
                continue
            grasp_z = table_z + grasp_offset
            back = xy * max(d - radius - BACKOFF_MARGIN_M, 0.0) / d
            poses = (
                (xy, grasp_z, 0),
                (xy, carry_z, 0),
                (back, grasp_z, EMPTY_MAX_PITCH_DEG),
                (back, table_z + height + HOVER_CLEARANCE_M, EMPTY_MAX_PITCH_DEG),
            )
            if not all(_reachable([*p, z], yaw, pitch, model) for p, z, pitch in poses):
                continue
            centre_px = 0.5 * (box[0] + box[2]) - intr.ppx
            score = abs(distance - present_distance) + 0.05 * abs(centre_px) / intr.fx
            if not _bare_background(xy, radius, p_cam[:2], obstacles):
                score += CLUTTER_PENALTY
            if best is None or score < best[0]:
                best = (score, Spot((float(xy[0]), float(xy[1])), float(yaw), distance, box))
    return None if best is None else best[1]


def _clear(
    xy: Array,
    radius: float,
    yaw: float,
    d: float,
    standoff: float,
    cam_xy: Array,
    obstacles: Sequence[Obstacle],
) -> bool:
    """Conditions (2)-(4) of :func:`presentation_spot` for one candidate."""
    u = np.array([math.cos(yaw), math.sin(yaw)])
    corridor_start = u * max(d - standoff - 0.05, 0.0)
    for ob in obstacles:
        q = np.asarray(ob.xy, dtype=float)
        if np.linalg.norm(q - xy) < radius + ob.radius + SPOT_CLEARANCE_M:
            return False
        if _segment_distance(q, cam_xy, xy) < radius + ob.radius + SIGHT_MARGIN_M:
            return False
        if _segment_distance(q, corridor_start, xy) < GRIPPER_HALF_WIDTH_M + ob.radius:
            return False
    return True


def _bare_background(
    xy: Array, radius: float, cam_xy: Array, obstacles: Sequence[Obstacle]
) -> bool:
    """Whether the camera sees the bottle at ``xy`` against bare table: no obstacle within
    :data:`BACKGROUND_M` behind it stands in the strip the liquid meter compares the bottle
    with (1.6 radii each side of it, widening with distance as the view does), in plan view.
    """
    ray = xy - cam_xy
    length = float(np.linalg.norm(ray))
    u = ray / max(length, 1e-9)
    for ob in obstacles:
        rel = np.asarray(ob.xy, dtype=float) - cam_xy
        along = float(rel @ u)
        if not length < along < length + BACKGROUND_M + ob.radius:
            continue
        across = abs(float(rel[0] * u[1] - rel[1] * u[0]))
        if across < 1.6 * radius * along / length + ob.radius + SIGHT_MARGIN_M:
            return False
    return True


def measure_window(cfg: AnalyzeConfig, object_hz: float) -> float:
    """Seconds allowed for ``cfg.frames`` measurements: :data:`WINDOW_PERIODS_PER_FRAME`
    object-stage periods per frame, at least :data:`MIN_WINDOW_S`."""
    return max(MIN_WINDOW_S, WINDOW_PERIODS_PER_FRAME * cfg.frames / object_hz)


# --------------------------------------------------------------------------- the task


class _Abort(Exception):  # noqa: N818 - control flow inside this module
    """Ends the analysis with a reason (becomes AnalyzeResult.ok = False)."""


@dataclass
class _Samples:
    """Measurements of one bottle in distinct frames, oldest first."""

    levels: list[tuple[float, LiquidLevel]]
    box_heights: list[float]
    frames_seen: int
    last_error: str | None

    def estimate(self, track_id: int) -> LiquidEstimate | None:
        return average_levels(track_id, self.levels) if self.levels else None

    @property
    def box_height(self) -> float | None:
        return float(np.median(self.box_heights)) if self.box_heights else None


#: For one frame's state: (pixel box, geometry) to measure, or None if the bottle is not seen.
Target = Callable[[SystemState], tuple[Box, ContainerGeometry] | None]


class _Analyze:
    def __init__(self, ctx: TaskContext, track_id: int | None) -> None:
        self.ctx, self.cfg = ctx, ctx.config.analyze
        self.grab_cfg = ctx.config.grab
        self.track_id = track_id
        self.start = ctx.now()
        self.deadline = self.start + self.cfg.timeout_s
        self.track: TrackState | None = None
        self.anchor = np.zeros(3)  # the bottle's position at its track's newest detection
        self.picked = False
        self.where = "in its place"  # where the bottle is, for a failure's reason
        self.held: _Held | None = None
        self.position: tuple[float, float, float] | None = None  # where the grasp found it
        self.samples: _Samples | None = None  # the last measurement, and where it was made
        self.view: str | None = None
        self.last_T: Array | None = None  # the last pose commanded by this task

    # ------------------------------------------------------------ results and time

    def result(
        self,
        ok: bool,
        reason: str,
        samples: _Samples | None = None,
        view: str | None = None,
    ) -> AnalyzeResult:
        """The report; without ``samples`` those of the last measurement, if any."""
        if samples is None:
            samples, view = self.samples, self.view
        track = self.track
        est = None if samples is None or track is None else samples.estimate(track.id)
        return AnalyzeResult(
            ok=ok,
            reason=reason,
            track_id=None if track is None else track.id,
            fill=None if est is None else est.fill,
            fill_std=None if est is None else est.fill_std,
            colour=None if est is None else est.colour,
            colour_name=None if est is None else colour_name(est.colour),
            confidence=None if est is None else est.confidence,
            frames=0 if est is None else est.samples,
            picked=self.picked,
            position=self.position
            if self.position is not None or track is None
            else tuple(float(v) for v in track.p_base),
            box_height_px=None if samples is None else samples.box_height,
            view=view if est is not None else None,
            duration_s=self.ctx.now() - self.start,
        )

    def remaining(self) -> float:
        return self.deadline - self.ctx.now()

    def timed_out(self) -> bool:
        """Past the deadline (to within :data:`MIN_WAIT_S`)."""
        return self.remaining() < MIN_WAIT_S

    # ------------------------------------------------------------ finding and measuring

    def find_track(self) -> TrackState:
        def read() -> TrackState | None:
            state = self.ctx.state()
            if self.track_id is not None:
                track = state.track(self.track_id)
                return track if track is not None and track.label == "bottle" else None
            bottles = state.bottles()
            return bottles[0] if bottles else None

        wait = min(self.grab_cfg.track_wait_s, max(self.remaining(), 0.0))
        if not self.ctx.wait_until(lambda: read() is not None, wait):
            which = "any bottle" if self.track_id is None else f"bottle track {self.track_id}"
            raise _Abort(
                f"no confirmed track of {which} within {wait:.0f} s: is a bottle in the "
                "camera's view and is object detection on?"
            )
        track = read()
        assert track is not None
        return track

    def collect(self, target: Target, window_s: float) -> _Samples:
        """Measure ``target`` in up to ``analyze.frames`` distinct new frames of the object
        stage, for at most ``window_s`` (and not past the deadline)."""
        ctx, meter = self.ctx, self.ctx.system.liquid_meter
        since = ctx.now()
        end = min(since + window_s, self.deadline)
        seen: set[float] = set()
        samples = _Samples([], [], 0, None)

        def new_frame() -> RGBDFrame | None:
            frame = ctx.state().detections_frame
            if frame is None or frame.timestamp < since or frame.timestamp in seen:
                return None
            return frame

        while len(samples.levels) < self.cfg.frames:
            if not ctx.wait_until(lambda: new_frame() is not None, end - ctx.now()):
                break
            state = ctx.state()
            frame = state.detections_frame
            assert frame is not None
            seen.add(frame.timestamp)
            samples.frames_seen += 1
            job = target(state)
            if job is None:
                continue
            box, geometry = job
            try:
                level = meter.measure(frame, box, geometry)
            except PerceptionError as exc:
                samples.last_error = str(exc)
                continue
            samples.levels.append((frame.timestamp, level))
            samples.box_heights.append(box[3] - box[1])
        return samples

    def _detection_near(self, state: SystemState, p_base: Array) -> Detection | None:
        """The bottle detection of ``state`` nearest ``p_base``, within the association gate."""
        T = self.ctx.system.T_base_cam
        best, best_d = None, ASSOCIATION_M
        for det in state.detections:
            if det.label != "bottle":
                continue
            d = float(np.linalg.norm(T[:3, :3] @ det.center_cam + T[:3, 3] - p_base))
            if d <= best_d:
                best, best_d = det, d
        return best

    def follow(self, state: SystemState) -> Array:
        """Where the analysed bottle is: its track's position at the track's newest detection.

        While the track is seen (a detection within :data:`STALE_S`) it is followed; once it
        is gone or stale (the tracker may coast a badly started track away, then start a new
        one on the bottle) the fresh bottle track nearest the last position, within
        :data:`REACQUIRE_M`, takes its place. Updates ``self.track`` and ``self.anchor``.
        """
        assert self.track is not None
        track = state.track(self.track.id)
        if track is None or state.time - track.last_seen > STALE_S:
            fresh = [
                t
                for t in state.bottles()
                if state.time - t.last_seen <= STALE_S
                and np.linalg.norm(t.p_base - self.anchor) < REACQUIRE_M
            ]
            if fresh:
                track = min(fresh, key=lambda t: float(np.linalg.norm(t.p_base - self.anchor)))
        if track is not None and state.time - track.last_seen <= STALE_S:
            self.track, self.anchor = track, track.p_base.copy()
        return self.anchor

    def in_place_target(self) -> Target:
        def target(state: SystemState) -> tuple[Box, ContainerGeometry] | None:
            det = self._detection_near(state, self.follow(state))
            if det is None:
                return None
            return det.box, ContainerGeometry(tuple(det.center_cam), det.radius, det.height)

        return target

    def judge(self, samples: _Samples, check_box: bool) -> str | None:
        """Why the view is poor, or None if the measurements can be trusted."""
        n, wanted = len(samples.levels), self.cfg.frames
        if n < wanted:
            why = f"only {n} of {wanted} frames measured"
            if samples.frames_seen == 0:
                why += " (no new object detections: is object detection on?)"
            elif samples.last_error is not None:
                why += f" (last: {samples.last_error})"
            elif n == 0:
                why += " (the bottle was not detected)"
            return why
        est = samples.estimate(0)
        assert est is not None
        if est.confidence < self.cfg.min_confidence:
            return f"mean confidence {est.confidence:.2f} < {self.cfg.min_confidence:.2f}"
        box_h = samples.box_height
        if check_box and box_h is not None and box_h < self.cfg.min_box_height_px:
            return f"the bottle is {box_h:.0f} px tall < {self.cfg.min_box_height_px:.0f} px"
        return None

    # ------------------------------------------------------------ motion

    def pose(self, p: ArrayLike, yaw: float, max_pitch_deg: int = 0) -> tuple[Array, Array]:
        """(T_base_ee, q): the gripper at ``p`` facing ``yaw``, level if the arm reaches it so
        near the last commanded pose (wrist unflipped), else pitched down in 5 degree steps up
        to ``max_pitch_deg``; _Abort if neither."""
        arm = self.ctx.arm
        found = level_pose(p, yaw, motion_seed(arm, self.last_T), arm.model, max_pitch_deg)
        if found is not None:
            return found
        raise _Abort(
            f"the gripper cannot reach ({', '.join(f'{v:.3f}' for v in p)}) m facing "
            f"{math.degrees(yaw):.0f} degrees"
        )

    def move(self, what: str, T: Array, q: Array, duration: float) -> None:
        """One checked move taking at least ``duration`` (longer if a joint would exceed
        :data:`SPEED_FRACTION` of its velocity limit); _Abort with the arm's reason."""
        arm = self.ctx.arm
        duration = paced_time(arm, q, duration)
        if not self.ctx.move_pose(T, moving_time=duration, custom_guess=q):
            raise _Abort(f"{what}: {arm.last_error or 'the arm refused the move'}")
        self.last_T = T

    def straight(
        self, what: str, p_goal: ArrayLike, yaw_goal: float, max_pitch_deg: int = 0
    ) -> None:
        """From the last commanded pose straight to ``p_goal`` in segments of at most
        :data:`SEGMENT_M` at :data:`CARRY_SPEED_M_S`, the yaw turning evenly to ``yaw_goal``,
        each point as level as :meth:`pose` finds (one joint-space move near the table can
        sweep the gripper through what stands there)."""
        assert self.last_T is not None
        p_from = self.last_T[:3, 3].copy()
        yaw_from = _yaw(self.last_T)
        turn = (yaw_goal - yaw_from + math.pi) % (2 * math.pi) - math.pi
        p_goal = np.asarray(p_goal, dtype=float)
        length = float(np.linalg.norm(p_goal - p_from))
        n = max(1, math.ceil(length / SEGMENT_M), math.ceil(abs(turn) / math.radians(20.0)))
        for k in range(1, n + 1):
            s = k / n
            T, q = self.pose((1 - s) * p_from + s * p_goal, yaw_from + s * turn, max_pitch_deg)
            self.move(what, T, q, max(SEGMENT_TIME_S, length / n / CARRY_SPEED_M_S))

    def finger(self) -> float:
        return float(self.ctx.arm.gripper.get_finger_position())

    # ------------------------------------------------------------ the run

    def run(self) -> AnalyzeResult:
        ctx, cfg = self.ctx, self.cfg
        ctx.progress(0.02, "waiting for a confirmed bottle track")
        self.track = self.find_track()
        self.anchor = self.track.p_base.copy()
        ctx.progress(0.1, f"measuring bottle track {self.track.id} in place")
        window = measure_window(cfg, ctx.config.runtime.object_hz)
        samples = self.collect(self.in_place_target(), window)
        self.samples, self.view = samples, "in place"
        poor = self.judge(samples, check_box=True)
        if poor is None:
            return self.result(
                True, f"measured in place over {len(samples.levels)} frames", samples, "in place"
            )
        if not cfg.allow_pick:
            return self.result(
                False,
                f"the view in place is poor ({poor}) and analyze.allow_pick is off: move the "
                "bottle nearer the camera, or allow picking",
                samples,
                "in place",
            )
        if self.timed_out():
            return self.result(
                False, f"the view in place is poor ({poor}) and no time is left to present it"
            )
        return self.present(poor, samples)

    def present(self, poor: str, in_place: _Samples) -> AnalyzeResult:
        """Pick, stand at the presentation spot, measure, put back (the module doc's step 3)."""
        ctx, gcfg = self.ctx, self.grab_cfg
        state = ctx.state()
        self.follow(state)
        track = self.track
        assert track is not None
        # Other objects, not counting a second track of this same bottle.
        obstacles = [
            Obstacle(
                (float(t.p_base[0]), float(t.p_base[1])),
                float(t.radius) if t.radius is not None else 0.04,
                float(t.p_base[2] + 0.5 * (t.height if t.height is not None else 0.25)),
            )
            for t in state.tracks
            if np.linalg.norm(t.p_base - track.p_base) > ASSOCIATION_M
        ]
        ctx.progress(0.2, f"view poor ({poor}): picking the bottle to present it")
        grabbed: GrabResult = grab(ctx, track_id=track.id)
        if not grabbed.ok:
            return self.result(
                False,
                f"the view in place is poor ({poor}) and picking the bottle failed: "
                f"{grabbed.reason}",
                in_place,
                "in place",
            )
        self.picked = True
        self.where = "held by the gripper"
        held = self.held = _Held.from_grab(grabbed, self.finger(), track, obstacles, gcfg)
        self.position = grabbed.target
        self.last_T = np.asarray(ctx.arm.get_ee_pose(), dtype=float)
        spot = None
        if not self.timed_out():
            spot = presentation_spot(
                ctx.system.T_base_cam,
                ctx.camera.intrinsics,
                held.radius,
                held.height,
                held.table_z,
                held.grasp_offset,
                obstacles,
                self.cfg.present_distance,
                gcfg.standoff,
                ctx.arm.model,
                held.carry_z,
            )
        if spot is None:
            why = (
                f"timed out after {self.cfg.timeout_s:.0f} s"
                if self.timed_out()
                else "there is no free spot on the table where the arm can stand the bottle "
                "fully in the camera's view"
            )
            self.put_down(held.home_xy, "back in its place")
            self.go_safe()
            return self.result(
                False,
                f"the view in place is poor ({poor}) and {why}; the bottle is back in its place",
                in_place,
                "in place",
            )
        spot_xy = np.array(spot.xy)
        where = f"at ({spot.xy[0]:.2f}, {spot.xy[1]:.2f}) m, {spot.distance:.2f} m from the camera"
        ctx.progress(0.45, f"presenting the bottle {where}")
        self.put_down(spot_xy, f"standing where it was presented, {where}")

        ctx.progress(0.6, "measuring the presented bottle")
        samples = (
            self.collect(
                self.presented_target(spot_xy),
                measure_window(self.cfg, ctx.config.runtime.object_hz),
            )
            if not self.timed_out()
            else _Samples([], [], 0, "timed out before measuring")
        )
        self.samples, self.view = samples, "presented"

        ctx.progress(0.75, "putting the bottle back")
        self.pick_up(spot_xy)
        self.put_down(held.home_xy, "back in its place")
        self.go_safe()
        poor_presented = self.judge(samples, check_box=False)
        if poor_presented is not None:
            return self.result(
                False,
                f"the view in place was poor ({poor}) and still poor with the bottle presented "
                f"{where} ({poor_presented}); the bottle is back in its place",
                samples,
                "presented",
            )
        return self.result(
            True,
            f"the view in place was poor ({poor}); measured over {len(samples.levels)} frames "
            f"with the bottle presented {where}, then put it back",
            samples,
            "presented",
        )

    def presented_target(self, spot_xy: Array) -> Target:
        """Measuring the released bottle: its detection near the spot gives the centre (none:
        not measured; it may have fallen), the closed gripper the radius, the grasp the
        height; the box is projected from that geometry (:func:`bottle_box`), since the
        detector's box of a clear bottle is narrower than the bottle."""
        held, system = self.held, self.ctx.system
        assert held is not None
        T_base_cam = system.T_base_cam
        T_cam_base = inv_T(T_base_cam)
        intr = self.ctx.camera.intrinsics
        centre = np.array([spot_xy[0], spot_xy[1], held.table_z + 0.5 * held.height])

        def target(state: SystemState) -> tuple[Box, ContainerGeometry] | None:
            det = self._detection_near(state, centre)
            if det is None:
                return None
            c_base = T_base_cam[:3, :3] @ det.center_cam + T_base_cam[:3, 3]
            foot = [c_base[0], c_base[1], held.table_z]
            box = bottle_box(intr, T_cam_base, foot, held.radius, held.height)
            return box, ContainerGeometry(tuple(det.center_cam), held.radius, held.height)

        return target

    def put_down(self, xy: Array, where: str) -> None:
        """Carry the held bottle at the carry height to above ``xy``, stand it there, release
        it and :meth:`retreat`."""
        held = self.held
        assert held is not None and self.last_T is not None
        yaw = math.atan2(xy[1], xy[0])
        p = self.last_T[:3, 3]
        self.straight("lift for carrying", [p[0], p[1], held.carry_z], _yaw(self.last_T))
        self.straight("carry", [xy[0], xy[1], held.carry_z], yaw)
        self.straight("lower onto the table", [xy[0], xy[1], held.grasp_z + RELEASE_HEIGHT_M], yaw)
        self.ctx.open_gripper()
        self.where = where
        self.retreat(xy)

    def retreat(self, xy: Array) -> None:
        """From the grasp pose at ``xy``: back off toward the base until the fingertips are
        :data:`BACKOFF_MARGIN_M` clear of the bottle, then rise :data:`HOVER_CLEARANCE_M`
        above its top (out of the camera's view of it: behind and above it)."""
        held = self.held
        assert held is not None
        yaw, back = math.atan2(xy[1], xy[0]), self.backoff_point(xy)
        self.straight("back off", [back[0], back[1], held.grasp_z], yaw, EMPTY_MAX_PITCH_DEG)
        top = held.table_z + held.height + HOVER_CLEARANCE_M
        self.straight("rise", [back[0], back[1], top], yaw, EMPTY_MAX_PITCH_DEG)

    def pick_up(self, xy: Array) -> None:
        """Grasp the bottle standing where this task released it (retreat, reversed)."""
        held = self.held
        assert held is not None
        yaw, back = math.atan2(xy[1], xy[0]), self.backoff_point(xy)
        self.straight(
            "down behind the bottle", [back[0], back[1], held.grasp_z], yaw, EMPTY_MAX_PITCH_DEG
        )
        self.straight("approach", [xy[0], xy[1], held.grasp_z], yaw, EMPTY_MAX_PITCH_DEG)
        self.ctx.close_gripper()
        if self.finger() < self.ctx.arm.model.finger_limits[0] + GRASP_MARGIN_M:
            self.ctx.open_gripper()
            self.retreat(xy)
            raise _Abort("could not grasp the bottle again where it was presented")
        self.where = "held by the gripper"

    def backoff_point(self, xy: Array) -> Array:
        """(x, y) on the line to the base where the open fingertips clear the bottle at ``xy``."""
        assert self.held is not None
        d = float(np.linalg.norm(xy))
        return xy * max(d - self.held.radius - BACKOFF_MARGIN_M, 0.0) / max(d, 1e-9)

    def go_safe(self) -> None:
        """To the grasp's safe start pose, out of the camera's way."""
        arm = self.ctx.arm
        T_safe = safe_start_pose(self.grab_cfg.safe_pose, arm.model)
        q_safe, _ = ik(T_safe, arm.get_joint_positions(), arm.model)
        self.move("safe start pose", T_safe, q_safe, self.grab_cfg.moving_time)


def _yaw(T: Array) -> float:
    """Heading of a pose's x axis in the base's xy plane, rad."""
    return math.atan2(T[1, 0], T[0, 0])


@dataclass(frozen=True)
class _Held:
    """The picked bottle: its geometry, where it came from and how it is carried, metres."""

    radius: float
    height: float
    table_z: float
    grasp_offset: float
    carry_z: float
    home_xy: Array

    @property
    def grasp_z(self) -> float:
        return self.table_z + self.grasp_offset

    @staticmethod
    def from_grab(
        grabbed: GrabResult,
        finger: float,
        track: TrackState,
        obstacles: Sequence[Obstacle],
        gcfg: GrabConfig,
    ) -> _Held:
        """The radius from the closed fingers (the track's if implausible), height, table and
        grasp height from the grasp, the carry height above every obstacle."""
        assert grabbed.target is not None and grabbed.grasp_z is not None
        height = float(grabbed.height if grabbed.height is not None else 2.0 * grabbed.target[2])
        table_z = grabbed.target[2] - 0.5 * height
        grasp_offset = grabbed.grasp_z - table_z
        radius = finger - PAD_INSET_M
        if not RADIUS_RANGE_M[0] <= radius <= RADIUS_RANGE_M[1]:
            radius = float(track.radius or 0.03)
        tallest = max([table_z] + [ob.top for ob in obstacles])
        carry_z = max(tallest + CARRY_CLEARANCE_M + grasp_offset, grabbed.grasp_z + gcfg.lift)
        return _Held(
            radius, height, table_z, grasp_offset, carry_z, np.array(grabbed.target[:2], float)
        )


def analyze(ctx: TaskContext, track_id: int | None = None) -> AnalyzeResult:
    """Measure a bottle's liquid, presenting it to the camera if the view is poor (see the
    module docstring); ``track_id`` picks the bottle, else the nearest the base."""
    ctx.require_aim()
    job = _Analyze(ctx, track_id)
    try:
        return job.run()
    except _Abort as exc:
        where = f"; the bottle is {job.where}" if job.picked else ""
        return job.result(False, f"{exc}{where}")
