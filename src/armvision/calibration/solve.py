"""Solvers for ``T_base_cam`` from gripper-tag samples.

Each sample pairs ``T_base_ee`` (forward kinematics of the joint readings) with ``T_cam_tag``
(the tag's pose as the camera measured it). The tag sits at ``offset_ee`` in the ee frame
(rotation :data:`armvision.robot.tag_mount.R_EE_TAG`), so every sample gives one point twice:
``p_cam = T_cam_tag[:3, 3]`` and ``p_base = T_base_ee @ offset_ee``, related by the rigid
``p_base = T_base_cam @ p_cam``.

Methods (:data:`METHODS`), all on the same samples:

* ``svd`` -- the paper's: rigid registration of the tag centres (Arun, Huang & Blostein 1987;
  Umeyama 1991), which needs only the positions, the best-measured part of a tag pose.
* ``robust_svd`` -- ``svd`` that drops samples whose residual stands out (a mis-detection, a
  pose where the arm had not settled) one at a time and reports them.
* ``joint`` -- scipy least squares over ``T_base_cam`` *and* the tag's offset in the ee
  frame, started from ``robust_svd``, robust loss, then outliers dropped: a tag mount that is
  a centimetre off no longer biases the camera pose.
* ``joint_kinematic`` -- ``joint`` plus the zero offsets of the shoulder, elbow, forearm-roll
  and wrist-angle encoders. The default: on the benchmark (README, "Measured figures") it
  matches ``joint`` when the encoders are perfect and does better when they carry zero
  offsets, as real servos do, and like ``joint`` it survives a wrong ``tag.offset_ee``.
* ``tsai``, ``park``, ``horaud``, ``andreff``, ``daniilidis`` -- OpenCV ``calibrateHandEye``,
  eye-to-hand: it is given base-to-gripper (``T_ee_base``) where eye-in-hand takes
  gripper-to-base, and its "camera-to-gripper" answer is then camera-to-base.
* ``shah``, ``li`` -- OpenCV ``calibrateRobotWorldHandEye``, solving ``A X = Z B`` with
  A = ``T_tag_cam``, B = ``T_ee_base``, X = ``T_cam_base``, Z = ``T_tag_ee``.

The OpenCV methods use the full tag poses, so they also depend on the tag's measured
rotation, which is several times noisier than its position; the table in the README shows
what that costs. Every fit reports per-sample residuals the same way: the distance, in the
base frame, between where the camera puts the tag centre and where the kinematics put it
(with the method's own tag offset).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from armvision.errors import CalibrationError
from armvision.geometry import inv_T, make_T
from armvision.robot.kinematics import fk

Array = NDArray[np.float64]

#: Default tag offset in the ee frame, the paper's mount (``config.tag.offset_ee``).
DEFAULT_OFFSET_EE = (-0.1, 0.0, 0.03)


@dataclass(frozen=True, eq=False)
class PointFit:
    """A rigid fit ``p_base ~ T_base_cam @ p_cam``; ``residuals`` (N,) metres per point."""

    T_base_cam: Array
    residuals: Array


@dataclass(frozen=True, eq=False)
class Fit:
    """One method's answer on a set of samples.

    ``residuals`` (N,) metres for every sample, ``used`` (N,) which samples the answer rests on
    (robust methods drop some), ``offset_ee`` the tag offset the method used or estimated,
    ``joint_offsets`` (6,) the encoder zero offsets a kinematic method estimated (the true
    angle is the reading minus the offset).
    """

    method: str
    T_base_cam: Array
    residuals: Array
    used: NDArray[np.bool_]
    offset_ee: Array
    notes: tuple[str, ...] = field(default=())
    joint_offsets: Array | None = None  # rad, only from methods that estimate them

    @property
    def dropped(self) -> list[int]:
        """Indices of the samples left out of the answer."""
        return [int(i) for i in np.flatnonzero(~self.used)]

    @property
    def rms_m(self) -> float:
        """RMS residual over the samples used, metres."""
        r = self.residuals[self.used]
        return float(np.sqrt(np.mean(r**2))) if r.size else math.nan

    @property
    def max_m(self) -> float:
        """Largest residual over the samples used, metres."""
        r = self.residuals[self.used]
        return float(np.max(r)) if r.size else math.nan


def _as_points(points: ArrayLike, name: str) -> Array:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise CalibrationError(f"{name} must be an (N, 3) array of points, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise CalibrationError(f"{name} holds non-finite values (NaN or inf)")
    return p


def solve_points(p_cam: ArrayLike, p_base: ArrayLike, weights: ArrayLike | None = None) -> PointFit:
    """Least-squares rigid transform with ``p_base ~ T_base_cam @ p_cam`` (Kabsch/Umeyama).

    ``weights`` (N,) non-negative, e.g. inverse variances; None weighs all points equally.
    When the best orthogonal fit is a reflection (coplanar points, or enough noise), the
    sign is corrected on the smallest singular direction, which is Umeyama's least-squares
    rotation; negating a column of R after the fact, as some implementations do, is not.
    Needs three points that are not on one line.
    """
    pc = _as_points(p_cam, "p_cam")
    pb = _as_points(p_base, "p_base")
    if pc.shape != pb.shape:
        raise CalibrationError(
            f"p_cam and p_base must pair up point for point, got {pc.shape} and {pb.shape}"
        )
    n = len(pc)
    if n < 3:
        raise CalibrationError(f"a rigid fit needs at least 3 points, got {n}")
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise CalibrationError(
            f"weights must be {n} finite non-negative numbers, not all zero; got {w!r}"
        )
    w = w / w.sum()
    c_cam = w @ pc
    c_base = w @ pb
    H = (pc - c_cam).T @ ((pb - c_base) * w[:, None])
    U, S, Vt = np.linalg.svd(H)
    if S[1] <= 1e-12 * max(S[0], 1e-300):
        raise CalibrationError(
            "the points lie on one line (or coincide), so the rotation about that line is"
            " undetermined: sample the tag at positions spread in more than one direction"
        )
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    T = make_T(R, c_base - R @ c_cam)
    return PointFit(T, point_residuals(T, pc, pb))


def point_residuals(T_base_cam: Array, p_cam: Array, p_base: Array) -> Array:
    """Per point, the distance between ``T_base_cam @ p_cam`` and ``p_base``, metres."""
    return np.linalg.norm(p_cam @ T_base_cam[:3, :3].T + T_base_cam[:3, 3] - p_base, axis=1)


def _check_poses(T: ArrayLike, name: str) -> Array:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise CalibrationError(f"{name} must be an (N, 4, 4) stack of poses, got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise CalibrationError(f"{name} holds non-finite values")
    return T


def tag_points(
    T_base_ee: ArrayLike, T_cam_tag: ArrayLike, offset_ee: ArrayLike = DEFAULT_OFFSET_EE
) -> tuple[Array, Array]:
    """The paired tag centres ``(p_cam, p_base)`` of a set of samples."""
    T_be = _check_poses(T_base_ee, "T_base_ee")
    T_ct = _check_poses(T_cam_tag, "T_cam_tag")
    if len(T_be) != len(T_ct):
        raise CalibrationError(f"{len(T_be)} ee poses but {len(T_ct)} tag poses")
    o = np.asarray(offset_ee, dtype=float).reshape(3)
    p_base = np.einsum("nij,j->ni", T_be[:, :3, :3], o) + T_be[:, :3, 3]
    return T_ct[:, :3, 3].copy(), p_base


def _residuals(
    T_base_cam: Array, T_base_ee: Array, T_cam_tag: Array, offset_ee: ArrayLike
) -> Array:
    return point_residuals(T_base_cam, *tag_points(T_base_ee, T_cam_tag, offset_ee))


def _outlier_threshold(residuals: Array, floor_m: float) -> float:
    """3 robust sigmas (MAD of the residuals) or ``floor_m``, whichever is larger."""
    sigma = 1.4826 * float(np.median(residuals))
    return max(3.0 * sigma, floor_m)


def solve_svd(
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
    offset_ee: ArrayLike = DEFAULT_OFFSET_EE,
    outlier_m: float = 0.005,
    min_samples: int = 3,
    joint_positions: ArrayLike | None = None,
) -> Fit:
    """The paper's method: rigid SVD registration of the tag centres, every sample counted."""
    p_cam, p_base = tag_points(T_base_ee, T_cam_tag, offset_ee)
    fit = solve_points(p_cam, p_base)
    return Fit(
        "svd", fit.T_base_cam, fit.residuals, np.ones(len(p_cam), bool), np.asarray(offset_ee)
    )


