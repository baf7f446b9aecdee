"""AprilTag detection and 6-D pose, refined with the depth image.

Detection is pupil-apriltags (the AprilTag 3 library). The pose is not pupil's: we solve PnP
with OpenCV's IPPE_SQUARE, which returns *both* solutions of the planar ambiguity (Collins &
Bartoli 2014), on corners undistorted with the camera's own (librealsense) distortion model.
Monocular PnP is weakest along the viewing axis and near-frontal tags flip between the two
solutions, so with depth we fit a plane to the depth pixels inside the tag and

* keep the PnP solution whose normal agrees with the measured plane (rejecting the flip),
* tilt its normal toward the measured one, each weighted by its covariance (PnP is sharper
  on large, close or oblique tags; depth on small frontal ones), keeping PnP's in-plane
  rotation, and
* place the centre where the ray through the tag's centre pixel meets the measured plane.

Frames: ``T_cam_tag`` in the AprilTag library's convention (origin at the tag centre, z into
the tag), camera optical frame x right, y down, z forward.

Three pupil-apriltags (1.0.4) quirks handled here: it registers only the first family of a
space-separated list (so one detector per family); it truncates ``decode_sharpening`` to an
integer when configuring the C detector (so we write the float back into the C struct); and its
``__del__`` frees the tag families before the detector that still uses them, an intermittent
segfault (duckietown/lib-dt-apriltags#33 fixed the same code), so :func:`pupil_detector` frees
them in the right order.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import (
    Intrinsics,
    RGBDFrame,
    deproject,
    normalised_rays,
    project,
)
from armvision.errors import PerceptionError
from armvision.geometry import cross3, make_T, rotation_between
from armvision.perception.fitting import fit_plane, unit_depth_rays

Array = NDArray[np.float64]

FAMILIES = (
    "tag36h11",
    "tag25h9",
    "tag16h5",
    "tagCircle21h7",
    "tagCircle49h12",
    "tagCustom48h12",
    "tagStandard41h12",
    "tagStandard52h13",
)

#: The step of :meth:`TagDetector._fused_normal`'s numerical Jacobian, and the rotations by
#: it about the camera's x, y and z axes (constant, so made once, not six Rodrigues per tag).
_NUDGE = 1e-6
_NUDGE_SHIFTS = np.eye(3) * _NUDGE
_NUDGE_ROTATIONS = np.array([cv2.Rodrigues(shift)[0] for shift in _NUDGE_SHIFTS])


@dataclass(frozen=True, eq=False)
class TagDetection:
    """One detected tag.

    ``corners`` (4, 2) pixels in AprilTag order (object points (-s, s), (s, s), (s, -s),
    (-s, -s) for half-size s); ``center`` (2,) pixel of the tag centre; ``pose_error`` the RMS
    reprojection error of the corners under ``T_cam_tag``, pixels; ``depth_refined`` whether
    the depth image corrected the pose (``plane_rms_m`` is then the plane fit's residual);
    ``flip_corrected`` whether depth chose PnP's second solution over its first.
    """

    id: int
    family: str
    corners: Array
    center: Array
    T_cam_tag: Array
    decision_margin: float
    hamming: int
    pose_error: float
    depth_refined: bool = False
    plane_rms_m: float = float("nan")
    flip_corrected: bool = False


def _free_in_order(detector: Any) -> None:
    """Destroy the C detector first, then its tag families (the reverse of pupil's order)."""
    ptr = getattr(detector, "tag_detector_ptr", None)
    if ptr is None:  # never built, or already freed
        return
    detector.tag_detector_ptr = None
    libc = detector.libc
    libc.apriltag_detector_destroy.restype = None
    libc.apriltag_detector_destroy(ptr)
    for family, handle in detector.tag_families.items():
        destroy = getattr(libc, f"{family}_destroy")
        destroy.restype = None
        destroy(handle)
    detector.tag_families = {}


@functools.cache
def _safe_detector_class() -> type:
    try:
        from pupil_apriltags import Detector
    except ImportError as exc:  # pragma: no cover - a dependency of armvision
        raise PerceptionError(
            f"pupil-apriltags is not installed ({exc}): pip install pupil-apriltags"
        ) from None
    return type("SafeDetector", (Detector,), {"__del__": _free_in_order})


def pupil_detector(**kwargs: Any) -> Any:
    """A ``pupil_apriltags.Detector(**kwargs)`` that frees its C state in a safe order.

    ``decode_sharpening`` is set as given (pupil-apriltags would truncate it to an integer).
    """
    detector = _safe_detector_class()(**kwargs)
    if "decode_sharpening" in kwargs:
        detector.tag_detector_ptr.contents.decode_sharpening = float(kwargs["decode_sharpening"])
    return detector


def tag_object_points(tag_size: float) -> Array:
    """Corner coordinates in the tag frame, in the order pupil-apriltags reports corners."""
    s = tag_size / 2.0
    return np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])


