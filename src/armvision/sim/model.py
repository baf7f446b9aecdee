"""The MuJoCo model of the simulated workspace, built with MuJoCo's ``MjSpec`` API.

The ViperX-300s comes from the static MJCF file ``sim/data/vx300s.xml``; :func:`build_spec`
loads it, sets what the configuration decides (the gripper's force limit, the tag mount on
the gripper) and adds everything a :class:`~armvision.sim.scene.SceneSpec` decides around it:
the table, lights, the camera on its stand, the bottles and cups with their liquid, the loose
AprilTags and the tags' textures and meshes from :mod:`armvision.sim.assets`. Element names
are those of :mod:`armvision.sim.names`.

Frames: ``world`` has z up with the floor at z = 0; the robot's ``base`` sits on the table top
at ``TABLE_TOP_Z`` with the same orientation, so ``T_world_base`` is a pure translation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from armvision.config import Config
from armvision.errors import SimulationError
from armvision.geometry import make_T, rot_z
from armvision.robot.tag_mount import R_EE_TAG
from armvision.robot.vx300s import EE_GRIPPER_X
from armvision.sim import assets, names
from armvision.sim._mujoco import mujoco
from armvision.sim.scene import (
    BOTTLE_CAP_HEIGHT,
    BOTTLE_CAP_WIDENING,
    BOTTLE_NECK_RADIUS,
    CUP_WALL,
    HANDLE_REACH,
    LIQUID_COLOURS,
    LooseTag,
    ObjectKind,
    ObjectSpec,
    SceneSpec,
)

Array = NDArray[np.float64]

TABLE_TOP_Z = 0.75  # world height of the table top and the robot base, metres
T_WORLD_BASE = make_T(p=[0.0, 0.0, TABLE_TOP_Z])
#: D435i colour stream at 640x480: fx = fy ~ 615 px (Intel's factory intrinsics are
#: 605-617 px). The vertical field of view, the same in every 4:3 and 16:9 mode of the colour
#: stream, follows from it; MuJoCo cameras are specified by exactly this angle.
D435I_FY_AT_480 = 615.0
D435I_FOVY_DEG = math.degrees(2.0 * math.atan(240.0 / D435I_FY_AT_480))
#: MuJoCo cameras look along -z with y up; the OpenCV optical frame looks along +z with y down.
R_MJCAM_CAM = np.diag([1.0, -1.0, -1.0])
#: The textured plate mesh shows its image on +z with the image top at +y (see assets).
R_TAG_PLATE = np.diag([1.0, -1.0, -1.0])
MARKER_PARKED = (0.0, 0.0, -10.0)  # the marker sphere's home, far out of view (world frame)
NOSLIP_ITERATIONS = 3
GRIPPER_MAX_FORCE_N = 30.0  # finger force at gripper_pressure = 1; 0.5 (default) gives 15 N

#: Contacts of the objects: they touch everything (the arm has contype 2, conaffinity 1).
OBJECT_CONTACT = {"contype": 1, "conaffinity": 3, "friction": [1.0, 0.005, 0.0001], "condim": 4}
NO_CONTACT = {"contype": 0, "conaffinity": 0}
GEOM = mujoco.mjtGeom


def quat_wxyz(R: ArrayLike) -> Array:
    """MuJoCo's (w, x, y, z) quaternion of rotation matrix ``R``."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return np.array([w, x, y, z])


def _sig(value: float, digits: int = 6) -> float:
    """``value`` to ``digits`` significant digits.

    The workspace has always been built to a fixed precision: poses, directions and the
    camera's field of view at 10 significant digits, object and camera-stand dimensions and
    liquid masses at 6, bottle shell masses and the gripper force at 4, cup vertices at 9.
    Keeping it means a seed keeps building the same model, so seeded runs stay reproducible.
    Python rounds floats to significant digits only by formatting them.
    """
    return float(f"{value:.{digits}g}")


def _sigs(values: ArrayLike, digits: int = 10) -> list[float]:
    """Each of ``values`` to ``digits`` significant digits (see :func:`_sig`)."""
    return [_sig(v, digits) for v in np.ravel(values)]


