"""What a seed decides about the simulated workspace: camera placement, objects, loose tags and
lighting, as plain data (:class:`SceneSpec`) that :mod:`armvision.sim.model` turns into a
MuJoCo model. Positions are in the robot's base frame.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, TypedDict, cast

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


ObjectKind = Literal[
    # Today's (default profile) kinds; their label is their kind.
    "bottle",
    "cup",
    # Bottle families of the cluttered profile.
    "wine_bottle",
    "water_bottle",
    "soda_bottle",
    "tinted_bottle",
    "squeeze_bottle",
    "jug",
    "sports_bottle",
    # Cup families.
    "mug",
    "tumbler",
    "clear_cup",
    # Distractors (label "other").
    "can",
    "can_stack",
    "canister",
    "box",
    "bowl",
    "block",
    "marker",
    "fruit",
]
Label = Literal["bottle", "cup", "other"]


@dataclass(frozen=True)
class KindInfo:
    """What a kind is: its truth label, wall and bottom thickness, shell mass (kg, without
    liquid) and whether a bottle's liquid can be seen through its wall."""

    label: Label
    wall: float
    base: float
    shell_mass: float
    fill_visible: bool


KINDS: dict[str, KindInfo] = {
    # A PET bottle weighs ~20-30 g; a ceramic or plastic cup ~100 g.
    "bottle": KindInfo("bottle", BOTTLE_WALL, BOTTLE_BASE, 0.03, True),
    "cup": KindInfo("cup", CUP_WALL, CUP_WALL, 0.1, False),
    "wine_bottle": KindInfo("bottle", 0.003, 0.006, 0.45, True),
    "water_bottle": KindInfo("bottle", BOTTLE_WALL, BOTTLE_BASE, 0.02, True),
    "soda_bottle": KindInfo("bottle", BOTTLE_WALL, BOTTLE_BASE, 0.04, True),
    "tinted_bottle": KindInfo("bottle", 0.003, 0.006, 0.25, True),
    "squeeze_bottle": KindInfo("bottle", 0.002, 0.003, 0.04, False),
    "jug": KindInfo("bottle", 0.002, 0.003, 0.08, False),
    "sports_bottle": KindInfo("bottle", 0.002, 0.003, 0.08, False),
    "mug": KindInfo("cup", CUP_WALL, 0.006, 0.3, False),
    "tumbler": KindInfo("cup", 0.003, 0.008, 0.2, True),
    "clear_cup": KindInfo("cup", 0.001, 0.001, 0.015, True),
    "can": KindInfo("other", 0.0, 0.0, 0.35, False),
    "can_stack": KindInfo("other", 0.0, 0.0, 0.7, False),
    "canister": KindInfo("other", 0.0, 0.0, 0.4, False),
    "box": KindInfo("other", 0.0, 0.0, 0.2, False),
    "bowl": KindInfo("other", 0.004, 0.005, 0.25, False),
    "block": KindInfo("other", 0.0, 0.0, 0.03, False),
    "marker": KindInfo("other", 0.0, 0.0, 0.015, False),
    "fruit": KindInfo("other", 0.0, 0.0, 0.15, False),
}
BOTTLE_FAMILIES = tuple(k for k, v in KINDS.items() if v.label == "bottle" and k != "bottle")
CUP_FAMILIES = tuple(k for k, v in KINDS.items() if v.label == "cup")
DISTRACTOR_KINDS = tuple(k for k, v in KINDS.items() if v.label == "other")
#: Kinds with a handle sticking out of the body (mugs, jugs): how far beyond ``radius``.
HANDLE_REACH = 0.02
#: What stands on a bottle's cap: a squeeze bottle's nozzle, a sports bottle's loop (m).
TOP_EXTRA = {"squeeze_bottle": 0.012, "sports_bottle": 0.012}
FRUIT_STEM = 0.008  # m above the sphere


