"""Set the held bottle down: ``place(x, y)`` or ``place(zone=NAME)``.

1. **What is held.** Inside a task that grabbed the bottle (sort) the :class:`~armvision.
   tasks.carry.Held` comes from that grasp. The ``place`` task sets down the bottle the
   system's newest successful ``grab`` task took (:meth:`System.last_status
   <armvision.runtime.system.System.last_status>`), as long as the fingers still close on
   something: between the empty-closed gap plus :data:`~armvision.tasks.grab.GRASP_MARGIN_M`
   (:data:`~armvision.tasks.grab.TOP_GRASP_MARGIN_M` for a grasp from above, by the cap) and
   the open gap; otherwise it fails with "nothing is held" and nothing moves.
2. **The spot.** ``(x, y)``: that spot; ``zone``: a free spot inside the named rectangle of
   ``place.zones`` (the bottle's footprint wholly inside it), the candidates of a
   :data:`ZONE_STEP_M` grid tried from the zone's corner farthest from the base, so bottles
   set down one after the other fill the zone from the back. A spot is free
   (:func:`spot_refusal`) when the bottle's footprint keeps ``place.clearance`` to every body
   and occupied cell of the planning scene (but the held bottle itself: its track, and
   whatever stands within reach of the fingers, the bottle seen in the gripper), the fingers'
   short way out toward the base is clear, and it lies within :data:`TABLE_RADIUS_M` of the
   base axis and beyond ``grab.min_base_distance``.
3. **The set-down** (:func:`plan_set_down`), planned whole before anything moves: straight up
   to the carry height (above everything on the table, :class:`~armvision.tasks.carry.Held`),
   straight across to above the spot while turning about the vertical only (the bottle stays
   upright whichever side the collision-aware grasp came from), straight down to the release
   height, open, back out along the gripper's own axis (held from above: none), up; with
   the spot already under the bottle (putting it back), straight down; every configuration
   checked against the planning scene as the grasp's are. Setting a bottle aside out of a
   cluster (the sort), the set-down is ``low``: no climb, the bottle slides across at the
   height it was lifted to with its own body checked against every other body
   (:func:`held_body_clearance`). A bottle held ``ahead`` of the
   point between the fingertips (a shallow grasp) is set down with that point short of the
   spot by as much. Then to the grasp's safe start pose, out
   of the camera's view (:meth:`Carrier.go_safe <armvision.tasks.carry.Carrier.go_safe>`).
   A spot off the table, taken or out of reach, an unknown zone, a full zone give a one-line
   reason and no motion.
4. **The check.** Within ``place.verify_s`` the bottle must be tracked again (a bottle track
   seen since the release within :data:`FIND_M` of the spot): ``placed`` is its tracked
   (x, y), ``error_m`` its distance to the asked spot, ``upright`` whether its tracked
   height is within ``place.height_tolerance`` of the held bottle's (a bottle lying down is
   not a standing cylinder of its height). ``ok`` when it stands within ``place.tolerance``.

Units: metres, radians; positions in the base frame. Stop halts the arm where it is at once
(TaskStopped propagates from every wait of the context).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.config import Config
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T, rot_z, rpy_to_R
from armvision.robot.kinematics import ArmModel, fk, ik
from armvision.runtime.context import TaskContext, TaskError
from armvision.runtime.planning_scene import Body, PlanningScene
from armvision.tasks.carry import (
    BACKOFF_MARGIN_M,
    CARRY_SPEED_M_S,
    EMPTY_MAX_PITCH_DEG,
    RELEASE_HEIGHT_M,
    STAND_BACK_M,
    Abort,
    Carrier,
    Held,
    held_body_clearance,
    scene_without_held,
)
from armvision.tasks.grab import (
    GRASP_MARGIN_M,
    HOVER_CLEARANCE_M,
    TOP_GRASP_MARGIN_M,
    GrabResult,
)
from armvision.tasks.grasp_plan import (
    CHECK_STEP_M as CHECK_STEP,
)
from armvision.tasks.grasp_plan import (
    MAX_STEP_RAD,
    TOP_ABOVE_M,
    TOP_PITCH_DEG,
    Checker,
    _Blocked,
    _executed,
    _straight,
)
from armvision.tasks.motion import SEGMENT_TIME_S, paced_time, unflipped_ik

Array = NDArray[np.float64]

#: Spots farther than this from the base axis are off the simulated bench's table (and
#: beyond the ViperX-300s's reach with a bottle), m.
TABLE_RADIUS_M = 0.7
#: The zone's candidate spots: a grid of this pitch, m.
ZONE_STEP_M = 0.02
#: After the release, the bottle's new track is looked for this far from the spot, m.
FIND_M = 0.08
#: The back-off strip: half as wide as the open gripper's fingers, m.
FINGER_HALF_WIDTH_M = 0.05


class PlaceError(TaskError):
    """A place that cannot be made; the message says why (nothing moved)."""


@dataclass(frozen=True)
class PlaceResult:
    """What the place did. ``ok`` when the bottle was set down and is tracked standing within
    ``place.tolerance`` of the asked spot.

    ``asked`` the spot (x, y) aimed at (inside ``zone`` if one was named); ``placed`` the
    bottle's tracked (x, y) afterwards (None if it was not found); ``error_m`` their distance;
    ``upright`` whether it is tracked standing at its height; ``released`` whether the
    gripper opened at the spot; ``duration_s`` clock seconds.
    """

    ok: bool
    reason: str
    zone: str | None = None
    asked: tuple[float, float] | None = None
    placed: tuple[float, float] | None = None
    error_m: float | None = None
    upright: bool | None = None
    released: bool = False
    track_id: int | None = None
    duration_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        def xy(v: tuple[float, float] | None) -> list[float] | None:
            return None if v is None else [round(float(c), 4) for c in v]

        return {
            "ok": self.ok,
            "reason": self.reason,
            "zone": self.zone,
            "asked": xy(self.asked),
            "placed": xy(self.placed),
            "error_m": None if self.error_m is None else round(self.error_m, 4),
            "upright": self.upright,
            "released": self.released,
            "track_id": self.track_id,
            "duration_s": round(self.duration_s, 3),
        }


def zone_rect(config: Config, name: str) -> tuple[float, float, float, float]:
    """The rectangle (x_min, y_min, x_max, y_max) of zone ``name``; PlaceError if unknown."""
    zones = config.place.zones
    if name not in zones:
        known = ", ".join(sorted(zones)) or "none"
        raise PlaceError(f"no zone {name!r} in place.zones (zones: {known})")
    return zones[name]


def _reach_poses(xy: Array, held: Held) -> list[tuple[Array, float, int]]:
    """The set-down's poses at spot ``xy``: (x, y, z), yaw, the pitch allowed (degrees)."""
    d = float(np.linalg.norm(xy))
    yaw = math.atan2(xy[1], xy[0])
    back = xy * max(d - held.radius - BACKOFF_MARGIN_M, 0.0) / max(d, 1e-9)
    top = held.table_z + held.height + HOVER_CLEARANCE_M
    grip = held.grip_xy(xy, yaw)
    if held.from_above:  # pointing down; released, straight up
        return [
            (np.array([grip[0], grip[1], held.grasp_z]), yaw, TOP_PITCH_DEG),
            (np.array([grip[0], grip[1], held.carry_z]), yaw, TOP_PITCH_DEG),
            (np.array([grip[0], grip[1], held.grasp_z + TOP_ABOVE_M]), yaw, TOP_PITCH_DEG),
        ]
    return [
        (np.array([grip[0], grip[1], held.grasp_z]), yaw, 0),
        (np.array([grip[0], grip[1], held.carry_z]), yaw, 0),
        (np.array([back[0], back[1], held.grasp_z]), yaw, EMPTY_MAX_PITCH_DEG),
        (np.array([back[0], back[1], top]), yaw, EMPTY_MAX_PITCH_DEG),
    ]


