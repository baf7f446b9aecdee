"""Draw what perception found onto the colour image (for ``armvision perceive`` and the UI).

Tags get their outline, id and axes (x red, y green, z blue, one tag edge long, projected with
the camera's own model); containers their box, label, score, fill and the liquid line.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, project
from armvision.perception.detection import Detection
from armvision.perception.liquid import LiquidLevel
from armvision.perception.tags import TagDetection

_LABEL_COLOURS = {"bottle": (255, 170, 0), "cup": (0, 200, 255)}  # RGB


def _text(image: NDArray[np.uint8], text: str, org: tuple[int, int], colour) -> None:
    x, y = org
    y = max(y, 12)
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
    cv2.rectangle(image, (x, y - h - 3), (x + w + 2, y + 2), (0, 0, 0), -1)
    cv2.putText(image, text, (x + 1, y - 1), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)


def draw_tags(
    image: NDArray[np.uint8], tags: Sequence[TagDetection], intr: Intrinsics, axis_m: float
) -> None:
    """Outline, id and pose axes of each tag, in place."""
    for tag in tags:
        corners = np.round(tag.corners).astype(np.int32)
        cv2.polylines(image, [corners], True, (0, 255, 0), 1, cv2.LINE_AA)
        p_tag = np.array([[0, 0, 0], [axis_m, 0, 0], [0, axis_m, 0], [0, 0, -axis_m]], float)
        p_cam = p_tag @ tag.T_cam_tag[:3, :3].T + tag.T_cam_tag[:3, 3]
        uv = project(intr, p_cam)
        if np.all(np.isfinite(uv)):
            o = tuple(np.round(uv[0]).astype(int))
            for end, colour in zip(uv[1:], ((255, 0, 0), (0, 255, 0), (0, 0, 255))):
                cv2.line(image, o, tuple(np.round(end).astype(int)), colour, 2, cv2.LINE_AA)
        distance = np.linalg.norm(tag.T_cam_tag[:3, 3])
        label = f"tag {tag.id} {distance:.2f} m" + (" +depth" if tag.depth_refined else "")
        _text(image, label, (int(corners[:, 0].min()), int(corners[:, 1].min()) - 4), (0, 255, 0))


def draw_containers(
    image: NDArray[np.uint8],
    detections: Sequence[Detection],
    levels: Sequence[LiquidLevel | None] = (),
) -> None:
    """Box, label, score and (when measured) fill % and liquid line of each container."""
    levels = list(levels) + [None] * (len(detections) - len(levels))
    for det, level in zip(detections, levels):
        x0, y0, x1, y1 = (round(v) for v in det.box)
        colour = _LABEL_COLOURS.get(det.label, (255, 255, 255))
        cv2.rectangle(image, (x0, y0), (x1, y1), colour, 2)
        text = f"{det.label} {det.score:.2f}"
        if level is not None:
            fill, level_row = level.fill, level.level_row
            if fill is None or level_row is None:
                text += " fill unknown"  # the liquid cannot be seen (an opaque wall, ...)
            else:
                text += f" fill {100 * fill:.0f}%"
                row = round(level_row)
                cv2.line(image, (x0, row), (x1, row), (255, 0, 255), 2, cv2.LINE_AA)
        _text(image, text, (x0, y0 - 4), colour)


def annotate(
    color: NDArray[np.uint8],
    intr: Intrinsics,
    tags: Sequence[TagDetection] = (),
    detections: Sequence[Detection] = (),
    levels: Sequence[LiquidLevel | None] = (),
    tag_axis_m: float = 0.04,
) -> NDArray[np.uint8]:
    """A copy of the RGB ``color`` image with tags, containers and liquid levels drawn on it."""
    image = np.ascontiguousarray(color).copy()
    draw_containers(image, detections, levels)
    draw_tags(image, tags, intr, tag_axis_m)
    return image
