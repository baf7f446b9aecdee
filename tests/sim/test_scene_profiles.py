"""Scene profiles: the default scenes stay as they were, the cluttered ones are close, partly
hidden, with distractors and every bottle and cup family, and rest on the table."""

from __future__ import annotations

import hashlib
import itertools
import math

import numpy as np
import pytest

from armvision.config import Config, SimConfig
from armvision.sim import names
from armvision.sim._mujoco import mujoco
from armvision.sim.scene import (
    BOTTLE_FAMILIES,
    CUP_FAMILIES,
    DISTRACTOR_KINDS,
    KINDS,
    OBJECT_BEARING_RANGE,
    OBJECT_RADIAL_RANGE,
    ObjectSpec,
    SceneSpec,
    footprint_gap,
    footprint_of,
    generate_scene,
)
from armvision.sim.world import SimWorld

CLUTTERED = Config(sim=SimConfig(profile="cluttered"))
#: Digests of generate_scene(Config(), seed) for seeds 0-5, recorded before the cluttered
#: profile existed (see _digest): the default scenes must not change.
DEFAULT_DIGESTS = {
    0: "cbdf75e96aeca00b",
    1: "c766d704f2daaf36",
    2: "64c8d6794eeb6eca",
    3: "2d6ba7655a5cf6ba",
    4: "2f407429a87aa9b3",
    5: "d3bc95752938d0dd",
}


def _numbers(o: ObjectSpec) -> tuple[float, ...]:
    return (o.radius, o.height, o.fill, o.x, o.y, o.yaw, *o.colour)


def _digest(scene: SceneSpec) -> str:
    rows: list[tuple[object, ...]] = [
        (o.name, o.kind, o.liquid, *(f"{v:.9g}" for v in _numbers(o))) for o in scene.objects
    ]
    rows.append(tuple(f"{v:.9g}" for v in scene.T_base_cam.ravel()))
    return hashlib.sha256(repr(rows).encode()).hexdigest()[:16]


def test_default_scenes_are_unchanged() -> None:
    for seed, digest in DEFAULT_DIGESTS.items():
        scene = generate_scene(Config(), seed)
        assert _digest(scene) == digest, f"seed {seed}"
        for o in scene.objects:
            assert o.kind in ("bottle", "cup") and o.label == o.kind


def test_existing_constructors_keep_their_meaning() -> None:
    bottle = ObjectSpec("b", "bottle", 0.03, 0.2, 0.5, "juice", x=0.4, y=0.0)
    cup = ObjectSpec("c", "cup", 0.034, 0.1, 0.3, "water", x=0.3, y=0.0)
    assert (bottle.label, cup.label) == ("bottle", "cup")
    assert bottle.body_height == 0.72 * 0.2 and bottle.fill_visible
    assert cup.body_height == 0.1 and cup.inner_radius == pytest.approx(0.03)
    assert bottle.shoulder_height == 0.0


def test_cluttered_scenes_are_deterministic_and_differ_from_default() -> None:
    a, b = generate_scene(CLUTTERED, 4), generate_scene(CLUTTERED, 4)
    assert a.objects == b.objects and np.array_equal(a.T_base_cam, b.T_base_cam)
    assert generate_scene(CLUTTERED, 5).objects != a.objects
    assert generate_scene(Config(), 4).objects != a.objects


def test_cluttered_scenes_over_seeds() -> None:
    seen: set[str] = set()
    for seed in range(20):
        scene = generate_scene(CLUTTERED, seed)
        objects = scene.objects
        assert 3 <= len(objects) <= 8
        others = sum(o.label == "other" for o in objects)
        assert len(objects) / 3 - 1e-9 <= others <= len(objects) / 2, seed
        for o in objects:
            seen.add(o.kind)
            assert o.label == KINDS[o.kind].label
            assert o.label in ("bottle", "cup", "other")
            if o.label == "other":
                assert o.fill == 0.0 and not o.fill_visible
            else:
                assert 0.0 < o.fill < 1.0 and o.radius < 0.038  # the open gripper fits
            if o.label == "bottle":
                assert o.shoulder_height > 0.0  # body + shoulder + neck + cap (+ top) = height
                assert o.fill_visible == (o.colour[3] < 1.0)
            rho, bearing = math.hypot(o.x, o.y), math.atan2(o.y, o.x)
            assert OBJECT_RADIAL_RANGE[0] <= rho <= OBJECT_RADIAL_RANGE[1]
            assert OBJECT_BEARING_RANGE[0] <= bearing <= OBJECT_BEARING_RANGE[1]
        gaps = [
            footprint_gap(footprint_of(p), footprint_of(q))
            for p, q in itertools.combinations(objects, 2)
        ]
        assert min(gaps) >= 0.01 - 1e-9, seed
    assert set(DISTRACTOR_KINDS) <= seen
    assert set(BOTTLE_FAMILIES) <= seen and set(CUP_FAMILIES) <= seen
    # The bottle families' proportions.
    for seed in range(20):
        for o in generate_scene(CLUTTERED, seed).objects:
            if o.kind == "wine_bottle":
                assert 0.6 <= o.shoulder <= 0.65 and o.neck_length >= 0.05
            if o.kind == "water_bottle":
                assert 0.75 <= o.shoulder <= 0.8 and o.neck_length <= 0.015


