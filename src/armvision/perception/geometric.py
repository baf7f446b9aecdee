"""Bottles, cups and other objects standing on the table, as vertical cylinders, from depth.

The table is the dominant plane of the depth point cloud (RANSAC), the robot's own points are
removed (capsules around its links, placed by forward kinematics when the frame's context
gives the camera pose and joint angles), and so are depth edges (occluding contours and the
flying pixels a depth camera puts along them, which would join neighbouring objects). What
stands on the table is clustered in the table plane, a cluster lying inside another's wall
circle (a cup's inside, a cap) is joined to it, and a vertical cylinder is fitted to each: a
circle through the *camera-facing wall* in the table plane (only that half is seen, so a
centroid would sit too near the camera) and the height from the highest points. The label
follows from the shape (height, a narrow neck or cap, a gap of no depth under a cap, a closed
top, a top as wide as the body, a bowl's proportions, straight walls, an inside seen from
above) and from how much depth the surface returns: clear plastic returns little, and on a
table a clear object is a bottle or a cup. What is neither is "other", an obstacle.

Table-plane coordinates used inside the detector are (u, w, h): two in-plane axes and the
height above the table.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import cv2
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import (
    DEPTH_BASELINE_M,
    DEPTH_FOCAL_PX,
    DEPTH_SUBPIXEL,
    Intrinsics,
    RGBDFrame,
    deproject,
    depth_rms_error,
    project,
)
from armvision.errors import PerceptionError
from armvision.geometry import cross3
from armvision.perception.detection import (
    BOTTLE_BODY_FRACTION,
    NO_CONTEXT,
    Detection,
    FrameContext,
    Label,
    _image_box,
    cylinder_box,
)
from armvision.perception.fitting import (
    fit_plane,
    gauss_newton_circle,
    kasa_kernel,
    percentile,
    unit_depth_ray_columns,
    unit_depth_rays,
)
from armvision.perception.liquid import bottle_outline, compile_rays
from armvision.perception.selfmask import VX300S_CAPSULES, self_mask
from armvision.robot.kinematics import VX300S, ArmModel

Array = NDArray[np.float64]
#: A cluster's wall circle: centre (u, w), radius, every point's residual, which are the wall.
_Circle = tuple[Array, float, Array, NDArray[np.bool_]]


class _Standing(NamedTuple):
    """An upright cylinder on the table: its axis's (u, w) in the table plane, its radius and
    height (m)."""

    center: Array
    radius: float
    height: float


class _TopDisc(NamedTuple):
    """What the full-resolution depth shows over an object's top (:meth:`_top_disc`): how
    many samples lie on it (a lid), beyond it (an opening), nearer (something in front) or
    return none."""

    on: int
    beyond: int
    nearer: int
    missing: int


class _Fit(NamedTuple):
    """A cluster's detection; whether it is one planar face; and, for one called other only
    because no opening was seen in its top (its top quarter as wide as its wall), what its top
    showed (else None)."""

    detection: Detection
    planar: bool
    unopened: _TopDisc | None = None


class _Cluster(NamedTuple):
    """One cluster's points: table-plane coordinates (N, 2), heights and depths (N,); its
    wall circle and whether that was fitted already (else it is still to be fitted)."""

    uw: Array
    h: Array
    z: Array
    circle: _Circle | None
    fitted: bool


#: :meth:`GeometricDetector._see_through`'s samples across the front (x the radius) and up
#: it (x the height), made once: np.linspace costs more per call than the rest of a row.
_SEE_ACROSS = np.linspace(-0.6, 0.6, 7)
_SEE_UP = np.linspace(0.15, 0.85, 8)
_CLEAR_MARGIN = 0.01  # m: a clear object blanks lines of sight this far beside its fitted circle


def bottle_box(
    intr: Intrinsics, foot_cam: Array, axis_cam: Array, radius: float, height: float
) -> tuple[float, float, float, float]:
    """Pixel box of an upright bottle standing at ``foot_cam``: the liquid meter's bottle
    model (body to the shoulder, then the cap's narrower width, see
    :func:`~armvision.perception.liquid.bottle_outline`) projected and clipped. Tighter than
    the whole cylinder's box where a bottle seen from above narrows to its cap, and the box
    the meter fits its model to."""
    outline = bottle_outline(foot_cam, axis_cam, radius, height, BOTTLE_BODY_FRACTION)
    return _image_box(intr, outline)


@functools.cache
def compile_kernels() -> None:
    """Compile the detector's Numba kernels (and the liquid meter's) once per process, from
    Numba's on-disk cache after the first time (a few seconds then, when ``make setup``
    does it), so that a detector's first frame is not late."""
    compile_rays()
    uw = np.column_stack([np.cos(np.arange(12.0)), np.sin(np.arange(12.0)) + 1.0]) * 0.03
    _wall_circle_kernel(uw, 0.001, 600, 8, 2e-5)
    _circle_inliers(uw, uw[:1] * 0.0, np.array([0.03]), 0.003)
    _depth_edges_kernel(
        np.ones((3, 3)), np.arange(9), np.float32(0.012), np.float32(0.08), np.float32(21.2)
    )
    _seen_through_kernel(uw, np.ones(12), 0.5, uw[:1], np.array([[0.03, 0.1]]), False)
    fit_plane(np.eye(3), 0.01, rng=np.random.default_rng(0), hypotheses=1)
    self_mask(np.ones((1, 3)), np.eye(4), np.zeros(6), workspace_radius=1.0, margin=0.01)