def _pose(T: ArrayLike) -> dict[str, list[float]]:
    """``pos`` and ``quat`` keywords of a MuJoCo element at pose ``T`` (10 significant digits)."""
    T = np.asarray(T, dtype=float)
    return {"pos": _sigs(T[:3, 3]), "quat": _sigs(quat_wxyz(T[:3, :3]))}


def build_spec(config: Config, scene: SceneSpec) -> mujoco.MjSpec:
    """The workspace for ``scene`` as an uncompiled ``MjSpec`` (its tag images in ``assets``)."""
    spec = mujoco.MjSpec.from_string(
        resources.files("armvision.sim").joinpath("data", names.ROBOT_FILE).read_text()
    )
    _set_options(spec, config, scene)
    _add_assets(spec, config, scene)
    _configure_robot(spec, config)
    _add_room(spec, scene)
    _add_camera(spec, scene.T_base_cam)
    _add_marker(spec)
    for obj in scene.objects:
        _add_object(spec, obj)
    for index, tag in enumerate(scene.loose_tags):
        _add_loose_tag(spec, tag, index)
    return spec


def build_model(config: Config, scene: SceneSpec) -> mujoco.MjModel:
    """The compiled workspace for ``scene``; SimulationError if MuJoCo refuses it."""
    try:
        return build_spec(config, scene).compile()
    except ValueError as exc:  # MuJoCo reports compile errors as ValueError
        raise SimulationError(f"the simulated workspace does not compile: {exc}") from exc


def _set_options(spec: mujoco.MjSpec, config: Config, scene: SceneSpec) -> None:
    """Physics options, rendering settings and the headlight."""
    spec.modelname = "armvision_workspace"
    # Menagerie's vx300s uses elliptic cones and impratio 10 so grasped objects do not slip.
    spec.option.timestep = config.sim.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    # MuJoCo's noslip pass (its documentation: "eliminates slip" of the soft contacts' friction);
    # without it a held bottle crept down the pads about 1 mm/s while the arm moved and stood
    # still when it stopped. Three iterations cost about 12 us a step.
    spec.option.noslip_iterations = NOSLIP_ITERATIONS
    spec.memory = 20 * 2**20
    spec.stat.center = [0.3, 0.0, 0.9]
    spec.stat.extent = 2.0
    visual = spec.visual
    visual.global_.offwidth = max(config.camera.width, 640)
    visual.global_.offheight = max(config.camera.height, 480)
    visual.map.znear, visual.map.zfar = 0.01, 20.0
    visual.quality.shadowsize = 2048
    light = scene.lighting
    visual.headlight.ambient = [light.ambient] * 3
    visual.headlight.diffuse = [light.headlight] * 3
    visual.headlight.specular = [0.05] * 3


def _add_assets(spec: mujoco.MjSpec, config: Config, scene: SceneSpec) -> None:
    """Sky, floor and table looks, the tag textures and plates, the cups' meshes."""
    tex, rgb = mujoco.mjtTexture, mujoco.mjtTextureRole.mjTEXROLE_RGB
    spec.add_material(name="marker", emission=1.0)
    spec.add_texture(
        name="sky",
        type=tex.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.75, 0.78, 0.82],
        rgb2=[0.5, 0.52, 0.55],
        width=64,
        height=64,
    )
    spec.add_texture(
        name="floor",
        type=tex.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.42, 0.4, 0.38],
        rgb2=[0.38, 0.36, 0.34],
        width=256,
        height=256,
    )
    spec.add_material(name="floor", texrepeat=[6.0, 6.0]).textures[rgb] = "floor"
    spec.add_material(name="table", rgba=[0.72, 0.6, 0.45, 1.0], specular=0.1)
    files: dict[str, bytes] = {}

    def tag_material(name: str, tag_id: int) -> None:
        texture = names.tag_texture(tag_id)
        if f"{texture}.png" not in files:
            image = assets.tag_image(tag_id, config.tag.family)
            files[f"{texture}.png"] = assets.png_bytes(image)
            spec.add_texture(name=texture, type=tex.mjTEXTURE_2D, file=f"{texture}.png")
        if spec.material(name) is None:
            material = spec.add_material(name=name, specular=0.0, shininess=0.0)
            material.textures[rgb] = texture

    tag_material(names.tag_texture(config.tag.id), config.tag.id)
    tag_material(names.ARM_TAG_MATERIAL, config.tag.id)
    plates = [(names.ARM_TAG_MESH, config.tag.size)]
    for index, loose in enumerate(scene.loose_tags):
        tag_material(names.tag_texture(loose.tag_id), loose.tag_id)
        plates.append((names.loose_tag(index), loose.size))
    for name, black_size in plates:
        v, f, uv = assets.textured_plate_mesh(assets.tag_outer_size(black_size), 0.001)
        spec.add_mesh(name=name, uservert=v.ravel(), userface=f.ravel(), usertexcoord=uv.ravel())
    for obj in scene.objects:
        if obj.kind == "cup":
            v, f = assets.lathe_mesh(assets.cup_profile(obj.radius, obj.height, CUP_WALL), 40)
            vert = _sigs(v, 9)  # see _sig
            spec.add_mesh(name=names.cup_mesh(obj.name), uservert=vert, userface=f.ravel())
        else:
            for name, profile in _object_profiles(obj):
                v, f = assets.lathe_mesh(profile, 40)
                spec.add_mesh(name=name, uservert=_sigs(v, 9), userface=f.ravel())
    spec.assets = files


