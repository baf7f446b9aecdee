"""Bottles and cups from jetson-inference's ``detectNet`` (TensorRT) on an NVIDIA Jetson.

The only module that imports jetson-inference and jetson-utils (lazily, on first use).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from armvision.camera.frames import RGBDFrame
from armvision.errors import PerceptionError
from armvision.perception.detection import (
    NO_CONTEXT,
    Detection,
    FrameContext,
    Label,
    detections_from_boxes,
)
from armvision.perception.learned import COCO91_CLASS_IDS


class JetsonDetector:
    """Bottles and cups from jetson-inference's ``detectNet`` (TensorRT) on an NVIDIA Jetson.

    ``detectNet(network, threshold=threshold)`` is built on first use; jetson-inference numbers
    COCO with a background class, so bottle is 44 and cup 47 (``class_ids``). The 3-D centre
    and size come from the depth in the box
    (:func:`~armvision.perception.detection.box_center_3d`). ``net`` and ``to_cuda``
    replace the network and jetson_utils' ``cudaFromNumpy`` (for tests, or a custom model).
    """

    def __init__(
        self,
        network: str = "ssd-mobilenet-v2",
        *,
        threshold: float = 0.5,
        class_ids: dict[Label, int] | None = None,
        center_fraction: float = 0.3,
        depth_percentile: float = 25.0,
        net: Any = None,
        to_cuda: Any = None,
    ) -> None:
        self.network = network
        self.threshold = float(threshold)
        self.class_ids = dict(COCO91_CLASS_IDS if class_ids is None else class_ids)
        self.center_fraction = float(center_fraction)
        self.depth_percentile = float(depth_percentile)
        self._net = net
        self._to_cuda = to_cuda

    def _load(self) -> tuple[Any, Any]:
        if self._net is not None and self._to_cuda is not None:
            return self._net, self._to_cuda
        try:
            from jetson_inference import detectNet
            from jetson_utils import cudaFromNumpy
        except ImportError:
            try:  # jetson-inference before 2022 installs the jetson.* namespace
                from jetson.inference import detectNet
                from jetson.utils import cudaFromNumpy
            except ImportError:
                raise PerceptionError(
                    "JetsonDetector needs jetson-inference, which runs on NVIDIA Jetson boards "
                    "(build it from github.com/dusty-nv/jetson-inference); elsewhere use "
                    "GeometricDetector or OnnxDetector"
                ) from None
        if self._net is None:
            self._net = detectNet(self.network, threshold=self.threshold)
        if self._to_cuda is None:
            self._to_cuda = cudaFromNumpy
        return self._net, self._to_cuda

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]:
        """Bottles and cups in ``frame``: detectNet on the colour image; for 3-D the
        context's table plane when it has one, else the depth in each box."""
        net, to_cuda = self._load()
        color = np.ascontiguousarray(frame.color)
        h, w = color.shape[:2]
        raw = net.Detect(to_cuda(color), w, h, "none")
        id_to_label = {v: k for k, v in self.class_ids.items()}
        picked = [
            d
            for d in raw
            if int(d.ClassID) in id_to_label and float(d.Confidence) >= self.threshold
        ]
        boxes = np.array([[d.Left, d.Top, d.Right, d.Bottom] for d in picked], dtype=float)
        return detections_from_boxes(
            frame,
            boxes.reshape(-1, 4),
            np.array([float(d.Confidence) for d in picked]),
            [id_to_label[int(d.ClassID)] for d in picked],
            self.center_fraction,
            self.depth_percentile,
            context.table_plane,
        )
