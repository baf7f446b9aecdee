"""Bottle and cup detection: where each container stands, how big it is, in the camera frame.

Three detectors share one record, :class:`Detection`, and one protocol, :class:`Detector`:

- :class:`GeometricDetector` (the default, no learned weights): the table is the dominant plane
  of the depth point cloud (RANSAC), the robot's own points are removed (capsules around its
  links, placed by forward kinematics when the camera pose and joint angles are known), what
  stands on the table is clustered in the table plane, and a vertical cylinder is fitted to
  each cluster: a circle through the *camera-facing wall* in the table plane (only that half is
  seen, so a centroid would sit too near the camera) and the height from the highest points.
  Bottle or cup follows from the shape: height, a narrow top (neck and cap) and a gap of no
  depth between liquid and cap (a clear bottle's wall returns no depth, only its liquid and
  cap do).
- :class:`OnnxDetector`: an SSD-MobileNet or YOLOv8 ONNX export through ONNX Runtime; the 3-D
  centre is a robust depth statistic over the centre of each box.
- :class:`JetsonDetector`: jetson-inference's ``detectNet`` on a Jetson, same 3-D centre.

Frames: ``cam`` is the colour optical frame (x right, y down, z forward); ``base`` the robot's
base_link; ``T_base_cam`` the camera pose (the calibration). Table-plane coordinates used inside
the geometric detector are (u, w, h): two in-plane axes and the height above the table.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import (
    Intrinsics,
    RGBDFrame,
    deproject,
    deproject_image,
    depth_rms_error,
    project,
)
from armvision.errors import PerceptionError
from armvision.geometry import inv_T, transform_points
from armvision.robot.kinematics import VX300S, ArmModel, fk

Array = NDArray[np.float64]
Label = Literal["bottle", "cup"]
LABELS: tuple[Label, ...] = ("bottle", "cup")


# --------------------------------------------------------------------------- the record


#: Prior share of a bottle's height taken by its body (below the shoulder); the simulated
#: bottles' value. Measure your own bottles and pass it to the detector and the liquid meter.
BOTTLE_BODY_FRACTION = 0.72


@dataclass(frozen=True, eq=False)
class Detection:
    """One bottle or cup.

    ``box`` (x0, y0, x1, y1) pixels, inclusive-exclusive like a slice; ``center_cam`` (3,)
    metres, the container's centre (on its axis, half-way up) in the camera frame; ``size``
    (3,) metres, (diameter, height, diameter) of the fitted cylinder; ``radius`` and
    ``height`` the same in metres. ``score`` in [0, 1]: the network's confidence for the
    learned detectors, the fit quality for :class:`GeometricDetector` (see its docstring).
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


@runtime_checkable
class Detector(Protocol):
    """Anything that finds bottles and cups in an RGB-D frame."""

    def detect(self, frame: RGBDFrame) -> list[Detection]: ...


# --------------------------------------------------------------------------- small pure helpers


@functools.lru_cache(maxsize=8)
def _unit_depth_rays(intr: Intrinsics, stride: int) -> tuple[Array, NDArray[np.intp]]:
    """Camera-frame points at depth 1 m (z = 1) of every ``stride``-th pixel of every
    ``stride``-th row, (N, 3), and those pixels' flat indices (N,); cached per intrinsics."""
    rays = deproject_image(intr, np.ones((intr.height, intr.width)))
    rows, cols = np.mgrid[0 : intr.height : stride, 0 : intr.width : stride]
    flat = (rows * intr.width + cols).ravel()
    rays = rays[flat]
    rays.flags.writeable = False
    flat.flags.writeable = False
    return rays, flat


def fit_plane_ransac(
    p: Array,
    tolerance: float,
    iterations: int,
    rng: np.random.Generator,
    normal_prior: Array | None = None,
    max_tilt_rad: float = math.radians(15.0),
) -> tuple[Array, float, NDArray[np.bool_]]:
    """Plane n.p + d = 0 with the most points of ``p`` (N, 3) within ``tolerance``; (n, d, inliers).

    All ``iterations`` three-point hypotheses are scored in one (N x iterations) array
    operation, then the best is refined by least squares (the normal is the smallest singular
    vector of the centred inliers). With ``normal_prior`` only hypotheses within
    ``max_tilt_rad`` of it count. ``n`` has unit length and ``d`` >= 0 (the origin, the camera,
    is on the positive side). Written here because neither OpenCV's Python API nor SciPy has a
    plane RANSAC, and Open3D would be a large dependency for twenty lines.
    """
    n_points = len(p)
    if n_points < 3:
        raise PerceptionError("too few depth points to find the table plane")
    idx = rng.integers(0, n_points, size=(iterations, 3))
    a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-9
    normals[ok] /= lengths[ok, None]
    if normal_prior is not None:
        ok &= np.abs(normals @ normal_prior) > math.cos(max_tilt_rad)
    d = -np.einsum("ij,ij->i", normals, a)
    counts = (np.abs(p @ normals.T + d) < tolerance).sum(axis=0)
    counts[~ok] = -1
    best = int(np.argmax(counts))
    if counts[best] < 3:
        raise PerceptionError(
            "no table plane in the depth image: is the table in view and within the depth range?"
        )
    inliers = np.abs(p @ normals[best] + d[best]) < tolerance
    centroid = p[inliers].mean(axis=0)
    normal = np.linalg.svd(p[inliers] - centroid, full_matrices=False)[2][2]
    offset = -float(normal @ centroid)
    if offset < 0.0:
        normal, offset = -normal, -offset
    inliers = np.abs(p @ normal + offset) < tolerance
    return normal, offset, inliers


