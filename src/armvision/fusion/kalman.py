"""Kalman filters: the paper's 7-state filter, and the default end-effector fusion filter.

Frames and units as everywhere (ARCHITECTURE.md): ``base`` is the robot's base_link, ``cam``
the colour optical frame, ``T_a_b`` the pose of b in a; metres, radians, seconds.

**The paper's filter** (:class:`PaperKF`), kept for reference and comparison: state
(x, y, z, 1, vx, vy, vz) in the base frame, constant velocity A with the loop period dt, no
input, the encoders' forward kinematics y1 = C1 x with C1 = [I4 0] and the camera's point
y2 = C2 x with C2 = [T^-1 0] (T = ``T_base_cam``, the calibration), both with measurement
covariance diag(1e-4, 1e-4, 1e-4, 1e-12), updated with whichever source is available.

**The default filter** (:class:`EEFilter`) estimates the end effector's position in the base
frame from the same two sources, with what the paper's filter lacks:

- *Motion model*: constant velocity, or constant acceleration as an option, driven by white
  noise of a given spectral density (the continuous white-noise acceleration / jerk models,
  Bar-Shalom, Li & Kirubarajan, "Estimation with Applications to Tracking and Navigation",
  2001, section 6.2); see :func:`motion_model`.
- *Measurement covariance from the sensor models*: the encoders' joint noise (plus the
  Dynamixel's quantisation) mapped through the point Jacobian, R = Jv diag(sigma_q^2) Jv^T
  (:func:`encoder_covariance`); the camera's error across the viewing ray from the pixel noise
  and along it from Intel's depth RMS model, rotated into the base frame
  (:func:`camera_point_covariance`), plus the tag's rotation noise acting on the lever from the
  tag to the end effector.
- *Systematic errors as states*. Both sources are biased, and by more than they are noisy:
  the encoders carry a fixed zero offset per joint (the servo horn; up to 0.3 deg gives a few
  millimetres at the gripper) and the camera carries the calibration's error (2 mm and 0.2 deg
  give 1-4 mm at the gripper). A filter that trusts either one inherits its bias: with the
  encoder channel's Cartesian offset as a random-walk state (``encoder_bias = "cartesian"``)
  the camera fixes the offset and the encoders give smoothness, but the result is exactly as
  biased as the calibration. The default therefore models both errors as they arise, as
  constant states with the sensors' specified spread as prior: six joint offsets b (the
  encoder measurement is fk(q_enc) = p + Jv(q) b) and a small correction xi = (dtheta, dt) of
  the calibration (``T_base_cam_true = T_base_cam exp(xi)``, so the camera measurement is
  p + R [p_cam]x dtheta - R dt), and it adds the tag's orientation as a measurement of both
  (log(R_base_tag,camera R_base_tag,encoders^T) = -R dtheta - Jw b). As the arm moves, the
  offsets of the joints and of the camera act differently on the measurements and the filter
  separates them (the waist offset and a camera rotation about the base z axis stay
  indistinguishable; there the priors share the difference). This is online
  self-calibration as in visual-inertial odometry (e.g. OpenVINS' online camera-IMU
  extrinsics, Geneva et al., ICRA 2020). No ground truth is used: the priors are the sensors'
  specifications in :class:`armvision.config.FusionConfig`.
- *Asynchronous timestamped measurements*: every measurement carries its capture time; the
  filter predicts to it. A measurement older than the state (a camera frame that took 40 ms to
  process while encoder readings kept coming) is inserted where it belongs and the newer ones
  are replayed from a short history (re-filtering, exact for a linear filter); one older than
  ``history_s`` is dropped and counted. Measurements with the same time are stacked into one
  update, so both sources are fused when both are present.
- *Chi-square gating*: a measurement whose normalised innovation squared y^T S^-1 y exceeds
  the ``gate_probability`` quantile of chi-square with dim(y) degrees of freedom is rejected
  (Bar-Shalom et al. 2001, section 3.7). After ``max_rejections`` in a row from one source the
  filter restarts its motion states from that source, so it cannot lock itself out.
- *Innovation-based adaptive process noise*: a fading-memory average of the normalised
  innovation squared per dimension is kept (Bar-Shalom et al. 2001, section 11.2, "adjustable
  level process noise"); while it exceeds ``adaptive_threshold`` the process noise is scaled up
  multiplicatively, and back down to nominal when it falls below, so the filter is smooth when
  the arm is still and follows it when it accelerates.
- *Measured joint velocities* where the arm has them (the Dynamixel driver reads
  Present_Velocity with every position): the end effector's velocity Jv(q) qd, with
  covariance Jv diag(sigma_qd^2) Jv^T, fused with the encoder reading of the same instant as
  a measurement of the velocity states, so that the filter's velocity does not have to be
  inferred from successive positions alone (``fusion.joint_velocities``).
- *Joseph-form update*, P = (I - KH) P (I - KH)^T + K R K^T, symmetrised, so the covariance
  stays symmetric positive definite whatever the gain (:func:`joseph_update`).
"""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from armvision.camera.frames import depth_rms_error
from armvision.config import FusionConfig
from armvision.fusion import FusionError
from armvision.fusion.drift import facing
from armvision.geometry import inv_T, make_T, skew
from armvision.robot.kinematics import VX300S, ArmModel, fk, point_jacobian

Array = NDArray[np.float64]

