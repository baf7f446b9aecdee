"""The robot's own points in a depth cloud: capsules around the ViperX-300s' links, placed by
forward kinematics, and the filter that drops the points inside them.

A detector that knows the camera pose (``T_base_cam``) and the joint angles at capture uses
:func:`self_mask` so the arm is never reported as a bottle or a cup.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import inv_T
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
    p_cam = np.ascontiguousarray(p_cam, dtype=float).reshape(-1, 3)
    if joint_positions is not None:
        a, b, radii = arm_capsules_base(joint_positions, capsules, model)
    else:  # the base does not move: drop it even without joint angles
        base = capsules[0]
        a, b = np.array([base[0]], float), np.array([base[1]], float)
        radii = np.array([base[2]], float)
    return _self_mask_kernel(
        p_cam,
        np.ascontiguousarray(T_base_cam, dtype=float),
        np.ascontiguousarray(a),
        np.ascontiguousarray(b),
        radii + margin,
        float(workspace_radius),
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _self_mask_kernel(
    p_cam: Array, T_base_cam: Array, a: Array, b: Array, reach: Array, workspace_radius: float
) -> NDArray[np.bool_]:
    """:func:`self_mask`'s test, compiled (numpy's calls on the cloud's columns cost about
    0.6 ms a frame): a point is kept within ``workspace_radius`` of the base's z axis and
    farther than ``reach[k]`` from every segment a[k]-b[k] (base frame); the distances are
    computed only for points inside a capsule's bounding box."""
    n, m = len(p_cam), len(a)
    lo, hi = np.empty((m, 3)), np.empty((m, 3))
    for k in range(m):
        for j in range(3):
            lo[k, j] = min(a[k, j], b[k, j]) - reach[k]
            hi[k, j] = max(a[k, j], b[k, j]) + reach[k]
    keep = np.empty(n, dtype=np.bool_)
    R, t = T_base_cam[:3, :3], T_base_cam[:3, 3]
    for i in range(n):
        px, py, pz = p_cam[i, 0], p_cam[i, 1], p_cam[i, 2]
        x = px * R[0, 0] + py * R[0, 1] + pz * R[0, 2] + t[0]
        y = px * R[1, 0] + py * R[1, 1] + pz * R[1, 2] + t[1]
        z = px * R[2, 0] + py * R[2, 1] + pz * R[2, 2] + t[2]
        kept = math.hypot(x, y) < workspace_radius
        for k in range(m):
            if not kept:
                break
            if not (lo[k, 0] <= x <= hi[k, 0] and lo[k, 1] <= y <= hi[k, 1]):
                continue
            if not lo[k, 2] <= z <= hi[k, 2]:
                continue
            # The distance to the segment: from its closest point, a + s (b - a), s in [0, 1].
            ux, uy, uz = b[k, 0] - a[k, 0], b[k, 1] - a[k, 1], b[k, 2] - a[k, 2]
            wx, wy, wz = x - a[k, 0], y - a[k, 1], z - a[k, 2]
            s = (wx * ux + wy * uy + wz * uz) / max(ux * ux + uy * uy + uz * uz, 1e-12)
            s = min(max(s, 0.0), 1.0)
            dx, dy, dz = wx - s * ux, wy - s * uy, wz - s * uz
            kept = math.sqrt(dx * dx + dy * dy + dz * dz) >= reach[k]
        keep[i] = kept
    return keep
