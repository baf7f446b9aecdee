"""The planning scene: what the arm must keep clear of, built from perception alone.

:class:`PlanningScene` holds the table plane (horizontal in the base frame, at ``table_z``),
every confirmed track as a vertical cylinder (:class:`Body`: its fitted radius and height with
its uncertainty added), the depth points that belong to no detected object as an occupancy
grid over the table (:class:`OccupancyGrid`, a height map of cells) and the arm's own links
(capsules at the joint angles of the fusion cycle). The object stage builds the grid from each
frame (:func:`occupancy_from_depth`); :attr:`SystemState.planning_scene
<armvision.runtime.state.SystemState.planning_scene>` assembles the scene, so a task plans
against it and the UI shows it.

Units: metres; positions in the base frame.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics
from armvision.fusion.tracker import TrackState
from armvision.geometry import transform_points
from armvision.perception.fitting import unit_depth_rays
from armvision.perception.selfmask import arm_capsules_base, self_mask

Array = NDArray[np.float64]

#: A track's radius grows by this many standard deviations of its horizontal position.
SIGMA_FACTOR = 2.0
#: ... but by no more than this, m (a fresh track's covariance is wide).
MAX_UNCERTAINTY_M = 0.03
#: A track of unknown size stands in for an object this wide and tall, m.
UNKNOWN_RADIUS_M = 0.05
UNKNOWN_HEIGHT_M = 0.3
#: A bottle's or cup's radius grows by this much, m: the detector fits the circle of what
#: returns depth, and a clear wall returns none, so a container's fitted radius runs short
#: (on the simulated bench, matched detections: bottles 1.5-7 mm, median 4.2 mm over default
#: seeds 0-19; clear cups and tumblers 8-16 mm; opaque cups and mugs 1-1.5 mm).
CONTAINER_RADIUS_MARGIN_M = 0.004
#: A body's top is raised by this much (a cap, a handle the fit misses), m.
TOP_MARGIN_M = 0.01
#: Occupancy grid: cell size, m; the least height above the table a point needs, m; the
#: depth pixels used (every ``GRID_STRIDE``-th of every ``GRID_STRIDE``-th row); the points a
#: cell needs to count as occupied; how far from a detected object a point still belongs to it.
GRID_CELL_M = 0.02
GRID_MIN_HEIGHT_M = 0.015
GRID_MAX_HEIGHT_M = 0.6
GRID_STRIDE = 4
GRID_MIN_POINTS = 4
GRID_OBJECT_MARGIN_M = 0.025
#: Only points this near the base axis are mapped (the arm's reach and a little more), m.
GRID_RADIUS_M = 0.85
#: Points nearer than this to a link of the arm are the arm itself, m.
GRID_ARM_MARGIN_M = 0.03
#: A depth jump above this share of the depth between neighbours marks an occluding edge,
#: whose flying pixels float in the air between objects and table.
EDGE_JUMP_SHARE = 0.03


@dataclass(frozen=True)
class Body:
    """An obstacle standing on the table as a vertical cylinder: centre ``xy``, ``radius``
    (the fitted radius plus its uncertainty), from ``bottom`` to ``top`` (z, m). ``track_id``
    and ``label`` name the track it comes from (None and ``occupied`` for a grid cell)."""

    xy: tuple[float, float]
    radius: float
    bottom: float
    top: float
    label: str
    track_id: int | None = None

    def describe(self) -> str:
        """``the cup (track 5) at (0.412, -0.118) m``, for a refusal's reason."""
        where = f"({self.xy[0]:.3f}, {self.xy[1]:.3f}) m"
        if self.track_id is None:
            return f"something the camera sees at {where} (no tracked object)"
        name = "an unknown object" if self.label == "other" else f"the {self.label}"
        return f"{name} (track {self.track_id}) at {where}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "xy": [round(v, 4) for v in self.xy],
            "radius": round(self.radius, 4),
            "bottom": round(self.bottom, 4),
            "top": round(self.top, 4),
            "label": self.label,
            "track_id": self.track_id,
        }


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """Depth points of one frame that belong to no detected object, as a height map.

    ``cells`` (K, 2) the centres of the occupied cells (``cell`` m square), ``tops`` (K,) the
    highest point in each (z, m); ``table_z`` the table's height the frame showed; ``t`` the
    frame's time.
    """

    cell: float
    cells: Array
    tops: Array
    table_z: float
    t: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "cell": self.cell,
            "table_z": round(self.table_z, 4),
            "t": self.t,
            "cells": [
                [round(float(x), 3), round(float(y), 3), round(float(z), 3)]
                for (x, y), z in zip(self.cells, self.tops)
            ],
        }


