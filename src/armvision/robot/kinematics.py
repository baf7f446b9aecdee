"""ViperX-300s kinematics: model constants, forward kinematics, Jacobians, inverse kinematics.

Numbers are Interbotix's ``mr_descriptions.py`` (space frame ``base_link``, end effector
``ee_gripper_link``) and the vx300s URDF for limits, home and sleep poses.

Forward kinematics is the product of exponentials (Lynch & Park, *Modern Robotics*, eq. 4.14),
T(q) = e^[S1]q1 ... e^[Sn]qn M. It is written here rather than taken from
``modern_robotics.FKinSpace`` because we need it vectorised over many configurations at once
(IK verification, benchmarks, self-filtering); the tests check it against modern_robotics.

Inverse kinematics is closed-form. The ViperX-300s has a spherical wrist (the forearm-roll,
wrist-angle and wrist-rotate axes meet in one point), a vertical waist axis and two parallel
pitch axes, so the wrist centre fixes waist, shoulder and elbow (two-link planar arm) and the
wrist rotation is an x-y-x Euler decomposition (Pieper's method). That gives all (up to eight)
solutions exactly and in microseconds; ``modern_robotics.IKinSpace`` (Newton from three seeds,
which the Interbotix API uses) converges only from nearby seeds and misses reachable poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import make_T, pose_error, rotation_between, skew

Array = NDArray[np.float64]

#: A pose counts as reached when fk of the answer is this close to the target.
POSITION_TOLERANCE_M = 1e-4
ORIENTATION_TOLERANCE_RAD = np.deg2rad(0.01)

_LIMIT_SLACK = 1e-9  # round-off allowance when a solution sits exactly on a joint limit


def _frozen(a: ArrayLike) -> Array:
    out = np.array(a, dtype=float)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class ArmModel:
    """Kinematic model of an Interbotix arm in Modern Robotics form.

    ``Slist`` holds one screw axis per row, (omega, v), in the space frame at the home pose;
    ``M`` is the end-effector pose at home. Limits are radians and radians per second.
    """

    name: str
    M: Array
    Slist: Array
    joint_names: tuple[str, ...]
    lower: Array
    upper: Array
    velocity: Array
    home: Array
    sleep: Array
    finger_limits: tuple[float, float] = (0.021, 0.057)
    finger_names: tuple[str, ...] = field(default=("left_finger", "right_finger"))

    def __post_init__(self) -> None:
        for name in ("M", "Slist", "lower", "upper", "velocity", "home", "sleep"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def within_limits(self, q: ArrayLike, slack: float = 0.0) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(np.all(q >= self.lower - slack) and np.all(q <= self.upper + slack))

    def limit_violations(self, q: ArrayLike) -> list[str]:
        """Readable list of the joints of ``q`` that lie outside their limits."""
        q = np.asarray(q, dtype=float)
        out = []
        for name, value, lo, hi in zip(self.joint_names, q, self.lower, self.upper):
            if not lo <= value <= hi:
                out.append(f"{name}={value:.4f} rad outside [{lo:.4f}, {hi:.4f}]")
        return out

    @cached_property
    def _wrist(self) -> _SphericalWristGeometry:
        return _SphericalWristGeometry.from_model(self)

    @cached_property
    def _screw_matrices(self) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
        """[w], [w]^2, v and a prismatic flag per joint, stacked for :func:`joint_exponentials`."""
        W = np.array([skew(S[:3]) for S in self.Slist], dtype=float)
        prismatic = np.logical_not(np.any(self.Slist[:, :3], axis=1))
        return W, W @ W, self.Slist[:, 3:].copy(), prismatic

    @cached_property
    def _limit_pairs(self) -> tuple[tuple[float, float], ...]:
        # plain floats: the IK inner loop is scalar code, where math beats numpy by 10x
        return tuple((float(lo), float(hi)) for lo, hi in zip(self.lower, self.upper))


_PI_LIMIT = np.pi - 1e-5

VX300S = ArmModel(
    name="vx300s",
    M=np.array(
        [[1.0, 0.0, 0.0, 0.536494], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.42705], [0, 0, 0, 1]]
    ),
    Slist=np.array(
        [
            [0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, -0.12705, 0.0, 0.0],
            [0.0, 1.0, 0.0, -0.42705, 0.0, 0.05955],
            [1.0, 0.0, 0.0, 0.0, 0.42705, 0.0],
            [0.0, 1.0, 0.0, -0.42705, 0.0, 0.35955],
            [1.0, 0.0, 0.0, 0.0, 0.42705, 0.0],
        ]
    ),
    joint_names=("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate"),
    lower=np.array([-_PI_LIMIT, -1.850049, -1.762783, -_PI_LIMIT, -1.867502, -_PI_LIMIT]),
    upper=np.array([_PI_LIMIT, 1.256637, 1.605703, _PI_LIMIT, 2.234021, _PI_LIMIT]),
    velocity=np.full(6, np.pi),
    home=np.zeros(6),
    sleep=np.array([0.0, -1.85, 1.55, 0.0, 0.8, 0.0]),
)


# --------------------------------------------------------------------------- forward kinematics


def joint_exponentials(model: ArmModel, Q: Array) -> Array:
    """e^[S_i]q_i for every joint i and configuration: Q (N, n) -> (N, n, 4, 4).

    Rodrigues' formula for screws (MR eq. 3.51, 3.88), evaluated for all joints in a few array
    operations: a per-joint Python loop costs more than the arithmetic at these sizes.
    """
    W, W2, v, prismatic = model._screw_matrices
    s = np.sin(Q)[..., None, None]
    c = np.cos(Q)[..., None, None]
    t = Q[..., None, None]
    rev = ~prismatic[:, None, None]
    E = np.zeros((*Q.shape, 4, 4))
    E[..., :3, :3] = np.eye(3) + rev * (s * W + (1.0 - c) * W2)
    G = np.where(rev, t * np.eye(3) + (1.0 - c) * W + (t - s) * W2, t * np.eye(3))
    E[..., :3, 3] = np.einsum("...ij,...j->...i", G, np.broadcast_to(v, G.shape[:-1]))
    E[..., 3, 3] = 1.0
    return E


def fk(q: ArrayLike, model: ArmModel = VX300S) -> Array:
    """``T_base_ee`` for joint angles ``q`` (n,) -> (4, 4), or a batch (N, n) -> (N, 4, 4).

    Product of exponentials in the space frame, T = e^[S1]q1 ... e^[Sn]qn M. Example:
    ``fk(np.zeros(6))`` is ``VX300S.M``.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    Q = np.atleast_2d(q)
    if Q.shape[1] != model.dof:
        raise ValueError(f"{model.name} has {model.dof} joints, got q with shape {q.shape}")
    E = joint_exponentials(model, Q)
    T = E[:, 0]
    for i in range(1, model.dof):
        T = T @ E[:, i]
    T = T @ model.M
    return T[0] if single else T


