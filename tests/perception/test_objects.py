"""Bottle and cup detection against the simulator's ground truth, plus the learned backends.

The geometric detector is judged on simulated scenes (1-4 bottles and cups, camera placed at
random, D435 depth noise) whose true object poses come from the simulator. The ONNX and
Jetson backends ship without trained weights: their decoding, class mapping, NMS and 3-D
centre are tested with tiny ONNX graphs built here that output constant tensors we choose,
and with a fake detectNet object that follows jetson-inference's interface.
"""

from __future__ import annotations

import inspect
import math
import sys

import numpy as np
import pytest

from armvision.camera.frames import Intrinsics, RGBDFrame, deproject
from armvision.config import Config, SimConfig
from armvision.errors import PerceptionError
from armvision.eval.objects import evaluate_objects, match_detections
from armvision.geometry import make_T, rot_x, transform_points
from armvision.perception.detection import (
    NO_CONTEXT,
    Detection,
    FrameContext,
    ObjectDetector,
    box_center_3d,
)
from armvision.perception.geometric import GeometricDetector
from armvision.perception.jetson import JetsonDetector
from armvision.perception.learned import OnnxDetector, class_ids_from_labels, read_labels

INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
ACCEPTANCE_SEEDS = list(range(20))


# --------------------------------------------------------------------------- simulated scenes


@pytest.fixture(scope="module")
def evaluation() -> dict:
    """One frame of each of 20 random scenes, detected and matched to the ground truth."""
    return evaluate_objects(Config(), ACCEPTANCE_SEEDS)


def test_recall_of_visible_objects(evaluation: dict) -> None:
    summary = evaluation["summary"]
    assert summary["scenes"] == 20
    assert summary["objects"] >= 20
    assert summary["object_recall"] >= 0.98, summary


def test_no_detections_on_the_robot_or_the_table(evaluation: dict) -> None:
    fps = {s["seed"]: s["false_positives"] for s in evaluation["per_scene"] if s["false_positives"]}
    assert evaluation["summary"]["object_false_positives"] == 0, fps


def test_bottle_or_cup_label(evaluation: dict) -> None:
    assert evaluation["summary"]["object_label_accuracy"] >= 0.95, evaluation["summary"]


def test_median_centre_error(evaluation: dict) -> None:
    assert evaluation["summary"]["object_center_error_mm_median"] <= 10.0, evaluation["summary"]


def test_sizes_and_boxes_match_the_truth(evaluation: dict) -> None:
    """Median height and radius errors of matched objects within 5 mm (a bottle's radius is
    measured on its liquid, 2 mm inside the wall); every box lies inside the image."""
    height_errors, radius_errors = [], []
    for scene in evaluation["per_scene"]:
        for det in scene["detections"]:
            x0, y0, x1, y1 = det["box"]
            assert 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480
            assert 0.0 <= det["score"] <= 1.0
        for obj in scene["objects"]:
            if obj["detection"] is not None:
                det = scene["detections"][obj["detection"]]
                height_errors.append(abs(det["height"] - obj["height"]))
                radius_errors.append(abs(det["radius"] - obj["radius"]))
    assert np.median(height_errors) < 0.005
    assert np.median(radius_errors) < 0.005


@pytest.fixture(scope="module")
def arm_world():
    """An empty table with the arm reaching down into the camera's view."""
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    world = SimWorld(Config(sim=SimConfig(min_objects=0, max_objects=0)), seed=3)
    arm = SimArm(world)
    camera = SimCamera(world)
    camera.start()
    yield world, arm, camera
    camera.stop()


@pytest.mark.parametrize(
    "pose",
    [(0.35, 0.0, 0.06, math.pi / 2), (0.4, 0.15, 0.1, math.pi / 3), (0.3, -0.2, 0.15, 0.0)],
)
def test_self_filter_removes_the_arm(arm_world, pose) -> None:
    """With the calibration and joint angles nothing is reported; without the angles the arm
    itself would be (so the filter, not luck, keeps it out)."""
    world, arm, camera = arm_world
    x, y, z, pitch = pose
    assert arm.set_ee_pose_components(x=x, y=y, z=z, roll=0.0, pitch=pitch)
    frame = camera.read()
    detector = GeometricDetector()
    T_base_cam = world.T_base_cam()
    assert detector.detect(frame, FrameContext(T_base_cam, arm.get_joint_positions())) == []
    assert len(detector.detect(frame, FrameContext(T_base_cam))) >= 1