def solve_robust_svd(
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
    offset_ee: ArrayLike = DEFAULT_OFFSET_EE,
    outlier_m: float = 0.005,
    min_samples: int = 3,
    joint_positions: ArrayLike | None = None,
) -> Fit:
    """SVD that drops the worst sample while it exceeds max(3 robust sigmas, ``outlier_m``).

    Stops at ``min_samples``; the dropped samples are listed in the fit's notes.
    """
    p_cam, p_base = tag_points(T_base_ee, T_cam_tag, offset_ee)
    used = np.ones(len(p_cam), bool)
    notes: list[str] = []
    while True:
        fit = solve_points(p_cam[used], p_base[used])
        residuals = point_residuals(fit.T_base_cam, p_cam, p_base)
        threshold = _outlier_threshold(residuals[used], outlier_m)
        worst = int(np.argmax(np.where(used, residuals, -1.0)))
        if residuals[worst] <= threshold or used.sum() <= max(min_samples, 3):
            break
        used[worst] = False
        notes.append(
            f"sample {worst} dropped: residual {1000 * residuals[worst]:.1f} mm"
            f" > {1000 * threshold:.1f} mm"
        )
    return Fit("robust_svd", fit.T_base_cam, residuals, used, np.asarray(offset_ee), tuple(notes))