def jacobian_space(q: ArrayLike, model: ArmModel = VX300S) -> Array:
    """Space Jacobian J_s(q), 6 x n with rows (omega, v): J_i = Ad(e^[S1]q1 ... e^[Si-1]qi-1) S_i.

    (Modern Robotics eq. 5.11.) The spatial twist of the end effector is J_s(q) @ qdot.
    """
    q = np.asarray(q, dtype=float)
    E = joint_exponentials(model, q[None, :])[0]
    J = np.zeros((6, model.dof))
    T = np.eye(4)
    for i in range(model.dof):
        R, p = T[:3, :3], T[:3, 3]
        w, v = model.Slist[i, :3], model.Slist[i, 3:]
        J[:3, i] = R @ w
        J[3:, i] = skew(p) @ (R @ w) + R @ v
        T = T @ E[i]
    return J


def point_jacobian(q: ArrayLike, model: ArmModel = VX300S) -> tuple[Array, Array, Array]:
    """(T_base_ee, Jv, Jw): pose and the 3 x n linear and angular Jacobians of the ee point.

    The space Jacobian's columns are J_i = Ad(T_i-1) S_i with T_i-1 = e^[S1]q1 ...
    e^[Si-1]qi-1 (Modern Robotics eq. 5.11): omega_i = R w_i, v_i = p x omega_i + R v_i, and
    T_base_ee = T_n M (eq. 4.14). The ee point moves at v_s + omega x p_ee, so
    Jv = J_v,s - [p_ee]x Jw: p_dot = Jv qdot is the velocity of the ee point and
    omega = Jw qdot the ee's angular velocity, both in the base frame. One pass over the
    joints gives the pose and both Jacobians (the fusion loop needs them at 100 Hz, the follow
    servo at 50 Hz; ``fk`` + ``jacobian_space`` would compute the joint exponentials twice).
    Equal to those to round-off, and to finite differences of ``fk``
    (tests/robot/test_kinematics.py).
    """
    q = np.asarray(q, dtype=float)
    E = joint_exponentials(model, q[None])[0]
    n = model.dof
    T_prev = np.empty((n, 4, 4))
    T = np.eye(4)
    for i in range(n):
        T_prev[i] = T
        T = T @ E[i]
    T_base_ee = T @ model.M
    w, v = model.Slist[:, :3], model.Slist[:, 3:]
    R = T_prev[:, :3, :3]
    Jw = np.einsum("kij,kj->ki", R, w)
    # (p_i - p_ee) x omega_i for every column at once (np.cross is slow on arrays this small).
    r = T_prev[:, :3, 3] - T_base_ee[:3, 3]
    Jv = np.einsum("kij,kj->ki", R, v) + (
        r[:, [1, 2, 0]] * Jw[:, [2, 0, 1]] - r[:, [2, 0, 1]] * Jw[:, [1, 2, 0]]
    )
    return T_base_ee, Jv.T, Jw.T


