"""The bottle and cup record every object detector returns, the protocol they share and what
they are told about each frame besides its pixels.

Four detectors implement :class:`ObjectDetector`:
:class:`~armvision.perception.geometric.GeometricDetector` (depth alone, no weights),
:class:`~armvision.perception.learned.OnnxDetector` (an ONNX model through ONNX Runtime),
:class:`~armvision.perception.jetson.JetsonDetector` (jetson-inference's ``detectNet``) and
:class:`~armvision.perception.hybrid.HybridDetector` (a network's labels, the geometric fit's
3-D); :func:`~armvision.perception.factory.object_detector` builds the one the configuration
chooses. Each is called as
``detector.detect(frame, FrameContext(T_base_cam=..., joint_positions=...))``; the learned
detectors ignore the context.

Frames: ``cam`` is the colour optical frame (x right, y down, z forward); ``base`` the robot's
base_link; ``T_base_cam`` the camera pose (the calibration).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame, deproject, project, project_xyz
from armvision.geometry import cross3

Array = NDArray[np.float64]
#: What a detection is: a bottle, a cup, or (:class:`~armvision.perception.hybrid.HybridDetector`
#: only) ``"other"``, an object the geometric fit found but the network did not name. The
#: runtime and the tasks act on bottles and cups only; other tracks are obstacles.
Label = Literal["bottle", "cup", "other"]
#: The classes a detector looks for (a network's class map names these).
LABELS: tuple[Label, ...] = ("bottle", "cup")

#: Prior share of a bottle's height taken by its body (below the shoulder); the simulated
#: bottles' value. Measure your own bottles and pass it to the detector and the liquid meter.
BOTTLE_BODY_FRACTION = 0.72
#: The bottle model (the liquid meter's, and a network's bottle box placed on the table): a
#: cylinder of the bottle's radius from the foot up to the body fraction of its height, then
#: a neck and cap this fraction of the radius wide at the top.
CAP_RADIUS_FRACTION = 0.47


@dataclass(frozen=True, eq=False)
class Detection:
    """One bottle or cup.

    ``box`` (x0, y0, x1, y1) pixels, inclusive-exclusive like a slice; ``center_cam`` (3,)
    metres, the container's centre (on its axis, half-way up) in the camera frame; ``size``
    (3,) metres, (diameter, height, diameter) of the fitted cylinder; ``radius`` and
    ``height`` the same in metres. ``score`` in [0, 1]: the network's confidence for the
    learned detectors, the fit quality for the geometric detector (see its docstring).
    ``axis_cam`` (3,) is the container's up axis in the camera frame when it is known (the
    table normal for the geometric detector), else None.
    """

    label: Label
    score: float
    box: tuple[float, float, float, float]
    center_cam: Array
    size: Array
    radius: float
    height: float
    axis_cam: Array | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict."""
        return {
            "label": self.label,
            "score": float(self.score),
            "box": [float(v) for v in self.box],
            "center_cam": [float(v) for v in self.center_cam],
            "size": [float(v) for v in self.size],
            "radius": float(self.radius),
            "height": float(self.height),
            "axis_cam": None if self.axis_cam is None else [float(v) for v in self.axis_cam],
        }


@dataclass(frozen=True, eq=False)
class FrameContext:
    """What a detector is told about the moment a frame was taken, besides its pixels.

    ``T_base_cam`` (4, 4): the camera's pose in the arm's base frame (the runtime's current
    estimate), None if unknown; ``joint_positions`` (rad): the arm's joints at capture, for
    the self-mask, None for no self-mask of the moving links; ``table_plane``: the table
    in the camera frame as (unit normal toward the camera, offset), ``normal . p + offset =
    0``, when a detector has found it in this frame (the hybrid's geometric detector tells
    the network's placement, :func:`box_on_table`), else None.
    """

    T_base_cam: Array | None = None
    joint_positions: Array | None = None
    table_plane: tuple[Array, float] | None = None


#: The context of a frame about which nothing is known (the detectors' default).
NO_CONTEXT = FrameContext()


@runtime_checkable
class ObjectDetector(Protocol):
    """Anything that finds bottles and cups in an RGB-D frame."""

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]: ...


# --------------------------------------------------------------------------- 3-D from a box


