"""The bottle and cup record every object detector returns, the protocol they share and what
they are told about each frame besides its pixels.

Four detectors implement :class:`ObjectDetector`:
:class:`~armvision.perception.geometric.GeometricDetector` (depth alone, no weights),
:class:`~armvision.perception.learned.OnnxDetector` (an ONNX model through ONNX Runtime),
:class:`~armvision.perception.jetson.JetsonDetector` (jetson-inference's ``detectNet``) and
:class:`~armvision.perception.hybrid.HybridDetector` (a network's labels, the geometric fit's
3-D); :func:`~armvision.perception.factory.object_detector` builds the one the configuration
chooses. Each is called as
``detector.detect(frame, FrameContext(T_base_cam=..., joint_positions=...))``; the learned
detectors ignore the context.

Frames: ``cam`` is the colour optical frame (x right, y down, z forward); ``base`` the robot's
base_link; ``T_base_cam`` the camera pose (the calibration).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame, deproject

Array = NDArray[np.float64]
#: What a detection is: a bottle, a cup, or (:class:`~armvision.perception.hybrid.HybridDetector`
#: only) ``"other"``, an object the geometric fit found but the network did not name. The
#: runtime and the tasks act on bottles and cups only; other tracks are obstacles.
Label = Literal["bottle", "cup", "other"]
#: The classes a detector looks for (a network's class map names these).
LABELS: tuple[Label, ...] = ("bottle", "cup")

#: Prior share of a bottle's height taken by its body (below the shoulder); the simulated
#: bottles' value. Measure your own bottles and pass it to the detector and the liquid meter.
BOTTLE_BODY_FRACTION = 0.72


@dataclass(frozen=True, eq=False)
class Detection:
    """One bottle or cup.

    ``box`` (x0, y0, x1, y1) pixels, inclusive-exclusive like a slice; ``center_cam`` (3,)
    metres, the container's centre (on its axis, half-way up) in the camera frame; ``size``
    (3,) metres, (diameter, height, diameter) of the fitted cylinder; ``radius`` and
    ``height`` the same in metres. ``score`` in [0, 1]: the network's confidence for the
    learned detectors, the fit quality for the geometric detector (see its docstring).
    ``axis_cam`` (3,) is the container's up axis in the camera frame when it is known (the
    table normal for the geometric detector), else None.
    """

    label: Label
    score: float
    box: tuple[float, float, float, float]
    center_cam: Array
    size: Array
    radius: float
    height: float
    axis_cam: Array | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict."""
        return {
            "label": self.label,
            "score": float(self.score),
            "box": [float(v) for v in self.box],
            "center_cam": [float(v) for v in self.center_cam],
            "size": [float(v) for v in self.size],
            "radius": float(self.radius),
            "height": float(self.height),
            "axis_cam": None if self.axis_cam is None else [float(v) for v in self.axis_cam],
        }


@dataclass(frozen=True, eq=False)
class FrameContext:
    """What a detector is told about the moment a frame was taken, besides its pixels.

    ``T_base_cam`` (4, 4): the camera's pose in the arm's base frame (the runtime's current
    estimate), None if unknown; ``joint_positions`` (rad): the arm's joints at capture, for
    the self-mask, None for no self-mask of the moving links.
    """

    T_base_cam: Array | None = None
    joint_positions: Array | None = None


#: The context of a frame about which nothing is known (the detectors' default).
NO_CONTEXT = FrameContext()


@runtime_checkable
class ObjectDetector(Protocol):
    """Anything that finds bottles and cups in an RGB-D frame."""

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]: ...


# --------------------------------------------------------------------------- 3-D from a box


def box_center_3d(
    intr: Intrinsics,
    depth: NDArray[np.floating],
    box: tuple[float, float, float, float],
    center_fraction: float = 0.3,
    depth_percentile: float = 25.0,
    min_pixels: int = 8,
) -> tuple[Array, float, float] | None:
    """(center_cam, radius, height) of a container from its pixel box and the depth image.

    The depth of the container's front surface is the ``depth_percentile`` of the valid depth
    in the central ``center_fraction`` of the box (a low percentile rather than the median
    because through a clear bottle above its liquid the camera sees the table behind it).
    The size follows from the box at that depth (diameter = width z / fx, height =
    box height z / fy, an upright container roughly facing the camera), and the centre is the
    deprojected box centre pushed one radius further along its ray, from the front surface to
    the axis. None when fewer than ``min_pixels`` depth pixels are valid.
    """
    x0, y0, x1, y1 = box
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half_w = 0.5 * center_fraction * (x1 - x0)
    half_h = 0.5 * center_fraction * (y1 - y0)
    r0 = int(np.clip(np.floor(cy - half_h), 0, intr.height - 1))
    r1 = int(np.clip(np.ceil(cy + half_h) + 1, r0 + 1, intr.height))
    c0 = int(np.clip(np.floor(cx - half_w), 0, intr.width - 1))
    c1 = int(np.clip(np.ceil(cx + half_w) + 1, c0 + 1, intr.width))
    patch = np.asarray(depth[r0:r1, c0:c1], dtype=float)
    valid = patch[patch > 0.0]
    if len(valid) < min_pixels:
        return None
    z_front = float(np.percentile(valid, depth_percentile))
    radius = 0.5 * (x1 - x0) * z_front / intr.fx
    height = (y1 - y0) * z_front / intr.fy
    p_front = deproject(intr, [[cx, cy]], [z_front])[0]
    center_cam = p_front + radius * p_front / np.linalg.norm(p_front)
    return center_cam, float(radius), float(height)


def detections_from_boxes(
    frame: RGBDFrame,
    boxes: Array,
    scores: Array,
    labels: Sequence[Label],
    center_fraction: float,
    depth_percentile: float,
) -> list[Detection]:
    """Detections for pixel boxes (N, 4) x0, y0, x1, y1; boxes without depth are dropped."""
    intr = frame.intrinsics
    out = []
    for box, score, label in zip(boxes, scores, labels):
        x0, y0, x1, y1 = (float(v) for v in box)
        x0, x1 = float(np.clip(x0, 0, intr.width)), float(np.clip(x1, 0, intr.width))
        y0, y1 = float(np.clip(y0, 0, intr.height)), float(np.clip(y1, 0, intr.height))
        if x1 - x0 < 1.0 or y1 - y0 < 1.0:
            continue
        located = box_center_3d(
            intr, frame.depth, (x0, y0, x1, y1), center_fraction, depth_percentile
        )
        if located is None:
            continue
        center_cam, radius, height = located
        out.append(
            Detection(
                label=label,
                score=float(score),
                box=(x0, y0, x1, y1),
                center_cam=center_cam,
                size=np.array([2.0 * radius, height, 2.0 * radius]),
                radius=radius,
                height=height,
            )
        )
    return out
