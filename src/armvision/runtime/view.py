"""Pictures of a :class:`~armvision.runtime.state.SystemState`: what the operator sees.

:func:`annotated` draws tags (outline, id, axes), containers (box, label, score, fill %, liquid
line) and tracks (id, uncertainty) on the newest frame; :func:`depth_image` maps the depth
image onto colours. Used by the UI's video streams and the demo's image.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import project
from armvision.geometry import inv_T
from armvision.perception.annotate import annotate
from armvision.runtime.state import SystemState

_TRACK_COLOUR = (255, 255, 0)  # RGB
_ZONE_COLOUR = (255, 140, 0)  # RGB


def draw_zones(
    image: NDArray[np.uint8],
    state: SystemState,
    zones: Mapping[str, tuple[float, float, float, float]],
    table_z: float = 0.0,
) -> None:
    """Outline each zone's rectangle on the table (``place.zones``, base frame at
    ``table_z``) on ``image`` as the camera the system works with sees it, with its name."""
    frame = state.frame
    if frame is None:
        return
    T_cam_base = inv_T(state.T_base_cam)
    for name, (x0, y0, x1, y1) in zones.items():
        corners = np.array(
            [[x0, y0, table_z], [x1, y0, table_z], [x1, y1, table_z], [x0, y1, table_z]]
        )
        px = project(frame.intrinsics, corners @ T_cam_base[:3, :3].T + T_cam_base[:3, 3])
        if not np.all(np.isfinite(px)):
            continue
        pts = np.round(px).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(image, [pts], True, _ZONE_COLOUR, 2, cv2.LINE_AA)
        x, y = (int(v) for v in np.round(px.min(axis=0)))
        cv2.putText(
            image,
            name,
            (max(x, 2), max(y - 4, 12)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            _ZONE_COLOUR,
            1,
            cv2.LINE_AA,
        )


def annotated(
    state: SystemState,
    tag_axis_m: float,
    newest: bool = True,
    zones: Mapping[str, tuple[float, float, float, float]] | None = None,
) -> NDArray[np.uint8] | None:
    """The colour image with everything the system found drawn on it (RGB), or None before
    the first frame.

    ``newest``: draw on the newest frame (live video; boxes may trail a moving object by the
    object stage's period); else on the frame the detections came from (a still image).
    ``zones``: also outline these table zones (:func:`draw_zones`).
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
    if zones:
        draw_zones(image, state, zones)
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