def reachable(xy: Array, held: Held, model: ArmModel) -> bool:
    """Whether the arm reaches every pose of the set-down at ``xy`` (level where it holds
    the bottle, pitched down up to the carrying rule's limit where it is empty)."""
    for p, yaw, max_pitch in _reach_poses(xy, held):
        pitches = [TOP_PITCH_DEG] if held.from_above else range(0, max_pitch + 1, 5)
        if not any(
            unflipped_ik(make_T(rpy_to_R(0.0, math.radians(pitch), yaw), p), model.home, model)
            is not None
            for pitch in pitches
        ):
            return False
    return True


def _strip_distance(q: Array, a: Array, b: Array) -> float:
    ab = b - a
    s = float(np.clip((q - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(q - (a + s * ab)))


def spot_refusal(
    xy: Array,
    held: Held,
    obstacles: Sequence[Body],
    clearance: float,
    min_base_distance: float,
    model: ArmModel,
    check_reach: bool = True,
) -> str | None:
    """Why the bottle cannot be set down at ``xy`` (the module docstring's step 2), or None.
    ``check_reach``: also whether the arm reaches it facing it from the base (before the
    grasp; once it is held, :func:`plan_set_down` decides)."""
    d = float(np.linalg.norm(xy))
    where = f"({xy[0]:.3f}, {xy[1]:.3f}) m"
    if d > TABLE_RADIUS_M:
        return (
            f"the spot {where} is off the table ({d:.2f} m from the base axis, at most "
            f"{TABLE_RADIUS_M} m)"
        )
    if d < max(min_base_distance, held.radius + 0.1):
        return f"the spot {where} is too near the base ({d:.2f} m from its axis)"
    back = xy * max(d - held.radius - BACKOFF_MARGIN_M, 0.0) / max(d, 1e-9)
    for b in obstacles:
        q = np.asarray(b.xy, dtype=float)
        if np.linalg.norm(q - xy) < held.radius + b.radius + clearance:
            return f"the spot {where} is taken: {b.describe()} is there"
        if _strip_distance(q, back, xy) < FINGER_HALF_WIDTH_M + b.radius:
            return f"the fingers could not back off from {where}: {b.describe()} is in the way"
    if check_reach and not reachable(xy, held, model):
        return f"the arm cannot reach the spot {where} to set the bottle down level"
    return None


def zone_candidates(rect: tuple[float, float, float, float], radius: float) -> Array:
    """Spots for a bottle of ``radius`` wholly inside ``rect``, a :data:`ZONE_STEP_M` grid,
    from the rectangle's corner farthest from the base."""
    x0, y0, x1, y1 = rect
    r = radius
    xs = np.arange(x0 + r, x1 - r + 1e-9, ZONE_STEP_M)
    ys = np.arange(y0 + r, y1 - r + 1e-9, ZONE_STEP_M)
    if not len(xs) or not len(ys):
        return np.zeros((0, 2))
    corners = np.array([[x0 + r, y0 + r], [x0 + r, y1 - r], [x1 - r, y0 + r], [x1 - r, y1 - r]])
    far = corners[int(np.argmax(np.linalg.norm(corners, axis=1)))]
    grid = np.array([(x, y) for x in xs for y in ys])
    return grid[np.argsort(np.linalg.norm(grid - far, axis=1), kind="stable")]


def zone_spot(
    rect: tuple[float, float, float, float],
    held: Held,
    obstacles: Sequence[Body],
    clearance: float,
    min_base_distance: float,
    model: ArmModel,
) -> Array | None:
    """The first of :func:`zone_candidates` free for the held bottle and reachable facing it
    from the base (:func:`spot_refusal`); None if none."""
    for xy in zone_candidates(rect, held.radius):
        if spot_refusal(xy, held, obstacles, clearance, min_base_distance, model) is None:
            return np.asarray(xy, dtype=float)
    return None


#: Releasing, the fingertips (this far ahead of the gripper's point) back off until they are
#: :data:`~armvision.tasks.carry.BACKOFF_MARGIN_M` clear of the bottle, m.
FINGERTIP_AHEAD_M = 0.03
#: Carrying, the gripper's turns about the vertical are tried in steps of this, degrees.
TURN_STEP_DEG = 30
#: Every configuration of the set-down keeps this clearance to the scene, m.
SET_DOWN_CLEARANCE_M = 0.005
#: A set-down at the height the bottle was lifted to (``low``, setting it aside): its body
#: keeps this clearance to every other body while it slides, or (bottles 1 cm apart) comes
#: no nearer than 2 mm closer than where it was taken, m.
SLIDE_CLEARANCE_M = 0.01


@dataclass(frozen=True)
class SetDown:
    """The set-down's joint configurations, checked: ``carry`` (up to the carry height and
    across, fingers closed), ``lower`` (straight down to the release height), ``back`` and
    ``rise`` (fingers open: out the way the gripper came in, then up); each step's moves in
    order, at most :data:`~armvision.tasks.grasp_plan.EXECUTE_STEP_M` apart."""

    spot: Array
    carry: tuple[Array, ...]
    lower: tuple[Array, ...]
    back: tuple[Array, ...]
    rise: tuple[Array, ...]


def _turning_line(
    q_from: Array, p_from: Array, p_to: Array, R_from: Array, turn: float, model: ArmModel
) -> list[Array]:
    """Configurations every :data:`~armvision.tasks.grasp_plan.CHECK_STEP_M` (and 5 degrees
    of turn) along the straight line ``p_from`` to ``p_to``, the gripper turning evenly by
    ``turn`` about the vertical from ``R_from`` (a held bottle stays upright), each near the
    one before; _Blocked if one is unreachable or jumps."""
    length = float(np.linalg.norm(p_to - p_from))
    n = max(1, math.ceil(length / CHECK_STEP), math.ceil(abs(turn) / math.radians(5.0)))
    out = [q_from]
    for k in range(1, n + 1):
        s = k / n
        T = make_T(rot_z(s * turn) @ R_from, p_from + s * (p_to - p_from))
        q, ok = ik(T, out[-1], model)
        if not ok or float(np.max(np.abs(q - out[-1]))) > MAX_STEP_RAD:
            raise _Blocked("out of reach")
        out.append(q)
    return out


def _heading(R: Array) -> float:
    """The yaw of a gripper orientation's x axis (its approach direction) in the base's xy
    plane."""
    return math.atan2(R[1, 0], R[0, 0])


def _turns(yaw_now: float, spot: Array) -> list[float]:
    """Turns to try while carrying: facing the spot from the base first, none, then every
    :data:`TURN_STEP_DEG` by nearness to the first."""
    facing = math.atan2(spot[1], spot[0])
    first = (facing - yaw_now + math.pi) % (2 * math.pi) - math.pi
    steps = [math.radians(d) for d in range(-180 + TURN_STEP_DEG, 180, TURN_STEP_DEG)]
    rest = sorted(steps, key=lambda t: abs((t - first + math.pi) % (2 * math.pi) - math.pi))
    return [first, 0.0, *rest]


def plan_set_down(
    q_now: Array,
    T_now: Array,
    spot: Array,
    held: Held,
    scene: PlanningScene,
    finger_closed: float,
    model: ArmModel,
    low: bool = False,
    stop: Callable[[], None] | None = None,
) -> SetDown | str:
    """The set-down at ``spot`` from the arm at ``q_now`` (pose ``T_now``, holding the bottle),
    or why not: straight up to the carry height, straight across while turning about the
    vertical (the bottle stays upright; the collision-aware grasp may have come from any side,
    so the turns of :func:`_turns` are tried until one keeps the arm on one IK branch),
    straight down, open, back along the gripper's own axis (held from above: none), up.
    With the spot under the bottle already (putting it back), straight down. Every
    configuration is checked against ``scene`` (the held bottle left out). ``low``: no climb
    to the carry height; the bottle slides across at the height it is held at (out of a
    cluster of bottles as tall as it, over which the arm cannot lift it), its own body checked
    against every body of the scene (:func:`held_body_clearance`, :data:`SLIDE_CLEARANCE_M`)
    while it slides and is lowered. ``stop`` is called before each option is checked (Stop
    ends a task planning here at once)."""
    R0 = T_now[:3, :3]
    p0 = T_now[:3, 3]
    carry_z = float(p0[2]) if low else max(held.carry_z, float(p0[2]))
    if float(np.linalg.norm(p0[:2] - held.grip_xy(spot, _heading(R0)))) < STAND_BACK_M:
        carry_z = float(p0[2])  # the spot is under the bottle (put back): straight down
    release_z = held.grasp_z + RELEASE_HEIGHT_M
    p_up = np.array([p0[0], p0[1], carry_z])
    top = held.table_z + held.height + HOVER_CLEARANCE_M
    where = f"({spot[0]:.3f}, {spot[1]:.3f}) m"
    check = Checker(scene, None, model)
    opened = model.finger_limits[1]
    why = f"the arm cannot carry the bottle, held as it is, to {where}"
    # Held from above, the gripper's heading does not matter: no turn first.
    turns = _turns(0.0, np.array([1.0, 0.0])) if held.from_above else _turns(_heading(R0), spot)
    turns = list(dict.fromkeys(turns))
    options = [
        (turn, during_lift)
        for turn in turns
        for during_lift in (False, True)
        if not (during_lift and turn == 0.0)
    ]
    # Never ask more of the carry than its start has (a neighbour's track swells while the
    # arm hides it), as the grasp's transit does.
    # The lift starts where the grasp left the arm, which the grasp checked; a track the arm
    # now hides may have swollen around it, so the lift only has to get no nearer than that.
    start_clearance, _ = check.least(q_now[None, :], finger_closed)
    lift_needed = min(SET_DOWN_CLEARANCE_M, start_clearance - 0.002)
    carry_needed = min(SET_DOWN_CLEARANCE_M, max(start_clearance - 0.002, 0.0))
    # Sliding out of a cluster the bottle gets no nearer to anything than where it stood
    # (its neighbours' bodies, grown by their uncertainty, may reach it there).
    bodies = check.obstacles if low else ()
    slide_needed = 0.0
    if low:
        held_start, _ = held_body_clearance(q_now[None, :], held, bodies, model)
        slide_needed = min(SLIDE_CLEARANCE_M, held_start - 0.002)
    for turn, during_lift in options:
        if stop is not None:
            stop()
        R = rot_z(turn) @ R0
        u = np.array([R[0, 0], R[1, 0], 0.0])
        u /= max(float(np.linalg.norm(u)), 1e-9)
        # The gripper heads along u: the point between the fingertips stands short of the spot
        # by how far ahead of it the bottle is held.
        grip = held.grip_xy(spot, math.atan2(u[1], u[0]))
        p_above = np.array([grip[0], grip[1], carry_z])
        p_release = np.array([grip[0], grip[1], release_z])
        if held.from_above:  # open, then straight up until the fingertips clear the cap
            p_back = p_release
            p_rise = p_release + np.array([0.0, 0.0, TOP_ABOVE_M])
        else:
            p_back = p_release - (held.radius + BACKOFF_MARGIN_M + FINGERTIP_AHEAD_M) * u
            p_rise = np.array([p_back[0], p_back[1], max(top, release_z)])
        lift_turn = turn if during_lift else 0.0
        try:
            up = _turning_line(q_now, p0, p_up, R0, lift_turn, model)
            across = _turning_line(
                up[-1], p_up, p_above, rot_z(lift_turn) @ R0, turn - lift_turn, model
            )
            down = _straight(across[-1], p_above, p_release, R, model)
            back = _straight(down[-1], p_release, p_back, R, model)
            rise = _straight(back[-1], p_back, p_rise, R, model)
        except _Blocked:
            continue
        hit = None
        for what, qs, finger, needed in (
            ("lifting it", up, finger_closed, lift_needed),
            ("carrying it", across, finger_closed, carry_needed),
            ("lowering it", down, finger_closed, SET_DOWN_CLEARANCE_M),
            ("backing off", back, opened, SET_DOWN_CLEARANCE_M),
            ("rising", rise, opened, SET_DOWN_CLEARANCE_M),
        ):
            clearance, thing = check.least(np.array(qs), finger)
            if clearance < needed:
                hit = (
                    f"{what} to {where} the arm would come within {1000 * clearance:.0f} mm "
                    f"of {thing}"
                )
                break
        if hit is None and low:
            for what, qs in (("sliding it", across), ("lowering it", down)):
                clearance, thing = held_body_clearance(qs, held, bodies, model)
                if clearance < slide_needed:
                    hit = (
                        f"{what} to {where} the bottle would come within "
                        f"{1000 * clearance:.0f} mm of {thing}"
                    )
                    break
        if hit is not None:
            why = hit
            continue
        return SetDown(
            spot,
            _executed(up, float(carry_z - p0[2]))
            + _executed(across, max(float(np.linalg.norm(p_above - p_up)), 0.01)),
            _executed(down, float(carry_z - release_z)),
            _executed(back, float(np.linalg.norm(p_back - p_release))),
            _executed(rise, float(p_rise[2] - p_back[2])),
        )
    return why


class Placer:
    """Plans and makes the set-down of the held bottle, and checks where it stands."""

    def __init__(
        self,
        ctx: TaskContext,
        held: Held,
        held_track: int | None,
        scene: PlanningScene | None = None,
    ) -> None:
        """``scene``: plan against this one (the scene before the grasp, whose tracks the
        arm did not hide) instead of the current one."""
        self.ctx, self.held, self.held_track = ctx, held, held_track
        self.base_scene = scene
        self.start = ctx.now()
        self.where = "held by the gripper"

    def scene(self) -> tuple[PlanningScene, list[Body]]:
        """The planning scene without the held bottle, and its obstacles."""
        grip = np.asarray(self.ctx.arm.get_ee_pose(), dtype=float)[:2, 3]
        full = self.base_scene or self.ctx.state().planning_scene
        return scene_without_held(full, self.held_track, grip, self.held.radius)

    def plan(
        self,
        xy: Array,
        scene: PlanningScene,
        obstacles: list[Body],
        footprint: bool = True,
        low: bool = False,
    ) -> SetDown | str:
        """The set-down at ``xy`` or why not; ``footprint`` False: the spot is not checked
        for room (putting the bottle back where it stood); ``low``: slid across at the height
        it is held at (:func:`plan_set_down`)."""
        ctx, cfg = self.ctx, self.ctx.config.place
        why = (
            None
            if not footprint
            else spot_refusal(
                xy,
                self.held,
                obstacles,
                cfg.clearance,
                ctx.config.grab.min_base_distance,
                ctx.arm.model,
                check_reach=False,
            )
        )
        if why is not None:
            return why
        q_now = np.asarray(ctx.arm.get_joint_positions(), dtype=float)
        T_now = fk(q_now, ctx.arm.model)
        finger = float(ctx.arm.gripper.get_finger_position())
        return plan_set_down(
            q_now, T_now, xy, self.held, scene, finger, ctx.arm.model, low, ctx.check
        )

    def choose(
        self,
        x: float | None,
        y: float | None,
        zone: str | None,
        footprint: bool = True,
        low: bool = False,
    ) -> SetDown:
        """The set-down to make; PlaceError (nothing moved) if there is none. ``low``: at
        ``(x, y)``, slid there at the height the bottle is held at (:func:`plan_set_down`)."""
        scene, obstacles = self.scene()
        if zone is not None:
            x0, y0, x1, y1 = zone_rect(self.ctx.config, zone)
            last = "no spot fits"
            for xy in zone_candidates((x0, y0, x1, y1), self.held.radius):
                found = self.plan(xy, scene, obstacles)
                if isinstance(found, SetDown):
                    return found
                last = found
            raise PlaceError(
                f"zone {zone!r} has no free spot the arm can set this bottle down on "
                f"(radius {100 * self.held.radius:.1f} cm; last: {last})"
            )
        if x is None or y is None:
            raise PlaceError("say where: place(x, y) in metres, or place(zone=NAME)")
        xy = np.array([float(x), float(y)])
        if not np.all(np.isfinite(xy)):
            raise PlaceError(f"the spot ({x}, {y}) is not a finite position in metres")
        found = self.plan(xy, scene, obstacles, footprint, low)
        if isinstance(found, str):
            raise PlaceError(found)
        return found

    def run(self, what: str, qs: tuple[Array, ...], speed: float = CARRY_SPEED_M_S) -> None:
        """Move through ``qs`` (near-straight moves), each paced within the joint limits."""
        ctx = self.ctx
        model = ctx.arm.model
        for q in qs:
            T_prev = np.asarray(ctx.arm.get_ee_pose(), dtype=float)
            length = float(np.linalg.norm(fk(q, model)[:3, 3] - T_prev[:3, 3]))
            duration = paced_time(ctx.arm, q, max(SEGMENT_TIME_S, length / speed))
            if not ctx.move_joints(q, moving_time=duration):
                raise Abort(f"{what}: {ctx.arm.last_error or 'the arm refused the move'}")

    def set_down(self, plan: SetDown, zone: str | None) -> PlaceResult:
        """Carry, stand, release, back off, go to the safe pose, then check (module doc)."""
        ctx = self.ctx
        spot = plan.spot
        asked = (float(spot[0]), float(spot[1]))
        where = f"({asked[0]:.3f}, {asked[1]:.3f}) m" + ("" if zone is None else f" in {zone!r}")
        ctx.progress(0.3, f"carrying the bottle to {where}")
        try:
            self.run("carry", plan.carry)
            self.run("lower onto the table", plan.lower)
            ctx.open_gripper()
            self.where = f"standing at {where}"
            self.run("back off", plan.back)
            self.run("rise", plan.rise)
            carrier = Carrier(ctx, ctx.config.grab)
            carrier.go_safe()
        except Abort as exc:
            released = self.where.startswith("standing")
            return self.result(
                False, f"{exc}; the bottle is {self.where}", zone, asked, released=released
            )
        ctx.progress(0.85, f"checking the bottle stands at {where}")
        return self.verify(spot, zone, where)

    def verify(self, spot: Array, zone: str | None, where: str) -> PlaceResult:
        ctx, cfg = self.ctx, self.ctx.config.place
        held = self.held
        since = ctx.now()

        def found() -> TrackState | None:
            state = ctx.state()
            near = [
                t
                for t in state.bottles()
                if t.last_seen >= since and np.linalg.norm(t.p_base[:2] - spot) < FIND_M
            ]
            return min(near, key=lambda t: float(np.linalg.norm(t.p_base[:2] - spot)), default=None)

        ctx.wait_until(lambda: found() is not None, cfg.verify_s)
        # Let the fresh track settle a little (its first fixes are the least certain).
        ctx.sleep(min(1.0, max(cfg.verify_s - (ctx.now() - since), 0.0)))
        track = found()
        if track is None:
            return self.result(
                False,
                f"released at {where}, but no bottle is tracked there within "
                f"{cfg.verify_s:.0f} s (did it fall?)",
                zone,
                (float(spot[0]), float(spot[1])),
                released=True,
            )
        placed = (float(track.p_base[0]), float(track.p_base[1]))
        error = float(np.linalg.norm(np.asarray(placed) - spot))
        height = track.height
        upright = (
            height is not None and abs(height - held.height) <= cfg.height_tolerance * held.height
        )
        ok = upright and error <= cfg.tolerance
        if ok:
            why = f"set down at {where}: tracked {100 * error:.1f} cm from the spot, upright"
        elif not upright:
            why = (
                f"set down at {where}, but the bottle there does not stand at its height (fallen?)"
            )
        else:
            why = (
                f"set down at {where}, but it is tracked {100 * error:.1f} cm from the spot "
                f"(more than {100 * cfg.tolerance:.0f} cm)"
            )
        return self.result(
            ok, why, zone, (float(spot[0]), float(spot[1])), placed, error, upright, True, track.id
        )

    def result(
        self,
        ok: bool,
        reason: str,
        zone: str | None,
        asked: tuple[float, float] | None = None,
        placed: tuple[float, float] | None = None,
        error: float | None = None,
        upright: bool | None = None,
        released: bool = False,
        track_id: int | None = None,
    ) -> PlaceResult:
        return PlaceResult(
            ok,
            reason,
            zone,
            asked,
            placed,
            error,
            upright,
            released,
            track_id,
            self.ctx.now() - self.start,
        )


def holding(ctx: TaskContext, from_above: bool = False) -> bool:
    """Whether the fingers close on something: between empty-closed (plus the grasp margin,
    that of a grasp from above if ``from_above``) and open (minus the margin)."""
    lo, hi = ctx.arm.model.finger_limits
    finger = float(ctx.arm.gripper.get_finger_position())
    margin = TOP_GRASP_MARGIN_M if from_above else GRASP_MARGIN_M
    return lo + margin < finger < hi - GRASP_MARGIN_M


def held_from_last_grab(ctx: TaskContext) -> tuple[Held, int | None]:
    """The bottle the newest successful grab task holds (module docstring, step 1);
    PlaceError if nothing is held."""
    status = ctx.system.last_status("grab")
    result = None if status is None else status.result
    from_above = bool(result and result.get("from_above"))
    if not holding(ctx, from_above):
        raise PlaceError("nothing is held: grab a bottle first (the gripper is open or empty)")
    if status is None or status.phase != "succeeded" or not result or not result.get("ok"):
        raise PlaceError(
            "nothing is held that a grab took: grab a bottle first (the fingers hold "
            "something no grab task picked up)"
        )
    grabbed = GrabResult(
        ok=True,
        reason=str(result.get("reason", "")),
        track_id=result.get("track_id"),
        target=tuple(result["target"]),
        height=result.get("height"),
        grasp_z=result.get("grasp_z"),
        finger=result.get("finger"),
        ahead=float(result.get("ahead") or 0.0),
        from_above=from_above,
    )
    state = ctx.state()
    track_id = grabbed.track_id
    track = state.track(track_id) if track_id is not None else None
    fake = track if track is not None else _track_stub(grabbed)
    tops = [b.top for b in state.planning_scene.obstacles(track_id)]
    finger = float(ctx.arm.gripper.get_finger_position())
    return Held.from_grab(grabbed, finger, fake, tops, ctx.config.grab), track_id


def _track_stub(grabbed: GrabResult) -> TrackState:
    """Stands in for the held bottle's track once the tracker dropped it: only its radius
    is read (by :meth:`Held.from_grab`, when the fingers' is implausible)."""
    assert grabbed.target is not None
    return TrackState(
        id=-1,
        label="bottle",
        confirmed=True,
        t=0.0,
        p_base=np.asarray(grabbed.target, dtype=float),
        v_base=np.zeros(3),
        cov=np.eye(6) * 1e-4,
        hits=0,
        last_seen=0.0,
        votes=(),
        radius=0.03,
        height=grabbed.height,
    )


def place(
    ctx: TaskContext, x: float | None = None, y: float | None = None, zone: str | None = None
) -> PlaceResult:
    """Set the held bottle down at ``(x, y)`` or on a free spot of ``zone`` and check it
    stands there (the module docstring). Bad input or no spot: PlaceError, nothing moves."""
    if zone is not None and (x is not None or y is not None):
        raise PlaceError("give either a spot (x, y) or a zone, not both")
    if zone is not None:
        zone_rect(ctx.config, zone)  # an unknown zone fails before anything else
    ctx.require_aim()
    held, track_id = held_from_last_grab(ctx)
    placer = Placer(ctx, held, track_id)
    plan = placer.choose(x, y, zone)
    return placer.set_down(plan, zone)
