"""Where to stand a picked bottle for the camera, and the pixel box of an upright bottle.

:func:`presentation_spot` searches the table, in front of the base, for the spot where the
camera sees the bottle best: fully in the image, near ``analyze.present_distance`` from the
camera, clear of every other object (:class:`Obstacle`) and of the line of sight, reachable for
the carrying moves of :mod:`armvision.tasks.carry`, preferably against bare table.
:func:`bottle_box` projects an upright bottle into the image as the liquid meter models it (the
box analyze measures a presented bottle in, since the detector's box of a clear bottle is
narrower than the bottle).

Units: metres, radians, pixels for boxes; positions in the base frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, pixel_box, project
from armvision.geometry import inv_T, make_T, rpy_to_R
from armvision.perception.detection import BOTTLE_BODY_FRACTION
from armvision.perception.liquid import bottle_outline
from armvision.robot.kinematics import ArmModel, ik
from armvision.tasks.carry import BACKOFF_MARGIN_M, EMPTY_MAX_PITCH_DEG
from armvision.tasks.grab import GRIPPER_HALF_WIDTH_M, HOVER_CLEARANCE_M
from armvision.tasks.motion import unflipped_ik, wrist_flipped

Array = NDArray[np.float64]
#: A pixel box (x0, y0, x1, y1).
Box = tuple[float, float, float, float]

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


def bottle_box(
    intr: Intrinsics,
    T_cam_base: ArrayLike,
    p_base_foot: ArrayLike,
    radius: float,
    height: float,
    body_fraction: float = BOTTLE_BODY_FRACTION,
) -> Box:
    """Pixel box (x0, y0, x1, y1) of an upright bottle standing at ``p_base_foot``: the
    liquid meter's bottle model (:func:`~armvision.perception.liquid.bottle_outline`) as the
    camera at ``T_cam_base`` sees it."""
    pts_base = bottle_outline(p_base_foot, [0.0, 0.0, 1.0], radius, height, body_fraction)
    T = np.asarray(T_cam_base, dtype=float)
    x0, y0, x1, y1 = pixel_box(project(intr, pts_base @ T[:3, :3].T + T[:3, 3]))
    return (float(x0), float(y0), float(x1), float(y1))


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


def _reachable(
    p: ArrayLike, yaw: float, pitches: Sequence[int], model: ArmModel, seed: Array
) -> bool:
    """Whether the gripper reaches ``p`` facing ``yaw`` pitched down by one of ``pitches``
    (degrees) on the wrist branch of ``seed``: unflipped, or flipped if the seed's is (the
    carrying moves stay on the branch the grasp left the arm on:
    :func:`~armvision.tasks.motion.level_pose`)."""
    flipped = wrist_flipped(seed)
    for pitch in pitches:
        T = make_T(rpy_to_R(0.0, math.radians(pitch), yaw), p)
        if not flipped and unflipped_ik(T, seed, model) is not None:
            return True
        if flipped:
            q, ok = ik(T, seed, model)
            if ok and wrist_flipped(q):
                return True
    return False


def presentation_spot(*args: Any, **kwargs: Any) -> Spot | None:
    """The best of :func:`presentation_spots` (same arguments), None if there is none."""
    spots = presentation_spots(*args, **kwargs)
    return spots[0] if spots else None


def presentation_spots(
    T_base_cam: ArrayLike,
    intr: Intrinsics,
    radius: float,
    height: float,
    table_z: float,
    grasp_offset: float,
    obstacles: Sequence[Obstacle],
    present_distance: float,
    standoff: float,
    model: ArmModel | None,
    carry_z: float,
    held_pitch_deg: int = 0,
    seed: ArrayLike | None = None,
) -> list[Spot]:
    """The spots on the table where the camera sees the bottle well, the best first.

    Candidates: :data:`SPOT_DISTANCES_M` from the base axis at :data:`SPOT_BEARINGS_RAD`. A
    candidate counts when (1) the bottle's projected box (:func:`bottle_box`) lies inside the
    image by :data:`IMAGE_MARGIN_PX` and its centre is at least :data:`MIN_RANGE_M` from the
    camera; (2) it is :data:`SPOT_CLEARANCE_M` clear of every obstacle; (3) no obstacle stands
    within :data:`SIGHT_MARGIN_M` of the line of sight from the camera to it (in plan view, so
    any height counts as blocking); (4) the open gripper's corridor from ``standoff`` short of
    it is clear (as the grasp requires); (5) the arm reaches, facing it from the base, the
    grasp pose ``grasp_offset`` above the table and the carry pose at ``carry_z`` with the
    gripper pitched as it was at the grasp (not checked without a ``model``: a planner that
    checks every move decides), ``held_pitch_deg`` (it holds the bottle there;
    :class:`~armvision.tasks.carry.Held`), and the back-off point (:data:`BACKOFF_MARGIN_M`
    behind the bottle) at the grasp height and :data:`HOVER_CLEARANCE_M` above the bottle,
    pitched down if need be, all on the wrist branch of ``seed`` (the joints the grasp left
    the arm at; default the home pose's, unflipped). The best is the one whose distance from
    the camera is nearest ``present_distance``, then the one nearest the image centre,
    preferring those seen against bare table (:func:`_bare_background`).
    """
    held, empty = (held_pitch_deg,), range(0, EMPTY_MAX_PITCH_DEG + 1, 5)
    q_seed = (
        np.zeros(6) if model is None else model.home if seed is None else np.asarray(seed, float)
    )
    T_base_cam = np.asarray(T_base_cam, dtype=float)
    T_cam_base = inv_T(T_base_cam)
    p_cam = T_base_cam[:3, 3]
    scored: list[tuple[float, Spot]] = []
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
                (xy, grasp_z, held),
                (xy, carry_z, held),
                (back, grasp_z, empty),
                (back, table_z + height + HOVER_CLEARANCE_M, empty),
            )
            if model is not None and not all(
                _reachable([*p, z], yaw, pitch, model, q_seed) for p, z, pitch in poses
            ):
                continue
            centre_px = 0.5 * (box[0] + box[2]) - intr.ppx
            score = abs(distance - present_distance) + 0.05 * abs(centre_px) / intr.fx
            if not _bare_background(xy, radius, p_cam[:2], obstacles):
                score += CLUTTER_PENALTY
            scored.append((score, Spot((float(xy[0]), float(xy[1])), float(yaw), distance, box)))
    return [spot for _, spot in sorted(scored, key=lambda s: s[0])]


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
