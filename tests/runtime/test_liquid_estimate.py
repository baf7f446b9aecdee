"""A track's liquid estimate when some or all of its measurements are unknown."""

from __future__ import annotations

import numpy as np
import pytest

from armvision.perception.liquid import LiquidLevel
from armvision.runtime.state import average_levels

DEBUG = np.zeros((2, 2, 3), np.uint8)


def _level(fill: float | None, confidence: float, unknown: str | None = None) -> LiquidLevel:
    colour = None if fill is None else (200, 100, 20)
    row = None if fill is None else 100.0
    return LiquidLevel(fill, row, confidence, colour, "profile", DEBUG, unknown=unknown)


def test_unknown_measurements_are_left_out_of_the_fill_and_counted() -> None:
    """Hand-worked: fills 0.4 (confidence 1) and 0.7 (confidence 0.5) average to
    (0.4 + 0.35) / 1.5 = 0.5; the unknown one counts confidence 0 in the mean confidence,
    (1 + 0.5 + 0) / 3 = 0.5, and is counted apart."""
    levels = [
        (0.0, _level(0.4, 1.0)),
        (0.1, _level(None, 0.0, "hidden")),
        (0.2, _level(0.7, 0.5)),
    ]
    est = average_levels(7, levels)
    assert est.fill == pytest.approx(0.5) and est.samples == 2 and est.unknown_samples == 1
    assert est.fill_std == pytest.approx(np.sqrt((1.0 * 0.1**2 + 0.5 * 0.2**2) / 1.5))
    assert est.confidence == pytest.approx(0.5) and est.unknown is None
    assert est.colour == (200, 100, 20) and est.t == 0.2
    assert est.to_dict()["fill"] == 0.5


def test_all_unknown_is_an_unknown_estimate_with_the_reason() -> None:
    levels = [(0.0, _level(None, 0.0, "opaque: a")), (0.1, _level(None, 0.0, "opaque: b"))]
    est = average_levels(3, levels)
    assert est.fill is None and est.fill_std is None and est.samples == 0
    assert est.unknown_samples == 2 and est.unknown == "opaque: b"
    assert est.confidence == 0.0 and est.colour is None
    d = est.to_dict()
    assert d["fill"] is None and d["unknown"] == "opaque: b" and d["unknown_samples"] == 2
