"""Collision-aware grasp planning: approaches all around a bottle, checked against the scene.

For a bottle (a track: centre, radius r, height h) :func:`plan_grasps` tries
``grab.approach_candidates`` approach headings all around it, each at a few stand-offs and
gripper pitches. One candidate is a sequence of joint configurations, every one found by
closed-form IK near the one before (so the arm stays on one branch):

1. **hover**: above the pre-grasp point, higher than everything near it;
2. **descend** straight down to the **pre-grasp** point, ``standoff`` short of the bottle's
   axis on the approach line, at the grasp height (the table + ``grasp_height_fraction`` h);
3. **approach** straight in until the bottle's axis is between the fingertips (where that is
   blocked, up to 2 cm short of it, :data:`AHEADS_M`: a shallower grasp);
4. **close**: the fingers' swept volume, from open to closed on the bottle (r + the pad inset);
5. **lift** straight up ``grab.lift``, the fingers closed.

Each step's configurations, 2 cm apart, and the joint-space lines between the configurations
executed are checked against the planning scene (every body and occupied cell but the bottle
itself, and the table) with :mod:`armvision.tasks.collision`. A candidate is free when its
least clearance is at least ``grab.clearance``; among the free ones the plan takes the best
score: clearance (up to :data:`ENOUGH_CLEARANCE_M`, more does not count), then reach (an
approach from the base's side, a level gripper). When none is free, :class:`GraspRefusal`
says what blocks them ("every approach to bottle 3 ... is blocked by the cup (track 5) at
...").

Where no candidate from the side is free and grasps from above are allowed
(``grab.top_grasp``, ``allow_top``), :func:`plan_grasps` tries :data:`TOP_HEADINGS` finger
headings with the gripper pointing down: hover above the bottle, straight down over it until
the point between the fingertips is :data:`TOP_BELOW_M` under its top, close on the cap and
neck, lift straight up; checked in the same way, scored :data:`TOP_PENALTY` below any side
grasp, and their blockers added to the refusal ("; from above: blocked by ...").

Units: metres, radians; positions in the base frame.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from armvision.config import GrabConfig
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T, rpy_to_R
from armvision.robot.kinematics import ArmModel, ik, ik_solutions
from armvision.robot.vx300s import FINGER_PAD_INSET
from armvision.runtime.planning_scene import PlanningScene
from armvision.tasks.collision import arm_spheres, clearances

Array = NDArray[np.float64]

#: Clearance beyond this does not make a candidate better, m.
ENOUGH_CLEARANCE_M = 0.03
#: Stand-offs tried, as shares of ``grab.standoff`` (the pre-grasp point must leave the open
#: fingertips, 29 mm ahead of the grasp point, clear of the bottle: 85 mm at least).
STANDOFF_SHARES = (1.0, 0.6)
MIN_STANDOFF_M = 0.085
#: Grasp heights tried, as shares of the bottle's height added to ``grab.grasp_height_fraction``
#: (a grasp higher up passes above cups, cans and boxes standing beside the bottle; below the
#: shoulder of every bottle family of the simulated bench, 58 % of the height at the lowest).
GRASP_RAISES = (0.0, 0.1)
#: Gripper pitches tried (down, about its own y axis), degrees; a level one is preferred.
PITCHES_DEG = (0, 15, 30)
#: How far ahead of the point between the fingertips the bottle's axis may stand, m: a
#: shallower grasp, whose fingertips reach less far past the bottle (28.5 mm at 0), leaves
#: room for a neighbour close behind it. The pads (box geoms -39.5..+28.5 mm along the
#: gripper's x from that point, ``sim/data/vx300s.xml``) still close on the bottle's widest
#: line with 8.5 mm of pad beyond it at the most. Tried only where the full depth is blocked.
AHEADS_M = (0.0, 0.012, 0.02)
#: A candidate's score loses this per metre of ``ahead`` (a full-depth grasp holds best).
AHEAD_WEIGHT = 0.3
#: Grasps from above (the gripper pointing down, :func:`_top_candidate`), tried only when no
#: grasp from the side is free (bottles standing 1-2 cm apart leave the fingers no room beside
#: them, but their caps and necks stand 4-5 cm apart): the pitch; the finger headings tried
#: (over half a turn: the two fingers are alike); how far below the bottle's top the point
#: between the fingertips stops (the pads, reaching 28.5 mm below it, close on the cap and
#: neck, or a short-necked bottle's shoulder, below a nozzle or cap loop: on the bench every
#: family, full, held so through a 15 cm carry); how far above that the descent starts (the
#: fingertips above the top); the share of the body's radius the closed fingers are checked
#: at (a cap is 0.47 of it on the bench); and the score a grasp from above loses against any
#: from the side (held by the cap, a full bottle slips 1-2 cm down the pads on the bench).
TOP_PITCH_DEG = 90
TOP_HEADINGS = 12
TOP_BELOW_M = 0.02
TOP_ABOVE_M = 0.07
TOP_NECK_SHARE = 0.45
TOP_PENALTY = 0.05
#: Straight steps are followed by IK every this far, m (the joint lines between are checked).
CHECK_STEP_M = 0.02
#: The grasp pose's IK branches tried, most natural first.
MAX_BRANCHES = 3
#: Consecutive configurations of a straight step may differ by at most this in any joint, rad
#: (more is a jump between IK branches, not a straight motion).
MAX_STEP_RAD = 0.5
#: Joint-space lines between executed configurations are checked every this much, rad.
LINE_STEP_RAD = 0.02
#: The hover point is this far above everything within :data:`HOVER_NEAR_M` of it, m.
HOVER_ABOVE_M = 0.06
HOVER_NEAR_M = 0.2
#: Executed moves of a straight step are at most this long (fewer stops, near-straight), m.
EXECUTE_STEP_M = 0.05


@dataclass(frozen=True)
class GraspCandidate:
    """One way to take the bottle: the approach heading ``yaw`` (the gripper's), stand-off,
    pitch, grasp height (z), how far ahead of the point between the fingertips the bottle's
    axis stands (``ahead``, m; :data:`AHEADS_M`); the joint configurations to execute per
    step (``descend``, ``approach``, ``lift``: each step's moves in order, ``hover`` first);
    its least clearance and score."""

    yaw: float
    standoff: float
    pitch_deg: int
    grasp_z: float
    ahead: float
    hover: Array = field(repr=False)
    descend: tuple[Array, ...] = field(repr=False)
    approach: tuple[Array, ...] = field(repr=False)
    lift: tuple[Array, ...] = field(repr=False)
    clearance: float
    score: float

    @property
    def grasp(self) -> Array:
        return self.approach[-1]

    @property
    def from_above(self) -> bool:
        """A grasp from above (by the cap)."""
        return self.pitch_deg == TOP_PITCH_DEG

    @property
    def pregrasp(self) -> Array:
        return self.descend[-1]


@dataclass(frozen=True)
class GraspRefusal:
    """No free candidate: why, for the operator (``reason``), and per blocker how many."""

    reason: str
    blocked: tuple[tuple[str, int], ...] = ()
    unreachable: int = 0


@dataclass(frozen=True)
class BottleGeometry:
    """The bottle as the planner uses it, from its track (m)."""

    track_id: int
    xy: Array
    radius: float
    height: float
    bottom: float
    grasp_z: float

    @property
    def top(self) -> float:
        return self.bottom + self.height

    @staticmethod
    def of(track: TrackState, cfg: GrabConfig) -> BottleGeometry:
        x, y, z = (float(v) for v in track.p_base)
        height = float(track.height) if track.height is not None else 2.0 * z
        radius = float(track.radius) if track.radius is not None else 0.035
        bottom = z - 0.5 * height
        return BottleGeometry(
            track.id,
            np.array([x, y]),
            radius,
            height,
            bottom,
            bottom + cfg.grasp_height_fraction * height,
        )


class _Blocked(Exception):  # noqa: N818 - control flow inside the planner
    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what


class Checker:
    """Clearance of configurations to one scene (the bottle to grasp, ``exclude_track``, left
    out)."""

    def __init__(self, scene: PlanningScene, exclude_track: int | None, model: ArmModel) -> None:
        self.model = model
        self.obstacles = scene.obstacles(exclude_track)
        self.table_z = scene.table_z

    def least(self, Q: Array, finger: float | list[float]) -> tuple[float, str]:
        """Least clearance over configurations ``Q`` (N, 6), and what it is to."""
        centres, radii = arm_spheres(Q, finger, self.model)
        best, which = clearances(centres, radii, self.obstacles, self.table_z)
        k = int(np.argmin(best))
        j = int(which[k])
        what = "the table" if j == -1 else self.obstacles[j].describe() if j >= 0 else "nothing"
        return float(best[k]), what


def joint_line(q_a: Array, q_b: Array, step: float = LINE_STEP_RAD) -> Array:
    """Configurations (N, 6) on the joint-space line from ``q_a`` to ``q_b``, ``step`` apart
    in the joint that moves most (both ends included)."""
    n = max(1, math.ceil(float(np.max(np.abs(q_b - q_a))) / step))
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return q_a[None, :] + s * (q_b - q_a)[None, :]


def _natural_order(T_base_ee: Array, model: ArmModel) -> list[Array]:
    """Every IK solution, the one a person would pick first: facing the target (not reaching
    over backwards), the least forearm roll and wrist rotation."""
    bearing = math.atan2(T_base_ee[1, 3], T_base_ee[0, 3])

    def cost(q: Array) -> float:
        facing = abs((q[0] - bearing + math.pi) % (2 * math.pi) - math.pi)
        return facing + abs(q[3]) + abs(q[5]) + 0.3 * abs(q[2])

    return sorted(ik_solutions(T_base_ee, model.home, model), key=cost)


def _straight(q_from: Array, p_from: Array, p_to: Array, R: Array, model: ArmModel) -> list[Array]:
    """Configurations every :data:`CHECK_STEP_M` along the straight line ``p_from`` to
    ``p_to`` at orientation ``R``, each near the one before; _Blocked if one is unreachable
    or jumps (``q_from`` is at ``p_from``)."""
    length = float(np.linalg.norm(p_to - p_from))
    n = max(1, math.ceil(length / CHECK_STEP_M))
    out = [q_from]
    for k in range(1, n + 1):
        p = p_from + (k / n) * (p_to - p_from)
        q, ok = ik(make_T(R, p), out[-1], model)
        if not ok or float(np.max(np.abs(q - out[-1]))) > MAX_STEP_RAD:
            raise _Blocked("out of reach")
        out.append(q)
    return out


def _executed(qs: list[Array], length: float) -> tuple[Array, ...]:
    """The configurations of a straight step to move through: at most
    :data:`EXECUTE_STEP_M` apart, the last one included (the first is where the arm is)."""
    n = max(1, math.ceil(length / EXECUTE_STEP_M))
    idx = sorted({round(k * (len(qs) - 1) / n) for k in range(1, n + 1)})
    return tuple(qs[i] for i in idx)


@dataclass(frozen=True)
class _Moves:
    """A candidate's checked motion: the hover configuration, each step's executed moves and
    the least clearance over all of them."""

    hover: Array
    descend: tuple[Array, ...]
    approach: tuple[Array, ...]
    lift: tuple[Array, ...]
    clearance: float


def _checked_moves(
    R: Array,
    p_grasp: Array,
    p_pre: Array,
    p_hover: Array,
    closed: float,
    check: Checker,
    cfg: GrabConfig,
    model: ArmModel,
) -> _Moves:
    """The straight moves hover -> pre-grasp -> grasp, the fingers' closing and the lift
    (``grab.lift`` straight up), all at orientation ``R``, checked against the scene (the
    module docstring); _Blocked with what blocks them."""
    p_lift = p_grasp + np.array([0.0, 0.0, cfg.lift])
    opened = model.finger_limits[1]
    sweep = [opened, 0.5 * (opened + closed), closed]
    # From each IK branch of the grasp pose (the :data:`MAX_BRANCHES` most natural), the
    # straight lines back out to the pre-grasp and hover points and up for the lift: the first
    # branch that reaches. The closing fingers are checked first: in clutter they are what
    # most often collides, and they cost one configuration.
    branches = _natural_order(make_T(R, p_grasp), model)[:MAX_BRANCHES]
    if not branches:
        raise _Blocked("out of reach")
    c_close, what = check.least(branches[0][None, :], sweep)
    if c_close < cfg.clearance:
        raise _Blocked(what)
    for q_grasp in branches:
        try:
            back = _straight(q_grasp, p_grasp, p_pre, R, model)
            up = _straight(back[-1], p_pre, p_hover, R, model)
            lift = _straight(q_grasp, p_grasp, p_lift, R, model)
        except _Blocked:
            continue
        break
    else:
        raise _Blocked("out of reach")
    descend, approach = up[::-1], back[::-1]
    q_hover = descend[0]
    run_descend = _executed(descend, float(np.linalg.norm(p_hover - p_pre)))
    run_approach = _executed(approach, float(np.linalg.norm(p_pre - p_grasp)))
    run_lift = _executed(lift, cfg.lift)

    def lines(start: Array, run: tuple[Array, ...], dense: list[Array]) -> Array:
        pts = [np.array(dense)]
        prev = start
        for q in run:
            pts.append(joint_line(prev, q))
            prev = q
        return np.concatenate(pts)

    least = math.inf
    for Q, finger in (
        (lines(q_hover, run_descend, descend), opened),
        (lines(descend[-1], run_approach, approach), opened),
        (approach[-1][None, :], sweep),
        (lines(approach[-1], run_lift, lift), closed),
    ):
        c, what = check.least(Q, finger)
        if c < cfg.clearance:
            raise _Blocked(what)
        least = min(least, c)
    return _Moves(q_hover, run_descend, run_approach, run_lift, least)


def _candidate(
    bottle: BottleGeometry,
    yaw: float,
    standoff: float,
    pitch_deg: int,
    grasp_z: float,
    ahead: float,
    hover_z: float,
    check: Checker,
    cfg: GrabConfig,
    model: ArmModel,
) -> GraspCandidate:
    """One candidate from the side, checked (see the module docstring); _Blocked with what
    blocks it."""
    R = rpy_to_R(0.0, math.radians(pitch_deg), yaw)
    u = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    p_grasp = np.array([bottle.xy[0], bottle.xy[1], grasp_z]) - ahead * u
    p_pre = p_grasp - standoff * u
    p_hover = np.array([p_pre[0], p_pre[1], max(hover_z, p_pre[2])])
    closed = max(bottle.radius + FINGER_PAD_INSET, model.finger_limits[0])
    moves = _checked_moves(R, p_grasp, p_pre, p_hover, closed, check, cfg, model)
    bearing = math.atan2(bottle.xy[1], bottle.xy[0])
    facing = math.cos((yaw - bearing + math.pi) % (2 * math.pi) - math.pi)
    raise_m = grasp_z - bottle.grasp_z
    score = (
        min(moves.clearance, ENOUGH_CLEARANCE_M)
        + 0.01 * facing
        - 0.0002 * pitch_deg
        - 0.02 * raise_m
        - AHEAD_WEIGHT * ahead
    )
    return GraspCandidate(
        yaw,
        standoff,
        pitch_deg,
        grasp_z,
        ahead,
        moves.hover,
        moves.descend,
        moves.approach,
        moves.lift,
        moves.clearance,
        score,
    )


def _top_candidate(
    bottle: BottleGeometry,
    yaw: float,
    hover_z: float,
    check: Checker,
    cfg: GrabConfig,
    model: ArmModel,
) -> GraspCandidate:
    """One candidate from above, the fingers opening across ``yaw + 90`` degrees, checked;
    _Blocked with what blocks it. The gripper points straight down; the point between the
    fingertips stops :data:`TOP_BELOW_M` under the bottle's top, so the pads close on its cap
    and neck; it comes down from :data:`TOP_ABOVE_M` higher (the fingertips above the top)."""
    R = rpy_to_R(0.0, math.radians(TOP_PITCH_DEG), yaw)
    p_grasp = np.array([bottle.xy[0], bottle.xy[1], bottle.top - TOP_BELOW_M])
    p_pre = p_grasp + np.array([0.0, 0.0, TOP_ABOVE_M])
    p_hover = np.array([p_pre[0], p_pre[1], max(hover_z, p_pre[2])])
    closed = max(TOP_NECK_SHARE * bottle.radius + FINGER_PAD_INSET, model.finger_limits[0])
    moves = _checked_moves(R, p_grasp, p_pre, p_hover, closed, check, cfg, model)
    score = min(moves.clearance, ENOUGH_CLEARANCE_M) - TOP_PENALTY
    return GraspCandidate(
        yaw,
        TOP_ABOVE_M,
        TOP_PITCH_DEG,
        float(p_grasp[2]),
        0.0,
        moves.hover,
        moves.descend,
        moves.approach,
        moves.lift,
        moves.clearance,
        score,
    )


def hover_height(bottle: BottleGeometry, scene: PlanningScene, p_xy: Array) -> float:
    """Above the bottle and everything within :data:`HOVER_NEAR_M` of ``p_xy`` by
    :data:`HOVER_ABOVE_M`, at the grasp height at least (z, m)."""
    tops = [bottle.top]
    for b in scene.obstacles(bottle.track_id):
        if math.hypot(b.xy[0] - p_xy[0], b.xy[1] - p_xy[1]) < HOVER_NEAR_M + b.radius:
            tops.append(b.top)
    return max(max(tops) + HOVER_ABOVE_M, bottle.grasp_z)


def plan_grasps(
    track: TrackState,
    scene: PlanningScene,
    cfg: GrabConfig,
    model: ArmModel,
    allow_top: bool = True,
    stop: Callable[[], None] | None = None,
) -> list[GraspCandidate] | GraspRefusal:
    """Every free candidate for ``track``, best first; or why there is none. Grasps from
    above are tried when none from the side is free, if ``allow_top`` and
    ``grab.top_grasp``. ``stop`` is called before each candidate is checked (a task passes
    ``ctx.check``, so Stop ends a plan of seconds at once)."""
    bottle = BottleGeometry.of(track, cfg)
    check = Checker(scene, track.id, model)
    free: list[GraspCandidate] = []
    blockers: Counter[str] = Counter()
    unreachable = 0
    n = cfg.approach_candidates
    bearing = math.atan2(bottle.xy[1], bottle.xy[0])
    for k in range(n):
        yaw = bearing + 2.0 * math.pi * k / n
        yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
        found: GraspCandidate | None = None
        reasons: list[str] = []
        u = np.array([math.cos(yaw), math.sin(yaw)])
        options = [
            (max(share * cfg.standoff, MIN_STANDOFF_M), raise_share, pitch, ahead)
            for ahead in AHEADS_M
            for raise_share in GRASP_RAISES
            for share in STANDOFF_SHARES
            for pitch in PITCHES_DEG
        ]
        for standoff, raise_share, pitch, ahead in options:
            if stop is not None:
                stop()
            hover_z = hover_height(bottle, scene, bottle.xy - (standoff + ahead) * u)
            grasp_z = bottle.grasp_z + raise_share * bottle.height
            try:
                found = _candidate(
                    bottle, yaw, standoff, pitch, grasp_z, ahead, hover_z, check, cfg, model
                )
                break
            except _Blocked as exc:
                reasons.append(exc.what)
        if found is not None:
            free.append(found)
            continue
        hits = [r for r in reasons if r != "out of reach"]
        if hits:
            blockers[Counter(hits).most_common(1)[0][0]] += 1
        else:
            unreachable += 1
    if not free and allow_top and cfg.top_grasp:
        free, from_above = _top_candidates(bottle, scene, check, cfg, model)
    else:
        from_above = ""
    if free:
        return sorted(free, key=lambda c: -c.score)
    reason = refusal_reason(bottle, blockers, unreachable, n) + from_above
    return GraspRefusal(reason, tuple(blockers.most_common()), unreachable)


def _top_candidates(
    bottle: BottleGeometry, scene: PlanningScene, check: Checker, cfg: GrabConfig, model: ArmModel
) -> tuple[list[GraspCandidate], str]:
    """The free grasps from above over :data:`TOP_HEADINGS` finger headings, and, if there
    is none, what blocks them for the refusal ("; from above: blocked by ...")."""
    hover_z = hover_height(bottle, scene, bottle.xy)
    bearing = math.atan2(bottle.xy[1], bottle.xy[0])
    free: list[GraspCandidate] = []
    reasons: Counter[str] = Counter()
    for k in range(TOP_HEADINGS):
        yaw = bearing + math.pi * k / TOP_HEADINGS
        try:
            free.append(_top_candidate(bottle, yaw, hover_z, check, cfg, model))
        except _Blocked as exc:
            reasons[exc.what] += 1
    if free or not reasons:
        return free, ""
    what, count = reasons.most_common(1)[0]
    if what == "out of reach":
        return [], "; from above: out of the arm's reach"
    return [], f"; from above: blocked by {what} in {count} of {TOP_HEADINGS} finger headings"


def refusal_reason(bottle: BottleGeometry, blockers: Counter[str], unreachable: int, n: int) -> str:
    """ "every approach to bottle 3 at (x, y) m is blocked: by the cup (track 5) at ... in
    14 of 24 directions, ...; 6 out of the arm's reach"."""
    where = f"bottle {bottle.track_id} at ({bottle.xy[0]:.3f}, {bottle.xy[1]:.3f}) m"
    if not blockers:
        return f"no approach to {where} is within the arm's reach ({n} directions tried)"
    parts = [f"by {what} in {count} of {n} directions" for what, count in blockers.most_common(3)]
    rest = sum(blockers.values()) - sum(c for _, c in blockers.most_common(3))
    if rest:
        parts.append(f"by other objects in {rest}")
    text = f"every approach to {where} is blocked: " + ", ".join(parts)
    if unreachable:
        text += f"; {unreachable} out of the arm's reach"
    return text
