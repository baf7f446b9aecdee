"""Sort the bottles on the table into zones by what is in them: ``sort(by="fill" | "colour")``.

The rule (:class:`SortRule`, from ``sort`` in the configuration unless ``rule`` says
otherwise): by fill, a bottle measured below the threshold goes to the zone ``below``
(default ``empty``), any other to ``above`` (``full``); by colour, to the zone the liquid's
colour name maps to (``"*"`` for any other colour; a colour without a zone is skipped). Every
zone named must exist in ``place.zones``; a bad rule fails before anything moves.

One bottle after the other, until none is left to look at:

1. **The next bottle**: of the confirmed bottle tracks not standing in a zone and not yet
   handled (a handled bottle is remembered by where it stood), the one nearest the camera
   (taking the front ones first uncovers those behind them). With none left, it looks
   again once after :data:`SETTLE_S` (a bottle just uncovered needs a few frames to be
   confirmed), then tries the refused ones again (step 4) and, if that moved any, looks for
   the bottles they uncovered.
2. **Measure** it with the analyze task (:func:`~armvision.tasks.analyze.analyze`: in place,
   or picked and presented when the view is poor, then put back). No trustworthy fill (an
   opaque wall, a hidden body: the meter says ``unknown``) or no colour name: skipped, with
   the reason. A bottle the analysis picked but could not carry to a presentation spot (its
   carrying moves keep the bottle as the grasp took it; near the base a grasp may leave the
   arm where no spot in view is reachable so) is taken once more and set down with the
   place task's planner on the best presentation spot that planner reaches, then measured
   and sorted from there (:meth:`_Sort.measure_moved`).
3. **Choose the zone** by the rule; check before the grasp that the zone has a free spot for
   a bottle of the track's size (else skipped: "zone full").
4. **Grab** it (:func:`~armvision.tasks.grab.grab`, collision-aware, from the side, or from
   above if the arm can carry it so to the zone). A refusal leaves the bottle untouched and
   it is skipped as unreachable, with the planner's reason, for now: once the other bottles
   have been looked at, each refused one is tried again if some bottle has been set down
   since its refusal (a neighbour taken away may free an approach), at most
   :data:`MAX_TRIES` grasps in all. A bottle whose pick for the measurement was refused
   waits the same way. When no bottle has been set down since any refusal, a refused bottle
   that, held by the cap, would have to be lifted over its neighbours higher than the arm
   reaches pointing down (a cluster of bottles or canisters as tall as it) is **set aside**
   (once): taken from above, slid out of the cluster at the height it was lifted to, its
   own body kept clear of every other body (:func:`~armvision.tasks.place.plan_set_down`
   with ``low``), set down on the first free spot of :func:`aside_candidates` (10-16 cm
   away, nearest the base first) and taken from there; with no such spot it is stood back
   where it was and waits again. A bottle whose pick for the measurement was refused is set
   aside the same way, then measured there.
5. **Place** it on a free spot of the zone (:class:`~armvision.tasks.place.Placer`: the
   analyze task's carrying moves, then the check of where it stands). Should the zone have
   no spot for the bottle as the fingers measured it, it is put back where it stood.

The report (:class:`SortResult`) lists per bottle what was done: ``placed`` (with the place
check), ``skipped`` (why) or ``failed`` (why, and where the bottle is). ``ok`` when no bottle
failed. Stop ends the sort at once: every wait is the task context's, so TaskStopped
propagates and the arm halts where it is.

Units: metres; positions in the base frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from armvision.config import Config
from armvision.fusion.tracker import TrackState
from armvision.runtime.context import TaskContext, TaskError
from armvision.runtime.planning_scene import PlanningScene
from armvision.tasks.analyze import AnalyzeResult, analyze
from armvision.tasks.carry import CARRY_CLEARANCE_M, Held, held_obstacles
from armvision.tasks.colour import COLOUR_PALETTE
from armvision.tasks.grab import GrabResult, grab
from armvision.tasks.grasp_plan import TOP_BELOW_M
from armvision.tasks.place import (
    PlaceError,
    Placer,
    SetDown,
    holding,
    reachable,
    zone_rect,
    zone_spot,
)
from armvision.tasks.spots import Obstacle, presentation_spots

Array = NDArray[np.float64]

#: A bottle whose presentation the analysis could not carry is set down on the first of this
#: many presentation spots the place planner finds a way to (each is planned in full).
MAX_SHOW_SPOTS = 40
#: A bottle track this near where a handled bottle stood is that bottle, m.
SAME_BOTTLE_M = 0.06
#: The sort looks at no more bottles than this (a tracker that keeps making new tracks
#: cannot keep it going).
MAX_BOTTLES = 12
#: Before the first bottle, the sort waits this long for tracks to settle, s.
SETTLE_S = 1.0
#: A bottle whose grasp is refused is tried at most this many times in all.
MAX_TRIES = 3
#: Setting a bottle aside (out of a cluster): the distances from where it stood tried, m
#: (its neighbours stand 1-3 cm from it; the side grasp wants ~3 cm all round), and the
#: headings tried at each.
ASIDE_DISTANCES_M = (0.1, 0.13, 0.16)
ASIDE_HEADINGS = 16


@dataclass(frozen=True)
class SortRule:
    """Which zone a measurement chooses (the module docstring)."""

    by: Literal["fill", "colour"]
    threshold: float = 0.3
    below: str = "empty"
    above: str = "full"
    colours: Mapping[str, str] = field(default_factory=dict)

    @staticmethod
    def make(config: Config, by: str | None, rule: Mapping[str, Any] | None) -> SortRule:
        """The rule from ``sort`` in ``config``, ``by`` and ``rule`` overriding it (keys
        ``threshold``, ``below``, ``above`` for fill; colour name to zone for colour);
        TaskError with what is wrong."""
        cfg = config.sort
        by = cfg.by if by is None else by
        if by not in ("fill", "colour"):
            raise TaskError(f"sort by 'fill' or 'colour', not {by!r}")
        rule = dict(rule or {})
        if by == "fill":
            unknown = sorted(set(rule) - {"threshold", "below", "above"})
            if unknown:
                raise TaskError(
                    f"a fill rule has the keys threshold, below, above, not {', '.join(unknown)}"
                )
            threshold = rule.get("threshold", cfg.fill_threshold)
            if isinstance(threshold, bool) or not isinstance(threshold, (int, float)):
                raise TaskError(f"the fill threshold must be a number 0..1, not {threshold!r}")
            if not 0.0 < float(threshold) < 1.0:
                raise TaskError(f"the fill threshold must be between 0 and 1, not {threshold}")
            made = SortRule(
                "fill",
                float(threshold),
                str(rule.get("below", cfg.below)),
                str(rule.get("above", cfg.above)),
            )
            zones = [made.below, made.above]
        else:
            colours = {str(k): str(v) for k, v in (rule or cfg.colours).items()}
            if not colours:
                raise TaskError(
                    "sorting by colour needs a rule: colour name to zone (sort.colours, e.g. "
                    '{"light blue" = "empty", "*" = "full"})'
                )
            bad = sorted(c for c in colours if c != "*" and c not in COLOUR_PALETTE)
            if bad:
                raise TaskError(
                    f"unknown colour name {bad[0]!r}: names are {', '.join(COLOUR_PALETTE)} or '*'"
                )
            made = SortRule("colour", colours=colours)
            zones = list(colours.values())
        for zone in zones:
            zone_rect(config, zone)  # PlaceError (a TaskError) names the zones there are
        return made

    def zone_for(self, measured: AnalyzeResult) -> tuple[str | None, str]:
        """(zone, why) for a measurement; zone None (skipped) with the reason."""
        if self.by == "fill":
            if measured.fill is None:
                return None, "unknown fill"
            pct = 100 * measured.fill
            if measured.fill < self.threshold:
                return self.below, f"fill {pct:.0f} % < {100 * self.threshold:.0f} %"
            return self.above, f"fill {pct:.0f} % >= {100 * self.threshold:.0f} %"
        name = measured.colour_name
        if name is None:
            return None, "no liquid colour seen"
        zone = self.colours.get(name, self.colours.get("*"))
        if zone is None:
            return None, f"no zone for the colour {name!r}"
        return zone, f"colour {name}"

    def to_dict(self) -> dict[str, Any]:
        if self.by == "fill":
            return {
                "by": "fill",
                "threshold": self.threshold,
                "below": self.below,
                "above": self.above,
            }
        return {"by": "colour", "colours": dict(self.colours)}


@dataclass
class BottleReport:
    """What the sort did with one bottle: ``action`` placed / skipped / failed / in zone."""

    track_id: int
    start: tuple[float, float]
    action: str = "skipped"
    reason: str = ""
    fill: float | None = None
    colour_name: str | None = None
    zone: str | None = None
    place: dict[str, Any] | None = None
    picked: bool = False  # the analysis picked it to present it (and put it back)
    tries: int = 1  # grasps tried (a refused one is tried again after others moved)
    aside: tuple[float, float] | None = None  # where it was set aside (out of a cluster, or
    # where the camera sees it, its presentation out of the analysis's reach)

    def to_dict(self) -> dict[str, Any]:
        return {
            "track_id": self.track_id,
            "picked": self.picked,
            "tries": self.tries,
            "start": [round(v, 4) for v in self.start],
            "aside": None if self.aside is None else [round(v, 4) for v in self.aside],
            "action": self.action,
            "reason": self.reason,
            "fill": None if self.fill is None else round(self.fill, 4),
            "colour_name": self.colour_name,
            "zone": self.zone,
            "place": self.place,
        }


@dataclass(frozen=True)
class SortResult:
    """The sort's report: per bottle (:class:`BottleReport`), ``ok`` when none failed."""

    ok: bool
    reason: str
    rule: SortRule
    bottles: tuple[BottleReport, ...]
    duration_s: float

    def to_dict(self) -> dict[str, Any]:
        counts = {
            a: sum(b.action == a for b in self.bottles) for a in ("placed", "skipped", "failed")
        }
        return {
            "ok": self.ok,
            "reason": self.reason,
            "rule": self.rule.to_dict(),
            **counts,
            "bottles": [b.to_dict() for b in self.bottles],
            "duration_s": round(self.duration_s, 3),
        }


