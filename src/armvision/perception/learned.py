"""Bottles and cups from a learned object detector: ONNX exports run by ONNX Runtime.

:class:`OnnxDetector` runs an SSD-MobileNet (TF Object Detection API) or a YOLOv8
(Ultralytics) export; the helpers decode their outputs (:func:`decode_ssd`,
:func:`decode_yolov8`), letterbox the input, suppress duplicates (:func:`nms`) and map class
names to ids (:func:`read_labels`, :func:`class_ids_from_labels`). The 3-D centre is a robust
depth statistic over the centre of each box
(:func:`~armvision.perception.detection.box_center_3d`). This is the only module that imports
ONNX Runtime (lazily, in :class:`OnnxDetector`); jetson-inference's detectNet is in
:mod:`armvision.perception.jetson`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import RGBDFrame
from armvision.errors import PerceptionError
from armvision.perception.detection import (
    LABELS,
    NO_CONTEXT,
    Detection,
    FrameContext,
    Label,
    detections_from_boxes,
)

Array = NDArray[np.float64]

#: Bottle and cup class ids. COCO with a background class 0 (91 ids, as TF Object Detection
#: API SSD exports and jetson-inference's ssd-mobilenet-v2 number them) and YOLOv8's 80
#: contiguous COCO classes.
COCO91_CLASS_IDS: dict[Label, int] = {"bottle": 44, "cup": 47}
YOLO_CLASS_IDS: dict[Label, int] = {"bottle": 39, "cup": 41}

#: The output layouts :class:`OnnxDetector` reads, for error messages.
ONNX_LAYOUTS = (
    "SSD-MobileNet-v2 exports (outputs boxes (1, N, 4), classes and scores (1, N), optionally "
    "a count (1,)) or YOLOv8/YOLO11 exports (one output (1, 4 + C, N))"
)


def read_labels(path: str | os.PathLike[str]) -> list[str]:
    """Class names, one per line (line number = class id), as jetson-inference's labels.txt."""
    try:
        return [line.strip() for line in Path(path).read_text(encoding="utf-8").splitlines()]
    except OSError as exc:
        raise PerceptionError(f"cannot read the labels file {path}: {exc.strerror}") from None


def class_ids_from_labels(labels: Sequence[str]) -> dict[Label, int]:
    """{"bottle": id, "cup": id} looked up by name in a labels list."""
    lowered = [name.lower() for name in labels]
    missing = [name for name in LABELS if name not in lowered]
    if missing:
        raise PerceptionError(
            f"the labels file has no {' or '.join(missing)} class; pass class_ids="
            "{'bottle': ..., 'cup': ...} for this model"
        )
    return {name: lowered.index(name) for name in LABELS}


def letterbox(
    image: NDArray[np.uint8], size: tuple[int, int], pad_value: int = 114
) -> tuple[NDArray[np.uint8], float, tuple[float, float]]:
    """Resize ``image`` to fit (width, height) keeping its aspect, pad the rest (Ultralytics).

    Returns (image, scale, (pad_x, pad_y)); an input pixel p maps back as (p - pad) / scale.
    """
    width, height = size
    h0, w0 = image.shape[:2]
    scale = min(width / w0, height / h0)
    w1, h1 = round(w0 * scale), round(h0 * scale)
    resized = cv2.resize(image, (w1, h1), interpolation=cv2.INTER_LINEAR)
    pad_x, pad_y = (width - w1) / 2.0, (height - h1) / 2.0
    top, left = round(pad_y - 0.1), round(pad_x - 0.1)
    out = cv2.copyMakeBorder(
        resized,
        top,
        height - h1 - top,
        left,
        width - w1 - left,
        cv2.BORDER_CONSTANT,
        value=(pad_value, pad_value, pad_value),
    )
    return np.asarray(out, dtype=np.uint8), float(scale), (float(left), float(top))