def fit_circle_kasa(xy: Array) -> tuple[Array, float]:
    """Algebraic (Kåsa) circle fit: least squares of 2 a x + 2 b y + c = x^2 + y^2.

    Centre (a, b), radius sqrt(c + a^2 + b^2). Exact for points on a circle, biased toward
    small radii on a short noisy arc, so use it to start :func:`fit_circle_geometric`.
    """
    A = np.column_stack([2.0 * xy, np.ones(len(xy))])
    rhs = np.einsum("ij,ij->i", xy, xy)
    (a, b, c), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    return np.array([a, b]), float(math.sqrt(max(c + a * a + b * b, 0.0)))


def fit_circle_geometric(
    xy: Array, center: Array, radius: float, scale: float, iterations: int = 15
) -> tuple[Array, float, Array]:
    """Geometric circle fit (residual |p - c| - r) by Gauss-Newton with Huber weights (IRLS).

    Points with |residual| > ``scale`` get weight scale / |residual|, so stray points pull
    linearly, not quadratically. Returns (centre, radius, residuals). A few numpy lines per
    iteration instead of scipy.optimize.least_squares, whose per-call overhead (~2 ms) is
    a large part of a 33 ms frame budget when a scene holds four objects.
    """
    c = np.asarray(center, dtype=float).copy()
    r = float(radius)
    for _ in range(iterations):
        diff = xy - c
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        res = dist - r
        w = np.minimum(1.0, scale / np.maximum(np.abs(res), 1e-12))
        J = np.empty((len(xy), 3))
        J[:, :2] = -diff / dist[:, None]
        J[:, 2] = -1.0
        JW = J * w[:, None]
        try:
            step = np.linalg.solve(JW.T @ J, -(JW.T @ res))
        except np.linalg.LinAlgError:  # all points in one spot: keep the start
            break
        c += step[:2]
        r += float(step[2])
        if np.abs(step).max() < 1e-6:
            break
    res = np.linalg.norm(xy - c, axis=1) - r
    return c, r, res


def segment_distances(p: Array, a: Array, b: Array) -> Array:
    """Distance (N, K) of points ``p`` (N, 3) to segments a[k]-b[k] ((K, 3) each)."""
    ab = b - a
    t = np.einsum("nkj,kj->nk", p[:, None, :] - a[None], ab) / np.maximum(
        np.einsum("kj,kj->k", ab, ab), 1e-12
    )
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2)


#: Capsules around the ViperX-300s' links at the home pose (all joints 0), base frame:
#: (first point, second point, radius, number of joints that move it). The points are the
#: joint axes' positions from the URDF chain (shoulder 0.127 m up, elbow 0.0596 m forward and
#: 0.3 m up, wrist 0.3 m further, ee 0.177 m beyond the wrist); the radii cover the link
#: bodies, servos and the open fingers (89 mm apart).
VX300S_CAPSULES: tuple[
    tuple[tuple[float, float, float], tuple[float, float, float], float, int], ...
] = (
    ((-0.05, 0.0, 0.03), (0.0, 0.0, 0.127), 0.09, 0),  # base and waist servo
    ((0.0, 0.0, 0.127), (0.05955, 0.0, 0.42705), 0.05, 2),  # upper arm
    ((0.05955, 0.0, 0.42705), (0.35955, 0.0, 0.42705), 0.05, 3),  # forearm
    ((0.33, 0.0, 0.42705), (0.55, 0.0, 0.42705), 0.075, 6),  # wrist, gripper, fingers, tag
)