@dataclass(frozen=True, eq=False)
class DepthView:
    """What the occupancy grid of one object frame is made from: the depth image (metres),
    its intrinsics, the camera pose and joint angles the detector was given, the detected
    objects (base-frame centre, radius, top z) and the frame's time. The object stage keeps
    this (cheap); :attr:`grid` builds the grid when first asked for (a task planning, the UI),
    so the stages' rates do not pay for it."""

    depth: Array
    intrinsics: Intrinsics
    T_base_cam: Array
    joint_positions: Array | None
    objects: tuple[tuple[tuple[float, float], float, float], ...]
    t: float

    @functools.cached_property
    def grid(self) -> OccupancyGrid:
        return occupancy_from_depth(
            self.depth, self.intrinsics, self.T_base_cam, self.joint_positions, self.objects,
            self.t,
        )  # fmt: skip


def table_height(z_base: Array, search: tuple[float, float] = (-0.1, 0.1)) -> float | None:
    """The table's height from base-frame point heights: the most populated 5 mm bin within
    ``search``, refined by the median of the points within 1 cm of it; None if no point is."""
    z = z_base[(z_base > search[0]) & (z_base < search[1])]
    if len(z) < 50:
        return None
    counts, edges = np.histogram(z, bins=np.arange(search[0], search[1] + 1e-9, 0.005))
    k = int(np.argmax(counts))
    centre = 0.5 * (edges[k] + edges[k + 1])
    near = z[np.abs(z - centre) < 0.01]
    return float(np.median(near))


