"""Lighting variation: off by default (scenes as before), random per seed when switched on."""

from __future__ import annotations

import numpy as np
from tests.sim.helpers import config_with

from armvision.sim._mujoco import mujoco
from armvision.sim.model import build_model
from armvision.sim.scene import Lighting, generate_scene, random_lighting


def test_default_scenes_keep_the_fixed_lighting() -> None:
    config = config_with()
    scene = generate_scene(config, 3)
    assert scene.lighting == Lighting()
    model = build_model(config, scene)
    np.testing.assert_allclose(model.vis.headlight.ambient, [0.35] * 3, rtol=1e-6)
    np.testing.assert_allclose(model.vis.headlight.diffuse, [0.45] * 3, rtol=1e-6)
    np.testing.assert_array_equal(model.light_dir[0], [0.0, 0.0, -1.0])


def test_random_lighting_varies_and_leaves_the_rest_of_the_scene() -> None:
    plain = generate_scene(config_with(randomize_camera=True), 5)
    lit = [
        generate_scene(config_with(randomize_camera=True, randomize_lighting=True), s)
        for s in (5, 6)
    ]
    assert lit[0].lighting != lit[1].lighting
    assert lit[0].lighting != Lighting()
    np.testing.assert_array_equal(lit[0].T_base_cam, plain.T_base_cam)
    assert lit[0].objects == plain.objects


def test_random_lighting_is_in_range_and_compiles() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        light = random_lighting(rng)
        assert 0.15 <= light.ambient <= 0.5 and 0.2 <= light.key <= 0.8
        assert np.isclose(np.linalg.norm(light.key_dir), 1.0) and light.key_dir[2] < 0
    config = config_with(randomize_lighting=True)
    model = build_model(config, generate_scene(config, 1))
    assert model.nlight == 1
    assert model.light_type[0] == mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