# --------------------------------------------------------------------------- inverse kinematics


@dataclass(frozen=True)
class _SphericalWristGeometry:
    """Lengths of a waist + two pitch joints + spherical-wrist arm, read off M and Slist.

    Points on the pitch axes are expressed in the arm plane (radial r, height z) at home.
    """

    shoulder: tuple[float, float]  # (r, z) of the shoulder axis
    upper_arm: tuple[float, float]  # shoulder axis -> elbow axis
    forearm: tuple[float, float]  # elbow axis -> wrist centre
    wrist_to_ee: float  # distance from the wrist centre to the ee along the ee x axis

    @staticmethod
    def from_model(model: ArmModel) -> _SphericalWristGeometry:
        S = model.Slist
        if model.dof != 6:
            raise ValueError(f"closed-form IK needs 6 joints; {model.name} has {model.dof}")
        expected_axes = np.array([[0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]])
        if not np.allclose(S[:, :3], expected_axes) or not np.allclose(model.M[:3, :3], np.eye(3)):
            raise ValueError(f"{model.name} is not a z-y-y-x-y-x arm with an aligned home pose")
        # A revolute screw (w, v) with |w| = 1 passes through the point w x v.
        points = np.cross(S[:, :3], S[:, 3:])
        if not np.allclose(points[0, :2], 0.0) or not np.allclose(points[:, 1], 0.0):
            raise ValueError(f"{model.name}: joint axes are not in the arm's x-z plane")
        shoulder, elbow, wrist = points[1], points[2], points[4]
        if not (np.isclose(points[3, 2], wrist[2]) and np.isclose(points[5, 2], wrist[2])):
            raise ValueError(f"{model.name}: wrist axes do not meet in one point")
        if not np.isclose(model.M[2, 3], wrist[2]) or not np.isclose(model.M[1, 3], 0.0):
            raise ValueError(f"{model.name}: the end effector is not on the wrist's x axis")
        return _SphericalWristGeometry(
            shoulder=(float(shoulder[0]), float(shoulder[2])),
            upper_arm=(float(elbow[0] - shoulder[0]), float(elbow[2] - shoulder[2])),
            forearm=(float(wrist[0] - elbow[0]), float(wrist[2] - elbow[2])),
            wrist_to_ee=float(model.M[0, 3] - wrist[0]),
        )

    @cached_property
    def reach(self) -> tuple[float, float]:
        """Smallest and largest shoulder-to-wrist-centre distance, ignoring joint limits."""
        l1, l2 = np.hypot(*self.upper_arm), np.hypot(*self.forearm)
        return abs(l1 - l2), l1 + l2


def _wrap_to_limits(theta: float, lo: float, hi: float, seed: float) -> float | None:
    """The value theta + 2k pi inside [lo, hi] nearest ``seed``; None when there is none."""
    best = None
    for k in (-2, -1, 0, 1, 2):
        t = theta + 2.0 * math.pi * k
        if lo - _LIMIT_SLACK <= t <= hi + _LIMIT_SLACK and (
            best is None or abs(t - seed) < abs(best - seed)
        ):
            best = t
    return None if best is None else min(max(best, lo), hi)


