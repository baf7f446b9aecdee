"""RGB-D frames, camera intrinsics, and projection between pixels and 3-D points.

Pixel convention (OpenCV, librealsense): pixel (u, v) = (column, row) and integer coordinates
are pixel centres, so the top-left pixel's centre is (0, 0). Points are in the camera's
optical frame: x right, y down, z forward, metres.

Projection follows librealsense's ``rs2_project_point_to_pixel`` and
``rs2_deproject_pixel_to_point`` (``include/librealsense2/rsutil.h``, SDK 2.59) for every
distortion model in :data:`DISTORTION_MODELS`, vectorised over points, and agrees with
pyrealsense2 2.59.1 (tests/camera/test_frames.py). librealsense's quirks are kept on purpose so
that points match what the SDK computes:

- ``brown_conrady``: projection distorts (radial factor on x, y; tangential terms on the
  undistorted x, y); deprojection inverts it with 10 fixed-point iterations.
- ``inverse_brown_conrady`` (the D400 colour stream): projection applies the radial factor first
  and the tangential terms to the scaled x, y; deprojection inverts that with 10 iterations.
  (SDKs before 2.4x instead applied the forward formula once; see librealsense issue #7335.)
- ``modified_brown_conrady``: projection as ``inverse_brown_conrady``; librealsense does not
  undistort it on deprojection (an assert that release builds drop), so neither does this.
- ``kannala_brandt4`` (fisheye, theta polynomial): deprojection by at most 4 Newton steps.
- ``ftheta``: librealsense's deprojection is not the exact inverse of its projection; kept.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: librealsense's ``rs2_distortion`` names (``rs.distortion.<name>``) that this module handles.
DISTORTION_MODELS = (
    "none",
    "brown_conrady",
    "inverse_brown_conrady",
    "modified_brown_conrady",
    "kannala_brandt4",
    "ftheta",
)
#: Fixed-point iterations of librealsense's Brown-Conrady undistortion ("determined empirically").
_BROWN_CONRADY_ITERATIONS = 10
#: Newton steps of librealsense's Kannala-Brandt undistortion, and its tolerance FLT_EPSILON.
_KANNALA_BRANDT_ITERATIONS = 4
_FLT_EPSILON = float(np.finfo(np.float32).eps)


#: Intel's depth RMS error model (RealSense D400 datasheet / "Tuning depth cameras for best
#: performance"): RMS = z^2 * subpixel / (focal_px * baseline), with subpixel ~0.08, the
#: D435's 50 mm baseline and ~424 px focal length of the depth imager at 848x480.
DEPTH_SUBPIXEL = 0.08
DEPTH_BASELINE_M = 0.050
DEPTH_FOCAL_PX = 424.0


def depth_rms_error(z: NDArray[np.floating] | float) -> NDArray[np.float64] | float:
    """Intel's expected depth RMS error (m) at depth ``z`` (m): z^2 * 0.08 / (424 px * 0.05 m).

    One sensor model for the simulator's depth noise and the detectors' weights.
    """
    return np.square(z) * DEPTH_SUBPIXEL / (DEPTH_FOCAL_PX * DEPTH_BASELINE_M)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one stream, librealsense's ``rs2_intrinsics`` fields.

    ``fx, fy`` focal lengths and ``ppx, ppy`` principal point, pixels; ``model`` and
    ``coeffs`` the distortion model (one of :data:`DISTORTION_MODELS`) and its five
    coefficients: [k1, k2, p1, p2, k3] for the Brown-Conrady models, [k1, k2, k3, k4, 0] for
    ``kannala_brandt4``, [w, 0, 0, 0, 0] for ``ftheta``.
    """

    width: int
    height: int
    fx: float
    fy: float
    ppx: float
    ppy: float
    model: str = "none"
    coeffs: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        # A tuple of floats even when given a list or array, so Intrinsics stay hashable.
        object.__setattr__(self, "coeffs", tuple(float(c) for c in self.coeffs))

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain JSON values (for saved files: snapshots, calibrations)."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "ppx": self.ppx,
            "ppy": self.ppy,
            "model": self.model,
            "coeffs": list(self.coeffs),
        }

    @property
    def K(self) -> Array:
        """3x3 camera matrix [[fx, 0, ppx], [0, fy, ppy], [0, 0, 1]] (OpenCV's K)."""
        return np.array([[self.fx, 0.0, self.ppx], [0.0, self.fy, self.ppy], [0.0, 0.0, 1.0]])

    @property
    def camera_params(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) as pupil-apriltags' ``detect(camera_params=...)`` wants them."""
        return (self.fx, self.fy, self.ppx, self.ppy)

    @property
    def hfov_deg(self) -> float:
        return float(np.degrees(2.0 * np.arctan2(self.width / 2.0, self.fx)))

    @property
    def vfov_deg(self) -> float:
        return float(np.degrees(2.0 * np.arctan2(self.height / 2.0, self.fy)))

    @classmethod
    def from_rs(cls, rs_intrinsics: Any) -> Intrinsics:
        """The intrinsics of a pyrealsense2 ``rs.intrinsics`` (read by attribute, no import)."""
        model = rs_intrinsics.model
        # pybind11 enums have .name; str() gives "distortion.<name>" as a fallback.
        name = getattr(model, "name", None) or str(model).rsplit(".", 1)[-1]
        # Five coefficients, zero-padded when the SDK reports fewer.
        c = [float(v) for v in rs_intrinsics.coeffs] + [0.0] * 5
        return cls(
            width=int(rs_intrinsics.width),
            height=int(rs_intrinsics.height),
            fx=float(rs_intrinsics.fx),
            fy=float(rs_intrinsics.fy),
            ppx=float(rs_intrinsics.ppx),
            ppy=float(rs_intrinsics.ppy),
            model=name,
            coeffs=(c[0], c[1], c[2], c[3], c[4]),
        )