def _normalised(intr: Intrinsics, uv: Array) -> Array:
    """Undistorted normalised image coordinates (x/z, y/z) of pixels (N, 2), any librealsense
    model: :func:`deproject`'s at depth 1, without its checks and (N, 3) result."""
    xy = np.empty((len(uv), 2))
    xy[:, 0], xy[:, 1] = normalised_rays(intr, uv)
    return xy


def _ippe_solutions(object_points: Array, xy: Array) -> list[tuple[Array, float]]:
    """Both IPPE_SQUARE poses (T_cam_tag) with their reprojection RMS in normalised units."""
    ok, rvecs, tvecs, errors = cv2.solvePnPGeneric(
        np.ascontiguousarray(object_points).reshape(-1, 1, 3),
        np.ascontiguousarray(xy).reshape(-1, 1, 2),
        np.eye(3),
        None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    if not ok:
        return []
    out = []
    for rvec, tvec, err in zip(rvecs, tvecs, np.ravel(errors)):
        out.append((make_T(cv2.Rodrigues(rvec)[0], np.ravel(tvec)), float(err)))
    return out


def _tag_depth_points(intr: Intrinsics, depth: NDArray, corners: Array, shrink: float) -> Array:
    """3-D points of the valid depth pixels inside the tag quad shrunk toward its centre.

    The pixels' rays come from the per-intrinsics cache of :func:`unit_depth_rays` when the
    depth image has the intrinsics' size (the same points as :func:`deproject`, cheaper)."""
    centre = corners.sum(axis=0) / len(corners)  # corners.mean(axis=0), without its overhead
    quad = centre + shrink * (corners - centre)
    x0, y0 = np.floor(quad.min(axis=0)).astype(int)
    x1, y1 = np.ceil(quad.max(axis=0)).astype(int)
    h, w = depth.shape
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
    if x1 <= x0 or y1 <= y0:
        return np.empty((0, 3))
    mask = np.zeros((y1 - y0 + 1, x1 - x0 + 1), dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.round(quad - [x0, y0]).astype(np.int32), 1)
    patch = depth[y0 : y1 + 1, x0 : x1 + 1]
    valid = mask.view(bool) & (patch > 0)  # the mask holds 0 and 1: a bool view
    z = patch[valid].astype(float)
    if len(z) == 0:
        return np.empty((0, 3))
    if (h, w) == (intr.height, intr.width):
        rays = unit_depth_rays(intr, 1)[0].reshape(h, w, 3)
        return rays[y0 : y1 + 1, x0 : x1 + 1][valid] * z[:, None]
    rows, cols = np.nonzero(valid)
    uv = np.column_stack([cols + x0, rows + y0]).astype(float)
    return deproject(intr, uv, z)


class TagDetector:
    """Find AprilTags of one family and estimate ``T_cam_tag`` for each.

    ``ids``: keep only these ids (None keeps all). ``tag_size``: edge of the black square, m.
    ``nthreads``, ``quad_decimate``, ``quad_sigma``, ``refine_edges``, ``decode_sharpening``:
    pupil-apriltags' detector settings (its defaults, except decimation 1.0: full resolution
    costs ~2x time at 640x480 but keeps small, distant tags). With ``nthreads`` > 1,
    pupil-apriltags 1.0.4 crashes now and then when detectors are created one after another
    (seen here in about one run in three of 300 detectors), so one thread is the default.
    ``max_hamming``: corrected bits accepted (0-2; more means more false positives).
    ``refine_with_depth``: use the depth image as described in the module docstring;
    ``min_depth_points`` valid depth pixels are needed inside the tag, and
    ``max_normal_disagreement_deg`` bounds how far the depth plane may be from the chosen PnP
    solution before the depth is distrusted. ``corner_sigma_px``: the corner noise used to
    weigh PnP's tag normal against the depth plane's; None estimates it per tag from the PnP
    residual (sigma^2 = SSR / (8 - 6), at least 0.05 px).
    """

    def __init__(
        self,
        family: str = "tag36h11",
        ids: Iterable[int] | None = None,
        tag_size: float = 0.04,
        nthreads: int = 1,
        quad_decimate: float = 1.0,
        quad_sigma: float = 0.0,
        refine_edges: bool = True,
        decode_sharpening: float = 0.25,
        max_hamming: int = 1,
        refine_with_depth: bool = True,
        min_depth_points: int = 30,
        max_normal_disagreement_deg: float = 30.0,
        corner_sigma_px: float | None = None,
    ) -> None:
        if family not in FAMILIES:
            raise PerceptionError(f"unknown AprilTag family {family!r}; use one of {FAMILIES}")
        if not tag_size > 0:
            raise PerceptionError(
                f"tag_size must be the black square's edge in metres, got {tag_size}"
            )
        self.family = family
        self.ids = None if ids is None else frozenset(int(i) for i in ids)
        self.tag_size = float(tag_size)
        self.max_hamming = int(max_hamming)
        self.refine_with_depth = refine_with_depth
        self.min_depth_points = int(min_depth_points)
        self.max_normal_disagreement = np.radians(max_normal_disagreement_deg)
        self.corner_sigma_px = None if corner_sigma_px is None else float(corner_sigma_px)
        self._detector = pupil_detector(
            families=family,
            nthreads=int(nthreads),
            quad_decimate=float(quad_decimate),
            quad_sigma=float(quad_sigma),
            refine_edges=int(bool(refine_edges)),
            decode_sharpening=float(decode_sharpening),
        )
        self._object_points = tag_object_points(self.tag_size)

    @classmethod
    def from_config(cls, tag_config, **kwargs) -> TagDetector:
        """A detector for the configured gripper tag (``config.tag``), other settings as given."""
        kwargs.setdefault("ids", None)
        return cls(family=tag_config.family, tag_size=tag_config.size, **kwargs)

    def detect(self, frame: RGBDFrame) -> list[TagDetection]:
        """Tags in an RGB-D frame; depth refines the poses when ``refine_with_depth``."""
        return self.detect_image(frame.color, frame.intrinsics, frame.depth)

    def detect_image(
        self, image: ArrayLike, intrinsics: Intrinsics, depth: ArrayLike | None = None
    ) -> list[TagDetection]:
        """Tags in a colour (H, W, 3 RGB) or grey (H, W) uint8 image, optionally with depth (m)."""
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim not in (2, 3):
            raise PerceptionError(
                f"expected an 8-bit grey or RGB image, got {image.dtype} {image.shape}"
            )
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        gray = np.ascontiguousarray(gray)
        if depth is not None:
            depth = np.asarray(depth)
            if depth.shape != gray.shape:
                raise PerceptionError(
                    f"depth {depth.shape} does not match colour {gray.shape}: align depth to colour"
                )
        detections = []
        for raw in self._detector.detect(gray):
            if raw.hamming > self.max_hamming or (
                self.ids is not None and raw.tag_id not in self.ids
            ):
                continue
            found = self._pose(raw, intrinsics, depth)
            if found is not None:
                detections.append(found)
        return detections

    def _pose(self, raw, intr: Intrinsics, depth: NDArray | None) -> TagDetection | None:
        corners = np.asarray(raw.corners, dtype=float)
        center = np.asarray(raw.center, dtype=float)
        # The corners' and the centre's rays in one call (the centre's for the depth plane).
        xy = _normalised(intr, np.concatenate([corners, center[None]]))
        solutions = _ippe_solutions(self._object_points, xy[:4])
        if not solutions:
            return None
        solutions.sort(key=lambda s: s[1])
        T_cam_tag = solutions[0][0]
        refined, flipped, plane_rms = False, False, float("nan")

        if depth is not None and self.refine_with_depth:
            points = _tag_depth_points(intr, depth, corners, shrink=0.8)
            plane = None
            if len(points) >= self.min_depth_points:
                # No RANSAC: the plate fills the quad; a refit drops speckle and its edge.
                plane = fit_plane(points, 0.004, refits=2, robust=True)
            if plane is not None:
                into = -plane.normal  # the plate's normal away from the camera, as the tag's z
                # The PnP solution whose tag normal (z, into the tag) agrees with the plane.
                angles = [
                    math.acos(min(max(float(T[:3, 2] @ into), -1.0), 1.0)) for T, _ in solutions
                ]
                best = int(np.argmin(angles))
                if angles[best] <= self.max_normal_disagreement:
                    flipped = best != 0
                    T_pnp = solutions[best][0]
                    normal = self._fused_normal(T_pnp, corners, intr, points, into, plane.rms)
                    R = rotation_between(T_pnp[:3, 2], normal) @ T_pnp[:3, :3]
                    ray = np.append(xy[4], 1.0)
                    p_centre = ray * plane.offset / (into @ ray)
                    T_cam_tag = make_T(R, p_centre)
                    refined, plane_rms = True, plane.rms

        return TagDetection(
            id=int(raw.tag_id),
            family=self.family,
            corners=corners,
            center=center,
            T_cam_tag=T_cam_tag,
            decision_margin=float(raw.decision_margin),
            hamming=int(raw.hamming),
            pose_error=self._reprojection_rms(T_cam_tag, corners, intr),
            depth_refined=refined,
            plane_rms_m=plane_rms,
            flip_corrected=flipped,
        )

    def _fused_normal(
        self,
        T_pnp: Array,
        corners: Array,
        intr: Intrinsics,
        points: Array,
        plane_normal: Array,
        plane_rms: float,
    ) -> Array:
        """Tag normal from PnP and the depth plane, each weighted by its covariance.

        PnP: sigma_px^2 (J^T J)^-1 from the corners' reprojection Jacobian (numerical, through
        the camera's distortion model). Depth: rms^2 (A^T A)^-1 of the plane fit's in-plane
        spread. Both as 2-D tilts in the tangent plane of the PnP normal; the fused tilt is
        C_pnp (C_pnp + C_depth)^-1 d, d the depth normal's tilt.
        """
        n = T_pnp[:3, 2]
        a = T_pnp[:3, 0]
        b = T_pnp[:3, 1]
        R_pnp, t_pnp = T_pnp[:3, :3], T_pnp[:3, 3]
        # Reprojection Jacobian w.r.t. a small rotation (camera frame) and translation.
        # The corners at the pose and at the six nudged poses, projected in one call.
        posed = np.empty((7, 4, 3))
        posed[0] = self._object_points @ R_pnp.T + t_pnp
        posed[1:4] = self._object_points @ (_NUDGE_ROTATIONS @ R_pnp).transpose(0, 2, 1) + t_pnp
        posed[4:] = posed[0] + _NUDGE_SHIFTS[:, None]
        uv = project(intr, posed.reshape(-1, 3)).reshape(7, -1)
        J = (uv[1:] - uv[0]).T / _NUDGE
        sigma_px = self.corner_sigma_px
        if sigma_px is None:
            residual = uv[0].reshape(-1, 2) - corners
            sigma_px = max(math.sqrt(float((residual * residual).sum()) / 2.0), 0.05)
        try:
            C_pose = sigma_px**2 * np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            return plane_normal
        # dn = dtheta x n, so the tilt along a is dtheta . (n x a).
        J_tilt = np.array([cross3(n, a), cross3(n, b)])
        (p00, p01), (p10, p11) = (J_tilt @ C_pose[:3, :3] @ J_tilt.T).tolist()
        # (The mean as a product: an axis-0 sum of a few hundred rows costs several times more.)
        spread = points - np.ones(len(points)) @ points / len(points)
        A = spread @ T_pnp[:3, :2]  # the spread along a and b
        (m00, m01), (m10, m11) = (A.T @ A).tolist()
        # The 2x2 inverses written out: np.linalg.inv's call costs more than the arithmetic.
        det = m00 * m11 - m01 * m10
        if det == 0.0:
            return n
        sigma_r = max(plane_rms, 1e-4)
        k = sigma_r**2 / det  # C_depth = sigma_r^2 (A^T A)^-1
        s00, s01, s10, s11 = p00 + k * m11, p01 - k * m01, p10 - k * m10, p11 + k * m00
        det = s00 * s11 - s01 * s10  # of S = C_pnp + C_depth
        if det == 0.0:
            return n
        d0, d1 = float(plane_normal @ a), float(plane_normal @ b)
        y0, y1 = (s11 * d0 - s01 * d1) / det, (s00 * d1 - s10 * d0) / det  # S^-1 d
        tilt0, tilt1 = p00 * y0 + p01 * y1, p10 * y0 + p11 * y1  # C_pnp S^-1 d
        fused = n + tilt0 * a + tilt1 * b
        return fused / math.sqrt(float(fused @ fused))

    def _reprojection_rms(self, T_cam_tag: Array, corners: Array, intr: Intrinsics) -> float:
        p_cam = self._object_points @ T_cam_tag[:3, :3].T + T_cam_tag[:3, 3]
        error = project(intr, p_cam) - corners
        return math.sqrt(float((error * error).sum(axis=1).sum()) / len(error))
