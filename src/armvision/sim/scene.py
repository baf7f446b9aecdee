"""What a seed decides about the simulated workspace: camera placement, objects, loose tags and
lighting, as plain data (:class:`SceneSpec`) that :mod:`armvision.sim.model` turns into a
MuJoCo model. Positions are in the robot's base frame.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from armvision.camera.placement import camera_pose_from_placement
from armvision.config import Config, SimConfig
from armvision.errors import SimulationError
from armvision.sim import assets

Array = NDArray[np.float64]

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
#: Bottle proportions: the neck is this fraction of the radius, the cap this much wider than
#: the neck and ``BOTTLE_CAP_HEIGHT`` tall; the neck fills the rest above the body.
BOTTLE_NECK_RADIUS = 0.42
BOTTLE_CAP_WIDENING = 1.12
BOTTLE_CAP_HEIGHT = 0.018  # m


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