def test_every_detector_satisfies_the_protocol() -> None:
    """The three detectors take the same call, detect(frame, context) with the context
    optional; the learned ones find the same with or without it."""
    for cls in (GeometricDetector, OnnxDetector, JetsonDetector):
        params = list(inspect.signature(cls.detect).parameters.values())
        assert [p.name for p in params] == ["self", "frame", "context"], cls.__name__
        assert params[2].default is NO_CONTEXT, cls.__name__
    net = FakeDetectNet([FakeDetectNetDetection(44, 0.9, 300, 200, 340, 300)])
    jetson = JetsonDetector(net=net, to_cuda=lambda image: image)
    for detector in (GeometricDetector(), jetson):
        assert isinstance(detector, ObjectDetector)
    frame = _flat_frame()
    plain = [d.to_dict() for d in jetson.detect(frame)]
    told = [d.to_dict() for d in jetson.detect(frame, FrameContext(np.eye(4), np.zeros(6)))]
    assert plain == told and [d["label"] for d in plain] == ["bottle"]


def test_the_pose_in_the_context_finds_every_object_at_its_true_place() -> None:
    """Scene seed 3 with the arm asleep: given the true camera pose and the encoder readings
    in the frame's context, the detector reports each true object with its label, its centre
    within 5 mm and its radius within 5 mm, and nothing else (the arm is filtered out)."""
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    with SimWorld(Config(), 3) as world, SimCamera(world) as camera:
        arm = SimArm(world)
        arm.go_to_sleep_pose()
        world.advance(0.3)
        frame = camera.read()
        context = FrameContext(world.T_base_cam(), arm.get_joint_positions())
        truth = world.ground_truth()
    found = GeometricDetector(seed=3).detect(frame, context)
    T_cam_base = np.linalg.inv(truth.T_base_cam)
    assert len(found) == len(truth.objects)
    for state in truth.objects:
        spec = state.spec
        center = transform_points(T_cam_base @ state.T_base_obj, [0.0, 0.0, spec.height / 2])
        det = min(found, key=lambda d: float(np.linalg.norm(d.center_cam - center)))
        assert det.label == spec.label
        assert np.linalg.norm(det.center_cam - center) < 0.005
        assert abs(det.radius - spec.radius) < 0.005


def test_a_camera_pose_that_is_no_pose_is_a_clear_error() -> None:
    with pytest.raises(PerceptionError, match="4x4"):
        GeometricDetector().detect(_flat_frame(), FrameContext(T_base_cam=np.eye(3)))


def test_empty_depth_is_a_clear_error() -> None:
    frame = RGBDFrame(
        np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640), np.float32), INTR, 0.0, 0
    )
    with pytest.raises(PerceptionError, match="depth"):
        GeometricDetector().detect(frame)


def test_matching_is_one_to_one_within_the_gate() -> None:
    truth = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    found = np.array([[0.099, 0.0, 1.0], [0.001, 0.0, 1.0], [0.5, 0.0, 1.0]])
    matches = match_detections(truth, found, 0.05)
    assert sorted((i, j) for i, j, _ in matches) == [(0, 1), (1, 0)]


# --------------------------------------------------------------------------- learned backends


def _flat_frame(z: float = 0.8) -> RGBDFrame:
    """A grey image and a wall of constant depth ``z`` (the container fronts in the tests)."""
    color = np.full((480, 640, 3), 128, np.uint8)
    depth = np.full((480, 640), z, np.float32)
    return RGBDFrame(color, depth, INTR, 0.0, 0)


def test_box_center_is_one_radius_behind_the_front_surface() -> None:
    frame = _flat_frame(0.8)
    box = (300.0, 200.0, 340.0, 300.0)
    center, radius, height = box_center_3d(INTR, frame.depth, box)
    assert radius == pytest.approx(20.0 * 0.8 / 615.0)
    assert height == pytest.approx(100.0 * 0.8 / 615.0)
    front = deproject(INTR, [[320.0, 250.0]], [0.8])[0]
    assert np.linalg.norm(center - front) == pytest.approx(radius)
    assert np.cross(center, front) == pytest.approx(np.zeros(3), abs=1e-12)  # same ray