def _configure_robot(spec: mujoco.MjSpec, config: Config) -> None:
    """Put the arm on the table, mount the gripper tag, limit the gripper's force."""
    spec.body(names.BASE_BODY).pos = T_WORLD_BASE[:3, 3]
    p_gripper_tag = _sigs(np.array([EE_GRIPPER_X, 0.0, 0.0]) + np.asarray(config.tag.offset_ee))
    site = spec.site(names.ARM_TAG_SITE)
    site.pos, site.quat = p_gripper_tag, _sigs(quat_wxyz(R_EE_TAG))
    spec.body(names.GRIPPER_BODY).add_geom(
        name=names.ARM_TAG_PLATE,
        type=GEOM.mjGEOM_MESH,
        meshname=names.ARM_TAG_MESH,
        material=names.ARM_TAG_MATERIAL,
        pos=p_gripper_tag,
        quat=_sigs(quat_wxyz(R_EE_TAG @ R_TAG_PLATE)),
        density=0.0,
        rgba=[1.0, 1.0, 1.0, 1.0],
        **NO_CONTACT,
    )
    force = _sig(GRIPPER_MAX_FORCE_N * max(config.robot.gripper_pressure, 0.05), 4)
    spec.actuator(names.GRIPPER_ACTUATOR).forcerange = [-force, force]


def _add_room(spec: mujoco.MjSpec, scene: SceneSpec) -> None:
    """The key light, the floor and the table."""
    world, light = spec.worldbody, scene.lighting
    world.add_light(
        name="ceiling",
        pos=[0.4, 0.0, 3.0],
        dir=_sigs(light.key_dir),
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        diffuse=[light.key] * 3,
        castshadow=False,
    )
    world.add_geom(
        name="floor",
        type=GEOM.mjGEOM_PLANE,
        size=[4.0, 4.0, 0.1],
        material="floor",
        contype=1,
        conaffinity=3,
    )
    world.add_geom(
        name="table",
        type=GEOM.mjGEOM_BOX,
        size=[0.55, 0.65, TABLE_TOP_Z / 2],
        pos=[0.3, 0.0, TABLE_TOP_Z / 2],
        material="table",
        contype=1,
        conaffinity=3,
        friction=[0.6, 0.005, 0.0001],
    )


def _add_camera(spec: mujoco.MjSpec, T_base_cam: Array) -> None:
    """The D435i (a mocap body) and its stand (another, turned to face the camera's way)."""
    world = spec.worldbody
    T_world_cam = T_WORLD_BASE @ T_base_cam
    mount_yaw = math.atan2(T_world_cam[1, 2], T_world_cam[0, 2])  # stand faces the camera's way
    pole_half = _sig((T_world_cam[2, 3] - 0.03) / 2)
    mount = world.add_body(
        name=names.CAMERA_MOUNT_BODY,
        mocap=True,
        **_pose(make_T(rot_z(mount_yaw), T_world_cam[:3, 3])),
    )
    mount.add_geom(
        name="camera_pole",
        type=GEOM.mjGEOM_CYLINDER,
        size=[0.012, pole_half, 0.0],
        pos=[-0.03, 0.0, _sig(-0.03 - pole_half)],
        rgba=[0.2, 0.2, 0.2, 1.0],
        **NO_CONTACT,
    )
    camera = world.add_body(
        name=names.CAMERA_BODY,
        mocap=True,
        **_pose(make_T(T_world_cam[:3, :3] @ R_MJCAM_CAM, T_world_cam[:3, 3])),
    )
    camera.add_camera(name=names.CAMERA_NAME, fovy=_sig(D435I_FOVY_DEG, 10))
    # D435i housing (90 x 25 x 25 mm) just behind the optical centre, out of its view.
    camera.add_geom(
        name="camera_housing",
        type=GEOM.mjGEOM_BOX,
        size=[0.045, 0.0125, 0.0125],
        pos=[0.0, 0.0, 0.014],
        rgba=[0.15, 0.15, 0.15, 1.0],
        **NO_CONTACT,
    )


