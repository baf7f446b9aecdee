"""Choosing the object detector from the configuration (``[perception]``): the factory, the
hybrid detector (network labels, geometric 3-D), the model-file errors, and the choice
reaching the runtime and ``armvision perceive``.

No weights ship with armvision: the ONNX models here are tiny graphs built in the test whose
outputs are constants of an export's exact shapes, boxes drawn around the objects of the
simulated scene of seed 3 (three bottles and a cup; the arm asleep).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from armvision.config import Config, PerceptionConfig, load_config
from armvision.errors import ConfigError, PerceptionError
from armvision.geometry import inv_T
from armvision.perception.detection import (
    FrameContext,
    box_on_table,
    cylinder_box,
)
from armvision.perception.factory import describe_detector, object_detector
from armvision.perception.geometric import GeometricDetector
from armvision.perception.hybrid import HybridDetector
from armvision.perception.jetson import JetsonDetector

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from armvision.perception.learned import OnnxDetector  # noqa: E402

W, H = 640, 480


def _constant_model(path, input_shape, input_type, outputs: dict[str, np.ndarray]) -> str:
    """An ONNX model whose outputs are the given constants (its input is ignored)."""
    nodes, graph_outputs = [], []
    for name, value in outputs.items():
        tensor = numpy_helper.from_array(value, name + "_value")
        nodes.append(helper.make_node("Constant", [], [name], value=tensor))
        dtype = helper.np_dtype_to_tensor_dtype(value.dtype)
        graph_outputs.append(helper.make_tensor_value_info(name, dtype, list(value.shape)))
    image = helper.make_tensor_value_info("image", input_type, list(input_shape))
    graph = helper.make_graph(nodes, "constant_detector", [image], graph_outputs)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


def ssd_model(path, boxes: list[tuple[str, float, tuple]], with_count: bool = True) -> str:
    """An SSD-MobileNet-v2 export (TF Object Detection API / jetson-inference COCO ids):
    boxes (1, N, 4) normalised ymin, xmin, ymax, xmax; classes and scores (1, N); count."""
    ids = {"bottle": 44, "cup": 47, "person": 1}
    b = np.array(
        [[[y0 / H, x0 / W, y1 / H, x1 / W] for _, _, (x0, y0, x1, y1) in boxes]], np.float32
    )
    outputs = {
        "detection_boxes": b,
        "detection_classes": np.array([[ids[label] for label, _, _ in boxes]], np.float32),
        "detection_scores": np.array([[score for _, score, _ in boxes]], np.float32),
    }
    if with_count:
        outputs["num_detections"] = np.array([len(boxes)], np.float32)
    return _constant_model(path, [1, H, W, 3], TensorProto.UINT8, outputs)


def yolo_model(path, boxes: list[tuple[str, float, tuple]]) -> str:
    """A YOLOv8/YOLO11 export (1, 84, N) on a 640x640 letterboxed input (80 px pad rows)."""
    ids = {"bottle": 39, "cup": 41}
    out = np.zeros((1, 84, len(boxes)), np.float32)
    for k, (label, score, (x0, y0, x1, y1)) in enumerate(boxes):
        out[0, :4, k] = ((x0 + x1) / 2, (y0 + y1) / 2 + 80, x1 - x0, y1 - y0)
        out[0, 4 + ids[label], k] = score
    return _constant_model(path, [1, 3, 640, 640], TensorProto.FLOAT, {"output0": out})


@pytest.fixture(scope="module")
def scene():
    """Seed 3 as ``armvision perceive --sim --seed 3`` renders it: the frame, its context, the
    geometric detections and the true centres (camera frame) by label."""
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    with SimWorld(Config(), 3) as world, SimCamera(world) as camera:
        arm = SimArm(world)
        arm.go_to_sleep_pose()
        world.advance(0.3)
        frame = camera.read()
        context = FrameContext(world.T_base_cam(), arm.get_joint_positions())
        T_cam_base = inv_T(world.T_base_cam())
        truth = []
        for o in world.objects():
            T = T_cam_base @ o.T_base_obj
            truth.append((o.spec.label, T[:3, 3] + T[:3, 2] * o.spec.height / 2))
    geometric = GeometricDetector().detect(frame, context)
    assert sorted(d.label for d in geometric) == ["bottle", "bottle", "bottle", "cup"]
    return frame, context, geometric, truth


def _pad(box, px: float = 4.0):
    x0, y0, x1, y1 = box
    return (x0 - px, y0 - px, x1 + px, y1 + px)


@pytest.fixture(scope="module")
def boxes(scene):
    """Network boxes (label, score, box): the middle bottle and the cup, a little larger than
    the geometric boxes; the other two bottles are left without a box."""
    _, _, geometric, _ = scene
    by_x = sorted(geometric, key=lambda d: d.center_cam[0])  # cup, bottle, bottle, bottle
    cup = next(d for d in geometric if d.label == "cup")
    middle = [d for d in by_x if d.label == "bottle"][1]
    return [("bottle", 0.91, _pad(middle.box)), ("cup", 0.83, _pad(cup.box))], middle, cup


@pytest.fixture(scope="module")
def ssd_path(tmp_path_factory, boxes):
    return ssd_model(tmp_path_factory.mktemp("ssd") / "ssd.onnx", boxes[0])


def _nearest(truth, p):
    return min(truth, key=lambda t: float(np.linalg.norm(t[1] - p)))


# --------------------------------------------------------------------------- the configuration


def test_the_configuration_selects_each_detector(tmp_path, boxes, ssd_path) -> None:
    yolo_path = yolo_model(tmp_path / "yolo.onnx", boxes[0])
    assert isinstance(object_detector(PerceptionConfig()), GeometricDetector)
    ssd = object_detector(PerceptionConfig(detector="onnx", model=ssd_path))
    assert isinstance(ssd, OnnxDetector) and ssd.kind == "ssd"
    assert ssd.class_ids == {"bottle": 44, "cup": 47}  # jetson-inference's SSD-MobileNet-v2 ids
    yolo = object_detector(PerceptionConfig(detector="onnx", model=yolo_path, nms_iou=0.6))
    assert isinstance(yolo, OnnxDetector) and yolo.kind == "yolov8" and yolo.nms_iou == 0.6
    assert yolo.class_ids == {"bottle": 39, "cup": 41}
    jetson = object_detector(PerceptionConfig(detector="jetson", score_threshold=0.4))
    assert isinstance(jetson, JetsonDetector) and jetson.network == "ssd-mobilenet-v2"
    assert jetson.threshold == 0.4 and jetson.class_ids == {"bottle": 44, "cup": 47}
    hybrid = object_detector(PerceptionConfig(detector="hybrid", model=ssd_path))
    assert isinstance(hybrid, HybridDetector) and isinstance(hybrid.network, OnnxDetector)
    labels = tmp_path / "labels.txt"
    labels.write_text("\n".join(["unlabeled", "person", "bottle", "cup"]))
    custom = object_detector(PerceptionConfig(detector="jetson", labels=str(labels)))
    assert isinstance(custom, JetsonDetector) and custom.class_ids == {"bottle": 2, "cup": 3}
    config = load_config(overrides=["perception.detector=hybrid", f"perception.model={ssd_path}"])
    assert config.perception.detector == "hybrid" and config.perception.model == ssd_path
    assert describe_detector(config.perception)[0]


@pytest.mark.parametrize("detector", ["onnx", "hybrid"])
def test_onnx_and_hybrid_need_a_model(detector) -> None:
    with pytest.raises(ConfigError, match=r"perception\.model") as err:
        load_config(overrides=[f"perception.detector={detector}"])
    assert "\n" not in str(err.value)


# --------------------------------------------------------------------------- the hybrid


def test_hybrid_names_with_the_network_and_places_with_the_geometric_fit(
    tmp_path, scene, boxes
) -> None:
    """The boxed bottle and cup carry the network's label and score and the geometric
    centre (a few mm from the truth); the unboxed bottles are "other"; a box over bare table
    (no fit) keeps the network's label and is the cylinder standing on the table the
    geometric detector found whose box it is."""
    frame, context, geometric, truth = scene
    net_boxes, middle, cup = boxes
    empty_table = (560.0, 380.0, 600.0, 420.0)
    path = ssd_model(tmp_path / "ssd3.onnx", [*net_boxes, ("cup", 0.66, empty_table)], False)
    detector = object_detector(PerceptionConfig(detector="hybrid", model=path))
    found = detector.detect(frame, context)
    assert sorted(d.label for d in found) == ["bottle", "cup", "cup", "other", "other"]
    for det, geo, score in ((found[0], middle, 0.91), (found[1], cup, 0.83)):
        assert det.label == geo.label and det.score == pytest.approx(score)
        np.testing.assert_array_equal(det.center_cam, geo.center_cam)
        assert (det.radius, det.height, det.box) == (geo.radius, geo.height, geo.box)
        label, true_centre = _nearest(truth, det.center_cam)
        assert label == det.label
        assert np.linalg.norm(det.center_cam - true_centre) < 0.01
    phantom = found[2]
    assert phantom.label == "cup" and phantom.score == pytest.approx(0.66)
    assert phantom.box == pytest.approx(empty_table, abs=0.01)
    plane = detector.geometric.last_plane
    expected = box_on_table(frame.intrinsics, phantom.box, *plane)
    assert expected is not None
    np.testing.assert_allclose(phantom.center_cam, expected[0])
    foot = phantom.center_cam - 0.5 * phantom.height * plane[0]
    assert abs(float(plane[0] @ foot) + plane[1]) < 1e-9  # standing on the table
    np.testing.assert_allclose(
        cylinder_box(
            frame.intrinsics, phantom.center_cam, plane[0], phantom.radius, phantom.height
        ),
        phantom.box,
        atol=0.05,
    )
    others = [d for d in found if d.label == "other"]
    unboxed = [d for d in geometric if d is not middle and d is not cup]
    assert sorted(d.box for d in others) == sorted(d.box for d in unboxed)
    for det in others:
        assert _nearest(truth, det.center_cam)[0] == "bottle"  # truly bottles, not named


def test_hybrid_with_a_yolo_export_matches_the_same_objects(tmp_path, scene, boxes) -> None:
    frame, context, _, _ = scene
    path = yolo_model(tmp_path / "yolo.onnx", boxes[0])
    found = object_detector(PerceptionConfig(detector="hybrid", model=path)).detect(frame, context)
    assert sorted(d.label for d in found) == ["bottle", "cup", "other", "other"]
    np.testing.assert_array_equal(found[0].center_cam, boxes[1].center_cam)


# --------------------------------------------------------------------------- the model file


def _one_line_naming(err: pytest.ExceptionInfo, path) -> None:
    message = str(err.value)
    assert "\n" not in message
    assert str(path) in message
    assert "SSD-MobileNet-v2" in message and "YOLOv8/YOLO11" in message
    assert "(1, 4 + C, N)" in message


def test_a_missing_model_file_is_a_one_line_error(tmp_path) -> None:
    path = tmp_path / "nowhere.onnx"
    with pytest.raises(PerceptionError, match="does not exist") as err:
        object_detector(PerceptionConfig(detector="hybrid", model=str(path)))
    _one_line_naming(err, path)
    usable, detail = describe_detector(PerceptionConfig(detector="onnx", model=str(path)))
    assert not usable and str(path) in detail and detail.startswith("onnx (perception.detector)")


@pytest.mark.parametrize(
    "outputs",
    [
        {"output0": np.zeros((1, 84), np.float32)},  # a YOLO head without candidates
        {"output0": np.zeros((1, 30, 10), np.float32)},  # too few classes for cup (41)
        {  # SSD boxes with 5 numbers
            "detection_boxes": np.zeros((1, 10, 5), np.float32),
            "detection_classes": np.zeros((1, 10), np.float32),
            "detection_scores": np.zeros((1, 10), np.float32),
        },
        {  # SSD scores per class (1, N, C): not this layout
            "boxes": np.zeros((1, 10, 4), np.float32),
            "classes": np.zeros((1, 10), np.float32),
            "scores": np.zeros((1, 10, 91), np.float32),
        },
    ],
)
def test_a_malformed_model_is_a_one_line_error(tmp_path, outputs) -> None:
    path = _constant_model(tmp_path / "bad.onnx", [1, H, W, 3], TensorProto.UINT8, outputs)
    with pytest.raises(PerceptionError, match="not a detector armvision reads") as err:
        object_detector(PerceptionConfig(detector="onnx", model=path))
    _one_line_naming(err, path)


def test_a_file_that_is_no_onnx_model_is_a_one_line_error(tmp_path) -> None:
    path = tmp_path / "weights.onnx"
    path.write_bytes(b"not a protobuf\n\x00\x01 at all\n")
    with pytest.raises(PerceptionError, match="cannot load") as err:
        object_detector(PerceptionConfig(detector="onnx", model=str(path)))
    _one_line_naming(err, path)


def test_an_ssd_export_without_a_count_output(tmp_path, scene, boxes) -> None:
    frame = scene[0]
    path = ssd_model(tmp_path / "ssd.onnx", boxes[0], with_count=False)
    found = object_detector(PerceptionConfig(detector="onnx", model=path)).detect(frame)
    assert [d.label for d in found] == ["bottle", "cup"]


# --------------------------------------------------------------------------- runtime and CLI


def test_the_system_runs_the_configured_hybrid_detector(ssd_path, boxes) -> None:
    """Lockstep, 1 s: the bottle and cup tracks are the two the network named; the unboxed
    bottles are tracked as "other" (obstacles), and only named bottles are bottles."""
    from armvision.bench.system import sim_system

    config = load_config(overrides=["perception.detector=hybrid", f"perception.model={ssd_path}"])
    with sim_system(config, seed=3) as system:
        assert isinstance(system.object_detector, HybridDetector)
        system.start()
        system.pump(1.0)
        state = system.snapshot()
        T = state.T_base_cam
    assert state.health["objects"].errors == 0
    labels = sorted(t.label for t in state.tracks)
    assert labels == ["bottle", "cup", "other", "other"], labels
    _, middle, cup = boxes
    for geo in (middle, cup):
        p = T[:3, :3] @ geo.center_cam + T[:3, 3]
        (track,) = [t for t in state.tracks if t.label == geo.label]
        assert np.linalg.norm(track.p_base - p) < 0.02
    assert [t.label for t in state.bottles()] == ["bottle"]
    measured = {t.label for t in state.tracks if t.id in state.liquid}
    assert measured <= {"bottle"}


def test_perceive_runs_the_configured_hybrid_detector(tmp_path, ssd_path, capsys) -> None:
    from armvision.cli.main import main

    out = tmp_path / "out"
    code = main(
        [
            "--set",
            "perception.detector=hybrid",
            "--set",
            f"perception.model={ssd_path}",
            "perceive",
            "--sim",
            "--seed",
            "3",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert code == 0
    record = json.loads((out / "detections.json").read_text())
    labels = sorted(d["label"] for d in record["detections"])
    assert labels == ["bottle", "cup", "other", "other"]
    bottle = next(d for d in record["detections"] if d["label"] == "bottle")
    assert bottle["fill"] is not None
    assert all(d["fill"] is None for d in record["detections"] if d["label"] != "bottle")


def test_info_says_which_detector_is_active(ssd_path, tmp_path) -> None:
    from armvision.cli.info import check_object_detector

    status = check_object_detector(Config())
    assert status.usable and status.detail.startswith("geometric (perception.detector)")
    config = load_config(overrides=["perception.detector=hybrid", f"perception.model={ssd_path}"])
    status = check_object_detector(config)
    assert status.usable and ssd_path in status.detail and "SSD" in status.detail
    bad = load_config(
        overrides=["perception.detector=onnx", f"perception.model={tmp_path / 'x.onnx'}"]
    )
    status = check_object_detector(bad)
    assert not status.usable and "does not exist" in status.detail


def test_eval_perception_measures_the_configured_detector(ssd_path) -> None:
    """`armvision eval perception` measures the detector the configuration chooses: on seed 3
    (three bottles and a cup) the hybrid with the test network, which boxes the middle bottle
    and the cup, finds those two with their labels and reports the other bottles as other
    (bottle recall 1/3, cup 1/1, nothing false); the geometric detector finds all four."""
    from armvision.eval.objects import evaluate_objects

    hybrid = load_config(None, ["perception.detector=hybrid", f"perception.model={ssd_path}"])
    found = evaluate_objects(hybrid, [3], randomize_camera=False)["summary"]
    assert found["detector"] == "hybrid"
    assert found["object_recall_bottle"] == pytest.approx(1 / 3)
    assert found["object_recall_cup"] == 1.0
    assert found["object_false_positives"] == 0
    geometric = evaluate_objects(load_config(None, []), [3], randomize_camera=False)["summary"]
    assert geometric["detector"] == "geometric"
    assert geometric["object_recall_bottle"] == 1.0 and geometric["object_recall_cup"] == 1.0