def _constant_onnx_model(path, input_shape, input_type, outputs: dict[str, np.ndarray]) -> None:
    """Write an ONNX model whose outputs are the given constants (its input is ignored)."""
    onnx = pytest.importorskip("onnx")
    from onnx import helper, numpy_helper

    nodes, graph_outputs = [], []
    for name, value in outputs.items():
        nodes.append(
            helper.make_node(
                "Constant", [], [name], value=numpy_helper.from_array(value, name + "_value")
            )
        )
        dtype = helper.np_dtype_to_tensor_dtype(value.dtype)
        graph_outputs.append(helper.make_tensor_value_info(name, dtype, list(value.shape)))
    image = helper.make_tensor_value_info("image", input_type, list(input_shape))
    graph = helper.make_graph(nodes, "constant_detector", [image], graph_outputs)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def test_onnx_ssd_decoding_threshold_classes_and_nms(tmp_path) -> None:
    """A TF-style SSD export (boxes ymin, xmin, ymax, xmax normalised; classes; scores; count):
    two overlapping bottles (NMS keeps the better), a cup, a person (other class), a weak
    bottle (below 0.5) and a padding row past the count."""
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto

    boxes = np.array(
        [
            [
                [0.40, 0.45, 0.60, 0.52],  # bottle, 0.9
                [0.41, 0.45, 0.61, 0.52],  # the same bottle again, 0.8: suppressed
                [0.50, 0.20, 0.65, 0.28],  # cup, 0.7
                [0.10, 0.10, 0.90, 0.30],  # person, 0.95: not ours
                [0.50, 0.70, 0.60, 0.75],  # bottle, 0.3: below threshold
                [0.50, 0.80, 0.60, 0.85],  # beyond count
            ]
        ],
        np.float32,
    )
    classes = np.array([[44, 44, 47, 1, 44, 44]], np.float32)
    scores = np.array([[0.9, 0.8, 0.7, 0.95, 0.3, 0.99]], np.float32)
    count = np.array([5], np.float32)
    path = tmp_path / "ssd.onnx"
    _constant_onnx_model(
        path,
        [1, 480, 640, 3],
        TensorProto.UINT8,
        {
            "detection_boxes": boxes,
            "detection_classes": classes,
            "detection_scores": scores,
            "num_detections": count,
        },
    )
    detector = OnnxDetector(path)
    assert detector.kind == "ssd"
    found = sorted(detector.detect(_flat_frame()), key=lambda d: d.label)
    assert [d.label for d in found] == ["bottle", "cup"]
    bottle, cup = found
    assert bottle.score == pytest.approx(0.9)
    assert bottle.box == pytest.approx((0.45 * 640, 0.40 * 480, 0.52 * 640, 0.60 * 480))
    assert cup.box == pytest.approx((0.20 * 640, 0.50 * 480, 0.28 * 640, 0.65 * 480))
    assert bottle.center_cam[2] > 0.8  # behind the front surface


def test_onnx_yolov8_decoding_letterbox_and_nms(tmp_path) -> None:
    """A YOLOv8 head (1, 84, N) on a 640x640 letterboxed input: 640x480 frames are padded by
    80 rows top and bottom, so boxes move up by 80 px on the way back."""
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto

    n = 5
    out = np.zeros((1, 84, n), np.float32)
    #            cx,    cy,    w,    h, class id, score
    rows = [
        (320.0, 320.0, 40.0, 100.0, 39, 0.9),  # bottle
        (322.0, 321.0, 40.0, 100.0, 39, 0.6),  # duplicate bottle: suppressed
        (100.0, 300.0, 60.0, 60.0, 41, 0.8),  # cup
        (500.0, 300.0, 60.0, 60.0, 0, 0.99),  # person: not ours
        (550.0, 300.0, 30.0, 60.0, 41, 0.2),  # weak cup
    ]
    for k, (cx, cy, w, h, cls, score) in enumerate(rows):
        out[0, :4, k] = (cx, cy, w, h)
        out[0, 4 + cls, k] = score
    path = tmp_path / "yolov8.onnx"
    _constant_onnx_model(path, [1, 3, 640, 640], TensorProto.FLOAT, {"output0": out})
    labels = tmp_path / "coco.txt"
    names = ["thing"] * 80
    names[39], names[41] = "bottle", "cup"
    labels.write_text("\n".join(names) + "\n")
    detector = OnnxDetector(path, labels_path=labels)
    assert detector.kind == "yolov8"
    assert detector.class_ids == {"bottle": 39, "cup": 41}
    found = sorted(detector.detect(_flat_frame()), key=lambda d: d.label)
    assert [d.label for d in found] == ["bottle", "cup"]
    assert found[0].box == pytest.approx((300.0, 190.0, 340.0, 290.0))
    assert found[1].box == pytest.approx((70.0, 190.0, 130.0, 250.0))
    assert found[0].score == pytest.approx(0.9)


def test_onnx_detector_errors(tmp_path) -> None:
    with pytest.raises(PerceptionError, match="does not exist"):
        OnnxDetector(tmp_path / "missing.onnx")
    labels = tmp_path / "labels.txt"
    labels.write_text("background\nperson\n")
    with pytest.raises(PerceptionError, match="no bottle or cup"):
        class_ids_from_labels(read_labels(labels))


