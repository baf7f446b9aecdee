"""SE(3) helpers on numpy arrays.

Convention (ARCHITECTURE.md): ``T_a_b`` is the pose of frame b in frame a, a 4x4 homogeneous
matrix, so ``p_a = T_a_b @ p_b`` and ``T_a_c = T_a_b @ T_b_c``. Points are ``(N, 3)`` arrays.
Rotation parametrisations are delegated to ``scipy.spatial.transform.Rotation``, except the
single-rotation :func:`rotation_between`, written out for speed.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]


def make_T(R: ArrayLike | None = None, p: ArrayLike | None = None) -> Array:
    """Homogeneous transform from a rotation matrix ``R`` (default I) and a translation ``p``."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=float)
    if p is not None:
        T[:3, 3] = np.asarray(p, dtype=float)
    return T


def inv_T(T_a_b: ArrayLike) -> Array:
    """``T_b_a`` from ``T_a_b`` as (R^T, -R^T p), exact for rigid transforms; on (..., 4, 4)."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    R_t = np.swapaxes(T_a_b[..., :3, :3], -1, -2)
    T_b_a = np.zeros_like(T_a_b)
    T_b_a[..., :3, :3] = R_t
    T_b_a[..., :3, 3] = -np.einsum("...ij,...j->...i", R_t, T_a_b[..., :3, 3])
    T_b_a[..., 3, 3] = 1.0
    return T_b_a


def transform_points(T_a_b: ArrayLike, p_b: ArrayLike) -> Array:
    """Map points ``p_b`` (N, 3) or (3,) given in frame b into frame a."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    p_b = np.asarray(p_b, dtype=float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def rot_x(angle: float) -> Array:
    """Rotation matrix about x by ``angle`` rad."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> Array:
    """Rotation matrix about y by ``angle`` rad."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> Array:
    """Rotation matrix about z by ``angle`` rad."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_to_R(roll: float, pitch: float, yaw: float) -> Array:
    """R = Rz(yaw) Ry(pitch) Rx(roll): fixed-axis roll, pitch, yaw as Interbotix and ROS use."""
    return Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()


def R_to_rpy(R: ArrayLike) -> Array:
    """Inverse of :func:`rpy_to_R`: (roll, pitch, yaw) in rad."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_euler("xyz")


def pose_from_xyz_rpy(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> Array:
    """``T`` with translation (x, y, z) and rotation :func:`rpy_to_R` (roll, pitch, yaw)."""
    return make_T(rpy_to_R(roll, pitch, yaw), [x, y, z])


def rotation_angle(R: ArrayLike) -> Array:
    """Geodesic angle (rad) of rotation matrices (..., 3, 3), from the trace (clipped)."""
    R = np.asarray(R, dtype=float)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def pose_error(T_w_a: ArrayLike, T_w_b: ArrayLike) -> tuple[Array, Array]:
    """Translation distance (m) and rotation angle (rad) between poses (..., 4, 4) in one frame.

    ``T_w_a`` and ``T_w_b`` are the poses of frames a and b in the same frame w.
    """
    T_w_a = np.asarray(T_w_a, dtype=float)
    T_w_b = np.asarray(T_w_b, dtype=float)
    dp = np.linalg.norm(T_w_a[..., :3, 3] - T_w_b[..., :3, 3], axis=-1)
    R_rel = np.swapaxes(T_w_a[..., :3, :3], -1, -2) @ T_w_b[..., :3, :3]
    return dp, rotation_angle(R_rel)


def as_xyz(p: ArrayLike) -> tuple[float, float, float]:
    """A 3-vector as three plain floats (for reports and JSON)."""
    x, y, z = (float(v) for v in np.asarray(p, dtype=float).reshape(3))
    return x, y, z


def cross3(a: ArrayLike, b: ArrayLike) -> Array:
    """a x b for two 3-vectors. Written out: np.cross costs ~15x as much per call on single
    vectors (its axis handling), and perception takes a few per object per frame."""
    a0, a1, a2 = np.asarray(a, dtype=float).ravel().tolist()
    b0, b1, b2 = np.asarray(b, dtype=float).ravel().tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def skew(v: ArrayLike) -> Array:
    """[v]x, the 3x3 matrix with [v]x w = v x w."""
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_between(a: ArrayLike, b: ArrayLike) -> Array:
    """The smallest rotation taking unit direction ``a`` onto unit direction ``b``.

    Rodrigues' formula R = I + sin(theta) K + 2 sin^2(theta / 2) K^2 (K = [k]x, k the unit
    axis a x b) on plain floats: scipy's Rotation.from_rotvec costs ~20x as much for one
    rotation, and the tag poses take one per tag per frame. Opposite directions: a turn by
    pi about an axis normal to ``a``, R = 2 k k^T - I. A zero direction gives NaNs.
    """
    a0, a1, a2 = np.asarray(a, dtype=float).ravel().tolist()
    b0, b1, b2 = np.asarray(b, dtype=float).ravel().tolist()
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if not (na > 0.0 and nb > 0.0):
        return np.full((3, 3), np.nan)
    u0, u1, u2 = a0 / na, a1 / na, a2 / na
    w0, w1, w2 = b0 / nb, b1 / nb, b2 / nb
    k0, k1, k2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
    s = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    c = u0 * w0 + u1 * w1 + u2 * w2
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite directions: turn by pi about any axis normal to a.
        k0, k1, k2 = (0.0, u2, -u1) if abs(u0) < 0.9 else (-u2, 0.0, u0)  # u x e_x or u x e_y
        n = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
        k0, k1, k2 = k0 / n, k1 / n, k2 / n
        return np.array(
            [
                [2.0 * k0 * k0 - 1.0, 2.0 * k0 * k1, 2.0 * k0 * k2],
                [2.0 * k1 * k0, 2.0 * k1 * k1 - 1.0, 2.0 * k1 * k2],
                [2.0 * k2 * k0, 2.0 * k2 * k1, 2.0 * k2 * k2 - 1.0],
            ]
        )
    k0, k1, k2 = k0 / s, k1 / s, k2 / s
    theta = math.atan2(s, c)
    st = math.sin(theta)
    vt = 2.0 * math.sin(0.5 * theta) ** 2  # 1 - cos(theta), without the cancellation
    # I + st K + vt (k k^T - I)
    return np.array(
        [
            [1.0 - vt + vt * k0 * k0, vt * k0 * k1 - st * k2, vt * k0 * k2 + st * k1],
            [vt * k1 * k0 + st * k2, 1.0 - vt + vt * k1 * k1, vt * k1 * k2 - st * k0],
            [vt * k2 * k0 - st * k1, vt * k2 * k1 + st * k0, 1.0 - vt + vt * k2 * k2],
        ]
    )


def adjoint(T_a_b: ArrayLike) -> Array:
    """6x6 adjoint Ad(T) mapping twists (omega, v) in frame b to frame a (Modern Robotics 3.20)."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    R, p = T_a_b[:3, :3], T_a_b[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(p) @ R
    return Ad
