"""Liquid level in a bottle from one RGB-D frame and the bottle's pixel box.

Two methods, both returning a frozen :class:`LiquidLevel`:

``method="hough"`` -- the paper's pipeline, kept as the reference: crop the box, Gaussian
blur, Sobel x and y, gradient magnitude, threshold, probabilistic Hough transform
(``cv2.HoughLinesP``), keep segments within +-10 degrees of horizontal, take the highest one as
the liquid surface and report the fill as the fraction of the box height below it. It is
fooled by anything horizontal above the liquid: the cap, the shoulder, label edges, reflections.

``method="profile"`` (default) -- measures in the bottle's own 3-D frame instead of the box:

1. **Table plane** from depth around the box (RANSAC): gives "up" and where the bottle stands.
   Assumes the bottle stands upright on an opaque surface that the depth camera sees beside it,
   and a camera not rolled by more than ~60 degrees (the table must look like a floor).
2. **Bottle axis, radius, height**: the caller's axis and height if known (an object
   detector's cylinder fit), the rest by fitting the projection of an upright bottle standing
   on the table to the box (Gauss-Newton on foot position, radius, height): off-centre bottles
   lean in the image, so the box is wider than the bottle and its centre is not the axis. The
   radius always comes from the box: a detector fits the circle of what returns depth, for a
   clear bottle its liquid or cap, short of the wall. The model's shoulder starts at
   ``body_fraction`` of the height; once step 6 has measured the shoulder the box is fitted
   again with it (a lower shoulder leans less, so the radius changes).
3. **Rectified strip**: the colour image resampled on the vertical plane through the axis
   facing the camera, in millimetre steps of height ``s`` above the table and lateral offset
   ``t``, so perspective and the lean of off-centre bottles are gone.
4. **Colour cue**: in each row the bottle's inner columns are compared with the background just
   beside the bottle in the same row; liquid differs from it, an empty clear wall barely does.
   The top surface of the liquid is an ellipse seen from above: at lateral offset ``t`` its far
   edge appears ``k * sqrt(r^2 - t^2)`` higher than the level (``k`` = tangent of the viewing
   angle below horizontal), so each column is shifted down by that before the rows are
   compared; the level is the best single step in that colour-minus-background profile
   between the base and the shoulder (liquid below it, by gravity).
   Assumes the liquid's colour differs from what is seen beside the bottle (it fails for clear
   water in front of a same-coloured background) and that the background beside the bottle
   is what is behind it.
5. **Depth cue** (:meth:`LiquidLevelMeter._depth_level`): every pixel of the box is a line of
   sight through the bottle's cylinders. One whose depth ends on the bottle says "liquid"
   below the lowest height its chord through the liquid reaches; one whose depth lies beyond
   the bottle (the table or room behind, or under a clear bottom) says "empty" there. The
   level is the best single step in the share of "liquid" rays per row. Points within
   ``wall_band`` of the outer wall's front, or above the body (a shoulder's or neck's wall),
   are no evidence: a D435 returns depth on part of a clear wall (on ClearGrasp's real frames
   ~10 % true and ~6 % 1-2 cm too far, the simulator's camera model of the cluttered profile;
   MuJoCo's plain render returns none), in blobs whatever is behind. Assumes the liquid
   returns depth (a clear liquid may let the IR pattern through: then the colour cue).
6. **Body top** (the shoulder, where the body stops being a straight cylinder;
   :meth:`LiquidLevelMeter._body_top`): the colour steps across ``t`` at the radius, on each
   side that shows the wall in the lower body; the body is the rows where every such side
   shows it, up to the best step to the rest, searched above the depth level, the height up
   to which the clear wall itself returned depth (less 5 mm) and 30 % of the height, and
   below the first stretch where no side shows even a faint step. Without a wall edge on
   either side the prior ``body_fraction`` of the height is taken, and the confidence drops.
   The fill is ``(level - base) / (body_top - base)``, the liquid height over the inner body
   height, as the simulator's ``ObjectSpec.fill``.

The two cues are fused: depth leads where it has evidence (it is metric and blind to colour),
averaged with colour (0.7 / 0.3) when they agree within ``agree_tol``; where depth has no data
at all the colour cue stands alone. **Confidence**: the share of rows the depth step explains,
times 0.8-1 by the colour step's contrast when the cues agree, 0.6 when they do not, the
colour cue's own quality times 0.5 when it stands alone, and times 0.7 when the shoulder was
not seen. On the simulator (both profiles, 200 see-through bottles) readings of confidence
0.9 and more were off by 0.8 points on average, 0.6-0.9 by 1.1, 0.5-0.6 by 2.2.

**Unknown** (``LiquidLevel.fill`` None, with the reason; never a number;
:meth:`LiquidLevelMeter._why_unseen`): when the wall is opaque (the depth camera sees the wall
at the bottle's surface over its body and its neck, or no line of sight passes the bottle
anywhere below its cap: a clear bottle always shows the room through its empty neck), when
the body is mostly hidden by something in front or outside the image, or when no upright
bottle on the table projects onto the box, or the box reaches the image's border (the fit
would take the border for the bottle's foot, side or cap).

``armvision.eval.liquid`` measures both methods, and each cue alone, on the simulator (the
figures are in the README).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, TypeVar

import cv2
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import (
    Intrinsics,
    RGBDFrame,
    deproject,
    project,
    project_xyz,
)
from armvision.errors import PerceptionError
from armvision.geometry import cross3
from armvision.perception.detection import (
    BOTTLE_BODY_FRACTION,
    Detection,
    fit_model_box,
    outline_rings,
    plane_basis,
)
from armvision.perception.fitting import fit_plane, percentile

Array = NDArray[np.float64]
Box = tuple[float, float, float, float]
Method = Literal["profile", "hough"]
_F = TypeVar("_F", bound=np.floating)
METHODS = ("profile", "hough")
#: How :attr:`LiquidLevel.unknown` begins when the wall hides the liquid.
OPAQUE = "opaque"
#: The camera's up (-y in the optical frame): the table's normal faces roughly this way.
_UP_CAM = np.array([0.0, -1.0, 0.0])


@dataclass(frozen=True, eq=False)
class LiquidLevel:
    """One liquid-level measurement, or the meter's statement that it cannot make one.

    ``fill`` 0..1: liquid height over the container's inner body height (``profile``; the
    simulator's ``ObjectSpec.fill``) or over the box height (``hough``, the paper's definition);
    None when the level is **unknown**: ``unknown`` then says why (an opaque wall, a body
    hidden or outside the image) and ``confidence`` is 0. ``level_row`` the image row of the
    liquid surface (on the bottle's axis for ``profile``; None when unknown); ``confidence``
    0..1; ``colour`` the liquid's median RGB, None when empty or unknown; ``debug`` an RGB crop
    of the box with the measurement drawn. ``level_m`` and ``body_height_m`` (``profile``
    only): the liquid surface and the body top (the shoulder) above the table, metres (the
    body top the box fit's shoulder prior when the first look found the wall opaque);
    ``level_colour_m`` and ``level_depth_m`` what each cue alone said (None: no evidence).
    """

    fill: float | None
    level_row: float | None
    confidence: float
    colour: tuple[int, int, int] | None
    method: str
    debug: NDArray[np.uint8] = field(repr=False)
    level_m: float | None = None
    body_height_m: float | None = None
    level_colour_m: float | None = None
    level_depth_m: float | None = None
    unknown: str | None = None

    @property
    def known(self) -> bool:
        """Whether the meter read a level (``fill`` is a number)."""
        return self.fill is not None

    @property
    def opaque(self) -> bool:
        """Unknown because the wall hides the liquid (no other view will show it)."""
        return self.unknown is not None and self.unknown.startswith(OPAQUE)


@dataclass(frozen=True)
class ContainerGeometry:
    """What an object detector may know about the container, camera frame, metres.

    ``centre_cam``: any point on the container's axis (the cylinder fit's centre); ``radius``
    the outer radius; ``height`` the whole height, cap included; ``table`` the plane it
    stands on, (up, offset) with ``up . p + offset = 0`` and ``up`` toward the camera (the
    geometric detector's RANSAC plane over the whole table: the meter then skips its own
    fit around the box). Each may be None.
    """

    centre_cam: tuple[float, float, float] | None = None
    radius: float | None = None
    height: float | None = None
    table: tuple[tuple[float, float, float], float] | None = None

    @classmethod
    def of(
        cls, det: Detection, radius: float | None = None, height: float | None = None
    ) -> ContainerGeometry:
        """What ``det`` knows of an upright container (``radius``/``height`` override its
        own): its centre, size and, when it has an axis (the table normal), the table plane
        through its foot."""
        radius = det.radius if radius is None else radius
        height = det.height if height is None else height
        centre = np.asarray(det.center_cam, dtype=float)
        table = None
        if det.axis_cam is not None:
            up = np.asarray(det.axis_cam, dtype=float)
            foot = centre - 0.5 * det.height * up
            table = ((float(up[0]), float(up[1]), float(up[2])), float(-up @ foot))
        c = (float(centre[0]), float(centre[1]), float(centre[2]))
        return cls(c, radius, height, table)


def _check_inputs(frame: RGBDFrame, box: ArrayLike) -> tuple[int, int, int, int]:
    """Integer box clipped to the image; PerceptionError for a bad image or an empty box."""
    color = np.asarray(frame.color)
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise PerceptionError(
            f"liquid level needs an (H, W, 3) uint8 RGB image, got {color.shape} {color.dtype}"
        )
    b = np.asarray(box, dtype=float).ravel()
    if b.size != 4 or not np.all(np.isfinite(b)):
        raise PerceptionError(f"the container box must be (x0, y0, x1, y1) pixels, got {box!r}")
    h, w = color.shape[:2]
    x0, y0 = max(math.floor(b[0]), 0), max(math.floor(b[1]), 0)
    x1, y1 = min(math.ceil(b[2]), w), min(math.ceil(b[3]), h)
    if x1 - x0 < 4 or y1 - y0 < 8:
        raise PerceptionError(
            f"the container box {tuple(b)} covers {max(x1 - x0, 0)}x{max(y1 - y0, 0)} pixels of"
            f" the {w}x{h} image; it needs at least 4x8: is it inside the image, as x0, y0, x1, y1?"
        )
    return x0, y0, x1, y1


def _border_cut(intr: Intrinsics, box: Box, top_known: bool, margin: float = 1.0) -> str | None:
    """Which image border the box reaches (within ``margin`` px), if any: "bottom", "left",
    "right" or, unless the caller knows the bottle's height, "top"."""
    x0, y0, x1, y1 = box
    for name, reached in (
        ("bottom", y1 >= intr.height - margin),
        ("left", x0 <= margin),
        ("right", x1 >= intr.width - margin),
        ("top", y0 <= margin and not top_known),
    ):
        if reached:
            return name
    return None


def _rgb_length(d: NDArray[np.float32]) -> NDArray[np.float32]:
    """Euclidean length of RGB differences (..., 3): ``np.linalg.norm(d, axis=-1)``, the same
    sums in the same order, without its slow reduction along a 3-long axis (~8x faster on
    the meter's strips)."""
    sq = d * d
    return np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])