#: Dynamixel X-series position resolution: readings are whole counts of 2 pi / 4096 rad, a
#: uniform rounding error of variance step^2 / 12 on top of the noise.
ENCODER_COUNTS_PER_TURN = 4096
#: D435i colour stream focal length at 640x480, pixels (used when no intrinsics are given).
DEFAULT_FOCAL_PX = 615.0
#: The adaptive process-noise scale falls by at most this factor per update once the
#: innovations are back to normal, so it relaxes over ~20 updates instead of snapping back.
ADAPTIVE_RELEASE = 0.8
#: A gated-out innovation counts in the adaptive average as at most this many gate widths:
#: enough to raise the process noise quickly in a manoeuvre, bounded for a wild outlier.
ADAPTIVE_NIS_CAP = 10.0
#: Measurements closer in time than this are one event and are fused in one stacked update.
SAME_TIME_S = 1e-6


# --------------------------------------------------------------------------- input checks


def as_array(name: str, value: ArrayLike, shape: tuple[int, ...]) -> Array:
    """``value`` as a float array of ``shape``, or FusionError saying what was wrong."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise FusionError(f"{name} must be numbers with shape {shape}, got {value!r}") from None
    if array.shape != shape:
        raise FusionError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise FusionError(f"{name} has non-finite values ({array.tolist()}); drop that reading")
    return array


def as_time(name: str, t: float) -> float:
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise FusionError(f"{name} must be a time in seconds, got {t!r}") from None
    if not math.isfinite(t):
        raise FusionError(f"{name} must be a finite time in seconds, got {t}")
    return t


# --------------------------------------------------------------------------- pure helpers


def joseph_update(x: Array, P: Array, y: Array, H: Array, R: Array) -> tuple[Array, Array, Array]:
    """Kalman update in Joseph form: (x+, P+, S) for innovation ``y`` = z - H x.

    S = H P H^T + R, K = P H^T S^-1, x+ = x + K y, P+ = (I - K H) P (I - K H)^T + K R K^T
    (Bucy & Joseph 1968; Bar-Shalom et al. 2001, eq. 5.2.3-18). Unlike P+ = (I - K H) P it
    keeps P symmetric positive definite under round-off and for any gain. The result is
    symmetrised, as round-off in the products can leave a 1e-19 asymmetry.
    """
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T  # S is symmetric: K = P H^T S^-1
    x_new = x + K @ y
    A = _identity(len(x)) - K @ H
    P_new = A @ P @ A.T + K @ R @ K.T
    return x_new, 0.5 * (P_new + P_new.T), S


@functools.lru_cache(maxsize=32)
def _identity(n: int) -> Array:
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


def normalised_innovation_squared(y: Array, S: Array) -> float:
    """y^T S^-1 y: chi-square with dim(y) degrees of freedom for a consistent filter."""
    return float(y @ np.linalg.solve(S, y))


@functools.lru_cache(maxsize=64)
def gate_threshold(probability: float, dim: int) -> float:
    """The chi-square gate: ``probability`` quantile with ``dim`` degrees of freedom."""
    return float(chi2.ppf(probability, dim))


@functools.lru_cache(maxsize=256)
def _motion_model_cached(dt: float, order: int, density: float) -> tuple[Array, Array]:
    F, Q = _motion_model(dt, order, density)
    F.flags.writeable = False
    Q.flags.writeable = False
    return F, Q


def motion_model(dt: float, order: int, density: float) -> tuple[Array, Array]:
    """Transition F and process noise Q of a 3-D point over ``dt`` seconds (see
    :func:`_motion_model`); cached, as a loop's period repeats (the arrays are read-only)."""
    return _motion_model_cached(float(dt), int(order), float(density))


