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
#: cup a visual shell and a collision wall; both have liquid when not empty. The cluttered
#: profile's bottles add a tapered shoulder (and a nozzle, a loop or handle pieces), cans a
#: lid and a rim, other distractors a body (see ``sim.model``).
ObjectPart = Literal[
    "wall", "neck", "cap", "shell", "liquid", "shoulder", "lid", "rim", "handle", "nozzle",
    "loop", "body", "stem",
]  # fmt: skip
WALL: ObjectPart = "wall"
NECK: ObjectPart = "neck"
CAP: ObjectPart = "cap"
SHELL: ObjectPart = "shell"
LIQUID: ObjectPart = "liquid"
SHOULDER: ObjectPart = "shoulder"
LID: ObjectPart = "lid"
RIM: ObjectPart = "rim"
HANDLE: ObjectPart = "handle"
NOZZLE: ObjectPart = "nozzle"
LOOP: ObjectPart = "loop"
BODY: ObjectPart = "body"
STEM: ObjectPart = "stem"
BOTTLE_PARTS: tuple[ObjectPart, ...] = (WALL, NECK, CAP, LIQUID)


def object_geom(obj: str, part: ObjectPart, index: int = 0) -> str:
    """Name of geom ``part`` of object body ``obj``; ``index`` > 0 numbers repeated parts
    (the upper can of a stack, a handle's pieces): ``f"{obj}_{part}{index}"``."""
    return f"{obj}_{part}" if index == 0 else f"{obj}_{part}{index}"


def object_mesh(obj: str, part: ObjectPart) -> str:
    """Name of the mesh of geom ``part`` of object ``obj`` (cluttered profile's shapes)."""
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
