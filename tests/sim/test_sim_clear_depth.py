"""SimCamera's real-camera habits: clear plastic, speckle, flying pixels, colour gains.

The real D435 side runs only where ClearGrasp's frames are (in ``$ARMVISION_REALDATA``, or
in ../shared/realdata beside the project); they are never part of the repository.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from armvision.config import Config
from armvision.eval.clear_depth import CATEGORIES, clear_bottle_scene, measure_real, measure_sim
from armvision.sim.camera import SimCamera, realsense_depth_model
from armvision.sim.world import SimWorld

# The real-data folder beside the project (../shared/realdata), or $ARMVISION_REALDATA.
REAL = (
    Path(os.environ.get("ARMVISION_REALDATA") or Path(__file__).parents[3] / "shared/realdata")
    / "cleargrasp_real_d435"
)


def _config(**sim: object) -> Config:
    base = Config()
    return dataclasses.replace(base, sim=dataclasses.replace(base.sim, **sim))


def _frames(config: Config, seed: int = 3, n: int = 1):
    world = SimWorld(config, seed, scene=clear_bottle_scene(config, seed))
    with world, SimCamera(world) as camera:
        out = []
        for _ in range(n):
            frame = camera.read()
            out.append((frame, camera.last_clear_truth))
        z = camera.render_true_depth()
    return out, z


@pytest.fixture(scope="module")
def effects_frames():
    return _frames(_config(camera_effects=True), n=2)


def test_measured_shares_fall_in_the_modelled_ranges() -> None:
    sim = Config().sim
    pooled = measure_sim(seeds=(5,))["pooled"]
    assert pooled["pixels"] > 5000
    assert abs(pooled["missing"] - sim.clear_missing) < 0.02
    assert abs(pooled["behind"] - sim.clear_behind) < 0.05
    assert abs(pooled["wrong"] - sim.clear_wrong) < 0.03
    good = 1.0 - sim.clear_missing - sim.clear_behind - sim.clear_wrong
    assert abs(pooled["good"] - good) < 0.05
    assert abs(sum(pooled[c] for c in CATEGORIES) - 1.0) < 1e-9


def test_clear_model_leaves_other_pixels_alone(effects_frames) -> None:
    (frame, truth), _ = effects_frames[0][0], None
    assert truth is not None and truth.clear.any()
    # The same frame with the clear model off, everything else equal.
    config = _config(camera_effects=True, clear_missing=0.0, clear_behind=1.0, clear_wrong=0.0)
    (plain, _), _ = _frames(config)[0][0], None
    assert np.array_equal(frame.depth[~truth.clear], plain.depth[~truth.clear])
    assert np.array_equal(frame.color, plain.color)
    assert not np.array_equal(frame.depth[truth.clear], plain.depth[truth.clear])


def test_frames_repeat_for_a_seed_and_differ_between_frames(effects_frames) -> None:
    frames, _ = effects_frames
    again, _ = _frames(_config(camera_effects=True), n=2)
    for (a, _), (b, _) in zip(frames, again):
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.color, b.color)
    assert not np.array_equal(frames[0][0].depth, frames[1][0].depth)


def test_missing_clear_depth_comes_in_blobs(effects_frames) -> None:
    frame, truth = effects_frames[0][0]
    missing = truth.clear & (frame.depth == 0)
    # A pixel missing depth has mostly missing neighbours (salt noise would give ~52 %).
    right = missing[:, :-1] & truth.clear[:, 1:]
    same = (missing[:, 1:] & right).sum() / max(right.sum(), 1)
    assert same > 0.8


def test_off_in_the_default_profile_frames_unchanged() -> None:
    config = Config()
    assert not config.sim.camera_effects_on
    assert _config(profile="cluttered").sim.camera_effects_on
    (frames, z) = _frames(config)
    frame, truth = frames[0]
    assert truth is None
    # Exactly the model as it was: the depth model on the plain render with the camera's rng.
    with SimWorld(config, 3, scene=clear_bottle_scene(config, 3)) as world:
        camera = SimCamera(world)
        rng = camera._rng
        rng.standard_normal(frame.color.shape, dtype=np.float32)  # the colour noise comes first
        expected = realsense_depth_model(z, rng, config.sim.depth_min, config.sim.depth_max)
    assert np.array_equal(frame.depth, expected)


@pytest.mark.skipif(not REAL.is_dir(), reason="ClearGrasp's real D435 frames are not here")
def test_measure_real_shares() -> None:
    result = measure_real(REAL)
    rows = [*result["frames"].values(), result["pooled"]]
    for row in rows:
        shares = [row[c] for c in CATEGORIES]
        assert all(0.0 <= s <= 1.0 for s in shares)
        assert abs(sum(shares) - 1.0) < 1e-9
    assert 0.23 <= result["pooled"]["missing"] <= 0.71