@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """One aligned colour + depth frame.

    ``color`` (H, W, 3) uint8 RGB; ``depth`` (H, W) float32 metres along the optical axis
    (z, not ray length), 0 where there is no measurement; ``timestamp`` seconds on the
    camera's clock (simulation time for SimCamera); ``index`` counts frames from 0.
    """

    color: NDArray[np.uint8]
    depth: NDArray[np.float32]
    intrinsics: Intrinsics
    timestamp: float
    index: int


def _check_model(intr: Intrinsics) -> None:
    if intr.model not in DISTORTION_MODELS:
        raise NotImplementedError(
            f"distortion model {intr.model!r} is not supported; use one of {DISTORTION_MODELS}"
        )


def distort(intr: Intrinsics, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    """Distorted normalised image coordinates of undistorted ones (x = X/Z, y = Y/Z).

    The distortion step of librealsense's ``rs2_project_point_to_pixel``; with
    r^2 = x^2 + y^2, f = 1 + k1 r^2 + k2 r^4 + k3 r^6:

    - brown_conrady: x' = f x + 2 p1 x y + p2 (r^2 + 2 x^2), y' = f y + 2 p2 x y + p1 (r^2 + 2 y^2)
    - inverse/modified_brown_conrady: the same with x, y replaced by f x, f y in the tangential
      terms (but not in r^2)
    - kannala_brandt4: theta = atan(r), x' = x theta (1 + k1 th^2 + ... + k4 th^8) / r
    - ftheta: x' = x atan(2 r tan(w / 2)) / (w r)
    """
    xu = np.asarray(x, dtype=float)
    yu = np.asarray(y, dtype=float)
    model = intr.model
    if model == "none":  # the common case first: no coefficients to read
        return xu, yu
    _check_model(intr)
    k1, k2, p1, p2, k3 = (float(c) for c in intr.coeffs)
    if model in ("brown_conrady", "inverse_brown_conrady", "modified_brown_conrady"):
        r2 = xu * xu + yu * yu
        f = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xf, yf = xu * f, yu * f
        # librealsense's inverse/modified variants take the tangential terms of the scaled x, y.
        xt, yt = (xu, yu) if model == "brown_conrady" else (xf, yf)
        return (
            xf + 2.0 * p1 * xt * yt + p2 * (r2 + 2.0 * xt * xt),
            yf + 2.0 * p2 * xt * yt + p1 * (r2 + 2.0 * yt * yt),
        )
    if model in ("kannala_brandt4", "ftheta"):
        # librealsense clamps r at FLT_EPSILON so the optical axis maps to itself.
        r = np.maximum(np.hypot(xu, yu), _FLT_EPSILON)
        if model == "kannala_brandt4":
            theta = np.arctan(r)
            t2 = theta * theta
            rd = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (p1 + t2 * p2))))
        else:
            rd = np.arctan(2.0 * r * np.tan(k1 / 2.0)) / k1
        return xu * rd / r, yu * rd / r
    return xu, yu


