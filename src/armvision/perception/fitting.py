"""Geometric fits shared by the perception modules: planes, circles and unit depth rays.

- :func:`fit_plane`: the one plane fit (RANSAC hypotheses, then least-squares refits)
  behind the geometric detector's table, the liquid meter's table and the tag plate.
- :func:`fit_circle_kasa` and :func:`fit_circle_geometric`: circles in the table plane; their
  compiled loops (:func:`kasa_kernel`, :func:`gauss_newton_circle`) are the detector's wall fits.
- :func:`unit_depth_rays`: the camera-frame rays of a pixel grid, cached per intrinsics.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.camera.frames import Intrinsics, deproject_image

Array = NDArray[np.float64]


@functools.lru_cache(maxsize=8)
def unit_depth_rays(intr: Intrinsics, stride: int) -> tuple[Array, NDArray[np.intp]]:
    """Camera-frame points at depth 1 m (z = 1) of every ``stride``-th pixel of every
    ``stride``-th row, (N, 3), and those pixels' flat indices (N,); cached per intrinsics."""
    rays = deproject_image(intr, np.ones((intr.height, intr.width)))
    rows, cols = np.mgrid[0 : intr.height : stride, 0 : intr.width : stride]
    flat = (rows * intr.width + cols).ravel()
    rays = rays[flat]
    rays.flags.writeable = False
    flat.flags.writeable = False
    return rays, flat


@functools.lru_cache(maxsize=8)
def unit_depth_ray_columns(intr: Intrinsics, stride: int) -> tuple[Array, Array]:
    """The x and y columns of :func:`unit_depth_rays` (z is 1), each contiguous: products
    with them cost about half a product with the (N, 3) rows; cached per intrinsics."""
    rays = unit_depth_rays(intr, stride)[0]
    x, y = np.ascontiguousarray(rays[:, 0]), np.ascontiguousarray(rays[:, 1])
    x.flags.writeable = False
    y.flags.writeable = False
    return x, y


# --------------------------------------------------------------------------- planes


@dataclass(frozen=True, eq=False)
class PlaneFit:
    """A plane ``normal . p + offset = 0`` fitted to points.

    ``normal`` has unit length and points to the side :func:`fit_plane` was asked for (by
    default toward the origin, the camera, so ``offset`` >= 0); ``inliers`` (N,) marks the
    input points within the tolerance of this plane; ``fitted`` is how many points the last
    least-squares fit used (the inliers of the plane before it); ``rms`` the RMS distance of
    the inliers from the plane, metres.
    """

    normal: Array
    offset: float
    inliers: NDArray[np.bool_]
    fitted: int
    rms: float


def _ransac_hypothesis(
    p: Array,
    tolerance: float,
    hypotheses: int,
    rng: np.random.Generator,
    normal_prior: Array | None,
    max_tilt_rad: float,
) -> tuple[Array, float] | None:
    """The three-point plane (n, d) with the most points of ``p`` within ``tolerance``.

    All hypotheses are scored in one (N x hypotheses) array operation; with ``normal_prior``
    only those within ``max_tilt_rad`` of it count. None if none has three points.
    """
    idx = rng.integers(0, len(p), size=(hypotheses, 3))
    a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
    # (b - a) x (c - a) written out: np.cross's axis handling costs twice the arithmetic.
    (u0, u1, u2), (v0, v1, v2) = (b - a).T, (c - a).T
    normals = np.column_stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0])
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-9
    normals[ok] /= lengths[ok, None]
    if normal_prior is not None:
        ok &= np.abs(normals @ normal_prior) > math.cos(max_tilt_rad)
    d = -np.einsum("ij,ij->i", normals, a)
    counts = _count_within(np.ascontiguousarray(p, dtype=float), normals, d, tolerance)
    counts[~ok] = -1
    best = int(np.argmax(counts))
    if counts[best] < 3:
        return None
    return normals[best], float(d[best])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _count_within(p: Array, normals: Array, d: Array, tolerance: float) -> NDArray[np.int64]:
    """How many points ``p`` (N, 3) lie within ``tolerance`` of each plane n . p + d = 0
    (``normals`` (K, 3), ``d`` (K,)): RANSAC's scores, compiled (the (N, K) array of
    distances cost a few hundred microseconds a frame)."""
    counts = np.zeros(len(normals), dtype=np.int64)
    for k in range(len(normals)):
        n0, n1, n2, dk = normals[k, 0], normals[k, 1], normals[k, 2], d[k]
        c = 0
        for i in range(len(p)):
            if abs(p[i, 0] * n0 + p[i, 1] * n1 + p[i, 2] * n2 + dk) < tolerance:
                c += 1
        counts[k] = c
    return counts


