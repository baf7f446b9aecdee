"""The Cartesian servo the follow task streams: one control step, and a target estimator.

:func:`servo_step` is one cycle: a twist (omega, p_dot) toward a desired end-effector pose,
feed-forward plus a proportional gain on the pose error, limited in speed and acceleration
(:func:`limit_rate`), turned into joint velocities by damped least squares
(:func:`damped_least_squares`) on the ee-point Jacobian
(:func:`~armvision.robot.kinematics.point_jacobian`), joints at a limit locked and every joint
kept under a share of its velocity limit. :class:`TargetEstimator` gives a moving target's
position and velocity from timestamped measurements, for the feed-forward.
:mod:`armvision.tasks.follow` explains the loop these serve.

Units: metres, radians, seconds; twists and positions in the base frame.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from armvision.config import FollowConfig
from armvision.robot.kinematics import VX300S, ArmModel, fk, point_jacobian

Array = NDArray[np.float64]

#: Only directions of the ee-point Jacobian whose singular value is below this are damped
#: (see :func:`damped_least_squares`); the follow poses have one near 0.02 (the forearm-roll
#: and wrist-rotate axes nearly aligned) and the rest above 0.11.
DAMPING_THRESHOLD = 0.1
#: The end effector's angular speed and acceleration limits, rad/s and rad/s^2.
MAX_ANGULAR_SPEED = 1.5
MAX_ANGULAR_ACCEL = 6.0
#: Streamed joint velocities stay below this fraction of each joint's velocity limit, leaving
#: room for the arm's stream check (velocity limit x elapsed time) on a jittery clock.
JOINT_SPEED_FRACTION = 0.5
#: A joint this close to a limit (rad) is locked when qdot would push it further out.
JOINT_LIMIT_MARGIN_RAD = 0.02
#: Target measurements (position, time) are fitted with a polynomial over this window, s.
ESTIMATOR_WINDOW_S = 0.4
#: A quadratic fit needs (measurements, span s) at least these; a straight line these.
ESTIMATOR_QUADRATIC = (6, 0.2)
ESTIMATOR_LINEAR = (3, 0.1)
#: A target is extrapolated at most this long past its newest measurement, s; later it is
#: held where that put it (with no velocity feed-forward) until it is seen again or lost.
#: It covers the camera-to-detection latency (a frame or two, more on a slow machine) and
#: a dropped frame or two; a target that stops dead is overshot by at most v x this.
MAX_EXTRAPOLATION_S = 0.2


# --------------------------------------------------------------------------- servo math


def damped_least_squares(
    J: Array,
    twist: ArrayLike,
    damping: float,
    weights: ArrayLike | None = None,
    threshold: float | None = None,
) -> Array:
    """Joint velocities for twist V by damped least squares, per singular direction.

    With J W^1/2 = U diag(sigma) V^T (W = diag(``weights``), default ones, lets fast joints
    take more of the motion): qdot = W^1/2 sum_i sigma_i / (sigma_i^2 + lambda_i^2) v_i u_i^T V.
    With ``threshold`` None every lambda_i is ``damping``, which is the classic
    qdot = W J^T (J W J^T + lambda^2 I)^-1 V, minimising |J qdot - V|^2 + lambda^2
    |qdot|^2_(W^-1) (Wampler 1986; Nakamura & Hanafusa 1986): near a singularity the error in
    V grows instead of qdot. With a ``threshold`` only directions with sigma_i below it are
    damped, lambda_i^2 = damping^2 (1 - (sigma_i / threshold)^2) (numerical filtering,
    Maciejewski & Klein 1988), so away from singularities the twist is met exactly. Example:
    J = 2 I, damping 0.5, no threshold: qdot = 2 / 4.25 V.
    """
    J = np.asarray(J, dtype=float)
    V = np.asarray(twist, dtype=float)
    w_sqrt = np.sqrt(np.ones(J.shape[1]) if weights is None else np.asarray(weights, dtype=float))
    U, sigma, Vt = np.linalg.svd(J * w_sqrt, full_matrices=False)
    if threshold is None:
        lam2 = np.full_like(sigma, damping**2)
    else:
        lam2 = damping**2 * np.clip(1.0 - (sigma / threshold) ** 2, 0.0, None)
    denominator = sigma**2 + lam2
    gain = np.divide(sigma, denominator, out=np.zeros_like(sigma), where=denominator > 0.0)
    return w_sqrt * (Vt.T @ (gain * (U.T @ V)))


def limit_rate(v: Array, v_prev: Array, max_norm: float, max_change: float) -> tuple[Array, bool]:
    """``v`` scaled to at most ``max_norm``, then moved to within ``max_change`` of ``v_prev``
    (both Euclidean norms); and whether either limit bit."""
    limited = False
    n = float(np.linalg.norm(v))
    if n > max_norm:
        v = v * (max_norm / n)
        limited = True
    dv = v - v_prev
    n = float(np.linalg.norm(dv))
    if n > max_change:
        v = v_prev + dv * (max_change / n)
        limited = True
    return v, limited


@dataclass(frozen=True)
class ServoGains:
    """The servo loop's gains and limits (see :class:`~armvision.config.FollowConfig`).

    ``gain`` 1/s on position and rotation errors; ``damping`` lambda of the DLS; ``max_speed``
    m/s and ``max_accel`` m/s^2 of the ee point; ``max_angular_speed`` rad/s and
    ``max_angular_accel`` rad/s^2 of the ee; ``joint_speed_fraction`` of each joint's limit.
    """

    gain: float = 4.0
    damping: float = 0.05
    max_speed: float = 0.25
    max_accel: float = 1.0
    max_angular_speed: float = MAX_ANGULAR_SPEED
    max_angular_accel: float = MAX_ANGULAR_ACCEL
    joint_speed_fraction: float = JOINT_SPEED_FRACTION

    @staticmethod
    def from_config(config: FollowConfig) -> ServoGains:
        return ServoGains(
            gain=config.gain,
            damping=config.damping,
            max_speed=config.max_speed,
            max_accel=config.max_accel,
        )


@dataclass(frozen=True)
class ServoStep:
    """One servo cycle: the joint target ``q``, the joint velocity ``qdot`` that got there,
    the commanded twist ``command`` (omega, p_dot) after the Cartesian limits and scaled down
    with qdot when the joint speed limit bit (pass it as the next cycle's ``twist_prev``), the
    twist ``achieved`` to first order (J qdot), and whether a limit bit (Cartesian speed or
    acceleration; joint limit or speed)."""

    q: Array
    qdot: Array
    command: Array
    achieved: Array
    cartesian_limited: bool
    joint_limited: bool


def servo_step(
    q: ArrayLike,
    T_base_des: ArrayLike,
    twist_ff: ArrayLike,
    twist_prev: ArrayLike,
    dt: float,
    gains: ServoGains,
    model: ArmModel = VX300S,
) -> ServoStep:
    """One cycle of the Cartesian servo: from joints ``q`` toward ``T_base_des`` in ``dt`` s.

    V = ``twist_ff`` + gain x (rotation vector of R_des R(q)^T, p_des - p(q)), limited in norm
    and in change from ``twist_prev`` (the previous cycle's ``command``), then
    :func:`damped_least_squares` on the ee-point Jacobian
    (:func:`~armvision.robot.kinematics.point_jacobian`) weighted by the joint velocity
    limits, damping the directions with singular values under :data:`DAMPING_THRESHOLD`;
    joints within :data:`JOINT_LIMIT_MARGIN_RAD` of a limit and moving out are locked; the
    joint velocities are scaled down together to the joint speed limit; q + qdot dt.

    The limits act on the command, not on J qdot: damping shrinks each cycle's J qdot by a
    fraction of the command that depends on the pose, and limiting the change from that
    (instead of from the previous command, which changes smoothly) would let the command
    jump back up by that fraction every cycle, a sawtooth in the ee's velocity.
    """
    q = np.asarray(q, dtype=float)
    T_des = np.asarray(T_base_des, dtype=float)
    V_ff = np.asarray(twist_ff, dtype=float)
    V_prev = np.asarray(twist_prev, dtype=float)
    T = fk(q, model)
    error = np.concatenate(
        [
            Rotation.from_matrix(T_des[:3, :3] @ T[:3, :3].T).as_rotvec(),
            T_des[:3, 3] - T[:3, 3],
        ]
    )
    V = V_ff + gains.gain * error
    w, w_hit = limit_rate(V[:3], V_prev[:3], gains.max_angular_speed, gains.max_angular_accel * dt)
    v, v_hit = limit_rate(V[3:], V_prev[3:], gains.max_speed, gains.max_accel * dt)
    command = np.concatenate([w, v])

    _, Jv, Jw = point_jacobian(q, model)
    J = np.vstack([Jw, Jv])  # rows (omega, p_dot), as the twists
    weights = (model.velocity / np.max(model.velocity)) ** 2
    qdot = damped_least_squares(J, command, gains.damping, weights, DAMPING_THRESHOLD)
    joint_limited = False
    low = (q <= model.lower + JOINT_LIMIT_MARGIN_RAD) & (qdot < 0.0)
    high = (q >= model.upper - JOINT_LIMIT_MARGIN_RAD) & (qdot > 0.0)
    if np.any(low | high):
        joint_limited = True
        locked = J * ~(low | high)
        qdot = damped_least_squares(locked, command, gains.damping, weights, DAMPING_THRESHOLD)
    ratio = float(np.max(np.abs(qdot) / (gains.joint_speed_fraction * model.velocity)))
    if ratio > 1.0:
        joint_limited = True
        qdot = qdot / ratio
        command = command / ratio  # what the arm will actually be asked to do
    q_next = np.clip(q + qdot * dt, model.lower, model.upper)
    qdot = (q_next - q) / dt
    return ServoStep(q_next, qdot, command, J @ qdot, v_hit or w_hit, joint_limited)


# --------------------------------------------------------------------------- the target


class TargetEstimator:
    """Position and velocity of a moving point from timestamped measurements (base frame).

    A polynomial p(t) = a + b (t - t_n) + c (t - t_n)^2 fitted by least squares to the
    measurements of the last ``window_s`` seconds (t_n the newest): the position at time t is
    its value there and the velocity its slope, extrapolated at most ``max_extrapolation_s``
    past t_n (then held, with zero velocity). The quadratic term is what keeps the velocity
    of a target going round a curve current: a straight line's slope is the velocity at the
    middle of the window, which on a circle points the wrong way by omega x window / 2 (14
    degrees at 10 cm/s on a 6 cm radius with 0.3 s), a feed-forward error the loop's gain has
    to make up. With fewer than :data:`ESTIMATOR_QUADRATIC` (count, span s) measurements the
    fit is a line, with fewer than :data:`ESTIMATOR_LINEAR` the newest measurement with zero
    velocity.
    """

    def __init__(
        self, window_s: float = ESTIMATOR_WINDOW_S, max_extrapolation_s: float = MAX_EXTRAPOLATION_S
    ) -> None:
        self.window_s = float(window_s)
        self.max_extrapolation_s = float(max_extrapolation_s)
        self._samples: deque[tuple[float, Array]] = deque()
        self.count = 0

    @property
    def last_time(self) -> float | None:
        """Time of the newest measurement (None before the first)."""
        return self._samples[-1][0] if self._samples else None

    @property
    def last_position(self) -> Array | None:
        return self._samples[-1][1].copy() if self._samples else None

    def update(self, t: float, p: ArrayLike) -> None:
        """Add a measurement ``p`` (m) taken at ``t`` (s); older-than-newest ones are ignored."""
        if self._samples and t <= self._samples[-1][0]:
            return
        self._samples.append((float(t), np.array(p, dtype=float)))
        self.count += 1
        while self._samples[0][0] < t - self.window_s:
            self._samples.popleft()

    def estimate(self, t: float) -> tuple[Array, Array] | None:
        """(position, velocity) at time ``t``; None before the first measurement."""
        if not self._samples:
            return None
        t_n, p_n = self._samples[-1]
        n, span = len(self._samples), t_n - self._samples[0][0]
        if n >= ESTIMATOR_QUADRATIC[0] and span >= ESTIMATOR_QUADRATIC[1]:
            degree = 2
        elif n >= ESTIMATOR_LINEAR[0] and span >= ESTIMATOR_LINEAR[1]:
            degree = 1
        else:
            return p_n.copy(), np.zeros(3)
        ts = np.array([s[0] - t_n for s in self._samples])
        A = np.vander(ts, degree + 1, increasing=True)  # columns 1, t, t^2
        coef, *_ = np.linalg.lstsq(A, np.array([s[1] for s in self._samples]), rcond=None)
        ahead = min(max(t - t_n, 0.0), self.max_extrapolation_s)
        powers = ahead ** np.arange(degree + 1)
        p = powers @ coef
        if t - t_n > self.max_extrapolation_s:
            return p, np.zeros(3)
        return p, (np.arange(1, degree + 1) * powers[:-1]) @ coef[1:]