@dataclass(frozen=True)
class ObjectSpec:
    """An object standing (or lying) on the table; its frame is at the bottom centre, z up.

    ``kind`` is the family (``"bottle"``, ``"wine_bottle"``, ``"mug"``, ``"can"``, ...; see
    :data:`KINDS`) and :attr:`label` the truth class a detector should report (``"bottle"``,
    ``"cup"`` or ``"other"``); for today's kinds ``"bottle"`` and ``"cup"`` the label is the kind.
    ``fill`` is the liquid column as a fraction of the inner height of the bottle's body (the
    cylinder below the shoulder) or of the cup; distractors have ``fill = 0``. ``x, y, yaw``
    place it in the base frame.

    Shape parameters (the defaults give today's bottles and cups):

    - ``radius``: of the body; for boxes, blocks and markers the radius of the circle around
      their footprint. ``height``: overall, cap, nozzle or loop included.
    - bottles: ``shoulder`` is the top of the cylindrical body as a fraction of ``height``;
      ``neck_length`` the neck's length (0: the neck fills everything between the shoulder
      and the cap, no tapered shoulder, as today's bottles); ``neck_radius`` (0: 0.42 of the
      radius); ``cap_height``.
    - cups, tumblers and bowls: ``bottom_radius`` (0: the same as ``radius``, straight walls).
    - boxes and blocks: ``width`` x ``depth`` (along the object's x and y); markers: ``width``
      is their length (lying along x), ``radius`` theirs.
    """

    name: str
    kind: ObjectKind
    radius: float
    height: float
    fill: float
    liquid: str
    x: float
    y: float
    yaw: float = 0.0
    colour: tuple[float, float, float, float] = (0.85, 0.92, 1.0, 0.25)
    shoulder: float = 0.72
    neck_length: float = 0.0
    neck_radius: float = 0.0
    cap_height: float = BOTTLE_CAP_HEIGHT
    bottom_radius: float = 0.0
    width: float = 0.0
    depth: float = 0.0
    accent: tuple[float, float, float, float] = (0.9, 0.9, 0.9, 1.0)  # cap, lid, handle

    @property
    def info(self) -> KindInfo:
        return KINDS[self.kind]

    @property
    def label(self) -> Label:
        """The truth class: ``"bottle"``, ``"cup"`` or ``"other"`` (a distractor)."""
        return self.info.label

    @property
    def fill_visible(self) -> bool:
        """Whether the liquid can be seen through the wall (False for opaque bottles, cups
        with opaque walls and distractors)."""
        return self.info.fill_visible

    @property
    def body_height(self) -> float:
        """Height of the part that holds liquid: a bottle's cylinder, a whole cup."""
        return self.shoulder * self.height if self.label == "bottle" else self.height

    @property
    def shoulder_height(self) -> float:
        """A bottle's tapered shoulder, between the body and the neck (0 for today's bottles,
        whose neck begins at the body's top)."""
        if self.label != "bottle" or self.neck_length <= 0:
            return 0.0
        top = self.cap_height + TOP_EXTRA.get(self.kind, 0.0)
        return self.height - self.body_height - self.neck_length - top

    @property
    def neck_r(self) -> float:
        """The bottle neck's radius."""
        return self.neck_radius if self.neck_radius > 0 else BOTTLE_NECK_RADIUS * self.radius

    @property
    def lower_radius(self) -> float:
        """Radius at the bottom (cups, tumblers, bowls taper towards it)."""
        return self.bottom_radius if self.bottom_radius > 0 else self.radius

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle around what the object covers on the table, handles included."""
        if self.kind in ("box", "block", "marker"):
            return self.radius
        return self.radius + (HANDLE_REACH if self.kind in ("mug", "jug") else 0.0)

    @property
    def inner_radius(self) -> float:
        return min(self.radius, self.lower_radius) - self.info.wall

    @property
    def inner_bottom(self) -> float:
        return self.info.base

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
        return self.info.shell_mass


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


# --------------------------------------------------------------------------- cluttered

#: Cluttered scenes: how many objects, the narrowest and widest free gap to a neighbour, and
#: how often an object is put deliberately behind another one (seen from the camera) or
#: beside one.
CLUTTERED_OBJECTS = (3, 8)
CLUTTERED_MIN_GAP = 0.01
CLUTTERED_MAX_GAP = 0.05
CLUTTERED_BEHIND_SHARE = 0.4
CLUTTERED_BESIDE_SHARE = 0.4
#: Salt of the cluttered profile's random stream (``default_rng([seed, salt])``).
CLUTTERED_SALT = 0xC1077E4
CLEAR = (0.85, 0.92, 1.0, 0.25)
TINTED_GLASS = (
    (0.45, 0.25, 0.08, 0.55),  # amber
    (0.15, 0.45, 0.2, 0.5),  # green
    (0.2, 0.3, 0.6, 0.5),  # cobalt blue
)
OPAQUE_PLASTIC = (
    (0.85, 0.15, 0.1, 1.0),
    (0.95, 0.8, 0.15, 1.0),
    (0.95, 0.95, 0.93, 1.0),
    (0.15, 0.35, 0.75, 1.0),
    (0.2, 0.6, 0.35, 1.0),
)
#: Printed can labels: saturated with a metallic sheen (light, slightly desaturated).
CAN_LABELS = (
    (0.78, 0.12, 0.12, 1.0),
    (0.15, 0.5, 0.25, 1.0),
    (0.2, 0.3, 0.7, 1.0),
    (0.85, 0.7, 0.2, 1.0),
    (0.7, 0.72, 0.75, 1.0),
)
METAL = (0.78, 0.79, 0.8, 1.0)
MATTE = (
    (0.55, 0.35, 0.2, 1.0),
    (0.9, 0.85, 0.7, 1.0),
    (0.3, 0.3, 0.35, 1.0),
    (0.6, 0.15, 0.45, 1.0),
    (0.95, 0.5, 0.1, 1.0),
)
FRUIT = ((0.95, 0.5, 0.05, 1.0), (0.8, 0.1, 0.1, 1.0), (0.55, 0.75, 0.15, 1.0))


Rgba = tuple[float, float, float, float]


def _pick(rng: np.random.Generator, options: tuple[Rgba, ...]) -> Rgba:
    return options[int(rng.integers(len(options)))]


def object_kind(name: str) -> ObjectKind:
    """``name`` as an object kind; SimulationError naming the kinds if it is none."""
    if name not in KINDS:
        raise SimulationError(f"no object kind {name!r}; the kinds are {', '.join(KINDS)}")
    return cast(ObjectKind, name)


class _ShapeSize(TypedDict):
    radius: float
    height: float


class Shape(_ShapeSize, total=False):
    """The shape and colour fields of an :class:`ObjectSpec` a kind's builder draws (the
    others keep their defaults)."""

    colour: Rgba
    shoulder: float
    neck_length: float
    neck_radius: float
    cap_height: float
    bottom_radius: float
    width: float
    depth: float
    accent: Rgba


#: Draws one kind's :class:`Shape` from the random stream.
ShapeBuilder = Callable[[np.random.Generator], Shape]


def _wine_bottle(rng: np.random.Generator) -> Shape:
    """Tall neck, shoulder at 60-65 %."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.033, 0.037)),
        height=float(u(0.28, 0.31)),
        shoulder=float(u(0.60, 0.65)),
        neck_length=float(u(0.05, 0.06)),
        neck_radius=0.0135,
        cap_height=0.025,
        colour=CLEAR if u() < 0.5 else _pick(rng, TINTED_GLASS),
        accent=(0.45, 0.05, 0.1, 1.0),
    )