def _xyx_euler(R: Array, seed_roll: float) -> list[tuple[float, float, float]]:
    """All (a, b, c) with R = Rx(a) Ry(b) Rx(c); at the b = 0 singularity a keeps ``seed_roll``."""
    r = R.tolist()
    b = math.acos(min(max(r[0][0], -1.0), 1.0))
    if math.sin(b) < 1e-9:
        if r[0][0] > 0:  # b = 0: only a + c is determined
            total = math.atan2(-r[1][2], r[1][1])
            return [(seed_roll, 0.0, total - seed_roll)]
        # b = pi: Rx(a) Ry(pi) Rx(c) depends on c - a only
        diff = math.atan2(r[1][2], r[1][1])
        return [(seed_roll, math.pi, diff + seed_roll)]
    a = math.atan2(r[1][0], -r[2][0])
    c = math.atan2(r[0][1], r[0][2])
    return [(a, b, c), (a + math.pi, -b, c + math.pi)]


def ik_solutions(
    T_base_ee: ArrayLike, q_seed: ArrayLike | None = None, model: ArmModel = VX300S
) -> list[Array]:
    """Every joint configuration within limits that reaches ``T_base_ee``, checked by fk.

    Closed form (Pieper): the wrist centre w = p - d R x fixes the waist (two branches, facing
    the target or reaching over backwards), shoulder and elbow (elbow up / down, law of cosines);
    the wrist joints follow from R_03^T R = Rx(q4) Ry(q5) Rx(q6) (two branches). Angles are
    wrapped into the limits nearest ``q_seed``; at a singularity the free joint keeps its seed.
    """
    T_base_ee = np.asarray(T_base_ee, dtype=float)
    seed = model.home if q_seed is None else np.asarray(q_seed, dtype=float)
    geo = model._wrist
    R, p = T_base_ee[:3, :3], T_base_ee[:3, 3]
    w = p - geo.wrist_to_ee * R[:, 0]

    seed_list = [float(v) for v in seed]
    wx, wy, wz = (float(v) for v in w)
    if math.hypot(wx, wy) < 1e-9:  # wrist centre on the waist axis: waist is free
        waists = [seed_list[0], seed_list[0] + math.pi]
    else:
        heading = math.atan2(wy, wx)
        waists = [heading, heading + math.pi]

    (a_x, a_z), (b_x, b_z) = geo.upper_arm, geo.forearm
    l1, l2 = math.hypot(a_x, a_z), math.hypot(b_x, b_z)
    alpha, beta = math.atan2(a_z, a_x), math.atan2(b_z, b_x)
    limits = model._limit_pairs
    R_ee = R @ model.M[:3, :3].T

    solutions: list[list[float]] = []
    for q1 in waists:
        c1, s1 = math.cos(q1), math.sin(q1)
        x, z = c1 * wx + s1 * wy - geo.shoulder[0], wz - geo.shoulder[1]
        cos_t2 = (x * x + z * z - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        if abs(cos_t2) > 1.0 + 1e-9:
            continue  # wrist centre out of reach on this side
        t2_abs = math.acos(min(max(cos_t2, -1.0), 1.0))
        for t2 in (t2_abs, -t2_abs) if t2_abs > 0.0 else (0.0,):
            t1 = math.atan2(z, x) - math.atan2(l2 * math.sin(t2), l1 + l2 * math.cos(t2))
            # A positive pitch q turns the arm plane by -q (y axis into the page).
            q2 = alpha - t1
            q3 = beta - alpha - t2
            cp, sp = math.cos(q2 + q3), math.sin(q2 + q3)
            R_03 = np.array([[c1 * cp, -s1, c1 * sp], [s1 * cp, c1, s1 * sp], [-sp, 0.0, cp]])
            for q4, q5, q6 in _xyx_euler(R_03.T @ R_ee, seed_list[3]):
                q = []
                for theta, (lo, hi), s in zip((q1, q2, q3, q4, q5, q6), limits, seed_list):
                    wrapped = _wrap_to_limits(theta, lo, hi, s)
                    if wrapped is None:
                        break
                    q.append(wrapped)
                else:
                    solutions.append(q)

    if not solutions:
        return []
    Q = np.array(solutions)
    dp, dr = pose_error(fk(Q, model), T_base_ee)  # one batched fk for every candidate
    good = (dp <= POSITION_TOLERANCE_M) & (dr <= ORIENTATION_TOLERANCE_RAD)
    return list(Q[good])


def _nearest(solutions: list[Array], seed: Array) -> Array:
    return min(solutions, key=lambda q: float(np.sum((q - seed) ** 2)))


def ik(
    T_base_ee: ArrayLike,
    q_seed: ArrayLike | None = None,
    model: ArmModel = VX300S,
    position_priority: bool = False,
) -> tuple[Array, bool]:
    """Joint angles reaching ``T_base_ee``, nearest ``q_seed`` (default: home); returns (q, ok).

    ``ok`` is True only if fk(q) is within 0.1 mm and 0.01 deg of the target and q is within
    the joint limits. When it is False, q is the seed (nothing to move to).

    With ``position_priority=True`` a target whose orientation cannot be reached is still
    reached in position: the end effector's approach (x) axis is turned as little as possible
    until the pose becomes reachable, and ``ok`` then means the position is within 0.1 mm.
    """
    T_base_ee = np.asarray(T_base_ee, dtype=float)
    if T_base_ee.shape != (4, 4) or not np.all(np.isfinite(T_base_ee)):
        raise ValueError("T_base_ee must be a finite 4x4 homogeneous transform")
    seed = model.home.copy() if q_seed is None else np.asarray(q_seed, dtype=float).copy()
    solutions = ik_solutions(T_base_ee, seed, model)
    if solutions:
        return _nearest(solutions, seed), True
    if position_priority:
        return _ik_position_priority(T_base_ee, seed, model)
    return seed, False


# Unit directions spread evenly over the sphere (Fibonacci lattice), for the approach-axis search.
def _sphere_directions(n: int) -> Array:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


_DIRECTIONS = _sphere_directions(4000)


def _ik_position_priority(T_base_ee: Array, seed: Array, model: ArmModel) -> tuple[Array, bool]:
    """Reach the position, with the approach axis as close to the asked one as the arm allows.

    With a spherical wrist, position and approach axis d fix the wrist centre p - l d; the roll
    about d is free. So search directions d: a Fibonacci lattice ordered by angle to the asked
    axis (wrist centres out of reach filtered out in one vectorised test), then bisection toward
    the asked axis and a shrinking pattern search on the sphere to polish the boundary point.
    """
    geo = model._wrist
    R, p = T_base_ee[:3, :3], T_base_ee[:3, 3]
    x_goal = R[:, 0]

    def solve(d: Array) -> list[Array]:
        T = make_T(rotation_between(x_goal, d) @ R, p)
        return ik_solutions(T, seed, model)

    # Vectorised reach test of the wrist centre for every direction, both waist branches.
    w = p[None, :] - geo.wrist_to_ee * _DIRECTIONS
    radial = np.hypot(w[:, 0], w[:, 1])
    dz = w[:, 2] - geo.shoulder[1]
    lo, hi = geo.reach
    in_reach = np.zeros(len(w), dtype=bool)
    for r in (radial - geo.shoulder[0], -radial - geo.shoulder[0]):
        dist = np.hypot(r, dz)
        in_reach |= (dist >= lo - 1e-9) & (dist <= hi + 1e-9)
    order = np.argsort(-(_DIRECTIONS @ x_goal))
    found = next(
        ((_DIRECTIONS[k], sols) for k in order[in_reach[order]] if (sols := solve(_DIRECTIONS[k]))),
        None,
    )
    if found is None:
        return seed, False
    best_d, best_sols = found

    def angle(d: Array) -> float:
        return float(np.arccos(np.clip(d @ x_goal, -1.0, 1.0)))

    # Bisect along the great circle from the feasible direction toward the asked axis.
    lo_d, hi_d = x_goal, best_d  # hi_d feasible
    for _ in range(30):
        mid = lo_d + hi_d
        if np.linalg.norm(mid) < 1e-12:
            break
        mid = mid / np.linalg.norm(mid)
        sols = solve(mid)
        if sols:
            hi_d, best_sols = mid, sols
        else:
            lo_d = mid
    best_d = hi_d

    # Pattern search on the sphere around the boundary point.
    step = 0.05
    while step > 1e-6:
        improved = False
        u = np.cross(best_d, [0.0, 0.0, 1.0] if abs(best_d[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(best_d, u)
        for a in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False):
            cand = best_d + step * (np.cos(a) * u + np.sin(a) * v)
            cand /= np.linalg.norm(cand)
            if angle(cand) < angle(best_d) - 1e-12:
                sols = solve(cand)
                if sols:
                    best_d, best_sols, improved = cand, sols, True
                    break
        if not improved:
            step *= 0.5

    q = _nearest(best_sols, seed)
    dp, _ = pose_error(fk(q, model), T_base_ee)
    return (q, True) if dp <= POSITION_TOLERANCE_M else (seed, False)