#: Relative slack on squared distances that rounding cannot exceed (a^2 + b^2 is within a
#: few ulp, ~1e-15, of the exact square of the correctly rounded hypot): a cheap superset test
#: before the hypot.
_SQ_SLACK = 1e-9


def _median(a: NDArray[_F], axis: int) -> NDArray[_F]:
    """``np.median(a, axis)`` of an array without NaN, by one partition: the same values
    (the middle one, or the mean of the two middle ones) without ``np.median``'s overhead,
    which dominates on the meter's small per-row medians (~2-5x faster there)."""
    n = a.shape[axis]
    if n == 0:
        return np.median(a, axis=axis)  # NaN, with numpy's warning
    k = n // 2
    if n % 2:
        return np.partition(a, k, axis=axis).take(k, axis=axis)
    part = np.partition(a, (k - 1, k), axis=axis)
    return (part.take(k - 1, axis=axis) + part.take(k, axis=axis)) / 2


def _linspace(start: float, stop: float, num: int) -> Array:
    """``np.linspace(start, stop, num)`` of two numbers (``num`` >= 2): its own sums (``arange
    * step + start``, the last set to ``stop``) without its overhead (~4 us a call)."""
    y = np.arange(num, dtype=float) * ((stop - start) / (num - 1)) + start
    y[-1] = stop
    return y


def _clamp(x: float, lo: float, hi: float) -> float:
    """``float(np.clip(x, lo, hi))`` of one number, without np.clip's overhead."""
    return float(min(max(x, lo), hi))


def _median_rgb(pixels: NDArray[np.floating]) -> tuple[int, int, int]:
    """The per-channel median of RGB pixels (..., 3), as integers."""
    r, g, b = (int(c) for c in _median(pixels.reshape(-1, 3), axis=0))
    return r, g, b


# --------------------------------------------------------------------------- the paper: Hough


def hough_level(
    frame: RGBDFrame,
    box: ArrayLike,
    blur_ksize: int = 5,
    magnitude_threshold: float = 60.0,
    hough_votes: int = 20,
    min_line_fraction: float = 0.3,
    max_line_gap: int = 5,
    max_angle_deg: float = 10.0,
) -> LiquidLevel:
    """The paper's liquid level: the highest near-horizontal Hough segment in the box.

    Gaussian blur (``blur_ksize``), Sobel x and y (3x3), magnitude ``sqrt(gx^2 + gy^2)``,
    binary edges where it exceeds ``magnitude_threshold`` grey levels per pixel,
    ``cv2.HoughLinesP(rho=1, theta=1 deg, threshold=hough_votes, minLineLength =
    min_line_fraction * box width, maxLineGap=max_line_gap)``, segments within
    ``max_angle_deg`` of horizontal; fill = (box bottom - highest segment) / box height. The
    tuning values are ours (the paper does not give them). No segment: fill 0, confidence 0.
    """
    x0, y0, x1, y1 = _check_inputs(frame, box)
    crop = np.ascontiguousarray(frame.color[y0:y1, x0:x1])
    grey = cv2.cvtColor(crop, cv2.COLOR_RGB2GRAY)
    k = blur_ksize | 1  # Gaussian kernels must be odd
    grey = cv2.GaussianBlur(grey, (k, k), 0)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    edges = (cv2.magnitude(gx, gy) > magnitude_threshold).astype(np.uint8) * 255
    h, w = grey.shape
    lines = cv2.HoughLinesP(
        edges,
        rho=1,
        theta=math.pi / 180.0,
        threshold=hough_votes,
        minLineLength=max(min_line_fraction * w, 3.0),
        maxLineGap=max_line_gap,
    )
    debug = crop.copy()
    if lines is None:
        return LiquidLevel(0.0, float(y1), 0.0, None, "hough", debug)
    # (N, 1, 4) in OpenCV 4, (N, 4) in OpenCV 5: x_a, y_a, x_b, y_b
    seg = lines.reshape(-1, 4).astype(float)
    angle = np.degrees(np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0]))
    angle = (angle + 90.0) % 180.0 - 90.0  # direction-free: -90..90, 0 = horizontal
    flat = seg[np.abs(angle) <= max_angle_deg]
    if len(flat) == 0:
        return LiquidLevel(0.0, float(y1), 0.0, None, "hough", debug)
    mid_y = 0.5 * (flat[:, 1] + flat[:, 3])
    best = flat[int(np.argmin(mid_y))]  # the highest line is the level
    row = float(mid_y.min())
    fill = float(np.clip((h - row) / h, 0.0, 1.0))
    length = float(np.hypot(best[2] - best[0], best[3] - best[1]))
    below = crop[int(row) + 1 :, max(int(0.3 * w), 0) : max(int(0.7 * w), 1)]
    # (np.median of integers takes the mean of the middle two in float64, as this does)
    colour = _median_rgb(below.astype(np.float64)) if below.size else None
    for x_a, y_a, x_b, y_b in flat.astype(int):
        cv2.line(debug, (x_a, y_a), (x_b, y_b), (0, 160, 255), 1)
    cv2.line(debug, (0, round(row)), (w - 1, round(row)), (255, 0, 0), 1)
    return LiquidLevel(
        fill=fill,
        level_row=y0 + row,
        confidence=float(min(1.0, length / w)),
        colour=colour,
        method="hough",
        debug=debug,
    )


# --------------------------------------------------------------------------- 3-D helpers


def _ray(intr: Intrinsics, u: float, v: float) -> Array:
    """Direction (x, y, 1) of the ray through pixel (u, v)."""
    return deproject(intr, [[u, v]], [1.0])[0]


def _ray_plane(ray: Array, normal: Array, offset: float) -> Array:
    """Where the ray from the camera centre along ``ray`` meets ``normal . p + offset = 0``."""
    denom = float(normal @ ray)
    if abs(denom) < 1e-9:
        raise PerceptionError("the bottle's foot is on the horizon: tilt the camera down")
    return ray * (-offset / denom)