#: Joints whose zero offsets ``joint_kinematic`` estimates: shoulder, elbow, forearm roll and
#: wrist angle. The waist's offset is a turn of the whole base about its axis, which no camera
#: can tell from a turn of the camera; the wrist-rotate offset moves the tag centre exactly as a
#: change of the tag offset does. Both stay in the calibration's error budget (see README).
KINEMATIC_JOINTS = (1, 2, 3, 4)


def _refine(
    name: str,
    T_be: Array,
    T_ct: Array,
    offset_ee: ArrayLike,
    outlier_m: float,
    min_samples: int,
    joint_positions: Array | None = None,
    joints: tuple[int, ...] = (),
) -> Fit:
    """Least squares over the camera pose, the tag offset and ``joints``' zero offsets."""
    if joints and joint_positions is None:
        raise ValueError("estimating joint zero offsets needs the joint positions")
    start = solve_robust_svd(T_be, T_ct, offset_ee, outlier_m, min_samples)
    p_cam = T_ct[:, :3, 3]
    k = len(joints)

    def unpack(x: Array) -> tuple[Array, Array, Array]:
        dq = np.zeros(6)
        dq[list(joints)] = x[9:]
        return make_T(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:6]), x[6:9], dq

    def kinematics(dq: Array) -> Array:
        return T_be if not k or joint_positions is None else fk(joint_positions - dq)

    def residual_vector(x: Array, mask: Array) -> Array:
        T, o, dq = unpack(x)
        T_ee = kinematics(dq)[mask]
        predicted = p_cam[mask] @ T[:3, :3].T + T[:3, 3]
        measured = np.einsum("nij,j->ni", T_ee[:, :3, :3], o) + T_ee[:, :3, 3]
        return (predicted - measured).ravel()

    x0 = np.concatenate(
        [
            Rotation.from_matrix(start.T_base_cam[:3, :3]).as_rotvec(),
            start.T_base_cam[:3, 3],
            np.asarray(offset_ee, dtype=float),
            np.zeros(k),
        ]
    )
    notes = list(start.notes)
    # Is the offset observable? The ee rotations must span more than one axis direction.
    R_flat = T_be[:, :3, :3].reshape(len(T_be), 9)
    spread = np.linalg.svd(R_flat - R_flat.mean(0), compute_uv=False)
    too_few = len(T_be) < 4 + 2 * k
    if too_few or spread[1] < 0.05:
        notes.append(
            f"{len(T_be)} samples are too few to estimate {9 + k} unknowns"
            if too_few
            else "ee orientations too alike to estimate the tag offset"
        )
        notes[-1] += "; the robust SVD answer with the configured offset is kept"
        return Fit(
            name, start.T_base_cam, start.residuals, start.used, start.offset_ee, tuple(notes)
        )

    def residuals_of(x: Array) -> Array:
        T, o, dq = unpack(x)
        return _residuals(T, kinematics(dq), T_ct, o)

    everyone = np.ones(len(T_be), bool)
    first = least_squares(
        residual_vector, x0, args=(everyone,), loss="soft_l1", f_scale=outlier_m / 3.0
    )
    residuals = residuals_of(first.x)
    threshold = _outlier_threshold(residuals, outlier_m)
    used = residuals <= threshold
    if used.sum() < max(min_samples, 4 + 2 * k):
        used = everyone.copy()
    for i in np.flatnonzero(~used):
        notes.append(
            f"sample {i} dropped: residual {1000 * residuals[i]:.1f} mm > {1000 * threshold:.1f} mm"
        )
    final = least_squares(residual_vector, first.x, args=(used,))
    T, o, dq = unpack(final.x)
    moved = 1000 * np.linalg.norm(o - np.asarray(offset_ee, dtype=float))
    notes.append(
        f"tag offset estimated {np.round(1000 * o, 1).tolist()} mm"
        f" ({moved:.1f} mm from the configured one)"
    )
    if k:
        notes.append(f"joint zero offsets estimated {np.round(np.degrees(dq), 3).tolist()} deg")
    return Fit(name, T, residuals_of(final.x), used, o, tuple(notes), dq if k else None)


