"""The carrying moves' pose rules: stay on the IK branch the arm is on, move a held bottle at
the pitch it was grasped at (checked by forward kinematics, the closed-form IK's solutions
and hand-worked rotations)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armvision.geometry import make_T, rpy_to_R
from armvision.robot.kinematics import VX300S, fk, ik_solutions
from armvision.tasks.carry import grasp_pitch_deg
from armvision.tasks.motion import level_pose, wrist_flipped


def _branches(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An unflipped and a flipped solution facing the target (waist within 90 degrees of it)."""
    bearing = math.atan2(T[1, 3], T[0, 3])
    facing = [
        q
        for q in ik_solutions(T, VX300S.home, VX300S)
        if abs((q[0] - bearing + math.pi) % (2 * math.pi) - math.pi) < math.pi / 2
    ]
    plain = [q for q in facing if not wrist_flipped(q)]
    rolled = [q for q in facing if wrist_flipped(q)]
    assert plain and rolled, "the pose should have both wrist branches"
    return plain[0], rolled[0]


def test_a_move_from_a_flipped_wrist_stays_on_its_branch() -> None:
    # A level pose 30 cm out, then 2 cm higher: from the unflipped solution the next pose is
    # unflipped (as before); from the flipped one (forearm rolled half a turn, as a
    # collision-aware grasp may reach in) it is the flipped one, a small step away, where an
    # unflipped answer would turn the forearm and wrist half a turn next to the bottle.
    yaw = math.radians(-15.0)
    T0 = make_T(rpy_to_R(0.0, 0.0, yaw), [0.30, 0.05, 0.20])
    plain, rolled = _branches(T0)
    p1 = [0.30, 0.05, 0.22]
    for seed, want_flipped in ((plain, False), (rolled, True)):
        found = level_pose(p1, yaw, seed, VX300S, pitches=(0,))
        assert found is not None
        T, q = found
        assert wrist_flipped(q) == want_flipped
        assert float(np.max(np.abs(q - seed))) < 0.3
        np.testing.assert_allclose(fk(q, VX300S), T, atol=1e-6)
        np.testing.assert_allclose(T[:3, 3], p1, atol=1e-9)


@pytest.mark.parametrize("pitch", [0, 5, 15, 30, 90])
def test_the_grasp_pitch_is_read_to_the_nearest_five_degrees(pitch: int) -> None:
    # Pitched down about the gripper's own y axis by `pitch`, read with up to 1.5 degrees of
    # error about each axis (an encoder reading), facing any way.
    rng = np.random.default_rng(pitch)
    for yaw in np.radians([-120.0, -15.0, 0.0, 40.0, 170.0]):
        err = np.radians(rng.uniform(-1.5, 1.5, 3))
        R = rpy_to_R(err[0], math.radians(pitch) + err[1], yaw + err[2])
        assert grasp_pitch_deg(make_T(R, [0.3, 0.0, 0.1])) == pitch
