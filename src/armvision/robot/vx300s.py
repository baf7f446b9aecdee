"""Physical facts of the ViperX-300s gripper, from the Interbotix vx300s URDF.

Distances are metres along ``gripper_link``'s x axis (the approach direction) unless noted.
The finger geometry is the URDF's as carried by MuJoCo Menagerie's trossen_vx300s: each finger
link sits ``FINGER_LINK_X`` in front of ``gripper_link`` and its pad ``FINGER_PAD_INSET``
inboard of the finger joint coordinate, so the finger joint value (``VX300S.finger_limits``,
closed .. open) is the finger link's distance from the centre line and the gap between the
pads is ``2 * (joint value - FINGER_PAD_INSET)``.
"""

from __future__ import annotations

EE_ARM_X = 0.042825  # gripper_link -> ee_arm_link
EE_GRIPPER_X = 0.1072  # gripper_link -> ee_gripper_link, the point between the fingertips
FINGER_LINK_X = 0.0687  # gripper_link -> left/right_finger_link
FINGER_PAD_INSET = 0.0125  # finger joint coordinate -> the pad's gripping face, sideways