def _in_fingers(ctx: TaskContext) -> bool:
    """Whether anything is in the fingers (with the narrower margin of a grasp from above:
    a cap counts)."""
    return holding(ctx, from_above=True)


def in_zone(config: Config, xy: Array) -> str | None:
    """The zone whose rectangle holds ``xy``, or None."""
    for name, (x0, y0, x1, y1) in config.place.zones.items():
        if x0 <= xy[0] <= x1 and y0 <= xy[1] <= y1:
            return name
    return None


@dataclass
class _Waiting:
    """A bottle refused before the arm reached it: its report, the zone its measurement chose
    (None: its pick for the measurement was refused), why, and how many bottles had been
    set down by then."""

    report: BottleReport
    zone: str | None
    why: str
    moved: int


class _Sort:
    def __init__(self, ctx: TaskContext, rule: SortRule) -> None:
        self.ctx, self.rule = ctx, rule
        self.start = ctx.now()
        self.reports: list[BottleReport] = []
        self.waiting: list[_Waiting] = []
        self.aside_tried: set[int] = set()  # reports (by track id) a set-aside was tried for

    def handled(self, track: TrackState) -> bool:
        return any(
            math.dist(r.start, track.p_base[:2]) < SAME_BOTTLE_M
            or (
                r.place is not None
                and r.place.get("asked") is not None
                and math.dist(r.place["asked"], track.p_base[:2]) < SAME_BOTTLE_M
            )
            for r in self.reports
        )

    def next_bottle(self) -> TrackState | None:
        state = self.ctx.state()
        cam = state.T_base_cam[:3, 3]
        left = [
            t
            for t in state.bottles()
            if t.height is not None
            and in_zone(self.ctx.config, t.p_base[:2]) is None
            and not self.handled(t)
        ]
        return min(left, key=lambda t: float(np.linalg.norm(t.p_base - cam)), default=None)

    def run(self) -> SortResult:
        ctx = self.ctx
        ctx.progress(0.01, "waiting for the bottles' tracks")
        ctx.wait_until(lambda: bool(ctx.state().bottles()), ctx.config.grab.track_wait_s)
        ctx.sleep(SETTLE_S)
        looked_again = False
        while len(self.reports) < MAX_BOTTLES:
            track = self.next_bottle()
            if track is None and not looked_again:
                # A bottle the last one moved uncovered needs a few frames to be confirmed.
                looked_again = True
                ctx.sleep(SETTLE_S)
                continue
            if track is None:
                moved = self.moved()
                if not self.retry_waiting():
                    return self.result()  # the bottle still in the gripper
                if self.moved() == moved:
                    break  # nothing moved: nothing new can have been uncovered
                looked_again = False  # the bottles moved may have hidden others: look again
                continue
            looked_again = False
            report = BottleReport(track.id, (float(track.p_base[0]), float(track.p_base[1])))
            self.reports.append(report)
            self.handle(track, report)
            if report.action == "failed" and _in_fingers(ctx):
                report.reason += "; the sort ends here, the bottle still in the gripper"
                return self.result()
        if len(self.reports) >= MAX_BOTTLES:
            self.retry_waiting()  # no more new bottles, but the refused ones get their tries
        return self.result()

    def progress(self, step: float, message: str) -> None:
        n = len(self.reports)
        self.ctx.progress(min(0.95, 0.05 + 0.15 * (n - 1) + 0.15 * step), message)

    def handle(self, track: TrackState, report: BottleReport) -> None:
        ctx, rule = self.ctx, self.rule
        self.progress(0.0, f"bottle {len(self.reports)} (track {track.id}): measuring it")
        measured = analyze(ctx, track_id=track.id)
        report.fill, report.colour_name = measured.fill, measured.colour_name
        report.picked = measured.picked
        if not measured.ok:
            report.reason = f"not measured: {measured.reason}"
            if measured.picked and _in_fingers(ctx):
                report.action = "failed"  # the analysis could not put it back
            elif measured.pick_untouched:
                self.wait(report, None, "")  # its pick was refused: try again later
            elif measured.unpresented and report.aside is None:
                self.measure_moved(np.asarray(measured.position or track.p_base), report)
            return
        zone, why = rule.zone_for(measured)
        if zone is None:
            report.reason = why
            return
        report.zone = zone
        # Where it stands now (a presented bottle was put back, as a new track).
        where = np.array(measured.position[:2] if measured.position else track.p_base[:2])
        now = self.track_near(where)
        if now is None:
            report.reason = f"{why}: its track was lost after the measurement"
            return
        self.take(now, report, zone, why)

    def take(
        self, now: TrackState, report: BottleReport, zone: str, why: str, aside: bool = False
    ) -> None:
        """Grab the measured bottle (track ``now``) and place it in ``zone``; ``aside``: if
        every approach from the side is refused and it cannot be carried to the zone held by
        the cap, set it aside first (:meth:`set_aside`)."""
        ctx = self.ctx
        if in_zone(ctx.config, now.p_base[:2]) == zone:
            report.action, report.reason = "in zone", f"{why}: already in {zone!r}"
            return
        if self.spot_for(now, zone) is None:
            report.reason = f"{why}, but zone {zone!r} has no free spot for it"
            return
        self.progress(0.5, f"bottle {len(self.reports)}: {why}, taking it to {zone!r}")
        before = ctx.state().planning_scene  # its neighbours, before the arm hides them
        # From above only if the arm can also carry it so to the zone: held by the cap, it
        # hangs a body's height lower, and must clear its neighbours' tops.
        top_ok = self.spot_for(now, zone, from_above=True) is not None
        grabbed = grab(ctx, track_id=now.id, allow_top=top_ok)
        if aside and not grabbed.ok and grabbed.untouched and not top_ok:
            # Every approach from the side is blocked, and held by the cap it cannot be
            # carried to the zone: taken so, it is set aside nearby, then taken from there.
            grabbed = grab(ctx, track_id=now.id, allow_top=True)
            if grabbed.ok and grabbed.from_above:
                moved = self.set_aside(now, grabbed, before, report, zone, why)
                if moved is not None:
                    self.take(moved, report, zone, f"{why} (set aside first, out of its cluster)")
                return
        if not grabbed.ok:
            report.reason = f"{why}, but it cannot be taken: {grabbed.reason}"
            if _in_fingers(ctx):
                report.action = "failed"  # something stays in the fingers
            elif grabbed.untouched:  # refused before it reached the bottle
                self.wait(report, zone, why)
            return
        placer = self.placer(now, grabbed, before)
        try:
            plan = placer.choose(None, None, zone)
        except PlaceError as exc:
            self.put_back(placer, report, f"{why}, but {exc}")
            return
        self.progress(0.75, f"bottle {len(self.reports)}: setting it down in {zone!r}")
        placed = placer.set_down(plan, zone)
        report.place = placed.to_dict()
        report.action = "placed" if placed.released else "failed"
        report.reason = f"{why}: {placed.reason}"
        if report.tries > 1:
            report.reason += f" (try {report.tries}, after other bottles were moved)"

    def placer(self, track: TrackState, grabbed: GrabResult, before: PlanningScene) -> Placer:
        """The set-downs of the bottle ``track`` just grabbed: held as the fingers closed on
        it, carried above every other object's top, planned against the scene ``before``
        the grasp (whose tracks the arm did not hide)."""
        ctx = self.ctx
        tops = [b.top for b in ctx.state().planning_scene.obstacles(track.id)]
        finger = float(ctx.arm.gripper.get_finger_position())
        held = Held.from_grab(grabbed, finger, track, tops, ctx.config.grab)
        return Placer(ctx, held, track.id, before)

    def set_aside(
        self,
        track: TrackState,
        grabbed: GrabResult,
        before: PlanningScene,
        report: BottleReport,
        zone: str | None,
        why: str,
    ) -> TrackState | None:
        """The bottle ``track``, just grabbed (from above), slid out of its cluster at the
        height it was lifted to and set down on the first free spot of
        :func:`aside_candidates`: its track there. None when it was not set aside (the
        report says why): no spot (stood back where it was, and waiting again for ``zone``,
        None: to be measured), or it could not be set down or found there."""
        ctx = self.ctx
        placer = self.placer(track, grabbed, before)
        held = placer.held
        scene, obstacles = placer.scene()
        last = "no spot"
        for xy in aside_candidates(held.home_xy):
            if in_zone(ctx.config, xy) is not None:
                continue
            plan = placer.plan(xy, scene, obstacles, low=True)
            if isinstance(plan, SetDown):
                break
            last = plan
        else:
            self.put_back(placer, report, f"{why}, but it cannot be set aside ({last})", low=True)
            if report.action != "failed":
                self.wait(report, zone, why)  # back in its place: another bottle may free it
            return None
        self.progress(0.6, f"bottle {len(self.reports)}: setting it aside, out of its cluster")
        aside = placer.set_down(plan, None)
        report.aside = (float(plan.spot[0]), float(plan.spot[1]))
        if not aside.released:
            report.action, report.reason = "failed", f"{why}; setting it aside: {aside.reason}"
            return None
        moved = self.track_near(plan.spot)
        if moved is None:
            report.reason = f"{why}: set aside, but its track was lost there"
        return moved

    def measure_aside(self, track: TrackState, report: BottleReport) -> None:
        """A bottle whose pick for its measurement was refused (hidden in a cluster, every
        approach from the side blocked): taken from above, set aside (:meth:`set_aside`),
        then measured and sorted from there (:meth:`handle`)."""
        ctx = self.ctx
        before = ctx.state().planning_scene
        grabbed = grab(ctx, track_id=track.id, allow_top=True)
        if not grabbed.ok:
            report.reason = f"not measured: it cannot be taken to be set aside: {grabbed.reason}"
            if _in_fingers(ctx):
                report.action = "failed"
            return
        moved = self.set_aside(track, grabbed, before, report, None, "to be measured")
        if moved is not None:
            self.handle(moved, report)

    def measure_moved(self, where: Array, report: BottleReport) -> None:
        """A bottle the analysis picked to present, but could not carry (no spot it reaches
        with the bottle held as the grasp took it, or a carry out of reach; it stands back at
        ``where``): taken again and set down with the place task's planner, which keeps the
        wrist branch the grasp chose and checks every move against the scene, on the best
        :func:`~armvision.tasks.spots.presentation_spots` spot it can reach, then measured and
        sorted from there (:meth:`handle`). Once per bottle (``report.aside``)."""
        ctx = self.ctx
        track = self.track_near(where[:2])
        if track is None:
            report.reason += "; its track was lost after it was put back"
            return
        before = ctx.state().planning_scene
        grabbed = grab(ctx, track_id=track.id, allow_top=False)
        if not grabbed.ok:
            report.reason += f"; taken to be shown to the camera elsewhere: {grabbed.reason}"
            if _in_fingers(ctx):
                report.action = "failed"
            return
        placer = self.placer(track, grabbed, before)
        held = placer.held
        scene, obstacles = placer.scene()
        spots = presentation_spots(
            ctx.state().T_base_cam,
            ctx.camera.intrinsics,
            held.radius,
            held.height,
            held.table_z,
            held.grasp_offset,
            [Obstacle(b.xy, b.radius, b.top) for b in obstacles],
            ctx.config.analyze.present_distance,
            ctx.config.grab.standoff,
            None,
            held.carry_z,
        )
        why = "no spot in the camera's full view"
        for spot in spots[:MAX_SHOW_SPOTS]:
            xy = np.asarray(spot.xy, dtype=float)
            if in_zone(ctx.config, xy) is not None:
                continue
            plan = placer.plan(xy, scene, obstacles)
            if isinstance(plan, SetDown):
                break
            why = plan
        else:
            self.put_back(placer, report, f"{report.reason}; it cannot be shown elsewhere ({why})")
            return
        self.progress(0.4, f"bottle {len(self.reports)}: setting it down where the camera sees it")
        shown = placer.set_down(plan, None)
        report.aside = (float(plan.spot[0]), float(plan.spot[1]))
        if not shown.released:
            report.action, report.reason = "failed", f"{report.reason}; moving it: {shown.reason}"
            return
        moved = self.track_near(plan.spot)
        if moved is None:
            report.reason += "; set down where the camera sees it, but its track was lost there"
            return
        self.handle(moved, report)

    def wait(self, report: BottleReport, zone: str | None, why: str) -> None:
        """Keep a bottle whose grasp was refused before anything moved (its neighbours block
        every approach) for another try once some other bottle has been moved (or, when none
        can be, to be set aside)."""
        self.waiting.append(_Waiting(report, zone, why, self.moved()))

    def moved(self) -> int:
        """How many bottles the sort has set down so far (each changes the scene)."""
        return sum(r.action == "placed" for r in self.reports)

    def retry_waiting(self) -> bool:
        """Try each refused bottle again while some other bottle has been moved since its
        refusal (a neighbour taken away may free an approach); a bottle is tried at most
        :data:`MAX_TRIES` times. False when the sort must end (a bottle stays in the
        gripper)."""
        ctx = self.ctx
        while True:
            ready = [w for w in self.waiting if w.moved < self.moved()]
            aside = not ready
            if aside:  # nothing moved since: set aside what no neighbour's going will free
                ready = [w for w in self.waiting if w.report.track_id not in self.aside_tried]
            if not ready:
                return True
            waiting = ready[0]
            self.waiting.remove(waiting)
            report = waiting.report
            if report.tries >= MAX_TRIES:
                continue
            report.tries += 1
            track = self.track_near(np.array(report.start))
            if track is None:
                report.reason += "; its track was lost before another try"
                continue
            if aside:
                self.aside_tried.add(report.track_id)
            if waiting.zone is None:
                (self.measure_aside if aside else self.handle)(track, report)
            else:
                self.take(track, report, waiting.zone, waiting.why, aside=aside)
            if report.action == "failed" and _in_fingers(ctx):
                report.reason += "; the sort ends here, the bottle still in the gripper"
                return False

    def put_back(self, placer: Placer, report: BottleReport, why: str, low: bool = False) -> None:
        """Stand the held bottle back where it came from; ``low``: first try sliding it back
        at the height it is held at (taken from above out of a cluster, it cannot be lifted
        over its neighbours), then as any set-down."""
        home = placer.held.home_xy
        plan = None
        for slide in (True, False) if low else (False,):
            try:
                plan = placer.choose(float(home[0]), float(home[1]), None, False, slide)
                break
            except PlaceError as exc:
                error = exc
        if plan is None:
            report.action, report.reason = "failed", f"{why}; it cannot be put back: {error}"
            return
        back = placer.set_down(plan, None)
        if back.released:
            report.reason = f"{why}; put back in its place"
        else:
            report.action, report.reason = "failed", f"{why}; putting it back: {back.reason}"

    def track_near(self, xy: Array) -> TrackState | None:
        """The bottle track nearest ``xy`` within :data:`SAME_BOTTLE_M` (waited for)."""

        def find() -> TrackState | None:
            near = [
                t
                for t in self.ctx.state().bottles()
                if t.height is not None and np.linalg.norm(t.p_base[:2] - xy) < SAME_BOTTLE_M
            ]
            return min(near, key=lambda t: float(np.linalg.norm(t.p_base[:2] - xy)), default=None)

        self.ctx.wait_until(lambda: find() is not None, self.ctx.config.grab.track_wait_s)
        return find()

    def spot_for(self, track: TrackState, zone: str, from_above: bool = False) -> Array | None:
        """A free spot in ``zone`` for a bottle of ``track``'s size, before it is grasped (from
        above if ``from_above``: then the arm must also reach the carry height above where it
        stands, pointing down)."""
        ctx = self.ctx
        cfg, gcfg = ctx.config.place, ctx.config.grab
        height = float(track.height or 0.2)
        radius = float(track.radius or 0.03)
        table_z = float(track.p_base[2]) - 0.5 * height
        state = ctx.state()
        tops = [b.top for b in state.planning_scene.obstacles(track.id)]
        offset = height - TOP_BELOW_M if from_above else gcfg.grasp_height_fraction * height
        carry_z = max(
            max([table_z, *tops]) + CARRY_CLEARANCE_M + offset, table_z + offset + gcfg.lift
        )
        home = np.array(track.p_base[:2])
        held = Held(radius, height, table_z, offset, carry_z, home, from_above=from_above)
        if from_above and not reachable(home, held, ctx.arm.model):  # the lift where it stands
            return None
        obstacles = held_obstacles(state.planning_scene, track.id, None, radius)
        return zone_spot(
            zone_rect(ctx.config, zone),
            held,
            obstacles,
            cfg.clearance,
            gcfg.min_base_distance,
            ctx.arm.model,
        )

    def result(self) -> SortResult:
        placed = sum(r.action == "placed" for r in self.reports)
        failed = [r for r in self.reports if r.action == "failed"]
        skipped = sum(r.action == "skipped" for r in self.reports)
        if not self.reports:
            reason = "no bottle to sort (none tracked outside the zones)"
        else:
            reason = f"{placed} placed, {skipped} skipped, {len(failed)} failed"
            if failed:
                reason += f" (first: track {failed[0].track_id}: {failed[0].reason})"
        return SortResult(
            ok=not failed,
            reason=reason,
            rule=self.rule,
            bottles=tuple(self.reports),
            duration_s=self.ctx.now() - self.start,
        )