def plane_basis(up: ArrayLike) -> tuple[Array, Array]:
    """Two unit vectors (e1, e2) that span the plane normal to the unit vector ``up`` (e1
    normal to the x axis too, or to the y axis when ``up`` is the x axis)."""
    up = np.asarray(up, dtype=float)
    e1 = cross3(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = cross3(up, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, cross3(up, e1)


def outline_rings(body_fraction: float) -> tuple[Array, Array]:
    """The bottle model's three rings (foot, shoulder, top): their heights as shares of the
    bottle's height and their radii as shares of its radius (the cap
    :data:`CAP_RADIUS_FRACTION` as wide as the body)."""
    return np.array([0.0, body_fraction, 1.0]), np.array([1.0, 1.0, CAP_RADIUS_FRACTION])


#: 24 directions around a cylinder's rim (cos, sin columns) for :func:`cylinder_box`.
_RING_COS, _RING_SIN = (
    f(np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False))[:, None] for f in (np.cos, np.sin)
)


def cylinder_box(
    intr: Intrinsics, center_cam: Array, axis_cam: Array, radius: float, height: float
) -> tuple[float, float, float, float]:
    """Pixel box (x0, y0, x1, y1) of a vertical cylinder: its rims' projection, clipped."""
    return _image_box(intr, _cylinder_rims(center_cam, axis_cam, radius, height))


def _cylinder_rims(center_cam: Array, axis_cam: Array, radius: float, height: float) -> Array:
    """Points (48, 3) around a cylinder's bottom and top rims, camera frame."""
    e1, e2 = plane_basis(axis_cam)
    ring = radius * (_RING_COS * e1 + _RING_SIN * e2)
    return np.concatenate(
        [center_cam + ring - 0.5 * height * axis_cam, center_cam + ring + 0.5 * height * axis_cam]
    )


def _image_box(intr: Intrinsics, points_cam: Array) -> tuple[float, float, float, float]:
    """Pixel box of the camera-frame points in front of the camera, clipped to the image;
    all zeros when none is."""
    uv = project(intr, points_cam[points_cam[:, 2] > 1e-3])
    if len(uv) == 0:
        return (0.0, 0.0, 0.0, 0.0)
    # pixel_box, clipped: on scalars, at a fraction of np.clip's call on a 4-vector.
    w, h = float(intr.width), float(intr.height)
    lo, hi = uv.min(axis=0).tolist(), uv.max(axis=0).tolist()
    return (
        min(max(lo[0], 0.0), w),
        min(max(lo[1], 0.0), h),
        min(max(hi[0] + 1.0, 0.0), w),
        min(max(hi[1] + 1.0, 0.0), h),
    )


def fit_model_box(
    intr: Intrinsics,
    box: ArrayLike,
    foot: Array,
    up: Array,
    e1: Array,
    e2: Array,
    ring: Array,
    rings: tuple[Array, Array],
    p: Array,
    free: tuple[bool, bool, bool, bool] = (True, True, True, True),
    steps: int = 8,
) -> tuple[Array, float]:
    """The parameters (a, b, radius, height) of an upright container standing at
    ``foot + a e1 + b e2`` on the table (``up`` its normal, ``e1``, ``e2`` spanning it) whose
    projected box (min u, min v, max u + 1, max v + 1, unclipped) matches ``box``, and the
    largest difference left (pixels). The container is ``rings``' rings (heights and radii as
    shares of its height and radius, :func:`outline_rings`) of the unit ``ring`` (points
    (K, 3) in the table plane). Gauss-Newton from ``p`` on the ``free`` parameters, at most
    ``steps`` steps each clipped to +-0.05, with central differences (the projected box is
    piecewise smooth in them); written here because it is four parameters and four
    residuals, where a solver's setup would cost more than the fit. Shared by
    :func:`box_on_table` and the liquid meter's box fit."""
    target = np.asarray(box, dtype=float)
    p = np.array(p, dtype=float)
    # The rings' points, with the coordinate first: (xyz, M, ring, point).
    frac, scale = (a[:, None] for a in rings)
    foot3, e1_3, e2_3, up3 = (a[:, None, None, None] for a in (foot, e1, e2, up))
    ring3 = ring.T[:, None, None, :]

    def bboxes(params: Array) -> Array:
        """Projected boxes (M, 4) of M parameter sets (M, 4) in one projection, as
        :func:`~armvision.camera.frames.pixel_box` bounds them."""
        a, b, r, h = params.T[:, :, None, None]
        centre = foot3 + a * e1_3 + b * e2_3
        x, y, z = centre + (frac * h) * up3 + (scale * r) * ring3
        uv = np.stack(project_xyz(intr, x, y, z), axis=1).reshape(len(params), 2, -1)
        return np.concatenate([uv.min(2), uv.max(2) + 1], axis=1)

    eps = 1e-4
    idx = np.flatnonzero(free)
    # The box at p and at p +- eps along each free parameter: central differences.
    trial = np.zeros((1 + 2 * len(idx), 4))
    trial[1 + np.arange(len(idx)), idx] = eps
    trial[1 + len(idx) + np.arange(len(idx)), idx] = -eps
    converged = False
    for iteration in range(steps + 1):  # the last box is the final p's
        boxes = bboxes(p + trial)
        res = boxes[0] - target
        if converged or iteration == steps:
            break
        if len(idx) == 1:  # one parameter (a detector's radius): lstsq in closed form
            j = (boxes[1] - boxes[2]) / (2 * eps)
            jj = float(j @ j)
            step = -float(j @ res) / jj if jj > 0.0 else 0.0
            p[idx[0]] += min(max(step, -0.05), 0.05)
            converged = abs(step) < 1e-5
        else:
            J = (boxes[1 : 1 + len(idx)] - boxes[1 + len(idx) :]).T / (2 * eps)
            delta = np.linalg.lstsq(J, -res, rcond=None)[0]
            p[idx] += np.minimum(np.maximum(delta, -0.05), 0.05)  # np.clip, faster
            converged = bool(np.max(np.abs(delta)) < 1e-5)
        p[2], p[3] = max(p[2], 0.005), max(p[3], 0.02)
    return p, float(np.max(np.abs(res)))


def box_on_table(
    intr: Intrinsics,
    box: tuple[float, float, float, float],
    normal: Array,
    offset: float,
    label: Label = "cup",
    depth: NDArray[np.floating] | None = None,
    radius_range: tuple[float, float] = (0.015, 0.07),
    occluder_m: float = 0.03,
) -> tuple[Array, float, float] | None:
    """(center_cam, radius, height) of the upright container standing on the table
    (``normal . p + offset = 0``, the normal toward the camera) whose projected box is
    ``box``: a cylinder, or for a bottle the bottle model (its body to
    :data:`BOTTLE_BODY_FRACTION` of the height, a cap :data:`CAP_RADIUS_FRACTION` as wide at
    the top). From the pixels alone, so a clear container that returned no depth in its
    box is placed as well as an opaque one. A first guess from the box's bottom-centre
    ray on the table, its width at that range and its top row over the axis, then
    :func:`fit_model_box` on the foot (two coordinates on the table), radius and height.
    None when the box's bottom row does not meet the table in front of the camera, a
    box edge is on the image border (the container continues outside it: its box is not
    its silhouette), its foot is hidden (with ``depth``: most of the pixels just under the
    box's middle that return depth return it ``occluder_m`` or more nearer than the table
    there: a nearer object, whose top edge is the box's bottom), or the fit leaves the
    radius outside ``radius_range``."""
    x0, y0, x1, y1 = (float(v) for v in box)
    if x0 <= 1.0 or y0 <= 1.0 or x1 >= intr.width - 1.0 or y1 >= intr.height - 1.0:
        return None
    n = np.asarray(normal, dtype=float)
    ray = deproject(intr, [[0.5 * (x0 + x1 - 1.0), y1 - 0.5]], [1.0])[0]
    along = float(n @ ray)
    if along >= -1e-6:
        return None  # the bottom row looks above the horizon of the table
    front = ray * (-offset / along)
    if front[2] <= 0.0:
        return None
    if depth is not None:
        row = min(int(y1) + 2, intr.height - 1)
        cols = np.arange(int(x0 + 0.2 * (x1 - x0)), int(np.ceil(x1 - 0.2 * (x1 - x0))) + 1)
        seen = np.asarray(depth[row, cols], dtype=float)
        rays = deproject(intr, np.column_stack([cols, np.full(len(cols), row)]), np.ones(len(cols)))
        down = rays @ n
        table_z = np.where(down < -1e-6, -offset / np.minimum(down, -1e-6), np.inf) * rays[:, 2]
        valid = seen > 0.0
        if valid.any() and np.mean(seen[valid] < table_z[valid] - occluder_m) > 0.5:
            return None
    e1, e2 = plane_basis(n)
    away = front - (front @ n) * n
    away /= np.linalg.norm(away)
    radius = 0.5 * (x1 - x0) * float(front[2]) / intr.fx
    foot = front + radius * away
    top_ray = deproject(intr, [[0.5 * (x0 + x1 - 1.0), y0 + 0.5]], [1.0])[0]
    # The top row's ray at the axis' distance along the view: its height above the table.
    t = float(foot @ away) / max(float(top_ray @ away), 1e-9)
    height = max(float(n @ (t * top_ray)) + offset, 0.02)
    # The rings' heights and radii as shares of the container's: a cylinder's two rims, or
    # the bottle model's foot, shoulder and cap.
    if label == "bottle":
        rings = outline_rings(BOTTLE_BODY_FRACTION)
    else:
        rings = (np.array([0.0, 1.0]), np.ones(2))
    ring = _RING_COS * e1 + _RING_SIN * e2
    p, _ = fit_model_box(
        intr, box, foot, n, e1, e2, ring, rings, np.array([0.0, 0.0, radius, height]), steps=10
    )
    a, b, r, h = (float(v) for v in p)
    if not radius_range[0] <= r <= radius_range[1]:
        return None
    return foot + a * e1 + b * e2 + 0.5 * h * n, r, h


def box_center_3d(
    intr: Intrinsics,
    depth: NDArray[np.floating],
    box: tuple[float, float, float, float],
    center_fraction: float = 0.3,
    depth_percentile: float = 25.0,
    min_pixels: int = 8,
) -> tuple[Array, float, float] | None:
    """(center_cam, radius, height) of a container from its pixel box and the depth image.

    The depth of the container's front surface is the ``depth_percentile`` of the valid depth
    in the central ``center_fraction`` of the box (a low percentile rather than the median
    because through a clear bottle above its liquid the camera sees the table behind it).
    The size follows from the box at that depth (diameter = width z / fx, height =
    box height z / fy, an upright container roughly facing the camera), and the centre is the
    deprojected box centre pushed one radius further along its ray, from the front surface to
    the axis. None when fewer than ``min_pixels`` depth pixels are valid.
    """
    x0, y0, x1, y1 = box
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half_w = 0.5 * center_fraction * (x1 - x0)
    half_h = 0.5 * center_fraction * (y1 - y0)
    r0 = int(np.clip(np.floor(cy - half_h), 0, intr.height - 1))
    r1 = int(np.clip(np.ceil(cy + half_h) + 1, r0 + 1, intr.height))
    c0 = int(np.clip(np.floor(cx - half_w), 0, intr.width - 1))
    c1 = int(np.clip(np.ceil(cx + half_w) + 1, c0 + 1, intr.width))
    patch = np.asarray(depth[r0:r1, c0:c1], dtype=float)
    valid = patch[patch > 0.0]
    if len(valid) < min_pixels:
        return None
    z_front = float(np.percentile(valid, depth_percentile))
    radius = 0.5 * (x1 - x0) * z_front / intr.fx
    height = (y1 - y0) * z_front / intr.fy
    p_front = deproject(intr, [[cx, cy]], [z_front])[0]
    center_cam = p_front + radius * p_front / np.linalg.norm(p_front)
    return center_cam, float(radius), float(height)


def detections_from_boxes(
    frame: RGBDFrame,
    boxes: Array,
    scores: Array,
    labels: Sequence[Label],
    center_fraction: float,
    depth_percentile: float,
    table_plane: tuple[Array, float] | None = None,
) -> list[Detection]:
    """Detections for pixel boxes (N, 4) x0, y0, x1, y1. With the ``table_plane`` each is
    the container of its label standing on it whose box it is (:func:`box_on_table`),
    whatever the depth in it, its axis the plane's normal; otherwise, or where that fit
    fails, from the depth in the box (:func:`box_center_3d`, no axis), and boxes without
    depth are dropped."""
    intr = frame.intrinsics
    out = []
    for box, score, label in zip(boxes, scores, labels):
        x0, y0, x1, y1 = (float(v) for v in box)
        x0, x1 = float(np.clip(x0, 0, intr.width)), float(np.clip(x1, 0, intr.width))
        y0, y1 = float(np.clip(y0, 0, intr.height)), float(np.clip(y1, 0, intr.height))
        if x1 - x0 < 1.0 or y1 - y0 < 1.0:
            continue
        located, axis = None, None
        if table_plane is not None:
            located = box_on_table(intr, (x0, y0, x1, y1), *table_plane, label, frame.depth)
            axis = np.asarray(table_plane[0], dtype=float)
        if located is None:
            axis = None
            located = box_center_3d(
                intr, frame.depth, (x0, y0, x1, y1), center_fraction, depth_percentile
            )
        if located is None:
            continue
        center_cam, radius, height = located
        out.append(
            Detection(
                label=label,
                score=float(score),
                box=(x0, y0, x1, y1),
                center_cam=center_cam,
                size=np.array([2.0 * radius, height, 2.0 * radius]),
                radius=radius,
                height=height,
                axis_cam=axis,
            )
        )
    return out