def fit_plane(
    points: Array,
    tolerance: float,
    *,
    rng: np.random.Generator | None = None,
    hypotheses: int = 64,
    normal_prior: Array | None = None,
    max_tilt_rad: float = math.radians(15.0),
    max_scored: int | None = None,
    refits: int = 1,
    robust: bool = False,
    toward: ArrayLike | None = None,
) -> PlaneFit | None:
    """The plane through most of ``points`` (N, 3): RANSAC, then least-squares refits.

    With ``rng`` the start is the best of ``hypotheses`` three-point planes (RANSAC, counting
    points within ``tolerance``; with ``normal_prior`` only planes within ``max_tilt_rad`` of
    it), scored on at most ``max_scored`` points drawn at random (all if None); without
    ``rng`` the start is all the points. Then ``refits`` times: the plane through the current
    inliers by least squares (the normal is the smallest singular vector of the centred
    points, found as an eigenvector of their 3x3 scatter matrix; the first refit uses the
    scored points, later ones all), and the inliers are the points within ``tolerance`` of it
    (with ``robust``, within max(3 x 1.4826 x MAD of the previous inliers' residuals,
    ``tolerance``), so the band follows the noise). The normal is turned to have a
    non-negative component along ``toward`` (default: toward the origin, so ``offset`` >= 0).
    None when there is no plane: fewer than three points, no hypothesis with three inliers,
    or fewer than three inliers after a refit.

    Written here because neither OpenCV's Python API nor SciPy has a plane RANSAC, and
    Open3D would be a large dependency for twenty lines.
    """
    points = np.asarray(points, dtype=float)
    if len(points) < 3:
        return None
    scored = points
    if rng is not None and max_scored is not None and len(points) > max_scored:
        scored = points[rng.choice(len(points), max_scored, False)]
    keep = np.ones(len(points), dtype=bool)
    if rng is not None:
        start = _ransac_hypothesis(scored, tolerance, hypotheses, rng, normal_prior, max_tilt_rad)
        if start is None:
            return None
        keep = np.abs(scored @ start[0] + start[1]) < tolerance
    subset, fitted = scored, 0
    for _ in range(refits):
        # The inliers' centroid and scatter matrix as products with the 0/1 mask ``keep``:
        # at a few hundred points, a boolean index or an axis-0 sum costs several times the
        # matrix product (the sums' order differs, a change at rounding level only).
        fitted = int(np.count_nonzero(keep))
        centroid = (keep @ subset) / fitted
        centred = subset - centroid
        # The eigenvector of the scatter matrix's smallest eigenvalue: the smallest right
        # singular vector of the centred inliers, at half an SVD's cost on a tag's points.
        normal = np.linalg.eigh((centred.T * keep) @ centred)[1][:, 0]
        residual_subset = centred @ normal
        residual = residual_subset if subset is points else (points - centroid) @ normal
        band = tolerance
        if robust:  # the band follows the spread of the inliers the plane was fitted to
            r = np.compress(keep, residual_subset)
            band = max(3.0 * 1.4826 * _median(np.abs(r - _median(r))), tolerance)
        keep = np.abs(residual) < band
        subset = points
        if np.count_nonzero(keep) < 3:
            return None
    offset = -float(normal @ centroid)
    side = -centroid if toward is None else np.asarray(toward, dtype=float)
    if normal @ side < 0.0:
        normal, offset = -normal, -offset
    kept = residual[keep]
    rms = math.sqrt(float((kept * kept).sum()) / len(kept))
    return PlaneFit(normal, offset, keep, fitted, rms)


