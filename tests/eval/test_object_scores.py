"""The object evaluation's tallies on a hand-worked scene: per-label recall and precision, the
distractor rate, and false positives; a detection labelled "other" is never a call."""

from __future__ import annotations

import math

import numpy as np

from armvision.eval.objects import _Counts, _score_scene, _summary
from armvision.perception.detection import Detection


def _obj(name: str, kind: str, truth: str, x: float, visible: bool = True) -> dict:
    return {
        "name": name,
        "kind": kind,
        "truth": truth,
        "radius": 0.03,
        "height": 0.2,
        "center_cam": np.array([x, 0.0, 1.0]),
        "visible_fraction": 1.0 if visible else 0.1,
        "visible": visible,
    }


def _det(label: str, x: float) -> Detection:
    return Detection(
        label=label,
        score=0.9,
        box=(0.0, 0.0, 10.0, 10.0),
        center_cam=np.array([x, 0.0, 1.0]),
        size=np.array([0.06, 0.06, 0.2]),
        radius=0.03,
        height=0.2,
    )


def test_a_hand_worked_cluttered_scene() -> None:
    objects = [
        _obj("b1", "wine_bottle", "bottle", 0.0),
        _obj("b2", "water_bottle", "bottle", 0.2),
        _obj("c1", "mug", "cup", 0.4),
        _obj("can", "can", "other", 0.6),
        _obj("bowl", "bowl", "other", 0.8),
        _obj("b3", "water_bottle", "bottle", 1.0, visible=False),
    ]
    detections = [
        _det("bottle", 0.001),  # b1, right
        _det("cup", 0.201),  # b2, wrong label
        _det("bottle", 0.601),  # the can: a distractor called a bottle
        _det("cup", 0.399),  # c1, right
        _det("bottle", -0.5),  # nothing there
        _det("bottle", 1.001),  # b3, out of view: neither right nor wrong
    ]
    counts = _Counts()
    false_positives = _score_scene(objects, detections, 0.05, counts)
    s = _summary(counts, 1)
    assert sorted(false_positives) == [2, 4]
    assert s["object_false_positives"] == 2
    assert s["object_recall"] == 1.0  # b1, b2, c1 each matched (b3 is out of view)
    assert s["object_recall_bottle"] == 0.5  # b2 was found, but as a cup
    assert s["object_recall_cup"] == 1.0
    assert math.isclose(s["object_precision_bottle"], 1 / 3)  # b1 right; the can, nothing
    assert s["object_precision_cup"] == 0.5  # c1 right, b2 wrong
    assert s["distractor_rate"] == 0.5 and s["distractors_visible"] == 2
    assert s["found_by_kind"]["can"] == {"visible": 1, "found": 1, "called": 1, "rate": 1.0}
    assert s["found_by_kind"]["bowl"]["found"] == 0
    assert s["object_label_accuracy"] == 3 / 4  # of the 4 matched bottles and cups
    assert math.isclose(s["object_center_error_mm_median"], 1.0)


def test_a_scene_without_distractors_counts_as_before() -> None:
    objects = [_obj("b1", "bottle", "bottle", 0.0), _obj("c1", "cup", "cup", 0.3)]
    detections = [_det("bottle", 0.002), _det("bottle", 0.7)]
    counts = _Counts()
    assert _score_scene(objects, detections, 0.05, counts) == [1]
    s = _summary(counts, 1)
    assert s["object_recall"] == 0.5 and s["object_false_positives"] == 1
    assert s["object_recall_cup"] == 0.0 and s["object_precision_bottle"] == 0.5
    assert math.isnan(s["distractor_rate"])


def test_other_labels_are_right_on_distractors_and_misses_on_containers() -> None:
    objects = [
        _obj("b1", "wine_bottle", "bottle", 0.0),
        _obj("c1", "mug", "cup", 0.2),
        _obj("can", "can", "other", 0.4),
        _obj("box", "box", "other", 0.6),
        _obj("bowl", "bowl", "other", 0.8),
    ]
    detections = [
        _det("bottle", 0.001),  # b1, right
        _det("other", 0.201),  # c1 called other: a miss, not a false positive
        _det("other", 0.401),  # the can as other: right
        _det("cup", 0.601),  # the box called a cup: a false positive
        _det("other", -0.5),  # an "other" on nothing: harmless
    ]
    counts = _Counts()
    assert _score_scene(objects, detections, 0.05, counts) == [3]
    s = _summary(counts, 1)
    assert s["object_false_positives"] == 1
    assert s["object_recall"] == 0.5  # b1 found; c1 only as "other"
    assert s["object_recall_bottle"] == 1.0 and s["object_recall_cup"] == 0.0
    assert s["object_precision_bottle"] == 1.0
    assert s["object_precision_cup"] == 0.0  # its one cup was the box
    assert math.isclose(s["distractor_rate"], 1 / 3)  # the box of can, box and bowl
    assert s["found_by_kind"]["can"] == {"visible": 1, "found": 1, "called": 0, "rate": 1.0}
    assert s["found_by_kind"]["mug"]["called"] == 0 and s["found_by_kind"]["mug"]["found"] == 1
    assert s["object_label_accuracy"] == 0.5  # b1 right, c1 labelled other
