"""Set the held bottle down: ``place(x, y)`` or ``place(zone=NAME)``.

1. **What is held.** Inside a task that grabbed the bottle (sort) the :class:`~armvision.
   tasks.carry.Held` comes from that grasp. The ``place`` task sets down the bottle the
   system's newest successful ``grab`` task took (:meth:`System.last_status
   <armvision.runtime.system.System.last_status>`), as long as the fingers still close on
   something: between the empty-closed gap plus :data:`~armvision.tasks.grab.GRASP_MARGIN_M`
   and the open gap; otherwise it fails with "nothing is held" and nothing moves.
2. **The spot.** ``(x, y)``: that spot; ``zone``: a free spot inside the named rectangle of
   ``place.zones`` (the bottle's footprint wholly inside it), the candidates of a 1 cm grid
   tried from the zone's corner farthest from the base, so bottles set down one after the
   other fill the zone from the back. A spot is free (:func:`spot_refusal`) when the bottle's
   footprint keeps ``place.clearance`` to every body and occupied cell of the planning scene
   (but the held bottle itself, and whatever is within reach of the fingers: the bottle seen
   in the gripper), the fingers' short back-off strip toward the base is clear as well, it lies
   within :data:`TABLE_RADIUS_M` of the base axis and beyond ``grab.min_base_distance``, and
   the arm reaches every pose of the set-down level (the gripper facing the spot from the
   base), wrist unflipped. All of it is decided before the arm moves: a spot off the table,
   taken or out of reach, an unknown zone, a full zone give a one-line reason and no motion.
3. **Setting down** (:meth:`Carrier.put_down <armvision.tasks.carry.Carrier.put_down>`, the
   analyze task's carrying moves): up to the carry height above everything on the table,
   level across to above the spot, straight down, open, back off toward the base and rise,
   then to the grasp's safe start pose, out of the camera's view.
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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.config import Config
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T, rpy_to_R
from armvision.robot.kinematics import ArmModel
from armvision.runtime.context import TaskContext, TaskError
from armvision.runtime.planning_scene import Body, PlanningScene
from armvision.tasks.carry import BACKOFF_MARGIN_M, EMPTY_MAX_PITCH_DEG, Abort, Carrier, Held
from armvision.tasks.grab import GRASP_MARGIN_M, HOVER_CLEARANCE_M, GrabResult
from armvision.tasks.motion import unflipped_ik

Array = NDArray[np.float64]

#: Spots farther than this from the base axis are off the simulated bench's table (and
#: beyond the ViperX-300s's reach with a bottle), m.
TABLE_RADIUS_M = 0.7
#: The zone's candidate spots: a grid of this pitch, m.
ZONE_STEP_M = 0.01
#: After the release, the bottle's new track is looked for this far from the spot, m.
FIND_M = 0.08
#: Scene bodies and cells whose centre is this near the gripper (beyond the held bottle's
#: radius) are the held bottle itself, as the camera sees it in the fingers, m.
HELD_MARGIN_M = 0.04
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


def _reach_poses(xy: Array, held: Held) -> list[tuple[Array, float, int]]:
    """The set-down's poses at spot ``xy``: (x, y, z), yaw, the pitch allowed (degrees)."""
    d = float(np.linalg.norm(xy))
    yaw = math.atan2(xy[1], xy[0])
    back = xy * max(d - held.radius - BACKOFF_MARGIN_M, 0.0) / max(d, 1e-9)
    top = held.table_z + held.height + HOVER_CLEARANCE_M
    return [
        (np.array([xy[0], xy[1], held.grasp_z]), yaw, 0),
        (np.array([xy[0], xy[1], held.carry_z]), yaw, 0),
        (np.array([back[0], back[1], held.grasp_z]), yaw, EMPTY_MAX_PITCH_DEG),
        (np.array([back[0], back[1], top]), yaw, EMPTY_MAX_PITCH_DEG),
    ]


def reachable(xy: Array, held: Held, model: ArmModel) -> bool:
    """Whether the arm reaches every pose of the set-down at ``xy`` (level where it holds
    the bottle, pitched down up to the carrying rule's limit where it is empty)."""
    for p, yaw, max_pitch in _reach_poses(xy, held):
        if not any(
            unflipped_ik(make_T(rpy_to_R(0.0, math.radians(pitch), yaw), p), model.home, model)
            is not None
            for pitch in range(0, max_pitch + 1, 5)
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
) -> str | None:
    """Why the bottle cannot be set down at ``xy`` (the module docstring's step 2), or None."""
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
    if not reachable(xy, held, model):
        return f"the arm cannot reach the spot {where} to set the bottle down level"
    return None


