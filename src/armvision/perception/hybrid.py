"""A network names the objects, the geometric fit places them: :class:`HybridDetector`.

A learned detector's box says *what* an object is but places it only roughly (a depth
percentile in the box's centre); the geometric detector fits the cylinder that stands on the
table (centre, radius, height, axis) but tells a bottle from a cup by shape alone. The hybrid
runs both on the same frame and context and pairs them:

- each network box takes the geometric detection whose box overlaps it best, with an IoU of at
  least ``min_iou`` (0.3), or else whose 3-D centre projects inside the box; each geometric
  detection goes to one box at most (best overlaps first). The pair is reported with the
  network's label and score and the geometric box, centre, size, radius, height and axis,
  unless the two boxes overlap by less than ``min_fit_iou`` (0.7) and the network's box
  could be placed on the table (below): then the fit is of a part of the container (a
  clear one's patches), and the container standing on the table whose box it is is
  reported (with an oracle's boxes of what is seen, 3 px of noise, on 80 cluttered scenes:
  clear cups 10-11 mm from their centre, median, against 12.0 mm with every fit kept; the
  other containers unchanged);
- a network box no geometric detection fits is reported as the network gave it. The
  geometric detector runs first and tells the network the table plane it found
  (``FrameContext.table_plane``), so such a box is the container standing on the table
  whose silhouette it is (:func:`~armvision.perception.detection.box_on_table`: a cylinder,
  or the bottle model for a bottle): a clear cup that returned no depth is placed from its
  box alone. Without a plane (a geometric
  detector that does not report one), from the depth in the box
  (:func:`~armvision.perception.detection.box_center_3d`);
- a geometric detection no box matched is reported with the label ``"other"`` (something
  stands there: the tasks do not pick it, but a grasp keeps clear of it).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from armvision.camera.frames import RGBDFrame, project
from armvision.perception.detection import (
    NO_CONTEXT,
    Detection,
    FrameContext,
    ObjectDetector,
)

Box = tuple[float, float, float, float]


def box_iou(a: Box, b: Box) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0.0 or h <= 0.0:
        return 0.0
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0.0 else 0.0


class HybridDetector:
    """Labels and scores from ``network``, 3-D from ``geometric`` (see the module docstring).

    ``network`` and ``geometric`` are any :class:`ObjectDetector`; in practice an
    :class:`~armvision.perception.learned.OnnxDetector` and a
    :class:`~armvision.perception.geometric.GeometricDetector`. The context (camera pose,
    joints) goes to both: the geometric detector needs it for the table and the self-mask.
    """

    def __init__(
        self,
        network: ObjectDetector,
        geometric: ObjectDetector,
        *,
        min_iou: float = 0.3,
        min_fit_iou: float = 0.7,
    ) -> None:
        self.network = network
        self.geometric = geometric
        self.min_iou = float(min_iou)
        self.min_fit_iou = float(min_fit_iou)

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]:
        """The network's objects placed by the geometric fit, then the unnamed ones."""
        fitted = self.geometric.detect(frame, context)
        plane = getattr(self.geometric, "last_plane", None)
        if plane is not None and context.table_plane is None:
            context = dataclasses.replace(context, table_plane=plane)
        named = self.network.detect(frame, context)
        pairs: list[tuple[float, int, int]] = []
        for i, net in enumerate(named):
            x0, y0, x1, y1 = net.box
            for j, geo in enumerate(fitted):
                iou = box_iou(net.box, geo.box)
                u, v = project(frame.intrinsics, np.asarray(geo.center_cam, float)[None])[0]
                inside = bool(x0 <= u <= x1 and y0 <= v <= y1)
                if iou >= self.min_iou or inside:
                    pairs.append((iou, i, j))
        match: dict[int, int] = {}
        taken: set[int] = set()
        for _, i, j in sorted(pairs, key=lambda p: (-p[0], p[1], p[2])):
            if i not in match and j not in taken:
                match[i] = j
                taken.add(j)
        out: list[Detection] = []
        for i, net in enumerate(named):
            if i not in match:
                out.append(net)
                continue
            geo = fitted[match[i]]
            if net.axis_cam is not None and box_iou(net.box, geo.box) < self.min_fit_iou:
                # A fit of part of the box (a clear container's patches): the container
                # standing on the table whose box it is.
                out.append(net)
                continue
            # The network's label and score, the geometric fit's box and 3-D shape.
            out.append(dataclasses.replace(geo, label=net.label, score=float(net.score)))
        for j, geo in enumerate(fitted):
            if j not in taken:
                out.append(dataclasses.replace(geo, label="other", score=float(geo.score)))
        return out
