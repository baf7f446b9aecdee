"""Clearance between the arm and a planning scene: the ViperX-300s as spheres, the scene as
vertical cylinders on a table plane.

The arm is covered by spheres (:data:`LINK_SPHERES` on the links, :func:`gripper_spheres` on
the gripper and its two fingers at any opening), placed by forward kinematics for a batch of
joint configurations at once. A body of the scene (:class:`~armvision.runtime.planning_scene.
Body`) is a vertical cylinder; the signed distance from a point p to a cylinder of centre c,
radius r, from z = b to z = t is, with d_xy = |p_xy - c| - r and d_z = max(b - p_z, p_z - t),
hypot(d_xy, d_z) when both are positive, else max(d_xy, d_z) (negative inside). A sphere's
clearance is that distance minus its radius; the table's is its centre's height above the
table minus its radius. :func:`clearances` gives the least over every sphere, per
configuration, and which body it is (-1: the table).

Dimensions are the vx300s URDF's as the simulated arm carries them (``sim/data/vx300s.xml``,
:mod:`armvision.robot.vx300s`). Units: metres, radians; positions in the base frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import inv_T
from armvision.robot.kinematics import VX300S, ArmModel, fk
from armvision.robot.vx300s import EE_GRIPPER_X, FINGER_LINK_X, FINGER_PAD_INSET
from armvision.runtime.planning_scene import Body

Array = NDArray[np.float64]


def _along(
    a: Sequence[float], b: Sequence[float], radius: float, moved_by: int, n: int
) -> list[tuple[tuple[float, ...], float, int]]:
    """``n`` spheres of ``radius`` evenly from ``a`` to ``b``, each moved by ``moved_by`` joints."""
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    return [(tuple(pa + s * (pb - pa)), radius, moved_by) for s in np.linspace(0.0, 1.0, n)]


#: Spheres on the links at the home pose (all joints zero), base frame: (centre, radius,
#: number of joints that move it). Upper arm: the shoulder (0.127 m up) to the elbow
#: (0.0596 m forward, 0.3 m up); forearm: the elbow to the wrist, 0.3 m out; the wrist box.
LINK_SPHERES: tuple[tuple[tuple[float, ...], float, int], ...] = tuple(
    _along((0.0, 0.0, 0.17), (0.0, 0.0, 0.40), 0.035, 2, 6)  # upper arm
    + _along((0.02, 0.0, 0.42705), (0.05955, 0.0, 0.42705), 0.04, 2, 2)  # elbow servos
    + _along((0.09, 0.0, 0.42705), (0.345, 0.0, 0.42705), 0.032, 3, 7)  # forearm
    + _along((0.375, 0.0, 0.42705), (0.41, 0.0, 0.42705), 0.032, 5, 2)  # wrist
)

#: Gripper spheres in the ee frame (x forward between the fingertips, y across the fingers).
#: The servo box behind the bar, the bar holding the fingers (0.12 m across), the tag plate
#: on top.
GRIPPER_BODY_SPHERES: tuple[tuple[tuple[float, float, float], float], ...] = (
    ((-0.105, 0.0, 0.0), 0.032),
    ((-0.085, 0.0, 0.0), 0.032),
    *(((-0.052, float(y), 0.0), 0.015) for y in np.linspace(-0.05, 0.05, 6)),
    ((-0.1, 0.0, 0.035), 0.02),
)
#: The finger pads: 68 mm long (from 1 mm behind the finger link), 12 mm thick, 24 mm high;
#: two rows of spheres (6 mm above and below the pad's middle) 8.5 mm in radius cover its
#: cross-section (half-diagonal 8.5 mm) and add 2.5 mm to its faces.
PAD_X = np.linspace(
    FINGER_LINK_X - EE_GRIPPER_X - 0.001 + 0.008, FINGER_LINK_X - EE_GRIPPER_X + 0.067 - 0.004, 9
)
PAD_Z = (-0.006, 0.006)
PAD_RADIUS = 0.0085


def gripper_spheres(finger: float) -> tuple[Array, Array]:
    """(centres (S, 3) in the ee frame, radii (S,)): the gripper body and both finger pads
    with each finger ``finger`` m from the centre line (the finger joint's value)."""
    centres = [c for c, _ in GRIPPER_BODY_SPHERES]
    radii = [r for _, r in GRIPPER_BODY_SPHERES]
    y = finger - 0.5 * FINGER_PAD_INSET
    for side in (1.0, -1.0):
        for x in PAD_X:
            for z in PAD_Z:
                centres.append((float(x), side * y, z))
                radii.append(PAD_RADIUS)
    return np.array(centres, dtype=float), np.array(radii, dtype=float)


def arm_spheres(
    Q: ArrayLike,
    finger: float | Sequence[float],
    model: ArmModel = VX300S,
) -> tuple[Array, Array]:
    """Sphere centres (N, S, 3) and radii (S,) of the arm at the joint configurations ``Q``
    (N, 6), the fingers at ``finger`` (one value, or several: the spheres of each opening are
    all included, so a closing motion's swept volume is covered)."""
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    n = len(Q)
    openings = [finger] if isinstance(finger, (int, float)) else [float(f) for f in finger]
    # Link spheres: a point on link i goes to fk(q with the joints after i zero) M^-1 p_home.
    groups = sorted({m for _, _, m in LINK_SPHERES})
    link_c = np.zeros((n, len(LINK_SPHERES), 3))
    for m in groups:
        Qm = np.zeros_like(Q)
        Qm[:, :m] = Q[:, :m]
        T = fk(Qm, model) @ inv_T(model.M)
        T = T.reshape(n, 4, 4)
        ks = [k for k, (_, _, mm) in enumerate(LINK_SPHERES) if mm == m]
        P = np.array([LINK_SPHERES[k][0] for k in ks], dtype=float)
        link_c[:, ks] = np.einsum("nij,kj->nki", T[:, :3, :3], P) + T[:, None, :3, 3]
    link_r = np.array([r for _, r, _ in LINK_SPHERES], dtype=float)
    ee_c, ee_r = [], []
    for f in openings:
        c, r = gripper_spheres(f)
        ee_c.append(c)
        ee_r.append(r)
    C_ee = np.concatenate(ee_c)
    T_ee = fk(Q, model).reshape(n, 4, 4)
    grip_c = np.einsum("nij,kj->nki", T_ee[:, :3, :3], C_ee) + T_ee[:, None, :3, 3]
    return np.concatenate([link_c, grip_c], axis=1), np.concatenate([link_r, *ee_r])


def _body_arrays(bodies: Sequence[Body]) -> tuple[Array, Array, Array, Array]:
    xy = np.array([b.xy for b in bodies], dtype=float).reshape(-1, 2)
    r = np.array([b.radius for b in bodies], dtype=float)
    bottom = np.array([b.bottom for b in bodies], dtype=float)
    top = np.array([b.top for b in bodies], dtype=float)
    return xy, r, bottom, top


def cylinder_distances(p: Array, bodies: Sequence[Body]) -> Array:
    """Signed distance (..., K) of points ``p`` (..., 3) to each body's cylinder (the module
    docstring's formula)."""
    xy, r, bottom, top = _body_arrays(bodies)
    d_xy = np.linalg.norm(p[..., None, :2] - xy, axis=-1) - r
    d_z = np.maximum(bottom - p[..., None, 2], p[..., None, 2] - top)
    return signed_gap(d_xy, d_z)


def signed_gap(d_xy: Array, d_z: Array) -> Array:
    """The signed distance between a vertical cylinder and a point or another vertical
    cylinder from their gaps across (``d_xy``) and in height (``d_z``), each negative where
    they overlap that way: hypot of both where both are positive, else the larger."""
    outside = np.hypot(np.maximum(d_xy, 0.0), np.maximum(d_z, 0.0))
    return np.where((d_xy > 0.0) & (d_z > 0.0), outside, np.maximum(d_xy, d_z))


def clearances(
    centres: Array, radii: Array, bodies: Sequence[Body], table_z: float | None
) -> tuple[Array, Array]:
    """(least clearance (N,), the body it is to (N,), -1 for the table) of the spheres
    (N, S, 3) with radii (S,) to ``bodies`` and the table at ``table_z`` (None: no table)."""
    n = centres.shape[0]
    best = np.full(n, np.inf)
    which = np.full(n, -2, dtype=int)
    if bodies:
        d = cylinder_distances(centres, bodies) - radii[None, :, None]  # (N, S, K)
        flat = d.reshape(n, -1)
        k = np.argmin(flat, axis=1)
        best = flat[np.arange(n), k]
        which = k % len(bodies)
    if table_z is not None:
        above = np.min(centres[..., 2] - radii[None, :], axis=1) - table_z
        lower = above < best
        best = np.where(lower, above, best)
        which = np.where(lower, -1, which)
    return best, which