def _step_split(is_liquid: NDArray[np.bool_]) -> tuple[int, int]:
    """Best split k of rows (bottom first) into liquid [0, k) and empty [k, N).

    Cost(k) = empty rows below k + liquid rows from k on, for every k in 0..N at once by
    cumulative sums; among equal costs the middle one, so a run of ambiguous rows is split
    evenly. Returns (k, cost).
    """
    n = len(is_liquid)
    liquid = np.zeros(n + 1, dtype=np.intp)  # liquid rows below k
    np.cumsum(is_liquid, out=liquid[1:])
    cost = np.arange(n + 1) + liquid[-1] - 2 * liquid
    low = cost.min()
    best = (cost == low).nonzero()[0]
    return int(best[len(best) // 2]), int(low)


# --------------------------------------------------------------------------- default: profile


#: cos and sin of :func:`unit_ring`'s default 24 angles, (24, 1): computed once.
_RING_ANGLES = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
_RING_COS, _RING_SIN = np.cos(_RING_ANGLES)[:, None], np.sin(_RING_ANGLES)[:, None]


def unit_ring(up: ArrayLike, n: int = 24) -> Array:
    """``n`` points (n, 3) on the unit circle around the axis ``up``."""
    return _ring(*plane_basis(up), n)


def _ring(e1: Array, e2: Array, n: int = 24) -> Array:
    """:func:`unit_ring` of the plane basis (e1, e2) of its axis."""
    if n == 24:
        return _RING_COS * e1 + _RING_SIN * e2
    ang = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2


def bottle_outline(
    foot: ArrayLike,
    up: ArrayLike,
    radius: ArrayLike,
    height: ArrayLike,
    body_fraction: float,
    ring: Array | None = None,
) -> Array:
    """Points (..., 72, 3) outlining the model bottle standing at ``foot`` along ``up``: rings
    of 24 at the foot, the shoulder and the top. Leading dimensions of ``foot``, ``radius`` and
    ``height`` broadcast (the meter fits many parameter sets at once); ``ring``, the
    :func:`unit_ring` around ``up`` if the caller has it already."""
    ring = unit_ring(up) if ring is None else ring
    up = np.asarray(up, dtype=float)

    def ring_axis(a: ArrayLike) -> Array:
        """``a`` with an axis for the three rings before its (point, xyz) axes."""
        a = np.asarray(a, dtype=float)
        return a[..., None, :, :] if a.ndim >= 2 else a

    # All three rings at once, (..., ring, point, xyz): foot + (frac h) up + (scale r) ring.
    frac, scale = (a[:, None, None] for a in outline_rings(body_fraction))
    pts = ring_axis(foot) + (frac * ring_axis(height)) * up + (scale * ring_axis(radius)) * ring
    return pts.reshape(*pts.shape[:-3], -1, 3)


@dataclass(frozen=True)
class _Frame3D:
    """The bottle's frame in the camera frame: foot on the table, up, away, lateral."""

    foot: Array
    up: Array
    away: Array
    lateral: Array
    radius: float
    top: float  # whole height above the table, metres
    misfit_px: float = 0.0  # how far the fitted bottle's projected box is from the box

    def points(self, s: Array, t: Array | float, a: Array | float = 0.0) -> Array:
        """Camera-frame points at height s, lateral t, away a (broadcast arrays)."""
        s, t, a = np.asarray(s, float), np.asarray(t, float), np.asarray(a, float)
        return (
            self.foot
            + s[..., None] * self.up
            + t[..., None] * self.lateral
            + a[..., None] * self.away
        )


#: cos and sin of the debug image's rings' 48 angles (closed: the last is the first).
_DEBUG_COS = np.cos(np.linspace(0.0, 2.0 * math.pi, 48))
_DEBUG_SIN = np.sin(np.linspace(0.0, 2.0 * math.pi, 48))
#: The colour cue's inner columns across the liquid's width (within 0.7 of its radius).
_INNER_COLUMNS = 15
#: The lines of sight the meter looks at pass within this share of the radius from the
#: bottle's axis (the widest any cue asks for: :meth:`LiquidLevelMeter._why_unseen`'s body).
_RAY_MISS = 0.8


@dataclass(frozen=True)
class _Rays:
    """The lines of sight of a bottle's box that pass within :data:`_RAY_MISS` of the radius
    from its axis, one entry per pixel (row by row), against its cylinders.

    ``s_low``: the lowest height (above the table, never below the base) of the ray's chord
    through the liquid's cylinder (nan where it misses it); ``height``: the height of its
    depth's point (a number, meaningless, where not ``valid``); ``s_axis``: the height where it
    passes the axis closest; ``miss``: that closest distance over the radius; ``valid``: the
    pixel has depth; ``on_bottle``: its point lies on or in the bottle (within the radius +
    ``surface_tol``, above the base, below the top); ``before``: it lies nearer than the
    bottle's front by ``occluder_m`` (something in front); ``hits_liquid_cylinder``.
    """

    s_low: Array
    height: Array
    s_axis: Array
    miss: Array
    valid: NDArray[np.bool_]
    on_bottle: NDArray[np.bool_]
    before: NDArray[np.bool_]
    at_wall: NDArray[np.bool_]
    hits_liquid_cylinder: NDArray[np.bool_]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _rays_kernel(
    depth: NDArray[np.floating],
    box: NDArray[np.int64],
    stride: int,
    camera: Array,
    axes: Array,
    sizes: Array,
) -> tuple[
    Array,
    Array,
    Array,
    Array,
    NDArray[np.bool_],
    NDArray[np.bool_],
    NDArray[np.bool_],
    NDArray[np.bool_],
    NDArray[np.bool_],
]:
    """:meth:`LiquidLevelMeter._rays`, compiled (a per-pixel loop; as numpy calls it was a
    tenth of a cluttered frame's perception): the fields of :class:`_Rays`, in order.

    ``box`` (x0, y0, x1, y1), ``camera`` (ppx, ppy, fx, fy), ``axes`` the rows away,
    lateral, up and foot of the bottle's frame, ``sizes`` its radius, the liquid's radius,
    its top, then the meter's base, surface_tol, occluder_m and wall_band. The ray (x, y, 1)
    of a pixel has depth z as its parameter; its horizontal offset from the axis is
    (z da - fa, z dl - fl), whose square is qa z^2 - 2 half_b z + c0."""
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    ppx, ppy, fx, fy = camera[0], camera[1], camera[2], camera[3]
    radius, r_liq, top = sizes[0], sizes[1], sizes[2]
    base, surface_tol, occluder_m, wall_band = sizes[3], sizes[4], sizes[5], sizes[6]
    fa = axes[3, 0] * axes[0, 0] + axes[3, 1] * axes[0, 1] + axes[3, 2] * axes[0, 2]
    fl = axes[3, 0] * axes[1, 0] + axes[3, 1] * axes[1, 1] + axes[3, 2] * axes[1, 2]
    fu = axes[3, 0] * axes[2, 0] + axes[3, 1] * axes[2, 1] + axes[3, 2] * axes[2, 2]
    c0 = fa * fa + fl * fl
    rows = len(range(y0, y1, stride))
    cols = len(range(x0, x1, stride))
    n = rows * cols
    s_low, height, s_axis, miss = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    valid, on_bottle = np.empty(n, np.bool_), np.empty(n, np.bool_)
    before, at_wall, hit_liq = np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n, np.bool_)
    radii2 = (radius * radius, r_liq * r_liq)
    near_limit = radius + surface_tol
    near2 = near_limit * near_limit
    xs = np.empty(cols)
    for k, u in enumerate(range(x0, x1, stride)):
        xs[k] = (u - ppx) / fx
    count = 0
    for v in range(y0, y1, stride):
        y = (v - ppy) / fy
        for k, u in enumerate(range(x0, x1, stride)):
            x = xs[k]
            da = y * axes[0, 1] + (x * axes[0, 0] + axes[0, 2])
            dl = y * axes[1, 1] + (x * axes[1, 0] + axes[1, 2])
            du = y * axes[2, 1] + (x * axes[2, 0] + axes[2, 2])
            qa = da * da + dl * dl
            half_b = da * fa + dl * fl
            z_near = half_b / qa
            off_a, off_l = z_near * da - fa, z_near * dl - fl
            # Every use of a ray asks for one passing near the axis: the rest are dropped.
            m = math.sqrt(off_a * off_a + off_l * off_l) / radius
            if not m < _RAY_MISS:
                continue
            z = float(depth[v, u])
            # The chord equation qa z^2 + qb z + c0 = R^2 with -qb = 2 half_b, for the outer
            # cylinder and the liquid's: the root of its discriminant, and hit.
            neg_qb = 2.0 * half_b
            qb2, qa2, qa4 = neg_qb * neg_qb, 2.0 * qa, 4.0 * qa
            disc = qb2 - qa4 * (c0 - radii2[0])
            disc_liq = qb2 - qa4 * (c0 - radii2[1])
            # The outer cylinder's front (inf where the ray misses it).
            front = (neg_qb - math.sqrt(max(disc, 0.0))) / qa2 if disc > 0 else np.inf
            # The liquid chord's lower end: its near end on a ray rising away from the camera
            # (du >= 0), else its far end.
            z_low = (neg_qb - math.copysign(math.sqrt(max(disc_liq, 0.0)), du)) / qa2
            low = z_low * du - fu
            s_low[count] = (low if low > base else base) if disc_liq > 0 else np.nan
            h = z * du - fu
            ok = z > 0
            a, b = z * da - fa, z * dl - fl
            on = ok and h > base + 0.002 and h < top + surface_tol
            if on:  # within the radius: hypot (slow) only where the squares cannot tell
                sq = a * a + b * b
                if abs(sq - near2) <= near2 * _SQ_SLACK:
                    on = math.hypot(a, b) < near_limit
                else:
                    on = sq < near2
            height[count], s_axis[count], miss[count] = h, z_near * du - fu, m
            valid[count], on_bottle[count], hit_liq[count] = ok, on, disc_liq > 0
            before[count] = ok and not on and z < front - occluder_m
            # A point within wall_band of the outer front surface may be the wall itself.
            at_wall[count] = on and z < front + wall_band
            count += 1
    return (
        s_low[:count],
        height[:count],
        s_axis[:count],
        miss[:count],
        valid[:count],
        on_bottle[:count],
        before[:count],
        at_wall[:count],
        hit_liq[:count],
    )


@functools.cache
def compile_rays() -> None:
    """Compile :func:`_rays_kernel` for the depth types cameras give (float32 metres, and
    float64) once per process, from Numba's on-disk cache after the first time (a few
    seconds then, when ``make setup`` does it): a meter's first bottle is then not late."""
    box, camera = np.array([0, 0, 2, 2]), np.array([1.0, 1.0, 600.0, 600.0])
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.2, 0.6]])
    sizes = np.array([0.03, 0.028, 0.2, 0.002, 0.004, 0.015, 0.008])
    for dtype in (np.float32, np.float64):
        _rays_kernel(np.ones((2, 2), dtype), box, 1, camera, axes, sizes)