def solve_joint(
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
    offset_ee: ArrayLike = DEFAULT_OFFSET_EE,
    outlier_m: float = 0.005,
    min_samples: int = 3,
    joint_positions: ArrayLike | None = None,
) -> Fit:
    """``T_base_cam`` and the tag offset together, by nonlinear least squares.

    Unknowns: the camera's rotation (rotation vector) and position, and the tag centre in the
    ee frame; residuals: the tag centres' 3-D disagreement. Started from ``robust_svd`` with
    the configured offset; a soft-L1 loss (scale ``outlier_m`` / 3) keeps outliers from
    pulling, after which samples beyond the robust threshold are dropped and the fit is
    repeated with plain least squares. The offset is observable only when the ee orientation
    varies between samples, which the sampling plan ensures; with too little variation the
    configured offset is kept (see the notes).
    """
    T_be = _check_poses(T_base_ee, "T_base_ee")
    T_ct = _check_poses(T_cam_tag, "T_cam_tag")
    return _refine("joint", T_be, T_ct, offset_ee, outlier_m, min_samples)


def solve_joint_kinematic(
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
    offset_ee: ArrayLike = DEFAULT_OFFSET_EE,
    outlier_m: float = 0.005,
    min_samples: int = 3,
    joint_positions: ArrayLike | None = None,
) -> Fit:
    """``joint`` plus the zero offsets of :data:`KINEMATIC_JOINTS` (needs the joint readings).

    An encoder whose zero is a fraction of a degree off bends every ee pose the kinematics
    report, which a rigid camera pose cannot absorb; estimating those offsets with the camera
    removes their share of the error. The kinematics are then fk(q - offsets); the offsets
    are in the fit (``joint_offsets``) and the calibration file.
    """
    T_be = _check_poses(T_base_ee, "T_base_ee")
    T_ct = _check_poses(T_cam_tag, "T_cam_tag")
    if joint_positions is None:
        raise CalibrationError("joint_kinematic needs the joint readings of every sample")
    q = np.asarray(joint_positions, dtype=float)
    if q.shape != (len(T_be), 6) or not np.all(np.isfinite(q)):
        raise CalibrationError(
            f"joint_positions must be ({len(T_be)}, 6) finite angles, got shape {q.shape}"
        )
    return _refine(
        "joint_kinematic", T_be, T_ct, offset_ee, outlier_m, min_samples, q, KINEMATIC_JOINTS
    )


