"""The simulated workspace: a ViperX-300s on a table, bottles and cups, AprilTags, a D435i.

:func:`build_mjcf` writes the MuJoCo scene as MJCF text from a :class:`SceneSpec` (the part a
seed decides: camera placement, objects, loose tags); :class:`SimWorld` compiles it, owns the
physics clock and answers every ground-truth question (true camera pose, end-effector and tag
poses, object poses and fill levels, which object the gripper holds).

Frames: ``world`` has z up with the floor at z = 0; the robot's ``base`` sits on the table top
at ``TABLE_TOP_Z`` with the same orientation, so ``T_world_base`` is a pure translation. Public
methods answer in the base frame, like everything above the simulator.

Clock: in ``lockstep`` mode nothing moves until someone calls :meth:`SimWorld.run_until`
(blocking arm moves and camera reads do), so a seed gives the same run every time. In
``realtime`` mode a thread steps physics at wall-clock speed and :meth:`run_until` waits.
Controllers (the simulated servos) are called before every physics step, under the lock.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from armvision.config import Config, SimConfig
from armvision.errors import SimulationError
from armvision.geometry import inv_T, make_T, rot_z
from armvision.robot.kinematics import VX300S
from armvision.robot.tag_mount import R_EE_TAG, tag_mount
from armvision.sim import assets
from armvision.sim._mujoco import mujoco

Array = NDArray[np.float64]
log = logging.getLogger("armvision.sim")

Mode = Literal["lockstep", "realtime"]

TABLE_TOP_Z = 0.75  # world height of the table top and the robot base, metres
T_WORLD_BASE = make_T(p=[0.0, 0.0, TABLE_TOP_Z])
CAMERA_NAME = "d435i"
#: D435i colour stream at 640x480: fx = fy ~ 615 px (Intel's factory intrinsics are
#: 605-617 px). The vertical field of view, the same in every 4:3 and 16:9 mode of the colour
#: stream, follows from it; MuJoCo cameras are specified by exactly this angle.
D435I_FY_AT_480 = 615.0
D435I_FOVY_DEG = math.degrees(2.0 * math.atan(240.0 / D435I_FY_AT_480))

#: ViperX-300s joint origins, parent to child, from the Interbotix vx300s URDF.
URDF_JOINT_ORIGINS = {
    "waist": (0.0, 0.0, 0.079),
    "shoulder": (0.0, 0.0, 0.04805),
    "elbow": (0.05955, 0.0, 0.3),
    "forearm_roll": (0.2, 0.0, 0.0),
    "wrist_angle": (0.1, 0.0, 0.0),
    "wrist_rotate": (0.069744, 0.0, 0.0),
}
EE_ARM_X = 0.042825  # gripper_link -> ee_arm_link
EE_GRIPPER_X = 0.1072  # gripper_link -> ee_gripper_link, the point between the fingertips
#: Finger geometry from MuJoCo Menagerie's trossen_vx300s: the finger links sit 0.0687 m in
#: front of gripper_link and their pads 0.0125 m inboard of the finger joint coordinate, so
#: the joint value (0.021 closed .. 0.057 open) is the finger link's distance from the centre
#: line and the pads are 17 mm apart closed, 89 mm open.
FINGER_LINK_X = 0.0687
FINGER_PAD_INSET = 0.0125

#: Servo model per joint: (armature kg m^2, kp N m/rad, kv N m s/rad, torque limit N m).
#: Torque limits are the Dynamixel stall torques at 12 V of the vx300s' servos (XM540-W270:
#: 10.6 N m, doubled on shoulder and elbow; XM430-W350 on wrist_rotate: 4.1 N m). The armature
#: stands for the reflected rotor inertia; kp and kv are chosen stiff and critically damped so
#: the arm tracks its profile within a fraction of a millimetre, as a Dynamixel's PID does.
SERVOS = {
    "waist": (0.04, 600.0, 21.0, 10.6),
    "shoulder": (0.08, 1000.0, 33.0, 21.2),
    "elbow": (0.08, 800.0, 20.0, 21.2),
    "forearm_roll": (0.04, 200.0, 6.0, 10.6),
    "wrist_angle": (0.04, 200.0, 6.0, 10.6),
    "wrist_rotate": (0.02, 100.0, 3.0, 4.1),
}
#: Link inertials (COM position, mass kg, principal inertia) from the Interbotix URDF as
#: carried by MuJoCo Menagerie's trossen_vx300s (principal axes simplified to the link axes).
INERTIALS = {
    "base_link": ((-0.0535, -0.0006, 0.0206), 0.969, (0.0072, 0.0060, 0.0017)),
    "shoulder_link": ((0.0003, 0.0, 0.0116), 0.799, (0.0012, 0.0011, 0.0009)),
    "upper_arm_link": ((0.0207, 0.0, 0.2265), 0.793, (0.0091, 0.0089, 0.0008)),
    "upper_forearm_link": ((0.1057, 0.0, 0.0), 0.322, (0.0014, 0.0013, 0.0002)),
    "lower_forearm_link": ((0.0513, 0.0068, 0.0), 0.415, (0.0006, 0.0005, 0.0002)),
    "wrist_link": ((0.0467, 0.0, 0.0106), 0.115, (5.5e-5, 4.6e-5, 4.3e-5)),
    "gripper_link": ((0.0396, 0.0, 0.0040), 0.260, (0.0007, 0.0007, 0.0005)),
    "left_finger_link": ((0.0173, -0.0061, 0.0), 0.0348, (2.5e-5, 1.4e-5, 1.2e-5)),
    "right_finger_link": ((0.0173, 0.0061, 0.0), 0.0348, (2.5e-5, 1.4e-5, 1.2e-5)),
}
GRIPPER_MAX_FORCE_N = 30.0  # finger force at gripper_pressure = 1; 0.5 (default) gives 15 N
#: Contact parameters of Menagerie's vx300s finger pads (condim 4 = torsional friction too).
PAD_CONTACT = 'condim="4" solimp="2 1 0.01" solref="0.01 1" friction="1 0.005 0.0001"'

#: Where the scene generator puts objects, base frame: radius from the base axis, bearing.
OBJECT_RADIAL_RANGE = (0.28, 0.52)
OBJECT_BEARING_RANGE = (-math.radians(50.0), math.radians(50.0))
OBJECT_CLEARANCE = 0.06  # free gap between objects, room for a finger
LIQUID_COLOURS = {
    "water": (0.55, 0.75, 0.95, 1.0),
    "juice": (0.95, 0.55, 0.1, 1.0),
    "cola": (0.25, 0.1, 0.05, 1.0),
    "wine": (0.5, 0.05, 0.15, 1.0),
    "milk": (0.95, 0.95, 0.92, 1.0),
}
CUP_COLOURS = (
    (0.85, 0.2, 0.2, 1.0),
    (0.2, 0.45, 0.85, 1.0),
    (0.95, 0.95, 0.95, 1.0),
    (0.2, 0.65, 0.3, 1.0),
)
LIQUID_DENSITY = 1000.0  # kg/m^3
BOTTLE_WALL = 0.0015  # m; also the gap between the liquid and the wall
BOTTLE_BASE = 0.003  # m, bottom thickness under the liquid
CUP_WALL = 0.004
MARKER_PARKED = (0.0, 0.0, -10.0)  # the marker sphere's home, far out of view (world frame)


# --------------------------------------------------------------------------- small pure helpers


def _f(values: ArrayLike) -> str:
    """Numbers for an MJCF attribute."""
    return " ".join(f"{v:.10g}" for v in np.atleast_1d(np.asarray(values, dtype=float)))


def quat_wxyz(R: ArrayLike) -> Array:
    """MuJoCo's (w, x, y, z) quaternion of rotation matrix ``R``."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return np.array([w, x, y, z])