def arm_capsules_base(
    q: ArrayLike,
    capsules: Sequence[tuple[Any, Any, float, int]] = VX300S_CAPSULES,
    model: ArmModel = VX300S,
) -> tuple[Array, Array, Array]:
    """Capsules around the arm's links at joint angles ``q``: (a (K, 3), b (K, 3), radii (K,)).

    A point fixed to link i (moved by joints 1..i) at the home pose goes to
    e^[S1]q1 ... e^[Si]qi p_home. That product is fk of q with joints after i set to zero,
    times M^-1 (product of exponentials, Modern Robotics eq. 4.14), so one batched
    :func:`fk` call places every capsule.
    """
    q = np.asarray(q, dtype=float)
    Q = np.zeros((len(capsules), model.dof))
    for k, (_, _, _, n_moving) in enumerate(capsules):
        Q[k, :n_moving] = q[:n_moving]
    T_base_link = fk(Q, model) @ inv_T(model.M)
    a_home = np.array([c[0] for c in capsules], dtype=float)
    b_home = np.array([c[1] for c in capsules], dtype=float)
    a = np.einsum("kij,kj->ki", T_base_link[:, :3, :3], a_home) + T_base_link[:, :3, 3]
    b = np.einsum("kij,kj->ki", T_base_link[:, :3, :3], b_home) + T_base_link[:, :3, 3]
    radii = np.array([c[2] for c in capsules], dtype=float)
    return a, b, radii


