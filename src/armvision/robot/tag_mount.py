"""Where the gripper's AprilTag sits on the arm: a fact about the robot, used by calibration,
fusion, the simulated bench and the drift monitor alike."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.geometry import make_T

Array = NDArray[np.float64]

#: The gripper tag's orientation in the ee frame (AprilTag convention: x right, y down, z into
#: the tag): it faces +z_ee, out of the top of the gripper, upright for a camera in front of
#: the robot. The mount's position is ``config.tag.offset_ee``; this rotation is fixed by it.
R_EE_TAG = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def tag_mount(offset_ee: ArrayLike) -> Array:
    """``T_ee_tag``: the gripper tag's pose in the ee frame for a mount at ``offset_ee`` (m)."""
    return make_T(R_EE_TAG, offset_ee)