def _motion_model(dt: float, order: int, density: float) -> tuple[Array, Array]:
    """Transition F and process noise Q of a 3-D point over ``dt`` seconds.

    ``order`` 2: constant velocity, state (p, v), white-noise acceleration of spectral density
    ``density``^2 (m^2/s^3): per axis F = [[1, dt], [0, 1]], Q = q [[dt^3/3, dt^2/2],
    [dt^2/2, dt]]. ``order`` 3: constant acceleration, state (p, v, a), white-noise jerk:
    Q = q [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]
    (Bar-Shalom et al. 2001, sections 6.2.2 and 6.2.3). The state stacks each derivative's
    three axes, so the 3-D matrices are kron(per-axis, I3).
    """
    q = density * density
    if order == 2:
        F1 = np.array([[1.0, dt], [0.0, 1.0]])
        Q1 = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    elif order == 3:
        F1 = np.array([[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        Q1 = q * np.array(
            [
                [dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0],
                [dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0],
                [dt**3 / 6.0, dt**2 / 2.0, dt],
            ]
        )
    else:
        raise FusionError(f"motion model order must be 2 (cv) or 3 (ca), not {order}")
    eye3 = np.eye(3)
    return np.asarray(np.kron(F1, eye3), dtype=float), np.asarray(np.kron(Q1, eye3), dtype=float)


def encoder_joint_variance(noise_rad: float) -> float:
    """Variance of one reading: Gaussian noise plus the rounding to whole encoder counts."""
    step = 2.0 * math.pi / ENCODER_COUNTS_PER_TURN
    return noise_rad * noise_rad + step * step / 12.0


def encoder_covariance(Jv: Array, joint_variance: float | Array) -> Array:
    """Covariance of fk(q) from independent joint errors: Jv diag(var) Jv^T (first order)."""
    var = np.broadcast_to(np.asarray(joint_variance, dtype=float), (Jv.shape[1],))
    return (Jv * var) @ Jv.T


def camera_point_covariance(
    p_cam: ArrayLike,
    pixel_sigma: float,
    focal_px: float = DEFAULT_FOCAL_PX,
    depth_scale: float = 1.0,
    floor: float = 0.0,
) -> Array:
    """Covariance (3x3, camera frame) of a point measured by an RGB-D camera at ``p_cam``.

    Across the viewing ray u = p/|p| the pixel noise gives sigma_lat = |p| pixel_sigma / f;
    along it, the depth error of Intel's RMS model (:func:`depth_rms_error` of z, scaled by
    ``depth_scale`` for what survives the fit that made the point) stretched by |p|/z from
    z-depth to range. Each at least ``floor``. Sigma = s_lat^2 (I - u u^T) + s_ray^2 u u^T.
    Rotate it into the base frame with R_base_cam Sigma R_base_cam^T.
    """
    p = np.asarray(p_cam, dtype=float)
    r = float(np.linalg.norm(p))
    z = max(float(p[2]), 1e-3)
    u = p / max(r, 1e-9)
    s_lat = max(r * pixel_sigma / focal_px, floor)
    s_ray = max(float(depth_rms_error(z)) * depth_scale * r / z, floor)
    uu = np.outer(u, u)
    return s_lat * s_lat * (np.eye(3) - uu) + s_ray * s_ray * uu


def lever_covariance(lever: ArrayLike, rotation_sigma: float) -> Array:
    """Covariance of a point at ``lever`` from a frame whose rotation has isotropic error.

    dp = dphi x l, so Cov = s^2 [l]x [l]x^T = s^2 (|l|^2 I - l l^T).
    """
    lever = np.asarray(lever, dtype=float)
    return rotation_sigma**2 * (float(lever @ lever) * np.eye(3) - np.outer(lever, lever))


def se3_exp_small(xi: ArrayLike) -> Array:
    """exp of a small correction xi = (dtheta, dt): make_T(Rotation(dtheta), dt)."""
    xi = np.asarray(xi, dtype=float)
    return make_T(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])


# --------------------------------------------------------------------------- the paper's filter


def paper_process_noise(dt: float, accel_noise: float = 0.1) -> Array:
    """The process noise PaperKF uses by default (the paper states none).

    The constant-velocity white-noise-acceleration Q of :func:`motion_model` with the default
    filter's ``accel_noise``, laid out for (x, y, z, 1, vx, vy, vz) with zero noise on the
    homogeneous coordinate, so the two filters differ in their models, not in tuning.
    """
    _, Q6 = motion_model(dt, 2, accel_noise)
    Q = np.zeros((7, 7))
    idx = [0, 1, 2, 4, 5, 6]
    Q[np.ix_(idx, idx)] = Q6
    return Q


class PaperKF:
    """The paper's 7-state Kalman filter, exactly (see the module docstring).

    State x = (x, y, z, 1, vx, vy, vz), base frame. A = [[I3, 0, dt I3], [0, 1, 0],
    [0, 0, I3]]; encoders y1 = C1 x, C1 = [I4 0]; camera y2 = C2 x, C2 = [T^-1 0] with
    T = ``T_base_cam``; R1 = R2 = diag(1e-4, 1e-4, 1e-4, 1e-12). ``Q`` defaults to
    :func:`paper_process_noise`. The update is the textbook one in Joseph form with
    K = P C^T inv(S), as filterpy's ``KalmanFilter.update`` computes it (the tests compare them
    step by step). ``x0``/``P0``: the initial state (homogeneous coordinate 1) and covariance.
    """

    R_PAPER = np.diag([1e-4, 1e-4, 1e-4, 1e-12])

    def __init__(
        self,
        T_base_cam: ArrayLike,
        dt: float = 0.01,
        Q: ArrayLike | None = None,
        x0: ArrayLike | None = None,
        P0: ArrayLike | None = None,
    ) -> None:
        T_base_cam = as_array("T_base_cam", T_base_cam, (4, 4))
        if not (math.isfinite(dt) and dt > 0.0):
            raise FusionError(f"dt must be a positive loop period in seconds, got {dt}")
        self.dt = float(dt)
        self.A = np.eye(7)
        self.A[0:3, 4:7] = self.dt * np.eye(3)
        self.C1 = np.hstack([np.eye(4), np.zeros((4, 3))])
        self.C2 = np.hstack([inv_T(T_base_cam), np.zeros((4, 3))])
        self.R1 = self.R_PAPER.copy()
        self.R2 = self.R_PAPER.copy()
        self.Q = paper_process_noise(self.dt) if Q is None else as_array("Q", Q, (7, 7))
        self.x = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        if x0 is not None:
            self.x = as_array("x0", x0, (7,)).copy()
        self.P = np.diag([1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0])
        if P0 is not None:
            self.P = as_array("P0", P0, (7, 7)).copy()

    @property
    def position(self) -> Array:
        """The estimated end-effector position, base frame (3,)."""
        return self.x[:3].copy()

    def predict(self) -> None:
        """x = A x, P = A P A^T + Q (u = 0)."""
        self.x = self.A @ self.x
        self.P = self.A @ self.P @ self.A.T + self.Q

    def _update(self, y: Array, C: Array, R: Array) -> None:
        innovation = y - C @ self.x
        PCt = self.P @ C.T
        S = C @ PCt + R
        K = PCt @ np.linalg.inv(S)
        self.x = self.x + K @ innovation
        A = np.eye(7) - K @ C
        self.P = A @ self.P @ A.T + K @ R @ K.T

    def update_encoders(self, p_base: ArrayLike) -> None:
        """y1 = (fk position, 1) with C1 = [I4 0]."""
        p = as_array("p_base", p_base, (3,))
        self._update(np.append(p, 1.0), self.C1, self.R1)

    def update_camera(self, p_cam: ArrayLike) -> None:
        """y2 = (end-effector point in the camera frame, 1) with C2 = [T^-1 0]."""
        p = as_array("p_cam", p_cam, (3,))
        self._update(np.append(p, 1.0), self.C2, self.R2)

    def step(self, p_base: ArrayLike | None = None, p_cam: ArrayLike | None = None) -> Array:
        """One loop period: predict, then update with each source given; the new position."""
        self.predict()
        if p_base is not None:
            self.update_encoders(p_base)
        if p_cam is not None:
            self.update_camera(p_cam)
        return self.position


# --------------------------------------------------------------------------- the filter core


@dataclass(frozen=True, eq=False)
class Measurement:
    """One linear(ised) measurement z = H x + noise(R), from ``source`` ("encoders", ...)."""

    source: str
    z: Array
    H: Array
    R: Array


@dataclass
class FilterStats:
    """Counters of what a filter did with its measurements."""

    updates: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    restarts: int = 0
    late_replayed: int = 0
    late_dropped: int = 0


@dataclass(frozen=True)
class _Checkpoint:
    t: float
    x: Array
    P: Array
    q_scale: float
    nis_average: float
    consecutive: tuple[tuple[str, int], ...]
    counts: tuple[int, tuple[tuple[str, int], ...], int]  # updates, rejected, restarts


class MotionFilter:
    """A point moving in 3-D (constant velocity or acceleration) plus constant extra states.

    State x = (p (3), v (3)[, a (3)], extra (n_extra)). The extra states (biases, calibration
    corrections) follow random walks of densities ``extra_walk`` (n_extra,). Prediction to any
    later time, gated stacked updates in Joseph form and the adaptive process noise are those
    of the module docstring. ``gate_probability`` None switches gating off (the tracker gates
    while associating). ``reset_sigma`` (position m, velocity m/s) is the spread the motion
    states restart with after ``max_rejections`` rejected measurements from one source.
    """

    def __init__(
        self,
        order: int = 2,
        noise_density: float = 0.1,
        n_extra: int = 0,
        extra_walk: ArrayLike | None = None,
        gate_probability: float | None = 0.999,
        adaptive: bool = True,
        adaptive_fading: float = 0.1,
        adaptive_threshold: float = 2.0,
        adaptive_max_scale: float = 1000.0,
        max_rejections: int = 5,
        reset_sigma: tuple[float, float] = (0.05, 0.5),
    ) -> None:
        if order not in (2, 3):
            raise FusionError(f"order must be 2 (constant velocity) or 3 (acceleration): {order}")
        if not (math.isfinite(noise_density) and noise_density > 0.0):
            raise FusionError(f"noise_density must be > 0, got {noise_density}")
        self.order = order
        self.n_motion = 3 * order
        self.n = self.n_motion + int(n_extra)
        self.noise_density = float(noise_density)
        walk = np.zeros(int(n_extra)) if extra_walk is None else np.asarray(extra_walk, float)
        if walk.shape != (int(n_extra),) or np.any(walk < 0) or not np.all(np.isfinite(walk)):
            raise FusionError(f"extra_walk must be {n_extra} densities >= 0, got {extra_walk!r}")
        self.extra_walk = walk
        self.gate_probability = gate_probability
        self.adaptive = bool(adaptive)
        self.adaptive_fading = float(adaptive_fading)
        self.adaptive_threshold = float(adaptive_threshold)
        self.adaptive_max_scale = float(adaptive_max_scale)
        self.max_rejections = int(max_rejections)
        self.reset_sigma = reset_sigma
        self.t: float | None = None
        self.x = np.zeros(self.n)
        self.P = np.eye(self.n)
        self.q_scale = 1.0
        self.nis_average = 1.0
        self._last_dt = 0.0
        self._consecutive: dict[str, int] = {}
        self._transitions: dict[float, tuple[Array, Array, Array]] = {}
        self.stats = FilterStats()

    @property
    def initialized(self) -> bool:
        return self.t is not None

    def initialize(self, t: float, x0: ArrayLike, P0: ArrayLike) -> None:
        """Start at time ``t`` with state ``x0`` (n,) and covariance ``P0`` (n, n)."""
        self.t = as_time("t", t)
        self.x = as_array("x0", x0, (self.n,)).copy()
        P0 = as_array("P0", P0, (self.n, self.n))
        self.P = 0.5 * (P0 + P0.T)
        self.q_scale, self.nis_average = 1.0, 1.0
        self._consecutive = {}

    def _transition(self, dt: float) -> tuple[Array, Array]:
        cached = self._transitions.get(dt)
        if cached is None:
            F_m, Q_m = motion_model(dt, self.order, self.noise_density)
            m = self.n_motion
            F = np.eye(self.n)
            F[:m, :m] = F_m
            Q_base = np.zeros((self.n, self.n))
            Q_base[:m, :m] = Q_m
            Q_extra = np.zeros((self.n, self.n))
            Q_extra[m:, m:] = np.diag(self.extra_walk**2 * dt)
            if len(self._transitions) > 64:  # irregular times: do not grow without bound
                self._transitions.clear()
            cached = self._transitions[dt] = (F, Q_base, Q_extra)
        F, Q_base, Q_extra = cached
        return F, Q_base * self.q_scale + Q_extra

    def predicted(self, t: float) -> tuple[Array, Array]:
        """State and covariance predicted to ``t`` (>= the filter's time), without changing it."""
        if self.t is None:
            raise FusionError("the filter has no state yet: give it a measurement first")
        dt = t - self.t
        if dt < -SAME_TIME_S:
            raise FusionError(
                f"cannot predict back in time from {self.t:.6f} s to {t:.6f} s; "
                "give measurements in time order (or use EEFilter, which replays late ones)"
            )
        if dt <= 0.0:
            return self.x.copy(), self.P.copy()
        F, Q = self._transition(dt)
        P = F @ self.P @ F.T + Q
        return F @ self.x, 0.5 * (P + P.T)

    def predict(self, t: float) -> None:
        """Move the state to time ``t``."""
        self._last_dt = max(float(t) - self.t, 0.0) if self.t is not None else 0.0
        self.x, self.P = self.predicted(t)
        self.t = max(float(t), self.t if self.t is not None else float(t))

    def innovation(self, m: Measurement) -> tuple[Array, Array]:
        """(y, S) of a measurement against the current state."""
        return m.z - m.H @ self.x, m.H @ self.P @ m.H.T + m.R

    def update(self, measurements: Sequence[Measurement], gate: bool = True) -> list[bool]:
        """Fuse measurements taken at the filter's current time; which ones were accepted.

        First the innovations set the adaptive process noise, and if it rose, the prediction
        just made is given the extra noise (so the first measurements of a manoeuvre are judged
        against the covariance the manoeuvre calls for). Then each measurement is gated on its
        own (when ``gate`` and a gate probability is set) and the accepted ones are stacked
        into one Joseph update.
        """
        probability = self.gate_probability
        gating = gate and probability is not None

        def threshold(dim: int) -> float:
            return math.inf if probability is None else gate_threshold(probability, dim)

        nis = [self._nis(m) for m in measurements]
        if self.adaptive and measurements:
            before = self.q_scale
            capped = [
                (
                    min(d2, ADAPTIVE_NIS_CAP * threshold(len(m.z))) if gating else d2,
                    len(m.z),
                )
                for d2, m in zip(nis, measurements)
            ]
            self._adapt(capped)
            if self.q_scale > before and self._last_dt > 0.0:
                m_ = self.n_motion
                _, Q_m = motion_model(self._last_dt, self.order, self.noise_density)
                self.P[:m_, :m_] += (self.q_scale - before) * Q_m
                if gating:
                    nis = [self._nis(m) for m in measurements]
        accepted: list[bool] = []
        restart: Measurement | None = None
        for d2, m in zip(nis, measurements):
            ok = not gating or d2 <= threshold(len(m.z))
            if ok:
                self._consecutive[m.source] = 0
            else:
                self.stats.rejected[m.source] = self.stats.rejected.get(m.source, 0) + 1
                count = self._consecutive.get(m.source, 0) + 1
                self._consecutive[m.source] = count
                if count >= self.max_rejections and restart is None:
                    restart = m
            accepted.append(ok)
        if restart is not None:
            self._restart_motion()
            self._consecutive[restart.source] = 0
            accepted = [m is restart or ok for m, ok in zip(measurements, accepted)]
        use = [m for m, ok in zip(measurements, accepted) if ok]
        if len(use) == 1:
            m = use[0]
            self.x, self.P, _ = joseph_update(self.x, self.P, m.z - m.H @ self.x, m.H, m.R)
            self.stats.updates += 1
        elif use:
            z = np.concatenate([m.z for m in use])
            H = np.vstack([m.H for m in use])
            R = _block_diag([m.R for m in use])
            self.x, self.P, _ = joseph_update(self.x, self.P, z - H @ self.x, H, R)
            self.stats.updates += 1
        return accepted

    def _nis(self, m: Measurement) -> float:
        y = m.z - m.H @ self.x
        return normalised_innovation_squared(y, m.H @ self.P @ m.H.T + m.R)

    def _restart_motion(self) -> None:
        """Forget the motion states (keep the extra states): after a run of rejections."""
        m = self.n_motion
        sp, sv = self.reset_sigma
        self.P[:m, :] = 0.0
        self.P[:, :m] = 0.0
        diag = [sp * sp] * 3 + [sv * sv] * 3 + [(10.0 * sv) ** 2] * (m - 6)
        self.P[:m, :m] = np.diag(diag)
        self.x[3:m] = 0.0
        self.q_scale = 1.0
        self.stats.restarts += 1

    def _adapt(self, nis_values: list[tuple[float, int]]) -> None:
        """Fading-memory average NIS per dimension drives the process-noise scale.

        Above ``adaptive_threshold`` the scale is multiplied by average / threshold each update
        (fast attack: a manoeuvre is followed within a few updates); below, it falls by the
        same ratio but at most by ``ADAPTIVE_RELEASE`` per update, back to 1.
        """
        if not nis_values:
            return
        # One step per update, from all its innovations together (so their order is moot).
        per_dim = sum(d2 for d2, _ in nis_values) / sum(dim for _, dim in nis_values)
        a = self.adaptive_fading
        self.nis_average = (1.0 - a) * self.nis_average + a * per_dim
        ratio = self.nis_average / self.adaptive_threshold
        factor = ratio if ratio > 1.0 else max(ratio, ADAPTIVE_RELEASE)
        self.q_scale = min(max(self.q_scale * factor, 1.0), self.adaptive_max_scale)

    # checkpoints for replaying late measurements

    def checkpoint(self) -> _Checkpoint:
        """Everything :meth:`restore` needs to go back to this moment (a copy)."""
        return _Checkpoint(
            self.t if self.t is not None else -math.inf,
            self.x.copy(),
            self.P.copy(),
            self.q_scale,
            self.nis_average,
            tuple(self._consecutive.items()),
            (self.stats.updates, tuple(self.stats.rejected.items()), self.stats.restarts),
        )

    def restore(self, c: _Checkpoint) -> None:
        """Go back to a :meth:`checkpoint` (to replay measurements from there)."""
        self.t = None if c.t == -math.inf else c.t
        self.x, self.P = c.x.copy(), c.P.copy()
        self.q_scale, self.nis_average = c.q_scale, c.nis_average
        self._consecutive = dict(c.consecutive)
        # A replay redoes what came after: count it once, as in the final history.
        self.stats.updates, rejected, self.stats.restarts = c.counts
        self.stats.rejected = dict(rejected)


def _block_diag(blocks: Sequence[Array]) -> Array:
    n = sum(len(b) for b in blocks)
    out = np.zeros((n, n))
    i = 0
    for b in blocks:
        k = len(b)
        out[i : i + k, i : i + k] = b
        i += k
    return out


# --------------------------------------------------------------------------- end-effector filter


@dataclass(frozen=True, eq=False)
class EEEstimate:
    """The fused end effector at time ``t``: position and velocity in the base frame.

    ``cov`` is the 6x6 covariance of (p, v). ``encoder_bias`` (rad, per joint) and
    ``camera_correction`` (dtheta rad, dt m: ``T_base_cam_true ~ T_base_cam exp(xi)``) are the
    estimated systematic errors when the filter has those states, else None;
    ``cartesian_bias`` likewise for ``encoder_bias = "cartesian"``. ``q_scale`` is the adaptive
    process-noise factor. Arrays are read-only.
    """

    t: float
    p_base: Array
    v_base: Array
    cov: Array
    encoder_bias: Array | None
    cartesian_bias: Array | None
    camera_correction: Array | None
    q_scale: float

    @property
    def sigma_mm(self) -> float:
        """RMS positional standard deviation, sqrt(trace(P_pp)), millimetres."""
        return 1000.0 * math.sqrt(max(float(np.trace(self.cov[:3, :3])), 0.0))


def _read_only(a: Array) -> Array:
    """A read-only copy of ``a``."""
    out = np.array(a, dtype=float)
    out.flags.writeable = False
    return out


def _frozen(a: Array | None) -> Array | None:
    return None if a is None else _read_only(a)


@dataclass(frozen=True)
class _Event:
    t: float
    measurements: tuple[Measurement | Callable[[], Measurement | None], ...]


class EEFilter:
    """The default end-effector fusion filter (module docstring): position in the base frame.

    ``T_base_cam``: the calibration; ``T_ee_tag``: the tag's mount on the gripper;
    ``focal_px``: the colour camera's focal length (pixel noise to metres). ``use_encoders`` /
    ``use_camera`` restrict it to one source (the single-source baselines); the bias and
    calibration states exist only when both sources are used, as only then are they
    observable. Feed it :meth:`update_encoders` and :meth:`update_camera` with capture times
    in seconds on one clock, in any order within ``config.history_s``; read :meth:`estimate`.
    """

    def __init__(
        self,
        config: FusionConfig,
        T_base_cam: ArrayLike,
        T_ee_tag: ArrayLike,
        focal_px: float = DEFAULT_FOCAL_PX,
        model: ArmModel = VX300S,
        use_encoders: bool = True,
        use_camera: bool = True,
    ) -> None:
        if not (use_encoders or use_camera):
            raise FusionError("an EEFilter needs at least one source: encoders or camera")
        self.config = config
        self.T_base_cam = as_array("T_base_cam", T_base_cam, (4, 4)).copy()
        self.T_ee_tag = as_array("T_ee_tag", T_ee_tag, (4, 4)).copy()
        self.T_tag_ee = inv_T(self.T_ee_tag)
        self.focal_px = float(focal_px)
        self.model = model
        self.use_encoders, self.use_camera = bool(use_encoders), bool(use_camera)
        both = self.use_encoders and self.use_camera
        order = 2 if config.motion_model == "cv" else 3
        density = config.accel_noise if order == 2 else config.jerk_noise
        m = 3 * order
        self.bias_model = config.encoder_bias if both else "none"
        n_bias = {"joint": model.dof, "cartesian": 3, "none": 0}[self.bias_model]
        self.estimate_camera_pose = bool(config.estimate_camera_pose and both)
        n_cam = 6 if self.estimate_camera_pose else 0
        self._b = slice(m, m + n_bias)
        self._xi = slice(m + n_bias, m + n_bias + n_cam)
        walk = np.zeros(n_bias + n_cam)
        if self.bias_model == "cartesian":
            walk[:3] = config.cartesian_bias_walk
        self.core = MotionFilter(
            order=order,
            noise_density=density,
            n_extra=n_bias + n_cam,
            extra_walk=walk,
            gate_probability=config.gate_probability,
            adaptive=config.adaptive_noise,
            adaptive_fading=config.adaptive_fading,
            adaptive_threshold=config.adaptive_threshold,
            adaptive_max_scale=config.adaptive_max_scale,
            max_rejections=config.max_rejections,
        )
        self._joint_var = encoder_joint_variance(math.radians(config.encoder_noise_deg))
        self._velocity_var = math.radians(config.velocity_noise_deg_s) ** 2
        self._events: list[_Event] = []
        self._checkpoints: list[_Checkpoint] = []
        self._joint_history: list[tuple[float, Array]] = []

    # ---------------------------------------------------------------- public

    @property
    def stats(self) -> FilterStats:
        return self.core.stats

    @property
    def time(self) -> float | None:
        """Time of the newest measurement fused, or None before the first."""
        return self.core.t

    def update_encoders(self, t: float, q: ArrayLike, qd: ArrayLike | None = None) -> None:
        """Fuse the joint encoder readings ``q`` (rad) taken at time ``t``, and the joint
        velocities ``qd`` (rad/s) measured with them if the arm measures them (None: it does
        not) and ``config.joint_velocities`` is on: the end effector's velocity Jv(q) qd, a
        measurement of the velocity states (a constant zero offset moves no joint, so the
        bias states do not enter it)."""
        if not self.use_encoders:
            raise FusionError("this filter was built without encoders (use_encoders=False)")
        t = as_time("t", t)
        q = as_array("joint positions", q, (self.model.dof,))
        qd_measured = None
        if qd is not None and self.config.joint_velocities:
            qd_measured = as_array("joint velocities", qd, (self.model.dof,))
        self._remember_joints(t, q)
        T_base_ee, Jv, _ = point_jacobian(q, self.model)
        H = np.zeros((3, self.core.n))
        H[:, :3] = np.eye(3)
        if self.bias_model == "joint":
            H[:, self._b] = Jv
        elif self.bias_model == "cartesian":
            H[:, self._b] = np.eye(3)
        R = encoder_covariance(Jv, self._joint_var) + np.eye(3) * 1e-12
        measurements: list[Measurement | Callable[[], Measurement | None]] = [
            Measurement("encoders", T_base_ee[:3, 3], H, R)
        ]
        if qd_measured is not None:
            H_v = np.zeros((3, self.core.n))
            H_v[:, 3:6] = np.eye(3)
            R_v = encoder_covariance(Jv, self._velocity_var) + np.eye(3) * 1e-12
            measurements.append(Measurement("joint velocities", Jv @ qd_measured, H_v, R_v))
        self._add(t, measurements)

    def update_camera(self, t: float, T_cam_tag: ArrayLike) -> None:
        """Fuse a gripper-tag pose seen by the camera in a frame captured at time ``t``."""
        if not self.use_camera:
            raise FusionError("this filter was built without the camera (use_camera=False)")
        t = as_time("t", t)
        T_cam_tag = as_array("T_cam_tag", T_cam_tag, (4, 4))
        cfg = self.config
        R_base_cam = self.T_base_cam[:3, :3]
        T_cam_ee = T_cam_tag @ self.T_tag_ee
        p_cam = T_cam_ee[:3, 3]
        if p_cam[2] <= 0.0:
            raise FusionError(f"tag pose puts the end effector behind the camera (z={p_cam[2]})")
        rot_sigma = math.radians(cfg.tag_rotation_sigma_deg)
        cov_cam = camera_point_covariance(
            p_cam, cfg.camera_pixel_sigma, self.focal_px, cfg.camera_depth_scale
        ) + lever_covariance(T_cam_ee[:3, 3] - T_cam_tag[:3, 3], rot_sigma)
        cov_cam += np.eye(3) * cfg.camera_sigma_floor**2
        H = np.zeros((3, self.core.n))
        H[:, :3] = np.eye(3)
        if self.estimate_camera_pose:
            H[:, self._xi.start : self._xi.start + 3] = R_base_cam @ skew(p_cam)
            H[:, self._xi.start + 3 : self._xi.stop] = -R_base_cam
        z = R_base_cam @ p_cam + self.T_base_cam[:3, 3]
        measurements: list[Measurement | Callable[[], Measurement | None]] = [
            Measurement("camera", z, H, R_base_cam @ cov_cam @ R_base_cam.T)
        ]
        if self.bias_model == "joint" and self.estimate_camera_pose and facing(T_cam_tag):
            # Built when applied, from the joint readings around t known by then (a camera
            # result usually arrives after the encoder readings that bracket its frame).
            measurements.append(
                functools.partial(self._orientation_measurement, t, T_cam_tag.copy(), rot_sigma)
            )
        self._add(t, measurements)

    def estimate(self, t: float | None = None) -> EEEstimate:
        """The estimate predicted to ``t`` (default: the newest measurement's time)."""
        core = self.core
        if core.t is None:
            raise FusionError("no estimate yet: the filter has had no measurement")
        t_out = core.t if t is None else max(as_time("t", t), core.t)
        x, P = core.predicted(t_out)
        b = x[self._b]
        return EEEstimate(
            t=t_out,
            p_base=_read_only(x[:3]),
            v_base=_read_only(x[3:6]),
            cov=_read_only(P[:6, :6]),
            encoder_bias=_frozen(b) if self.bias_model == "joint" else None,
            cartesian_bias=_frozen(b) if self.bias_model == "cartesian" else None,
            camera_correction=_frozen(x[self._xi]) if self.estimate_camera_pose else None,
            q_scale=core.q_scale,
        )

    def T_base_cam_refined(self) -> Array:
        """The calibration corrected by the estimated camera error (the given one without)."""
        if not self.estimate_camera_pose or self.core.t is None:
            return self.T_base_cam.copy()
        return self.T_base_cam @ se3_exp_small(self.core.x[self._xi])

    def T_base_ee(self, q: ArrayLike) -> Array:
        """A full pose for joint readings ``q``: fk with the estimated joint offsets removed
        (orientation) and the fused position."""
        q = as_array("joint positions", q, (self.model.dof,))
        if self.bias_model == "joint" and self.core.t is not None:
            q = q - self.core.x[self._b]
        T = fk(q, self.model)
        if self.core.t is not None:
            T[:3, 3] = self.core.x[:3]
        return T

    # ---------------------------------------------------------------- internals

    def _prior(self, z: Array) -> tuple[Array, Array]:
        cfg = self.config
        core = self.core
        x0 = np.zeros(core.n)
        x0[:3] = z
        diag = np.zeros(core.n)
        diag[:3] = 0.01**2  # 1 cm: loose; the first update pulls p to the measurement
        diag[3:6] = 0.5**2  # m/s: the arm may be moving when the filter starts
        diag[6 : core.n_motion] = 2.0**2  # m/s^2
        if self.bias_model == "joint":
            # A zero offset uniform in +-b_max has standard deviation b_max / sqrt(3).
            diag[self._b] = (math.radians(cfg.encoder_bias_deg) / math.sqrt(3.0)) ** 2
        elif self.bias_model == "cartesian":
            diag[self._b] = cfg.cartesian_bias_sigma**2
        if self.estimate_camera_pose:
            # The stated errors are magnitudes of random directions: per axis / sqrt(3).
            s_rot = math.radians(cfg.calibration_rotation_error_deg) / math.sqrt(3.0)
            s_tr = cfg.calibration_translation_error / math.sqrt(3.0)
            diag[self._xi.start : self._xi.start + 3] = max(s_rot, 1e-6) ** 2
            diag[self._xi.start + 3 : self._xi.stop] = max(s_tr, 1e-6) ** 2
        return x0, np.diag(diag)

    def _remember_joints(self, t: float, q: Array) -> None:
        history = self._joint_history
        if history and t < history[-1][0]:
            bisect.insort(history, (t, q), key=lambda item: item[0])
        else:
            history.append((t, q))
        horizon = history[-1][0] - max(self.config.history_s, 0.1)
        while len(history) > 2 and history[0][0] < horizon:
            history.pop(0)

    def joints_at(self, t: float) -> Array | None:
        """Joint readings interpolated (or extrapolated 1 period at most) to time ``t``."""
        history = self._joint_history
        if not history:
            return None
        times = np.array([h[0] for h in history])
        if len(history) == 1 or t < times[0] - 0.02 or t > times[-1] + 0.02:
            nearest = int(np.argmin(np.abs(times - t)))
            return history[nearest][1] if abs(times[nearest] - t) <= 0.02 else None
        i = int(np.clip(np.searchsorted(times, t), 1, len(times) - 1))
        t0, q0 = history[i - 1]
        t1, q1 = history[i]
        if t1 - t0 < 1e-9:
            return q1
        return q0 + (q1 - q0) * (t - t0) / (t1 - t0)

    def _orientation_measurement(
        self, t: float, T_cam_tag: Array, rot_sigma: float
    ) -> Measurement | None:
        """The tag's orientation, camera vs encoders: -R dtheta - Jw b (joint biases only)."""
        q = self.joints_at(t)
        if q is None:
            return None
        T_base_ee_enc, _, Jw = point_jacobian(q, self.model)
        R_base_cam = self.T_base_cam[:3, :3]
        R_base_tag_cam = R_base_cam @ T_cam_tag[:3, :3]
        R_base_tag_enc = T_base_ee_enc[:3, :3] @ self.T_ee_tag[:3, :3]
        e = Rotation.from_matrix(R_base_tag_cam @ R_base_tag_enc.T).as_rotvec()
        H = np.zeros((3, self.core.n))
        H[:, self._b] = -Jw
        H[:, self._xi.start : self._xi.start + 3] = -R_base_cam
        R = np.eye(3) * rot_sigma**2 + encoder_covariance(Jw, self._joint_var)
        return Measurement("tag orientation", e, H, R)

    def _add(
        self, t: float, measurements: list[Measurement | Callable[[], Measurement | None]]
    ) -> None:
        """Fuse one event: in order, merged with one at the same time, or late and replayed."""
        core = self.core
        if core.t is None:
            first = measurements[0]
            if not isinstance(first, Measurement):
                raise FusionError("a filter starts from a measurement, not a deferred one")
            x0, P0 = self._prior(first.z)
            core.initialize(t, x0, P0)
        t_core = core.t
        assert t_core is not None  # initialised above
        newest = self._events[-1].t if self._events else -math.inf
        if t > newest + SAME_TIME_S and t >= t_core - SAME_TIME_S:
            self._checkpoints.append(core.checkpoint())
            self._events.append(_Event(t, tuple(measurements)))
            self._apply(self._events[-1])
            self._prune()
            return
        if not self._checkpoints or t < self._checkpoints[0].t - SAME_TIME_S:
            core.stats.late_dropped += 1  # older than the history: nothing to replay from
            return
        i = bisect.bisect_left([e.t for e in self._events], t - SAME_TIME_S)
        events = self._events[i:]
        if events and abs(events[0].t - t) <= SAME_TIME_S:
            events[0] = _Event(events[0].t, events[0].measurements + tuple(measurements))
        else:
            events.insert(0, _Event(t, tuple(measurements)))
        if len(events) > 1:
            core.stats.late_replayed += 1
        # Re-filter from the state before event i with the new measurements in place.
        core.restore(self._checkpoints[i])
        del self._events[i:], self._checkpoints[i:]
        for event in events:
            self._checkpoints.append(core.checkpoint())
            self._events.append(event)
            self._apply(event)
        self._prune()

    def _apply(self, event: _Event) -> None:
        self.core.predict(event.t)
        built = [m if isinstance(m, Measurement) else m() for m in event.measurements]
        self.core.update([m for m in built if m is not None])

    def _prune(self) -> None:
        t_core = self.core.t
        if t_core is None:
            return
        horizon = t_core - self.config.history_s
        k = bisect.bisect_left([c.t for c in self._checkpoints], horizon)
        k = min(k, len(self._checkpoints) - 1)  # keep the newest, so merging always works
        if k > 0:
            del self._checkpoints[:k], self._events[:k]