def undistort(intr: Intrinsics, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    """Undistorted normalised coordinates of distorted ones, as ``rs2_deproject_pixel_to_point``.

    brown_conrady and inverse_brown_conrady: librealsense's 10 fixed-point iterations
    x <- (x_d - dx(x)) / f(x), exact inverses of :func:`distort` to float precision for real
    lens coefficients. kannala_brandt4: up to 4 Newton steps on theta, then r = tan(theta).
    ftheta: r = tan(w r_d) / atan(2 tan(w / 2)). none and modified_brown_conrady: unchanged.
    """
    _check_model(intr)
    x_d = np.asarray(x, dtype=float)
    y_d = np.asarray(y, dtype=float)
    k1, k2, p1, p2, k3 = (float(c) for c in intr.coeffs)
    model = intr.model
    if model in ("brown_conrady", "inverse_brown_conrady"):
        xu, yu = x_d, y_d
        for _ in range(_BROWN_CONRADY_ITERATIONS):
            r2 = xu * xu + yu * yu
            icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
            # inverse_brown_conrady's tangential terms act on the radially scaled point.
            xq, yq = (xu, yu) if model == "brown_conrady" else (xu / icdist, yu / icdist)
            dx = 2.0 * p1 * xq * yq + p2 * (r2 + 2.0 * xq * xq)
            dy = 2.0 * p2 * xq * yq + p1 * (r2 + 2.0 * yq * yq)
            xu, yu = (x_d - dx) * icdist, (y_d - dy) * icdist
        return xu, yu
    if model == "kannala_brandt4":
        rd = np.maximum(np.hypot(x_d, y_d), _FLT_EPSILON)
        theta = rd.copy()
        done = np.zeros(rd.shape, dtype=bool)
        for _ in range(_KANNALA_BRANDT_ITERATIONS):
            t2 = theta * theta
            f = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (p1 + t2 * p2)))) - rd
            # librealsense stops a point's Newton loop for good once |f| < FLT_EPSILON.
            done |= np.abs(f) < _FLT_EPSILON
            df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * p1 + 9.0 * t2 * p2)))
            theta = np.where(done, theta, theta - f / df)
        r = np.tan(theta)
        return x_d * r / rd, y_d * r / rd
    if model == "ftheta":
        rd = np.maximum(np.hypot(x_d, y_d), _FLT_EPSILON)
        r = np.tan(k1 * rd) / np.arctan(2.0 * np.tan(k1 / 2.0))
        return x_d * r / rd, y_d * r / rd
    return x_d, y_d


