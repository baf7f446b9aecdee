"""Carrying a picked bottle for analyze: lift, carry upright, stand it down, back off, take it up.

:class:`Held` is the picked bottle (its radius from the closed fingers, its height, the table,
the grasp and carry heights, the grasp's pitch, where it came from). :class:`Carrier` moves the
arm with it: every move is a straight line in short segments (:meth:`Carrier.straight`), each
point reached on the wrist branch the arm is on (unflipped, or as a collision-aware grasp left
it: :func:`~armvision.tasks.motion.level_pose`); a held bottle is moved at the pitch it was
grasped at (level, or pitched down where the grasp near the base had to be: the bottle stood
upright between the fingers then, so it stays upright), an empty gripper at that pitch, level,
or pitched down up to :data:`EMPTY_MAX_PITCH_DEG`. :meth:`Carrier.put_down` carries the bottle
above everything else on the table (where the arm cannot lift it that high, above what stands
in its way: :meth:`Carrier.lower_carry`) to a spot, stands it there and releases it,
:meth:`Carrier.retreat` backs the gripper off behind it and up out of the camera's view,
:meth:`Carrier.pick_up` grasps it again there, :meth:`Carrier.go_safe` goes to the grasp's safe
start pose. A move that cannot be made raises :class:`Abort` with the reason.

Units: metres, seconds, radians unless named ``_deg``; positions in the base frame.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.config import GrabConfig
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T
from armvision.robot.kinematics import ArmModel, fk, ik
from armvision.robot.vx300s import FINGER_PAD_INSET
from armvision.runtime.context import TaskContext
from armvision.runtime.planning_scene import Body, PlanningScene
from armvision.tasks.collision import signed_gap
from armvision.tasks.grab import HOVER_CLEARANCE_M, GrabResult, holding, safe_start_pose
from armvision.tasks.grasp_plan import Checker, joint_line
from armvision.tasks.motion import SEGMENT_TIME_S, level_pose, motion_seed, paced_time

Array = NDArray[np.float64]

#: A finger-measured radius outside this range is not believed (the track's is used), m.
RADIUS_RANGE_M = (0.01, 0.07)
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
#: always carried at the grasp's pitch, so it stays upright.
EMPTY_MAX_PITCH_DEG = 90
#: A bottle that cannot be carried is stood back where it was taken if the gripper is still
#: this near above that spot, m.
STAND_BACK_M = 0.01
#: Scene bodies and cells whose centre is this near the gripper (beyond the held bottle's
#: radius) are the held bottle itself, as the camera sees it in the fingers, m.
HELD_MARGIN_M = 0.04
#: Where the carry height above everything on the table is out of reach, lower ones are tried
#: down to the lift's height in steps of this, m (:meth:`Carrier.put_down`) ...
LOWER_CARRY_STEP_M = 0.02
#: ... each taken only if the arm keeps this clearance to the planning scene ...
LOWER_ARM_CLEARANCE_M = 0.005
#: ... and the held bottle's body this clearance to every other body, m.
LOWER_HELD_CLEARANCE_M = 0.01


def _cannot_reach(p: ArrayLike, yaw: float) -> str:
    where = ", ".join(f"{v:.3f}" for v in np.asarray(p, dtype=float))
    return f"the gripper cannot reach ({where}) m facing {math.degrees(yaw):.0f} degrees"


def _segments(
    p_from: Array, yaw_from: float, p_goal: ArrayLike, yaw_goal: float
) -> list[tuple[Array, float, float]]:
    """The points of a straight move (position, yaw, the segment's length): segments at most
    :data:`SEGMENT_M` long, the yaw turning evenly by the shorter way, 20 degrees a segment
    at most."""
    turn = (yaw_goal - yaw_from + math.pi) % (2 * math.pi) - math.pi
    p_goal = np.asarray(p_goal, dtype=float)
    length = float(np.linalg.norm(p_goal - p_from))
    n = max(1, math.ceil(length / SEGMENT_M), math.ceil(abs(turn) / math.radians(20.0)))
    return [
        ((1 - k / n) * p_from + (k / n) * p_goal, yaw_from + (k / n) * turn, length / n)
        for k in range(1, n + 1)
    ]


class Abort(Exception):  # noqa: N818 - control flow inside the analyze task
    """Ends the analysis with a reason (becomes AnalyzeResult.ok = False)."""


def grasp_pitch_deg(T_base_ee: ArrayLike) -> int:
    """How far down a gripper pose is pitched about its own y axis, degrees, to the nearest
    5 (both grasp planners pitch in 5 degree steps; the reading's error is far smaller)."""
    R = np.asarray(T_base_ee, dtype=float)[:3, :3]
    pitch = math.degrees(math.asin(float(np.clip(-R[2, 0], -1.0, 1.0))))
    return 5 * round(pitch / 5)


def _yaw(T_base_x: Array) -> float:
    """Heading of a pose's x axis in the base's xy plane, rad."""
    return math.atan2(T_base_x[1, 0], T_base_x[0, 0])


@dataclass(frozen=True)
class Held:
    """The picked bottle: its geometry, where it came from and how it is carried, metres;
    ``ahead``: its axis stands this far ahead of the point between the fingertips, along the
    gripper's heading (a shallow grasp; 0 for a full-depth one); ``from_above``: held by the
    cap, the gripper pointing down (:class:`Carrier`'s moves are not for such a bottle; the
    place task's are); ``pitch_deg``: how far down the gripper was pitched about its own y
    axis (the fingers' closing axis) when it closed on the standing bottle, degrees
    (:func:`grasp_pitch_deg`)."""

    radius: float
    height: float
    table_z: float
    grasp_offset: float
    carry_z: float
    home_xy: Array
    ahead: float = 0.0
    from_above: bool = False
    pitch_deg: int = 0

    @property
    def grasp_z(self) -> float:
        return self.table_z + self.grasp_offset

    @staticmethod
    def from_grab(
        grabbed: GrabResult,
        finger: float,
        track: TrackState,
        obstacle_tops: Sequence[float],
        gcfg: GrabConfig,
        pitch_deg: int = 0,
    ) -> Held:
        """The radius from the closed fingers (the track's if implausible, or held from above:
        the fingers closed on the cap), height, table and grasp height from the grasp, the
        carry height above every other object's top (``obstacle_tops``)."""
        assert grabbed.target is not None and grabbed.grasp_z is not None
        height = float(grabbed.height if grabbed.height is not None else 2.0 * grabbed.target[2])
        table_z = grabbed.target[2] - 0.5 * height
        grasp_offset = grabbed.grasp_z - table_z
        radius = finger - FINGER_PAD_INSET  # closed on a bottle, finger = radius + inset
        if grabbed.from_above or not RADIUS_RANGE_M[0] <= radius <= RADIUS_RANGE_M[1]:
            radius = float(track.radius or 0.03)  # from above, the fingers measured the cap
        tallest = max([table_z, *obstacle_tops])
        carry_z = max(tallest + CARRY_CLEARANCE_M + grasp_offset, grabbed.grasp_z + gcfg.lift)
        return Held(
            radius,
            height,
            table_z,
            grasp_offset,
            carry_z,
            np.array(grabbed.target[:2], float),
            grabbed.ahead,
            grabbed.from_above,
            pitch_deg,
        )

    def grip_xy(self, xy: ArrayLike, yaw: float) -> Array:
        """Where the point between the fingertips is when the bottle stands at ``xy`` and the
        gripper heads ``yaw``."""
        heading = np.array([math.cos(yaw), math.sin(yaw)])
        return np.asarray(xy, dtype=float)[:2] - self.ahead * heading


def held_obstacles(
    scene: PlanningScene, held_track: int | None, grip_xy: Array | None, held_radius: float
) -> list[Body]:
    """The scene's bodies and cells but the held bottle: its track, and whatever stands
    within its radius plus :data:`HELD_MARGIN_M` of the fingers (``grip_xy``)."""
    out = []
    for b in scene.obstacles(held_track):
        if grip_xy is not None and math.dist(b.xy, grip_xy) < held_radius + HELD_MARGIN_M:
            continue
        out.append(b)
    return out


def scene_without_held(
    scene: PlanningScene, held_track: int | None, grip_xy: Array | None, held_radius: float
) -> tuple[PlanningScene, list[Body]]:
    """``scene`` without the held bottle (:func:`held_obstacles`), and its obstacles."""
    obstacles = held_obstacles(scene, held_track, grip_xy, held_radius)
    bodies = tuple(b for b in obstacles if b.track_id is not None)
    cells = tuple(b for b in obstacles if b.track_id is None)
    return PlanningScene(scene.table_z, bodies, cells, scene.arm), obstacles


def held_body_clearance(
    qs: Sequence[Array] | Array, held: Held, bodies: Sequence[Body], model: ArmModel
) -> tuple[float, str]:
    """Least distance over the configurations ``qs`` of the held bottle (a vertical cylinder
    of its radius and height, its axis ``held.ahead`` ahead of the point between the
    fingertips along the gripper's heading, its bottom ``held.grasp_offset`` below that
    point) to ``bodies`` (vertical cylinders), and which body it is to. The distance of two
    vertical cylinders is :func:`~armvision.tasks.collision.signed_gap` of their gaps."""
    if not bodies:
        return math.inf, "nothing"
    T = fk(np.asarray(qs, dtype=float), model).reshape(-1, 4, 4)
    heading = T[:, :2, 0]
    norm = np.linalg.norm(heading, axis=1, keepdims=True)
    heading = np.where(norm > 1e-6, heading / np.maximum(norm, 1e-12), 0.0)
    xy = T[:, :2, 3] + held.ahead * heading
    bottom = T[:, 2, 3] - held.grasp_offset
    top = bottom + held.height
    b_xy = np.array([b.xy for b in bodies], dtype=float).reshape(-1, 2)
    b_r = np.array([b.radius for b in bodies], dtype=float)
    b_bottom = np.array([b.bottom for b in bodies], dtype=float)
    b_top = np.array([b.top for b in bodies], dtype=float)
    d_xy = np.linalg.norm(xy[:, None, :] - b_xy[None], axis=-1) - held.radius - b_r
    d_z = np.maximum(b_bottom[None] - top[:, None], bottom[:, None] - b_top[None])
    d = signed_gap(d_xy, d_z)
    i, k = np.unravel_index(int(np.argmin(d)), d.shape)
    return float(d[i, k]), bodies[int(k)].describe()


class Carrier:
    """The arm's moves while the analysed bottle is off its place (the module docstring).

    ``held`` is the picked bottle (None before the pick), ``T_base_ee_last`` the last pose
    commanded (straight moves start there), ``where`` where the bottle is, for a failure's
    reason.
    """

    def __init__(self, ctx: TaskContext, grab_cfg: GrabConfig) -> None:
        self.ctx, self.grab_cfg = ctx, grab_cfg
        self.held: Held | None = None
        self.T_base_ee_last: Array | None = None
        self.where = "in its place"
        self.taken_xy: Array | None = None  # where the held bottle was last picked up
        # The planning scene from before the pick (its tracks not hidden by the arm) and the
        # held bottle's track in it: a carry below the height above everything is checked
        # against them (None: no lower carry is tried).
        self.scene: PlanningScene | None = None
        self.held_track: int | None = None
        self.grasp_yaw: float | None = None  # the gripper's heading when it took the bottle

    # ------------------------------------------------------------ one move

    def held_pitches(self) -> tuple[int, ...]:
        """The pitch a held bottle is moved at: the grasp's (it stood upright then)."""
        return (0 if self.held is None else self.held.pitch_deg,)

    def empty_pitches(self) -> tuple[int, ...]:
        """The pitches the empty gripper is moved at, in order of preference: the grasp's (no
        turn of the fingers next to the bottle), level, then pitched down in 5 degree steps
        up to :data:`EMPTY_MAX_PITCH_DEG`."""
        return tuple(dict.fromkeys((*self.held_pitches(), *range(0, EMPTY_MAX_PITCH_DEG + 1, 5))))

    def pose(self, p: ArrayLike, yaw: float, pitches: Sequence[int]) -> tuple[Array, Array]:
        """(T_base_ee, q): the gripper at ``p`` facing ``yaw`` at the first of ``pitches``
        (degrees down) the arm reaches near the last commanded pose, on its wrist branch
        (:func:`~armvision.tasks.motion.level_pose`); Abort if none."""
        arm = self.ctx.arm
        seed = motion_seed(arm, self.T_base_ee_last)
        found = level_pose(p, yaw, seed, arm.model, pitches=pitches)
        if found is not None:
            return found
        raise Abort(_cannot_reach(p, yaw))

    def move(self, what: str, T_base_ee: Array, q: Array, duration: float) -> None:
        """One checked move taking at least ``duration`` (longer if a joint would exceed
        :data:`~armvision.tasks.motion.SPEED_FRACTION` of its velocity limit); Abort with the
        arm's reason."""
        arm = self.ctx.arm
        duration = paced_time(arm, q, duration)
        if not self.ctx.move_pose(T_base_ee, moving_time=duration, custom_guess=q):
            raise Abort(f"{what}: {arm.last_error or 'the arm refused the move'}")
        self.T_base_ee_last = T_base_ee

    def straight(
        self, what: str, p_goal: ArrayLike, yaw_goal: float, pitches: Sequence[int]
    ) -> None:
        """From the last commanded pose straight to ``p_goal`` in segments of at most
        :data:`SEGMENT_M` at :data:`CARRY_SPEED_M_S`, the yaw turning evenly to ``yaw_goal``,
        each point as level as :meth:`pose` finds (one joint-space move near the table can
        sweep the gripper through what stands there)."""
        assert self.T_base_ee_last is not None
        p_from = self.T_base_ee_last[:3, 3].copy()
        for p, yaw, length in _segments(p_from, _yaw(self.T_base_ee_last), p_goal, yaw_goal):
            T, q = self.pose(p, yaw, pitches)
            self.move(what, T, q, max(SEGMENT_TIME_S, length / CARRY_SPEED_M_S))

    def plan_legs(
        self, legs: Sequence[tuple[ArrayLike, float, Sequence[int]]]
    ) -> list[list[tuple[Array, Array, float]]] | str:
        """The straight moves ``legs`` ((goal, yaw, pitches to try) each, from the last
        commanded pose, segmented as :meth:`straight` does): per leg its points (pose,
        joints, segment length), each solved near the one before; or why one cannot be
        reached. Planned
        before the first move, so a carry the arm cannot finish does not start, and executed
        as planned (:meth:`run_leg`)."""
        assert self.T_base_ee_last is not None
        model = self.ctx.arm.model
        seed = motion_seed(self.ctx.arm, self.T_base_ee_last)
        p_from, yaw_from = self.T_base_ee_last[:3, 3].copy(), _yaw(self.T_base_ee_last)
        planned: list[list[tuple[Array, Array, float]]] = []
        for p_goal, yaw_goal, pitches in legs:
            leg = []
            for p, yaw, length in _segments(p_from, yaw_from, p_goal, yaw_goal):
                found = level_pose(p, yaw, seed, model, pitches=pitches)
                if found is None:
                    return _cannot_reach(p, yaw)
                seed = found[1]
                leg.append((found[0], found[1], length))
            planned.append(leg)
            p_from, yaw_from = np.asarray(p_goal, dtype=float), yaw_goal
        return planned

    def run_leg(self, what: str, leg: list[tuple[Array, Array, float]]) -> None:
        """Make one planned leg's moves (:meth:`plan_legs`) at the carrying speed."""
        for T, q, length in leg:
            self.move(what, T, q, max(SEGMENT_TIME_S, length / CARRY_SPEED_M_S))

    def finger(self) -> float:
        return float(self.ctx.arm.gripper.get_finger_position())

    # ------------------------------------------------------------ carrying steps

    def put_down(self, xy: Array, where: str, yaw: float | None = None) -> None:
        """Carry the held bottle at the carry height to above ``xy``, stand it there, release
        it and retreat as :meth:`retreat` does; every point of these moves is planned before
        the first (Abort, nothing moved, if one cannot be reached). ``yaw``: the gripper
        faces that way at ``xy`` and backs off along its own axis (putting the bottle back
        where it was grasped: the grasp's heading, whose way in was clear); default: facing
        ``xy`` from the base, backing off toward the base."""
        held = self.held
        assert held is not None and self.T_base_ee_last is not None
        if yaw is None:
            yaw, back = math.atan2(xy[1], xy[0]), self.backoff_point(xy)
        else:
            heading = np.array([math.cos(yaw), math.sin(yaw)])
            back = np.asarray(xy, dtype=float) - (held.radius + BACKOFF_MARGIN_M) * heading
        p = self.T_base_ee_last[:3, 3]
        g = held.grip_xy(xy, yaw)
        top = held.table_z + held.height + HOVER_CLEARANCE_M
        yaw_now = _yaw(self.T_base_ee_last)

        full, empty = self.held_pitches(), self.empty_pitches()

        def legs(carry_z: float) -> list[tuple[ArrayLike, float, Sequence[int]]]:
            return [
                ([p[0], p[1], carry_z], yaw_now, full),
                ([g[0], g[1], carry_z], yaw, full),
                ([g[0], g[1], held.grasp_z + RELEASE_HEIGHT_M], yaw, full),
                ([back[0], back[1], held.grasp_z], yaw, empty),
                ([back[0], back[1], top], yaw, empty),
            ]

        plan = self.plan_legs(legs(held.carry_z))
        if isinstance(plan, str):
            plan = self.lower_carry(legs, plan)
        lift, carry, lower, back_off, rise = plan
        self.run_leg("lift for carrying", lift)
        self.run_leg("carry", carry)
        self.run_leg("lower onto the table", lower)
        self.ctx.open_gripper()
        self.where = where
        self.run_leg("back off", back_off)
        self.run_leg("rise", rise)

    def lower_carry(
        self,
        legs: Callable[[float], list[tuple[ArrayLike, float, Sequence[int]]]],
        why: str,
    ) -> list[list[tuple[Array, Array, float]]]:
        """The carry above everything (``why``: the point of it the arm cannot reach) planned
        lower instead: the highest of the heights :data:`LOWER_CARRY_STEP_M` apart down to
        the lift's whose legs (``legs(height)``) the arm reaches and whose moves keep the arm
        :data:`LOWER_ARM_CLEARANCE_M` from the planning scene (the held bottle left out; or,
        with a neighbour swollen while the arm hid it, no nearer than at the start) and the
        held bottle :data:`LOWER_HELD_CLEARANCE_M` from every other body (near a shelf of the
        arm's reach, a bottle held level is only carried over what stands in its way, not
        over the tallest thing on the table). Abort with ``why`` if none."""
        held, scene = self.held, self.scene
        assert held is not None and self.T_base_ee_last is not None
        if scene is None:
            raise Abort(why)
        lowest = held.grasp_z + self.grab_cfg.lift
        if held.carry_z - lowest < LOWER_CARRY_STEP_M:
            raise Abort(why)
        model = self.ctx.arm.model
        grip = self.T_base_ee_last[:2, 3]
        without, _ = scene_without_held(scene, self.held_track, grip, held.radius)
        bodies = without.bodies
        check = Checker(without, None, model)
        q_now = np.asarray(self.ctx.arm.get_joint_positions(), dtype=float)
        closed, opened = self.finger(), model.finger_limits[1]
        start, _ = check.least(q_now[None, :], closed)
        arm_needed = min(LOWER_ARM_CLEARANCE_M, start - 0.002)
        held_start, _ = held_body_clearance(q_now[None, :], held, bodies, model)
        held_needed = min(LOWER_HELD_CLEARANCE_M, held_start - 0.002)
        blocked = why  # no lower carry the arm reaches: the first reason stands
        for carry_z in np.arange(
            held.carry_z - LOWER_CARRY_STEP_M, lowest - 1e-9, -LOWER_CARRY_STEP_M
        ):
            plan = self.plan_legs(legs(float(carry_z)))
            if isinstance(plan, str):
                continue
            moves = [q_now] + [q for leg in plan for _, q, _ in leg]
            lines = [joint_line(a, b) for a, b in itertools.pairwise(moves)]
            n_held = sum(len(leg) for leg in plan[:3])  # lift, carry, lower: closed
            held_qs = np.concatenate(lines[:n_held])
            empty_qs = np.concatenate(lines[n_held:])
            for what, clearance, needed in (
                ("the arm", check.least(held_qs, closed), arm_needed),
                ("the open gripper", check.least(empty_qs, opened), arm_needed),
                ("the bottle", held_body_clearance(held_qs, held, bodies, model), held_needed),
            ):
                if clearance[0] < needed:
                    blocked = (
                        f"{why}; carried lower, at {carry_z:.3f} m, {what} would come within "
                        f"{1000 * clearance[0]:.0f} mm of {clearance[1]}"
                    )
                    break
            else:
                return plan
        raise Abort(blocked)

    def stand_back(self) -> bool:
        """After a move that could not be made with the bottle held, the gripper still above
        the spot the bottle was last taken from (within :data:`STAND_BACK_M`; where it stood,
        or where it was presented): lower it straight back there, release it, back off along
        the gripper's own heading (the way the grasp came in) and rise. False, with nothing
        moved, when the gripper is elsewhere."""
        held, T = self.held, self.T_base_ee_last
        if held is None or T is None:
            return False
        yaw = _yaw(T)
        grip = held.grip_xy(self.taken_xy if self.taken_xy is not None else held.home_xy, yaw)
        if float(np.linalg.norm(T[:2, 3] - grip)) > STAND_BACK_M:
            return False
        # The lift reversed, in the grasp's own orientation (it may be pitched where a level
        # gripper does not reach), then out the way the grasp came in, and up.
        self.fixed("stand it back", [grip[0], grip[1], held.grasp_z + RELEASE_HEIGHT_M])
        self.ctx.open_gripper()
        self.where = (
            "back in its place"
            if self.taken_xy is None
            else "standing where it was presented, at "
            f"({self.taken_xy[0]:.2f}, {self.taken_xy[1]:.2f}) m"
        )
        back = grip - (held.radius + BACKOFF_MARGIN_M) * np.array([math.cos(yaw), math.sin(yaw)])
        self.fixed("back off", [back[0], back[1], held.grasp_z + RELEASE_HEIGHT_M])
        self.fixed("rise", [back[0], back[1], held.table_z + held.height + HOVER_CLEARANCE_M])
        return True

    def fixed(self, what: str, p_goal: ArrayLike) -> None:
        """From the last commanded pose straight to ``p_goal`` keeping its orientation, in
        segments as :meth:`straight`; Abort if a point is out of reach."""
        assert self.T_base_ee_last is not None
        R = self.T_base_ee_last[:3, :3].copy()
        p_from = self.T_base_ee_last[:3, 3].copy()
        for p, _, length in _segments(p_from, 0.0, p_goal, 0.0):
            T = make_T(R, p)
            q, ok = ik(T, motion_seed(self.ctx.arm, self.T_base_ee_last), self.ctx.arm.model)
            if not ok:
                raise Abort(_cannot_reach(p, _yaw(T)))
            self.move(what, T, q, max(SEGMENT_TIME_S, length / CARRY_SPEED_M_S))

    def retreat(self, xy: Array) -> None:
        """From the grasp pose at ``xy``: back off toward the base until the fingertips are
        :data:`BACKOFF_MARGIN_M` clear of the bottle, then rise
        :data:`~armvision.tasks.grab.HOVER_CLEARANCE_M` above its top (out of the camera's
        view of it: behind and above it)."""
        held = self.held
        assert held is not None
        yaw, back = math.atan2(xy[1], xy[0]), self.backoff_point(xy)
        empty = self.empty_pitches()
        self.straight("back off", [back[0], back[1], held.grasp_z], yaw, empty)
        top = held.table_z + held.height + HOVER_CLEARANCE_M
        self.straight("rise", [back[0], back[1], top], yaw, empty)

    def pick_up(self, xy: Array) -> None:
        """Grasp the bottle standing where this task released it (retreat, reversed)."""
        held = self.held
        assert held is not None
        yaw, back = math.atan2(xy[1], xy[0]), self.backoff_point(xy)
        self.straight(
            "down behind the bottle", [back[0], back[1], held.grasp_z], yaw, self.empty_pitches()
        )
        g = held.grip_xy(xy, yaw)
        # At the first grasp's pitch: the bottle is put back where that grasp took it, at it.
        self.straight("approach", [g[0], g[1], held.grasp_z], yaw, self.held_pitches())
        self.ctx.close_gripper()
        if not holding(self.ctx.arm):
            self.ctx.open_gripper()
            self.retreat(xy)
            raise Abort("could not grasp the bottle again where it was presented")
        self.where = "held by the gripper"
        self.taken_xy = np.asarray(xy, dtype=float)

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