def _water_bottle(rng: np.random.Generator) -> Shape:
    """Short neck, shoulder at 75-80 %."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.03, 0.036)),
        height=float(u(0.19, 0.24)),
        shoulder=float(u(0.75, 0.80)),
        neck_length=float(u(0.008, 0.014)),
        neck_radius=0.013,
        cap_height=0.016,
        colour=CLEAR,
        accent=(0.2, 0.4, 0.9, 1.0),
    )


def _soda_bottle(rng: np.random.Generator) -> Shape:
    u = rng.uniform
    return Shape(
        radius=float(u(0.03, 0.036)),
        height=float(u(0.2, 0.25)),
        shoulder=float(u(0.62, 0.70)),
        neck_length=float(u(0.018, 0.028)),
        neck_radius=0.0125,
        cap_height=0.016,
        colour=(0.8, 0.95, 0.85, 0.3),
        accent=(0.85, 0.1, 0.1, 1.0),
    )


def _tinted_bottle(rng: np.random.Generator) -> Shape:
    """Coloured glass, beer-like."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.029, 0.033)),
        height=float(u(0.22, 0.25)),
        shoulder=float(u(0.58, 0.66)),
        neck_length=float(u(0.04, 0.055)),
        neck_radius=0.012,
        cap_height=0.008,
        colour=_pick(rng, TINTED_GLASS),
        accent=METAL,
    )