def _median(x: Array) -> float:
    """``np.median`` of a 1-D array without NaNs, by one partition: np.median's checks and
    the mean of its middle pair cost several times the partition on a tag's residuals."""
    half = len(x) // 2
    if len(x) % 2:
        return float(np.partition(x, half)[half])
    middle = np.partition(x, (half - 1, half))
    return (float(middle[half - 1]) + float(middle[half])) / 2.0


# --------------------------------------------------------------------------- circles


def fit_circle_kasa(xy: Array) -> tuple[Array, float]:
    """Algebraic (Kåsa) circle fit: least squares of 2 a x + 2 b y + c = x^2 + y^2.

    Centre (a, b), radius sqrt(c + a^2 + b^2). Exact for points on a circle, biased toward
    small radii on a short noisy arc, so use it to start :func:`fit_circle_geometric`.
    Solved by its 3x3 normal equations about the points' mean (well conditioned there).
    Fewer than 3 distinct points: the mean, radius 0.
    """
    cx, cy, r = kasa_kernel(np.ascontiguousarray(xy, dtype=float), 1)
    return np.array([cx, cy]), r


def solve3(A: Array, b: Array) -> tuple[float, float, float] | None:
    """The solution of ``A x = b`` for a 3x3 symmetric positive semi-definite ``A`` (normal
    equations) by cofactors, or None when ``A`` is singular: its determinant below 1e-12 of
    its diagonal's product (Hadamard's bound, so the test ignores each unknown's scale)."""
    (a, b_, c), (d, e, f), (g, h, i) = np.asarray(A, dtype=float).tolist()
    ok, x, y, z = _solve3(a, b_, c, d, e, f, g, h, i, *np.asarray(b, dtype=float).tolist())
    return (x, y, z) if ok else None


