"""The liquid evaluation's scenes per profile and its per-family and opaque-bottle figures."""

from __future__ import annotations

import dataclasses
import math

from armvision.config import Config
from armvision.eval.liquid import (
    CLUTTERED_DISTRACTORS,
    UNKNOWN_CONFIDENCE,
    _by_family,
    _opaque_summary,
    liquid_scene,
)
from armvision.sim.scene import BOTTLE_FAMILIES, footprint_gap, footprint_of


def _cluttered() -> Config:
    config = Config()
    return dataclasses.replace(config, sim=dataclasses.replace(config.sim, profile="cluttered"))


def test_the_default_scenes_hold_plain_bottles_only() -> None:
    scene = liquid_scene(Config(), 5, bottles=4)
    assert [o.kind for o in scene.objects] == ["bottle"] * 4


def test_cluttered_scenes_mix_bottle_families_with_distractors() -> None:
    config = _cluttered()
    kinds = set()
    for seed in range(6):
        scene = liquid_scene(config, seed, bottles=4)
        again = liquid_scene(config, seed, bottles=4)  # the same for a seed
        assert scene.objects == again.objects
        assert (scene.T_base_cam == again.T_base_cam).all()
        labels = [o.label for o in scene.objects]
        assert labels.count("bottle") == 4 and labels.count("other") == CLUTTERED_DISTRACTORS
        kinds |= {o.kind for o in scene.objects if o.label == "bottle"}
        feet = [footprint_of(o) for o in scene.objects]
        gaps = [footprint_gap(p, q) for i, p in enumerate(feet) for q in feet[i + 1 :]]
        assert min(gaps) >= 0.01 - 1e-9
    assert kinds <= set(BOTTLE_FAMILIES) and len(kinds) >= 4


def test_per_family_and_opaque_figures() -> None:
    per_bottle = [
        {"kind": "wine_bottle", "fill_visible": True, "error_pct": 4.0, "confidence": 0.9},
        {"kind": "wine_bottle", "fill_visible": True, "error_pct": -2.0, "confidence": 0.8},
        {"kind": "jug", "fill_visible": False, "error_pct": 60.0, "confidence": 0.5},
        {"kind": "jug", "fill_visible": False, "error_pct": 0.0, "confidence": 0.0},
    ]
    assert _by_family(per_bottle) == {
        "jug": {"bottles": 2, "mae_pct": 30.0},
        "wine_bottle": {"bottles": 2, "mae_pct": 3.0},
    }
    opaque = _opaque_summary(per_bottle)
    assert opaque["opaque_bottles"] == 2 and opaque["opaque_unknown_rate"] == 0.5
    assert opaque["mae_pct_fill_visible"] == 3.0
    assert UNKNOWN_CONFIDENCE > 0.0
    assert math.isnan(_opaque_summary(per_bottle[:2])["opaque_unknown_rate"])