#: MuJoCo cameras look along -z with y up; the OpenCV optical frame looks along +z with y down.
R_MJCAM_CAM = np.diag([1.0, -1.0, -1.0])


def camera_pose_from_placement(
    distance: float, azimuth: float, height: float, pitch: float
) -> Array:
    """``T_base_cam`` (OpenCV optical frame) of a camera facing the base axis, pitched down.

    The camera sits ``distance`` from the base z axis at bearing ``azimuth`` (rad, 0 = +x) and
    ``height`` above the base; its optical axis points horizontally at the base axis, then
    tilts down by ``pitch`` (rad). Image x is horizontal (no roll).
    """
    p_base_cam = np.array([distance * math.cos(azimuth), distance * math.sin(azimuth), height])
    forward = -np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    z_cam = math.cos(pitch) * forward + math.sin(pitch) * np.array([0.0, 0.0, -1.0])
    x_cam = np.cross(z_cam, [0.0, 0.0, 1.0])
    x_cam /= np.linalg.norm(x_cam)
    y_cam = np.cross(z_cam, x_cam)
    return make_T(np.column_stack([x_cam, y_cam, z_cam]), p_base_cam)


#: The textured plate mesh shows its image on +z with the image top at +y (see assets).
R_TAG_PLATE = np.diag([1.0, -1.0, -1.0])


# --------------------------------------------------------------------------- scene description


@dataclass(frozen=True)
class ObjectSpec:
    """A bottle or cup standing on the table; its frame is at the bottom centre, z up.

    ``fill`` is the liquid column as a fraction of the inner height of the bottle's body (the
    cylinder below the neck) or of the cup. ``x, y, yaw`` place it in the base frame.
    """

    name: str
    kind: Literal["bottle", "cup"]
    radius: float
    height: float
    fill: float
    liquid: str
    x: float
    y: float
    yaw: float = 0.0
    colour: tuple[float, float, float, float] = (0.85, 0.92, 1.0, 0.25)

    @property
    def body_height(self) -> float:
        """Height of the part that holds liquid: a bottle's cylinder, a whole cup."""
        return 0.72 * self.height if self.kind == "bottle" else self.height

    @property
    def inner_radius(self) -> float:
        return self.radius - (BOTTLE_WALL if self.kind == "bottle" else CUP_WALL)

    @property
    def inner_bottom(self) -> float:
        return BOTTLE_BASE if self.kind == "bottle" else CUP_WALL

    @property
    def liquid_height(self) -> float:
        """Height of the liquid column, metres."""
        return self.fill * (self.body_height - self.inner_bottom)

    @property
    def liquid_top(self) -> float:
        """Height of the liquid surface above the object's bottom (upright), metres."""
        return self.inner_bottom + self.liquid_height

    @property
    def liquid_mass(self) -> float:
        return LIQUID_DENSITY * math.pi * self.inner_radius**2 * self.liquid_height

    @property
    def shell_mass(self) -> float:
        # A PET bottle weighs ~20-30 g; a ceramic or plastic cup ~100 g.
        return 0.03 if self.kind == "bottle" else 0.1


@dataclass(frozen=True)
class LooseTag:
    """An AprilTag lying on the table (like a printed sticker), base frame."""

    tag_id: int
    x: float
    y: float
    yaw: float
    size: float


@dataclass(frozen=True)
class Lighting:
    """The scene's lights: MuJoCo's headlight (at the camera) and one directional key light.

    ``ambient``, ``headlight`` and ``key`` are grey intensities 0..1 (the headlight's ambient
    and diffuse, the key light's diffuse); ``key_dir`` is the key light's direction in the
    world frame (pointing from the light into the scene). The defaults are the fixed lighting
    every scene had before lighting could vary.
    """

    ambient: float = 0.35
    headlight: float = 0.45
    key: float = 0.45
    key_dir: tuple[float, float, float] = (0.0, 0.0, -1.0)


def random_lighting(rng: np.random.Generator) -> Lighting:
    """Dim to bright rooms: ambient 0.15-0.5, headlight 0.15-0.6, key light 0.2-0.8 shining
    down at 35-90 degrees of elevation from any bearing."""
    elevation = math.radians(rng.uniform(35.0, 90.0))
    bearing = rng.uniform(-math.pi, math.pi)
    key_dir = (
        -math.cos(elevation) * math.cos(bearing),
        -math.cos(elevation) * math.sin(bearing),
        -math.sin(elevation),
    )
    return Lighting(
        ambient=float(rng.uniform(0.15, 0.5)),
        headlight=float(rng.uniform(0.15, 0.6)),
        key=float(rng.uniform(0.2, 0.8)),
        key_dir=key_dir,
    )


@dataclass(frozen=True)
class SceneSpec:
    """Everything a seed decides about a scene."""

    T_base_cam: Array
    objects: tuple[ObjectSpec, ...] = ()
    loose_tags: tuple[LooseTag, ...] = ()
    lighting: Lighting = field(default_factory=Lighting)


