"""The object detector the configuration chooses (``[perception]``): :func:`object_detector`.

``geometric`` needs nothing; ``onnx`` and ``hybrid`` load ``perception.model`` with ONNX
Runtime and check that its outputs are a layout :class:`~armvision.perception.learned.OnnxDetector`
reads (:data:`~armvision.perception.learned.ONNX_LAYOUTS`), so a missing or wrong file fails
here, in one line naming it, not at the first frame; ``jetson`` builds detectNet on first use.
:func:`describe_detector` says which detector is active and whether it can be built, for
``armvision info``.
"""

from __future__ import annotations

from armvision.config import PerceptionConfig
from armvision.errors import PerceptionError
from armvision.perception.detection import Label, ObjectDetector
from armvision.perception.geometric import GeometricDetector
from armvision.perception.hybrid import HybridDetector
from armvision.perception.jetson import JetsonDetector
from armvision.perception.learned import (
    COCO91_CLASS_IDS,
    OnnxDetector,
    class_ids_from_labels,
    read_labels,
)


def _onnx(config: PerceptionConfig) -> OnnxDetector:
    if config.model is None:  # the configuration's validator makes this unreachable
        raise PerceptionError(f"perception.detector = {config.detector!r} needs perception.model")
    return OnnxDetector(
        config.model,
        labels_path=config.labels,
        threshold=config.score_threshold,
        nms_iou=config.nms_iou,
    )


def object_detector(config: PerceptionConfig) -> ObjectDetector:
    """The detector ``config.detector`` names, built from the rest of the section."""
    if config.detector == "geometric":
        return GeometricDetector()
    if config.detector == "onnx":
        return _onnx(config)
    if config.detector == "hybrid":
        return HybridDetector(_onnx(config), GeometricDetector())
    class_ids: dict[Label, int] = dict(COCO91_CLASS_IDS)
    if config.labels is not None:
        class_ids = class_ids_from_labels(read_labels(config.labels))
    return JetsonDetector(
        config.model or "ssd-mobilenet-v2",
        threshold=config.score_threshold,
        class_ids=class_ids,
    )


def describe_detector(config: PerceptionConfig) -> tuple[bool, str]:
    """(usable, one line): the active detector, why it is the one, and its model's layout or
    why it cannot be built."""
    why = "(perception.detector)"
    if config.detector == "geometric":
        return True, f"geometric {why}: depth alone, no weights"
    if config.detector == "jetson":
        network = config.model or "ssd-mobilenet-v2"
        return True, f"jetson {why}: detectNet {network}, loaded on the first frame"
    try:
        detector = _onnx(config)
    except PerceptionError as exc:
        return False, f"{config.detector} {why}: {exc}"
    layout = {"ssd": "SSD (boxes, classes, scores)", "yolov8": "YOLOv8/YOLO11 (1, 4 + C, N)"}
    ids = ", ".join(f"{k} {v}" for k, v in detector.class_ids.items())
    text = f"{config.detector} {why}: {config.model}, {layout[detector.kind]}, classes {ids}"
    if config.detector == "hybrid":
        text += "; 3-D from the geometric fit"
    return True, text