def _squeeze_bottle(rng: np.random.Generator) -> Shape:
    """Opaque, a flip cap with a nozzle on top."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.028, 0.035)),
        height=float(u(0.18, 0.22)),
        shoulder=float(u(0.68, 0.74)),
        neck_length=0.008,
        neck_radius=0.016,
        cap_height=0.018,
        colour=_pick(rng, OPAQUE_PLASTIC),
        accent=(0.95, 0.95, 0.95, 1.0),
    )


def _jug(rng: np.random.Generator) -> Shape:
    """Opaque, a handle on the side."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.033, 0.037)),
        height=float(u(0.2, 0.24)),
        shoulder=float(u(0.70, 0.75)),
        neck_length=0.012,
        neck_radius=0.014,
        cap_height=0.018,
        colour=(0.93, 0.93, 0.9, 1.0),
        accent=_pick(rng, OPAQUE_PLASTIC),
    )


def _sports_bottle(rng: np.random.Generator) -> Shape:
    """Opaque, a wide cap with a carrying loop."""
    u = rng.uniform
    r = float(u(0.032, 0.037))
    return Shape(
        radius=r,
        height=float(u(0.21, 0.25)),
        shoulder=float(u(0.75, 0.79)),
        neck_length=0.006,
        neck_radius=0.7 * r,
        cap_height=0.02,
        colour=_pick(rng, OPAQUE_PLASTIC),
        accent=(0.15, 0.15, 0.15, 1.0),
    )


def _cup(rng: np.random.Generator) -> Shape:
    """Plain cup, as in the default profile."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.03, 0.037)), height=float(u(0.08, 0.11)), colour=_pick(rng, CUP_COLOURS)
    )


def _mug(rng: np.random.Generator) -> Shape:
    u = rng.uniform
    return Shape(
        radius=float(u(0.03, 0.036)),
        height=float(u(0.085, 0.1)),
        colour=_pick(rng, CUP_COLOURS + MATTE),
    )


def _tumbler(rng: np.random.Generator) -> Shape:
    """Thick glass, slightly wider at the top."""
    u = rng.uniform
    r = float(u(0.032, 0.037))
    return Shape(radius=r, height=float(u(0.09, 0.12)), bottom_radius=0.85 * r, colour=CLEAR)


def _clear_cup(rng: np.random.Generator) -> Shape:
    """Thin clear plastic, tapered."""
    u = rng.uniform
    r = float(u(0.034, 0.037))
    return Shape(
        radius=r, height=float(u(0.09, 0.11)), bottom_radius=0.7 * r, colour=(0.9, 0.95, 1.0, 0.2)
    )


def _can(rng: np.random.Generator) -> Shape:
    """Food can: closed flat top, printed label."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.033, 0.042)),
        height=float(u(0.09, 0.125)),
        colour=_pick(rng, CAN_LABELS),
        accent=METAL,
    )