def _add_marker(spec: mujoco.MjSpec) -> None:
    """The red marker sphere (a mocap body, parked out of view until shown)."""
    marker = spec.worldbody.add_body(name=names.MARKER_BODY, mocap=True, pos=list(MARKER_PARKED))
    marker.add_geom(
        name=names.MARKER_BODY,
        type=GEOM.mjGEOM_SPHERE,
        size=[0.01, 0.0, 0.0],
        rgba=[1.0, 0.0, 0.0, 1.0],
        material="marker",
        **NO_CONTACT,
    )


def _object_profiles(obj: ObjectSpec) -> list[tuple[str, list[tuple[float, float]]]]:
    """The lathed meshes (name, outline) of the cluttered profile's objects."""
    if obj.label == "bottle" and obj.shoulder_height > 0:
        outline = assets.frustum_profile(obj.radius, obj.neck_r, obj.shoulder_height)
        return [(names.object_mesh(obj.name, names.SHOULDER), outline)]
    wall, base = obj.info.wall, obj.info.base
    if obj.kind == "mug":
        outline = assets.cup_profile(obj.radius, obj.height, wall)
        return [(names.object_mesh(obj.name, names.SHELL), outline)]
    if obj.kind in ("tumbler", "clear_cup"):
        outline = assets.tapered_cup_profile(obj.radius, obj.lower_radius, obj.height, wall, base)
        return [(names.object_mesh(obj.name, names.SHELL), outline)]
    if obj.kind == "bowl":
        outline = assets.bowl_profile(obj.radius, obj.lower_radius, obj.height, wall)
        return [(names.object_mesh(obj.name, names.SHELL), outline)]
    return []


def _add_object(spec: mujoco.MjSpec, obj: ObjectSpec) -> None:
    """A free body: bottle = transparent cylinder + neck + cap; cup = lathed mesh; the
    cluttered profile's families and distractors in :func:`_add_cluttered_object`."""
    if obj.kind not in ("bottle", "cup"):
        _add_cluttered_object(spec, obj)
        return
    T_world_obj = T_WORLD_BASE @ make_T(rot_z(obj.yaw), [obj.x, obj.y, 0.0])
    body = spec.worldbody.add_body(name=obj.name, **_pose(T_world_obj))
    body.add_freejoint(name=names.object_joint(obj.name))
    r, h = obj.radius, obj.body_height
    colour = list(obj.colour)

    def cylinder(part: names.ObjectPart, radius: float, half: float, z: float, **kw: object):
        return body.add_geom(
            name=names.object_geom(obj.name, part),
            type=GEOM.mjGEOM_CYLINDER,
            size=[_sig(radius), _sig(half), 0.0],
            pos=[0.0, 0.0, _sig(z)],
            **kw,
        )

    if obj.kind == "bottle":
        neck_r, cap_h = BOTTLE_NECK_RADIUS * r, BOTTLE_CAP_HEIGHT
        neck_h = obj.height - h - cap_h
        shell = obj.shell_mass
        cylinder(
            names.WALL, r, h / 2, h / 2, rgba=colour, mass=_sig(shell * 0.8, 4), **OBJECT_CONTACT
        )
        cylinder(
            names.NECK,
            neck_r,
            neck_h / 2,
            h + neck_h / 2,
            rgba=colour,
            mass=_sig(shell * 0.1, 4),
            **OBJECT_CONTACT,
        )
        cylinder(
            names.CAP,
            neck_r * BOTTLE_CAP_WIDENING,
            cap_h / 2,
            obj.height - cap_h / 2,
            rgba=[0.9, 0.9, 0.9, 1.0],
            mass=_sig(shell * 0.1, 4),
            **OBJECT_CONTACT,
        )
    else:
        body.add_geom(
            name=names.object_geom(obj.name, names.SHELL),
            type=GEOM.mjGEOM_MESH,
            meshname=names.cup_mesh(obj.name),
            rgba=colour,
            mass=obj.shell_mass,
            **NO_CONTACT,
        )
        # The collision shape is the cup's convex hull: nothing is put into cups.
        cylinder(
            names.WALL, r, h / 2, h / 2, rgba=[0.0] * 4, group=3, density=0.0, **OBJECT_CONTACT
        )
    if obj.liquid_height > 1e-4:
        lh = obj.liquid_height
        cylinder(
            names.LIQUID,
            obj.inner_radius - 0.0005,
            lh / 2,
            obj.inner_bottom + lh / 2,
            rgba=list(LIQUID_COLOURS[obj.liquid]),
            mass=_sig(obj.liquid_mass),
            **NO_CONTACT,
        )


