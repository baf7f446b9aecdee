"""The robot's own points in a depth cloud: capsules around the ViperX-300s' links, placed by
forward kinematics, and the filter that drops the points inside them.

A detector that knows the camera pose (``T_base_cam``) and the joint angles at capture uses
:func:`self_mask` so the arm is never reported as a bottle or a cup.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import inv_T, transform_points
from armvision.robot.kinematics import VX300S, ArmModel, fk

Array = NDArray[np.float64]


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


def self_mask(
    p_cam: Array,
    T_base_cam: Array,
    joint_positions: ArrayLike | None,
    *,
    workspace_radius: float,
    margin: float,
    capsules: Sequence[tuple[Any, Any, float, int]] = VX300S_CAPSULES,
    model: ArmModel = VX300S,
) -> NDArray[np.bool_]:
    """Which camera-frame points (N, 3) to keep: within ``workspace_radius`` of the base axis
    and farther than ``margin`` from every link capsule.

    Without ``joint_positions`` only the first capsule (the base, which does not move) is
    used; the moving links are then kept.
    """
    keep = np.ones(len(p_cam), dtype=bool)
    if len(p_cam) == 0:
        return keep
    p_base = transform_points(T_base_cam, p_cam)
    # Contiguous columns: comparisons on them cost a fraction of those on (N, 3) rows.
    x, y, z = np.ascontiguousarray(p_base.T)
    keep &= np.hypot(x, y) < workspace_radius
    if joint_positions is not None:
        a, b, radii = arm_capsules_base(joint_positions, capsules, model)
    else:  # the base does not move: drop it even without joint angles
        base = capsules[0]
        a, b = np.array([base[0]], float), np.array([base[1]], float)
        radii = np.array([base[2]], float)
    # Only points inside a capsule's bounding box can be within it: the distances to its
    # segment are computed for those alone (most of a table's points are far away).
    reach = radii + margin
    lo, hi = np.minimum(a, b) - reach[:, None], np.maximum(a, b) + reach[:, None]
    # First against the box around them all (one test per point), then per capsule.
    (x0, y0, z0), (x1, y1, z1) = lo.min(axis=0), hi.max(axis=0)
    inside = np.flatnonzero(
        keep & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (z >= z0) & (z <= z1)
    )
    x, y, z = x[inside], y[inside], z[inside]
    for k, ((x0, y0, z0), (x1, y1, z1)) in enumerate(zip(lo, hi)):
        boxed = np.flatnonzero(
            (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (z >= z0) & (z <= z1)
        )
        if len(boxed):
            near = segment_distances(p_base[inside[boxed]], a[k : k + 1], b[k : k + 1])
            keep[inside[boxed[near[:, 0] < reach[k]]]] = False
    return keep