def _can_stack(rng: np.random.Generator) -> Shape:
    """Two equal cans, one on the other."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.033, 0.04)),
        height=2 * float(u(0.08, 0.11)),
        colour=_pick(rng, CAN_LABELS),
        accent=METAL,
    )


def _canister(rng: np.random.Generator) -> Shape:
    """Tall canister of wipes, a lid on top."""
    u = rng.uniform
    return Shape(
        radius=float(u(0.04, 0.048)),
        height=float(u(0.17, 0.2)),
        colour=_pick(rng, OPAQUE_PLASTIC),
        accent=_pick(rng, OPAQUE_PLASTIC),
    )


def _box(rng: np.random.Generator) -> Shape:
    u = rng.uniform
    w, d = float(u(0.05, 0.1)), float(u(0.04, 0.07))
    return Shape(
        radius=0.5 * math.hypot(w, d),
        height=float(u(0.05, 0.15)),
        width=w,
        depth=d,
        colour=_pick(rng, MATTE + OPAQUE_PLASTIC),
    )


def _bowl(rng: np.random.Generator) -> Shape:
    u = rng.uniform
    r = float(u(0.055, 0.075))
    return Shape(
        radius=r,
        height=float(u(0.045, 0.065)),
        bottom_radius=0.5 * r,
        colour=_pick(rng, CUP_COLOURS + MATTE),
    )


def _block(rng: np.random.Generator) -> Shape:
    """Toy cube."""
    a = float(rng.uniform(0.03, 0.05))
    return Shape(
        radius=a / math.sqrt(2.0), height=a, width=a, depth=a, colour=_pick(rng, OPAQUE_PLASTIC)
    )


def _marker(rng: np.random.Generator) -> Shape:
    """Lying on its side along x."""
    u = rng.uniform
    r, length = float(u(0.0065, 0.009)), float(u(0.12, 0.14))
    return Shape(
        radius=0.5 * math.hypot(length, 2 * r),
        height=2 * r,
        width=length,
        depth=2 * r,
        colour=(0.95, 0.95, 0.95, 1.0),
        accent=_pick(rng, OPAQUE_PLASTIC),
    )


def _fruit(rng: np.random.Generator) -> Shape:
    """A sphere, a short stem on top."""
    r = float(rng.uniform(0.03, 0.042))
    return Shape(
        radius=r, height=2 * r + FRUIT_STEM, colour=_pick(rng, FRUIT), accent=(0.3, 0.2, 0.1, 1.0)
    )


#: The kinds :func:`random_cluttered_object` draws, each with its shape's builder (the plain
#: ``"bottle"`` is the default profile's alone, :func:`random_object`).
CLUTTERED_SHAPES: dict[ObjectKind, ShapeBuilder] = {
    "wine_bottle": _wine_bottle,
    "water_bottle": _water_bottle,
    "soda_bottle": _soda_bottle,
    "tinted_bottle": _tinted_bottle,
    "squeeze_bottle": _squeeze_bottle,
    "jug": _jug,
    "sports_bottle": _sports_bottle,
    "cup": _cup,
    "mug": _mug,
    "tumbler": _tumbler,
    "clear_cup": _clear_cup,
    "can": _can,
    "can_stack": _can_stack,
    "canister": _canister,
    "box": _box,
    "bowl": _bowl,
    "block": _block,
    "marker": _marker,
    "fruit": _fruit,
}


def random_cluttered_object(rng: np.random.Generator, name: str, kind: str) -> ObjectSpec:
    """An object of ``kind`` (a bottle or cup family or a distractor) with random size and,
    for containers, fill and liquid; not yet placed. Bottles and cups stay below 0.038 m
    in radius so the open gripper fits around them."""
    known = object_kind(kind)
    builder = CLUTTERED_SHAPES.get(known)
    if builder is None:
        raise SimulationError(f"no object kind {kind!r}; kinds: {sorted(KINDS)}")
    shape = builder(rng)
    if KINDS[known].label == "other":  # a distractor: empty
        return ObjectSpec(name, known, fill=0.0, liquid="water", x=0.0, y=0.0, **shape)
    liquid = str(rng.choice(list(LIQUID_COLOURS)))
    return ObjectSpec(
        name, known, fill=float(rng.uniform(0.1, 0.9)), liquid=liquid, x=0.0, y=0.0, **shape
    )


@dataclass(frozen=True)
class Footprint:
    """What an object covers on the table: a disc of ``a`` or a rectangle of half sides
    ``a`` x ``b`` turned by ``yaw``, centred at ``x, y`` (base frame)."""

    x: float
    y: float
    a: float
    b: float = 0.0
    yaw: float = 0.0
    rect: bool = False

    def corners(self) -> list[tuple[float, float]]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return [
            (self.x + c * u - s * v, self.y + s * u + c * v)
            for u, v in ((self.a, self.b), (-self.a, self.b), (-self.a, -self.b), (self.a, -self.b))
        ]

    def distance_to_point(self, px: float, py: float) -> float:
        """Distance from the point to the footprint's edge, negative inside (rect: <= 0)."""
        dx, dy = px - self.x, py - self.y
        if not self.rect:
            return math.hypot(dx, dy) - self.a
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        u, v = abs(c * dx + s * dy) - self.a, abs(-s * dx + c * dy) - self.b
        return math.hypot(max(u, 0.0), max(v, 0.0)) + min(max(u, v), 0.0)