def _add_loose_tag(spec: mujoco.MjSpec, tag: LooseTag, index: int) -> None:
    """A mocap plate showing the tag, lying face up on the table, and a site in the tag frame."""
    # Face up: plate +z = world up, so the tag's z (into the tag) points down.
    T_world_plate = T_WORLD_BASE @ make_T(rot_z(tag.yaw), [tag.x, tag.y, 0.001])
    name = names.loose_tag(index)
    body = spec.worldbody.add_body(name=name, mocap=True, **_pose(T_world_plate))
    body.add_geom(
        type=GEOM.mjGEOM_MESH,
        meshname=name,
        material=names.tag_texture(tag.tag_id),
        density=0.0,
        **NO_CONTACT,
    )
    site = body.add_site(name=name, quat=_sigs(quat_wxyz(R_TAG_PLATE.T)), group=4)
    site.size[0] = 0.004


@dataclass(frozen=True)
class _Parts:
    """Adds the geoms of one cluttered object to its body: sizes and positions in the object's
    frame (bottom centre, z up), names from :mod:`armvision.sim.names`."""

    body: mujoco.MjsBody
    obj: ObjectSpec

    @property
    def colour(self) -> list[float]:
        return list(self.obj.colour)

    @property
    def accent(self) -> list[float]:
        return list(self.obj.accent)

    def geom(
        self,
        part: names.ObjectPart,
        kind: int,
        size: list[float],
        pos: list[float],
        rgba: list[float],
        mass: float,
        index: int = 0,
        contact: bool = True,
        **kw: object,
    ) -> None:
        self.body.add_geom(
            name=names.object_geom(self.obj.name, part, index),
            type=kind,
            size=[_sig(v) for v in size],
            pos=[_sig(v) for v in pos],
            rgba=rgba,
            mass=_sig(mass, 4),
            **(OBJECT_CONTACT if contact else NO_CONTACT),
            **kw,
        )

    def cylinder(self, part: names.ObjectPart, radius: float, z0: float, z1: float,
                 rgba: list[float], mass: float, index: int = 0,
                 contact: bool = True) -> None:  # fmt: skip
        half = (z1 - z0) / 2
        self.geom(part, GEOM.mjGEOM_CYLINDER, [radius, half, 0.0], [0.0, 0.0, z0 + half], rgba,
                  mass, index, contact)  # fmt: skip

    def mesh(self, part: names.ObjectPart, rgba: list[float], mass: float, z: float = 0.0) -> None:
        self.geom(part, GEOM.mjGEOM_MESH, [0.0, 0.0, 0.0], [0.0, 0.0, z], rgba, mass,
                  meshname=names.object_mesh(self.obj.name, part))  # fmt: skip

    def capsule(self, part: names.ObjectPart, a: list[float], b: list[float], radius: float,
                rgba: list[float], mass: float, index: int) -> None:  # fmt: skip
        self.body.add_geom(
            name=names.object_geom(self.obj.name, part, index),
            type=GEOM.mjGEOM_CAPSULE,
            fromto=[_sig(v) for v in (*a, *b)],
            size=[_sig(radius), 0.0, 0.0],
            rgba=rgba,
            mass=_sig(mass, 4),
            **OBJECT_CONTACT,
        )

    def handle(self, z0: float, z1: float, rgba: list[float], mass: float) -> None:
        """A handle on the +x side: two arms and an upright, within ``HANDLE_REACH``."""
        r = self.obj.radius
        x_in, x_out, t = r - 0.003, r + HANDLE_REACH - 0.006, 0.005
        self.capsule(names.HANDLE, [x_in, 0, z0], [x_out, 0, z0], t, rgba, mass / 3, 0)
        self.capsule(names.HANDLE, [x_out, 0, z0], [x_out, 0, z1], t, rgba, mass / 3, 1)
        self.capsule(names.HANDLE, [x_in, 0, z1], [x_out, 0, z1], t, rgba, mass / 3, 2)