def random_camera_pose(sim: SimConfig, rng: np.random.Generator | None) -> Array:
    """``T_base_cam`` from the configured placement, jittered when ``randomize_camera``."""
    distance, azimuth = sim.camera_distance, math.radians(sim.camera_azimuth_deg)
    height, pitch = sim.camera_height, math.radians(sim.camera_pitch_deg)
    if sim.randomize_camera and rng is not None:
        distance += rng.uniform(-1, 1) * sim.camera_distance_jitter
        azimuth += math.radians(rng.uniform(-1, 1) * sim.camera_azimuth_jitter_deg)
        height += rng.uniform(-1, 1) * sim.camera_height_jitter
        pitch += math.radians(rng.uniform(-1, 1) * sim.camera_pitch_jitter_deg)
    return camera_pose_from_placement(distance, azimuth, height, pitch)


def random_object(rng: np.random.Generator, name: str) -> ObjectSpec:
    """A bottle (2/3 of the time) or cup with random size, fill and liquid, not yet placed.

    Radii stay below 0.038 m so the open gripper (pads 89 mm apart) fits around them.
    """
    liquid = str(rng.choice(list(LIQUID_COLOURS)))
    fill = float(rng.uniform(0.1, 0.9))
    if rng.uniform() < 2.0 / 3.0:
        return ObjectSpec(
            name,
            "bottle",
            radius=float(rng.uniform(0.026, 0.037)),
            height=float(rng.uniform(0.16, 0.24)),
            fill=fill,
            liquid=liquid,
            x=0.0,
            y=0.0,
        )
    colour = CUP_COLOURS[int(rng.integers(len(CUP_COLOURS)))]
    return ObjectSpec(
        name,
        "cup",
        radius=float(rng.uniform(0.03, 0.037)),
        height=float(rng.uniform(0.08, 0.11)),
        fill=fill,
        liquid=liquid,
        x=0.0,
        y=0.0,
        colour=colour,
    )


def place_without_overlap(
    rng: np.random.Generator,
    radii: list[float],
    radial_range: tuple[float, float] = OBJECT_RADIAL_RANGE,
    bearing_range: tuple[float, float] = OBJECT_BEARING_RANGE,
    clearance: float = OBJECT_CLEARANCE,
    max_tries: int = 2000,
) -> list[tuple[float, float]]:
    """Random (x, y) in the base frame for discs of ``radii``, ``clearance`` apart.

    Sampled uniformly by area in the annular sector ``radial_range`` x ``bearing_range`` (the
    reachable part of the table in front of the robot and the camera), by rejection.
    """
    placed: list[tuple[float, float, float]] = []
    r_lo, r_hi = radial_range
    for radius in radii:
        for _ in range(max_tries):
            rho = math.sqrt(rng.uniform(r_lo**2, r_hi**2))
            bearing = rng.uniform(*bearing_range)
            x, y = rho * math.cos(bearing), rho * math.sin(bearing)
            if all(math.hypot(x - px, y - py) >= radius + pr + clearance for px, py, pr in placed):
                placed.append((x, y, radius))
                break
        else:
            raise SimulationError(
                f"could not place {len(radii)} objects without overlap; use fewer objects"
            )
    return [(x, y) for x, y, _ in placed]