def footprint_of(obj: ObjectSpec) -> Footprint:
    if obj.kind in ("box", "block", "marker"):
        return Footprint(obj.x, obj.y, obj.width / 2, obj.depth / 2, obj.yaw, rect=True)
    return Footprint(obj.x, obj.y, obj.footprint_radius)


def footprint_gap(p: Footprint, q: Footprint) -> float:
    """Free gap between two footprints on the table (negative when they overlap)."""
    if not p.rect:
        return q.distance_to_point(p.x, p.y) - p.a
    if not q.rect:
        return p.distance_to_point(q.x, q.y) - q.a
    # Two rectangles: apart along a separating axis, or overlapping.
    for yaw in (p.yaw, p.yaw + math.pi / 2, q.yaw, q.yaw + math.pi / 2):
        axis = (math.cos(yaw), math.sin(yaw))
        proj_p = [axis[0] * x + axis[1] * y for x, y in p.corners()]
        proj_q = [axis[0] * x + axis[1] * y for x, y in q.corners()]
        if max(proj_p) < min(proj_q) or max(proj_q) < min(proj_p):
            break
    else:
        return -1.0
    # Disjoint convex polygons: the nearest pair includes a corner of one of them.
    return min(
        min(q.distance_to_point(x, y) for x, y in p.corners()),
        min(p.distance_to_point(x, y) for x, y in q.corners()),
    )


def _in_band(x: float, y: float, bearing_range: tuple[float, float] = OBJECT_BEARING_RANGE) -> bool:
    rho, bearing = math.hypot(x, y), math.atan2(y, x)
    return (
        OBJECT_RADIAL_RANGE[0] <= rho <= OBJECT_RADIAL_RANGE[1]
        and bearing_range[0] <= bearing <= bearing_range[1]
    )


def place_cluttered(
    rng: np.random.Generator,
    drafts: list[ObjectSpec],
    cam_xy: tuple[float, float],
    extra_radii: tuple[float, ...] = (),
    max_tries: int = 3000,
    bearing_range: tuple[float, float] = OBJECT_BEARING_RANGE,
) -> tuple[list[ObjectSpec], list[tuple[float, float]]]:
    """Place ``drafts`` close together in the default's band, at least ``CLUTTERED_MIN_GAP``
    apart; after the first, about ``CLUTTERED_BEHIND_SHARE`` of them deliberately behind an
    already placed one as the camera (at ``cam_xy``) sees it, shifted sideways so that they
    are partly hidden, and ``CLUTTERED_BESIDE_SHARE`` beside one, 1-5 cm from it; the rest
    anywhere in the band (the fallback of the others too). Then discs of ``extra_radii``
    (loose tags) anywhere free. ``bearing_range`` narrows the band (the sort profile keeps
    the sides free for its zones)."""
    placed: list[Footprint] = []
    objects: list[ObjectSpec] = []

    def free(fp: Footprint) -> bool:
        return _in_band(fp.x, fp.y, bearing_range) and all(
            footprint_gap(fp, other) >= CLUTTERED_MIN_GAP for other in placed
        )

    r_lo, r_hi = OBJECT_RADIAL_RANGE
    for draft in drafts:
        yaw = float(rng.uniform(-math.pi, math.pi))
        mode = rng.uniform() if objects else 1.0
        behind = mode < CLUTTERED_BEHIND_SHARE
        beside = not behind and mode < CLUTTERED_BEHIND_SHARE + CLUTTERED_BESIDE_SHARE
        for attempt in range(max_tries):
            if beside and attempt < 50:
                near = objects[int(rng.integers(len(objects)))]
                gap = float(rng.uniform(CLUTTERED_MIN_GAP, CLUTTERED_MAX_GAP))
                # Beside a placed object: a bearing around it, the gap between the circles.
                around = float(rng.uniform(-math.pi, math.pi))
                reach = near.footprint_radius + draft.footprint_radius + gap
                x, y = near.x + reach * math.cos(around), near.y + reach * math.sin(around)
            elif behind and attempt < 50:
                front = objects[int(rng.integers(len(objects)))]
                ux, uy = front.x - cam_xy[0], front.y - cam_xy[1]
                norm = math.hypot(ux, uy)
                ux, uy = ux / norm, uy / norm
                reach = front.footprint_radius + draft.footprint_radius
                along = reach + float(rng.uniform(CLUTTERED_MIN_GAP, 0.03))
                side = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.7)) * reach
                x, y = front.x + along * ux - side * uy, front.y + along * uy + side * ux
            else:
                rho = math.sqrt(rng.uniform(r_lo**2, r_hi**2))
                bearing = rng.uniform(*bearing_range)
                x, y = rho * math.cos(bearing), rho * math.sin(bearing)
            candidate = dataclasses.replace(draft, x=float(x), y=float(y), yaw=yaw)
            fp = footprint_of(candidate)
            if free(fp):
                placed.append(fp)
                objects.append(candidate)
                break
        else:
            raise SimulationError(f"could not place {len(drafts)} cluttered objects")
    extra: list[tuple[float, float]] = []
    for radius in extra_radii:
        for _ in range(max_tries):
            rho = math.sqrt(rng.uniform(r_lo**2, r_hi**2))
            bearing = rng.uniform(*bearing_range)
            fp = Footprint(rho * math.cos(bearing), rho * math.sin(bearing), radius)
            if free(fp):
                placed.append(fp)
                extra.append((fp.x, fp.y))
                break
        else:
            raise SimulationError("could not place the loose tags among the cluttered objects")
    return objects, extra