def _bottle_parts(p: _Parts) -> tuple[float, float]:
    """A bottle family's body, lathed shoulder, neck and cap; the cap's top and radius."""
    obj, shell = p.obj, p.obj.shell_mass
    body_h, sh = obj.body_height, obj.shoulder_height
    neck_top = body_h + sh + obj.neck_length
    cap_top = neck_top + obj.cap_height
    cap_r = obj.neck_r * (1.05 if obj.kind == "sports_bottle" else BOTTLE_CAP_WIDENING)
    p.cylinder(names.WALL, obj.radius, 0.0, body_h, p.colour, shell * 0.75)
    p.mesh(names.SHOULDER, p.colour, shell * 0.1, z=body_h)
    p.cylinder(names.NECK, obj.neck_r, body_h + sh, neck_top, p.colour, shell * 0.05)
    p.cylinder(names.CAP, cap_r, neck_top, cap_top, p.accent, shell * 0.05)
    return cap_top, cap_r


def _bottle(p: _Parts) -> None:
    _bottle_parts(p)


def _squeeze_bottle(p: _Parts) -> None:
    """A bottle with a nozzle on its flip cap."""
    cap_top, _ = _bottle_parts(p)
    p.cylinder(names.NOZZLE, 0.004, cap_top, p.obj.height, p.accent, p.obj.shell_mass * 0.05)


def _sports_bottle(p: _Parts) -> None:
    """A bottle with a loop across its cap."""
    cap_top, cap_r = _bottle_parts(p)
    loop_r, t = 0.6 * cap_r, 0.003
    top = p.obj.height - t
    p.capsule(names.LOOP, [-loop_r, 0, cap_top], [-loop_r, 0, top], t, p.accent, 0.002, 0)
    p.capsule(names.LOOP, [-loop_r, 0, top], [loop_r, 0, top], t, p.accent, 0.002, 1)
    p.capsule(names.LOOP, [loop_r, 0, cap_top], [loop_r, 0, top], t, p.accent, 0.002, 2)


def _jug(p: _Parts) -> None:
    """A bottle with a handle on its side."""
    _bottle_parts(p)
    h = p.obj.height
    p.handle(0.35 * h, 0.68 * h, p.colour, p.obj.shell_mass * 0.05)


def _mug(p: _Parts) -> None:
    h, shell = p.obj.height, p.obj.shell_mass
    p.mesh(names.SHELL, p.colour, shell * 0.85)
    p.handle(0.25 * h, 0.75 * h, p.colour, shell * 0.15)


def _shell(p: _Parts) -> None:
    """Tumbler, clear cup, bowl: the lathed shell alone (its convex hull collides)."""
    p.mesh(names.SHELL, p.colour, p.obj.shell_mass)


def _cans(p: _Parts) -> None:
    """A can (rim, labelled wall, lid), or two stacked for ``can_stack``."""
    r, h, shell = p.obj.radius, p.obj.height, p.obj.shell_mass
    count = 2 if p.obj.kind == "can_stack" else 1
    can_h = h / 2 if count == 2 else h
    for k in range(count):
        z = k * can_h
        m = shell / count
        p.cylinder(names.RIM, 0.97 * r, z, z + 0.004, p.accent, 0.05 * m, k)
        p.cylinder(names.WALL, r, z + 0.004, z + can_h - 0.004, p.colour, 0.9 * m, k)
        p.cylinder(names.LID, 0.97 * r, z + can_h - 0.004, z + can_h, p.accent, 0.05 * m, k)