def _rigid(T: ArrayLike, name: str) -> Array:
    """``T`` as a finite 4x4 with an orthonormal rotation, or SimulationError naming it."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise SimulationError(f"{name} must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-6):
        raise SimulationError(f"{name}'s rotation is not orthonormal: build it with make_T")
    return T


def bench_scene(config: Config) -> SceneSpec:
    """A fixed bench, the same every time: a juice bottle (60 % full) and a water cup in easy
    reach, and tag ``follow.tag_id`` lying between them, under the configured camera. For
    tests and benchmarks of the running system and its UI."""
    bottle = ObjectSpec("bottle", "bottle", 0.032, 0.2, 0.6, "juice", x=0.40, y=0.10)
    cup = ObjectSpec(
        "cup", "cup", 0.034, 0.1, 0.3, "water", x=0.33, y=-0.17, colour=(0.8, 0.2, 0.2, 1.0)
    )
    tag = LooseTag(config.follow.tag_id, 0.45, -0.03, 0.3, config.tag.size)
    return SceneSpec(random_camera_pose(config.sim, None), (bottle, cup), (tag,))


def generate_scene(config: Config, seed: int) -> SceneSpec:
    """The scene for ``seed``: camera pose, 1-4 objects and any loose tags, without overlap."""
    sim = config.sim
    rng = np.random.default_rng(seed)
    T_base_cam = random_camera_pose(sim, rng)
    n = int(rng.integers(sim.min_objects, sim.max_objects + 1))
    drafts = [random_object(rng, f"object{i}") for i in range(n)]
    tag_half = assets.tag_outer_size(config.tag.size) / math.sqrt(2.0)
    radii = [o.radius for o in drafts] + [tag_half] * sim.loose_tags
    xy = place_without_overlap(rng, radii)
    objects = tuple(
        dataclasses.replace(o, x=x, y=y, yaw=float(rng.uniform(-math.pi, math.pi)))
        for o, (x, y) in zip(drafts, xy[:n])
    )
    free_ids = [i for i in range(100) if i != config.tag.id]
    loose = tuple(
        LooseTag(free_ids[k], x, y, float(rng.uniform(-math.pi, math.pi)), config.tag.size)
        for k, (x, y) in enumerate(xy[n:])
    )
    # Lighting draws from its own stream so switching it on leaves the rest of the scene as is.
    lighting = (
        random_lighting(np.random.default_rng([seed, 0x11647]))
        if sim.randomize_lighting
        else Lighting()
    )
    return SceneSpec(T_base_cam, objects, loose, lighting)


# --------------------------------------------------------------------------- MJCF


def _robot_xml(tag_size: float, offset_ee: ArrayLike) -> str:
    """The ViperX-300s: link chain as the URDF, primitive geoms sized like the links."""

    def inertial(link: str) -> str:
        pos, mass, inertia = INERTIALS[link]
        return f'<inertial pos="{_f(pos)}" mass="{mass}" diaginertia="{_f(inertia)}"/>'

    def joint(name: str, axis: str) -> str:
        i = VX300S.joint_names.index(name)
        armature = SERVOS[name][0]
        return (
            f'<joint name="{name}" axis="{axis}" range="{VX300S.lower[i]:.10g} '
            f'{VX300S.upper[i]:.10g}" armature="{armature}" damping="0.1"/>'
        )

    def pos(name: str) -> str:
        return _f(URDF_JOINT_ORIGINS[name])

    R_ee_plate = R_EE_TAG @ R_TAG_PLATE
    p_gripper_tag = np.array([EE_GRIPPER_X, 0.0, 0.0]) + np.asarray(offset_ee, dtype=float)
    finger_pad = (
        'type="box" size="0.034 0.006 0.012" class="pad"'  # pad from -1 mm to 67 mm along x
    )
    return f"""
    <body name="base_link" pos="{_f(T_WORLD_BASE[:3, 3])}" childclass="arm">
      {inertial("base_link")}
      <geom name="base" type="box" size="0.07 0.06 0.036" pos="-0.035 0 0.036"/>
      <body name="shoulder_link" pos="{pos("waist")}" gravcomp="1">
        {inertial("shoulder_link")}
        {joint("waist", "0 0 1")}
        <geom name="shoulder" type="cylinder" size="0.045 0.022" pos="0 0 0.02"/>
        <body name="upper_arm_link" pos="{pos("shoulder")}" gravcomp="1">
          {inertial("upper_arm_link")}
          {joint("shoulder", "0 1 0")}
          <geom name="shoulder_servos" type="cylinder" size="0.03 0.045" zaxis="0 1 0"/>
          <geom name="upper_arm" type="capsule" size="0.024" fromto="0 0 0.03 0 0 0.3"/>
          <geom name="upper_arm_elbow" type="capsule" size="0.024" fromto="0 0 0.3 0.04 0 0.3"/>
          <body name="upper_forearm_link" pos="{pos("elbow")}" gravcomp="1">
            {inertial("upper_forearm_link")}
            {joint("elbow", "0 1 0")}
            <geom name="elbow_servos" type="cylinder" size="0.028 0.04" zaxis="0 1 0"/>
            <geom name="upper_forearm" type="capsule" size="0.022" fromto="0.03 0 0 0.2 0 0"/>
            <body name="lower_forearm_link" pos="{pos("forearm_roll")}" gravcomp="1">
              {inertial("lower_forearm_link")}
              {joint("forearm_roll", "1 0 0")}
              <geom name="lower_forearm" type="box" size="0.045 0.022 0.024" pos="0.05 0 0"/>
              <body name="wrist_link" pos="{pos("wrist_angle")}" gravcomp="1">
                {inertial("wrist_link")}
                {joint("wrist_angle", "0 1 0")}
                <geom name="wrist" type="box" size="0.03 0.02 0.022" pos="0.035 0 0"/>
                <body name="gripper_link" pos="{pos("wrist_rotate")}" gravcomp="1">
                  {inertial("gripper_link")}
                  {joint("wrist_rotate", "1 0 0")}
                  <geom name="gripper_servo" type="box" size="0.022 0.024 0.024" pos="0.01 0 0"/>
                  <geom name="gripper_bar" type="box" size="0.012 0.06 0.012" pos="0.055 0 0"/>
                  <geom name="tag_plate" type="mesh" mesh="arm_tag_plate" material="arm_tag"
                        pos="{_f(p_gripper_tag)}" quat="{_f(quat_wxyz(R_ee_plate))}"
                        contype="0" conaffinity="0" density="0" rgba="1 1 1 1"/>
                  <site name="ee_arm_link" pos="{EE_ARM_X} 0 0" size="0.004" group="4"/>
                  <site name="ee_gripper_link" pos="{EE_GRIPPER_X} 0 0" size="0.004" group="4"/>
                  <site name="arm_tag" pos="{_f(p_gripper_tag)}" quat="{_f(quat_wxyz(R_EE_TAG))}"
                        size="0.004" group="4"/>
                  <body name="left_finger_link" pos="{FINGER_LINK_X} 0 0" gravcomp="1">
                    {inertial("left_finger_link")}
                    <joint name="left_finger" type="slide" axis="0 1 0" range="0.021 0.057"
                           armature="0.251" damping="10"/>
                    <geom name="left_pad" {finger_pad} pos="0.033 {-FINGER_PAD_INSET + 0.006} 0"/>
                  </body>
                  <body name="right_finger_link" pos="{FINGER_LINK_X} 0 0" gravcomp="1">
                    {inertial("right_finger_link")}
                    <joint name="right_finger" type="slide" axis="0 1 0" range="-0.057 -0.021"
                           armature="0.251" damping="10"/>
                    <geom name="right_pad" {finger_pad} pos="0.033 {FINGER_PAD_INSET - 0.006} 0"/>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>"""


def _actuators_xml(gripper_pressure: float) -> str:
    lines = []
    for name in VX300S.joint_names:
        i = VX300S.joint_names.index(name)
        _, kp, kv, torque = SERVOS[name]
        lines.append(
            f'<position name="{name}" joint="{name}" kp="{kp}" kv="{kv}" '
            f'ctrlrange="{VX300S.lower[i]:.10g} {VX300S.upper[i]:.10g}" '
            f'forcerange="{-torque} {torque}"/>'
        )
    force = GRIPPER_MAX_FORCE_N * max(gripper_pressure, 0.05)
    lines.append(
        f'<position name="gripper" joint="left_finger" kp="2000" kv="20" '
        f'ctrlrange="0.021 0.057" forcerange="{-force:.4g} {force:.4g}"/>'
    )
    return "\n    ".join(lines)


def _object_xml(obj: ObjectSpec) -> str:
    """A free body: bottle = transparent cylinder + neck + cap; cup = lathed mesh."""
    T_world_obj = T_WORLD_BASE @ make_T(rot_z(obj.yaw), [obj.x, obj.y, 0.0])
    head = (
        f'<body name="{obj.name}" pos="{_f(T_world_obj[:3, 3])}" '
        f'quat="{_f(quat_wxyz(T_world_obj[:3, :3]))}">\n'
        f'      <freejoint name="{obj.name}_joint"/>'
    )
    parts = [head]
    r, h = obj.radius, obj.body_height
    if obj.kind == "bottle":
        neck_r, neck_h, cap_h = 0.42 * r, obj.height - h - 0.018, 0.018
        parts += [
            f'<geom name="{obj.name}_wall" type="cylinder" size="{r:.6g} {h / 2:.6g}" '
            f'pos="0 0 {h / 2:.6g}" rgba="{_f(obj.colour)}" mass="{obj.shell_mass * 0.8:.4g}" '
            'class="object"/>',
            f'<geom name="{obj.name}_neck" type="cylinder" size="{neck_r:.6g} {neck_h / 2:.6g}" '
            f'pos="0 0 {h + neck_h / 2:.6g}" rgba="{_f(obj.colour)}" '
            f'mass="{obj.shell_mass * 0.1:.4g}" class="object"/>',
            f'<geom name="{obj.name}_cap" type="cylinder" size="{neck_r * 1.12:.6g} '
            f'{cap_h / 2:.6g}" pos="0 0 {obj.height - cap_h / 2:.6g}" '
            f'rgba="0.9 0.9 0.9 1" mass="{obj.shell_mass * 0.1:.4g}" class="object"/>',
        ]
    else:
        parts += [
            f'<geom name="{obj.name}_shell" type="mesh" mesh="{obj.name}_cup" '
            f'rgba="{_f(obj.colour)}" contype="0" conaffinity="0" mass="{obj.shell_mass}"/>',
            # The collision shape is the cup's convex hull: nothing is put into cups.
            f'<geom name="{obj.name}_wall" type="cylinder" size="{r:.6g} {h / 2:.6g}" '
            f'pos="0 0 {h / 2:.6g}" rgba="0 0 0 0" group="3" density="0" class="object"/>',
        ]
    if obj.liquid_height > 1e-4:
        lh = obj.liquid_height
        parts.append(
            f'<geom name="{obj.name}_liquid" type="cylinder" '
            f'size="{obj.inner_radius - 0.0005:.6g} {lh / 2:.6g}" '
            f'pos="0 0 {obj.inner_bottom + lh / 2:.6g}" '
            f'rgba="{_f(LIQUID_COLOURS[obj.liquid])}" mass="{obj.liquid_mass:.6g}" '
            'contype="0" conaffinity="0"/>'
        )
    parts.append("</body>")
    return "\n      ".join(parts)


def _loose_tag_xml(tag: LooseTag, index: int) -> str:
    # The tag lies face up: plate +z = world up, so the tag's z (into the tag) points down.
    T_world_plate = T_WORLD_BASE @ make_T(rot_z(tag.yaw), [tag.x, tag.y, 0.001])
    R_plate_tag = R_TAG_PLATE.T
    return (
        f'<body name="loose_tag{index}" mocap="true" pos="{_f(T_world_plate[:3, 3])}" '
        f'quat="{_f(quat_wxyz(T_world_plate[:3, :3]))}">\n'
        f'      <geom type="mesh" mesh="loose_tag{index}" material="tag{tag.tag_id}" '
        'contype="0" conaffinity="0" density="0"/>\n'
        f'      <site name="loose_tag{index}" quat="{_f(quat_wxyz(R_plate_tag))}" size="0.004" '
        'group="4"/>\n    </body>'
    )


def build_mjcf(config: Config, scene: SceneSpec) -> tuple[str, dict[str, bytes]]:
    """MJCF text and its asset files (tag textures) for ``scene``."""
    sim, tag = config.sim, config.tag
    light = scene.lighting
    width, height = config.camera.width, config.camera.height
    files: dict[str, bytes] = {}
    textures, meshes = [], []

    def add_tag_texture(tag_id: int) -> None:
        if f"tag{tag_id}.png" in files:
            return
        files[f"tag{tag_id}.png"] = assets.png_bytes(assets.tag_image(tag_id, tag.family))
        textures.append(
            f'<texture name="tag{tag_id}" type="2d" file="tag{tag_id}.png"/>\n'
            f'    <material name="tag{tag_id}" texture="tag{tag_id}" specular="0" shininess="0"/>'
        )

    def add_plate_mesh(name: str, black_size: float) -> None:
        v, f, uv = assets.textured_plate_mesh(assets.tag_outer_size(black_size), 0.001)
        meshes.append(
            f'<mesh name="{name}" vertex="{assets.mjcf_floats(v)}" '
            f'face="{assets.mjcf_floats(f)}" texcoord="{assets.mjcf_floats(uv)}"/>'
        )

    add_tag_texture(tag.id)
    textures.append(f'<material name="arm_tag" texture="tag{tag.id}" specular="0" shininess="0"/>')
    add_plate_mesh("arm_tag_plate", tag.size)
    for k, loose in enumerate(scene.loose_tags):
        add_tag_texture(loose.tag_id)
        add_plate_mesh(f"loose_tag{k}", loose.size)
    for obj in scene.objects:
        if obj.kind == "cup":
            v, f = assets.lathe_mesh(assets.cup_profile(obj.radius, obj.height, CUP_WALL), 40)
            meshes.append(
                f'<mesh name="{obj.name}_cup" vertex="{assets.mjcf_floats(v)}" '
                f'face="{assets.mjcf_floats(f)}"/>'
            )

    T_world_cam = T_WORLD_BASE @ scene.T_base_cam
    R_world_mjcam = T_world_cam[:3, :3] @ R_MJCAM_CAM
    mount_yaw = math.atan2(T_world_cam[1, 2], T_world_cam[0, 2])  # stand faces the camera's way
    pole_top = T_world_cam[2, 3] - 0.03
    body_xml = "\n    ".join(
        [_object_xml(o) for o in scene.objects]
        + [_loose_tag_xml(t, k) for k, t in enumerate(scene.loose_tags)]
    )
    xml = f"""