def decode_ssd(
    boxes: Array,
    classes: Array,
    scores: Array,
    count: Array | int,
    class_ids: dict[Label, int],
    threshold: float,
    image_size: tuple[int, int],
    box_order: Literal["yxyx", "xyxy"] = "yxyx",
    normalized: bool = True,
) -> tuple[Array, Array, list[Label]]:
    """Bottle and cup boxes (N, 4) x0, y0, x1, y1 in pixels, scores and labels of an SSD export.

    ``boxes`` (1, N, 4), ``classes`` and ``scores`` (1, N), ``count`` the valid rows (TF Object
    Detection API: ``detection_boxes`` as normalised ymin, xmin, ymax, xmax).
    """
    n = int(np.asarray(count).ravel()[0]) if np.size(count) else len(np.ravel(scores))
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)[:n]
    c = np.rint(np.asarray(classes, dtype=float).ravel()[:n]).astype(int)
    s = np.asarray(scores, dtype=float).ravel()[:n]
    if box_order == "yxyx":
        b = b[:, [1, 0, 3, 2]]
    if normalized:
        width, height = image_size
        b = b * [width, height, width, height]
    id_to_label = {v: k for k, v in class_ids.items()}
    keep = (s >= threshold) & np.isin(c, list(id_to_label))
    return b[keep], s[keep], [id_to_label[int(i)] for i in c[keep]]


def decode_yolov8(
    output: Array, class_ids: dict[Label, int], threshold: float
) -> tuple[Array, Array, list[Label]]:
    """Bottle and cup boxes (N, 4) x0, y0, x1, y1 in network-input pixels from a YOLOv8 head.

    ``output`` (1, 4 + C, N): per candidate (cx, cy, w, h) then C class scores (already
    sigmoid). Each candidate keeps its best class among bottle and cup.
    """
    pred = np.asarray(output, dtype=float).reshape(output.shape[-2], output.shape[-1]).T
    names = list(class_ids)
    cls_scores = pred[:, [4 + class_ids[name] for name in names]]
    best = np.argmax(cls_scores, axis=1)
    s = cls_scores[np.arange(len(pred)), best]
    keep = s >= threshold
    cx, cy, w, h = pred[keep, 0], pred[keep, 1], pred[keep, 2], pred[keep, 3]
    b = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    return b, s[keep], [names[i] for i in best[keep]]


