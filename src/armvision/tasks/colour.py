"""Naming a liquid's colour as the camera sees it: the nearest of a small palette in CIELAB.

:func:`colour_name` gives the name :class:`~armvision.tasks.analyze.AnalyzeResult` reports
for the liquid's median RGB.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Apparent liquid colours and their names (sRGB). The name reported is the nearest entry in
#: CIELAB with lightness counted at half weight, so a dim room shifts a name less than a hue
#: does. It names the colour as the camera sees it through the wall, not the drink.
COLOUR_PALETTE: dict[str, tuple[int, int, int]] = {
    "white": (235, 235, 230),
    "grey": (128, 128, 128),
    "black": (30, 30, 30),
    "red": (190, 35, 40),
    "dark red": (120, 40, 60),
    "orange": (225, 130, 40),
    "amber": (195, 140, 80),
    "yellow": (225, 200, 60),
    "brown": (110, 70, 40),
    "green": (60, 140, 60),
    "blue": (50, 90, 190),
    "light blue": (140, 175, 215),
    "purple": (120, 60, 140),
}
#: Weight of CIELAB lightness against a and b when naming a colour (:func:`colour_name`).
LIGHTNESS_WEIGHT = 0.5


def _lab(rgb: ArrayLike) -> Array:
    """CIELAB (L 0..100, a, b) of sRGB colours (N, 3) uint8, by OpenCV's D65 conversion."""
    pixels = np.asarray(rgb, dtype=np.float32).reshape(1, -1, 3) / 255.0
    return cv2.cvtColor(pixels, cv2.COLOR_RGB2Lab).reshape(-1, 3).astype(float)


_PALETTE_NAMES = tuple(COLOUR_PALETTE)
_PALETTE_LAB = _lab(list(COLOUR_PALETTE.values()))


def colour_name(rgb: ArrayLike | None) -> str | None:
    """The :data:`COLOUR_PALETTE` name nearest ``rgb`` (0..255) in CIELAB, lightness at
    :data:`LIGHTNESS_WEIGHT`; None for None. E.g. (126, 153, 180) -> "light blue"."""
    if rgb is None:
        return None
    d = _PALETTE_LAB - _lab(np.asarray(rgb, dtype=float).reshape(1, 3))[0]
    d[:, 0] *= LIGHTNESS_WEIGHT
    return _PALETTE_NAMES[int(np.argmin(np.einsum("ij,ij->i", d, d)))]