def occupancy_from_depth(
    depth: ArrayLike,
    intr: Intrinsics,
    T_base_cam: ArrayLike,
    joint_positions: ArrayLike | None,
    objects: Sequence[tuple[ArrayLike, float, float]],
    t: float = 0.0,
    *,
    cell: float = GRID_CELL_M,
    stride: int = GRID_STRIDE,
    table_z: float | None = None,
) -> OccupancyGrid:
    """The occupancy grid of one depth image (metres, aligned to ``intr``).

    Every ``stride``-th pixel is deprojected into the base frame; pixels on occluding edges
    (a depth jump above :data:`EDGE_JUMP_SHARE` to a neighbour: flying pixels) are dropped,
    then the points below :data:`GRID_MIN_HEIGHT_M` above the table (``table_z``, else
    :func:`table_height` of this cloud, else 0), farther than :data:`GRID_RADIUS_M` from the
    base axis, on the arm (:func:`~armvision.perception.selfmask.self_mask` at
    ``joint_positions``) or within :data:`GRID_OBJECT_MARGIN_M` of a detected object
    (``objects``: base-frame centre, radius, top z of each). What is left is binned into
    ``cell`` squares; a cell with :data:`GRID_MIN_POINTS` points is occupied up to its highest.
    """
    depth = np.asarray(depth, dtype=float)
    T_base_cam = np.asarray(T_base_cam, dtype=float)
    rays, flat = unit_depth_rays(intr, stride)
    z = depth.ravel()[flat]
    rows, cols = -(-intr.height // stride), -(-intr.width // stride)
    grid = z.reshape(rows, cols)
    # Largest depth difference to a 4-neighbour, per pixel (no data counts as no jump).
    jump = np.zeros_like(grid)
    for axis in (0, 1):
        d = np.abs(np.diff(grid, axis=axis))
        both = (np.take(grid, range(1, grid.shape[axis]), axis=axis) > 0) & (
            np.take(grid, range(grid.shape[axis] - 1), axis=axis) > 0
        )
        d = np.where(both, d, 0.0)
        pad_lo = [(0, 0), (0, 0)]
        pad_hi = [(0, 0), (0, 0)]
        pad_lo[axis], pad_hi[axis] = (1, 0), (0, 1)
        jump = np.maximum(jump, np.maximum(np.pad(d, pad_lo), np.pad(d, pad_hi)))
    good = (z > 0.0) & np.isfinite(z) & (jump.ravel() <= EDGE_JUMP_SHARE * np.maximum(z, 0.1))
    p_cam = rays[good] * z[good, None]
    p_base = transform_points(T_base_cam, p_cam)
    if table_z is None:
        found = table_height(p_base[:, 2])
        table_z = 0.0 if found is None else found
    h = p_base[:, 2] - table_z
    keep = (h > GRID_MIN_HEIGHT_M) & (h < GRID_MAX_HEIGHT_M)
    keep &= np.hypot(p_base[:, 0], p_base[:, 1]) < GRID_RADIUS_M
    for centre, radius, top in objects:
        c = np.asarray(centre, dtype=float)
        near = np.hypot(p_base[:, 0] - c[0], p_base[:, 1] - c[1]) < radius + GRID_OBJECT_MARGIN_M
        keep &= ~(near & (p_base[:, 2] < top + GRID_OBJECT_MARGIN_M))
    idx = np.flatnonzero(keep)
    if len(idx):
        on = self_mask(
            p_cam[idx],
            T_base_cam,
            joint_positions,
            workspace_radius=math.inf,
            margin=GRID_ARM_MARGIN_M,
        )
        idx = idx[on]
    pts = p_base[idx]
    if len(pts) == 0:
        return OccupancyGrid(cell, np.zeros((0, 2)), np.zeros(0), float(table_z), t)
    ij = np.floor(pts[:, :2] / cell).astype(np.int64)
    keys, inverse, counts = np.unique(ij, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    tops = np.full(len(keys), -np.inf)
    np.maximum.at(tops, inverse, pts[:, 2])
    occupied = counts >= GRID_MIN_POINTS
    centres = (keys[occupied] + 0.5) * cell
    return OccupancyGrid(cell, centres.astype(float), tops[occupied], float(table_z), t)


def track_body(track: TrackState, table_z: float) -> Body:
    """A track as a :class:`Body`: its radius plus :data:`SIGMA_FACTOR` standard deviations of
    its horizontal position (at most :data:`MAX_UNCERTAINTY_M`), and a bottle's or cup's plus
    :data:`CONTAINER_RADIUS_MARGIN_M`, from the table to its top plus :data:`TOP_MARGIN_M`
    (plus its vertical uncertainty)."""
    P_xy = np.asarray(track.cov, dtype=float)[:2, :2]
    sigma_xy = math.sqrt(max(float(np.max(np.linalg.eigvalsh(P_xy))), 0.0))
    sigma_z = math.sqrt(max(float(track.cov[2, 2]), 0.0))
    radius = track.radius if track.radius is not None else UNKNOWN_RADIUS_M
    if track.radius is not None and track.label in ("bottle", "cup"):
        radius += CONTAINER_RADIUS_MARGIN_M
    height = track.height if track.height is not None else UNKNOWN_HEIGHT_M
    x, y, z = (float(v) for v in track.p_base)
    top = z + 0.5 * height + TOP_MARGIN_M + min(SIGMA_FACTOR * sigma_z, MAX_UNCERTAINTY_M)
    return Body(
        (x, y),
        float(radius) + min(SIGMA_FACTOR * sigma_xy, MAX_UNCERTAINTY_M),
        float(table_z),
        float(max(top, table_z)),
        track.label,
        track.id,
    )


@dataclass(frozen=True, eq=False)
class PlanningScene:
    """The table, the tracked objects, unexplained occupied space and the arm's links.

    ``table_z`` the table's height (the grid's, else 0: the arm stands on the table);
    ``bodies`` one per confirmed track (:func:`track_body`); ``cells`` the occupancy grid's
    cells that lie outside every body, as bodies of label ``occupied``; ``arm`` the link
    capsules (a (K, 3), b (K, 3), radii (K,)) at the joints of the fusion cycle, or None.
    """

    table_z: float
    bodies: tuple[Body, ...]
    cells: tuple[Body, ...]
    arm: tuple[Array, Array, Array] | None = None

    @staticmethod
    def build(
        tracks: Sequence[TrackState],
        grid: OccupancyGrid | None,
        joint_positions: ArrayLike | None = None,
    ) -> PlanningScene:
        table_z = 0.0 if grid is None else grid.table_z
        bodies = tuple(track_body(t, table_z) for t in tracks)
        cells: list[Body] = []
        if grid is not None and len(grid.cells):
            half = grid.cell / math.sqrt(2.0)
            free = np.ones(len(grid.cells), dtype=bool)
            for b in bodies:
                d = np.hypot(grid.cells[:, 0] - b.xy[0], grid.cells[:, 1] - b.xy[1])
                free &= d > b.radius + half
            for (x, y), top in zip(grid.cells[free], grid.tops[free]):
                cells.append(Body((float(x), float(y)), half, table_z, float(top), "occupied"))
        arm = None if joint_positions is None else arm_capsules_base(joint_positions)
        return PlanningScene(float(table_z), bodies, tuple(cells), arm)

    def obstacles(self, exclude_track: int | None = None) -> tuple[Body, ...]:
        """Every body and occupied cell, but the track ``exclude_track`` (the one to grasp) and
        any track lying inside it: a body whose centre is nearer the excluded one's than half
        their radii together is that object tracked twice (two solid objects on the table
        cannot stand inside each other; the tracker may start a second track on a bottle it
        lost sight of for a moment)."""
        gone = next((b for b in self.bodies if b.track_id == exclude_track), None)

        def same(b: Body) -> bool:
            if gone is None:
                return False
            d = math.hypot(b.xy[0] - gone.xy[0], b.xy[1] - gone.xy[1])
            return d < 0.5 * (b.radius + gone.radius)

        kept = tuple(
            b
            for b in self.bodies
            if exclude_track is None or (b.track_id != exclude_track and not same(b))
        )
        return kept + self.cells

    def to_dict(self) -> dict[str, Any]:
        return {
            "table_z": round(self.table_z, 4),
            "bodies": [b.to_dict() for b in self.bodies],
            "occupied_cells": [b.to_dict() for b in self.cells],
            "arm": None
            if self.arm is None
            else [
                {"a": a.round(4).tolist(), "b": b.round(4).tolist(), "radius": float(r)}
                for a, b, r in zip(*self.arm)
            ],
        }