def _object_geoms(world: SimWorld) -> dict[int, str]:
    m = world.model
    bodies = {
        mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, o.name): o for o in world.scene.objects
    }
    return {
        g: bodies[int(m.geom_bodyid[g])].name for g in range(m.ngeom) if m.geom_bodyid[g] in bodies
    }


@pytest.mark.parametrize("seed", [5, 7])
def test_cluttered_world_rests_without_interpenetration(seed: int) -> None:
    world = SimWorld(CLUTTERED, seed)
    m, d = world.model, world.data
    geoms = _object_geoms(world)
    assert len({geoms[g] for g in geoms}) == len(world.scene.objects)
    for o in world.scene.objects:  # the truth API covers every object
        assert world.object_spec(o.name) is o
        T = world.T_base_object(o.name)
        assert np.allclose(T[:3, 3], [o.x, o.y, 0.0], atol=1e-6)
    for g, name in geoms.items():  # clear or tinted: alpha < 1, opaque: alpha 1
        spec = world.object_spec(name)
        gname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        walls = (names.object_geom(name, names.WALL), names.object_geom(name, names.SHELL))
        if gname in walls and m.geom_group[g] != 3:
            assert (m.geom_rgba[g, 3] < 1.0) == (spec.colour[3] < 1.0), gname
    before = {o.spec.name: o.T_base_obj for o in world.objects()}
    world.advance(0.5)
    for c in d.contact[: d.ncon]:
        if c.geom1 in geoms and c.geom2 in geoms and geoms[c.geom1] != geoms[c.geom2]:
            assert c.dist > -0.001, (geoms[c.geom1], geoms[c.geom2], c.dist)
    for o in world.objects():
        moved = np.linalg.norm(o.T_base_obj[:3, 3] - before[o.spec.name][:3, 3])
        assert moved < 0.005 and o.upright, (o.spec.kind, moved)
        assert not o.held


def _visible_pixels(renderer: mujoco.Renderer, world: SimWorld) -> dict[str, int]:
    renderer.update_scene(world.data, camera=world.camera_id)
    renderer.enable_segmentation_rendering()
    seg = renderer.render()
    renderer.disable_segmentation_rendering()
    geom_ids = seg[..., 0][seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM]
    geoms = _object_geoms(world)
    counts: dict[str, int] = {o.name: 0 for o in world.scene.objects}
    for g, n in zip(*np.unique(geom_ids, return_counts=True)):
        if int(g) in geoms:
            counts[geoms[int(g)]] += int(n)
    return counts


def test_some_cluttered_object_is_partly_hidden() -> None:
    """Seen from the camera, some object shows between 10 % and 90 % of what it shows alone."""
    world = SimWorld(CLUTTERED, 5)
    m, d = world.model, world.data
    renderer = mujoco.Renderer(m, 240, 320)
    try:
        together = _visible_pixels(renderer, world)
        qpos0 = d.qpos.copy()
        shares = {}
        for o in world.scene.objects:
            for other in world.scene.objects:  # everything else far below the floor
                if other.name != o.name:
                    adr = m.jnt_qposadr[
                        mujoco.mj_name2id(
                            m, mujoco.mjtObj.mjOBJ_JOINT, names.object_joint(other.name)
                        )
                    ]
                    d.qpos[adr : adr + 3] = [0.0, 0.0, -5.0]
            mujoco.mj_forward(m, d)
            alone = _visible_pixels(renderer, world)[o.name]
            d.qpos[:] = qpos0
            mujoco.mj_forward(m, d)
            if alone > 50:
                shares[o.kind] = together[o.name] / alone
    finally:
        renderer.close()
    assert any(0.1 <= s <= 0.9 for s in shares.values()), shares