<mujoco model="armvision_workspace">
  <compiler angle="radian" autolimits="true"/>
  <!-- Menagerie's vx300s uses elliptic cones and impratio 10 so grasped objects do not slip. -->
  <option timestep="{sim.timestep}" integrator="implicitfast" cone="elliptic" impratio="10"/>
  <size memory="20M"/>
  <statistic center="0.3 0 0.9" extent="2"/>
  <visual>
    <global offwidth="{max(width, 640)}" offheight="{max(height, 480)}"/>
    <map znear="0.01" zfar="20"/>
    <quality shadowsize="2048"/>
    <headlight ambient="{_f([light.ambient] * 3)}" diffuse="{_f([light.headlight] * 3)}"
               specular="0.05 0.05 0.05"/>
  </visual>
  <default>
    <default class="arm">
      <geom contype="2" conaffinity="1" rgba="0.12 0.12 0.13 1" density="0"/>
      <default class="pad">
        <geom {PAD_CONTACT} rgba="0.2 0.2 0.22 1"/>
      </default>
    </default>
    <default class="object">
      <geom contype="1" conaffinity="3" friction="1 0.005 0.0001" condim="4"/>
    </default>
  </default>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.75 0.78 0.82" rgb2="0.5 0.52 0.55"
             width="64" height="64"/>
    <texture name="floor" type="2d" builtin="checker" rgb1="0.42 0.4 0.38" rgb2="0.38 0.36 0.34"
             width="256" height="256"/>
    <material name="floor" texture="floor" texrepeat="6 6"/>
    <material name="table" rgba="0.72 0.6 0.45 1" specular="0.1"/>
    {chr(10).join(textures)}
    {chr(10).join(meshes)}
  </asset>
  <worldbody>
    <light name="ceiling" pos="0.4 0 3" dir="{_f(light.key_dir)}" directional="true"
           diffuse="{_f([light.key] * 3)}" castshadow="false"/>
    <geom name="floor" type="plane" size="4 4 0.1" material="floor" contype="1" conaffinity="3"/>
    <geom name="table" type="box" size="0.55 0.65 {TABLE_TOP_Z / 2}" pos="0.3 0 {TABLE_TOP_Z / 2}"
          material="table" contype="1" conaffinity="3" friction="0.6 0.005 0.0001"/>
    {_robot_xml(tag.size, tag.offset_ee)}
    <body name="camera_mount" mocap="true" pos="{_f(T_world_cam[:3, 3])}"
          quat="{_f(quat_wxyz(rot_z(mount_yaw)))}">
      <geom name="camera_pole" type="cylinder" size="0.012 {pole_top / 2:.6g}"
            pos="-0.03 0 {-0.03 - pole_top / 2:.6g}" rgba="0.2 0.2 0.2 1" contype="0"
            conaffinity="0"/>
    </body>
    <body name="camera" mocap="true" pos="{_f(T_world_cam[:3, 3])}"
          quat="{_f(quat_wxyz(R_world_mjcam))}">
      <camera name="{CAMERA_NAME}" fovy="{D435I_FOVY_DEG:.10g}"/>
      <!-- D435i housing (90 x 25 x 25 mm) just behind the optical centre, out of its view -->
      <geom name="camera_housing" type="box" size="0.045 0.0125 0.0125" pos="0.0 0 0.014"
            rgba="0.15 0.15 0.15 1" contype="0" conaffinity="0"/>
    </body>
    <body name="marker" mocap="true" pos="{_f(MARKER_PARKED)}">
      <geom name="marker" type="sphere" size="0.01" rgba="1 0 0 1" material="marker"
            contype="0" conaffinity="0"/>
    </body>
    {body_xml}
  </worldbody>
  <equality>
    <joint joint1="right_finger" joint2="left_finger" polycoef="0 -1 0 0 0"/>
  </equality>
  <actuator>
    {_actuators_xml(config.robot.gripper_pressure)}
  </actuator>