class GeometricDetector:
    """Bottles and cups as vertical cylinders standing on the table, from depth alone.

    Per frame: (1) the table plane by RANSAC on a subsampled point cloud (within
    ``max_table_tilt_deg`` of the table normal the camera pose predicts, when the frame's
    :class:`~armvision.perception.detection.FrameContext` gives ``T_base_cam``); (2) every
    pixel's height above it; pixels between ``min_height`` and ``max_height`` and nearer than
    ``max_range`` are candidates, except depth edges (a 3x3 depth range above ``edge_jump``
    or 5 x the depth noise); (3) with the context's ``T_base_cam``, anything farther than
    ``workspace_radius`` from the base axis is dropped and so are candidates within
    ``arm_margin`` of the arm's base, and with its ``joint_positions`` too of every link's
    capsule (the self-filter); without a camera pose only the range and height crop applies
    and the robot may be reported; (4) candidates are binned onto a ``grid_cell`` grid in the
    table plane, the occupied cells joined by a closing and labelled with OpenCV's connected
    components; a cluster with at least ``contained_fraction`` of its points within
    ``contained_margin`` of another's wall circle (either way round) is joined to it, one
    lying inside several circles is shared among them (:meth:`_share_insides`), and one
    holding two objects that touch (a container's full round wall and, outside it, something
    else) is split in two first (:meth:`_split_touching`); (5) per
    cluster a circle is fitted to the camera-facing wall (algebraic fit, then geometric Huber
    IRLS on the points within a band of the circle on the side facing the camera, so a cup's
    inner far wall, its liquid and a bottle's liquid surface do not pull it), the height is the
    ``top_rank``-th highest point (for a bottle raised through the full-resolution pixels near
    its axis: a nozzle or cap loop, or a cap over a clear neck that returned no depth,
    :meth:`_cap_top`), and the label comes from the shape (below). A cluster
    with no round wall (a box's face, its grazing side cut off as a depth edge) is "other",
    its footprint's width the diameter, unless at least ``bottle_min_height`` tall it is a
    clear bottle's cap and neck over a body that returned no depth (:meth:`_cap_over_gap`):
    a bottle about the cap's axis, or it narrows to a cap in its top ``cap_band``
    (:meth:`_narrow_top`): a flat-sided bottle. A cluster that fits no shape at all, not
    even a flat face (objects standing against each other), is one obstacle, other, when it
    is not too thin, too wide or too low for that (:meth:`_shapeless_obstacles`). (6) A
    short cluster cut by the left, right or top image border may be a clear bottle whose cap is
    outside the image: if its silhouette continues upward in colour (``color_contrast`` grey
    levels against its surroundings, with nothing standing behind it in depth) by more than
    ``bottle_gap``, it is a bottle whose height is that body top / ``bottle_body_fraction`` (a
    shape prior: the simulated bottles' body is 72 % of their height). (7) Nearest first, an
    object whose front surface returns no depth over at least ``clear_share`` of it (samples
    seen through a nearer object's fitted cylinder, a clear one's 1 cm wider, left out) and
    ``clear_min_radius`` or more in radius is clear: a bottle by height, else a cup; not a
    cluster with no round wall whose sides (below 0.75 x its top) lie within ``flat_face_rms``
    of one line over at least 1.5 x ``clear_min_radius`` of width: one planar face, a box of
    shiny metal or foil that returned no depth. (8) A clear cup seen only in pieces (patches too
    small for a cluster, or a clear piece fitted with a circle under ``clear_refit_radius``) is
    one cup of ``fragment_radius`` behind them when they group together and its front returns no
    depth over ``clear_share`` of it (:meth:`_clear_pieces`; ``fragment_min_points = 0`` turns
    this off). Only every ``pixel_stride``-th pixel and row is used, and circle fits use at most
    ``max_fit_points`` points.

    The shape rules. A bottle: at least ``bottle_min_height`` tall, or a neck (the top quarter's
    90th-percentile distance from the axis below ``neck_ratio`` x the radius), or a gap of at
    least ``bottle_gap`` with no points in the height profile under something narrow (below
    ``gap_top_ratio`` x the radius: a cap, not a clear cup's rim). A tall object with no neck
    and no gap, or a gap under a wide closed top (a lid over a band that returned no depth), is
    other when its top ``top_band`` is as wide as the body (75th percentile of distances from
    the axis at least ``wide_top_ratio`` x the radius or, if larger, x the median over 2 cm
    slices below of the same percentile: a can stack or canister; a partly seen wall fits a
    circle narrower than its points), and a tall object with no neck, cap or gap is other when
    its camera-facing wall fits two straight lines (as for cups, below) over at least
    ``tall_face_min_width`` (a box standing on end; a narrower arc is nearly straight: a
    bottle's sliver past a nearer object), unless it narrows to a cap in its top ``cap_band``
    (:meth:`_narrow_top`: a flat-sided bottle turned corner-on). A closed top: of the points
    inside the rim (nearer the axis than ``closed_top_inner`` x the radius, at least
    ``closed_top_min_points``), a share of at least ``closed_top_fraction`` lies within
    ``closed_top_tolerance`` of the rim (the near wall's 99th-percentile height, at most the
    top: a can's pull ring or flying pixels rise above its lid) (a can, box or block); a short
    object with one and no bottle evidence is other. A would-be cup is also other when wide and
    short (radius above ``bowl_min_radius`` and height below ``bowl_height_ratio`` x the
    diameter: a bowl), when its camera-facing wall fits two straight lines (a box's faces) with
    an RMS distance below ``straight_wall_ratio`` x that of the circle, the circle's being above
    ``straight_wall_min_rms``, or when seen from ``inside_min_elevation_deg`` or more above with
    its far top in view it shows no inside (fewer than ``closed_top_min_points``, or a fifth, of
    the points on its far half below the rim: a can's lid, or a box whose top returned no
    depth), and from lower when it shows no inside and the full-resolution depth over its top
    (:meth:`_top_disc`: the strided cloud loses a top seen at a low angle with the edges) is a
    lid, or meets fewer than ``opening_min_points`` rays passing over the rim into an opening
    while more of it is hidden by something nearer (or out of the image) than returns no depth
    (a top blanked by clear plastic, its own or in front, stays a cup). On cluttered seeds 0-399
    the objects whose top was hidden by something nearer were five cans and a fruit, and one
    tumbler. Either way, one whose top returned no depth through a clear object in front
    (:meth:`_blanked_top`) and whose top quarter is as wide as its wall is a cup after all:
    nothing of its top was seen. A short object called other for anything but its width is a cup
    when it carries a handle on its side (:meth:`_handle`): a mug filled near its rim shows a
    top as closed as a can's.

    A bottle's centre and radius are its body's (:meth:`_bottle_body`): the wall circle is
    fitted again below ``body_fit_fraction`` of its height when the whole cluster's circle is
    its cap's; a body radius below ``bottle_min_radius`` (a cap or a sliver seen past a
    nearer object) is widened toward ``bottle_prior_radius``, all the way at half of
    ``bottle_min_radius`` and in proportion between, the seen front kept in place
    (:meth:`_widened`; 0 turns it off). A step from under 18 mm straight to 30 mm had made
    a JPEG replay of the demo's tracks differ from the recording by 1.46 mm (0.55 without;
    0.42 with the ramp). A
    cluster at least ``bottle_min_height`` tall with no round wall through it is fitted again
    by its points above ``upper_fit_fraction`` of its height (:meth:`_upper_circle`): a bottle
    joined at its foot by a lower object (a cup's far wall a centimetre in front), taken when
    that circle is a bottle's (radius up to ``upper_max_radius``). A tall cluster that the
    wide-top test calls other but that is no wider than ``hidden_neck_max_radius`` and is
    only an upper part, its body hidden behind a nearer object (:meth:`_axis_below`), is a
    bottle's neck and cap seen over that object (a can stack's top is a can's width): a
    bottle, centred on its neck. One whose axis below shows what stands behind it, farther
    than the axis by ``through_margin`` or more (on at least half the samples, all but one
    of the rest hidden), stands on a body that returned no depth: a clear bottle's cap and neck, the
    body empty (MuJoCo's plain render gives a clear wall no depth, and on a real D435 an
    empty clear body can keep too few points to join its cap). A bottle about the cap's axis
    with ``bottle_prior_radius``.

    ``score``  = (fraction of wall points within 2.5 sigma of the fitted surface, sigma being
    Intel's depth noise at that distance) x min(1, wall points / ``full_support_points``):
    near 1 for a well-seen cylinder, low for a ragged or barely seen cluster. Clusters with
    fewer than ``min_points`` points, a radius outside ``radius_range`` or a height below
    ``min_object_height`` are not reported.
    """

    def __init__(
        self,
        *,
        min_height: float = 0.012,
        max_height: float = 0.40,
        max_range: float = 1.6,
        workspace_radius: float = 0.85,
        arm_margin: float = 0.02,
        arm_capsules: Sequence[tuple[Any, Any, float, int]] = VX300S_CAPSULES,
        arm_model: ArmModel = VX300S,
        plane_tolerance: float = 0.008,
        ransac_iterations: int = 64,
        ransac_points: int = 1500,
        max_table_tilt_deg: float = 15.0,
        grid_cell: float = 0.005,
        min_points: int = 40,
        radius_range: tuple[float, float] = (0.008, 0.08),
        min_object_height: float = 0.03,
        bottle_min_height: float = 0.135,
        neck_ratio: float = 0.7,
        bottle_gap: float = 0.02,
        top_rank: int = 5,
        use_color: bool = True,
        color_contrast: float = 10.0,
        bottle_body_fraction: float = BOTTLE_BODY_FRACTION,
        closed_top_inner: float = 0.6,
        closed_top_tolerance: float = 0.008,
        closed_top_fraction: float = 0.6,
        closed_top_min_points: int = 8,
        opening_min_points: int = 3,
        wide_top_ratio: float = 0.9,
        top_band: float = 0.015,
        cap_band: float = 0.03,
        bowl_min_radius: float = 0.042,
        bowl_height_ratio: float = 0.65,
        straight_wall_ratio: float = 0.8,
        straight_wall_min_rms: float = 0.002,
        tall_face_min_width: float = 0.05,
        handle_min_points: int = 8,
        full_support_points: int = 150,
        pixel_stride: int = 2,
        max_fit_points: int = 600,
        edge_jump: float = 0.012,
        clear_share: float = 0.3,
        clear_min_radius: float = 0.015,
        inside_min_elevation_deg: float = 30.0,
        gap_top_ratio: float = 0.8,
        fit_tolerance: float = 2e-5,
        fit_iterations: int = 8,
        contained_fraction: float = 0.8,
        contained_margin: float = 0.006,
        flat_face_rms: float = 0.003,
        body_fit_fraction: float = 0.55,
        upper_fit_fraction: float = 0.4,
        upper_max_radius: float = 0.05,
        hidden_neck_max_radius: float = 0.02,
        hidden_low_fraction: float = 0.4,
        hidden_margin: float = 0.06,
        through_margin: float = 0.02,
        bottle_min_radius: float = 0.024,
        bottle_prior_radius: float = 0.030,
        fragment_min_points: int = 20,
        fragment_radius: float = 0.035,
        fragment_clearance: float = 0.01,
        clear_refit_radius: float = 0.028,
        fragment_min_height: float = 0.055,
        fragment_max_span: float = 2.5,
        consensus_fraction: float = 0.6,
        consensus_draws: int = 64,
        split_outside: float = 0.15,
        split_min_width: float = 0.035,
        split_draws: int = 128,
        split_depth: int = 3,
        shapeless_max_width: float = 0.5,
        seed: int = 0,
    ) -> None:
        self.edge_jump = float(edge_jump)
        self.clear_share = float(clear_share)
        self.clear_min_radius = float(clear_min_radius)
        self.inside_min_elevation_deg = float(inside_min_elevation_deg)
        self.gap_top_ratio = float(gap_top_ratio)
        self.fit_tolerance = float(fit_tolerance)
        # The wall circle's Huber IRLS steps; 8, not 15: the same labels on cluttered seeds
        # 0-59 and default 0-19 / 9001-9020, centre medians 3.19 / 1.38 / 1.71 mm (3.22 /
        # 1.38 / 1.73 with 15), a tenth of the fits no longer run to the cap.
        self.fit_iterations = int(fit_iterations)
        self.contained_fraction = float(contained_fraction)
        self.contained_margin = float(contained_margin)
        self.flat_face_rms = float(flat_face_rms)
        self.body_fit_fraction = float(body_fit_fraction)
        self.upper_fit_fraction = float(upper_fit_fraction)
        self.upper_max_radius = float(upper_max_radius)
        self.hidden_neck_max_radius = float(hidden_neck_max_radius)
        self.hidden_low_fraction = float(hidden_low_fraction)
        self.hidden_margin = float(hidden_margin)
        self.through_margin = float(through_margin)
        self.bottle_min_radius = float(bottle_min_radius)
        self.bottle_prior_radius = float(bottle_prior_radius)
        self.fragment_min_points = int(fragment_min_points)
        self.fragment_radius = float(fragment_radius)
        self.fragment_clearance = float(fragment_clearance)
        self.clear_refit_radius = float(clear_refit_radius)
        self.fragment_min_height = float(fragment_min_height)
        self.fragment_max_span = float(fragment_max_span)
        self.consensus_fraction = float(consensus_fraction)
        self.consensus_draws = int(consensus_draws)
        self.split_outside = float(split_outside)
        self.split_min_width = float(split_min_width)
        self.split_draws = int(split_draws)
        self.split_depth = int(split_depth)
        self.shapeless_max_width = float(shapeless_max_width)
        self.min_height = float(min_height)
        self.max_height = float(max_height)
        self.max_range = float(max_range)
        self.workspace_radius = float(workspace_radius)
        self.arm_margin = float(arm_margin)
        self.arm_capsules = tuple(arm_capsules)
        self.arm_model = arm_model
        self.plane_tolerance = float(plane_tolerance)
        self.ransac_iterations = int(ransac_iterations)
        self.ransac_points = int(ransac_points)
        self.max_table_tilt_deg = float(max_table_tilt_deg)
        self.grid_cell = float(grid_cell)
        self.min_points = int(min_points)
        self.radius_range = (float(radius_range[0]), float(radius_range[1]))
        self.min_object_height = float(min_object_height)
        self.bottle_min_height = float(bottle_min_height)
        self.neck_ratio = float(neck_ratio)
        self.bottle_gap = float(bottle_gap)
        self.top_rank = int(top_rank)
        self.use_color = bool(use_color)
        self.color_contrast = float(color_contrast)
        self.bottle_body_fraction = float(bottle_body_fraction)
        self.closed_top_inner = float(closed_top_inner)
        self.closed_top_tolerance = float(closed_top_tolerance)
        self.closed_top_fraction = float(closed_top_fraction)
        self.closed_top_min_points = int(closed_top_min_points)
        self.opening_min_points = int(opening_min_points)
        self.wide_top_ratio = float(wide_top_ratio)
        self.top_band = float(top_band)
        self.cap_band = float(cap_band)
        self.bowl_min_radius = float(bowl_min_radius)
        self.bowl_height_ratio = float(bowl_height_ratio)
        self.straight_wall_ratio = float(straight_wall_ratio)
        self.straight_wall_min_rms = float(straight_wall_min_rms)
        self.tall_face_min_width = float(tall_face_min_width)
        self.handle_min_points = int(handle_min_points)
        self.full_support_points = int(full_support_points)
        if int(pixel_stride) < 1:
            raise ValueError(f"pixel_stride must be >= 1, not {pixel_stride}")
        self.pixel_stride = int(pixel_stride)
        self.max_fit_points = int(max_fit_points)
        self._rng = np.random.default_rng(seed)
        compile_kernels()
        #: The last frame's table plane n.p_cam + d = 0 (n toward the camera): the hybrid
        #: detector hands it to the network's placement (FrameContext.table_plane).
        self.last_plane: tuple[Array, float] | None = None
        #: The frame being detected's camera pose and joint angles, for the self-filter of
        #: what is looked at beyond the strided cloud (:meth:`_cap_top`).
        self._frame_pose: tuple[Array | None, ArrayLike | None] = (None, None)

    # ---------------------------------------------------------------- public

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]:
        """Bottles and cups in ``frame``; the context's camera pose gives the table prior and
        the workspace crop, its joint angles the self-filter (see the class docstring)."""
        T_base_cam = _pose(context.T_base_cam)
        self._frame_pose = (T_base_cam, context.joint_positions)
        intr = frame.intrinsics
        depth = np.asarray(frame.depth)
        if depth.shape != (intr.height, intr.width):
            raise PerceptionError(
                f"depth image is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                f"{intr.width}x{intr.height}: align depth to colour before detecting"
            )
        rays, _ = unit_depth_rays(intr, self.pixel_stride)
        # Only the strided pixels, row by row as the rays: a slice, not unit_depth_rays'
        # flat indices (a third of the gather's time).
        z = depth[:: self.pixel_stride, :: self.pixel_stride].astype(np.float64).ravel()
        in_range = (z > 0.0) & (z < self.max_range)
        normal, offset = self._table_plane(z, rays, in_range, T_base_cam)
        self.last_plane = (normal, offset)
        # Height of every pixel above the table: n.(z ray) + d, without building the cloud
        # (the rays' z is 1; in place on their contiguous columns).
        ray_x, ray_y = unit_depth_ray_columns(intr, self.pixel_stride)
        n_x, n_y, n_z = normal.tolist()
        h = ray_x * n_x
        h += ray_y * n_y
        h += n_z
        h *= z
        h += offset
        candidate = in_range & (h > self.min_height) & (h < self.max_height)
        idx = np.flatnonzero(candidate)
        if self.edge_jump > 0.0:
            idx = idx[~self._depth_edges(z, intr, idx)]
        p_cam = rays[idx] * z[idx, None]
        keep = self._self_filter(p_cam, T_base_cam, context.joint_positions)
        idx, p_cam = idx[keep], p_cam[keep]
        if len(idx) < min(self.min_points, max(self.fragment_min_points, 1)):
            return []
        e1, e2 = self._plane_axes(normal)
        uw = np.column_stack([p_cam @ e1, p_cam @ e2])
        labels = self._cluster(uw)
        order = np.argsort(labels, kind="stable")
        bounds = np.flatnonzero(np.diff(labels[order])) + 1
        clusters = [m for m in np.split(order, bounds) if labels[m[0]] > 0]
        groups = self._merge_contained(clusters, uw, p_cam[:, 2], h[idx])
        found = self._fit_clusters(
            frame,
            [
                _Cluster(uw[m], h[idx[m]], p_cam[m, 2], circle, fitted)
                for m, circle, fitted in groups
            ],
            normal,
            offset,
            e1,
            e2,
        )
        fits = [(f, groups[k][0]) for k, f in enumerate(found) if f is not None]
        fits += self._shapeless_obstacles(
            frame, [groups[k][0] for k, f in enumerate(found) if f is None],
            uw, h[idx], normal, offset, e1, e2,
        )  # fmt: skip
        detections, shares = self._clear_containers(
            frame, [f for f, _ in fits], normal, offset, e1, e2
        )
        if self.fragment_min_points <= 0:
            return detections
        return self._clear_pieces(
            frame,
            z,
            idx,
            uw,
            h[idx],
            detections,
            [m for _, m in fits],
            shares,
            normal,
            offset,
            e1,
            e2,
        )

    # ---------------------------------------------------------------- steps

    def _table_plane(
        self, z: Array, rays: Array, in_range: NDArray[np.bool_], T_base_cam: Array | None
    ) -> tuple[Array, float]:
        """The table plane (normal toward the camera, offset) by RANSAC on a random sample
        of the pixels ``in_range`` (with depth, nearer than ``max_range``)."""
        valid = np.flatnonzero(in_range)
        if len(valid) < 100:
            raise PerceptionError(
                "the depth image is (nearly) empty: is the camera's depth stream running and "
                "the table within range?"
            )
        pick = self._rng.choice(valid, size=min(self.ransac_points, len(valid)), replace=False)
        p_cam = rays[pick] * z[pick, None]
        prior = None
        if T_base_cam is not None:
            prior = T_base_cam[2, :3]  # base z in the camera frame: R_cam_base[:, 2]
        plane = fit_plane(
            p_cam,
            self.plane_tolerance,
            rng=self._rng,
            hypotheses=self.ransac_iterations,
            normal_prior=prior,
            max_tilt_rad=math.radians(self.max_table_tilt_deg),
        )
        if plane is None:
            raise PerceptionError(
                "no table plane in the depth image: is the table in view and within the depth "
                "range?"
            )
        share = float(plane.inliers.mean())
        if share < 0.2:
            raise PerceptionError(
                f"the largest plane holds only {share:.0%} of the depth points: is the "
                "table in view? (try `armvision sim snapshot` or check the camera placement)"
            )
        return plane.normal, plane.offset

    def _depth_edges(
        self, z: Array, intr: Intrinsics, idx: NDArray[np.intp] | None = None
    ) -> NDArray[np.bool_]:
        """Which pixels (of the strided grid, flat: those of ``idx``, default all) have a 3x3
        neighbourhood spanning a depth range above ``edge_jump`` (or 5 x Intel's depth noise
        there, if larger) and depth themselves: occluding contours and the flying pixels a
        depth camera puts along them, which would join objects standing apart. Faces seen
        at a grazing angle go too (their depth changes fast). :meth:`detect` asks about its
        candidates alone, a fraction of the grid."""
        s = self.pixel_stride
        grid = z.reshape(-(-intr.height // s), -(-intr.width // s))
        if idx is None:
            idx = np.arange(grid.size)
        return _depth_edges_kernel(
            grid,
            np.asarray(idx, dtype=np.int64),
            np.float32(self.edge_jump),
            np.float32(DEPTH_SUBPIXEL),
            np.float32(DEPTH_FOCAL_PX * DEPTH_BASELINE_M),
        )

    def _self_filter(
        self, p_cam: Array, T_base_cam: Array | None, joint_positions: ArrayLike | None
    ) -> NDArray[np.bool_]:
        if T_base_cam is None:
            return np.ones(len(p_cam), dtype=bool)
        return self_mask(
            p_cam,
            T_base_cam,
            joint_positions,
            workspace_radius=self.workspace_radius,
            margin=self.arm_margin,
            capsules=self.arm_capsules,
            model=self.arm_model,
        )

    @staticmethod
    def _plane_axes(normal: Array) -> tuple[Array, Array]:
        """Two unit axes spanning the table plane (e1 near the camera's x axis)."""
        e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
        e1 /= np.linalg.norm(e1)
        return e1, cross3(normal, e1)

    def _cluster(self, uw: Array, grid_cell: float | None = None) -> NDArray[np.int32]:
        """Connected-component label (0 = none) per point, from a grid in the table plane
        (cells of ``grid_cell``, by default the detector's)."""
        cell = np.floor((uw - uw.min(axis=0)) / (grid_cell or self.grid_cell)).astype(np.int64)
        shape = cell.max(axis=0) + 3
        grid = np.zeros((int(shape[1]), int(shape[0])), dtype=np.uint8)
        grid[cell[:, 1] + 1, cell[:, 0] + 1] = 1
        # Close one-cell gaps (edge dropouts, a cap offset from its liquid column).
        closed = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        _, components = cv2.connectedComponents(closed, connectivity=8)
        return components[cell[:, 1] + 1, cell[:, 0] + 1].astype(np.int32)

    def _merge_contained(
        self, clusters: list[NDArray[np.intp]], uw: Array, z: Array, h: Array
    ) -> list[tuple[NDArray[np.intp], _Circle | None, bool]]:
        """Clusters with a point count of at least ``min_points`` after joining every cluster
        lying inside another's wall circle to it (at least ``contained_fraction`` of its
        points within ``contained_margin`` of the circle): a cup's inside, cut from its wall
        at the rim by the depth-edge filter, or a clear bottle's cap above its liquid. Each
        with its wall circle (None: to be fitted, the cluster having grown). Objects standing
        apart (gaps of a centimetre or more) lie outside each other's circles. Each comes
        with its :meth:`_wall_circle` and whether that was computed (a cluster left alone
        keeps its own, even None or a circle too small or large: the fit need not run again).
        A cluster with a wall circle of its own is not joined to a smaller one's circle: a
        clear cup's sparse front fits too wide a circle, which reached over the can it
        touched, and so does the shallow arc of a liquid's far edge seen over a rim. First,
        a vessel takes back its inside from the clusters it joined (:meth:`_reclaim_insides`;
        ``h`` is each point's height); those clusters are fitted again."""
        clusters = sorted(clusters, key=len, reverse=True)
        big = [k for k, members in enumerate(clusters) if len(members) >= self.min_points]
        fits: list[_Circle | None] = [None] * len(clusters)
        for k, fit in zip(
            big,
            self._wall_circles(
                [uw[clusters[k]] for k in big], [self._sigma(z[clusters[k]]) for k in big]
            ),
        ):
            fits[k] = fit
        clusters, fits = self._split_touching(clusters, fits, uw, z, h)
        # A circle too small or large is not a container's wall: it contains nothing.
        circles = [fit if fit is not None and self._radius_ok(fit[1]) else None for fit in fits]
        n = len(clusters)
        lo, hi = _boxes(uw, clusters)
        changed = self._reclaim_insides(clusters, circles, uw, z, h, lo, hi)
        if self._share_insides(clusters, circles, uw, lo, hi, changed):
            kept = [k for k in range(n) if len(clusters[k])]
            clusters = [clusters[k] for k in kept]
            fits = [fits[k] for k in kept]
            circles = [circles[k] for k in kept]
            changed = changed[kept]
            n = len(clusters)
        if changed.any():
            lo, hi = _boxes(uw, clusters)
        joins = np.eye(n, dtype=bool)
        for j, circle in enumerate(circles):
            if circle is None:
                continue
            reach = circle[1] + self.contained_margin
            # A cluster whose bounding box misses the circle's has no point inside it.
            near = np.flatnonzero(
                ((lo <= circle[0] + reach) & (hi >= circle[0] - reach)).all(axis=1)
            )
            for i in near:
                own = circles[i]
                if own is not None and len(clusters[i]) > len(clusters[j]):
                    # A larger cluster with a wall of its own takes what lies in its own
                    # circle; this one may be a neighbour it reaches (a clear cup's circle,
                    # too wide, or a liquid's far edge, an arc fitted as a wide wall).
                    continue
                points = uw[clusters[i]]
                inside = _radial(points, circle[0]) < circle[1] + self.contained_margin
                joins[i, j] = inside.mean() >= self.contained_fraction
        # Either way round: a cup's outer wall holds its inside, and the inside's own circle
        # (its far inner wall) may hold the outer wall's points.
        group = _components(joins)
        members_of: dict[int, list[int]] = {}
        for k, g in enumerate(group.tolist()):
            members_of.setdefault(g, []).append(k)
        out = []
        for parts in members_of.values():  # in the order of their first (largest) cluster
            merged = np.concatenate([clusters[k] for k in parts])
            if len(merged) >= self.min_points:
                alone = len(parts) == 1 and not changed[parts[0]]
                out.append((merged, fits[parts[0]] if alone else None, alone))
        return out

    def _reclaim_insides(
        self,
        clusters: list[NDArray[np.intp]],
        circles: Sequence[_Circle | None],
        uw: Array,
        z: Array,
        h: Array,
        lo: Array,
        hi: Array,
    ) -> NDArray[np.bool_]:
        """Give each well-seen vessel's wall the points of other clusters inside its circle
        and below its rim (:meth:`_rim`, less ``closed_top_tolerance``), in place; which
        clusters changed. Over a cup's rim the camera sees its inner far wall at about the
        depth of what stands just behind it, and the two clustered together: the cup kept no
        inside (so it read as closed, a can) and the neighbour a piece of the cup. Nothing
        else stands inside a wall. Only walls that fix their circle (at most
        ``bowl_min_radius``, at least ``full_support_points`` wall points, nine in ten
        within 2.5 sigma: not a clear object's sparse front), and only from clusters that
        keep ``min_points`` (one lying inside as a whole is joined by the circle test).
        ``lo``, ``hi``: the clusters' bounding boxes (:func:`_boxes`)."""
        changed = np.zeros(len(clusters), dtype=bool)
        for j, circle in enumerate(circles):
            if circle is None or circle[1] > self.bowl_min_radius:
                continue
            center, radius, res, wall = circle
            # A cluster whose bounding box misses the circle's has no point inside it.
            near = np.flatnonzero(((lo <= center + radius) & (hi >= center - radius)).all(axis=1))
            near = near[near != j]
            support = int(wall.sum())
            if len(near) == 0 or support < self.full_support_points:
                continue
            if not _fixes_circle(res, wall, self._sigma(z[clusters[j]])):
                continue
            hj = h[clusters[j]]
            rim = self._rim(uw[clusters[j]], hj, center, radius, self._top(hj))
            for i in near:
                members = clusters[i]
                inside = (_radial(uw[members], center) < radius) & (
                    h[members] < rim - self.closed_top_tolerance
                )
                taken = int(inside.sum())
                if taken and len(members) - taken >= self.min_points:
                    clusters[j] = np.concatenate([clusters[j], members[inside]])
                    clusters[i] = members[~inside]
                    changed[i] = changed[j] = True
        return changed

    def _share_insides(
        self,
        clusters: list[NDArray[np.intp]],
        circles: Sequence[_Circle | None],
        uw: Array,
        lo: Array,
        hi: Array,
        changed: NDArray[np.bool_],
    ) -> bool:
        """Share out, in place, each cluster with no wall of its own that lies inside two or
        more vessels' circles: ``contained_fraction`` of its points within
        ``contained_margin`` of one circle or another, no one circle holding that many (the
        join takes those whole). Each point goes to the circle it lies deepest in. Two cups
        standing together show the top bands of their inner far walls (above what
        :meth:`_reclaim_insides` takes) as one cluster over both rims, which was reported as
        an obstacle behind them. Whether any was shared (those clusters are left empty)."""
        shared = False
        walls = [(j, c[0], c[1]) for j, c in enumerate(circles) if c is not None]
        if len(walls) < 2:
            return False
        for i, circle in enumerate(circles):
            if circle is not None or not len(clusters[i]):
                continue
            # (``lo``, ``hi``: boxes from before _reclaim_insides, which only took points
            # from clusters: they still hold them.)
            near = [
                (j, center, radius)
                for j, center, radius in walls
                if (lo[i] <= center + radius).all() and (hi[i] >= center - radius).all()
            ]
            if len(near) < 2:
                continue
            points = uw[clusters[i]]
            depth = np.stack([_radial(points, center) - radius for _, center, radius in near])
            inside = depth < self.contained_margin
            if inside.mean(axis=1).max() >= self.contained_fraction:
                continue
            if inside.any(axis=0).mean() < self.contained_fraction:
                continue
            owner = np.argmin(depth, axis=0)
            for k, (j, _, _) in enumerate(near):
                mine = clusters[i][owner == k]
                if len(mine):
                    clusters[j] = np.concatenate([clusters[j], mine])
                    changed[j] = True
            clusters[i] = clusters[i][:0]
            changed[i] = shared = True
        return shared

    def _split_touching(
        self,
        clusters: list[NDArray[np.intp]],
        fits: list[_Circle | None],
        uw: Array,
        z: Array,
        h: Array,
    ) -> tuple[list[NDArray[np.intp]], list[_Circle | None]]:
        """The clusters (largest first) and their wall circles (``fits``, None below
        ``min_points``), each of at least 2 x ``min_points`` that holds two objects touching
        split in two (:meth:`_split`), both parts with their own circle, and the rest split
        again while it splits (``split_depth`` times at most: a row of objects standing
        together); largest first again."""
        out: list[tuple[NDArray[np.intp], _Circle | None]] = []
        for members, fit in zip(clusters, fits):
            for _ in range(self.split_depth):
                parts = None
                if len(members) >= 2 * self.min_points:
                    parts = self._split(uw[members], z[members], h[members], fit)
                if parts is None:
                    break
                vessel, rest = members[parts[0]], members[parts[1]]
                out.append((vessel, self._wall_circle(uw[vessel], self._sigma(z[vessel]))))
                members, fit = rest, self._wall_circle(uw[rest], self._sigma(z[rest]))
            out.append((members, fit))
        out.sort(key=lambda item: len(item[0]), reverse=True)
        return [m for m, _ in out], [f for _, f in out]

    def _split(
        self, uw: Array, z: Array, h: Array, whole: _Circle | None
    ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]] | None:
        """A cluster of two objects standing against each other as two masks (the container,
        the rest); None when it is one object. Objects that touch share a cluster: a cup
        against a bowl or a can, a sports bottle against a canister, a clear cup against a
        wine bottle. Tried on a cluster whose own wall circle (``whole``) is no container's
        (none, or a radius outside ``radius_range``) or leaves ``split_outside`` of its
        points (and ``min_points``) more than 3 sigma (at least ``contained_margin``)
        outside it. The container: of ``split_draws`` circles drawn, the one most points
        agree on (:meth:`_best_drawn_circle`, facing the camera), fitted again to them, at
        least ``bottle_min_radius`` in radius (a full wall, not a sliver's or a clear
        piece's narrow circle), with what lies inside it. The rest is another object when
        it has ``min_points`` points, stands ``min_object_height`` tall and spans
        ``split_min_width`` (a mug's handle reaches 3 cm out at most), when the container's
        points fit a round wall of their own (:meth:`_round_wall`), and when, if the rest
        fits a circle too, neither axis lies inside the other's circle (patches of one clear
        object). Where two round walls meet, each point goes to the one it lies deeper in
        (then the container must keep ``min_points``). :meth:`_split_touching` tries the
        rest again. On cached cluttered seeds 0-1299: 12 more containers found (9 of them on
        650-1299), 3 false positives fewer, nothing lost. The rules came from seeds 0-349
        and 73 and from hand-made depth images (``benchmarks/bench_touching.py``: random
        touching pairs); 650-1299 was looked at only as totals and lists of changes."""
        sigma = self._sigma(z)
        margin = max(3.0 * sigma, self.contained_margin)
        if whole is not None:
            center, radius = whole[0], whole[1]
            if self._radius_ok(radius):
                outside = int(np.count_nonzero(_radial(uw, center) > radius + margin))
                if outside < max(self.min_points, self.split_outside * len(uw)):
                    return None  # one container (a mug's handle, flying pixels outside)
        agree = self._best_drawn_circle(uw, sigma, self.split_draws, facing=True)
        if agree is None:
            return None
        fit = self._wall_circle(uw[agree], sigma)
        if fit is None or not self.bottle_min_radius <= fit[1] <= self.radius_range[1]:
            return None
        vessel = _radial(uw, fit[0]) < fit[1] + margin
        rest = ~vessel
        if min(int(vessel.sum()), int(rest.sum())) < self.min_points:
            return None
        own = self._wall_circle(uw[vessel], sigma)
        if own is None or not self._round_wall(uw[vessel], own, sigma):
            return None
        if self._top(h[rest]) < self.min_object_height:
            return None
        _, _, lo, hi = _principal_extent(uw[rest])
        if float((hi - lo).max()) < self.split_min_width:
            return None
        other = self._wall_circle(uw[rest], sigma)
        if other is None or not self._radius_ok(other[1]):
            return vessel, rest
        if math.dist(own[0], other[0]) < max(own[1], other[1]):
            return None  # one's axis inside the other: patches of one object (clear plastic)
        if not self._round_wall(uw[rest], other, sigma):
            return vessel, rest  # a box's faces, no wall to meet the container's
        # Where the two walls meet, each point to the one it lies deeper in (signed distances
        # from the walls, negative inside; the container's inside stays with it).
        off_own = _radial(uw, own[0]) - own[1]
        nearer = vessel & (off_own > -margin) & (_radial(uw, other[0]) - other[1] < off_own)
        if np.count_nonzero(vessel & ~nearer) < self.min_points:
            return None  # the container's points lie deeper in the other: no container
        return vessel & ~nearer, rest | nearer

    def _round_wall(self, uw: Array, fit: _Circle, sigma: float) -> bool:
        """Whether ``fit`` (a :meth:`_wall_circle` of ``uw``) is a round wall: a radius in
        ``radius_range``, not a box's two straight lines (:meth:`_straight_walls`), and its
        wall fixing its circle (:func:`_fixes_circle`, as in :meth:`_reclaim_insides`)."""
        _, radius, res, wall = fit
        if not self._radius_ok(radius) or self._straight_walls(uw[wall], res[wall]):
            return False
        return _fixes_circle(res, wall, sigma)

    def _radius_ok(self, radius: float) -> bool:
        return self.radius_range[0] <= radius <= self.radius_range[1]

    @staticmethod
    def _sigma(z: Array) -> float:
        """Intel's depth noise at the median depth of ``z``, at least a millimetre."""
        return max(float(depth_rms_error(percentile(z, 50.0))), 0.001)

    def _shapeless_obstacles(
        self,
        frame: RGBDFrame,
        shapeless: Sequence[NDArray[np.intp]],
        uw: Array,
        h: Array,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> list[tuple[_Fit, NDArray[np.intp]]]:
        """Clusters that fitted no shape at all (no round wall, no flat face: objects standing
        against each other, or one with a handle, a spout and a lid, wider than a flat face
        is taken to be), each reported as one obstacle, other, when it stands at least
        ``min_object_height`` tall and its footprint is at most ``shapeless_max_width``
        across: a circle about the middle of its points' 2nd-98th percentile extent along
        their principal axes, the longer extent its diameter. Wider ones are what stands
        beyond the table (a wall, a chair), not on it; narrower than the smallest radius's
        diameter, slivers of objects hidden behind nearer ones (all 22 such clusters on
        cached cluttered seeds 0-1299: an obstacle that thin says nothing, and those on cups
        would count as cups called other), also not; nor one standing less than a quarter of
        its width high (a cloth's sweep up to the backdrop on ClearGrasp's frame 153: 46 cm
        wide, 4 cm high). On PoseCNN's YCB frame 2 a pitcher with a banana and a gelatin box
        against its foot made one cluster 33 cm long whose circle was 14 cm in radius: none
        of the three was reported, not even as something to keep clear of. Its handle and
        spout fit no circle either, so the cluster is not taken apart. Returns each one's
        fit and its points (indices into ``uw``); its score is its support, as a flat
        face's."""
        out: list[tuple[_Fit, NDArray[np.intp]]] = []
        for members in shapeless:
            top = self._top(h[members])
            if len(members) < self.min_points or top < self.min_object_height:
                continue
            mid, axes, lo, hi = _principal_extent(uw[members])
            width = float((hi - lo).max())
            if not 2.0 * self.radius_range[0] <= width <= self.shapeless_max_width:
                continue
            if top < 0.25 * width:
                continue  # the surface's own relief
            center = mid + axes @ (0.5 * (lo + hi))
            radius = 0.5 * width
            center_cam = center[0] * e1 + center[1] * e2 + (0.5 * top - offset) * normal
            det = Detection(
                label="other",
                score=min(1.0, len(members) / self.full_support_points),
                box=cylinder_box(frame.intrinsics, center_cam, normal, radius, top),
                center_cam=center_cam,
                size=np.array([width, top, width]),
                radius=radius,
                height=top,
                axis_cam=normal.copy(),
            )
            out.append((_Fit(det, False, None), members))
        return out

    def _fit_cluster(
        self,
        frame: RGBDFrame,
        uw: Array,
        h: Array,
        z: Array,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
        circle: _Circle | None = None,
        fitted: bool = False,
    ) -> _Fit | None:
        """The cluster's detection, whether it is one planar face (no round wall and its
        points within ``flat_face_rms`` (RMS) of one line in the table plane) and what its top
        showed if it is other for showing no opening. ``circle`` is its :meth:`_wall_circle`
        when ``fitted``; else that is fitted here."""
        cluster = _Cluster(uw, h, z, circle, fitted)
        return self._fit_clusters(frame, [cluster], normal, offset, e1, e2)[0]

    def _fit_clusters(
        self,
        frame: RGBDFrame,
        clusters: Sequence[_Cluster],
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> list[_Fit | None]:
        """:meth:`_fit_cluster` of every cluster, the circle fits of one kind run together:
        the wall circles not fitted yet, then the bottles' bodies (:meth:`_bottle_body`)."""
        sigmas = [self._sigma(c.z) for c in clusters]
        circles = [c.circle for c in clusters]
        todo = [k for k, c in enumerate(clusters) if not c.fitted]
        fits = self._wall_circles([clusters[k].uw for k in todo], [sigmas[k] for k in todo])
        for k, fit in zip(todo, fits):
            circles[k] = fit
        tops = [self._top(c.h) for c in clusters]
        # A tall cluster without a round wall may be a bottle joined at its foot by a lower
        # object's rim (a cup's far wall a centimetre in front of it): its upper part's; any
        # other, the circle most of its points agree on (a mug's handle pulled the fit off).
        for k, c in enumerate(clusters):
            circle = circles[k]
            if circle is None or not self._radius_ok(circle[1]):
                circles[k] = (
                    self._upper_circle(c.uw, c.h, tops[k], sigmas[k])
                    or self._consensus_circle(c.uw, sigmas[k])
                    or circle
                )
        shapes = [
            self._shape(frame, c.uw, c.h, tops[k], circles[k], normal, offset, e1, e2)
            for k, c in enumerate(clusters)
        ]
        bodies = {}
        for k, shape in enumerate(shapes):
            if shape is not None and shape[0] == "bottle":
                body = self._body_mask(clusters[k].h, shape[1])
                if int(body.sum()) >= self.min_points:
                    bodies[k] = body
        body_fits = dict(
            zip(
                bodies,
                self._wall_circles(
                    [clusters[k].uw[body] for k, body in bodies.items()],
                    [sigmas[k] for k in bodies],
                ),
            )
        )
        out: list[_Fit | None] = []
        for k, shape in enumerate(shapes):
            if shape is None:
                out.append(None)
                continue
            label, top, circle, planar, unopened = shape
            if label == "bottle":
                c = clusters[k]
                circle = self._bottle_body(
                    c.uw, c.h, top, sigmas[k], circle, body_fits.get(k), fitted=True
                )
            det = self._detection(frame, label, top, circle, sigmas[k], normal, offset, e1, e2)
            out.append(_Fit(det, planar, unopened))
        return out

    def _shape(
        self,
        frame: RGBDFrame,
        uw: Array,
        h: Array,
        top: float,
        circle: _Circle | None,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> tuple[Label, float, _Circle, bool, _TopDisc | None] | None:
        """A cluster's label, height (``top``, :meth:`_top`), circle (its wall's, or without
        a round wall its flat face's), whether it is one planar face and, when it is other
        only for showing no opening in its top, what the top showed; None if it is too low or
        shapeless."""
        if top < self.min_object_height:
            return None
        if circle is None or not self._radius_ok(circle[1]):
            # No round wall: a box's face seen flat (its grazing side cut off as a depth
            # edge), or a shapeless cluster. Kept as an obstacle if it is small enough.
            face = self._flat_face(uw)
            if face is None:
                return None
            if top >= self.bottle_min_height:
                cap = self._cap_over_gap(frame, uw, h, top, normal, offset, e1, e2)
                if cap is not None:
                    return "bottle", top, cap, False, None
                if self._narrow_top(uw, h, top):
                    return "bottle", top, face, False, None
            # A face at least 1.5 x clear_min_radius wide (not a sliver of a clear object
            # seen past a nearer one) on one line below its top (which fills an area).
            side = uw[h < 0.75 * top]
            wide = face[1] >= 1.5 * self.clear_min_radius and len(side) >= 20
            planar = wide and _line_ss(side) < len(side) * self.flat_face_rms**2
            return "other", top, face, planar, None
        center, radius, res, wall = circle
        rim = self._rim(uw, h, center, radius, top)
        label = self._classify(uw, h, center, radius, top, res, wall, rim=rim)
        if (
            label == "other"
            and top >= self.bottle_min_height
            and radius <= self.hidden_neck_max_radius
        ):
            below = self._axis_below(frame, h, center, top, normal, offset, e1, e2)
            if below == "hidden":
                label = "bottle"  # a bottle's neck and cap above a nearer object that hides it
            elif below == "through":
                # A cap over nothing the camera sees, with what stands behind in view through
                # it: a clear bottle's cap and neck over a body that returned no depth.
                label, circle = "bottle", (center, self.bottle_prior_radius, res, wall)
        unopened = None
        if label == "cup" and not self._shows_inside(uw, h, center, radius, rim):
            # What the top showed, kept for _clear_containers when the top quarter is as wide
            # as the wall (a vessel's rim; a fruit narrows to its top): an object called
            # other below for showing no opening may have had its top blanked by clear
            # plastic in front.
            upper = _radial(uw[h > 0.75 * top], center)
            rimmed = len(upper) >= 5 and percentile(upper, 75.0) >= radius
            elevation = math.atan2(offset - top, math.hypot(*center))
            far_top = self._far_top_in_view(frame, center, radius, top, normal, offset, e1, e2)
            disc = self._top_disc(frame, center, radius, rim, normal, offset, e1, e2)
            if elevation >= math.radians(self.inside_min_elevation_deg) and far_top:
                # Its top in view from above, yet no inside: closed (unless clear plastic in
                # front blanked it: _clear_containers).
                label, unopened = "other", disc if rimmed else None
            else:
                judged = disc.on + disc.beyond
                if (
                    judged >= self.closed_top_min_points
                    and disc.on >= self.closed_top_fraction * judged
                ):
                    label = "other"  # a lid where a cup's opening would be
                elif disc.beyond < self.opening_min_points and disc.missing <= disc.nearer:
                    # Its top hidden by something nearer (or out of the image): no opening
                    # seen, and none to be seen. A top returning no depth is left a cup: clear
                    # plastic, its own or in front, blanks it (judged by _clear_containers).
                    label, unopened = "other", disc if rimmed else None
        if (
            label == "other"
            and top < self.bottle_min_height
            and not (radius > self.bowl_min_radius and top < self.bowl_height_ratio * 2.0 * radius)
            and self._handle(uw, h, center, radius, top)
        ):
            # A mug, whatever its top showed: filled to a few mm under the rim, its liquid
            # reads as a can's closed lid.
            label, unopened = "cup", None
        return label, top, circle, False, unopened

    def _detection(
        self,
        frame: RGBDFrame,
        label: Label,
        top: float,
        circle: _Circle,
        sigma: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> Detection:
        """The detection of a cluster of ``label`` and height ``top`` standing in ``circle``."""
        center, radius, res, wall = circle
        foot_cam = center[0] * e1 + center[1] * e2 - offset * normal
        intr = frame.intrinsics
        seen_top = top
        cylinder = cylinder_box(intr, foot_cam + 0.5 * top * normal, normal, radius, top)
        x0, y0, x1, _ = cylinder
        at_border = x0 <= 2.0 or y0 <= 2.0 or x1 >= intr.width - 2.0
        if top < self.bottle_min_height and self.use_color and at_border:
            # A clear bottle cut by the image border (its cap outside) shows in depth only as
            # its liquid; its empty body above shows in colour. Cups are opaque: depth saw all.
            # Only at the border: a clear bottle standing in front of a cup would otherwise
            # make the cup look taller in colour.
            body_top = self._color_top(frame, foot_cam, normal, offset, e1, e2, radius, top)
            if body_top > top + self.bottle_gap:
                label = "bottle"
                top = max(top, body_top / self.bottle_body_fraction)
        elif label == "bottle":
            # The full-resolution points near the axis above the top, read once for both.
            near = self._near_axis(frame, foot_cam, normal, offset, radius, top, self.max_height)
            top = self._thin_top(near[1], top)
            top = self._cap_top(frame, foot_cam, normal, offset, radius, top, near=near)
        n_wall = int(wall.sum())
        fit_fraction = float((np.abs(res[wall]) < 2.5 * sigma).mean())
        score = fit_fraction * min(1.0, n_wall / self.full_support_points)
        center_cam = foot_cam + 0.5 * top * normal
        det = Detection(
            label=label,
            score=score,
            box=(
                bottle_box(frame.intrinsics, foot_cam, normal, radius, top)
                if label == "bottle"
                else cylinder
                if top == seen_top
                else cylinder_box(frame.intrinsics, center_cam, normal, radius, top)
            ),
            center_cam=center_cam,
            size=np.array([2.0 * radius, top, 2.0 * radius]),
            radius=float(radius),
            height=top,
            axis_cam=normal.copy(),
        )
        return det

    def _clear_containers(
        self,
        frame: RGBDFrame,
        fits: Sequence[_Fit],
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> tuple[list[Detection], list[float]]:
        """Detections not labelled bottle that the depth camera mostly cannot see (a missing
        share of at least ``clear_share`` over their front surface, see
        :meth:`_see_through`, nearest first, leaving out the samples whose line of sight
        passes through a nearer object's cylinder: they do not see this object's surface, and
        a clear one blanks what is behind it, an opaque one's edge drops depth (a clear
        object's cylinder is 1 cm wider: a fit to its patches may be narrow); not the nearer
        objects' image boxes, which hid cups behind and beside bottles) and at least
        ``clear_min_radius`` in radius (not a
        fragment of a clear object's sparse depth): clear plastic or
        glass, on a table a drinking vessel or a bottle (by height), not a can, box or bowl.
        One called other for its flat top may be the liquid in a clear cup, the clear wall
        above returning no depth (:meth:`_clear_above`, lines of sight through any clear
        object, nearer or behind, left out: above it the rays meet what stands behind, an
        opaque object returns depth): a
        cup. So is one called other for showing no opening in its top whose top clear plastic
        in front blanked (:meth:`_blanked_top`; when its top quarter is as wide as its wall,
        see :meth:`_shape`): nothing was seen there, closed or open. Returns the detections
        and each one's missing share."""
        detections = [f.detection for f in fits]
        planar = [f.planar for f in fits]
        out = list(detections)
        shares = [0.0] * len(out)
        if self.clear_share >= 1.0:
            return out, shares
        clear_ones: list[_Standing] = []
        nearer: list[_Standing] = []
        feet = [d.center_cam - 0.5 * d.height * normal for d in detections]
        centers = [np.array([foot @ e1, foot @ e2]) for foot in feet]
        solid: list[int] = []
        for i in np.argsort([d.center_cam[2] for d in detections]):  # nearest first
            det = out[i]
            share = self._see_through(
                frame, centers[i], det.radius, det.height, normal, offset, e1, e2, nearer
            )
            shares[i] = share
            nearer.append(_standing(centers[i], det, share >= self.clear_share))
            if share < self.clear_share:
                solid.append(i)
                continue
            clear_ones.append(nearer[-1])
            # Not wider than a flat face is taken to be: objects standing together
            # (_shapeless_obstacles) are no one clear container.
            clear = (
                det.label != "bottle"
                and self.clear_min_radius <= det.radius <= 2.0 * self.radius_range[1]
            )
            if clear and not planar[i]:
                label: Label = "bottle" if det.height >= self.bottle_min_height else "cup"
                box = det.box
                if label == "bottle":
                    box = bottle_box(frame.intrinsics, feet[i], normal, det.radius, det.height)
                out[i] = dataclasses.replace(det, label=label, box=box)
        for i in solid:
            det = out[i]
            if det.label == "other" and self._blanked_top(
                det, fits[i].unopened, centers[i], offset, clear_ones
            ):
                out[i] = dataclasses.replace(det, label="cup")
                continue
            # Above it, the rays meet what stands behind: missing depth there may be a clear
            # object's, nearer or behind, through which samples are left out; an opaque one
            # returns depth.
            if (
                det.label == "other"
                and not planar[i]
                and self._clear_above(frame, det, centers[i], normal, offset, e1, e2, clear_ones)
            ):
                out[i] = dataclasses.replace(det, label="cup")
        return out, shares

    def _blanked_top(
        self,
        det: Detection,
        disc: _TopDisc | None,
        center: Array,
        offset: float,
        clear_ones: Sequence[_Standing],
    ) -> bool:
        """Whether an object called other for showing no opening (``disc``: what its top
        showed) saw its top only through clear plastic in front: more of the top's samples
        returned no depth than lay on or beyond it, at least as many as returned something
        nearer (the clear object's own front), and the lines of sight to at least half of a
        grid over it (:meth:`_top_disc`'s, at the object's height) pass through one of
        ``clear_ones``. On cluttered seeds 0-399 these were four tumblers and clear cups
        behind clear bottles; a can and a fruit behind clear bottles showed their tops
        (the bottle's front returned depth over them), and a fruit whose top was blanked
        narrows to it."""
        if (
            disc is None
            or not clear_ones
            or disc.missing <= disc.on + disc.beyond
            or disc.missing < disc.nearer
        ):
            return False
        grid = self._disc_grid(det.radius)
        behind = _seen_through(center + grid, np.full(len(grid), det.height), offset, clear_ones)
        return float(behind.mean()) >= 0.5

    def _clear_pieces(
        self,
        frame: RGBDFrame,
        z: Array,
        idx: NDArray[np.intp],
        uw: Array,
        h: Array,
        detections: list[Detection],
        members: Sequence[NDArray[np.intp]],
        shares: Sequence[float],
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> list[Detection]:
        """Clear containers seen only in pieces: a D435 returns no depth over half of clear
        plastic and the surface behind it over a third (ClearGrasp's real frames), so what
        is left of a clear cup is scattered patches, each too small for a cluster, or a
        piece that was fitted as an object of its own with too small a circle.

        The pieces: detections not labelled bottle whose circle is narrower than
        ``clear_refit_radius`` and whose front returns no depth over at least ``clear_share``
        of it (:meth:`_clear_containers`), or would as the front of a ``fragment_radius``
        container behind its points (a circle fitted through a clear piece runs through the
        patches that returned depth, so its own front shows them). Their points and the
        candidate points no cluster took (``members`` are the detections' points in ``uw``,
        ``idx`` each point's pixel on the strided grid, ``h`` its height), leaving out those
        within
        ``fragment_clearance`` of another detection's footprint (its edges, a grazing face),
        are grouped on a grid twice as coarse. A group of at least ``fragment_min_points``,
        its top from ``fragment_min_height`` to below ``bottle_min_height`` (see below for
        lower ones), its bearings
        spanning no more than ``fragment_max_span`` x the radius at its range (wider: a
        surface, or something lying), is taken for the front of a container of radius
        ``fragment_radius`` (scattered patches do not fix a radius), its centre behind them
        (:func:`_behind_front`), its height their top. A lower group, however low (clear
        plastic lying on its side, on ClearGrasp's frames, or the liquid or the bottom of a
        clear cup), stands that high only when a clear wall above it does
        (:meth:`_clear_wall_top`), and is as tall as that wall. It replaces the group's
        pieces when it stands ``fragment_clearance`` clear of every other detection and
        returns no depth over at least ``clear_share`` of its front (lines of sight through
        nearer objects left out): a clear cup. Its centre is good to a centimetre or two: enough to
        count it and to keep a grasp clear of it. Taller groups are left as they were: a
        bottle is something the tasks grasp.
        """
        plane = np.column_stack([e1, e2])
        feet = [(d.center_cam @ plane, d.radius) for d in detections]
        clear = [share >= self.clear_share for share in shares]
        standing = [_standing(feet[k][0], d, clear[k]) for k, d in enumerate(detections)]
        clear_ones = [standing[k] for k in range(len(detections)) if clear[k]]
        pieces = [
            k
            for k, d in enumerate(detections)
            if d.label != "bottle"
            and d.radius < self.clear_refit_radius
            and (
                clear[k]
                or self._see_through(
                    frame,
                    _behind_front(uw[members[k]], self.fragment_radius),
                    self.fragment_radius,
                    d.height,
                    normal,
                    offset,
                    e1,
                    e2,
                    clear_ones,
                    skip_beyond=True,
                )
                >= self.clear_share
            )
        ]
        taken = np.zeros(len(uw), dtype=bool)
        for m in members:
            taken[m] = True
        solid = [k for k in range(len(detections)) if k not in pieces]
        free = np.flatnonzero(~taken)
        for k in solid:  # a detection's remnants (edges, a grazing face) are its own
            free = free[_radial(uw[free], feet[k][0]) >= feet[k][1] + self.fragment_clearance]
        owner = np.full(len(uw), -1)
        for k in pieces:
            owner[members[k]] = k
        which = np.sort(np.concatenate([free] + [members[k] for k in pieces]))
        if len(which) < self.fragment_min_points:
            return detections
        labels = self._cluster(uw[which], 2.0 * self.grid_cell)
        radius = self.fragment_radius
        replaced: set[int] = set()
        added: list[Detection] = []
        for label in np.unique(labels[labels > 0]):
            group = which[labels == label]
            top = self._top(h[group])
            # However low (every candidate point is at least min_height up): a clear cup's
            # liquid or bottom, its wall above blank, is judged by that wall below.
            if len(group) < self.fragment_min_points or top >= self.bottle_min_height:
                continue
            bearings = np.arctan2(uw[group, 1], uw[group, 0])
            span = float(bearings.max() - bearings.min()) * float(np.median(np.hypot(*uw[group].T)))
            if span > self.fragment_max_span * radius:
                continue  # wider than one cup's front: a surface, or something lying
            center = _behind_front(uw[group], radius)
            gap = radius + self.fragment_clearance
            if any(math.hypot(*(center - feet[k][0])) < feet[k][1] + gap for k in solid):
                continue
            if any(math.hypot(*(center - c)) < r + gap for c, r in feet[len(detections) :]):
                continue
            far = math.hypot(*center)
            nearer = [standing[k] for k in solid if math.hypot(*feet[k][0]) < far]
            if top < self.fragment_min_height:
                # Low pieces: clear plastic lying, or the liquid in a clear cup, whose wall
                # above returns no depth where what stands behind it would.
                top = self._clear_wall_top(frame, center, radius, top, normal, offset, e1, e2)
                if top < self.fragment_min_height:
                    continue
            share = self._see_through(frame, center, radius, top, normal, offset, e1, e2, nearer)
            if share < self.clear_share:
                continue
            foot_cam = center[0] * e1 + center[1] * e2 - offset * normal
            center_cam = foot_cam + 0.5 * top * normal
            added.append(
                Detection(
                    label="cup",
                    score=share * min(1.0, len(group) / self.full_support_points),
                    box=cylinder_box(frame.intrinsics, center_cam, normal, radius, top),
                    center_cam=center_cam,
                    size=np.array([2.0 * radius, top, 2.0 * radius]),
                    radius=radius,
                    height=top,
                    axis_cam=normal.copy(),
                )
            )
            feet.append((center, radius))
            replaced.update(int(k) for k in np.unique(owner[group]) if k >= 0)
        return [d for k, d in enumerate(detections) if k not in replaced] + added

    def _clear_wall_top(
        self,
        frame: RGBDFrame,
        center: Array,
        radius: float,
        top: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
        step: float = 0.01,
    ) -> float:
        """The top of a clear wall standing on what was seen up to ``top``: climbing in
        ``step`` bands of :meth:`_see_through` samples (three rows) over the object's front,
        while a band, or the one above it (a patch may show what is behind), returns no
        depth over at least ``clear_share`` of it and the table or whatever stands beside
        the object at those heights (1.5 radii to either side) returns depth on each side
        (two of three rows), up to ``bottle_min_height``. ``top`` itself when the first band
        returns depth (above a can the rays meet what stands behind). With no depth beside
        it (beyond the table's far edge) nothing is judged, nor with none on one side: a
        clear bottle lying across the view (ClearGrasp's frames) is clear beside its pieces
        along its length."""
        to_cam = -center / max(math.hypot(*center), 1e-9)
        lateral = np.array([-to_cam[1], to_cam[0]])
        beside = center + np.outer([-1.5 * radius, 1.5 * radius], lateral)
        beside_feet = (beside[:, :1] * e1 + beside[:, 1:] * e2 - offset * normal)[:, None, :]
        raised = top
        for low in np.arange(top, self.bottle_min_height - step, step):
            heights = low + step * np.array([0.2, 0.5, 0.8])
            p_cam = beside_feet + heights[None, :, None] * normal
            uv, ok = _in_image(frame.intrinsics, p_cam.reshape(-1, 3))
            seen = np.zeros(len(ok), dtype=bool)
            seen[ok] = _depth_at(frame, uv[ok]) > 0.0
            if (seen.reshape(2, -1).sum(axis=1) < 2).any():
                break  # no depth beside it on a side: nothing to judge by, or it lies
            share = self._see_through(
                frame, center, radius, top, normal, offset, e1, e2, (), heights
            )
            if share >= self.clear_share:
                raised = low + step
            elif low > raised:
                break  # two bands in a row: one may be a patch showing what is behind
        return raised

    def _clear_above(
        self,
        frame: RGBDFrame,
        det: Detection,
        center: Array,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
        skip: Sequence[_Standing],
    ) -> bool:
        """Whether a short, cup-wide object called other is the liquid in a clear vessel: its
        flat top is the liquid's surface, read as a lid, and above it the vessel's wall
        returns no depth over at least ``clear_share`` of its front (:meth:`_see_through`
        from 0.5 to 3.5 cm above the top; over a can the rays there meet what stands behind
        it, and return depth)."""
        if not (
            self.clear_min_radius <= det.radius <= self.bowl_min_radius
            and det.height < self.bottle_min_height - 0.035
        ):
            return False
        heights = det.height + np.linspace(0.005, 0.035, 8)
        share = self._see_through(
            frame, center, det.radius, det.height, normal, offset, e1, e2, skip, heights, True
        )
        return share >= self.clear_share

    def _see_through(
        self,
        frame: RGBDFrame,
        center: Array,
        radius: float,
        top: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
        skip: Sequence[_Standing] = (),
        heights: Array | None = None,
        skip_beyond: bool = False,
    ) -> float:
        """Share of the object's front surface where the depth camera returns nothing:
        sampled over the middle 60 % of its width and 15-85 % of its height (or at
        ``heights``, 8 of them); samples with
        something nearer in front (another object) do not count. Near 0 for an opaque
        object (speckle), about half for clear plastic on a D435 (52 % missing on ClearGrasp's
        real frames, 22-75 % per frame; the rest mostly shows what is behind). Missing depth
        alone, not depth behind the surface: a fitted cylinder wider than a round or tapered
        object (fruit, a bowl) sees the table behind its edges. Samples whose line of sight
        passes through one of ``skip`` (nearer objects: they do not see this one's surface;
        with ``skip_beyond``, clear ones anywhere on the line carried on past the sample) are
        left out. 0 with fewer than 12 samples to judge by."""
        to_cam = -center / max(math.hypot(*center), 1e-9)
        lateral = np.array([-to_cam[1], to_cam[0]])
        t = radius * _SEE_ACROSS
        hs = top * _SEE_UP if heights is None else heights
        uw = center + np.outer(np.sqrt(radius**2 - t**2), to_cam) + np.outer(t, lateral)
        base = uw[:, :1] * e1 + uw[:, 1:] * e2 - offset * normal
        p_cam = (base[None, :, :] + hs[:, None, None] * normal).reshape(-1, 3)
        uv, ok = _in_image(frame.intrinsics, p_cam)
        if skip:
            ok &= ~_seen_through(
                np.tile(uw, (len(hs), 1)), np.repeat(hs, len(uw)), offset, skip, skip_beyond
            )
        if ok.sum() < 12:
            return 0.0
        seen = _depth_at(frame, uv[ok])
        expected = p_cam[ok, 2]
        margin = np.maximum(0.015, 3.0 * depth_rms_error(expected))
        missing = seen <= 0.0
        judged = missing | (seen >= expected - margin)
        if judged.sum() < 12:
            return 0.0
        return float(missing[judged].mean())

    def _bottle_body(
        self,
        uw: Array,
        h: Array,
        top: float,
        sigma: float,
        circle: _Circle,
        fit: _Circle | None = None,
        fitted: bool = False,
    ) -> _Circle:
        """A bottle's wall circle: its body's, not its cap's or a sliver's.

        The circle through the whole cluster is the cap's and neck's where they return most
        of the depth (a clear bottle's wall returns little: on the cluttered bench an empty
        wine bottle's fit was 16 mm for 36). So the wall circle is fitted again to the body
        alone (below ``body_fit_fraction`` of the height, under the shoulder) and taken when
        it is at least 3 mm wider and at most 0.65 x the body points' spread across the view
        (the spread runs short of the diameter, its edges cut as depth edges: 53 mm for a
        70 mm bottle; a circle much wider than what is seen is a fit to noise). A
        radius still below ``bottle_min_radius`` is a cap or a sliver of a bottle partly
        hidden, not a body: it is widened toward ``bottle_prior_radius`` (:meth:`_widened`)
        and the centre moves away from the camera by the difference, keeping the seen front
        where it is (a narrow circle through the front has its centre too near the camera
        by as much).
        ``fit`` is the body's :meth:`_wall_circle` when ``fitted`` (None: too few points)."""
        center, radius = circle[0], circle[1]
        body = self._body_mask(h, top)
        if int(body.sum()) >= self.min_points:
            if not fitted:
                fit = self._wall_circle(uw[body], sigma)
            if fit is not None and self._radius_ok(fit[1]) and fit[1] > radius + 0.003:
                to_cam = -fit[0] / max(math.hypot(*fit[0]), 1e-9)
                across = uw[body] @ np.array([-to_cam[1], to_cam[0]])
                lo, hi = np.percentile(across, [2.0, 98.0])
                if fit[1] <= 0.65 * float(hi - lo):
                    return _on_all(uw, body, fit)
        center, radius = self._widened(center, radius, h, top)
        return center, radius, circle[2], circle[3]  # the score judges the fit to what was seen

    def _upper_circle(self, uw: Array, h: Array, top: float, sigma: float) -> _Circle | None:
        """The wall circle of the cluster's points above ``upper_fit_fraction`` of its height
        (residuals and wall over all its points), for a cluster at least ``bottle_min_height``
        tall; None if shorter, or if that circle is no bottle's either (a radius outside
        ``radius_range`` or above ``upper_max_radius``). ``top``: its :meth:`_top`."""
        upper = h >= self.upper_fit_fraction * top
        if top < self.bottle_min_height or int(upper.sum()) < self.min_points:
            return None
        fit = self._wall_circle(uw[upper], sigma)
        if fit is None or not self.radius_range[0] <= fit[1] <= self.upper_max_radius:
            return None
        return _on_all(uw, upper, fit)

    def _consensus_circle(self, uw: Array, sigma: float) -> _Circle | None:
        """The wall circle of the points most of the cluster agrees on, for a cluster whose
        own fit found no round wall: a mug whose handle faces the camera pulls the fit to a
        line. Circles through 3 points drawn at random (``consensus_draws``, a fixed seed:
        the same frame gives the same answer), at least ``clear_min_radius`` in radius (not a
        handle's own curve), the one with the most points within 3 sigma (at least 3 mm)
        kept if they are ``consensus_fraction`` of the cluster; then fitted again
        (:meth:`_wall_circle`) to those points alone, its radius in ``radius_range``."""
        if self.consensus_fraction >= 1.0 or len(uw) < self.min_points:
            return None
        agree = self._best_drawn_circle(uw, sigma, self.consensus_draws)
        if agree is None or agree.mean() < self.consensus_fraction:
            return None
        fit = self._wall_circle(uw[agree], sigma)
        if fit is None or not self._radius_ok(fit[1]):
            return None
        return _on_all(uw, agree, fit)

    def _best_drawn_circle(
        self, uw: Array, sigma: float, draws: int, facing: bool = False
    ) -> NDArray[np.bool_] | None:
        """Of ``draws`` circles through 3 points of ``uw`` drawn at random (seeded by the
        point count: the same frame gives the same answer), from ``clear_min_radius`` to the
        largest radius (and with ``facing``, their centre farther from the camera than the
        points: a wall's front, not a circle touching the fronts of two walls side by side),
        the points within 3 sigma (at least 3 mm) of the one that has the most (counted on
        at most ``max_fit_points`` of them, evenly strided); None when no circle was drawn.
        Hand-written RANSAC: OpenCV and scikit-image fit circles only to all the points
        given."""
        rng = np.random.default_rng(len(uw))
        picks = rng.integers(0, len(uw), size=(draws, 3))
        a, b, c = uw[picks[:, 0]], uw[picks[:, 1]], uw[picks[:, 2]]
        # Circumcentres: the perpendicular bisectors of ab and ac meet there.
        ab, ac = b - a, c - a
        det = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
        ok = np.abs(det) > 1e-12
        ab2, ac2 = (ab**2).sum(axis=1), (ac**2).sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ox = (ac[:, 1] * ab2 - ab[:, 1] * ac2) / det
            oy = (ab[:, 0] * ac2 - ac[:, 0] * ab2) / det
        radii = np.hypot(ox, oy)
        ok &= (radii >= self.clear_min_radius) & (radii <= self.radius_range[1])
        if facing:  # the camera stands over (0, 0)
            ok &= np.hypot(a[:, 0] + ox, a[:, 1] + oy) > np.hypot(*((a + b + c) / 3.0).T)
        if not ok.any():
            return None
        centers = a[ok] + np.column_stack([ox[ok], oy[ok]])
        band = max(3.0 * sigma, 0.003)
        some = np.ascontiguousarray(uw[:: max(1, len(uw) // self.max_fit_points)], dtype=float)
        best = int(np.argmax(_circle_inliers(some, centers, radii[ok], band)))
        return np.abs(_radial(uw, centers[best]) - radii[ok][best]) < band

    def _top(self, h: Array) -> float:
        """A cluster's height: its ``top_rank``-th highest point (above a few flying pixels)."""
        k = min(self.top_rank, len(h))
        return float(np.partition(h, len(h) - k)[len(h) - k])

    def _body_mask(self, h: Array, top: float) -> NDArray[np.bool_]:
        """Which points of a bottle of height ``top`` are its body's, for its circle."""
        return h < self.body_fit_fraction * top

    def _widened(self, center: Array, radius: float, h: Array, top: float) -> tuple[Array, float]:
        """A circle narrower than ``bottle_min_radius`` (m) widened toward
        ``bottle_prior_radius``: by the share (m - r) / (m / 2) of the difference, all of it
        from half of m down, so the radius changes continuously with the fit (pixel noise
        moves it by as little as it moves the fit). Its centre moves away from the camera
        (at the origin) by as much, so that its front stays; any other circle unchanged,
        and so is one of a cluster that does not reach down (its points' 5th height
        percentile above ``hidden_low_fraction`` of its ``top``): an upper part, a bottle's
        neck over a nearer object, whose narrow circle is about its axis."""
        if radius >= self.bottle_min_radius or percentile(h, 5.0) >= (
            self.hidden_low_fraction * top
        ):
            return center, radius
        share = min(1.0, 2.0 * (self.bottle_min_radius - radius) / self.bottle_min_radius)
        wider = radius + share * (self.bottle_prior_radius - radius)
        away = center / max(math.hypot(*center), 1e-9)
        return center + (wider - radius) * away, wider

    def _cap_over_gap(
        self,
        frame: RGBDFrame,
        uw: Array,
        h: Array,
        top: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> _Circle | None:
        """A clear bottle seen as its cap and neck over a body that returned no depth: the
        points above the widest gap in the height profile (at least ``bottle_gap``, and in
        the upper half) at least 10, 10-35 mm wide across the view, and in the gap,
        within 0.6 x ``bottle_prior_radius`` of their axis, the full-resolution depth
        returning under 5 % of what a surface there would (the strided, edge-filtered cloud
        also loses the middle of a thin sliver of a canister behind a nearer object: 14 %
        there, at most 2.4 % on clear bottles). Its circle is about their axis,
        ``bottle_prior_radius`` wide (None when not so)."""
        order = np.argsort(h)
        # The gap below the top: the few points above it (``top_rank``) are flying pixels
        # or pieces of a cap, not where the gap is.
        steps = np.diff(h[order][: int(np.searchsorted(h[order], top, side="right"))])
        if len(steps) == 0:
            return None
        k = int(np.argmax(steps))
        low, high = float(h[order[k]]), float(h[order[k + 1]])
        if high - low < self.bottle_gap or high < 0.5 * top:
            return None
        above = uw[order[k + 1 :]]
        if len(above) < 10:
            return None
        cap = self._flat_face(above, min_radius=0.005)
        if cap is None or cap[1] > 0.0175:
            return None
        center = cap[0]
        foot_cam = center[0] * e1 + center[1] * e2 - offset * normal
        low, high = low + 0.005, high - 0.005
        _, inside = self._near_axis(
            frame, foot_cam, normal, offset, self.bottle_prior_radius, low, high
        )
        # What a surface across the gap would return: the gap's rows x the band's columns.
        intr = frame.intrinsics
        ends = project(intr, foot_cam + np.outer([low, high], normal))
        band = 1.2 * self.bottle_prior_radius * intr.fx / float(foot_cam[2])
        if len(inside) > 0.05 * abs(float(ends[1, 1] - ends[0, 1])) * band:
            return None
        return center, self.bottle_prior_radius, np.zeros(len(uw)), np.ones(len(uw), dtype=bool)

    def _narrow_top(self, uw: Array, h: Array, top: float) -> bool:
        """Whether a tall cluster without a round wall (or whose wall fits a box's two
        straight faces) narrows to a bottle's cap: its top
        ``cap_band`` (at least 10 points) at least 1 cm and at most ``neck_ratio`` x as wide
        across the view (2nd to 98th percentile) as its body (below ``body_fit_fraction`` of
        its height, at least 20 points), the body no wider than 2 x ``upper_max_radius``.
        Real bottles are flat-sided as often as round (bleach, mustard, shampoo): a
        bleach bottle behind a mustard bottle on PoseCNN's YCB frame 4 showed a 86 mm body
        that fitted no circle under a 53 mm cap (0.62), and was other; a drill's top there is
        0.83 x as wide as its body, a box's or a canister's as wide. Wider bodies are
        clusters of objects standing together (a sports bottle against a canister on cluttered
        seed 223: a 146 mm body)."""
        mid = uw.mean(axis=0)
        lateral = np.array([-mid[1], mid[0]]) / max(math.hypot(*mid), 1e-9)
        across = uw @ lateral
        cap = across[h > top - self.cap_band]
        body = across[h < self.body_fit_fraction * top]
        if len(cap) < 10 or len(body) < 20:
            return False
        w_cap = float(np.percentile(cap, 98.0) - np.percentile(cap, 2.0))
        w_body = float(np.percentile(body, 98.0) - np.percentile(body, 2.0))
        return 0.01 <= w_cap <= self.neck_ratio * w_body and w_body <= 2.0 * self.upper_max_radius

    def _flat_face(self, uw: Array, min_radius: float | None = None) -> _Circle | None:
        """A cluster without a round wall as a footprint circle: its width across the view
        (2nd to 98th percentile along its principal axis) as the diameter, the centre half
        that width behind the middle of the seen face; None when wider than twice the
        largest radius or narrower than ``min_radius`` (the smallest radius by default).
        Residuals are zero and every point is "wall" (score from support)."""
        mid, axes, lo, hi = _principal_extent(uw)
        radius = 0.5 * float(hi[1] - lo[1])
        low = self.radius_range[0] if min_radius is None else min_radius
        if not low <= radius <= 2.0 * self.radius_range[1]:
            return None
        away = mid / max(math.hypot(*mid), 1e-9)
        center = mid + axes[:, 1] * 0.5 * float(hi[1] + lo[1]) + radius * away
        return center, radius, np.zeros(len(uw)), np.ones(len(uw), dtype=bool)

    def _wall_circle(self, uw: Array, sigma: float) -> _Circle | None:
        """Circle through the cluster's camera-facing wall in the table plane: (centre, radius,
        every point's residual, which points are the wall); None if the wall is too thin."""
        ok, cx, cy, radius, res, wall = _wall_circle_kernel(
            np.ascontiguousarray(uw, dtype=float),
            float(sigma),
            self.max_fit_points,
            self.fit_iterations,
            self.fit_tolerance,
        )
        return (np.array([cx, cy]), radius, res, wall) if ok else None

    def _wall_circles(self, uws: Sequence[Array], sigmas: Sequence[float]) -> list[_Circle | None]:
        """:meth:`_wall_circle` of several clusters (points ``uws``, depth noise ``sigmas``)."""
        return [self._wall_circle(uw, sigma) for uw, sigma in zip(uws, sigmas)]

    def _color_top(
        self,
        frame: RGBDFrame,
        foot_cam: Array,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
        radius: float,
        start: float,
        step: float = 0.004,
    ) -> float:
        """Height up to which the cylinder's silhouette differs in colour from its surroundings.

        Per height level: the image row of the back of the cylinder's cross-section (every
        lower cross-section covers that row over the full width while the body continues),
        the mean colour inside the silhouette on that row against the mean just left and
        right of it; levels count while the difference exceeds ``color_contrast`` grey levels
        (one missing level tolerated). Returns ``start`` when nothing continues above it.
        """
        intr = frame.intrinsics
        levels = start + step * np.arange(1, int((self.max_height - start) / step))
        if len(levels) == 0:
            return start
        angles = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        ring = radius * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
        p_cam = foot_cam + ring[None, :, :] + levels[:, None, None] * normal
        uv = project(intr, p_cam.reshape(-1, 3)).reshape(len(levels), len(angles), 2)
        if not np.isfinite(uv).all():
            return start
        u0, u1 = uv[..., 0].min(axis=1), uv[..., 0].max(axis=1)
        rows = np.rint(uv[..., 1].min(axis=1)).astype(int) + 2
        color, depth = frame.color, frame.depth
        top, misses = start, 0
        for h_level, row, a, b in zip(levels, rows, u0, u1):
            if not 0 <= row < intr.height:
                break
            line = color[row].astype(np.float32)
            c0, c1 = max(int(a) + 2, 0), min(int(b) - 1, intr.width)
            inside = line[c0:c1]
            # Through a clear wall one sees the table (or nothing); something standing behind
            # the silhouette would also differ in colour, so it ends the search.
            z_in = depth[row, c0:c1].astype(float)
            seen = z_in > 0.0
            if seen.any():
                cols = np.arange(c0, c1)[seen]
                p_in = deproject(intr, np.column_stack([cols, np.full(len(cols), row)]), z_in[seen])
                if np.mean(p_in @ normal + offset > self.min_height) > 0.3:
                    break
            outside = np.concatenate(
                [
                    line[max(int(a) - 8, 0) : max(int(a) - 2, 0)],
                    line[min(int(b) + 3, intr.width) : min(int(b) + 9, intr.width)],
                ]
            )
            if len(inside) < 3 or len(outside) < 3:
                break
            contrast = float(np.linalg.norm(inside.mean(axis=0) - outside.mean(axis=0)))
            if contrast > self.color_contrast:
                top, misses = float(h_level), 0
            else:
                misses += 1
                if misses > 1:
                    break
        return top

    def _classify(
        self,
        uw: Array,
        h: Array,
        center: Array,
        radius: float,
        top: float,
        res: Array | None = None,
        wall: NDArray[np.bool_] | None = None,
        *,
        rim: float | None = None,
    ) -> Label:
        """Bottle, cup or other from the cluster's shape (see the class docstring); ``rim``
        is :meth:`_rim`'s height when the caller has it (computed here otherwise)."""
        r = _radial(uw, center)
        neck = False
        upper = h > 0.75 * top
        if upper.sum() >= 5:
            neck = percentile(r[upper], 90.0) < self.neck_ratio * radius
        gap, capped = self._gap(r, h, radius)
        if rim is None:
            rim = self._rim(uw, h, center, radius, top)
        closed = self._closed_top(r, h, radius, rim)
        if top >= self.bottle_min_height and not neck and (not gap or (closed and not capped)):
            # Tall, no neck, no gap (or one under a wide, closed top: a lid over a band that
            # returned no depth, not a clear bottle's cap) and as wide at the top as the
            # body: a can stack or a canister, not a bottle (a bottle's top band is its cap,
            # 0.45-0.75 x the radius).
            band = h > top - self.top_band
            c, r_body = self._widened(center, radius, h, top)
            r_top = _radial(uw[band], c)
            # The same statistic below the band, 2 cm slice by slice, the median slice: a
            # circle fitted to a partly seen wall may be narrower than its points' spread
            # about it; the median leaves out a slice with a neighbour's points in it.
            r_all = _radial(uw, c)
            slices = np.minimum((h / 0.02).astype(np.intp), int(top / 0.02))
            below = h <= top - self.top_band
            per_slice = [
                percentile(r_all[below & (slices == k)], 75.0)
                for k in np.flatnonzero(np.bincount(slices[below]) >= 8)
            ]
            if per_slice:
                r_body = max(r_body, float(np.median(per_slice)))
            if percentile(r_top, 75.0) >= self.wide_top_ratio * r_body:
                return "other"
        if (
            top >= self.bottle_min_height
            and not (neck or capped or gap)
            and res is not None
            and wall is not None
            and self._straight_walls(uw[wall], res[wall], min_width=self.tall_face_min_width)
            and not self._narrow_top(uw, h, top)
        ):
            return "other"  # a tall box: two straight faces, nothing of a bottle above them
        if top >= self.bottle_min_height or neck or capped:
            return "bottle"
        if closed:
            return "other"  # a can, box or block: a flat closed top at rim height
        if radius > self.bowl_min_radius and top < self.bowl_height_ratio * 2.0 * radius:
            return "other"  # wide and short: a bowl
        if res is not None and wall is not None and self._straight_walls(uw[wall], res[wall]):
            return "other"  # a box's faces: two straight lines fit better than the circle
        return "cup"

    def _thin_top(
        self, near_heights: Array, top: float, reach: float = 0.04, step: float = 0.006
    ) -> float:
        """A bottle's top with what is too thin for the strided, edge-filtered cloud: a
        nozzle or a cap loop (a few millimetres, one or two pixels wide, all depth edge).
        Of ``near_heights``, the heights of the full-resolution points within 0.6 x the
        radius of the axis from ``top`` up (:meth:`_near_axis`), those above the top within
        ``reach``; the top climbs through them while no step exceeds ``step``; its third
        highest point is the new top if that is more than ``closed_top_tolerance`` higher,
        else the top is unchanged."""
        heights = near_heights[(near_heights > top) & (near_heights < top + reach)]
        heights = np.sort(heights)
        steps = np.diff(np.concatenate([[top], heights]))
        climb = int(np.argmax(steps > step)) if (steps > step).any() else len(heights)
        if climb < 3:
            return top
        # The third highest of the chain (noise makes single points), and only a real
        # structure: a few millimetres above the top the strided cloud saw.
        raised = float(heights[climb - 3])
        return raised if raised > top + self.closed_top_tolerance else top

    def _near_axis(
        self,
        frame: RGBDFrame,
        foot_cam: Array,
        normal: Array,
        offset: float,
        radius: float,
        low: float,
        high: float,
    ) -> tuple[Array, Array]:
        """The full-resolution points (camera frame, (N, 3)) and their heights (N,) within
        0.6 x ``radius`` of the axis standing at ``foot_cam`` and between ``low`` and
        ``high`` above the table, from the pixels of the window where that part of the axis
        projects (what is too thin or too sparse for the strided cloud)."""
        none = (np.zeros((0, 3)), np.zeros(0))
        intr = frame.intrinsics
        column = foot_cam + np.outer([low, high], normal)
        uv = project(intr, column)
        if not np.isfinite(uv).all():
            return none
        half = 0.6 * radius * intr.fx / max(float(column[:, 2].min()), 0.1)
        x0 = max(int(uv[:, 0].min() - half), 0)
        x1 = min(int(uv[:, 0].max() + half) + 1, intr.width)
        y0 = max(int(uv[:, 1].min()) - 2, 0)
        y1 = min(int(uv[:, 1].max()) + 3, intr.height)
        if x1 <= x0 or y1 <= y0:
            return none
        z = np.asarray(frame.depth[y0:y1, x0:x1], dtype=float)
        rows, cols = np.nonzero(z > 0.0)
        if len(rows) == 0:
            return none
        p = deproject(intr, np.column_stack([cols + x0, rows + y0]), z[rows, cols])
        h = p @ normal + offset
        off_axis = p - foot_cam - np.outer(h, normal)
        near = (np.linalg.norm(off_axis, axis=1) < 0.6 * radius) & (h > low) & (h < high)
        return p[near], h[near]

    def _cap_top(
        self,
        frame: RGBDFrame,
        foot_cam: Array,
        normal: Array,
        offset: float,
        radius: float,
        top: float,
        gap: float = 0.01,
        min_points: int = 10,
        spread: float = 0.03,
        near: tuple[Array, Array] | None = None,
    ) -> float:
        """A clear bottle's top where its neck returned no depth but its cap did: of the
        full-resolution pixels above ``top`` (up to ``max_height``) whose points lie within
        0.6 x the radius of the axis (and off the arm, by the frame's self-filter), grouped
        where their heights part by more than ``gap``, the highest group of at least
        ``min_points`` gives the top, its 95th-percentile height, when it is no taller than
        ``spread`` (a cap, not a surface). ``top`` unchanged otherwise. On cluttered seeds
        the cluster of a clear wine bottle ended 10-14 cm under its cap (centre 5-7 cm low).
        ``near``: :meth:`_near_axis`'s points from at most ``top`` up, when the caller has
        them."""
        if near is None:
            near = self._near_axis(frame, foot_cam, normal, offset, radius, top, self.max_height)
        above = near[1] > top + gap
        p, h = near[0][above], near[1][above]
        if len(h) < min_points:
            return top
        heights = np.sort(h[self._self_filter(p, *self._frame_pose)])
        groups = np.split(heights, np.flatnonzero(np.diff(heights) > gap) + 1)
        groups = [g for g in groups if len(g) >= min_points]
        if not groups or groups[-1][-1] - groups[-1][0] > spread:
            return top
        return float(np.percentile(groups[-1], 95.0))

    def _far_top_in_view(
        self,
        frame: RGBDFrame,
        center: Array,
        radius: float,
        top: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> bool:
        """Whether the far half of the object's top (its rim and what is inside it) is in
        the image and not hidden behind something nearer: at least half of 15 samples on
        it (0.3-0.9 x the radius past the axis) are in the image with no depth nearer than
        their own (missing depth does not hide: a metal lid may return none)."""
        away = center / max(math.hypot(*center), 1e-9)
        lateral = np.array([-away[1], away[0]])
        ring = [(a, b) for a in (0.3, 0.6, 0.9) for b in (-0.5, -0.25, 0.0, 0.25, 0.5)]
        uw = np.array([center + radius * (a * away + b * lateral) for a, b in ring])
        p_cam = uw[:, :1] * e1 + uw[:, 1:] * e2 + (top - offset) * normal
        uv, ok = _in_image(frame.intrinsics, p_cam)
        if ok.sum() < len(ring) // 2:
            return False
        seen = _depth_at(frame, uv[ok])
        margin = np.maximum(0.01, 3.0 * depth_rms_error(p_cam[ok, 2]))
        hidden = (seen > 0.0) & (seen < p_cam[ok, 2] - margin)
        return int((~hidden).sum()) >= len(ring) // 2

    def _top_disc(
        self,
        frame: RGBDFrame,
        center: Array,
        radius: float,
        rim: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> _TopDisc:
        """What the full-resolution depth shows across the top: of 21 samples (a 5 x 5
        grid's, within the disc) on the disc inside ``closed_top_inner`` x the radius at
        ``rim`` height, how many return depth (on, beyond, nearer, missing): within
        ``closed_top_tolerance`` (or 3 sigma) of that disc (a lid), beyond it (over the rim
        into an opening), nearer (something in front hides the top) or none (samples outside
        the image are in none). The strided cloud loses a top seen at a low angle: its depth
        changes fast across it, so it goes with the edges."""
        uw = center + self._disc_grid(radius)
        p_cam = uw[:, :1] * e1 + uw[:, 1:] * e2 + (rim - offset) * normal
        uv, ok = _in_image(frame.intrinsics, p_cam)
        if not ok.any():
            return _TopDisc(0, 0, 0, 0)
        seen = _depth_at(frame, uv[ok])
        expected = p_cam[ok, 2]
        margin = np.maximum(self.closed_top_tolerance, 3.0 * depth_rms_error(expected))
        on = (seen > 0.0) & (np.abs(seen - expected) <= margin)
        beyond = (seen > 0.0) & (seen > expected + margin)
        nearer = (seen > 0.0) & (seen < expected - margin)
        return _TopDisc(
            int(on.sum()), int(beyond.sum()), int(nearer.sum()), int((seen <= 0.0).sum())
        )

    def _disc_grid(self, radius: float) -> Array:
        """The 21 points of a 5 x 5 grid within ``closed_top_inner`` x ``radius`` of a top's
        centre (u, w offsets), where :meth:`_top_disc` looks."""
        a = np.linspace(-1.0, 1.0, 5) * self.closed_top_inner * radius
        return np.array([(x, y) for x in a for y in a if math.hypot(x, y) <= a[-1] + 1e-12])

    def _axis_below(
        self,
        frame: RGBDFrame,
        h: Array,
        center: Array,
        top: float,
        normal: Array,
        offset: float,
        e1: Array,
        e2: Array,
    ) -> Literal["hidden", "through"] | None:
        """What the camera sees on the axis below a cluster that is only an object's upper
        part (its lowest points, 5th percentile, above ``hidden_low_fraction`` of its top), at
        6 samples between a tenth of its top and its lowest points, all in the image:
        "hidden" when at least 60 % have depth ``hidden_margin`` or more nearer than the axis
        (a body seen would be at most its radius nearer; missing depth does not count), the
        body behind a nearer object; "through" when at least 3 have depth ``through_margin`` or
        more beyond it (what stands behind, or the table) and at most one is neither beyond
        nor hidden (missing depth counts as neither: it may be clear plastic in front), the
        body there but returning no depth; else None."""
        low = percentile(h, 5.0)
        if low < self.hidden_low_fraction * top:
            return None
        heights = np.linspace(0.1 * top, 0.9 * low, 6)
        foot = center[0] * e1 + center[1] * e2 - offset * normal
        p_cam = foot + heights[:, None] * normal
        uv, ok = _in_image(frame.intrinsics, p_cam)
        if not ok.all():
            return None
        seen = _depth_at(frame, uv)
        hidden = int(np.count_nonzero((seen > 0.0) & (seen < p_cam[:, 2] - self.hidden_margin)))
        if hidden >= 0.6 * len(seen):
            return "hidden"
        through = int(np.count_nonzero(seen > p_cam[:, 2] + self.through_margin))
        if through >= 3 and hidden + through >= 5:
            return "through"
        return None

    def _handle(self, uw: Array, h: Array, center: Array, radius: float, top: float) -> bool:
        """Whether the cluster carries a handle on its side: in one 30-degree bearing sector
        about the axis, at least ``handle_min_points`` points 10-35 mm outside the wall
        circle (the handle's upright: the simulated mugs' reach 20 mm out over 25-75 % of the
        height, like a real mug's) spanning a third of the height; every point outside the
        wall in that sector between 20 % and 85 % of the height (an object standing beside
        it reaches the table; a handle leaves a gap under and over it); and the 30-degree
        sectors either side holding almost nothing outside the wall (a fruit's or a box's
        bulge past the circle is wide). Cans, canisters, boxes, blocks and fruit have no
        handle: on cluttered seeds 0-399 and 700-999 none of them showed one."""
        r = _radial(uw, center) - radius
        out = r > 0.006
        r_out, h_out = r[out], h[out]
        upright = (r_out > 0.010) & (r_out < 0.035)
        if int(upright.sum()) < self.handle_min_points:
            return False  # most objects: nothing that far out
        bearing = np.arctan2(uw[out, 1] - center[1], uw[out, 0] - center[0])
        width = np.deg2rad(30.0)
        # The sectors, 15 degrees apart, that hold an upright point.
        step = np.deg2rad(15.0)
        cells = np.unique(np.floor(bearing[upright] / step).astype(int))
        for start in step * np.unique(np.concatenate([cells, cells - 1])):
            turned = np.mod(bearing - start, 2.0 * np.pi)
            sector = turned < width
            hs = h_out[sector & upright]
            if len(hs) < self.handle_min_points or hs.max() - hs.min() < top / 3.0:
                continue
            others = h_out[sector]
            beside = (turned >= 2.0 * np.pi - width) | ((turned >= width) & (turned < 2.0 * width))
            if others.min() >= 0.2 * top and others.max() <= 0.85 * top and int(beside.sum()) <= 2:
                return True
        return False

    def _rim(self, uw: Array, h: Array, center: Array, radius: float, top: float) -> float:
        """Height of the object's rim: the 99th percentile of its near wall (more than half
        the radius toward the camera), at most ``top``. The highest points overall may be
        a can's pull ring or the flying pixels along its far edge, a centimetre above the
        lid on a real D435 frame; the near wall ends where the lid or rim is."""
        to_cam = -center / max(math.hypot(*center), 1e-9)
        near = (uw - center) @ to_cam > 0.5 * radius
        if int(near.sum()) < 10:
            return top
        return min(top, percentile(h[near], 99.0))

    def _shows_inside(self, uw: Array, h: Array, center: Array, radius: float, rim: float) -> bool:
        """Whether the cluster shows the inside of an open vessel: at least
        ``closed_top_min_points`` points on the far half (beyond 0.2 x the radius past the
        axis, seen from the camera), at least a fifth of them more than
        ``closed_top_tolerance`` below ``rim`` (:meth:`_rim`'s height, computed once per
        cluster by the caller, which gives it to :meth:`_classify` too): the inner far wall
        under the rim, or the liquid (an empty cup of a cluttered scene showed 41 %). A
        can's or box's far half shows only its top, at rim height (1 % on PoseCNN's soup
        can)."""
        to_cam = -center / max(math.hypot(*center), 1e-9)
        far = (uw - center) @ to_cam < -0.2 * radius
        if int(far.sum()) < self.closed_top_min_points:
            return False
        below = h[far] < rim - self.closed_top_tolerance
        return int(below.sum()) >= self.closed_top_min_points and float(below.mean()) >= 0.2

    def _gap(self, r: Array, h: Array, radius: float) -> tuple[bool, bool]:
        """(gap, capped): whether the height profile has a gap of at least ``bottle_gap``
        with no points (a clear wall, between liquid and cap or liquid and rim), and whether
        what lies above the widest gap is narrow (90th percentile of its distance from the
        axis below ``gap_top_ratio`` x the radius): a cap, not the rim of a clear cup."""
        if len(h) < 2:
            return False, False
        order = np.argsort(h)
        steps = np.diff(h[order])
        k = int(np.argmax(steps))
        if float(steps[k]) < self.bottle_gap:
            return False, False
        above = r[order[k + 1 :]]
        return True, percentile(above, 90.0) < self.gap_top_ratio * radius

    def _closed_top(self, r: Array, h: Array, radius: float, top: float) -> bool:
        """Whether the points inside the rim (r < ``closed_top_inner`` x the radius, away
        from the wall) lie at rim height: a closed top. A cup shows its inside, below the rim
        (or nothing inside the rim at all: looking into it at a steep angle)."""
        inside = r < self.closed_top_inner * radius
        if int(inside.sum()) < self.closed_top_min_points:
            return False
        at_rim = np.abs(h[inside] - top) < self.closed_top_tolerance
        return float(at_rim.mean()) >= self.closed_top_fraction

    def _straight_walls(self, points: Array, res: Array, min_width: float = 0.0) -> bool:
        """Whether the camera-facing wall fits two straight lines (a box's corner, or one
        face) much better than the circle: RMS distance to the better of the best split into
        two lines below ``straight_wall_ratio`` x the circle's RMS residual, which must
        itself exceed ``straight_wall_min_rms`` (a round wall fits the circle to the noise),
        over at least ``min_width`` of width (a narrow arc is nearly straight)."""
        if len(points) < 20:
            return False
        circle_rms = float(np.sqrt(np.mean(res**2)))
        if circle_rms < self.straight_wall_min_rms:
            return False
        points = points[:: max(1, len(points) // self.max_fit_points)]
        q = points - points.mean(axis=0)
        _, vecs = np.linalg.eigh(q.T @ q)
        along = q @ vecs[:, 1]
        if float(along.max() - along.min()) < min_width:
            return False
        ordered = q[np.argsort(along)]
        n = len(ordered)
        # Every split's two line fits at once, from prefix sums of the moments.
        x, y = ordered[:, 0], ordered[:, 1]
        moments = np.column_stack([np.ones(n), x, y, x * x, x * y, y * y])
        prefix = np.vstack([np.zeros(6), np.cumsum(moments, axis=0)])
        k = np.arange(5, n - 5, max(1, n // 40))
        split = _moments_line_ss(prefix[k]) + _moments_line_ss(prefix[n] - prefix[k])
        best = min(_line_ss(ordered), float(split.min(initial=np.inf)))
        return math.sqrt(best / n) < self.straight_wall_ratio * circle_rms


def _fixes_circle(res: Array, wall: NDArray[np.bool_], sigma: float) -> bool:
    """Whether a wall fixes its circle: nine in ten of its points (``wall``, of the
    residuals ``res``) within 2.5 ``sigma`` of it (not a clear object's sparse front, nor a
    box's corner, which fits a circle to four in five)."""
    return bool(np.count_nonzero(np.abs(res[wall]) < 2.5 * sigma) >= 0.9 * int(wall.sum()))


def _on_all(uw: Array, subset: NDArray[np.bool_], fit: _Circle) -> _Circle:
    """A circle fitted to the points ``subset`` of a cluster (``uw``) as the whole
    cluster's: every point's residual, its wall those of the subset's wall."""
    wall = np.zeros(len(uw), dtype=bool)
    wall[np.flatnonzero(subset)[fit[3]]] = True
    return fit[0], fit[1], _radial(uw, fit[0]) - fit[1], wall


def _principal_extent(uw: Array) -> tuple[Array, Array, Array, Array]:
    """Points (N, 2) along their principal axes: their mean, the axes (columns, the major
    one last), and the 2nd and 98th percentiles of the points' coordinates along each
    (2,) (a few stray points do not widen it)."""
    mid = uw.mean(axis=0)
    q = uw - mid
    _, axes = np.linalg.eigh(q.T @ q)
    along = np.column_stack([q @ axes[:, 0], q @ axes[:, 1]])  # as each axis alone gives it
    return mid, axes, np.percentile(along, 2.0, axis=0), np.percentile(along, 98.0, axis=0)


def _boxes(uw: Array, clusters: Sequence[NDArray[np.intp]]) -> tuple[Array, Array]:
    """Every cluster's bounding box (lo, hi), (N, 2) each, all at once over their points laid
    end to end."""
    n = len(clusters)
    if n == 0:
        return np.empty((0, 2)), np.empty((0, 2))
    laid = uw[np.concatenate(clusters)]
    starts = np.cumsum([0] + [len(m) for m in clusters[:-1]])
    return np.minimum.reduceat(laid, starts), np.maximum.reduceat(laid, starts)


def _components(joins: NDArray[np.bool_]) -> NDArray[np.intp]:
    """Component index per node of the undirected graph ``joins`` (n x n; a frame's clusters,
    almost all of them alone): union-find over the few joined pairs. scipy's
    connected_components first builds a sparse matrix, which costs more than this here."""
    parent = list(range(len(joins)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in np.argwhere(joins & ~np.eye(len(joins), dtype=bool)):
        ri, rj = root(int(i)), root(int(j))
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    return np.array([root(i) for i in range(len(joins))], dtype=np.intp)


def _behind_front(points: Array, radius: float) -> Array:
    """Centre (u, w) of a cylinder of ``radius`` whose near side ``points`` (N, 2) are scattered
    over, seen from the camera at the origin: on the bearing half-way between the outermost
    points' bearings, 0.7 x the radius beyond their median range (a front arc's points lie
    0.64-0.79 x the radius in front of the centre: the mean of cos over it, uniform or
    foreshortened). Bearings and a median, not a circle fit: of what a D435 returns in front
    of clear plastic's background, over a third is centimetres off (ClearGrasp's real
    frames), while the pixels' columns are where the object is."""
    bearings = np.arctan2(points[:, 1], points[:, 0])
    bearing = 0.5 * float(bearings.min() + bearings.max())
    distance = float(np.median(np.hypot(points[:, 0], points[:, 1]))) + 0.7 * radius
    return distance * np.array([math.cos(bearing), math.sin(bearing)])


def _standing(center: Array, det: Detection, clear: bool) -> _Standing:
    """The cylinder a detection standing at ``center`` (u, w) blocks lines of sight with: its
    fitted one, 1 cm wider when it is clear (a fit to clear plastic's patches may be narrow)."""
    return _Standing(center, det.radius + (_CLEAR_MARGIN if clear else 0.0), det.height)


def _seen_through(
    uw: Array,
    h: Array,
    camera_height: float,
    cylinders: Sequence[_Standing],
    beyond: bool = False,
) -> NDArray[np.bool_]:
    """Whether the line of sight from the camera (over the table plane's origin,
    ``camera_height`` above it) to each point (``uw`` (N, 2) in the table plane, ``h`` (N,)
    above it) passes through one of ``cylinders`` before reaching the point (with ``beyond``,
    anywhere along it, carried on past the point until it meets the table). Along the sight
    line the height falls, so it passes through a cylinder when it meets the cylinder's
    circle and is below the cylinder's top where it leaves it (or at the point)."""
    if not cylinders:
        return np.zeros(len(uw), dtype=bool)
    return _seen_through_kernel(
        np.ascontiguousarray(uw, dtype=float),
        np.ascontiguousarray(h, dtype=float),
        float(camera_height),
        np.array([c.center for c in cylinders], dtype=float).reshape(-1, 2),
        np.array([[c.radius, c.height] for c in cylinders], dtype=float),
        bool(beyond),
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _seen_through_kernel(
    uw: Array, h: Array, camera_height: float, centers: Array, sizes: Array, beyond: bool
) -> NDArray[np.bool_]:
    """:func:`_seen_through`, compiled (a few numpy calls per cylinder and frame on a few
    dozen points each): ``centers`` (K, 2), ``sizes`` (K, 2) the radii and heights. The
    sight line to point p is t p, t from 0 (over the camera) to 1 (at p), at height
    camera_height + t (h - camera_height); it crosses a circle between t_mid -+ half."""
    hidden = np.zeros(len(uw), dtype=np.bool_)
    for i in range(len(uw)):
        u, w = uw[i, 0], uw[i, 1]
        d2 = max(u * u + w * w, 1e-12)
        rise = h[i] - camera_height
        for k in range(len(centers)):
            c0, c1, r, top = centers[k, 0], centers[k, 1], sizes[k, 0], sizes[k, 1]
            t_mid = (u * c0 + w * c1) / d2
            du, dw = u * t_mid - c0, w * t_mid - c1
            miss2 = du * du + dw * dw
            if not miss2 <= r * r:
                continue
            half = math.sqrt(max(r * r - miss2, 0.0) / d2)
            t_in, t_out = t_mid - half, t_mid + half
            if beyond:  # the sight line carried on past the point, until it meets the table
                ok = camera_height + t_in * rise > 0.0
            else:
                t_out = min(t_out, 1.0)
                ok = t_in < 1.0
            if ok and t_out > 0.0 and camera_height + t_out * rise <= top:
                hidden[i] = True
                break
    return hidden


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _wall_circle_kernel(
    uw: Array, sigma: float, max_fit_points: int, iterations: int, tolerance: float
) -> tuple[bool, float, float, float, Array, NDArray[np.bool_]]:
    """:meth:`GeometricDetector._wall_circle`, compiled (see :mod:`.fitting`): (found, cx,
    cy, radius, residuals, wall). A Kåsa start on at most ``max_fit_points`` of the points
    (a few hundred fix a circle to well under a millimetre), then twice: the wall is the
    points facing the camera (at (0, 0) in (u, w), seen from the start's centre) within
    max(4 sigma, 6 mm) of the circle, and the circle is fitted to at most
    ``max_fit_points`` of them (Huber scale 2 sigma). No circle with fewer than 10 wall
    points."""
    n = len(uw)
    cx, cy, r = kasa_kernel(uw, max(1, n // max_fit_points))
    norm = max(math.hypot(cx, cy), 1e-9)
    to_x, to_y = -cx / norm, -cy / norm
    band, scale = max(4.0 * sigma, 0.006), 2.0 * sigma
    res = np.empty(n)
    _circle_residuals(uw, cx, cy, r, res)
    wall = np.zeros(n, dtype=np.bool_)
    idx = np.empty(n, dtype=np.int64)
    for _ in range(2):
        count = 0
        for k in range(n):
            facing = (uw[k, 0] - cx) * to_x + (uw[k, 1] - cy) * to_y > 0.0
            wall[k] = facing and abs(res[k]) < band
            if wall[k]:
                idx[count] = k
                count += 1
        if count < 10:  # too thin a wall: no circle
            return False, cx, cy, r, res, wall
        fit_to = idx[: count : max(1, count // max_fit_points)]
        cx, cy, r = gauss_newton_circle(uw, fit_to, cx, cy, r, scale, iterations, tolerance)
        _circle_residuals(uw, cx, cy, r, res)
    return True, cx, cy, r, res, wall


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _circle_residuals(uw: Array, cx: float, cy: float, r: float, out: Array) -> None:
    """Each point's distance from the circle (cx, cy, r), into ``out``."""
    for k in range(len(uw)):
        dx, dy = uw[k, 0] - cx, uw[k, 1] - cy
        out[k] = math.sqrt(dx * dx + dy * dy) - r


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _circle_inliers(uw: Array, centers: Array, radii: Array, band: float) -> NDArray[np.int64]:
    """For each circle (``centers``, ``radii``), how many points lie within ``band`` of it."""
    counts = np.zeros(len(radii), dtype=np.int64)
    for j in range(len(radii)):
        cx, cy, r = centers[j, 0], centers[j, 1], radii[j]
        for k in range(len(uw)):
            dx, dy = uw[k, 0] - cx, uw[k, 1] - cy
            counts[j] += abs(math.sqrt(dx * dx + dy * dy) - r) < band
    return counts


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _depth_edges_kernel(
    grid: Array,
    idx: NDArray[np.int64],
    edge_jump: np.float32,
    subpixel: np.float32,
    focal_baseline: np.float32,
) -> NDArray[np.bool_]:
    """:meth:`GeometricDetector._depth_edges` of the flat indices ``idx`` of ``grid``:
    the 3x3 neighbourhood's depth range (pixels without depth count as 1 km for its near end,
    as 0 for its far end; the image border adds nothing) above max(``edge_jump``, 5 x
    :func:`depth_rms_error`), in float32 as the depth camera's values (and in numpy's order
    of operations); compiled, so only the pixels asked about are looked at (cv2's erode and
    dilate went over the whole grid)."""
    rows, cols = grid.shape
    out = np.empty(len(idx), dtype=np.bool_)
    for n in range(len(idx)):
        r, c = idx[n] // cols, idx[n] % cols
        near, far = np.float32(np.inf), np.float32(-np.inf)
        for rr in range(max(r - 1, 0), min(r + 2, rows)):
            for cc in range(max(c - 1, 0), min(c + 2, cols)):
                g = np.float32(grid[rr, cc])
                near = min(near, g if g > 0 else np.float32(1e3))
                far = max(far, g)
        at = np.float32(grid[r, c])
        limit = max(edge_jump, np.float32(5.0) * ((at * at) * subpixel / focal_baseline))
        out[n] = at > 0 and far - near > limit
    return out


def _radial(uw: Array, center: Array) -> Array:
    """Distance of every point of ``uw`` (N, 2) from ``center``: ``np.hypot`` on the two
    columns, a third of ``np.linalg.norm(uw - center, axis=1)``'s time."""
    return np.hypot(uw[:, 0] - center[0], uw[:, 1] - center[1])


def _in_image(intr: Intrinsics, p_cam: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Camera-frame points' nearest pixels (N, 2) and which of them fall inside the image
    (points behind the camera project to NaN and do not)."""
    uv = np.rint(project(intr, p_cam))
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
    return uv, ok


def _depth_at(frame: RGBDFrame, uv: Array) -> Array:
    """The frame's depth (m, 0 = none) at pixels ``uv`` (N, 2) inside the image."""
    depth = np.asarray(frame.depth)
    return depth[uv[:, 1].astype(int), uv[:, 0].astype(int)].astype(np.float64)


def _moments_line_ss(m: Array) -> Array:
    """:func:`_line_ss` of point sets given by their moments (K, 6): count, sum x, sum y,
    sum x^2, sum xy, sum y^2 (of points near the origin, for precision): the smaller
    eigenvalue of each set's 2x2 scatter matrix, in closed form."""
    n, sx, sy, sxx, sxy, syy = m.T
    cxx, cxy, cyy = sxx - sx * sx / n, sxy - sx * sy / n, syy - sy * sy / n
    return np.maximum(0.5 * (cxx + cyy) - np.hypot(0.5 * (cxx - cyy), cxy), 0.0)


def _line_ss(points: Array) -> float:
    """Sum of squared distances of 2-D points to their best-fitting line."""
    if len(points) < 3:
        return 0.0
    q = points - points.mean(axis=0)
    return float(np.linalg.eigvalsh(q.T @ q)[0])


def _pose(T_base_cam: ArrayLike | None) -> Array | None:
    """The context's camera pose as a 4x4 float array (None stays None)."""
    if T_base_cam is None:
        return None
    T = np.asarray(T_base_cam, dtype=float)
    if T.shape != (4, 4):
        raise PerceptionError(
            f"FrameContext.T_base_cam must be the 4x4 camera pose in the base frame, not an "
            f"array of shape {T.shape}; pass None when the pose is not known"
        )
    return T