# The circle fits below are compiled (Numba): a frame's fits are a few hundred points each,
# where numpy's per-call overhead, not the arithmetic, set the cost (the batched numpy version
# took 2.4 ms a cluttered frame, these 0.4). They release the interpreter's lock, so the tag
# stage's thread runs meanwhile.


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve3(
    a: float,
    b_: float,
    c: float,
    d: float,
    e: float,
    f: float,
    g: float,
    h: float,
    i: float,
    x: float,
    y: float,
    z: float,
) -> tuple[bool, float, float, float]:
    """:func:`solve3` on the matrix's entries, row by row, and the right-hand side's:
    (solved, x0, x1, x2)."""
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b_ * c1 + c * c2
    if not abs(det) > 1e-12 * abs(a * e * i):  # also a zero diagonal, or NaN
        return False, 0.0, 0.0, 0.0
    return (
        True,
        (x * c0 + b_ * (z * f - y * i) + c * (y * h - z * e)) / det,
        (a * (y * i - z * f) + x * c1 + c * (z * d - y * g)) / det,
        (a * (e * z - h * y) + b_ * (g * y - d * z) + x * c2) / det,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def kasa_kernel(xy: Array, step: int) -> tuple[float, float, float]:
    """:func:`fit_circle_kasa` of every ``step``-th point of ``xy`` (N >= 1, 2): (cx, cy, r)."""
    n = 0
    mx = my = 0.0
    for k in range(0, len(xy), step):
        mx += xy[k, 0]
        my += xy[k, 1]
        n += 1
    mx /= n
    my /= n
    # The normal equations of A [a b c]^T = q.q, A = [2 qx, 2 qy, 1], q about the mean.
    sxx = sxy = sx = syy = sy = s1 = sxz = syz = sz = 0.0
    for k in range(0, len(xy), step):
        ax = 2.0 * (xy[k, 0] - mx)
        ay = 2.0 * (xy[k, 1] - my)
        zz = 0.25 * (ax * ax + ay * ay)
        sxx += ax * ax
        sxy += ax * ay
        sx += ax
        syy += ay * ay
        sy += ay
        s1 += 1.0
        sxz += ax * zz
        syz += ay * zz
        sz += zz
    ok, a, b, c = _solve3(sxx, sxy, sx, sxy, syy, sy, sx, sy, s1, sxz, syz, sz)
    if not ok:
        return mx, my, 0.0
    return mx + a, my + b, math.sqrt(max(c + a * a + b * b, 0.0))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def gauss_newton_circle(
    xy: Array,
    idx: NDArray[np.int64],
    cx: float,
    cy: float,
    r: float,
    scale: float,
    iterations: int,
    tolerance: float,
) -> tuple[float, float, float]:
    """The geometric circle fit of :func:`fit_circle_geometric` on the points ``xy[idx]``
    from (cx, cy, r): (cx, cy, r). Each iteration solves J^T W J step = -J^T W res, with
    J = -[ux, uy, 1] (u the unit vector from the centre to the point) and Huber weights."""
    for _ in range(iterations):
        sxx = sxy = sxr = syy = syr = srr = bx = by = br = 0.0
        for k in idx:
            ux = xy[k, 0] - cx
            uy = xy[k, 1] - cy
            dist = max(math.sqrt(ux * ux + uy * uy), 1e-9)
            res = dist - r
            w = min(1.0, scale / max(abs(res), 1e-12))
            ux /= dist
            uy /= dist
            wux = w * ux
            wuy = w * uy
            sxx += wux * ux
            sxy += wux * uy
            sxr += wux
            syy += wuy * uy
            syr += wuy
            srr += w
            bx += wux * res
            by += wuy * res
            br += w * res
        ok, s0, s1, s2 = _solve3(sxx, sxy, sxr, sxy, syy, syr, sxr, syr, srr, bx, by, br)
        if not ok:  # all points in one spot: keep where it is
            break
        cx += s0
        cy += s1
        r += s2
        if max(abs(s0), abs(s1), abs(s2)) < tolerance:
            break
    return cx, cy, r


def fit_circle_geometric(
    xy: Array,
    center: Array,
    radius: float,
    scale: float,
    iterations: int = 15,
    tolerance: float = 1e-6,
) -> tuple[Array, float, Array]:
    """Geometric circle fit (residual |p - c| - r) by Gauss-Newton with Huber weights (IRLS).

    Points with |residual| > ``scale`` get weight scale / |residual|, so stray points pull
    linearly, not quadratically. Stops when no parameter moves more than ``tolerance``
    (metres) in an iteration. Returns (centre, radius, residuals). The compiled loop is
    :func:`gauss_newton_circle` (scipy.optimize.least_squares costs more per call than a
    frame's fits together).
    """
    xy = np.ascontiguousarray(xy, dtype=float)
    cx0, cy0 = (float(v) for v in np.asarray(center, dtype=float))
    cx, cy, r = gauss_newton_circle(
        xy,
        np.arange(len(xy), dtype=np.int64),
        cx0,
        cy0,
        float(radius),
        float(scale),
        int(iterations),
        float(tolerance),
    )
    res = np.linalg.norm(xy - np.array([cx, cy]), axis=1) - r
    return np.array([cx, cy]), float(r), res


def percentile(a: Array, q: float) -> float:
    """``np.percentile(a, q)`` of a non-empty 1-D array without NaN, the same number: numpy's
    linear interpolation between the two order statistics around ``(n - 1) q / 100``, found
    by one partition, without its overhead (~30 us a call against ~3; the detector and the
    liquid meter take a few hundred a frame on arrays of a few hundred points)."""
    n = len(a)
    at = (q / 100.0) * (n - 1)
    lo = int(at)
    hi = min(lo + 1, n - 1)
    part = np.partition(a, (lo, hi))
    below, above = float(part[lo]), float(part[hi])
    gamma = at - lo
    diff = above - below
    # numpy's _lerp: from the nearer end, for monotonicity
    return above - diff * (1.0 - gamma) if gamma >= 0.5 else below + diff * gamma