</mujoco>
"""
    xml = xml.replace("<asset>", '<asset>\n    <material name="marker" emission="1"/>', 1)
    return xml, files


# --------------------------------------------------------------------------- ground truth records


@dataclass(frozen=True)
class ObjectState:
    """Ground truth of one object: its spec plus where it is now (bottom centre, base frame)."""

    spec: ObjectSpec
    T_base_obj: Array
    held: bool

    @property
    def upright(self) -> bool:
        return bool(self.T_base_obj[2, 2] > math.cos(math.radians(10.0)))

    def to_dict(self) -> dict[str, Any]:
        s = self.spec
        return {
            "name": s.name,
            "kind": s.kind,
            "radius": s.radius,
            "height": s.height,
            "fill": s.fill,
            "liquid": s.liquid,
            "liquid_rgba": list(LIQUID_COLOURS[s.liquid]),
            "liquid_top_above_bottom": s.liquid_top,
            "T_base_obj": self.T_base_obj.tolist(),
            "position_base": self.T_base_obj[:3, 3].tolist(),
            "upright": self.upright,
            "held": self.held,
        }


@dataclass(frozen=True)
class GroundTruth:
    """Everything the simulator knows at one instant, in the base frame."""

    time: float
    T_base_cam: Array
    T_base_ee: Array
    T_base_tag: Array
    T_ee_tag: Array
    joint_positions: Array
    finger_position: float
    objects: tuple[ObjectState, ...]
    held_object: str | None
    loose_tags: dict[int, Array] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "time": self.time,
            "frames": "T_a_b is the pose of frame b in frame a; cam is the OpenCV optical frame",
            "T_world_base": T_WORLD_BASE.tolist(),
            "T_base_cam": self.T_base_cam.tolist(),
            "T_base_ee": self.T_base_ee.tolist(),
            "T_base_tag": self.T_base_tag.tolist(),
            "T_ee_tag": self.T_ee_tag.tolist(),
            "joint_names": list(VX300S.joint_names),
            "joint_positions": self.joint_positions.tolist(),
            "finger_position": self.finger_position,
            "objects": [o.to_dict() for o in self.objects],
            "held_object": self.held_object,
            "loose_tags": {str(k): v.tolist() for k, v in self.loose_tags.items()},
        }


# --------------------------------------------------------------------------- the world


Controller = Callable[[float], None]


class SimWorld:
    """The workspace in MuJoCo: build it from a config and a seed, step it, ask it the truth.

    ``mode="lockstep"``: time advances only in :meth:`run_until` (called by blocking arm moves,
    gripper actions and camera reads), so runs are repeatable. ``mode="realtime"``: a thread
    steps physics at wall-clock speed until :meth:`close`. Use as a context manager.
    """

    def __init__(
        self,
        config: Config | None = None,
        seed: int = 0,
        mode: Mode = "lockstep",
        scene: SceneSpec | None = None,
    ) -> None:
        if mode not in ("lockstep", "realtime"):
            raise SimulationError(f"mode must be 'lockstep' or 'realtime', not {mode!r}")
        self.config = config if config is not None else Config()
        self.seed = int(seed)
        self.mode: Mode = mode
        self.scene = scene if scene is not None else generate_scene(self.config, self.seed)
        xml, files = build_mjcf(self.config, self.scene)
        try:
            self.model = mujoco.MjModel.from_xml_string(xml, files)
        except ValueError as exc:  # MuJoCo reports compile errors as ValueError
            raise SimulationError(f"the simulated workspace does not compile: {exc}") from exc
        self.data = mujoco.MjData(self.model)
        self.lock = threading.RLock()
        self._controllers: list[Controller] = []
        self._ids()
        self._set_initial_state()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._thread_error: BaseException | None = None
        if mode == "realtime":
            self._thread = threading.Thread(
                target=self._realtime_loop, name="sim-physics", daemon=True
            )
            self._thread.start()

    # ---------------------------------------------------------------- construction helpers

    def _ids(self) -> None:
        m = self.model

        def idx(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(m, kind, name)
            if i < 0:  # pragma: no cover - only if build_mjcf and this disagree
                raise SimulationError(f"internal: the scene has no {name}")
            return i

        J, B, S, G = (
            mujoco.mjtObj.mjOBJ_JOINT,
            mujoco.mjtObj.mjOBJ_BODY,
            mujoco.mjtObj.mjOBJ_SITE,
            mujoco.mjtObj.mjOBJ_GEOM,
        )
        self._qadr = np.array([m.jnt_qposadr[idx(J, n)] for n in VX300S.joint_names])
        self._dofadr = np.array([m.jnt_dofadr[idx(J, n)] for n in VX300S.joint_names])
        self._finger_qadr = (
            m.jnt_qposadr[idx(J, "left_finger")],
            m.jnt_qposadr[idx(J, "right_finger")],
        )
        self.arm_actuators = np.array(
            [idx(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in VX300S.joint_names]
        )
        self.gripper_actuator = idx(mujoco.mjtObj.mjOBJ_ACTUATOR, "gripper")
        self._ee_site = idx(S, "ee_gripper_link")
        self._tag_site = idx(S, "arm_tag")
        self._loose_sites = {
            t.tag_id: idx(S, f"loose_tag{k}") for k, t in enumerate(self.scene.loose_tags)
        }
        self.camera_id = idx(mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        self._camera_mocap = m.body_mocapid[idx(B, "camera")]
        self._mount_mocap = m.body_mocapid[idx(B, "camera_mount")]
        self._marker_mocap = m.body_mocapid[idx(B, "marker")]
        self._object_bodies = {o.name: idx(B, o.name) for o in self.scene.objects}
        self._pads = (idx(G, "left_pad"), idx(G, "right_pad"))

    def _set_initial_state(self) -> None:
        """Arm in its sleep pose (as the real arm powers up), gripper open, objects at rest."""
        d = self.data
        d.qpos[self._qadr] = VX300S.sleep
        d.qpos[self._finger_qadr[0]] = VX300S.finger_limits[1]
        d.qpos[self._finger_qadr[1]] = -VX300S.finger_limits[1]
        d.ctrl[self.arm_actuators] = VX300S.sleep
        d.ctrl[self.gripper_actuator] = VX300S.finger_limits[1]
        mujoco.mj_forward(self.model, d)

    # ---------------------------------------------------------------- clock

    @property
    def time(self) -> float:
        """Simulation time, seconds since the world was built."""
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def add_controller(self, controller: Controller) -> None:
        """Call ``controller(t)`` before every physics step (under the lock) to set ``ctrl``."""
        with self.lock:
            self._controllers.append(controller)

    def remove_controller(self, controller: Controller) -> None:
        with self.lock:
            self._controllers.remove(controller)

    def _step(self, n: int) -> None:
        """``n`` physics steps with the controllers run before each; caller holds the lock."""
        m, d = self.model, self.data
        if not self._controllers:
            mujoco.mj_step(m, d, n)
        else:
            for _ in range(n):
                for controller in self._controllers:
                    controller(d.time)
                mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qpos)):
            raise SimulationError(
                f"the simulation became unstable at t={d.time:.3f} s; try a smaller sim.timestep"
            )

    def run_until(self, t: float, timeout_s: float | None = None) -> None:
        """Make simulation time reach ``t`` (to within a step): step to it (lockstep) or wait."""
        if self.mode == "lockstep":
            with self.lock:
                n = math.ceil((t - self.data.time) / self.timestep - 1e-6)
                if n > 0:
                    self._step(n)
            return
        limit = (t - self.time) * 2.0 + 5.0 if timeout_s is None else timeout_s
        deadline = time.monotonic() + limit
        while self.time < t - 0.5 * self.timestep:
            if self._thread_error is not None:
                raise SimulationError(f"the physics thread failed: {self._thread_error}")
            if self._stop.is_set():
                raise SimulationError("the simulation is closed; build a new SimWorld")
            if time.monotonic() > deadline:
                raise SimulationError(
                    f"simulation time did not reach {t:.3f} s within {limit:.1f} s: "
                    "the physics thread is too slow for real time on this machine"
                )
            time.sleep(min(0.002, max(t - self.time, 0.0)))

    def advance(self, seconds: float) -> None:
        """Run the simulation ``seconds`` further (see :meth:`run_until`)."""
        self.run_until(self.time + seconds)

    def _realtime_loop(self) -> None:
        """Keep simulation time equal to wall-clock time since start, in steps of ~2 ms."""
        start_wall, start_sim = time.monotonic(), self.time
        try:
            while not self._stop.is_set():
                target = start_sim + (time.monotonic() - start_wall)
                behind = target - self.time
                if behind > 0.25:  # cannot keep up: drop the backlog instead of spiralling
                    log.warning("simulation %.0f ms behind real time; skipping", behind * 1e3)
                    start_sim, start_wall = self.time, time.monotonic()
                    continue
                # At most 10 steps per lock hold, so readers and renderers get a turn.
                n = min(int(behind / self.timestep), 10)
                if n > 0:
                    with self.lock:
                        self._step(n)
                else:
                    time.sleep(self.timestep)
        except BaseException as exc:  # reported by run_until, not lost in the thread
            self._thread_error = exc
            log.exception("simulation physics thread failed")

    def close(self) -> None:
        """Stop the physics thread (realtime mode); the world keeps its last state."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- scene edits

    def set_camera_pose(self, T_base_cam: ArrayLike) -> None:
        """Move the camera (and its stand) to ``T_base_cam``, OpenCV optical frame."""
        T_world_cam = T_WORLD_BASE @ np.asarray(T_base_cam, dtype=float)
        R_world_mjcam = T_world_cam[:3, :3] @ R_MJCAM_CAM
        with self.lock:
            self.data.mocap_pos[self._camera_mocap] = T_world_cam[:3, 3]
            self.data.mocap_quat[self._camera_mocap] = quat_wxyz(R_world_mjcam)
            yaw = math.atan2(T_world_cam[1, 2], T_world_cam[0, 2])
            self.data.mocap_pos[self._mount_mocap] = T_world_cam[:3, 3]
            self.data.mocap_quat[self._mount_mocap] = quat_wxyz(rot_z(yaw))
            mujoco.mj_forward(self.model, self.data)

    def set_marker(self, p_base: ArrayLike | None) -> None:
        """Show the red marker sphere (1 cm radius, no collisions) at ``p_base``; None hides it."""
        p_world = (
            np.array(MARKER_PARKED)
            if p_base is None
            else T_WORLD_BASE[:3, :3] @ np.asarray(p_base, dtype=float) + T_WORLD_BASE[:3, 3]
        )
        with self.lock:
            self.data.mocap_pos[self._marker_mocap] = p_world
            mujoco.mj_forward(self.model, self.data)

    def set_object_pose(self, name: str, T_base_obj: ArrayLike) -> None:
        """Put object ``name`` (bottom centre, z along its axis) at ``T_base_obj``, at rest.

        Sets the object's free joint and zeroes its velocity, as if a hand had placed it there;
        physics carries on from that state. Drive an object along a path by calling this every
        frame or so with small steps (large jumps into another body make contact forces fly).
        """
        if name not in self._object_bodies:
            raise SimulationError(
                f"no object {name!r}; the scene has {[o.name for o in self.scene.objects]}"
            )
        T = _rigid(T_base_obj, "T_base_obj")
        T_world_obj = T_WORLD_BASE @ T
        joint = self.model.body_jntadr[self._object_bodies[name]]
        qadr, dofadr = self.model.jnt_qposadr[joint], self.model.jnt_dofadr[joint]
        with self.lock:
            self.data.qpos[qadr : qadr + 3] = T_world_obj[:3, 3]
            self.data.qpos[qadr + 3 : qadr + 7] = quat_wxyz(T_world_obj[:3, :3])
            self.data.qvel[dofadr : dofadr + 6] = 0.0
            mujoco.mj_forward(self.model, self.data)

    def set_loose_tag_pose(self, tag_id: int, T_base_tag: ArrayLike) -> None:
        """Put loose tag ``tag_id`` at ``T_base_tag`` (AprilTag convention: z into the tag).

        Loose tags are mocap bodies: they go exactly where they are put and push nothing. To
        move one along a path, call this from a controller (:meth:`add_controller`) every step.
        """
        index = next((k for k, t in enumerate(self.scene.loose_tags) if t.tag_id == tag_id), None)
        if index is None:
            raise SimulationError(
                f"no loose tag {tag_id}; the scene has {[t.tag_id for t in self.scene.loose_tags]}"
            )
        T = _rigid(T_base_tag, "T_base_tag")
        # The body is the plate; its site (the tag frame) sits at the body origin turned by
        # R_TAG_PLATE^T, so the plate's rotation is R_base_tag R_TAG_PLATE.
        T_world_plate = T_WORLD_BASE @ make_T(T[:3, :3] @ R_TAG_PLATE, T[:3, 3])
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"loose_tag{index}")
        mocap = self.model.body_mocapid[body]
        with self.lock:
            self.data.mocap_pos[mocap] = T_world_plate[:3, 3]
            self.data.mocap_quat[mocap] = quat_wxyz(T_world_plate[:3, :3])
            mujoco.mj_forward(self.model, self.data)

    @property
    def marker_radius(self) -> float:
        return float(
            self.model.geom_size[
                self.model.body_geomadr[
                    mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "marker")
                ]
            ][0]
        )

    # ---------------------------------------------------------------- ground truth

    @property
    def T_world_base(self) -> Array:
        return T_WORLD_BASE.copy()

    def _T_base(self, pos: ArrayLike, xmat: ArrayLike) -> Array:
        T_world_x = make_T(np.asarray(xmat, dtype=float).reshape(3, 3), pos)
        return inv_T(T_WORLD_BASE) @ T_world_x

    def T_base_cam(self) -> Array:
        """True camera pose, OpenCV optical frame (x right, y down, z forward)."""
        with self.lock:
            T_base_mjcam = self._T_base(
                self.data.cam_xpos[self.camera_id], self.data.cam_xmat[self.camera_id]
            )
        T_base_mjcam[:3, :3] = T_base_mjcam[:3, :3] @ R_MJCAM_CAM
        return T_base_mjcam

    def T_base_ee(self) -> Array:
        """True pose of ee_gripper_link (the point between the fingertips)."""
        with self.lock:
            return self._T_base(
                self.data.site_xpos[self._ee_site], self.data.site_xmat[self._ee_site]
            )

    def T_base_tag(self) -> Array:
        """True pose of the gripper's AprilTag, AprilTag convention (z into the tag)."""
        with self.lock:
            return self._T_base(
                self.data.site_xpos[self._tag_site], self.data.site_xmat[self._tag_site]
            )

    def T_base_loose_tags(self) -> dict[int, Array]:
        """True poses of the loose tags on the table, by tag id."""
        with self.lock:
            return {
                tag_id: self._T_base(self.data.site_xpos[s], self.data.site_xmat[s])
                for tag_id, s in self._loose_sites.items()
            }

    @property
    def T_ee_tag(self) -> Array:
        return tag_mount(self.config.tag.offset_ee)

    def joint_positions(self) -> Array:
        """True arm joint angles, rad, in VX300S.joint_names order."""
        with self.lock:
            return self.data.qpos[self._qadr].copy()

    def joint_velocities(self) -> Array:
        with self.lock:
            return self.data.qvel[self._dofadr].copy()

    def finger_position(self) -> float:
        """True travel of the left finger, metres (0.021 closed .. 0.057 open)."""
        with self.lock:
            return float(self.data.qpos[self._finger_qadr[0]])

    def T_base_object(self, name: str) -> Array:
        """True pose of an object's bottom centre (z along its axis)."""
        body = self._object_bodies[name]
        with self.lock:
            return self._T_base(self.data.xpos[body], self.data.xmat[body])

    def held_object(self) -> str | None:
        """The object touching both finger pads, or None."""
        left, right = self._pads
        touching: dict[int, set[int]] = {left: set(), right: set()}
        with self.lock:
            d, m = self.data, self.model
            for c in d.contact[: d.ncon]:
                for pad, other in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                    if pad in touching:
                        touching[pad].add(int(m.geom_bodyid[other]))
        both = touching[left] & touching[right]
        for name, body in self._object_bodies.items():
            if body in both:
                return name
        return None

    def objects(self) -> tuple[ObjectState, ...]:
        held = self.held_object()
        return tuple(
            ObjectState(o, self.T_base_object(o.name), o.name == held) for o in self.scene.objects
        )

    def object_spec(self, name: str) -> ObjectSpec:
        for o in self.scene.objects:
            if o.name == name:
                return o
        raise SimulationError(
            f"no object {name!r}; the scene has {[o.name for o in self.scene.objects]}"
        )

    def ground_truth(self) -> GroundTruth:
        """A consistent snapshot of every true quantity, read under the lock."""
        with self.lock:
            objects = self.objects()
            return GroundTruth(
                time=self.time,
                T_base_cam=self.T_base_cam(),
                T_base_ee=self.T_base_ee(),
                T_base_tag=self.T_base_tag(),
                T_ee_tag=self.T_ee_tag,
                joint_positions=self.joint_positions(),
                finger_position=self.finger_position(),
                objects=objects,
                held_object=next((o.spec.name for o in objects if o.held), None),
                loose_tags=self.T_base_loose_tags(),
            )