_HAND_EYE = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
_ROBOT_WORLD = {
    "shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}


def _split(
    T: NDArray[np.floating],
) -> tuple[list[NDArray[np.floating]], list[NDArray[np.floating]]]:
    return [R.copy() for R in T[:, :3, :3]], [t.reshape(3, 1).copy() for t in T[:, :3, 3]]


def _offset_from(T_base_cam: Array, T_be: Array, T_ct: Array) -> Array:
    """The tag centre in the ee frame implied by a camera pose, averaged over the samples."""
    T_ee_tag = np.linalg.inv(T_be) @ T_base_cam @ T_ct
    return T_ee_tag[:, :3, 3].mean(axis=0)


def solve_opencv(
    method: str,
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
) -> Fit:
    """One of OpenCV's hand-eye solvers (see the module docstring), eye-to-hand."""
    T_be = _check_poses(T_base_ee, "T_base_ee")
    T_ct = _check_poses(T_cam_tag, "T_cam_tag")
    if len(T_be) < 3:
        raise CalibrationError(f"hand-eye calibration needs at least 3 poses, got {len(T_be)}")
    T_ee_base = np.linalg.inv(T_be)
    try:
        if method in _HAND_EYE:
            R_gb, t_gb = _split(T_ee_base)
            R_tc, t_tc = _split(T_ct)
            R, t = cv2.calibrateHandEye(R_gb, t_gb, R_tc, t_tc, method=_HAND_EYE[method])
            T_base_cam = make_T(R, t.reshape(3))
            offset = _offset_from(T_base_cam, T_be, T_ct)
        elif method in _ROBOT_WORLD:
            R_wc, t_wc = _split(np.linalg.inv(T_ct))  # "world to camera" = T_tag_cam
            R_bg, t_bg = _split(T_ee_base)  # "base to gripper" = T_ee_base
            R_cb, t_cb, R_te, t_te = cv2.calibrateRobotWorldHandEye(
                R_wc, t_wc, R_bg, t_bg, method=_ROBOT_WORLD[method]
            )
            T_base_cam = inv_T(make_T(R_cb, t_cb.reshape(3)))
            offset = inv_T(make_T(R_te, t_te.reshape(3)))[:3, 3]
        else:
            raise CalibrationError(f"unknown OpenCV hand-eye method {method!r}")
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV {method} failed: {exc.err}") from exc
    if not np.all(np.isfinite(T_base_cam)):
        raise CalibrationError(
            f"OpenCV {method} returned no answer: the poses need rotations about at least two"
            " different axes"
        )
    # OpenCV may return a slightly non-orthonormal R; project it onto SO(3) for consistency.
    T_base_cam[:3, :3] = Rotation.from_matrix(T_base_cam[:3, :3]).as_matrix()
    residuals = _residuals(T_base_cam, T_be, T_ct, offset)
    return Fit(method, T_base_cam, residuals, np.ones(len(T_be), bool), np.asarray(offset))


def _opencv(method: str) -> Callable[..., Fit]:
    def solve(
        T_base_ee,
        T_cam_tag,
        offset_ee=DEFAULT_OFFSET_EE,
        outlier_m=0.005,
        min_samples=3,
        joint_positions=None,
    ) -> Fit:
        return solve_opencv(method, T_base_ee, T_cam_tag)

    solve.__doc__ = f"OpenCV's {method} hand-eye solver (the tag offset is estimated by it)."
    return solve


#: Every solver by name, each
#: ``f(T_base_ee, T_cam_tag, offset_ee, outlier_m, min_samples, joint_positions=None)``.
METHODS: dict[str, Callable[..., Fit]] = {
    "svd": solve_svd,
    "robust_svd": solve_robust_svd,
    "joint": solve_joint,
    "joint_kinematic": solve_joint_kinematic,
    **{name: _opencv(name) for name in (*_HAND_EYE, *_ROBOT_WORLD)},
}

#: The default method and why: see the module docstring and README.
DEFAULT_METHOD = "joint_kinematic"


def solve(
    T_base_ee: ArrayLike,
    T_cam_tag: ArrayLike,
    method: str = DEFAULT_METHOD,
    offset_ee: ArrayLike = DEFAULT_OFFSET_EE,
    outlier_m: float = 0.005,
    min_samples: int = 3,
    joint_positions: ArrayLike | None = None,
) -> Fit:
    """``T_base_cam`` from samples by the named method (see :data:`METHODS`)."""
    if method not in METHODS:
        raise CalibrationError(
            f"unknown calibration method {method!r}; use one of {', '.join(METHODS)}"
        )
    return METHODS[method](T_base_ee, T_cam_tag, offset_ee, outlier_m, min_samples, joint_positions)