def cluttered_kinds(rng: np.random.Generator, n: int) -> list[str]:
    """``n`` kinds: a third to a half distractors, the rest bottle and cup families (about
    two bottles to a cup), in a random order."""
    n_other = int(rng.integers(math.ceil(n / 3), n // 2 + 1))
    kinds = [str(k) for k in rng.choice(DISTRACTOR_KINDS, n_other)]
    for _ in range(n - n_other):
        family = BOTTLE_FAMILIES if rng.uniform() < 0.6 else CUP_FAMILIES
        kinds.append(str(family[int(rng.integers(len(family)))]))
    return [kinds[i] for i in rng.permutation(n)]


def generate_cluttered_scene(config: Config, seed: int) -> SceneSpec:
    """The cluttered profile's scene for ``seed``: 3-8 objects 1-5 cm apart, some partly
    hidden behind others, a third to a half of them distractors, random lighting."""
    sim = config.sim
    rng = np.random.default_rng([seed, CLUTTERED_SALT])
    T_base_cam = random_camera_pose(sim, rng)
    n = int(rng.integers(CLUTTERED_OBJECTS[0], CLUTTERED_OBJECTS[1] + 1))
    drafts = [
        random_cluttered_object(rng, f"object{i}", kind)
        for i, kind in enumerate(cluttered_kinds(rng, n))
    ]
    return _placed_scene(config, seed, rng, T_base_cam, drafts)


def _placed_scene(
    config: Config,
    seed: int,
    rng: np.random.Generator,
    T_base_cam: np.ndarray,
    drafts: list[ObjectSpec],
    bearing_range: tuple[float, float] = OBJECT_BEARING_RANGE,
) -> SceneSpec:
    """A hard bench's scene from its drafted objects: placed close together
    (:func:`place_cluttered`) with room for the loose tags, which get free ids and random
    turns, and the room's random lighting."""
    tag_half = assets.tag_outer_size(config.tag.size) / math.sqrt(2.0)
    cam_xy = (float(T_base_cam[0, 3]), float(T_base_cam[1, 3]))
    objects, tag_xy = place_cluttered(
        rng, drafts, cam_xy, (tag_half,) * config.sim.loose_tags, bearing_range=bearing_range
    )
    free_ids = [i for i in range(100) if i != config.tag.id]
    loose = tuple(
        LooseTag(free_ids[k], x, y, float(rng.uniform(-math.pi, math.pi)), config.tag.size)
        for k, (x, y) in enumerate(tag_xy)
    )
    # A hard bench is lit as a real room is: from the randomised set, whatever
    # sim.randomize_lighting says (that switch keeps the default profile's fixed light).
    lighting = random_lighting(np.random.default_rng([seed, 0x11647]))
    return SceneSpec(T_base_cam, tuple(objects), loose, lighting)


#: Sort scenes: how many bottles and distractors, the band's bearings (the sides are the
#: zones'), the bottle kinds (those whose liquid shows) and how far every true fill stays
#: from ``sort.fill_threshold`` (a fill on the threshold belongs to neither zone for sure).
SORT_BOTTLES = (2, 4)
SORT_DISTRACTORS = (0, 2)
SORT_BEARING_RANGE = (-math.radians(26.0), math.radians(26.0))
SORT_BOTTLE_KINDS = ("bottle", "water_bottle", "soda_bottle", "wine_bottle")
SORT_FILL_MARGIN = 0.08
SORT_FILL_RANGE = (0.08, 0.9)
#: Salt of the sort profile's random stream.
SORT_SALT = 0x5027


def sort_fills(rng: np.random.Generator, n: int, threshold: float) -> list[float]:
    """``n`` true fills in :data:`SORT_FILL_RANGE`, each at least :data:`SORT_FILL_MARGIN`
    from ``threshold``, the first below it and the second above (both zones are used), the
    rest on either side by chance."""
    lo, hi = SORT_FILL_RANGE
    below = (lo, max(lo, threshold - SORT_FILL_MARGIN))
    above = (min(hi, threshold + SORT_FILL_MARGIN), hi)
    sides = [below, above] + [below if rng.uniform() < 0.5 else above for _ in range(n - 2)]
    return [float(rng.uniform(*side)) for side in sides[:n]]


def generate_sort_scene(config: Config, seed: int) -> SceneSpec:
    """The sort profile's scene for ``seed``: 2-4 bottles whose liquid shows (the plain one
    and the water, soda and wine families) with fills either side of
    ``sort.fill_threshold`` (:func:`sort_fills`), and 0-2 distractors, 1-5 cm apart as in the
    cluttered profile, in the middle of the band (:data:`SORT_BEARING_RANGE`) so the default
    ``place.zones`` either side stay free; random lighting."""
    sim = config.sim
    rng = np.random.default_rng([seed, SORT_SALT])
    T_base_cam = random_camera_pose(sim, rng)
    n_bottles = int(rng.integers(SORT_BOTTLES[0], SORT_BOTTLES[1] + 1))
    n_other = int(rng.integers(SORT_DISTRACTORS[0], SORT_DISTRACTORS[1] + 1))
    fills = sort_fills(rng, n_bottles, config.sort.fill_threshold)
    drafts: list[ObjectSpec] = []
    for i, fill in enumerate(fills):
        kind = SORT_BOTTLE_KINDS[int(rng.integers(len(SORT_BOTTLE_KINDS)))]
        if kind == "bottle":
            draft = random_object(rng, f"object{i}")
            while draft.kind != "bottle":
                draft = random_object(rng, f"object{i}")
        else:
            draft = random_cluttered_object(rng, f"object{i}", kind)
        drafts.append(dataclasses.replace(draft, fill=fill))
    for j in range(n_other):
        kind = str(DISTRACTOR_KINDS[int(rng.integers(len(DISTRACTOR_KINDS)))])
        drafts.append(random_cluttered_object(rng, f"object{n_bottles + j}", kind))
    drafts = [drafts[i] for i in rng.permutation(len(drafts))]
    return _placed_scene(config, seed, rng, T_base_cam, drafts, SORT_BEARING_RANGE)


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
    """The scene for ``seed`` in the configured profile (``sim.profile``). Default: camera
    pose, 1-4 objects and any loose tags, without overlap; cluttered: see
    :func:`generate_cluttered_scene`."""
    sim = config.sim
    if sim.profile == "cluttered":
        return generate_cluttered_scene(config, seed)
    if sim.profile == "sort":
        return generate_sort_scene(config, seed)
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
