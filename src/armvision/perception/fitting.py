"""Geometric fits shared by the perception modules: planes, circles and unit depth rays.

- :func:`fit_plane`: the one plane fit (RANSAC hypotheses, then least-squares refits)
  behind the geometric detector's table, the liquid meter's table and the tag plate.
- :func:`fit_circle_kasa` and :func:`fit_circle_geometric`: circles in the table plane.
- :func:`unit_depth_rays`: the camera-frame rays of a pixel grid, cached per intrinsics.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

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
    distances = p @ normals.T
    distances += d
    counts = (np.abs(distances, out=distances) < tolerance).sum(axis=0)
    counts[~ok] = -1
    best = int(np.argmax(counts))
    if counts[best] < 3:
        return None
    return normals[best], float(d[best])


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
    Solved by its 3x3 normal equations about the points' mean (well conditioned there): a
    tenth of ``np.linalg.lstsq``'s time on a few hundred points.
    """
    mean = xy.mean(axis=0)
    q = xy - mean
    A = np.empty((len(q), 4))
    A[:, :2] = 2.0 * q
    A[:, 2] = 1.0
    A[:, 3] = np.einsum("ij,ij->i", q, q)
    normal = A[:, :3].T @ A
    solved = solve3(normal[:, :3], normal[:, 3])
    if solved is None:  # fewer than 3 distinct points: no circle; the mean, radius 0
        return mean, 0.0
    a, b, c = solved
    return mean + np.array([a, b]), float(math.sqrt(max(c + a * a + b * b, 0.0)))