def _canister(p: _Parts) -> None:
    r, h, shell = p.obj.radius, p.obj.height, p.obj.shell_mass
    p.cylinder(names.WALL, r, 0.0, h - 0.02, p.colour, 0.9 * shell)
    p.cylinder(names.LID, r, h - 0.02, h, p.accent, 0.1 * shell)


def _box(p: _Parts) -> None:
    """Box and block: ``width`` x ``depth`` x ``height``."""
    obj = p.obj
    half = [obj.width / 2, obj.depth / 2, obj.height / 2]
    p.geom(names.BODY, GEOM.mjGEOM_BOX, half, [0.0, 0.0, obj.height / 2], p.colour, obj.shell_mass)


def _marker(p: _Parts) -> None:
    """Lying along x: the barrel and a coloured cap at +x."""
    obj, shell = p.obj, p.obj.shell_mass
    mr, cap_len = obj.depth / 2, 0.035
    barrel = obj.width - cap_len
    along_x = _sigs(quat_wxyz(Rotation.from_euler("y", 90, degrees=True).as_matrix()))
    x0 = -obj.width / 2
    p.geom(names.BODY, GEOM.mjGEOM_CYLINDER, [mr, barrel / 2, 0.0], [x0 + barrel / 2, 0.0, mr],
           p.colour, 0.7 * shell, quat=along_x)  # fmt: skip
    p.geom(names.CAP, GEOM.mjGEOM_CYLINDER, [mr, cap_len / 2, 0.0],
           [x0 + barrel + cap_len / 2, 0.0, mr], p.accent, 0.3 * shell, quat=along_x)  # fmt: skip


def _fruit(p: _Parts) -> None:
    r, h, shell = p.obj.radius, p.obj.height, p.obj.shell_mass
    p.geom(names.BODY, GEOM.mjGEOM_SPHERE, [r, 0.0, 0.0], [0.0, 0.0, r], p.colour, shell)
    p.cylinder(names.STEM, 0.002, 2 * r - 0.004, h, p.accent, 0.0005, contact=False)


#: The geoms of each kind of the cluttered profile (the default profile's ``"bottle"`` and
#: ``"cup"`` are built by :func:`_add_object`); the same kinds as
#: :data:`armvision.sim.scene.CLUTTERED_SHAPES` but ``"cup"``.
CLUTTERED_PARTS: dict[ObjectKind, Callable[[_Parts], None]] = {
    "wine_bottle": _bottle,
    "water_bottle": _bottle,
    "soda_bottle": _bottle,
    "tinted_bottle": _bottle,
    "squeeze_bottle": _squeeze_bottle,
    "jug": _jug,
    "sports_bottle": _sports_bottle,
    "mug": _mug,
    "tumbler": _shell,
    "clear_cup": _shell,
    "can": _cans,
    "can_stack": _cans,
    "canister": _canister,
    "box": _box,
    "bowl": _shell,
    "block": _box,
    "marker": _marker,
    "fruit": _fruit,
}


def _add_cluttered_object(spec: mujoco.MjSpec, obj: ObjectSpec) -> None:
    """A free body for the cluttered profile's bottle and cup families and distractors.

    Clear and tinted parts keep their colour's alpha (< 1), opaque ones alpha 1. Every part
    that collides gets the objects' contact and friction; masses add up to the kind's shell
    mass plus the liquid.
    """
    add_parts = CLUTTERED_PARTS.get(obj.kind)
    if add_parts is None:  # pragma: no cover - scene.random_cluttered_object knows the same kinds
        raise SimulationError(f"internal: no model for object kind {obj.kind!r}")
    T_world_obj = T_WORLD_BASE @ make_T(rot_z(obj.yaw), [obj.x, obj.y, 0.0])
    body = spec.worldbody.add_body(name=obj.name, **_pose(T_world_obj))
    body.add_freejoint(name=names.object_joint(obj.name))
    parts = _Parts(body, obj)
    add_parts(parts)
    if obj.liquid_height > 1e-4:
        lh = obj.liquid_height
        parts.cylinder(
            names.LIQUID,
            obj.inner_radius - 0.0005,
            obj.inner_bottom,
            obj.inner_bottom + lh,
            list(LIQUID_COLOURS[obj.liquid]),
            obj.liquid_mass,
            contact=False,
        )