class FakeDetectNetDetection:
    """One result as jetson-inference's detectNet.Detection exposes it."""

    def __init__(self, class_id, confidence, left, top, right, bottom) -> None:
        self.ClassID = class_id
        self.Confidence = confidence
        self.Left, self.Top, self.Right, self.Bottom = left, top, right, bottom
        self.Width, self.Height = right - left, bottom - top


class FakeDetectNet:
    """A fake of jetson-inference's detectNet: Detect(cuda_img, width, height, overlay)."""

    def __init__(self, results) -> None:
        self.results = results
        self.calls = []

    def Detect(self, image, width=0, height=0, overlay="box,labels,conf"):
        self.calls.append((image.shape, width, height, overlay))
        return self.results


def test_jetson_detector_maps_coco_ids_and_locates_in_3d() -> None:
    """The network is a fake (no Jetson here); the mapping and 3-D centre are real."""
    net = FakeDetectNet(
        [
            FakeDetectNetDetection(44, 0.9, 300, 200, 340, 300),  # bottle
            FakeDetectNetDetection(47, 0.7, 100, 250, 160, 310),  # cup
            FakeDetectNetDetection(1, 0.99, 0, 0, 100, 400),  # person
        ]
    )
    detector = JetsonDetector(net=net, to_cuda=lambda image: image)
    found = detector.detect(_flat_frame(0.8))
    assert [d.label for d in found] == ["bottle", "cup"]
    assert net.calls == [((480, 640, 3), 640, 480, "none")]
    center, radius, _ = box_center_3d(INTR, _flat_frame(0.8).depth, (300, 200, 340, 300))
    assert found[0].center_cam == pytest.approx(center)
    assert found[0].radius == pytest.approx(radius)


def test_jetson_detector_without_jetson_inference_says_so(monkeypatch) -> None:
    for name in ("jetson_inference", "jetson_utils", "jetson", "jetson.inference"):
        monkeypatch.setitem(sys.modules, name, None)  # makes the import fail
    with pytest.raises(PerceptionError, match="Jetson"):
        JetsonDetector().detect(_flat_frame())


def test_detection_record_round_trips_to_json() -> None:
    det = Detection(
        "cup", 0.8, (1.0, 2.0, 3.0, 4.0), np.array([0.0, 0.1, 0.7]), np.ones(3), 0.5, 1.0
    )
    as_dict = det.to_dict()
    assert as_dict["label"] == "cup" and as_dict["center_cam"] == [0.0, 0.1, 0.7]


def test_geometric_detector_on_a_synthetic_cylinder() -> None:
    """A rendered-by-hand scene: table plane and one opaque cylinder (a cup), exact depth."""
    T_cam_table = make_T(rot_x(-math.radians(120.0)), [0.0, 0.2, 0.9])  # table z up, seen at 30°
    axis_cam = T_cam_table[:3, 2]
    foot_cam = transform_points(T_cam_table, [0.02, 0.15, 0.0])
    radius, height = 0.035, 0.1
    v, u = np.mgrid[0:480, 0:640]
    rays = np.stack([(u - INTR.ppx) / INTR.fx, (v - INTR.ppy) / INTR.fy, np.ones(u.shape)], -1)
    # Table: n.(t ray) + d = 0.
    n_table, d_table = axis_cam, -axis_cam @ T_cam_table[:3, 3]
    t_table = -d_table / (rays @ n_table)
    # Cylinder side: |(t ray - foot) x axis| = r, nearest root, 0 <= height coordinate <= h.
    a_perp = rays - (rays @ axis_cam)[..., None] * axis_cam
    f_perp = foot_cam - (foot_cam @ axis_cam) * axis_cam
    qa = np.einsum("...i,...i", a_perp, a_perp)
    qb = -2.0 * a_perp @ f_perp
    qc = f_perp @ f_perp - radius**2
    disc = qb * qb - 4 * qa * qc
    t_cyl = np.where(disc > 0, (-qb - np.sqrt(np.maximum(disc, 0))) / (2 * qa), np.inf)
    along = t_cyl * (rays @ axis_cam) - foot_cam @ axis_cam
    t_cyl[(along < 0) | (along > height)] = np.inf
    z = np.where(t_table > 0, t_table, np.inf)
    z = np.minimum(z, t_cyl)
    z[~np.isfinite(z)] = 0.0
    frame = RGBDFrame(np.full((480, 640, 3), 128, np.uint8), z.astype(np.float32), INTR, 0.0, 0)
    (det,) = GeometricDetector().detect(frame)
    true_center = foot_cam + 0.5 * height * axis_cam
    assert det.label == "cup"
    assert np.linalg.norm(det.center_cam - true_center) < 0.003
    assert det.radius == pytest.approx(radius, abs=0.002)
    assert det.height == pytest.approx(height, abs=0.004)