def cylinder_box(
    intr: Intrinsics, center_cam: Array, axis_cam: Array, radius: float, height: float
) -> tuple[float, float, float, float]:
    """Pixel box (x0, y0, x1, y1) of a vertical cylinder: its rims' projection, clipped."""
    e1 = np.cross(axis_cam, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(axis_cam, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis_cam, e1)
    angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    ring = radius * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
    rims = np.concatenate(
        [center_cam + ring - 0.5 * height * axis_cam, center_cam + ring + 0.5 * height * axis_cam]
    )
    uv = project(intr, rims[rims[:, 2] > 1e-3])
    if len(uv) == 0:
        return (0.0, 0.0, 0.0, 0.0)
    x0, y0 = np.clip(uv.min(axis=0), 0, [intr.width, intr.height])
    x1, y1 = np.clip(uv.max(axis=0) + 1.0, 0, [intr.width, intr.height])
    return (float(x0), float(y0), float(x1), float(y1))


# --------------------------------------------------------------------------- geometric detector


class GeometricDetector:
    """Bottles and cups as vertical cylinders standing on the table, from depth alone.

    Per frame: (1) the table plane by RANSAC on a subsampled point cloud (within
    ``max_table_tilt_deg`` of the table normal the calibration predicts, when ``T_base_cam`` is
    given); (2) every pixel's height above it; pixels between ``min_height`` and ``max_height``
    and nearer than ``max_range`` are candidates; (3) with ``T_base_cam`` and the joint angles,
    candidates within ``arm_margin`` of the arm's link capsules are dropped (the self-filter)
    and so is anything farther than ``workspace_radius`` from the base axis; without them only
    the range and height crop applies and the robot may be reported; (4) candidates are binned
    onto a ``grid_cell`` grid in the table plane, the occupied cells joined by a closing and
    labelled with OpenCV's connected components, so a bottle's cap and liquid, which overlap in
    the plane though a gap of clear wall separates them in depth, are one cluster; (5) per
    cluster a circle is fitted to the camera-facing wall (algebraic fit, then geometric Huber
    IRLS on the points within a band of the circle on the side facing the camera, so a cup's
    inner far wall, its liquid and a bottle's liquid surface do not pull it), the height is the
    ``top_rank``-th highest point, and the label comes from the shape (``bottle_min_height``,
    a neck narrower than ``neck_ratio`` x the radius in the top quarter, or a gap of at least
    ``bottle_gap`` with no points in the height profile). (6) A short cluster cut by the
    left, right or top image border may be a clear bottle whose cap is outside the image: if
    its silhouette continues upward in colour (``color_contrast`` grey levels against its
    surroundings, with nothing standing behind it in depth) by more than ``bottle_gap``, it is
    a bottle whose height is that body top / ``bottle_body_fraction`` (a shape prior: the
    simulated bottles' body is 72 % of their height). Only every ``pixel_stride``-th pixel
    and row is used, and circle fits use at most ``max_fit_points`` points.

    ``score``  = (fraction of wall points within 2.5 sigma of the fitted surface, sigma being
    Intel's depth noise at that distance) x min(1, wall points / ``full_support_points``):
    near 1 for a well-seen cylinder, low for a ragged or barely seen cluster. Clusters with
    fewer than ``min_points`` points, a radius outside ``radius_range`` or a height below
    ``min_object_height`` are not reported.

    Measured ~9 ms per 640x480 frame (median over scenes, 17 ms with four objects) on 2 cores.
    """

    def __init__(
        self,
        T_base_cam: ArrayLike | None = None,
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
        full_support_points: int = 150,
        pixel_stride: int = 2,
        max_fit_points: int = 600,
        seed: int = 0,
    ) -> None:
        self.T_base_cam = None if T_base_cam is None else np.asarray(T_base_cam, dtype=float)
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
        self.full_support_points = int(full_support_points)
        if int(pixel_stride) < 1:
            raise ValueError(f"pixel_stride must be >= 1, not {pixel_stride}")
        self.pixel_stride = int(pixel_stride)
        self.max_fit_points = int(max_fit_points)
        self._rng = np.random.default_rng(seed)
        #: The last frame's table plane n.p_cam + d = 0 (n toward the camera), for debugging.
        self.last_plane: tuple[Array, float] | None = None

    # ---------------------------------------------------------------- public

    def detect(self, frame: RGBDFrame, joint_positions: ArrayLike | None = None) -> list[Detection]:
        """Bottles and cups in ``frame``; ``joint_positions`` (rad) enable the self-filter."""
        intr = frame.intrinsics
        depth = np.asarray(frame.depth, dtype=np.float64)
        if depth.shape != (intr.height, intr.width):
            raise PerceptionError(
                f"depth image is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                f"{intr.width}x{intr.height}: align depth to colour before detecting"
            )
        rays, flat = _unit_depth_rays(intr, self.pixel_stride)
        z = depth.ravel()[flat]
        normal, offset = self._table_plane(z, rays)
        self.last_plane = (normal, offset)
        # Height of every pixel above the table: n.(z ray) + d, without building the cloud.
        h = z * (rays @ normal) + offset
        candidate = (z > 0.0) & (z < self.max_range)
        candidate &= (h > self.min_height) & (h < self.max_height)
        idx = np.flatnonzero(candidate)
        p_cam = rays[idx] * z[idx, None]
        keep = self._self_filter(p_cam, joint_positions)
        idx, p_cam = idx[keep], p_cam[keep]
        if len(idx) < self.min_points:
            return []
        e1, e2 = self._plane_axes(normal)
        uw = np.column_stack([p_cam @ e1, p_cam @ e2])
        labels = self._cluster(uw)
        detections = []
        order = np.argsort(labels, kind="stable")
        bounds = np.flatnonzero(np.diff(labels[order])) + 1
        for members in np.split(order, bounds):
            if len(members) < self.min_points or labels[members[0]] <= 0:
                continue
            det = self._fit_cluster(
                frame, uw[members], h[idx[members]], p_cam[members, 2], normal, offset, e1, e2
            )
            if det is not None:
                detections.append(det)
        return detections

    # ---------------------------------------------------------------- steps

    def _table_plane(self, z: Array, rays: Array) -> tuple[Array, float]:
        valid = np.flatnonzero((z > 0.0) & (z < self.max_range))
        if len(valid) < 100:
            raise PerceptionError(
                "the depth image is (nearly) empty: is the camera's depth stream running and "
                "the table within range?"
            )
        pick = self._rng.choice(valid, size=min(self.ransac_points, len(valid)), replace=False)
        p_cam = rays[pick] * z[pick, None]
        prior = None
        if self.T_base_cam is not None:
            prior = self.T_base_cam[2, :3]  # base z in the camera frame: R_cam_base[:, 2]
        normal, offset, inliers = fit_plane_ransac(
            p_cam,
            self.plane_tolerance,
            self.ransac_iterations,
            self._rng,
            prior,
            math.radians(self.max_table_tilt_deg),
        )
        if inliers.mean() < 0.2:
            raise PerceptionError(
                f"the largest plane holds only {inliers.mean():.0%} of the depth points: is the "
                "table in view? (try `armvision sim snapshot` or check the camera placement)"
            )
        return normal, offset

    def _self_filter(self, p_cam: Array, joint_positions: ArrayLike | None) -> NDArray[np.bool_]:
        keep = np.ones(len(p_cam), dtype=bool)
        if self.T_base_cam is None or len(p_cam) == 0:
            return keep
        p_base = transform_points(self.T_base_cam, p_cam)
        keep &= np.hypot(p_base[:, 0], p_base[:, 1]) < self.workspace_radius
        if joint_positions is not None:
            a, b, radii = arm_capsules_base(joint_positions, self.arm_capsules, self.arm_model)
        else:  # the base does not move: drop it even without joint angles
            base = self.arm_capsules[0]
            a, b = np.array([base[0]], float), np.array([base[1]], float)
            radii = np.array([base[2]], float)
        near_arm = (segment_distances(p_base[keep], a, b) < radii + self.arm_margin).any(axis=1)
        keep[np.flatnonzero(keep)[near_arm]] = False
        return keep

    @staticmethod
    def _plane_axes(normal: Array) -> tuple[Array, Array]:
        """Two unit axes spanning the table plane (e1 near the camera's x axis)."""
        e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(normal, e1)

    def _cluster(self, uw: Array) -> NDArray[np.int32]:
        """Connected-component label (0 = none) per point, from a grid in the table plane."""
        cell = np.floor((uw - uw.min(axis=0)) / self.grid_cell).astype(np.int64)
        shape = cell.max(axis=0) + 3
        grid = np.zeros((int(shape[1]), int(shape[0])), dtype=np.uint8)
        grid[cell[:, 1] + 1, cell[:, 0] + 1] = 1
        # Close one-cell gaps (edge dropouts, a cap offset from its liquid column).
        grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        _, components = cv2.connectedComponents(grid, connectivity=8)
        return components[cell[:, 1] + 1, cell[:, 0] + 1].astype(np.int32)

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
    ) -> Detection | None:
        sigma = max(float(depth_rms_error(float(np.median(z)))), 0.001)
        # A few hundred points fix a circle to well under a millimetre; thousands cost time.
        sub = slice(None, None, max(1, len(uw) // self.max_fit_points))
        center, radius = fit_circle_kasa(uw[sub])
        center, radius, _ = fit_circle_geometric(uw[sub], center, radius, 2.0 * sigma)
        res = np.linalg.norm(uw - center, axis=1) - radius
        # The camera is at (0, 0) in (u, w): keep the wall facing it, near the circle.
        to_cam = -center / max(np.linalg.norm(center), 1e-9)
        band = max(4.0 * sigma, 0.006)
        for _ in range(2):
            wall = ((uw - center) @ to_cam > 0.0) & (np.abs(res) < band)
            if wall.sum() < 10:
                return None
            fit = np.flatnonzero(wall)[:: max(1, int(wall.sum()) // self.max_fit_points)]
            center, radius, _ = fit_circle_geometric(uw[fit], center, radius, 2.0 * sigma)
            res = np.linalg.norm(uw - center, axis=1) - radius
        if not self.radius_range[0] <= radius <= self.radius_range[1]:
            return None
        k = min(self.top_rank, len(h))
        top = float(np.partition(h, len(h) - k)[len(h) - k])
        if top < self.min_object_height:
            return None
        label = self._classify(uw, h, center, radius, top)
        foot_cam = center[0] * e1 + center[1] * e2 - offset * normal
        intr = frame.intrinsics
        x0, y0, x1, _ = cylinder_box(intr, foot_cam + 0.5 * top * normal, normal, radius, top)
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
        n_wall = int(wall.sum())
        fit_fraction = float((np.abs(res[wall]) < 2.5 * sigma).mean())
        score = fit_fraction * min(1.0, n_wall / self.full_support_points)
        center_cam = foot_cam + 0.5 * top * normal
        return Detection(
            label=label,
            score=score,
            box=cylinder_box(frame.intrinsics, center_cam, normal, radius, top),
            center_cam=center_cam,
            size=np.array([2.0 * radius, top, 2.0 * radius]),
            radius=float(radius),
            height=top,
            axis_cam=normal.copy(),
        )

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

    def _classify(self, uw: Array, h: Array, center: Array, radius: float, top: float) -> Label:
        if top >= self.bottle_min_height:
            return "bottle"
        upper = h > 0.75 * top
        if upper.sum() >= 5:
            r_upper = float(np.median(np.linalg.norm(uw[upper] - center, axis=1)))
            if r_upper < self.neck_ratio * radius:
                return "bottle"
        heights = np.sort(h)
        if len(heights) > 1 and float(np.diff(heights).max()) >= self.bottle_gap:
            return "bottle"
        return "cup"


# --------------------------------------------------------------------------- learned detectors

#: Bottle and cup class ids. COCO with a background class 0 (91 ids, as TF Object Detection
#: API SSD exports and jetson-inference's ssd-mobilenet-v2 number them) and YOLOv8's 80
#: contiguous COCO classes.
COCO91_CLASS_IDS = {"bottle": 44, "cup": 47}
YOLO_CLASS_IDS = {"bottle": 39, "cup": 41}


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


def _detections_from_boxes(
    frame: RGBDFrame,
    boxes: Array,
    scores: Array,
    labels: Sequence[Label],
    center_fraction: float,
    depth_percentile: float,
) -> list[Detection]:
    """Detections for pixel boxes (N, 4) x0, y0, x1, y1; boxes without depth are dropped."""
    intr = frame.intrinsics
    out = []
    for box, score, label in zip(boxes, scores, labels):
        x0, y0, x1, y1 = (float(v) for v in box)
        x0, x1 = float(np.clip(x0, 0, intr.width)), float(np.clip(x1, 0, intr.width))
        y0, y1 = float(np.clip(y0, 0, intr.height)), float(np.clip(y1, 0, intr.height))
        if x1 - x0 < 1.0 or y1 - y0 < 1.0:
            continue
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
            )
        )
    return out


def read_labels(path: str | os.PathLike[str]) -> list[str]:
    """Class names, one per line (line number = class id), as jetson-inference's labels.txt."""
    try:
        return [line.strip() for line in Path(path).read_text(encoding="utf-8").splitlines()]
    except OSError as exc:
        raise PerceptionError(f"cannot read the labels file {path}: {exc.strerror}") from None


def class_ids_from_labels(labels: Sequence[str]) -> dict[str, int]:
    """{"bottle": id, "cup": id} looked up by name in a labels list."""
    lowered = [name.lower() for name in labels]
    missing = [name for name in LABELS if name not in lowered]
    if missing:
        raise PerceptionError(
            f"the labels file has no {' or '.join(missing)} class; pass class_ids="
            "{'bottle': ..., 'cup': ...} for this model"
        )
    return {name: lowered.index(name) for name in LABELS}


def letterbox(
    image: NDArray[np.uint8], size: tuple[int, int], pad_value: int = 114
) -> tuple[NDArray[np.uint8], float, tuple[float, float]]:
    """Resize ``image`` to fit (width, height) keeping its aspect, pad the rest (Ultralytics).

    Returns (image, scale, (pad_x, pad_y)); an input pixel p maps back as (p - pad) / scale.
    """
    width, height = size
    h0, w0 = image.shape[:2]
    scale = min(width / w0, height / h0)
    w1, h1 = round(w0 * scale), round(h0 * scale)
    resized = cv2.resize(image, (w1, h1), interpolation=cv2.INTER_LINEAR)
    pad_x, pad_y = (width - w1) / 2.0, (height - h1) / 2.0
    top, left = round(pad_y - 0.1), round(pad_x - 0.1)
    out = cv2.copyMakeBorder(
        resized,
        top,
        height - h1 - top,
        left,
        width - w1 - left,
        cv2.BORDER_CONSTANT,
        value=(pad_value, pad_value, pad_value),
    )
    return out, scale, (float(left), float(top))


def decode_ssd(
    boxes: Array,
    classes: Array,
    scores: Array,
    count: Array | int,
    class_ids: dict[str, int],
    threshold: float,
    image_size: tuple[int, int],
    box_order: Literal["yxyx", "xyxy"] = "yxyx",
    normalized: bool = True,
) -> tuple[Array, Array, list[Label]]:
    """Bottle and cup boxes (N, 4) x0, y0, x1, y1 in pixels, scores and labels of an SSD export.

    ``boxes`` (1, N, 4), ``classes`` and ``scores`` (1, N), ``count`` the valid rows (TF Object
    Detection API: ``detection_boxes`` as normalised ymin, xmin, ymax, xmax).
    """
    n = int(np.asarray(count).ravel()[0]) if np.size(count) else len(np.ravel(scores))
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)[:n]
    c = np.rint(np.asarray(classes, dtype=float).ravel()[:n]).astype(int)
    s = np.asarray(scores, dtype=float).ravel()[:n]
    if box_order == "yxyx":
        b = b[:, [1, 0, 3, 2]]
    if normalized:
        width, height = image_size
        b = b * [width, height, width, height]
    id_to_label = {v: k for k, v in class_ids.items()}
    keep = (s >= threshold) & np.isin(c, list(id_to_label))
    return b[keep], s[keep], [id_to_label[int(i)] for i in c[keep]]  # type: ignore[misc]


def decode_yolov8(
    output: Array, class_ids: dict[str, int], threshold: float
) -> tuple[Array, Array, list[Label]]:
    """Bottle and cup boxes (N, 4) x0, y0, x1, y1 in network-input pixels from a YOLOv8 head.

    ``output`` (1, 4 + C, N): per candidate (cx, cy, w, h) then C class scores (already
    sigmoid). Each candidate keeps its best class among bottle and cup.
    """
    pred = np.asarray(output, dtype=float).reshape(output.shape[-2], output.shape[-1]).T
    names = list(class_ids)
    cls_scores = pred[:, [4 + class_ids[name] for name in names]]
    best = np.argmax(cls_scores, axis=1)
    s = cls_scores[np.arange(len(pred)), best]
    keep = s >= threshold
    cx, cy, w, h = pred[keep, 0], pred[keep, 1], pred[keep, 2], pred[keep, 3]
    b = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    return b, s[keep], [names[i] for i in best[keep]]  # type: ignore[misc]


def nms(
    boxes: Array, scores: Array, labels: Sequence[str], iou_threshold: float
) -> NDArray[np.intp]:
    """Indices kept by per-class non-maximum suppression (OpenCV's ``dnn.NMSBoxesBatched``)."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.intp)
    xywh = [[float(x0), float(y0), float(x1 - x0), float(y1 - y0)] for x0, y0, x1, y1 in boxes]
    class_index = [LABELS.index(label) for label in labels]  # type: ignore[arg-type]
    kept = cv2.dnn.NMSBoxesBatched(
        xywh, [float(s) for s in scores], class_index, 0.0, iou_threshold
    )
    return np.asarray(kept, dtype=np.intp).ravel()


class OnnxDetector:
    """Bottles and cups from an ONNX object detector run by ONNX Runtime.

    Two export formats: ``"ssd"`` (TF Object Detection API SSD-MobileNet: outputs boxes,
    classes, scores and a count; normalised ymin, xmin, ymax, xmax; uint8 NHWC input) and
    ``"yolov8"`` (Ultralytics: one output (1, 84, N); float NCHW input in [0, 1],
    letterboxed). ``kind=None`` tells them apart by their outputs. Class ids: ``class_ids`` if
    given, else looked up by name in ``labels_path`` (one name per line, line = id), else
    COCO's (bottle 44, cup 47 with background for SSD; 39, 41 for YOLO). Boxes scoring below
    ``threshold`` are dropped, then per-class NMS at ``nms_iou``. The 3-D centre and size come
    from the depth in the box (:func:`box_center_3d`).

    ONNX Runtime is imported here, not at module import: ``pip install onnxruntime`` (or
    ``onnxruntime-gpu``) to use this detector. ``providers`` defaults to ONNX Runtime's.
    """

    def __init__(
        self,
        model_path: str | os.PathLike[str],
        *,
        kind: Literal["ssd", "yolov8"] | None = None,
        labels_path: str | os.PathLike[str] | None = None,
        class_ids: dict[str, int] | None = None,
        threshold: float = 0.5,
        nms_iou: float = 0.45,
        ssd_box_order: Literal["yxyx", "xyxy"] = "yxyx",
        center_fraction: float = 0.3,
        depth_percentile: float = 25.0,
        providers: Sequence[str] | None = None,
    ) -> None:
        try:
            import onnxruntime
        except ImportError:
            raise PerceptionError(
                "OnnxDetector needs ONNX Runtime: pip install onnxruntime (onnxruntime-gpu on "
                "CUDA machines), or use GeometricDetector, which needs no weights"
            ) from None
        if not Path(model_path).is_file():
            raise PerceptionError(f"ONNX model {model_path} does not exist")
        try:
            self.session = onnxruntime.InferenceSession(
                str(model_path),
                providers=list(providers) if providers else onnxruntime.get_available_providers(),
            )
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph types
            raise PerceptionError(f"ONNX Runtime cannot load {model_path}: {exc}") from exc
        self.input = self.session.get_inputs()[0]
        self.output_names = [o.name for o in self.session.get_outputs()]
        if kind is None:
            kind = "yolov8" if len(self.output_names) == 1 else "ssd"
        if kind not in ("ssd", "yolov8"):
            raise PerceptionError(f"kind must be 'ssd' or 'yolov8', not {kind!r}")
        self.kind = kind
        if class_ids is None and labels_path is not None:
            labels = read_labels(labels_path)
            class_ids = class_ids_from_labels(labels)
        if class_ids is None:
            class_ids = dict(COCO91_CLASS_IDS if kind == "ssd" else YOLO_CLASS_IDS)
        unknown = set(class_ids) - set(LABELS)
        if unknown:
            raise PerceptionError(f"class_ids may name only {LABELS}, not {sorted(unknown)}")
        self.class_ids = dict(class_ids)
        self.threshold = float(threshold)
        self.nms_iou = float(nms_iou)
        self.ssd_box_order = ssd_box_order
        self.center_fraction = float(center_fraction)
        self.depth_percentile = float(depth_percentile)

    def _input_layout(self) -> tuple[bool, tuple[int | None, int | None]]:
        """(channels_first, (width, height) or None where the model takes any size)."""
        shape = list(self.input.shape)
        channels_first = len(shape) == 4 and shape[1] == 3
        dims = shape[2:4] if channels_first else shape[1:3]
        h, w = (d if isinstance(d, int) and d > 0 else None for d in dims)
        return channels_first, (w, h)

    def _ssd_outputs(self, outputs: list[Array]) -> tuple[Array, Array, Array, Array]:
        by_name: dict[str, Array] = {}
        for name, value in zip(self.output_names, outputs):
            key = name.lower()
            for role in ("box", "class", "score", "num"):
                if role in key and role not in by_name:
                    by_name[role] = value
        if len(by_name) < 4:  # unnamed outputs: the TF export's order
            by_name = dict(zip(("box", "class", "score", "num"), outputs))
        return by_name["box"], by_name["class"], by_name["score"], by_name["num"]

    def detect(self, frame: RGBDFrame) -> list[Detection]:
        """Bottles and cups in ``frame`` (colour for the network, depth for the 3-D centre)."""
        color = np.asarray(frame.color)
        h0, w0 = color.shape[:2]
        channels_first, (w_in, h_in) = self._input_layout()
        if self.kind == "yolov8":
            size = (w_in or 640, h_in or 640)
            image, scale, (pad_x, pad_y) = letterbox(color, size)
        else:
            size = (w_in or w0, h_in or h0)
            image = color if size == (w0, h0) else cv2.resize(color, size)
        tensor = image[None]
        if channels_first:
            tensor = tensor.transpose(0, 3, 1, 2)
        if "float" in self.input.type:
            tensor = tensor.astype(np.float32) / (255.0 if self.kind == "yolov8" else 1.0)
        outputs = self.session.run(None, {self.input.name: np.ascontiguousarray(tensor)})
        if self.kind == "yolov8":
            boxes, scores, labels = decode_yolov8(outputs[0], self.class_ids, self.threshold)
            boxes = (boxes - [pad_x, pad_y, pad_x, pad_y]) / scale
        else:
            raw_boxes, classes, raw_scores, count = self._ssd_outputs(outputs)
            boxes, scores, labels = decode_ssd(
                raw_boxes,
                classes,
                raw_scores,
                count,
                self.class_ids,
                self.threshold,
                (w0, h0),
                self.ssd_box_order,
            )
        keep = nms(boxes, scores, labels, self.nms_iou)
        return _detections_from_boxes(
            frame,
            boxes[keep],
            scores[keep],
            [labels[i] for i in keep],
            self.center_fraction,
            self.depth_percentile,
        )


class JetsonDetector:
    """Bottles and cups from jetson-inference's ``detectNet`` (TensorRT) on an NVIDIA Jetson.

    ``detectNet(network, threshold=threshold)`` is built on first use; jetson-inference numbers
    COCO with a background class, so bottle is 44 and cup 47 (``class_ids``). The 3-D centre
    and size come from the depth in the box (:func:`box_center_3d`). ``net`` and ``to_cuda``
    replace the network and jetson_utils' ``cudaFromNumpy`` (for tests, or a custom model).
    """

    def __init__(
        self,
        network: str = "ssd-mobilenet-v2",
        *,
        threshold: float = 0.5,
        class_ids: dict[str, int] | None = None,
        center_fraction: float = 0.3,
        depth_percentile: float = 25.0,
        net: Any = None,
        to_cuda: Any = None,
    ) -> None:
        self.network = network
        self.threshold = float(threshold)
        self.class_ids = dict(COCO91_CLASS_IDS if class_ids is None else class_ids)
        self.center_fraction = float(center_fraction)
        self.depth_percentile = float(depth_percentile)
        self._net = net
        self._to_cuda = to_cuda

    def _load(self) -> tuple[Any, Any]:
        if self._net is not None and self._to_cuda is not None:
            return self._net, self._to_cuda
        try:
            from jetson_inference import detectNet
            from jetson_utils import cudaFromNumpy
        except ImportError:
            try:  # jetson-inference before 2022 installs the jetson.* namespace
                from jetson.inference import detectNet  # type: ignore[no-redef]
                from jetson.utils import cudaFromNumpy  # type: ignore[no-redef]
            except ImportError:
                raise PerceptionError(
                    "JetsonDetector needs jetson-inference, which runs on NVIDIA Jetson boards "
                    "(build it from github.com/dusty-nv/jetson-inference); elsewhere use "
                    "GeometricDetector or OnnxDetector"
                ) from None
        if self._net is None:
            self._net = detectNet(self.network, threshold=self.threshold)
        if self._to_cuda is None:
            self._to_cuda = cudaFromNumpy
        return self._net, self._to_cuda

    def detect(self, frame: RGBDFrame) -> list[Detection]:
        """Bottles and cups in ``frame``: detectNet on the colour image, depth for 3-D."""
        net, to_cuda = self._load()
        color = np.ascontiguousarray(frame.color)
        h, w = color.shape[:2]
        raw = net.Detect(to_cuda(color), w, h, "none")
        id_to_label = {v: k for k, v in self.class_ids.items()}
        picked = [
            d
            for d in raw
            if int(d.ClassID) in id_to_label and float(d.Confidence) >= self.threshold
        ]
        boxes = np.array([[d.Left, d.Top, d.Right, d.Bottom] for d in picked], dtype=float)
        return _detections_from_boxes(
            frame,
            boxes.reshape(-1, 4),
            np.array([float(d.Confidence) for d in picked]),
            [id_to_label[int(d.ClassID)] for d in picked],  # type: ignore[misc]
            self.center_fraction,
            self.depth_percentile,
        )
