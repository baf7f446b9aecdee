"""Grab a bottle: collision-aware (``grab.planner = "collision"``, the default) or the paper's
straight approach from the base (``"paper"``, the baseline), with the paper's safety rules.

**Collision-aware.** Wait for a confirmed bottle track, then plan before anything moves:
:func:`~armvision.tasks.grasp_plan.plan_grasps` tries approaches all around each bottle
against the planning scene (``state.planning_scene``: the table, every track with its
uncertainty, the occupancy grid, :mod:`armvision.runtime.planning_scene`) and the bottle taken
(without a ``track_id``) is the one with the best free candidate. If none is free, the task
fails with the planner's reason ("every approach to bottle 3 ... is blocked by the cup (track
5) at ...") and the arm and gripper do not move (it looks :data:`PLAN_LOOKS` times first:
young tracks settle). Otherwise: open the gripper; the safe start pose; plan again with what
the camera sees from there; to the chosen candidate's hover point along a joint path clear of
the whole scene, the bottle included (:func:`~armvision.tasks.joint_plan.joint_path`: the
straight joint line if free, else OMPL's RRT-Connect, timed within the joint speed limits;
the next candidate if no path is found); down to the pre-grasp point; re-read the track (a
bottle that moved more than :data:`MOVED_M` is planned for again from there, one the gripper
hides keeps the plan); straight in; close; lift; check, as below. Every configuration moved
through was checked against the scene. Should the fingers close on nothing (the bottle's
track was off, or the fingers nudged it), they open, back out and up the way they came, and
the arm goes back to the safe start pose, looks again for :data:`RELOOK_S` and plans the
grasp anew, :data:`MISSED_RETRIES` time(s), before the task fails. A bottle that slips out
during the lift is taken anew the same way, the open gripper first going down the way it
went up; the new attempt has ``timeout_s`` of its own.

**The paper's sequence:**

1. **Safe start.** Gripper open, end effector at ``grab.safe_pose`` (default (0.1, 0, 0.65) m,
   gripper level, pointing along +x). The ViperX-300s reaches it; for an arm or a configured
   pose it cannot reach, :func:`safe_start_pose` takes the nearest reachable one: the same
   position with the nearest reachable orientation, else the position lowered in 2 cm steps.
2. **A confirmed bottle track.** Wait (up to ``grab.track_wait_s``) for the fusion loop to
   confirm a bottle whose size is known. Without a ``track_id`` the bottle taken is the
   nearest to the base whose approach corridor (the line from the base, as wide as the open
   gripper) is clear of every other tracked object.
3. **Waypoint.** With the bottle at horizontal distance d from the base axis and bearing
   yaw = atan2(y, x): the end effector goes to distance d - ``standoff`` (d if d < standoff)
   on that line, at the grasp height, facing the bottle (yaw). Grasp height = the table
   (bottle centre minus half its estimated height) + ``grasp_height_fraction`` x height.
4. **Approach**: straight on to the bottle's axis at the grasp height, same yaw.
5. **Close**, then **lift** ``grab.lift`` (10 cm), then **check** the grasp (after the close
   and after the lift, :func:`holding`): the gripper's own confirmation where it has one (the
   Dynamixel gripper's current and finger gap together), else the finger gap must stay above
   the empty-closed gap by :data:`GRASP_MARGIN_M` (an empty gripper closes to 0.021 m per
   finger; on a bottle of radius r it stops near r + 12.5 mm).

Safety and robustness: a bottle nearer than ``min_base_distance`` to the base axis aborts the
task; every motion's result is checked and a refused one is tried again after
``retry_delay_s`` (``retries`` times) before the task fails with the arm's reason; the track is
re-read before the waypoint and before the approach, and if the bottle moved by more than
:data:`MOVED_M` the plan is made again (once chosen, the bottle is kept by its track id while
bottle is among its label votes: the gripper hiding part of it on the way in can tip the vote,
:func:`tracked_bottle`); the task fails after ``timeout_s`` (each new attempt
after a missed or slipped grasp has ``timeout_s`` of its own). A failed
grasp opens the gripper and backs off to the waypoint, so nothing is left pinched. Stop
(TaskStopped) halts the arm where it is, gripper unchanged.

**From above.** Where no approach from the side is free (bottles 1-2 cm apart), the
collision-aware planner tries grasps from above (``grab.top_grasp``): the gripper pointing
down comes straight down over the bottle and closes on its cap and neck, then lifts; checked
the same way. The gap check then needs :data:`TOP_GRASP_MARGIN_M` (a cap is narrower than a
body). ``allow_top=False`` keeps to grasps from the side (the analyze task carries the bottle
level).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from armvision.config import GrabConfig
from armvision.fusion.tracker import TrackState
from armvision.geometry import as_xyz, make_T, rot_z
from armvision.robot.base import DEFAULT_ACCEL_TIME_S, Arm
from armvision.robot.kinematics import VX300S, ArmModel, fk, ik
from armvision.runtime.context import TaskContext, TaskError
from armvision.runtime.state import SystemState
from armvision.tasks.grasp_plan import Checker, GraspCandidate, GraspRefusal, plan_grasps
from armvision.tasks.joint_plan import joint_path, path_times
from armvision.tasks.motion import SEGMENT_TIME_S, level_pose, motion_seed, paced_time

#: The finger gap must exceed the empty-closed gap by this much for a grasp to count, metres.
GRASP_MARGIN_M = 0.004
#: ... by this much when the grasp is from above: it closes on a cap, 11-16 mm in radius.
TOP_GRASP_MARGIN_M = 0.002
#: Ends the reason of a grab that refused before anything moved (the arm, the gripper).
NOTHING_MOVED = "(nothing moved)"


def holding(arm: Arm, margin: float = GRASP_MARGIN_M) -> bool:
    """Whether the closed gripper holds something: the gripper's own confirmation where it
    senses one (a Dynamixel gripper: current and finger gap together), else the finger gap
    above the empty-closed one by ``margin`` (:data:`GRASP_MARGIN_M`; for a grasp from
    above, :data:`TOP_GRASP_MARGIN_M`)."""
    confirmed = arm.gripper.grasp_confirmed()
    if confirmed is not None:
        return confirmed
    return arm.gripper.get_finger_position() >= arm.model.finger_limits[0] + margin


#: A bottle that moved more than this between two reads of its track is re-planned for, metres.
MOVED_M = 0.02
#: Half-width of the corridor the open gripper sweeps on its way in: pads 89 mm apart plus
#: the fingers themselves (Interbotix vx300s gripper), metres.
GRIPPER_HALF_WIDTH_M = 0.06
#: Above the waypoint, the gripper comes down from this far above the bottle's top, metres.
HOVER_CLEARANCE_M = 0.08
#: How far the corridor extends behind the waypoint toward the base, metres.
CORRIDOR_BACK_M = 0.05


@dataclass(frozen=True)
class GrabResult:
    """What the grab did. ``ok`` only when the bottle is held after the lift.

    ``track_id`` the bottle's track; ``target`` (x, y, z) the bottle centre the approach aimed
    at, base frame; ``height`` its estimated height; ``grasp_z`` the grasp height; ``finger``
    the finger position after the lift (m); ``stages`` the stages completed, in order;
    ``retries`` motions retried; ``duration_s`` from start to end (clock seconds);
    ``replans`` plans made again for a bottle that moved; ``approach_deg`` the heading of the
    final approach (the paper's: the bottle's bearing); ``joint_paths_planned`` moves for which
    no straight joint line was free and RRT-Connect found the path; ``ahead`` how far ahead of
    the point between the fingertips (along the gripper's heading) the bottle's axis stands,
    m: 0 but for a shallow grasp (:data:`~armvision.tasks.grasp_plan.AHEADS_M`);
    ``from_above`` whether the bottle was grasped from above, by the cap (``grasp_z`` is
    then, as from the side, the height of the point between the fingertips);
    :attr:`untouched` whether it failed before the final approach (the bottle as it was).
    """

    ok: bool
    reason: str
    track_id: int | None = None
    target: tuple[float, float, float] | None = None
    height: float | None = None
    grasp_z: float | None = None
    finger: float | None = None
    stages: tuple[str, ...] = ()
    retries: int = 0
    duration_s: float = 0.0
    replans: int = 0
    approach_deg: float | None = None
    joint_paths_planned: int = 0
    ahead: float = 0.0
    from_above: bool = False

    @property
    def untouched(self) -> bool:
        """Failed before the final approach: the gripper never came to the bottle (a refusal,
        or no joint path to any grasp), so another try may find its way free."""
        return not self.ok and "approach" not in self.stages

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "reason": self.reason,
            "track_id": self.track_id,
            "target": None if self.target is None else [round(v, 4) for v in self.target],
            "height": None if self.height is None else round(self.height, 4),
            "grasp_z": None if self.grasp_z is None else round(self.grasp_z, 4),
            "finger": None if self.finger is None else round(self.finger, 4),
            "stages": list(self.stages),
            "retries": self.retries,
            "replans": self.replans,
            "duration_s": round(self.duration_s, 3),
            "approach_deg": None if self.approach_deg is None else round(self.approach_deg, 1),
            "joint_paths_planned": self.joint_paths_planned,
            "ahead": round(self.ahead, 4),
            "from_above": self.from_above,
            "untouched": self.untouched,
        }


def safe_start_pose(position: tuple[float, float, float], model: ArmModel = VX300S) -> np.ndarray:
    """``T_base_ee`` for the safe start: ``position`` with the gripper level, or the nearest
    reachable pose (nearest orientation, else the position lowered in 2 cm steps)."""
    T = make_T(np.eye(3), position)
    seed = np.zeros(model.dof)
    q, ok = ik(T, seed, model)
    if ok:
        return T
    q, ok = ik(T, seed, model, position_priority=True)
    if ok:
        return fk(q, model)
    x, y, z = position
    for k in range(1, 40):
        T = make_T(np.eye(3), (x, y, z - 0.02 * k))
        q, ok = ik(T, seed, model, position_priority=True)
        if ok:
            return fk(q, model)
    raise TaskError(
        f"the safe start pose {position} and every pose below it are out of reach: "
        "set grab.safe_pose to a reachable position"
    )


def corridor_clear(target: TrackState, others: list[TrackState], standoff: float) -> bool:
    """True if no other object stands in the strip the open gripper sweeps to ``target``."""
    p = np.asarray(target.p_base[:2], dtype=float)
    d = float(np.linalg.norm(p))
    if d < 1e-6:
        return False
    u = p / d
    start = max(d - standoff - CORRIDOR_BACK_M, 0.0)
    for other in others:
        q = np.asarray(other.p_base[:2], dtype=float)
        along = float(q @ u)
        across = abs(float(q[0] * u[1] - q[1] * u[0]))
        radius = other.radius if other.radius is not None else 0.04
        if start - radius <= along <= d + radius and across < GRIPPER_HALF_WIDTH_M + radius:
            return False
    return True


def tracked_bottle(state: SystemState, track_id: int) -> TrackState | None:
    """The bottle a grab has chosen, track ``track_id``, while it may still be one: its
    height known and bottle among its label votes, whether or not bottle leads them. A
    bottle's label can lose the vote while the gripper hides part of it on the way in: in a
    cluttered grab (seed 14 of `eval grab --profile cluttered`) a bottle behind two others,
    read as other in the frames of the approach, was given up at its pre-grasp point. The
    first choice takes only a track labelled bottle."""
    track = state.track(track_id)
    if track is None or track.height is None or dict(track.votes).get("bottle", 0.0) <= 0.0:
        return None
    return track


def choose_bottle(state: SystemState, standoff: float, track_id: int | None) -> TrackState | None:
    """The bottle to take: ``track_id`` if given and tracked, else the nearest to the base
    with a clear corridor (else simply the nearest). Only tracks whose height is known."""
    bottles = [t for t in state.bottles() if t.height is not None]
    if track_id is not None:
        return next((t for t in bottles if t.id == track_id), None)
    if not bottles:
        return None
    for bottle in bottles:
        others = [t for t in state.tracks if t.id != bottle.id]
        if corridor_clear(bottle, others, standoff):
            return bottle
    return bottles[0]


@dataclass
class _Plan:
    track: TrackState
    yaw: float
    d: float
    grasp_z: float
    top: float
    waypoint: np.ndarray = field(repr=False)
    grasp: np.ndarray = field(repr=False)
    ahead: float = 0.0  # the bottle's axis ahead of the point between the fingertips, m
    from_above: bool = False  # grasped from above, by the cap


def plan_grasp(track: TrackState, cfg: GrabConfig) -> _Plan:
    """Waypoint and grasp poses for a bottle track (see the module docstring)."""
    x, y, z = (float(v) for v in track.p_base)
    height = float(track.height) if track.height is not None else 2.0 * z
    d = math.hypot(x, y)
    yaw = math.atan2(y, x)
    bottom = z - height / 2.0
    grasp_z = bottom + cfg.grasp_height_fraction * height
    d_way = d - cfg.standoff if d >= cfg.standoff else d
    R = rot_z(yaw)
    waypoint = make_T(R, (d_way * math.cos(yaw), d_way * math.sin(yaw), grasp_z))
    grasp = make_T(R, (x, y, grasp_z))
    return _Plan(track, yaw, d, grasp_z, bottom + height, waypoint, grasp)


class _Grab:
    def __init__(self, ctx: TaskContext, cfg: GrabConfig, track_id: int | None) -> None:
        self.ctx, self.cfg, self.track_id = ctx, cfg, track_id
        self.start = ctx.now()
        #: When the current attempt started: ``timeout_s`` bounds each (the first, and each
        #: one after a missed or slipped grasp).
        self.attempt_start = self.start
        self.stages: list[str] = []
        self.retries = 0
        self.replans = 0
        self.plan: _Plan | None = None
        self.last_target: np.ndarray | None = None
        self.joint_paths = 0

    def result(self, ok: bool, reason: str, finger: float | None = None) -> GrabResult:
        plan = self.plan
        return GrabResult(
            ok=ok,
            reason=reason,
            track_id=None if plan is None else plan.track.id,
            target=None if plan is None else as_xyz(plan.track.p_base),
            height=None if plan is None else plan.track.height,
            grasp_z=None if plan is None else plan.grasp_z,
            finger=finger,
            stages=tuple(self.stages),
            retries=self.retries,
            duration_s=self.ctx.now() - self.start,
            replans=self.replans,
            approach_deg=None if plan is None else math.degrees(plan.yaw),
            joint_paths_planned=self.joint_paths,
            ahead=0.0 if plan is None else plan.ahead,
            from_above=plan is not None and plan.from_above,
        )

    def remaining(self) -> float:
        return self.cfg.timeout_s - (self.ctx.now() - self.attempt_start)

    def check_time(self) -> None:
        if self.remaining() <= 0.0:
            raise _Abort(f"timed out after {self.cfg.timeout_s:.0f} s")

    def move(
        self,
        what: str,
        T: np.ndarray,
        position_priority: bool = False,
        moving_time: float | None = None,
    ) -> None:
        """A checked move, retried after a delay if refused; _Abort with the arm's reason.

        The move takes ``moving_time`` (default ``grab.moving_time``) or longer if some joint
        would otherwise go faster than :data:`SPEED_FRACTION` of its limit.
        """
        arm = self.ctx.arm
        duration = moving_time or self.cfg.moving_time
        q, ok = ik(T, arm.get_joint_positions(), arm.model)
        if ok:
            duration = paced_time(arm, q, duration)
        for attempt in range(self.cfg.retries + 1):
            self.check_time()
            if self.ctx.move_pose(
                T,
                moving_time=duration,
                position_priority=position_priority,
            ):
                self.last_target = np.asarray(T, dtype=float)
                return
            if attempt < self.cfg.retries:
                self.retries += 1
                self.ctx.sleep(self.cfg.retry_delay_s)
        raise _Abort(f"{what}: {self.ctx.arm.last_error or 'the arm refused the move'}")

    def wait_for_track(self, progress: float) -> None:
        """Wait (within the task's time) for a confirmed track of the bottle to grab; abort
        with what to check if none comes within ``grab.track_wait_s``."""
        ctx, cfg = self.ctx, self.cfg
        ctx.progress(progress, "waiting for a confirmed bottle track")
        found = ctx.wait_until(
            lambda: self.read_track() is not None,
            min(cfg.track_wait_s, max(self.remaining(), 0.0)),
        )
        if not found:
            which = "any bottle" if self.track_id is None else f"bottle track {self.track_id}"
            raise _Abort(
                f"no confirmed track of {which} within {cfg.track_wait_s:.0f} s: is a bottle "
                "in the camera's view and is object detection on?"
            )

    def read_track(self) -> TrackState | None:
        state = self.ctx.state()
        if self.plan is None:
            return choose_bottle(state, self.cfg.standoff, self.track_id)
        return state.track(self.plan.track.id)

    def replan_if_moved(self) -> None:
        """Re-read the track; plan again if the bottle moved (abort if it is gone)."""
        assert self.plan is not None
        track = self.read_track()
        if track is None:
            raise _Abort("the bottle's track was lost")
        if np.linalg.norm(track.p_base[:2] - self.plan.track.p_base[:2]) > MOVED_M:
            self.replans += 1
        self.plan = plan_grasp(track, self.cfg)
        self.check_distance()

    def check_distance(self) -> None:
        assert self.plan is not None
        if self.plan.d < self.cfg.min_base_distance:
            raise _Abort(
                f"the bottle is {100 * self.plan.d:.1f} cm from the base axis, nearer than "
                f"{100 * self.cfg.min_base_distance:.0f} cm: not safe to grasp"
            )

    def move_straight(self, what: str, p_goal: np.ndarray, segments: int) -> None:
        """Move the gripper along the straight line from the last target to ``p_goal`` in
        ``segments`` moves (a single joint-space move between two poses near the table can
        sweep the gripper through what stands there), facing the bottle, each point as level
        as the arm allows (see :meth:`pose_at`)."""
        assert self.last_target is not None
        p_from = self.last_target[:3, 3].copy()
        for k in range(1, segments + 1):
            s = k / segments
            T = self.pose_at((1 - s) * p_from + s * np.asarray(p_goal, dtype=float))
            self.move(what, T, moving_time=max(self.cfg.moving_time / segments, SEGMENT_TIME_S))

    def pose_at(self, p: np.ndarray) -> np.ndarray:
        """The gripper at ``p`` facing the bottle (yaw), level if the arm reaches it so, else
        pitched down just enough.

        Near the base a level gripper cannot reach low points; pitching it down about its own
        y axis keeps the wrist unflipped, where "any reachable orientation" may turn the
        forearm and wrist half a turn and sweep the table. Solutions are sought next to the
        last target's, so consecutive points do not jump between IK branches.
        """
        assert self.plan is not None
        arm = self.ctx.arm
        found = level_pose(p, self.plan.yaw, motion_seed(arm, self.last_target), arm.model)
        if found is None:
            return make_T(rot_z(self.plan.yaw), p)  # unreachable: the move will say so
        return found[0]

    def finger(self) -> float:
        return float(self.ctx.arm.gripper.get_finger_position())

    def run(self) -> GrabResult:
        ctx, cfg = self.ctx, self.cfg
        ctx.progress(0.02, "opening the gripper")
        ctx.open_gripper()
        ctx.progress(0.08, "going to the safe start pose")
        self.move("safe start pose", safe_start_pose(cfg.safe_pose, ctx.arm.model))
        self.stages.append("safe_start")

        self.wait_for_track(0.25)
        track = self.read_track()
        assert track is not None
        self.plan = plan_grasp(track, cfg)
        self.check_distance()
        self.stages.append("bottle_found")

        ctx.progress(0.4, f"to the waypoint {100 * cfg.standoff:.0f} cm short of the bottle")
        self.replan_if_moved()
        # Come down onto the waypoint from above it, clear of everything standing nearby.
        hover = self.plan.waypoint[:3, 3].copy()
        hover[2] = max(hover[2], self.plan.top + HOVER_CLEARANCE_M)
        self.move("above the waypoint", self.pose_at(hover))
        self.move_straight("waypoint", self.plan.waypoint[:3, 3], segments=2)
        self.stages.append("waypoint")

        ctx.progress(0.55, "final approach")
        self.replan_if_moved()
        self.move_straight("approach", self.plan.grasp[:3, 3], segments=3)
        self.stages.append("approach")

        ctx.progress(0.7, "closing the gripper")
        ctx.close_gripper()
        if not holding(ctx.arm):
            self.back_off()
            raise _Abort("the gripper closed on nothing: the bottle was not between the fingers")
        self.stages.append("closed")

        ctx.progress(0.8, f"lifting {100 * cfg.lift:.0f} cm")
        lifted = self.plan.grasp.copy()
        lifted[2, 3] += cfg.lift
        self.move_straight("lift", lifted[:3, 3], segments=2)
        self.stages.append("lifted")
        finger = self.finger()
        if not holding(ctx.arm):
            raise _Abort("the bottle slipped out during the lift")
        self.stages.append("checked")
        ctx.progress(1.0, "holding the bottle")
        return self.result(True, "bottle grasped and lifted", finger)

    def back_off(self) -> None:
        """Open the gripper and retreat to the waypoint, leaving nothing pinched."""
        self.ctx.open_gripper()
        if self.plan is not None:
            self.ctx.move_pose(
                self.pose_at(self.plan.waypoint[:3, 3]), moving_time=self.cfg.moving_time
            )


class _PlannedGrab(_Grab):
    """The collision-aware grab (``grab.planner = "collision"``; the module docstring)."""

    def __init__(
        self, ctx: TaskContext, cfg: GrabConfig, track_id: int | None, allow_top: bool = True
    ) -> None:
        super().__init__(ctx, cfg, track_id)
        self.candidate: GraspCandidate | None = None
        self.paths_planned = 0
        self.allow_top = allow_top

    def margin(self) -> float:
        """The finger gap a grasp needs to count (:func:`holding`)."""
        top = self.candidate is not None and self.candidate.from_above
        return TOP_GRASP_MARGIN_M if top else GRASP_MARGIN_M

    # ------------------------------------------------------------ planning

    def plan_for(
        self,
        state: SystemState,
        track_id: int | None,
        prefer: int | None = None,
        chosen: bool = True,
    ) -> tuple[TrackState, list[GraspCandidate]]:
        """The bottle to take and its free candidates, best first; _Abort with the refusal's
        reason if no bottle can be taken. ``track_id``: that bottle only, labelled bottle on
        the first choice (``chosen`` False), else while bottle is among its votes
        (:func:`tracked_bottle`); ``prefer``: that one (the bottle chosen before, kept the same
        way) if it is about as good as the best."""
        bottles = [t for t in state.bottles() if t.height is not None]
        if track_id is not None:
            track = (
                tracked_bottle(state, track_id)
                if chosen
                else next((t for t in bottles if t.id == track_id), None)
            )
            if track is None:
                raise _Abort(f"the track of bottle {track_id} was lost")
            bottles = [track]
        elif prefer is not None and chosen and all(t.id != prefer for t in bottles):
            kept = tracked_bottle(state, prefer)
            bottles += [] if kept is None else [kept]
        scene = state.planning_scene
        model = self.ctx.arm.model
        best: tuple[float, TrackState, list[GraspCandidate]] | None = None
        refusals: list[str] = []
        for bottle in bottles:
            d = math.hypot(float(bottle.p_base[0]), float(bottle.p_base[1]))
            if d < self.cfg.min_base_distance:
                refusals.append(
                    f"bottle {bottle.id} is {100 * d:.1f} cm from the base axis, nearer than "
                    f"{100 * self.cfg.min_base_distance:.0f} cm: not safe to grasp"
                )
                continue
            found = plan_grasps(bottle, scene, self.cfg, model, self.allow_top, self.ctx.check)
            if isinstance(found, GraspRefusal):
                refusals.append(found.reason)
                continue
            # A bottle the camera places surely beats one it barely sees (a clear bottle's
            # fit may sit centimetres off); staying with the bottle chosen before is a plus.
            score = found[0].score - CERTAINTY_WEIGHT * bottle.sigma_mm / 1000.0
            if prefer is not None and bottle.id == prefer:
                score += 0.01
            if best is None or score > best[0]:
                best = (score, bottle, found)
        if best is None:
            raise _Abort("; ".join(refusals) if refusals else "no bottle to grasp")
        return best[1], best[2]

    def checker(self, state: SystemState, exclude: int | None) -> Callable[[np.ndarray], float]:
        check = Checker(state.planning_scene, exclude, self.ctx.arm.model)
        opened = self.ctx.arm.model.finger_limits[1]
        return lambda Q: check.least(Q, opened)[0]

    def transit(self, what: str, q_goal: np.ndarray, state: SystemState) -> None:
        """Move to ``q_goal`` along a joint path clear of the whole scene (the target
        included): the straight joint line if it is free, else RRT-Connect's path."""
        least = self.checker(state, None)
        q_now = np.asarray(self.ctx.arm.get_joint_positions(), dtype=float)
        # Never ask more than the start and goal have (the arm may start folded near the base).
        needed = min(
            self.cfg.clearance,
            max(least(q_now[None]) - 0.002, 0.0),
            max(least(np.asarray(q_goal)[None]) - 0.002, 0.0),
        )
        path = joint_path(
            q_now,
            q_goal,
            least,
            needed,
            self.ctx.arm.model,
            min(self.cfg.plan_time_s, max(self.remaining(), 0.1)),
            seed=self.paths_planned,
        )
        self.paths_planned += 1
        if path is None:
            raise _Abort(f"{what}: no collision-free joint path found")
        self.joint_paths += len(path) > 2
        accel = float(getattr(self.ctx.arm, "accel_time", DEFAULT_ACCEL_TIME_S))
        for q, duration in zip(path[1:], path_times(path, self.ctx.arm.model, accel), strict=True):
            self.move_q(what, q, duration)

    # ------------------------------------------------------------ motion

    def move_q(self, what: str, q: np.ndarray, duration: float) -> None:
        """A checked joint move, retried after a delay if refused; _Abort with the reason."""
        duration = paced_time(self.ctx.arm, q, duration)
        for attempt in range(self.cfg.retries + 1):
            self.check_time()
            if self.ctx.move_joints(q, moving_time=duration):
                self.last_target = fk(q, self.ctx.arm.model)
                return
            if attempt < self.cfg.retries:
                self.retries += 1
                self.ctx.sleep(self.cfg.retry_delay_s)
        raise _Abort(f"{what}: {self.ctx.arm.last_error or 'the arm refused the move'}")

    def steps(self, what: str, qs: tuple[np.ndarray, ...]) -> None:
        duration = max(self.cfg.moving_time / max(len(qs), 1), SEGMENT_TIME_S)
        for q in qs:
            self.move_q(what, q, duration)

    def adopt(self, track: TrackState, candidate: GraspCandidate) -> None:
        model = self.ctx.arm.model
        self.candidate = candidate
        x, y, _ = (float(v) for v in track.p_base)
        top = float(track.p_base[2]) + 0.5 * float(track.height or 0.0)
        self.plan = _Plan(
            track,
            candidate.yaw,
            math.hypot(x, y),
            candidate.grasp_z,
            top,
            fk(candidate.pregrasp, model),
            fk(candidate.grasp, model),
            candidate.ahead,
            candidate.from_above,
        )

    def go_to(self, state: SystemState, track: TrackState, found: list[GraspCandidate]) -> None:
        """To the hover point of the first candidate a free joint path reaches, and down to
        its pre-grasp point."""
        for candidate in found[:MAX_PATH_TRIES]:
            try:
                self.transit("to above the grasp", candidate.hover, state)
            except _Abort as exc:
                if "no collision-free joint path" not in str(exc):
                    raise
                continue
            self.adopt(track, candidate)
            self.steps("down to the pre-grasp point", candidate.descend)
            return
        raise _Abort(
            f"no collision-free joint path reaches any of the {min(len(found), MAX_PATH_TRIES)}"
            f" best grasps of bottle {track.id}"
        )

    def take(self, track: TrackState) -> TrackState:
        """Plan the grasp from where the arm is (of the bottle asked for, else of the best
        bottle, ``track`` if it is about as good: a track the arm hid may come back as a new
        one), go there, approach and close; the track taken."""
        ctx = self.ctx
        ctx.progress(0.35, "planning the grasp")
        state = ctx.state()
        track, found = self.plan_for(state, self.track_id, prefer=track.id)
        self.go_to(state, track, found)
        self.stages.append("waypoint")

        ctx.progress(0.55, "final approach")
        for _ in range(2):
            state = ctx.state()
            now = state.track(track.id)
            # A track hidden by the gripper keeps the plan; one that moved is planned again.
            if now is None or np.linalg.norm(now.p_base[:2] - track.p_base[:2]) <= MOVED_M:
                break
            self.replans += 1
            track, found = self.plan_for(state, track.id)
            self.go_to(state, track, found)
        assert self.candidate is not None
        self.steps("approach", self.candidate.approach)
        self.stages.append("approach")

        ctx.progress(0.7, "closing the gripper")
        ctx.close_gripper()
        return track

    def run(self) -> GrabResult:
        ctx, cfg = self.ctx, self.cfg
        self.wait_for_track(0.05)
        # Plan before anything moves: a refusal leaves the arm and gripper as they are. A young
        # track's size and place are still settling (a phantom may even be dropped), so a
        # refusal is made only after a few looks.
        for attempt in range(PLAN_LOOKS):
            try:
                track, found = self.plan_for(ctx.state(), self.track_id, chosen=False)
                break
            except _Abort as exc:
                if attempt == PLAN_LOOKS - 1:
                    raise _Abort(f"{exc} {NOTHING_MOVED}") from None
                ctx.sleep(PLAN_LOOK_INTERVAL_S)
        self.adopt(track, found[0])
        self.stages.append("bottle_found")

        ctx.progress(0.15, "opening the gripper")
        ctx.open_gripper()
        ctx.progress(0.2, "going to the safe start pose")
        model = ctx.arm.model
        T_safe = safe_start_pose(cfg.safe_pose, model)
        q_safe, ok = ik(T_safe, ctx.arm.get_joint_positions(), model)
        if not ok:
            raise _Abort("the safe start pose is out of reach: set grab.safe_pose")
        self.transit("safe start pose", q_safe, ctx.state())
        self.stages.append("safe_start")

        whys: list[str] = []  # why each attempt failed
        for attempt in range(1 + MISSED_RETRIES):
            track = self.take(track)
            missed = self.candidate
            assert missed is not None
            if holding(ctx.arm, self.margin()):
                self.stages.append("closed")
                ctx.progress(0.8, f"lifting {100 * cfg.lift:.0f} cm")
                self.steps("lift", missed.lift)
                self.stages.append("lifted")
                if holding(ctx.arm, self.margin()):
                    break
                why = "the bottle slipped out during the lift"
                ctx.open_gripper()
                # Down the way it went up, the fingers open: a bottle that slid out stands
                # between them again, one that fell lies below the grasp height.
                self.steps("down", (*tuple(reversed(missed.lift[:-1])), missed.grasp))
            else:
                why = "the gripper closed on nothing: the bottle was not between the fingers"
                ctx.open_gripper()
            # Back out the way the gripper came in (checked free), then up.
            self.steps("back off", (*tuple(reversed(missed.approach[:-1])), missed.pregrasp))
            self.steps("up", (*tuple(reversed(missed.descend[:-1])), missed.hover))
            whys.append(why)
            if attempt == MISSED_RETRIES:
                if attempt and whys[0] == why:
                    why += " (twice: it was looked at again in between)"
                elif attempt:
                    why += f" (at the second try; at the first, {whys[0]})"
                raise _Abort(why)
            # The fingers may have nudged it, or its track was off, or it stood so that it
            # slipped: out of the camera's way, look again, and plan anew.
            self.stages.append("missed")
            ctx.progress(0.3, f"{why}: looking again")
            self.transit("safe start pose", q_safe, ctx.state())
            ctx.sleep(RELOOK_S)
            self.attempt_start = ctx.now()  # the new attempt has timeout_s of its own
        finger = self.finger()
        self.stages.append("checked")
        ctx.progress(1.0, "holding the bottle")
        return self.result(True, "bottle grasped and lifted", finger)


#: A candidate whose hover point no joint path reaches gives way to the next, this many times.
MAX_PATH_TRIES = 4
#: A bottle's score loses this many metres per metre of its track's position uncertainty.
CERTAINTY_WEIGHT = 2.0
#: A grasp that closed on nothing is made again this many times, after backing off to the safe
#: start pose and looking again for this long (s): the fingers may have nudged the bottle,
#: or its track was off by more than they forgive.
MISSED_RETRIES = 1
RELOOK_S = 1.0
#: Before refusing, the collision-aware grab plans this many times, this far apart (seconds).
PLAN_LOOKS = 3
PLAN_LOOK_INTERVAL_S = 1.0


class _Abort(Exception):  # noqa: N818 - control flow inside this module
    """Ends the grab with a reason (becomes GrabResult.ok = False)."""


def grab(ctx: TaskContext, track_id: int | None = None, allow_top: bool = True) -> GrabResult:
    """Grasp a bottle and lift it (see the module docstring); ``track_id`` picks the bottle.
    ``grab.planner`` chooses the collision-aware grasp (default) or the paper's;
    ``allow_top`` False keeps the collision-aware one to grasps from the side (a bottle to be
    carried level, as the analyze task carries it)."""
    ctx.require_aim()
    cfg = ctx.config.grab
    job = (
        _PlannedGrab(ctx, cfg, track_id, allow_top)
        if cfg.planner == "collision"
        else _Grab(ctx, cfg, track_id)
    )
    try:
        return job.run()
    except _Abort as exc:
        finger = job.finger()
        return job.result(False, str(exc), finger)