def aside_candidates(xy: Array) -> Array:
    """Spots to set a bottle standing at ``xy`` aside on, out of its cluster: every
    :data:`ASIDE_HEADINGS` around it at each of :data:`ASIDE_DISTANCES_M`, the nearest
    first and, at one distance, those nearer the base first (the side grasp that follows
    comes from the base's side)."""
    xy = np.asarray(xy, dtype=float)
    angles = np.linspace(0.0, 2.0 * math.pi, ASIDE_HEADINGS, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    spots = [xy + d * u for d in ASIDE_DISTANCES_M for u in ring]
    order = sorted(
        range(len(spots)), key=lambda k: (k // ASIDE_HEADINGS, float(np.linalg.norm(spots[k])))
    )
    return np.array([spots[k] for k in order])


def sort(
    ctx: TaskContext, by: str | None = None, rule: Mapping[str, Any] | None = None
) -> SortResult:
    """Measure every bottle on the table and place it in the zone its measurement chooses
    (the module docstring). ``by``: ``"fill"`` or ``"colour"`` (default ``sort.by``);
    ``rule``: for fill ``{"threshold": 0.3, "below": "empty", "above": "full"}``, for colour
    ``{"light blue": "empty", "*": "full"}`` (default from ``sort``)."""
    made = SortRule.make(ctx.config, by, rule)
    ctx.require_aim()
    return _Sort(ctx, made).run()
