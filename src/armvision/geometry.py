"""SE(3) helpers on numpy arrays.

Convention (ARCHITECTURE.md): ``T_a_b`` is the pose of frame b in frame a, a 4x4 homogeneous
matrix, so ``p_a = T_a_b @ p_b`` and ``T_a_c = T_a_b @ T_b_c``. Points are ``(N, 3)`` arrays.
Rotation parametrisations are delegated to ``scipy.spatial.transform.Rotation``.
"""

from __future__ import annotations

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
    a0, a1, a2 = (float(v) for v in np.ravel(a))
    b0, b1, b2 = (float(v) for v in np.ravel(b))
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def skew(v: ArrayLike) -> Array:
    """[v]x, the 3x3 matrix with [v]x w = v x w."""
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_between(a: ArrayLike, b: ArrayLike) -> Array:
    """The smallest rotation taking unit direction ``a`` onto unit direction ``b``."""
    u = np.asarray(a, dtype=float) / np.linalg.norm(a)
    w = np.asarray(b, dtype=float) / np.linalg.norm(b)
    axis = np.cross(u, w)
    s, c = np.linalg.norm(axis), float(np.dot(u, w))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite directions: turn by pi about any axis normal to a.
        normal = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * normal / np.linalg.norm(normal)).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def adjoint(T_a_b: ArrayLike) -> Array:
    """6x6 adjoint Ad(T) mapping twists (omega, v) in frame b to frame a (Modern Robotics 3.20)."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    R, p = T_a_b[:3, :3], T_a_b[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(p) @ R
    return Ad
