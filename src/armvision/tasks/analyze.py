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
   ``analyze.min_confidence``, when the meter could read no level in any of them (it says
   ``unknown``: a hidden body, an opaque wall; unknown frames count confidence 0 and are left
   out of the fill), or when the bottle's median box is shorter than
   ``analyze.min_box_height_px`` pixels. A bottle whose wall hides its liquid in every frame
   is not presented: no view would show it.
3. **Presented** (poor view and ``analyze.allow_pick``): the bottle is grasped and lifted
   (:func:`~armvision.tasks.grab.grab`), carried above everything else on the table, stood on
   the table at the :func:`~armvision.tasks.spots.presentation_spot`, released, and the
   gripper backs off and rises out of the way (:mod:`armvision.tasks.carry`); then it is
   measured as in 2, with the radius the closed gripper measured and the box projected from
   that geometry (:func:`~armvision.tasks.spots.bottle_box`); then it is grasped again where
   it was released, carried back, stood where it was and released, and the arm returns to the
   grasp's safe start pose. The presented result counts when enough frames came and their
   mean confidence reaches ``min_confidence`` (the box size is not judged again: the spot
   makes it as large as the arm and the field of view allow).

Detections are mapped into the base frame, and the spot and the presented box are worked out,
with the camera pose the system works with at that moment (``SystemState.T_base_cam``: the
calibration as the fusion loop refines it from the gripper tag), read anew at each use.

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
silhouette edges too far in. Closed on the bottle, each finger stands
:data:`~armvision.robot.vx300s.FINGER_PAD_INSET` outside the bottle's wall, so the finger position
gives the radius to ~1 mm.

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
the arm halts where it is, the gripper as it was). A carry the arm cannot make (a spot it
cannot reach holding the bottle as it was grasped) stands the bottle straight back where it
was taken, when the gripper is still above that spot
(:meth:`~armvision.tasks.carry.Carrier.stand_back`). The spot is chosen, and the bottle carried,
on the wrist branch the grasp left the arm on: a collision-aware grasp near the base may roll
the forearm half a turn, and then no spot in view may be reachable (``unpresented``; the sort
moves such a bottle with the place task's planner instead).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import RGBDFrame
from armvision.config import AnalyzeConfig
from armvision.errors import PerceptionError
from armvision.fusion.tracker import TrackState
from armvision.geometry import as_xyz, inv_T
from armvision.perception.detection import Detection
from armvision.perception.liquid import ContainerGeometry, LiquidLevel
from armvision.runtime.context import TaskContext
from armvision.runtime.state import ASSOCIATION_M, LiquidEstimate, SystemState, average_levels
from armvision.tasks.carry import Abort, Carrier, Held, grasp_pitch_deg
from armvision.tasks.colour import colour_name
from armvision.tasks.grab import GrabResult, grab, holding
from armvision.tasks.spots import Box, Obstacle, Spot, bottle_box, presentation_spot

Array = NDArray[np.float64]

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


@dataclass(frozen=True)
class AnalyzeResult:
    """What the analysis found. ``ok`` when a trustworthy measurement was made.

    ``fill`` 0..1 of the body's inner height (the meter's definition), ``fill_std`` the
    confidence-weighted spread of the frames (both None when the liquid could not be seen in
    any frame: ``reason`` says why, e.g. an opaque wall); ``colour`` the liquid's median RGB
    as seen (None when it looked empty) and ``colour_name`` the nearest
    :data:`~armvision.tasks.colour.COLOUR_PALETTE` name;
    ``confidence`` the frames' mean confidence 0..1; ``frames`` how many were averaged;
    ``picked`` whether the bottle was picked and presented; ``position`` the bottle's centre
    (x, y, z) in the base frame where it stood at the start (and stands again at the end);
    ``box_height_px`` its median box height in the frames averaged; ``view`` "in place" or
    "presented"; ``duration_s`` from start to end (clock seconds). When ``ok`` is False the
    numbers are those of the last measurement made, if any, and ``reason`` says what failed;
    ``pick_untouched`` then says the pick for the presentation failed before the gripper
    came to the bottle (:attr:`~armvision.tasks.grab.GrabResult.untouched`), ``unpresented``
    that the bottle was picked to be presented, but there was no spot for it or the arm could
    not carry it there, and it stands back in its place (the sort then moves it with the
    place task's planner: :meth:`~armvision.tasks.sort._Sort.measure_moved`).
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
    pick_untouched: bool = False
    unpresented: bool = False

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
            "pick_untouched": self.pick_untouched,
            "unpresented": self.unpresented,
        }


def measure_window(cfg: AnalyzeConfig, object_hz: float) -> float:
    """Seconds allowed for ``cfg.frames`` measurements: :data:`WINDOW_PERIODS_PER_FRAME`
    object-stage periods per frame, at least :data:`MIN_WINDOW_S`."""
    return max(MIN_WINDOW_S, WINDOW_PERIODS_PER_FRAME * cfg.frames / object_hz)


# --------------------------------------------------------------------------- the task


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
        self.carrier = Carrier(ctx, self.grab_cfg)  # the arm's moves once the bottle is picked
        self.position: tuple[float, float, float] | None = None  # where the grasp found it
        self.samples: _Samples | None = None  # the last measurement, and where it was made
        self.view: str | None = None
        self.pick_untouched = False  # the pick failed before the gripper came to the bottle
        self.stood_presented = False  # the bottle has stood at the presentation spot

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
            else as_xyz(track.p_base),
            box_height_px=None if samples is None else samples.box_height,
            view=view if est is not None else None,
            duration_s=self.ctx.now() - self.start,
            pick_untouched=self.pick_untouched,
            unpresented=not ok
            and self.picked
            and not self.stood_presented
            and self.carrier.where == "back in its place",
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
            raise Abort(
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
        """The bottle detection of ``state`` nearest ``p_base``, within the association gate
        (mapped into the base frame with the state's camera pose)."""
        T = state.T_base_cam
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
            return det.box, ContainerGeometry.of(det)

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
        if est.fill is None:
            return f"the liquid cannot be seen in any of the {n} frames ({est.unknown})"
        if est.confidence < self.cfg.min_confidence:
            return f"mean confidence {est.confidence:.2f} < {self.cfg.min_confidence:.2f}"
        box_h = samples.box_height
        if check_box and box_h is not None and box_h < self.cfg.min_box_height_px:
            return f"the bottle is {box_h:.0f} px tall < {self.cfg.min_box_height_px:.0f} px"
        return None

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
        if samples.levels and all(level.opaque for _, level in samples.levels):
            return self.result(
                False,
                f"the view in place is poor ({poor}): the bottle's wall hides its liquid, so "
                "no view will show it; not picked",
                samples,
                "in place",
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
        obstacles = self.other_objects()
        self.ctx.progress(0.2, f"view poor ({poor}): picking the bottle to present it")
        failed = self.pick(obstacles)
        if failed is not None:
            return self.result(
                False,
                f"the view in place is poor ({poor}) and picking the bottle failed: {failed}",
                in_place,
                "in place",
            )
        spot = None if self.timed_out() else self.choose_spot(obstacles)
        if spot is None:
            return self.no_spot(poor, in_place)
        where = f"at ({spot.xy[0]:.2f}, {spot.xy[1]:.2f}) m, {spot.distance:.2f} m from the camera"
        samples = self.measure_presented(np.array(spot.xy), where)
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

    def other_objects(self) -> list[Obstacle]:
        """Every tracked object but the analysed bottle (not counting a second track of this
        same bottle), as obstacles for carrying and for the choice of spot."""
        state = self.ctx.state()
        self.follow(state)
        track = self.track
        assert track is not None
        return [
            Obstacle(
                (float(t.p_base[0]), float(t.p_base[1])),
                float(t.radius) if t.radius is not None else 0.04,
                float(t.p_base[2] + 0.5 * (t.height if t.height is not None else 0.25)),
            )
            for t in state.tracks
            if np.linalg.norm(t.p_base - track.p_base) > ASSOCIATION_M
        ]

    def pick(self, obstacles: list[Obstacle]) -> str | None:
        """Grasp and lift the bottle (:func:`~armvision.tasks.grab.grab`) and note what is
        held; the grasp's reason if it failed, else None."""
        ctx, carrier, track = self.ctx, self.carrier, self.track
        assert track is not None
        # The scene as the camera saw it before the arm came: a carry below the height above
        # everything is checked against it (Carrier.lower_carry).
        carrier.scene, carrier.held_track = ctx.state().planning_scene, track.id
        grabbed: GrabResult = grab(ctx, track_id=track.id, allow_top=False)  # carried level
        if not grabbed.ok:
            self.pick_untouched = grabbed.untouched
            return grabbed.reason
        self.picked = True
        carrier.where = "held by the gripper"
        carrier.T_base_ee_last = np.asarray(ctx.arm.get_ee_pose(), dtype=float)
        carrier.grasp_yaw = float(
            np.arctan2(carrier.T_base_ee_last[1, 0], carrier.T_base_ee_last[0, 0])
        )
        carrier.held = Held.from_grab(
            grabbed,
            carrier.finger(),
            track,
            [ob.top for ob in obstacles],
            self.grab_cfg,
            grasp_pitch_deg(carrier.T_base_ee_last),
        )
        self.position = grabbed.target
        return None

    def choose_spot(self, obstacles: list[Obstacle]) -> Spot | None:
        """The :func:`~armvision.tasks.spots.presentation_spot` for the held bottle, seen with
        the camera pose the system works with now and reached on the wrist branch the grasp
        left the arm on; one whose carry height above everything is out of reach only if no
        other is (:meth:`~armvision.tasks.carry.Carrier.put_down` then carries it lower)."""
        ctx, held = self.ctx, self.carrier.held
        assert held is not None
        q_now = np.asarray(ctx.arm.get_joint_positions(), dtype=float)
        lowest = held.grasp_z + self.grab_cfg.lift
        for carry_z in dict.fromkeys((held.carry_z, min(held.carry_z, lowest))):
            spot = presentation_spot(
                ctx.state().T_base_cam,
                ctx.camera.intrinsics,
                held.radius,
                held.height,
                held.table_z,
                held.grasp_offset,
                obstacles,
                self.cfg.present_distance,
                self.grab_cfg.standoff,
                ctx.arm.model,
                carry_z,
                held.pitch_deg,
                q_now,
            )
            if spot is not None:
                return spot
        return None

    def no_spot(self, poor: str, in_place: _Samples) -> AnalyzeResult:
        """Nowhere to present the held bottle (or no time left): put it back, say why."""
        held = self.carrier.held
        assert held is not None
        why = (
            f"timed out after {self.cfg.timeout_s:.0f} s"
            if self.timed_out()
            else "there is no free spot on the table where the arm can stand the bottle "
            "fully in the camera's view"
        )
        self.carrier.put_down(held.home_xy, "back in its place", self.carrier.grasp_yaw)
        self.carrier.go_safe()
        return self.result(
            False,
            f"the view in place is poor ({poor}) and {why}; the bottle is back in its place",
            in_place,
            "in place",
        )

    def measure_presented(self, spot_xy: Array, where: str) -> _Samples:
        """Stand the held bottle at ``spot_xy``, measure it there, then put it back in its
        place and go to the safe start pose; the measurements (none if time ran out)."""
        ctx, carrier = self.ctx, self.carrier
        held = carrier.held
        assert held is not None
        ctx.progress(0.45, f"presenting the bottle {where}")
        carrier.put_down(spot_xy, f"standing where it was presented, {where}")
        self.stood_presented = True

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
        carrier.pick_up(spot_xy)
        carrier.put_down(held.home_xy, "back in its place", carrier.grasp_yaw)
        carrier.go_safe()
        return samples

    def presented_target(self, spot_xy: Array) -> Target:
        """Measuring the released bottle: its detection near the spot gives the centre (none:
        not measured; it may have fallen), the closed gripper the radius, the grasp the
        height; the box is projected from that geometry
        (:func:`~armvision.tasks.spots.bottle_box`, with the state's camera pose), since the
        detector's box of a clear bottle is narrower than the bottle."""
        held = self.carrier.held
        assert held is not None
        intr = self.ctx.camera.intrinsics
        centre = np.array([spot_xy[0], spot_xy[1], held.table_z + 0.5 * held.height])

        def target(state: SystemState) -> tuple[Box, ContainerGeometry] | None:
            det = self._detection_near(state, centre)
            if det is None:
                return None
            T_base_cam = state.T_base_cam  # this frame's camera pose, as fusion refines it
            T_cam_base = inv_T(T_base_cam)
            c_base = T_base_cam[:3, :3] @ det.center_cam + T_base_cam[:3, 3]
            foot = [c_base[0], c_base[1], held.table_z]
            box = bottle_box(intr, T_cam_base, foot, held.radius, held.height)
            return box, ContainerGeometry.of(det, held.radius, held.height)

        return target


def analyze(ctx: TaskContext, track_id: int | None = None) -> AnalyzeResult:
    """Measure a bottle's liquid, presenting it to the camera if the view is poor (see the
    module docstring); ``track_id`` picks the bottle, else the nearest the base."""
    ctx.require_aim()
    job = _Analyze(ctx, track_id)
    try:
        return job.run()
    except Abort as exc:
        if job.picked and holding(ctx.arm):
            # The carry could not be made (a spot out of reach held level): stand the bottle
            # back where it was taken if the arm has not left it, rather than keep holding it.
            with contextlib.suppress(Abort):
                job.carrier.stand_back()
        where = f"; the bottle is {job.carrier.where}" if job.picked else ""
        return job.result(False, f"{exc}{where}")