def project(intr: Intrinsics, points: ArrayLike) -> Array:
    """Pixels (N, 2) of camera-frame points (N, 3), as librealsense's rs2_project_point_to_pixel.

    u = fx x' + ppx, v = fy y' + ppy with (x', y') = :func:`distort` of (x/z, y/z); for
    model "none" simply u = fx x/z + ppx. Points at or behind the camera (z <= 0) give NaN.
    Example: ``project(intr, [[0, 0, 1]])`` is ``[[ppx, ppy]]``.
    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    uv = np.empty((len(p), 2))
    uv[:, 0], uv[:, 1] = project_xyz(intr, p[:, 0], p[:, 1], p[:, 2])
    return uv


def project_xyz(intr: Intrinsics, x: ArrayLike, y: ArrayLike, z: ArrayLike) -> tuple[Array, Array]:
    """Pixel coordinates (u, v) of camera-frame points given as coordinate arrays of any one
    (broadcast) shape, NaN where z <= 0: :func:`project`'s formula, which it calls on its
    columns; directly, dense grids of points (the liquid meter's rectified strips) need no
    (N, 3) array."""
    z = np.asarray(z, dtype=float)
    if (z > 0.0).all():  # the common case: no division to guard, nothing to blank
        xd, yd = distort(intr, np.asarray(x, dtype=float) / z, np.asarray(y, dtype=float) / z)
        return xd * intr.fx + intr.ppx, yd * intr.fy + intr.ppy
    with np.errstate(divide="ignore", invalid="ignore"):
        xd, yd = distort(intr, np.asarray(x, dtype=float) / z, np.asarray(y, dtype=float) / z)
        u = xd * intr.fx + intr.ppx
        v = yd * intr.fy + intr.ppy
    behind = z <= 0.0
    if behind.any():
        behind = np.broadcast_to(behind, u.shape)
        u, v = np.where(behind, np.nan, u), np.where(behind, np.nan, v)
    return u, v


def normalised_rays(intr: Intrinsics, uv: Array) -> tuple[Array, Array]:
    """Undistorted (x, y) = (X/Z, Y/Z) of pixels ``uv`` (N, 2)."""
    return undistort(intr, (uv[:, 0] - intr.ppx) / intr.fx, (uv[:, 1] - intr.ppy) / intr.fy)


def deproject(intr: Intrinsics, uv: ArrayLike, depth: ArrayLike) -> Array:
    """Camera-frame points (N, 3) of pixels ``uv`` (N, 2) at depths ``depth`` (N,), metres.

    As librealsense's rs2_deproject_pixel_to_point: (x, y) = :func:`undistort` of
    ((u - ppx) / fx, (v - ppy) / fy), point = (x z, y z, z); the inverse of :func:`project`
    for models none, brown_conrady, inverse_brown_conrady and kannala_brandt4.
    """
    _check_model(intr)
    pixels = np.atleast_2d(np.asarray(uv, dtype=float))
    z = np.broadcast_to(np.asarray(depth, dtype=float), (pixels.shape[0],))
    x, y = normalised_rays(intr, pixels)
    return np.column_stack([x * z, y * z, z])


@functools.lru_cache(maxsize=8)
def _image_rays(intr: Intrinsics, height: int, width: int) -> tuple[Array, Array]:
    """Undistorted (x, y) of every pixel of an image, row by row; cached, read-only."""
    v, u = np.mgrid[0:height, 0:width]
    x, y = normalised_rays(intr, np.column_stack([u.ravel(), v.ravel()]).astype(float))
    x.flags.writeable = False
    y.flags.writeable = False
    return x, y


def deproject_image(intr: Intrinsics, depth: ArrayLike) -> Array:
    """Camera-frame points (H*W, 3) of every pixel of a depth image, row by row (0 stays 0).

    Same result as :func:`deproject` on every pixel; each pixel's undistorted ray depends only
    on the intrinsics, so it is computed once per (intrinsics, image size) and cached.
    """
    _check_model(intr)
    d = np.asarray(depth, dtype=float)
    x, y = _image_rays(intr, d.shape[0], d.shape[1])
    z = d.ravel()
    return np.column_stack([x * z, y * z, z])


def pixel_box(uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """The box (..., 4) of pixels (..., N, 2): min u, min v, max u + 1, max v + 1."""
    return np.stack(
        [uv[..., 0].min(-1), uv[..., 1].min(-1), uv[..., 0].max(-1) + 1, uv[..., 1].max(-1) + 1],
        axis=-1,
    )