def nms(
    boxes: Array, scores: Array, labels: Sequence[Label], iou_threshold: float
) -> NDArray[np.intp]:
    """Indices kept by per-class non-maximum suppression (OpenCV's ``dnn.NMSBoxesBatched``)."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.intp)
    xywh = [[float(x0), float(y0), float(x1 - x0), float(y1 - y0)] for x0, y0, x1, y1 in boxes]
    class_index = [LABELS.index(label) for label in labels]
    kept = cv2.dnn.NMSBoxesBatched(
        xywh, [float(s) for s in scores], class_index, 0.0, iou_threshold
    )
    return np.asarray(kept, dtype=np.intp).ravel()


def _shape_text(shape: Sequence[object] | None) -> str:
    return "(" + ", ".join(str(d) if d is not None else "?" for d in (shape or [])) + ")"


class OnnxDetector:
    """Bottles and cups from an ONNX object detector run by ONNX Runtime.

    Two export formats: ``"ssd"`` (TF Object Detection API SSD-MobileNet: outputs boxes,
    classes, scores and a count; normalised ymin, xmin, ymax, xmax; uint8 NHWC input) and
    ``"yolov8"`` (Ultralytics: one output (1, 84, N); float NCHW input in [0, 1],
    letterboxed). ``kind=None`` tells them apart by their outputs. Class ids: ``class_ids`` if
    given, else looked up by name in ``labels_path`` (one name per line, line = id), else
    COCO's (bottle 44, cup 47 with background for SSD; 39, 41 for YOLO). Boxes scoring below
    ``threshold`` are dropped, then per-class NMS at ``nms_iou``. The 3-D centre and size come
    from the depth in the box
    (:func:`~armvision.perception.detection.box_center_3d`).

    ONNX Runtime is imported here, not at module import: ``pip install onnxruntime`` (or
    ``onnxruntime-gpu``) to use this detector. ``providers`` defaults to ONNX Runtime's.
    """

    def __init__(
        self,
        model_path: str | os.PathLike[str],
        *,
        kind: Literal["ssd", "yolov8"] | None = None,
        labels_path: str | os.PathLike[str] | None = None,
        class_ids: dict[Label, int] | None = None,
        threshold: float = 0.5,
        nms_iou: float = 0.45,
        ssd_box_order: Literal["yxyx", "xyxy"] = "yxyx",
        center_fraction: float = 0.3,
        depth_percentile: float = 25.0,
        providers: Sequence[str] | None = None,
    ) -> None:
        try:
            import onnxruntime
        except ImportError:
            raise PerceptionError(
                "OnnxDetector needs ONNX Runtime: pip install onnxruntime (onnxruntime-gpu on "
                "CUDA machines), or use GeometricDetector, which needs no weights"
            ) from None
        if not Path(model_path).is_file():
            raise PerceptionError(
                f"ONNX model {model_path} does not exist; export one of {ONNX_LAYOUTS}"
            )
        try:
            self.session = onnxruntime.InferenceSession(
                str(model_path),
                providers=list(providers) if providers else onnxruntime.get_available_providers(),
            )
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph types
            why = " ".join(str(exc).split())[:300]
            raise PerceptionError(
                f"ONNX Runtime cannot load {model_path} ({why}); supported: {ONNX_LAYOUTS}"
            ) from exc
        self.input = self.session.get_inputs()[0]
        self.output_names = [o.name for o in self.session.get_outputs()]
        if kind is None:
            kind = "yolov8" if len(self.output_names) == 1 else "ssd"
        if kind not in ("ssd", "yolov8"):
            raise PerceptionError(f"kind must be 'ssd' or 'yolov8', not {kind!r}")
        self.kind = kind
        self.model_path = str(model_path)
        if class_ids is None and labels_path is not None:
            labels = read_labels(labels_path)
            class_ids = class_ids_from_labels(labels)
        if class_ids is None:
            class_ids = dict(COCO91_CLASS_IDS if kind == "ssd" else YOLO_CLASS_IDS)
        unknown = set(class_ids) - set(LABELS)
        if unknown:
            raise PerceptionError(f"class_ids may name only {LABELS}, not {sorted(unknown)}")
        self.class_ids = dict(class_ids)
        self._check_layout()
        self.threshold = float(threshold)
        self.nms_iou = float(nms_iou)
        self.ssd_box_order = ssd_box_order
        self.center_fraction = float(center_fraction)
        self.depth_percentile = float(depth_percentile)

    def _input_layout(self) -> tuple[bool, tuple[int | None, int | None]]:
        """(channels_first, (width, height) or None where the model takes any size)."""
        shape = list(self.input.shape)
        channels_first = len(shape) == 4 and shape[1] == 3
        dims = shape[2:4] if channels_first else shape[1:3]
        h, w = (d if isinstance(d, int) and d > 0 else None for d in dims)
        return channels_first, (w, h)

    def _ssd_roles(self) -> dict[str, int]:
        """Output index of each SSD role (box, class, score, num), by name, else the TF
        export's order; an empty dict when the outputs cannot be an SSD export's."""
        roles: dict[str, int] = {}
        for i, name in enumerate(self.output_names):
            key = name.lower()
            for role in ("box", "class", "score", "num"):
                if role in key and role not in roles:
                    roles[role] = i
        if all(r in roles for r in ("box", "class", "score")):
            return roles
        if len(self.output_names) == 4:  # unnamed outputs: the TF export's order
            return {"box": 0, "class": 1, "score": 2, "num": 3}
        return {}

    def _check_layout(self) -> None:
        """The model's outputs are one of :data:`ONNX_LAYOUTS`, else a one-line PerceptionError
        naming the file (dimensions the export leaves symbolic are not checked)."""
        outputs = self.session.get_outputs()

        def dims(i: int) -> list[int | None]:
            shape = outputs[i].shape
            return [d if isinstance(d, int) and d > 0 else None for d in (shape or [])]

        def fits(shape: list[int | None], want: list[int | None]) -> bool:
            return len(shape) == len(want) and all(
                w is None or d is None or d == w for d, w in zip(shape, want)
            )

        problem = None
        if self.kind == "yolov8":
            if len(outputs) != 1:
                problem = f"{len(outputs)} outputs, a YOLO export has one"
            else:
                shape = dims(0)
                channels = shape[1] if len(shape) == 3 else None
                need = 5 + max(self.class_ids.values())
                if not fits(shape, [1, None, None]) or (channels is not None and channels < need):
                    problem = (
                        f"output {outputs[0].name} of shape {_shape_text(outputs[0].shape)}, "
                        f"not (1, 4 + C, N) with at least {need} rows"
                    )
        else:
            roles = self._ssd_roles()
            if not roles:
                names = ", ".join(self.output_names)
                problem = f"outputs {names}: no boxes, classes and scores"
            else:
                box, cls, score = (dims(roles[r]) for r in ("box", "class", "score"))
                if not fits(box, [1, None, 4]):
                    problem = f"boxes of shape {_shape_text(outputs[roles['box']].shape)}"
                elif not (fits(cls, [1, box[1]]) and fits(score, [1, box[1]])):
                    problem = (
                        f"classes {_shape_text(outputs[roles['class']].shape)} and scores "
                        f"{_shape_text(outputs[roles['score']].shape)} do not match boxes "
                        f"{_shape_text(outputs[roles['box']].shape)}"
                    )
        if problem is not None:
            raise PerceptionError(
                f"ONNX model {self.model_path} is not a detector armvision reads ({problem}); "
                f"supported: {ONNX_LAYOUTS}"
            )

    def _ssd_outputs(self, outputs: list[Array]) -> tuple[Array, Array, Array, Array]:
        roles = self._ssd_roles()
        num = outputs[roles["num"]] if "num" in roles else np.zeros(0)
        return outputs[roles["box"]], outputs[roles["class"]], outputs[roles["score"]], num

    def detect(self, frame: RGBDFrame, context: FrameContext = NO_CONTEXT) -> list[Detection]:
        """Bottles and cups in ``frame`` (colour for the network; for the 3-D centre the
        context's table plane when it has one, else the depth in each box)."""
        color = np.asarray(frame.color)
        h0, w0 = color.shape[:2]
        channels_first, (w_in, h_in) = self._input_layout()
        if self.kind == "yolov8":
            size = (w_in or 640, h_in or 640)
            image, scale, (pad_x, pad_y) = letterbox(color, size)
        else:
            size = (w_in or w0, h_in or h0)
            image = color if size == (w0, h0) else np.asarray(cv2.resize(color, size), np.uint8)
        tensor: NDArray[np.uint8] | NDArray[np.floating] = image[None]
        if channels_first:
            tensor = tensor.transpose(0, 3, 1, 2)
        if "float" in self.input.type:
            tensor = tensor.astype(np.float32) / (255.0 if self.kind == "yolov8" else 1.0)
        outputs = self.session.run(None, {self.input.name: np.ascontiguousarray(tensor)})
        if self.kind == "yolov8":
            boxes, scores, labels = decode_yolov8(outputs[0], self.class_ids, self.threshold)
            boxes = (boxes - [pad_x, pad_y, pad_x, pad_y]) / scale
        else:
            raw_boxes, classes, raw_scores, count = self._ssd_outputs(outputs)
            boxes, scores, labels = decode_ssd(
                raw_boxes,
                classes,
                raw_scores,
                count,
                self.class_ids,
                self.threshold,
                (w0, h0),
                self.ssd_box_order,
            )
        keep = nms(boxes, scores, labels, self.nms_iou)
        return detections_from_boxes(
            frame,
            boxes[keep],
            scores[keep],
            [labels[i] for i in keep],
            self.center_fraction,
            self.depth_percentile,
            context.table_plane,
        )
