"""Names of the simulated workspace's MuJoCo elements, shared by the scene builder, the world
and the evaluations that look elements up in the compiled model.

The robot's names are those of ``sim/data/vx300s.xml``; the arm's joint and actuator names
are ``VX300S.joint_names`` and its finger joints ``VX300S.finger_names``.
"""

from __future__ import annotations

from typing import Literal

ROBOT_FILE = "vx300s.xml"  # in armvision/sim/data

# The robot (sim/data/vx300s.xml).
BASE_BODY = "base_link"
GRIPPER_BODY = "gripper_link"
EE_SITE = "ee_gripper_link"
ARM_TAG_SITE = "arm_tag"
GRIPPER_ACTUATOR = "gripper"
LEFT_PAD = "left_pad"
RIGHT_PAD = "right_pad"

# The gripper's tag plate, added to gripper_link by the builder.
ARM_TAG_PLATE = "tag_plate"
ARM_TAG_MESH = "arm_tag_plate"
ARM_TAG_MATERIAL = "arm_tag"

# The bench.
CAMERA_NAME = "d435i"
CAMERA_BODY = "camera"
CAMERA_MOUNT_BODY = "camera_mount"
MARKER_BODY = "marker"

#: Geoms of an object body, named ``f"{object}_{part}"``: a bottle has wall, neck and cap, a
#: cup a visual shell and a collision wall; both have liquid when not empty.
ObjectPart = Literal["wall", "neck", "cap", "shell", "liquid"]
WALL: ObjectPart = "wall"
NECK: ObjectPart = "neck"
CAP: ObjectPart = "cap"
SHELL: ObjectPart = "shell"
LIQUID: ObjectPart = "liquid"
BOTTLE_PARTS: tuple[ObjectPart, ...] = (WALL, NECK, CAP, LIQUID)


def object_geom(obj: str, part: ObjectPart) -> str:
    """Name of geom ``part`` of object body ``obj``."""
    return f"{obj}_{part}"


def object_joint(obj: str) -> str:
    return f"{obj}_joint"


def cup_mesh(obj: str) -> str:
    return f"{obj}_cup"


def loose_tag(index: int) -> str:
    """Name of the body, plate mesh and site of the scene's ``index``-th loose tag."""
    return f"loose_tag{index}"


def tag_texture(tag_id: int) -> str:
    """Name of the texture and material showing AprilTag ``tag_id``."""
    return f"tag{tag_id}"