def zone_spot(
    rect: tuple[float, float, float, float],
    held: Held,
    obstacles: Sequence[Body],
    clearance: float,
    min_base_distance: float,
    model: ArmModel,
) -> Array | None:
    """A free spot (:func:`spot_refusal`) for the held bottle wholly inside ``rect``, the
    first of the grid from the rectangle's corner farthest from the base; None if none."""
    x0, y0, x1, y1 = rect
    r = held.radius
    xs = np.arange(x0 + r, x1 - r + 1e-9, ZONE_STEP_M)
    ys = np.arange(y0 + r, y1 - r + 1e-9, ZONE_STEP_M)
    if not len(xs) or not len(ys):
        return None
    corners = np.array([[x0 + r, y0 + r], [x0 + r, y1 - r], [x1 - r, y0 + r], [x1 - r, y1 - r]])
    far = corners[int(np.argmax(np.linalg.norm(corners, axis=1)))]
    grid = np.array([(x, y) for x in xs for y in ys])
    for xy in grid[np.argsort(np.linalg.norm(grid - far, axis=1), kind="stable")]:
        if spot_refusal(xy, held, obstacles, clearance, min_base_distance, model) is None:
            return np.asarray(xy, dtype=float)
    return None


class Placer:
    """Sets the held bottle down with a :class:`Carrier` and checks where it stands."""

    def __init__(self, ctx: TaskContext, carrier: Carrier, held_track: int | None) -> None:
        self.ctx, self.carrier, self.held_track = ctx, carrier, held_track
        self.start = ctx.now()

    def obstacles(self) -> list[Body]:
        held = self.carrier.held
        assert held is not None
        grip = np.asarray(self.ctx.arm.get_ee_pose(), dtype=float)[:2, 3]
        return held_obstacles(self.ctx.state().planning_scene, self.held_track, grip, held.radius)

    def choose(self, x: float | None, y: float | None, zone: str | None) -> Array:
        """The spot to set the bottle down; PlaceError (nothing moved) if there is none."""
        ctx, cfg = self.ctx, self.ctx.config.place
        held = self.carrier.held
        assert held is not None
        model, min_d = ctx.arm.model, ctx.config.grab.min_base_distance
        if zone is not None:
            rect = zone_rect(ctx.config, zone)
            spot = zone_spot(rect, held, self.obstacles(), cfg.clearance, min_d, model)
            if spot is None:
                raise PlaceError(
                    f"zone {zone!r} has no free spot the arm reaches for a bottle of radius "
                    f"{100 * held.radius:.1f} cm"
                )
            return spot
        if x is None or y is None:
            raise PlaceError("say where: place(x, y) in metres, or place(zone=NAME)")
        xy = np.array([float(x), float(y)])
        if not np.all(np.isfinite(xy)):
            raise PlaceError(f"the spot ({x}, {y}) is not a finite position in metres")
        why = spot_refusal(xy, held, self.obstacles(), cfg.clearance, min_d, model)
        if why is not None:
            raise PlaceError(why)
        return xy

    def set_down(self, spot: Array, zone: str | None) -> PlaceResult:
        """Carry, stand, release, retreat, go to the safe pose, then check (module doc)."""
        ctx, carrier = self.ctx, self.carrier
        if carrier.T_base_ee_last is None:
            carrier.T_base_ee_last = np.asarray(ctx.arm.get_ee_pose(), dtype=float)
        asked = (float(spot[0]), float(spot[1]))
        where = f"({asked[0]:.3f}, {asked[1]:.3f}) m" + ("" if zone is None else f" in {zone!r}")
        ctx.progress(0.3, f"carrying the bottle to {where}")
        try:
            carrier.put_down(spot, f"standing at {where}")
            carrier.go_safe()
        except Abort as exc:
            released = carrier.where.startswith("standing")
            return self.result(
                False, f"{exc}; the bottle is {carrier.where}", zone, asked, released=released
            )
        ctx.progress(0.85, f"checking the bottle stands at {where}")
        return self.verify(spot, zone, where)

    def verify(self, spot: Array, zone: str | None, where: str) -> PlaceResult:
        ctx, cfg = self.ctx, self.ctx.config.place
        held = self.carrier.held
        assert held is not None
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


def holding(ctx: TaskContext) -> bool:
    """Whether the fingers close on something: between empty-closed (plus the grasp margin)
    and open (minus it)."""
    lo, hi = ctx.arm.model.finger_limits
    finger = float(ctx.arm.gripper.get_finger_position())
    return lo + GRASP_MARGIN_M < finger < hi - GRASP_MARGIN_M


def held_from_last_grab(ctx: TaskContext) -> tuple[Held, int | None]:
    """The bottle the newest successful grab task holds (module docstring, step 1);
    PlaceError if nothing is held."""
    if not holding(ctx):
        raise PlaceError("nothing is held: grab a bottle first (the gripper is open or empty)")
    status = ctx.system.last_status("grab")
    result = None if status is None else status.result
    if status is None or status.phase != "succeeded" or not result or not result.get("ok"):
        raise PlaceError(
            "nothing is held that a grab took: grab a bottle first (the fingers hold "
            "something no grab task picked up)"
        )
    grabbed = GrabResult(
        ok=True,
        reason=str(result.get("reason", "")),
        track_id=result.get("track_id"),
        target=tuple(result["target"]),  # type: ignore[arg-type]
        height=result.get("height"),
        grasp_z=result.get("grasp_z"),
        finger=result.get("finger"),
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
    carrier = Carrier(ctx, ctx.config.grab)
    carrier.held = held
    carrier.where = "held by the gripper"
    placer = Placer(ctx, carrier, track_id)
    spot = placer.choose(x, y, zone)
    return placer.set_down(spot, zone)
