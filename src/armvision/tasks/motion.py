"""Moving the gripper safely near the table: what grab and analyze share.

A joint-space move between two poses near the table can sweep the gripper through what stands
there, so both tasks move along straight lines in short segments, each point reached with the
wrist unflipped (or on the flipped branch a collision-aware grasp left the arm on, never
switching branch) and as level as the arm allows, and no joint faster than a share of its limit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import make_T, rpy_to_R
from armvision.robot.base import Arm
from armvision.robot.kinematics import ArmModel, ik

Array = NDArray[np.float64]

#: Shortest time for one segment of a straight-line move, seconds.
SEGMENT_TIME_S = 0.6
#: Consecutive points of a straight move may differ by at most this in any joint, rad.
MAX_JOINT_STEP_RAD = 1.2
#: Near objects, no joint moves faster than this share of its velocity limit.
SPEED_FRACTION = 0.5


def wrist_flipped(q: Array) -> bool:
    """Whether joints ``q`` have the wrist flipped: forearm roll or wrist rotate beyond +-90
    degrees (the branch a collision-aware grasp may take, the forearm rolled half a turn)."""
    return bool(abs(q[3]) >= math.pi / 2 or abs(q[5]) >= math.pi / 2)


def unflipped_ik(T_base_ee: Array, seed: Array, model: ArmModel) -> Array | None:
    """Joint angles for ``T_base_ee`` near ``seed`` with the wrist unflipped (forearm roll and wrist
    rotate within +-90 degrees), or None."""
    q, ok = ik(T_base_ee, seed, model)
    return q if ok and not wrist_flipped(q) else None


def motion_seed(arm: Arm, T_base_ee_last: Array | None) -> Array:
    """The joints to look for the next solution near: those of the last commanded pose (the
    encoder reading if there is none yet), so consecutive points stay on one IK branch."""
    q_now = np.asarray(arm.get_joint_positions(), dtype=float)
    return q_now if T_base_ee_last is None else ik(T_base_ee_last, q_now, arm.model)[0]


def level_pose(
    p: ArrayLike,
    yaw: float,
    seed: Array,
    model: ArmModel,
    max_pitch_deg: int = 90,
    pitches: Sequence[int] | None = None,
) -> tuple[Array, Array] | None:
    """(T_base_ee, q): the gripper at ``p`` facing ``yaw``, level if the arm reaches it so,
    else pitched down (about its own y axis) in 5 degree steps up to ``max_pitch_deg`` (or at
    the first of ``pitches``, degrees, it reaches), within :data:`MAX_JOINT_STEP_RAD` of
    ``seed`` and with the wrist unflipped (:func:`unflipped_ik`), or, from a seed whose wrist
    is flipped (a collision-aware grasp may reach in with the forearm rolled), on the seed's
    own branch; None if no such pose."""
    flipped = wrist_flipped(seed)
    for pitch_deg in range(0, max_pitch_deg + 1, 5) if pitches is None else pitches:
        T = make_T(rpy_to_R(0.0, math.radians(pitch_deg), yaw), p)
        q: Array | None
        if flipped:
            q, ok = ik(T, seed, model)
            q = q if ok else None
        else:
            q = unflipped_ik(T, seed, model)
        if q is not None and np.max(np.abs(q - seed)) < MAX_JOINT_STEP_RAD:
            return T, q
    return None


def paced_time(arm, q_goal: Array, moving_time: float) -> float:
    """``moving_time``, or longer if some joint would go faster than :data:`SPEED_FRACTION`
    of its limit on the way from the current reading to ``q_goal``."""
    q_now = np.asarray(arm.get_joint_positions(), dtype=float)
    slowest = float(np.max(np.abs(q_goal - q_now) / (SPEED_FRACTION * arm.model.velocity)))
    return max(moving_time, slowest + arm.accel_time)