class LiquidLevelMeter:
    """Measures the liquid level of upright bottles; every tuning value a named argument.

    ``method``: "profile" (default, see the module docstring) or "hough" (the paper's).
    ``base``: the bottle's bottom thickness under the liquid, m (the fill is measured from it).
    ``wall``: the gap between the outer wall and the liquid, m. ``body_fraction``: only the
    box fit's first model of the bottle and the last resort when no side of the body shows a
    silhouette edge (then the confidence drops); the shoulder is otherwise measured.
    ``step_m``: sampling step of the rectified strip and of the depth rows, m.

    Colour: ``colour_threshold``, RGB distance between liquid and empty rows
    (:meth:`_colour_step`); ``agree_tol``, the colour and depth levels agree within this, m.
    Depth (:meth:`_depth_level`): ``min_depth_points``, fewer usable rays than this is no
    depth evidence; ``liquid_share``, the share of rays ending on the bottle that makes a row
    liquid; ``wall_band``, a point within this of the outer wall's front may be the wall
    itself, m; ``surface_tol``, slack of "on the bottle" beyond the radius, m.
    Shoulder (:meth:`_body_top`): ``edge_threshold``, RGB distance by which the silhouette
    step must beat the background's; ``edge_band_in`` / ``edge_band_out``, the band around
    the radius where it is looked for, m; ``liquid_edge_in``, how far inside the wall the
    liquid's edge may show instead (a glass wall's thickness and the liquid's gap to it:
    3.5 mm on the simulated wine bottles), m; ``gap_m``, a stretch this long without a step
    ends the body; ``min_body_fraction``, the body is at least this share of the height; ``cap_m``,
    a depth level within this of the top means no ray passed the bottle (a cap and what
    stands on it are shorter), m. Unknown (:meth:`_why_unseen`): ``opaque_share``, the share
    of the body's and the neck's rays ending on the bottle that makes a wall opaque;
    ``min_body_seen``, the share of the body inside the image and not hidden;
    ``occluder_m``, how much nearer than the bottle's front a point is "in front", m;
    ``max_misfit``, how far the fitted bottle's projected box may be from the box, as a share
    of its width (a detector's box, with its centre and height fixed, is off by ~10 %).
    ``seed``: the table plane's RANSAC.
    """

    def __init__(
        self,
        method: Method = "profile",
        base: float = 0.003,
        wall: float = 0.002,
        body_fraction: float = BOTTLE_BODY_FRACTION,
        step_m: float = 0.001,
        colour_threshold: float = 30.0,
        agree_tol: float = 0.008,
        min_depth_points: int = 25,
        edge_threshold: float = 5.0,
        liquid_share: float = 0.6,
        opaque_share: float = 0.7,
        min_body_seen: float = 0.6,
        surface_tol: float = 0.005,
        occluder_m: float = 0.015,
        wall_band: float = 0.003,
        edge_band_in: float = 0.0035,
        liquid_edge_in: float = 0.006,
        edge_band_out: float = 0.004,
        gap_m: float = 0.006,
        min_body_fraction: float = 0.3,
        cap_m: float = 0.03,
        max_misfit: float = 0.3,
        seed: int = 0,
    ) -> None:
        if method not in METHODS:
            raise PerceptionError(f"liquid method must be one of {METHODS}, not {method!r}")
        self.method: Method = method
        self.base, self.wall, self.body_fraction = base, wall, body_fraction
        self.step_m, self.colour_threshold = step_m, colour_threshold
        self.agree_tol, self.min_depth_points = agree_tol, min_depth_points
        self.edge_threshold = edge_threshold
        self.liquid_share, self.opaque_share = liquid_share, opaque_share
        self.min_body_seen, self.surface_tol = min_body_seen, surface_tol
        self.occluder_m = occluder_m
        self.wall_band, self.gap_m = wall_band, gap_m
        self.min_body_fraction, self.cap_m = min_body_fraction, cap_m
        self.max_misfit = max_misfit
        self.edge_band_in, self.edge_band_out = edge_band_in, edge_band_out
        self.liquid_edge_in = liquid_edge_in
        self._rng = np.random.default_rng(seed)
        compile_rays()
        # The last table normal's plane basis and unit ring: every bottle on one table (all
        # of a frame's, from one detector) and both box fits of a bottle share them.
        self._basis_key: bytes | None = None
        self._basis: tuple[Array, Array, Array] = (_UP_CAM, _UP_CAM, _UP_CAM)

    def measure(
        self,
        frame: RGBDFrame,
        box: ArrayLike,
        geometry: ContainerGeometry | None = None,
    ) -> LiquidLevel:
        """The liquid level of the container in pixel ``box`` (x0, y0, x1, y1) of ``frame``."""
        if self.method == "hough":
            return hough_level(frame, box)
        return self._profile(frame, box, geometry or ContainerGeometry())

    # ---------------------------------------------------------------- profile steps

    def _table(self, frame: RGBDFrame, box: Box) -> tuple[Array, float]:
        """The table plane (up, offset: ``up . p + offset = 0``) from depth around the box."""
        intr = frame.intrinsics
        x0, y0, x1, y1 = (round(v) for v in box)
        bw, bh = x1 - x0, y1 - y0
        H, W = frame.depth.shape
        # The table around the bottle's foot: a band as high as half the box, 1 box width to
        # each side; the bottle itself is no plane, so RANSAC ignores it.
        ra, rb = max(y1 - bh // 2, 0), min(y1 + bh // 3, H)
        ca, cb = max(x0 - bw, 0), min(x1 + bw, W)
        depth = frame.depth[ra:rb:3, ca:cb:3]  # every 3rd pixel is plenty for a plane
        vv, uu = np.nonzero(depth > 0)
        if len(vv) < 30:
            raise PerceptionError(
                "no depth around the container's foot to find the table: is the depth stream"
                " aligned to colour and the table in range? (or use method='hough')"
            )
        uv = np.column_stack([uu * 3 + ca, vv * 3 + ra]).astype(float)
        pts = deproject(intr, uv, depth[vv, uu])
        # RANSAC on at most 1500 points (keeps this ~1 ms), counting only planes within 60° of
        # the camera's up (-y), so walls and the bottle's own front are not taken for the
        # table; then least-squares refits on the inliers, the second among all the points.
        table = fit_plane(
            pts,
            0.006,
            rng=self._rng,
            hypotheses=64,
            normal_prior=_UP_CAM,
            max_tilt_rad=math.acos(0.5),
            max_scored=1500,
            refits=2,
            toward=_UP_CAM,
        )
        if table is None or table.fitted < 20:
            raise PerceptionError(
                "no table plane in the depth around the container: the container must stand"
                " on a flat surface the camera sees (or use method='hough')"
            )
        return table.normal, float(table.offset)

    def _bottle_frame(
        self,
        frame: RGBDFrame,
        box: Box,
        geometry: ContainerGeometry,
        table: tuple[Array, float],
        body_fraction: float,
    ) -> _Frame3D:
        """The bottle standing on ``table``: foot, axis, radius and height (see the module's
        step 2); the box fit models the body as ``body_fraction`` of the height."""
        intr = frame.intrinsics
        x0, y0, x1, y1 = (round(v) for v in box)
        bw = x1 - x0
        up, offset = table
        # The camera's foot on the table; "away" is horizontal from it towards the bottle.
        cam_foot = -offset * up
        if geometry.centre_cam is not None:
            c = np.asarray(geometry.centre_cam, dtype=float)
            foot = c - (up @ c + offset) * up
        else:
            # First guess: the box's bottom-centre pixel on the table (the front of the foot).
            foot = _ray_plane(_ray(intr, 0.5 * (x0 + x1 - 1), y1 - 0.5), up, offset)
        radius = geometry.radius if geometry.radius is not None else 0.5 * bw * foot[2] / intr.fx
        top = geometry.height
        if top is None:
            ray = _ray(intr, 0.5 * (x0 + x1 - 1), y0 + 0.5)
            q = ray * ((foot - cam_foot) @ foot / ((foot - cam_foot) @ ray))
            top = float(up @ (q - foot))
        # The radius is always fitted to the box (a given one is the first guess): an object
        # detector fits the circle of what returns depth, which for a clear bottle is its
        # liquid or cap, short of the wall whose silhouette the box and the shoulder follow.
        free = (geometry.centre_cam is None, True, geometry.height is None)
        misfit = 0.0
        if any(free):
            foot, radius, top, misfit = self._fit_box(
                intr, box, up, offset, foot, radius, top, free, body_fraction
            )
        away = foot - cam_foot
        away -= (away @ up) * up
        away /= np.linalg.norm(away)
        lateral = cross3(away, up)  # away x up: image right for an upright camera
        if not 0.02 < top < 1.0:
            raise PerceptionError(
                f"the container box spans {top:.3f} m of height above the table; expected a"
                " bottle 0.02-1 m tall: does the box contain one upright bottle?"
            )
        return _Frame3D(foot, up, away, lateral, float(radius), top, misfit)

    def _table_basis(self, up: Array) -> tuple[Array, Array, Array]:
        """:func:`plane_basis` and :func:`unit_ring` of the table normal ``up``, kept for the
        next call with the same normal (read-only arrays)."""
        key = up.tobytes()
        if key != self._basis_key:
            e1, e2 = plane_basis(up)
            ring = _ring(e1, e2)
            for a in (e1, e2, ring):
                a.flags.writeable = False
            self._basis_key, self._basis = key, (e1, e2, ring)
        return self._basis

    def _fit_box(
        self,
        intr: Intrinsics,
        box: Box,
        up: Array,
        offset: float,
        foot: Array,
        radius: float,
        top: float,
        free: tuple[bool, bool, bool],
        body_fraction: float,
    ) -> tuple[Array, float, float, float]:
        """Foot, radius and height of an upright bottle whose projection fills ``box``, and
        the largest difference left between its projected box and ``box`` (pixels).

        The bottle is modelled as a cylinder of ``radius`` up to ``body_fraction`` of its
        height and a cap of half the radius at the top; its projected bounding box (min u,
        min v, max u + 1, max v + 1) is matched to ``box`` by Gauss-Newton on the free
        parameters (foot on the table: 2, radius, height). This undoes the lean of bottles
        off the image centre, which widens the box beyond the bottle's own width.
        """
        e1, e2, ring = self._table_basis(up)
        p, misfit = fit_model_box(
            intr,
            box,
            foot,
            up,
            e1,
            e2,
            ring,
            outline_rings(body_fraction),
            np.array([0.0, 0.0, radius, top]),
            (free[0], free[0], free[1], free[2]),
        )
        return foot + p[0] * e1 + p[1] * e2, float(p[2]), float(p[3]), misfit

    def _strip(
        self, frame: RGBDFrame, bf: _Frame3D, s: Array, t: Array, shift: Array | None = None
    ) -> NDArray[np.float32]:
        """Colour (len(s), len(t), 3) sampled on the axis plane; rows ``s`` up, shift per cell."""
        ss = s[:, None] if shift is None else s[:, None] + shift
        foot, up, lateral = (a[:, None, None] for a in (bf.foot, bf.up, bf.lateral))
        x, y, z = foot + ss * up + t * lateral  # (xyz, row, column)
        u, v = project_xyz(frame.intrinsics, x, y, z)
        map_x = u.astype(np.float32)
        map_y = v.astype(np.float32)
        return cv2.remap(
            frame.color, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        ).astype(np.float32)

    def _depression_tan(self, bf: _Frame3D, s: Array) -> Array:
        """tan of the viewing angle below horizontal at height s on the axis (camera at 0)."""
        to_cam = -bf.points(s, 0.0)
        return (to_cam @ bf.up) / np.maximum(-(to_cam @ bf.away), 1e-9)

    def _body_top(
        self,
        frame: RGBDFrame,
        bf: _Frame3D,
        s: Array,
        floor: float,
        search_wall: bool = False,
        empty_from: float | None = None,
    ) -> tuple[float, bool]:
        """Height of the shoulder: the top of the body's straight silhouette edges.

        In the rectified strip (columns inside the radius shifted down by
        ``k sqrt(r^2 - t^2)``, as the body's top rim is an ellipse like the liquid's surface)
        the colour step across ``t`` (RGB distance between neighbouring columns) is found on
        each side between ``r - edge_band_in`` and ``r + edge_band_out``: there lie the outer
        wall's silhouette and, below the level, the liquid's (a wall's thickness inside). The
        strongest step 1 mm either side of that band must fall inside it (a step rising
        towards the band's end belongs to a shoulder or a neck) and beat the background's
        steps further out (1.2-1.5 r, median) by ``edge_threshold``. A side counts if it
        shows the wall on at least 40 % of the lowest third of the rows (a clear wall before a
        background of its own colour shows none), and a row is body where every counted side
        shows it: background edges rarely line up on both sides at the bottle's radius. The
        body top is the best single step from body rows (below) to the rest
        (:func:`_step_split`) between 8 mm above the table and 10 mm below the top. Behind
        thick glass the liquid's edge stands further in than the band reaches (3.5 mm on the
        simulated wine bottles) and is the stronger step in the lowest third, so no side
        counted and the body took the prior, 2-3 cm too high on a wine bottle. Then a side
        counts if the wall's or the liquid's edge (down to ``liquid_edge_in`` inside the wall)
        shows on 40 % of the lowest third, provided :meth:`_wall_offsets` finds a silhouette
        beside the body where the wall shows alone (the empty body above the first depth
        level, else the lowest third) and the body rows found above the floor span
        ``gap_m``: a faint wall showing only its liquid would end the body at the liquid's
        surface. Returns (height, found); with no side showing the wall, ``body_fraction`` of
        the height, a prior, and found False. ``search_wall`` (a detector's geometry): the band is
        centred on each side's wall as :meth:`_wall_offsets` finds it in the empty body just
        above ``empty_from`` (the first depth level), else in the lowest third.
        """
        r = bf.radius
        start = int(s.searchsorted(self.base + 0.005))
        stop = int(s.searchsorted(bf.top - 0.01))
        if stop - start < 10:
            return self.body_fraction * bf.top, False
        lowest = slice(start, start + (stop - start) // 3)
        first = max(int(s.searchsorted(floor)), start)
        # Where the wall's silhouette shows alone: the empty body above the first depth
        # level (below it the liquid's own edge, a wall's thickness inside, is the
        # stronger), at most 4 cm of it and below 55 % of the height (no shoulder yet);
        # a bottle full to there: the lowest third.
        wall_rows = s[lowest][::2]
        if empty_from is not None:
            top_row = min(empty_from + 0.04, 0.55 * bf.top)
            upper = s[(s > empty_from + 0.005) & (s < top_row)][::2]
            if len(upper) >= 8:
                wall_rows = upper
        walls: tuple[float, float] = (r, r)
        wall_seen: bool | None = None  # whether the wall shows there; asked when needed
        if search_wall:
            seen = self._wall_offsets(frame, bf, wall_rows)
            walls, wall_seen = seen or walls, seen is not None
        # The strip at 0.5 mm steps, sampled where it matters only: on each side the band
        # around that side's wall and 1 mm beyond it, and the background 1.2-1.5 times as far.
        grid = np.arange(-1.5 * r, 2.0 * r, 0.0005)  # the phase of the validated sampling

        def within(lo: float, hi: float) -> Array:
            """The grid's values strictly between ``lo`` and ``hi`` (it is increasing)."""
            return grid[grid.searchsorted(lo, "right") : grid.searchsorted(hi, "left")]

        runs, bands = [], []
        for side, wall in zip((-1.0, 1.0), walls):
            lo, hi = wall - self.edge_band_in, wall + self.edge_band_out
            band_t = within(lo - 0.001, hi + 0.001)
            runs += [side * band_t, side * within(1.2 * wall, 1.5 * wall)]
            bands.append((band_t, lo, hi))
        t = np.concatenate(runs)
        # Only the rows used: the lowest third (which sides show the wall), then from the
        # floor to the top searched (where the body ends; the two overlap when the floor is
        # in the lowest third). Every row's steps are its own, so the rows between need no
        # strip.
        searched = s[start:stop]
        n_low = lowest.stop - start
        used = np.concatenate([np.arange(n_low), np.arange(first - start, stop - start)])
        k = self._depression_tan(bf, searched)[used, None]
        shift = k * np.sqrt(np.maximum(r**2 - t[None, :] ** 2, 0.0))
        strip = self._strip(frame, bf, searched[used], t, shift)
        cuts = [0, *itertools.accumulate(len(run) for run in runs)]
        # Colour edges across t between neighbouring columns, all runs at once (those
        # between the last column of one run and the first of the next are not used).
        edges = _rgb_length(strip[:, 1:] - strip[:, :-1])
        strengths: list[Array] = []
        backgrounds: list[NDArray[np.floating]] = []  # the rows' background steps, lowest third
        counted: list[int] = []  # the sides that show the wall in the lowest third
        for side in (0, 1):
            g_band, g_out = (edges[:, cuts[i] : cuts[i + 1] - 1] for i in (2 * side, 2 * side + 1))
            band_t, lo, hi = bands[side]
            where = 0.5 * (band_t[1:] + band_t[:-1])
            best = g_band.argmax(axis=1)
            inside = (where[best] > lo) & (where[best] < hi)
            background = _median(g_out, axis=1)
            strength = np.where(inside, g_band.max(axis=1) - background, 0.0)
            strengths.append(strength)
            backgrounds.append(background[:n_low])
            if np.count_nonzero(strength[:n_low] > self.edge_threshold) / n_low >= 0.4:
                counted.append(side)
        deep_only = not counted
        if deep_only:
            if wall_seen is None:
                wall_seen = self._wall_offsets(frame, bf, wall_rows) is not None
            if wall_seen:
                counted = self._liquid_edge_sides(
                    frame, bf, searched[:n_low], k[:n_low], walls, backgrounds, within
                )
        if not counted:
            return self.body_fraction * bf.top, False
        body_row = np.ones(len(used) - n_low, bool)  # rows first..stop
        faint = np.zeros(len(used) - n_low)  # the strongest in-band step of the counted sides
        for side in counted:
            body_row &= strengths[side][n_low:] > self.edge_threshold
            faint = np.maximum(faint, strengths[side][n_low:])
        # Above the body the band sees the background alone: the first gap_m stretch from
        # the floor up where two thirds of the rows show not even a faint step (below
        # edge_threshold / 2 on every counted side) ends the search; a faint clear wall in
        # the body still shows one.
        w = max(round(self.gap_m / self.step_m), 2)
        if stop - first < w:  # the depth level already put the body's top near the top
            return float(s[min(first, len(s) - 1)]), True
        blank = (faint < 0.5 * self.edge_threshold).astype(float)
        run = np.convolve(blank, np.ones(w) / w, mode="valid")
        gaps = (run >= 2.0 / 3.0).nonzero()[0]
        if len(gaps):
            stop = first + int(gaps[0]) + w // 2
        if stop - first < 4:
            return float(s[min(first, len(s) - 1)]), True
        k_split, _ = _step_split(body_row[: stop - first])
        if deep_only and np.count_nonzero(body_row[:k_split]) < w:
            return self.body_fraction * bf.top, False
        return float(s[first + max(k_split - 1, 0)]), True

    def _liquid_edge_sides(
        self,
        frame: RGBDFrame,
        bf: _Frame3D,
        rows: Array,
        k: Array,
        walls: tuple[float, float],
        backgrounds: list[NDArray[np.floating]],
        within: Callable[[float, float], Array],
    ) -> list[int]:
        """The sides (0 left, 1 right) whose strongest colour step in ``rows`` (the lowest
        third; ``k`` their depression tangents, (rows, 1)) lies between ``liquid_edge_in``
        inside the wall and ``edge_band_out`` beyond it and beats that row's background step
        (``backgrounds``, per side) by ``edge_threshold`` on 40 % of the rows: the wall's
        silhouette or, behind thick glass, the liquid's. ``within``: :meth:`_body_top`'s
        grid between two offsets."""
        r = bf.radius
        runs = [
            side * within(wall - self.liquid_edge_in - 0.001, wall + self.edge_band_out + 0.001)
            for side, wall in zip((-1.0, 1.0), walls)
        ]
        t = np.concatenate(runs)
        shift = k * np.sqrt(np.maximum(r**2 - t[None, :] ** 2, 0.0))
        edges = _rgb_length(np.diff(self._strip(frame, bf, rows, t, shift), axis=1))
        out, at = [], 0
        for side, (run, wall) in enumerate(zip(runs, walls)):
            g = edges[:, at : at + len(run) - 1]
            at += len(run)
            where = 0.5 * np.abs(run[1:] + run[:-1])[g.argmax(axis=1)]
            shows = (where > wall - self.liquid_edge_in) & (where < wall + self.edge_band_out)
            shows &= g.max(axis=1) - backgrounds[side] > self.edge_threshold
            if np.count_nonzero(shows) / len(rows) >= 0.4:
                out.append(side)
        return out

    def _profile(
        self, frame: RGBDFrame, box: ArrayLike, geometry: ContainerGeometry
    ) -> LiquidLevel:
        ibox = _check_inputs(frame, box)
        x0, y0, x1, y1 = (float(v) for v in np.ravel(box))
        fbox = (x0, y0, x1, y1)
        cut = _border_cut(frame.intrinsics, fbox, top_known=geometry.height is not None)
        if cut is not None:
            # The box ends where the image does, not where the bottle does: the fit would
            # take the border for the bottle's foot, side or cap.
            crop = np.ascontiguousarray(frame.color[ibox[1] : ibox[3], ibox[0] : ibox[2]])
            why = f"the bottle is cut by the image's {cut} border: its liquid cannot be read"
            return LiquidLevel(None, None, 0.0, None, "profile", crop.copy(), unknown=why)
        if geometry.table is not None:
            table = (np.asarray(geometry.table[0], dtype=float), float(geometry.table[1]))
        else:
            table = self._table(frame, fbox)
        bf = self._bottle_frame(frame, fbox, geometry, table, self.body_fraction)
        r_liq = max(bf.radius - self.wall, 0.5 * bf.radius)
        rays = self._rays(frame, ibox, bf, r_liq, stride=2)  # a first look: every 4th pixel
        # A first depth level, the whole bottle searched: the body's top is not below it. Not
        # when it reaches the top: then no ray passed the bottle anywhere, the mark of an
        # opaque wall (or a view the depth cannot tell), which says nothing about the body.
        first = self._depth_level(rays, bf.top - 0.01)
        first_level = None if first is None else first[0]
        # Where lines of sight first pass the bottle, if below its top (not just its cap).
        empty_from = (
            first_level if first_level is not None and first_level < bf.top - self.cap_m else None
        )
        if empty_from is None and bf.misfit_px <= self.max_misfit * (x1 - x0):
            # No line of sight passes the bottle below its top. If the wall also returns
            # depth over the body (taken at the box fit's shoulder), it is opaque wherever
            # the shoulder is: the search for it, a refit and the full look are not needed.
            prior = self.body_fraction * bf.top
            unknown = self._why_unseen(frame, bf, prior, rays, first_level)
            if unknown is not None and unknown.startswith(OPAQUE):
                debug = self._debug(frame, ibox, bf, None, prior, None)
                return LiquidLevel(
                    None, None, 0.0, None, "profile", debug, body_height_m=prior, unknown=unknown
                )
        floor = self.min_body_fraction * bf.top
        if empty_from is not None:
            floor = max(floor, empty_from - 0.003, self._wall_top(rays, bf) - 0.005)
        s = np.arange(0.0, bf.top, self.step_m)
        search = geometry.radius is not None  # a detector's radius: its box may be narrow
        body, shoulder_found = self._body_top(frame, bf, s, floor, search, empty_from)
        fraction = body / bf.top
        if shoulder_found and abs(fraction - self.body_fraction) > 0.02:
            # The box fit modelled the body as body_fraction of the height; with the body's
            # own top, fit again (a lower shoulder leans less: the radius changes) and look
            # for the shoulder once more with that radius.
            refit = self._bottle_frame(frame, fbox, geometry, table, fraction)
            moved = abs(refit.radius - bf.radius) + float(np.linalg.norm(refit.foot - bf.foot))
            bf = refit
            if moved > 0.0005:  # else the band around the radius is where it was
                s = np.arange(0.0, bf.top, self.step_m)
                body, shoulder_found = self._body_top(frame, bf, s, floor, search, empty_from)
        r = bf.radius
        r_liq = max(bf.radius - self.wall, 0.5 * bf.radius)
        body = _clamp(body, self.base + 0.01, bf.top)
        if bf.misfit_px > self.max_misfit * (x1 - x0):
            # No upright bottle on the table found projects onto the box (the table found is
            # another surface, or the box holds something else): nothing to measure in.
            return LiquidLevel(
                None, None, 0.0, None, "profile", self._debug(frame, ibox, bf, None, body, None),
                body_height_m=body,
                unknown=f"no upright bottle on the table fits the box (off by"
                f" {bf.misfit_px:.0f} px): is the table around its foot in view?",
            )  # fmt: skip
        rays = self._rays(frame, ibox, bf, r_liq)
        unknown = self._why_unseen(frame, bf, body, rays, first_level)
        if unknown is not None:
            debug = self._debug(frame, ibox, bf, None, body, None)
            return LiquidLevel(
                None, None, 0.0, None, "profile", debug, body_height_m=body, unknown=unknown
            )
        s_body = s[s <= body]
        # Colour cue: inner columns, unwarped by the surface ellipse, against the background
        # beside the bottle in the same row (unshifted: beside the wall nothing is elliptic).
        t_in = _linspace(-0.7 * r_liq, 0.7 * r_liq, _INNER_COLUMNS)
        k = self._depression_tan(bf, s_body)[:, None]
        shift = k * np.sqrt(np.maximum(r_liq**2 - t_in[None, :] ** 2, 0.0))
        t_bg = np.concatenate([_linspace(-1.6 * r, -1.25 * r, 4), _linspace(1.25 * r, 1.6 * r, 4)])
        # One strip: the inner columns shifted, then the background's (shift 0).
        both = self._strip(
            frame,
            bf,
            s_body,
            np.concatenate([t_in, t_bg]),
            np.concatenate([shift, np.zeros((len(s_body), len(t_bg)))], axis=1),
        )
        inner = both[:, :_INNER_COLUMNS]
        bg = _median(both[:, _INNER_COLUMNS:], axis=1)
        above_base = s_body >= self.base
        s_rows = s_body[above_base]
        profile = _median(inner - bg[:, None, :], axis=1)[above_base]  # (N, 3)
        level_c, q_c = self._colour_step(s_rows, profile)
        # Depth cue: the step between rays that meet liquid and rays that pass the bottle.
        depth_cue = self._depth_level(rays, body)
        # Fuse. Depth is metric and not fooled by colours, so it leads where it has evidence;
        # colour refines it when they agree and stands alone where depth has no data.
        if depth_cue is not None:
            level_d, q_d = depth_cue
            if abs(level_d - level_c) <= self.agree_tol:
                level, confidence = 0.7 * level_d + 0.3 * level_c, q_d * (0.8 + 0.2 * q_c)
            else:
                level, confidence = level_d, 0.6 * q_d
        else:
            level, confidence = level_c, 0.5 * q_c
        if not shoulder_found:
            confidence *= 0.7
        level = _clamp(level, self.base, body)
        fill = _clamp((level - self.base) / (body - self.base), 0.0, 1.0)
        level_px = project(frame.intrinsics, bf.points(np.array([level, body]), 0.0))
        below = inner[(s_body < level - 0.003) & (s_body > self.base)]
        colour = _median_rgb(below) if fill > 0.02 and below.size else None
        debug = self._debug(frame, ibox, bf, level, body, fill)
        return LiquidLevel(
            fill=fill,
            level_row=float(level_px[0, 1]),
            confidence=_clamp(confidence, 0.0, 1.0),
            colour=colour,
            method="profile",
            debug=debug,
            level_m=float(level),
            body_height_m=float(body),
            level_colour_m=level_c,
            level_depth_m=None if depth_cue is None else depth_cue[0],
        )

    def _colour_step(self, s: Array, profile: NDArray[np.floating]) -> tuple[float, float]:
        """Colour cue: the level where the colour-minus-background profile steps, or its ends.

        ``profile`` (N, 3): per row (height ``s``, bottom first) the median colour of the
        bottle's unwarped inner columns minus the background beside it. The best single step
        is the split with the least squared error of two constant segments (all splits at
        once by cumulative sums); it counts when the segments differ by ``colour_threshold``
        (the lower one is the liquid). Otherwise the bottle is one colour from bottom to
        shoulder: full if it differs from the background by twice ``colour_threshold``, else
        empty -- a guess (quality 0.3): a lit clear wall can differ from the background more
        than a dark liquid does. Returns (level, quality 0..1).
        """
        n = len(s)
        if n < 4:
            return self.base, 0.0
        c1 = np.cumsum(profile, axis=0)
        c2 = np.cumsum(np.sum(profile**2, axis=1))
        k = np.arange(1, n)  # rows [0, k) below, [k, n) above
        sum_lo = c1[:-1]  # the rows below each k
        sum_hi = c1[-1] - sum_lo
        sse = c2[-1] - np.sum(sum_lo**2, axis=1) / k - np.sum(sum_hi**2, axis=1) / (n - k)
        best = int(np.argmin(sse))
        mu_lo, mu_hi = sum_lo[best] / k[best], sum_hi[best] / (n - k[best])
        contrast = float(np.linalg.norm(mu_lo - mu_hi))
        if contrast >= self.colour_threshold:
            # Gravity: the lower segment is the liquid, whichever differs more from the
            # background (a lit clear wall can differ more than a dark wine).
            return float(s[k[best]]), float(min(1.0, contrast / (2.0 * self.colour_threshold)))
        # One colour from bottom to shoulder: full or empty. Without a step, colour can only
        # guess by how far it is from the background, so the quality is low.
        overall = float(np.linalg.norm(profile.mean(axis=0)))
        if overall > 2.0 * self.colour_threshold:
            return float(s[-1]) + self.step_m, 0.3
        return self.base, 0.3

    def _rays(
        self,
        frame: RGBDFrame,
        box: tuple[int, int, int, int],
        bf: _Frame3D,
        r_liq: float,
        stride: int = 1,
    ) -> _Rays:
        """Every ``stride``-th pixel (both ways) of the box whose line of sight passes within
        :data:`_RAY_MISS` of the radius from the axis, against the bottle's cylinders, with
        what its depth says (see :class:`_Rays` and :func:`_rays_kernel`)."""
        intr = frame.intrinsics
        depth = np.asarray(frame.depth)
        if depth.shape != (intr.height, intr.width) or depth.shape != frame.color.shape[:2]:
            raise PerceptionError(
                f"the depth image is {depth.shape[1]}x{depth.shape[0]} and the colour image"
                f" {frame.color.shape[1]}x{frame.color.shape[0]}: align depth to colour"
                " before measuring"
            )
        out = _rays_kernel(
            depth,
            np.array(box, dtype=np.int64),
            stride,
            np.array([intr.ppx, intr.ppy, intr.fx, intr.fy]),
            np.stack([bf.away, bf.lateral, bf.up, bf.foot]),
            np.array(
                [
                    bf.radius,
                    r_liq,
                    bf.top,
                    self.base,
                    self.surface_tol,
                    self.occluder_m,
                    self.wall_band,
                ]
            ),
        )
        return _Rays(*out)

    def _wall_offsets(self, frame: RGBDFrame, bf: _Frame3D, s: Array) -> tuple[float, float] | None:
        """How far from the axis each side's wall shows in colour in rows ``s`` (left, right).

        The box gives the radius, but a detector's box of a clear bottle may be a few mm
        narrower than the bottle (its depth is the liquid's), and then the wall's silhouette
        lies outside the band where the shoulder is looked for. So, per side, between 0.6 and
        1.5 times the radius, the outermost 0.5 mm column where a colour step beats the row's
        median step by ``edge_threshold`` in at least 40 % of the rows is the wall; a side
        with none takes the other side's (the bottle is round; a faint clear wall may show on
        one side only); None when neither shows one. It places the band only for a caller's
        geometry (a detector's): a box projected from the bottle itself (the evaluation's) is
        not narrow, and a background edge persisting beside the bottle would only move the
        band off the wall. Without one, :meth:`_body_top` asks it only whether a wall shows
        at all, when no side showed one in the band.
        """
        r = bf.radius
        grid = np.arange(0.6 * r, 1.5 * r, 0.0005)
        # Both sides in one strip, (rows, side, column, RGB): left (-t) then right (+t).
        strip = self._strip(frame, bf, s, np.concatenate([-grid, grid]))
        strip = strip.reshape(len(s), 2, len(grid), 3)
        g = _rgb_length(strip[:, :, 1:] - strip[:, :, :-1])
        # Each step or its neighbour's, whichever is larger (wrapping around each side's
        # columns, as np.roll does).
        wrapped = np.concatenate([g[..., -1:], g, g[..., :1]], axis=2)
        g = np.maximum(g, np.maximum(wrapped[..., :-2], wrapped[..., 2:]))
        edged = g - _median(g, axis=2)[..., None] > self.edge_threshold
        share = np.count_nonzero(edged, axis=0) / len(s)  # (side, column)
        out: list[float | None] = []
        for side_share in share:
            columns = (side_share >= 0.4).nonzero()[0]
            wall = 0.5 * (grid[columns[-1]] + grid[columns[-1] + 1]) if len(columns) else None
            out.append(None if wall is None else float(wall))
        left, right = out
        # The bottle is round: a side whose faint wall shows no edge takes the other side's.
        left = right if left is None else left
        right = left if right is None else right
        return None if left is None or right is None else (left, right)

    def _wall_top(self, rays: _Rays, bf: _Frame3D) -> float:
        """How high the front wall returns depth at the body's radius: the 95th percentile
        height of the points within ``wall_band`` of the outer cylinder's front (a clear wall
        does on some pixels on a D435, MuJoCo's plain render on none: then 0). The body
        reaches at least that high, less a few mm of shoulder still near the radius."""
        h = rays.height.take(rays.at_wall.nonzero()[0])  # all pass within _RAY_MISS = 0.8 r
        return percentile(h, 95.0) if len(h) >= 20 else 0.0

    def _why_unseen(
        self, frame: RGBDFrame, bf: _Frame3D, body: float, rays: _Rays, passes_below: float | None
    ) -> str | None:
        """Why the liquid cannot be seen in this view, or None if it can.

        **Outside the image**: less than ``min_body_seen`` of the body's axis plane projects
        into the image. **Hidden**: of the lines of sight through the body (within 0.8 r of
        the axis, base to shoulder), more than ``1 - min_body_seen`` end on something nearer
        than the bottle's front by ``occluder_m``. **Opaque**: the wall returns depth at the
        bottle's own surface over at least ``opaque_share`` of the lines of sight through the
        body *and* through the lower half of what is above the shoulder (within 0.25 r of the
        axis: the neck) or, wherever the shoulder was put, with no line of sight passing the
        bottle anywhere below its top (``passes_below``, the depth level over the whole
        height, at the top). A clear wall returns depth on a few pixels only (none in MuJoCo's
        plain render; ~10 % good and ~6 % wrong on ClearGrasp's real D435 frames, the
        simulator's camera model), a liquid only below its level and never in the empty neck,
        so only a bottle whose wall the camera cannot see through is dense in both.
        """
        intr = frame.intrinsics
        ss = _linspace(self.base, body, 12)
        tt = _linspace(-bf.radius, bf.radius, 7)
        uv = project(intr, bf.points(ss[:, None], tt[None, :]).reshape(-1, 3))
        in_image = (
            (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
        )
        seen = np.count_nonzero(in_image) / len(in_image)
        if seen < self.min_body_seen:
            return f"only {100 * seen:.0f} % of the bottle's body is inside the image"

        def share(mask: NDArray[np.bool_], of: NDArray[np.bool_], n: int) -> float:
            """The share of the ``n`` rays ``of`` that ``mask`` marks (their mean)."""
            return np.count_nonzero(mask & of) / n

        # Every ray passes within _RAY_MISS = 0.8 r of the axis.
        through_body = (rays.s_axis > self.base) & (rays.s_axis < body)
        n_through = int(np.count_nonzero(through_body))
        if n_through < 20:
            return "the bottle's body covers too few pixels to read a level"
        hidden = share(rays.before, through_body, n_through)
        if hidden > 1.0 - self.min_body_seen:
            return f"{100 * hidden:.0f} % of the bottle's body is hidden by something in front"
        body_rays = (
            (rays.miss < 0.5) & (rays.s_axis > self.base + 0.01) & (rays.s_axis < body - 0.005)
        )
        n_body = int(np.count_nonzero(body_rays))
        if n_body < 20:
            return None
        dense_body = share(rays.on_bottle, body_rays, n_body)
        if dense_body < self.opaque_share:
            return None
        upper_top = body + 0.004 + 0.5 * max(bf.top - body - 0.004, 0.0)
        neck_rays = (rays.miss < 0.25) & (rays.s_axis > body + 0.004) & (rays.s_axis < upper_top)
        n_neck = int(np.count_nonzero(neck_rays))
        dense_neck = share(rays.on_bottle, neck_rays, n_neck) if n_neck >= 10 else 0.0
        if n_neck >= 10 and dense_neck >= self.opaque_share:
            neck = f"{100 * dense_neck:.0f} % of the neck"
        elif passes_below is not None and passes_below >= bf.top - self.cap_m:
            neck = "no line of sight passes the bottle below its top"
        else:
            return None
        return (
            f"{OPAQUE}: the wall returns depth on {100 * dense_body:.0f} % of the body and"
            f" {neck}, so the liquid cannot be seen"
        )

    def _depth_level(self, rays: _Rays, body: float) -> tuple[float, float] | None:
        """Depth cue: the liquid level where lines of sight stop meeting liquid, and its quality.

        Each line of sight within 0.7 of the liquid's radius from the axis is placed at the
        lowest height its chord through the liquid's cylinder reaches (``s_low``, never below
        the base): had the liquid been above that height, the ray would have ended on it. So
        a ray whose depth lands on the bottle (liquid, or a clear wall that returned depth)
        with ``s_low`` below the level is expected, and one that passes beyond the bottle (the
        table or the room behind it, or under a clear bottom) says the liquid is below its
        ``s_low``. Per ``step_m`` of height the share of rays on the bottle is taken; rows
        where it reaches ``liquid_share`` are liquid, and the level is the best single step
        from liquid rows (below) to empty ones (:func:`_step_split`). The share, not every
        ray, because a clear wall returns depth on some pixels whatever is behind it (at most
        a third of the valid ones on the simulated D435). Quality: the share of rows the step
        explains. None when fewer than ``min_depth_points`` rays have depth.
        """
        use = (
            rays.hits_liquid_cylinder
            & (rays.miss < 0.7)
            & rays.valid
            & ~rays.before
            & ~rays.at_wall
            & (rays.s_low < body)
        )
        if np.count_nonzero(use) < self.min_depth_points:
            return None
        n_rows = max(math.ceil((body - self.base) / self.step_m), 1)
        # A point on the bottle above the body is the wall of a shoulder or a neck, no
        # evidence of liquid below it.
        keep = (use & (~rays.on_bottle | (rays.height < body + 0.002))).nonzero()[0]
        at = (rays.s_low.take(keep) - self.base) / self.step_m
        row = np.minimum(np.maximum(at.astype(int), 0), n_rows - 1)  # np.clip, faster
        n_all = np.bincount(row, minlength=n_rows)
        n_on = np.bincount(row, weights=rays.on_bottle.take(keep), minlength=n_rows)
        known = (n_all >= 2).nonzero()[0]
        if len(known) < 4:
            return None
        is_liquid = n_on[known] >= self.liquid_share * n_all[known]
        k, cost = _step_split(is_liquid)
        if k == 0:
            level = self.base
        elif k == len(known):
            level = body
        else:  # between the last liquid row and the first empty one
            level = self.base + self.step_m * 0.5 * (known[k - 1] + 1 + known[k])
        return float(level), 1.0 - cost / len(known)

    def _debug(
        self,
        frame: RGBDFrame,
        box: tuple[int, int, int, int],
        bf: _Frame3D,
        level: float | None,
        body: float,
        fill: float | None,
    ) -> NDArray[np.uint8]:
        """The box crop with the liquid surface (ellipse, blue; none when unknown) and the body
        top (green)."""
        x0, y0, x1, y1 = box
        debug = frame.color[y0:y1, x0:x1].copy()  # C-contiguous, for OpenCV to draw on
        heights, colours = [body], [(0, 200, 0)]
        if level is not None:
            heights, colours = [level, body], [(0, 90, 255), (0, 200, 0)]
        # Every ring in one projection: (ring, angle, xyz).
        rings = bf.points(
            np.repeat(np.array(heights)[:, None], len(_DEBUG_COS), axis=1),
            bf.radius * _DEBUG_COS,
            bf.radius * _DEBUG_SIN,
        )
        uv = project(frame.intrinsics, rings.reshape(-1, 3)) - [x0, y0]
        for ring_px, colour in zip(
            np.round(uv).astype(np.int32).reshape(len(heights), -1, 2), colours
        ):
            cv2.polylines(debug, [ring_px], True, colour, 1, cv2.LINE_AA)
        text = "unknown" if fill is None else f"{100 * fill:.0f}%"
        cv2.putText(debug, text, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 0, 0), 1)
        return debug


def measure_liquid(
    frame: RGBDFrame,
    box: ArrayLike,
    method: Method = "profile",
    geometry: ContainerGeometry | None = None,
) -> LiquidLevel:
    """The liquid level of the container in ``box`` with default settings (see the module)."""
    return LiquidLevelMeter(method).measure(frame, box, geometry)