def solve3(A: Array, b: Array) -> tuple[float, float, float] | None:
    """The solution of ``A x = b`` for a 3x3 symmetric positive semi-definite ``A`` (normal
    equations) by cofactors, or None when ``A`` is singular: its determinant below 1e-12 of
    its diagonal's product (Hadamard's bound, so the test ignores each unknown's scale).
    Written out: ``np.linalg.solve``'s call costs more than the arithmetic on a 3x3, and the
    circle fits solve hundreds of them per frame."""
    (a, b_, c), (d, e, f), (g, h, i) = A.tolist()
    return _solve3(a, b_, c, d, e, f, g, h, i, *b.tolist())


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
) -> tuple[float, float, float] | None:
    """:func:`solve3` on the matrix's entries, row by row, and the right-hand side's."""
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b_ * c1 + c * c2
    if not abs(det) > 1e-12 * abs(a * e * i):  # also a zero diagonal, or NaN
        return None
    return (
        (x * c0 + b_ * (z * f - y * i) + c * (y * h - z * e)) / det,
        (a * (y * i - z * f) + x * c1 + c * (z * d - y * g)) / det,
        (a * (e * z - h * y) + b_ * (g * y - d * z) + x * c2) / det,
    )


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
    (metres) in an iteration. Returns (centre, radius, residuals). One circle of
    :func:`fit_circles_geometric`.
    """
    xy = np.asarray(xy, dtype=float)
    centers, radii = fit_circles_geometric(
        xy,
        np.array([0, len(xy)]),
        np.asarray(center, dtype=float)[None],
        np.array([float(radius)]),
        np.array([float(scale)]),
        iterations,
        tolerance,
    )
    res = np.linalg.norm(xy - centers[0], axis=1) - radii[0]
    return centers[0], float(radii[0]), res


def fit_circles_geometric(
    xy: Array,
    bounds: NDArray[np.intp],
    centers: Array,
    radii: Array,
    scales: Array,
    iterations: int = 15,
    tolerance: float = 1e-6,
) -> tuple[Array, Array]:
    """:func:`fit_circle_geometric` of several circles at once: circle k fitted to the
    points ``xy[bounds[k]:bounds[k + 1]]`` (each run non-empty) from ``centers[k]`` and
    ``radii[k]`` with Huber scale ``scales[k]``; each stops on its own (its parameters
    then stay), the loop when all have. Returns the centres (K, 2) and radii (K,).

    Each iteration is two dozen numpy operations on all the points, whatever their number of
    circles: a frame's clusters fitted together cost a fraction of one call each (the
    calls' overhead, not the arithmetic, dominates at a few hundred points), and
    scipy.optimize.least_squares costs more per call than that still. The operations write
    into buffers allocated once, and the points of circles that have stopped are dropped
    (a third of the work on a cluttered frame's fits); each circle's sums, and so its steps,
    are those of the whole set's to the bit.
    """
    c = np.array(centers, dtype=float).reshape(-1, 2)
    r = np.array(radii, dtype=float).reshape(-1)
    cx, cy = c[:, 0].copy(), c[:, 1].copy()
    counts = np.diff(bounds)
    starts = np.asarray(bounds[:-1])
    which = np.repeat(np.arange(len(r)), counts)
    scale = np.asarray(scales, dtype=float)[which]
    # Coordinates and every per-point term as contiguous rows: strided columns of an
    # (N, k) array cost several times as much per operation at these sizes.
    x, y = np.ascontiguousarray(np.asarray(xy, dtype=float).T)
    active = list(range(len(r)))
    # Rows 0-8: the distinct sums of a circle's Gauss-Newton equations J^T W J step =
    # -J^T W res, with J = -[ux, uy, 1] (u the unit vector from the centre to the point):
    # the symmetric left side's 6 terms, then the right side's 3; summed over each run.
    # Rows 9-13: scratch. Row 5 is the Huber weight w, rows 2 and 4 w ux and w uy.
    buffer = np.empty((14, len(x)))
    terms, ux, uy, dist, res, tmp = buffer[:9], *buffer[9:]
    for _ in range(iterations):
        np.subtract(x, cx[which], out=ux)
        np.subtract(y, cy[which], out=uy)
        np.multiply(ux, ux, out=dist)
        np.multiply(uy, uy, out=tmp)
        dist += tmp
        np.sqrt(dist, out=dist)
        np.maximum(dist, 1e-9, out=dist)
        np.subtract(dist, r[which], out=res)
        np.abs(res, out=tmp)
        np.maximum(tmp, 1e-12, out=tmp)
        np.divide(scale, tmp, out=tmp)
        w, wux, wuy = terms[5], terms[2], terms[4]
        np.minimum(1.0, tmp, out=w)
        ux /= dist
        uy /= dist
        np.multiply(w, ux, out=wux)
        np.multiply(w, uy, out=wuy)
        np.multiply(wux, ux, out=terms[0])
        np.multiply(wux, uy, out=terms[1])
        np.multiply(wuy, uy, out=terms[3])
        np.multiply(wux, res, out=terms[6])
        np.multiply(wuy, res, out=terms[7])
        np.multiply(w, res, out=terms[8])
        sums = np.add.reduceat(terms, starts, axis=1).T.tolist()
        still = []
        for k, (xx, xy_, xr, yy, yr, rr, bx, by, br) in zip(active, sums):
            step = _solve3(xx, xy_, xr, xy_, yy, yr, xr, yr, rr, bx, by, br)
            if step is None:  # all points in one spot: keep the start
                continue
            cx[k] += step[0]
            cy[k] += step[1]
            r[k] += step[2]
            if max(abs(step[0]), abs(step[1]), abs(step[2])) >= tolerance:
                still.append(k)
        if not still:
            break
        if len(still) < len(active):  # only the circles still moving: their runs, in order
            keep = np.zeros(len(r), dtype=bool)
            keep[still] = True
            keep = keep[which]
            x, y, which, scale = x[keep], y[keep], which[keep], scale[keep]
            starts = np.concatenate([[0], np.cumsum(counts[still])[:-1]])
            live = buffer[:, : len(x)]
            terms, ux, uy, dist, res, tmp = live[:9], *live[9:]
        active = still
    return np.column_stack([cx, cy]), r


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
