"""Pictures of a :class:`~armvision.runtime.state.SystemState`: what the operator sees.

:func:`annotated` draws tags (outline, id, axes), containers (box, label, score, fill %, liquid
line) and tracks (id, uncertainty) on the newest frame; :func:`depth_image` maps the depth
image onto colours. Used by the UI's video streams and the demo's image.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.perception.annotate import annotate
from armvision.runtime.state import SystemState

_TRACK_COLOUR = (255, 255, 0)  # RGB


def annotated(
    state: SystemState, tag_axis_m: float, newest: bool = True
) -> NDArray[np.uint8] | None:
    """The colour image with everything the system found drawn on it (RGB), or None before
    the first frame.

    ``newest``: draw on the newest frame (live video; boxes may trail a moving object by the
    object stage's period); else on the frame the detections came from (a still image).
    """
    frame = state.frame if newest else (state.detections_frame or state.frame)
    if frame is None:
        return None
    levels = []
    for det in state.detections:
        track = state.track_of(det) if det.label == "bottle" else None
        estimate = None if track is None else state.liquid.get(track.id)
        levels.append(None if estimate is None else estimate.latest)
    image = annotate(
        frame.color, frame.intrinsics, state.tags, state.detections, levels, tag_axis_m
    )
    for t in state.tracks:
        if t.box is None:
            continue
        x0, y1 = round(t.box[0]), round(t.box[3])
        cv2.putText(
            image,
            f"#{t.id} +-{t.sigma_mm:.0f}mm",
            (x0, min(y1 + 14, image.shape[0] - 2)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            _TRACK_COLOUR,
            1,
            cv2.LINE_AA,
        )
    return image


def depth_image(depth: NDArray[np.floating], near_m: float, far_m: float) -> NDArray[np.uint8]:
    """Depth (metres, 0 = no data) as an RGB image: near red through far blue (OpenCV's
    Turbo map), no data black."""
    span = max(far_m - near_m, 1e-6)
    scaled = np.clip((far_m - np.asarray(depth, dtype=np.float32)) / span, 0.0, 1.0)
    bgr = cv2.applyColorMap((255 * scaled).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[~(np.asarray(depth) > 0)] = 0
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
