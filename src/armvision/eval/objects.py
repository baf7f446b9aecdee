"""Bottle and cup detection accuracy in simulation: recall, false positives, labels, 3-D centres.

For each seed the simulator builds a scene of 1-4 bottles and cups (``sim.min_objects`` ..
``sim.max_objects``) with the camera placed at random around the configured placement
(``sim.randomize_camera``), the arm at its sleep pose (or ``arm_pose="home"``), and renders one
noisy RGB-D frame. :class:`GeometricDetector` runs on it (or the detector ``perception.detector``
configures: a user's ONNX model, alone or in the hybrid, is measured the same way) with the
self-filter given the simulator's true ``T_base_cam`` and the arm's encoder readings
(``SimArm.get_joint_positions``, bias and noise included): at this stage of the pipeline the
calibration is not known, so the evaluation stands in the true camera pose for the
calibration that will provide it.

Truth: an object's centre is the point on its axis half-way up, ``T_base_obj @ (0, 0, H/2)``,
mapped into the camera frame with the true ``T_base_cam``. Detections are matched to objects by
the Hungarian method on 3-D centre distance (scipy's ``linear_sum_assignment``), pairs farther
apart than ``match_gate_m`` not counting.

Visible: an object counts for recall when at least ``min_visible_fraction`` (30 %) of its
camera-facing surface is in the image and unoccluded. The surface is sampled on the object's
true shape (a cup's wall; a bottle's body, neck and cap); a sample is seen when it projects
inside the image and no opaque surface lies in front of it in the simulator's exact depth
render (MuJoCo writes no depth for clear bottle walls, so an object behind a clear bottle is
seen, as a depth camera sees it). A detection matched to an object that is not visible is
neither a hit nor a false positive; every other unmatched detection (on the robot, the table,
a phantom) is a false positive.

Distractors (truth label ``other``: cans, boxes, bowls, ... in the cluttered profile) are
matched like the rest. Only detections labelled bottle or cup are calls (tasks act on those
alone): one matched to a distractor is a false positive and the distractor was "called" a
bottle or cup; a detection labelled ``other`` is never a false positive (on a distractor it is
right), and on a bottle or cup it is a miss for recall. The summary gives, besides the overall
figures, per label (``bottle``, ``cup``) the recall (visible objects found with their label)
and the precision (detections of that label that were right, those matched to an object out of
view excepted), ``distractor_rate`` (the share of visible distractor appearances reported as
bottle or cup) and ``found_by_kind``: for every object kind (bottle and cup families,
distractor kinds) how often a visible one was matched by a detection of any label (``found``,
``rate``) and by one labelled bottle or cup (``called``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal, NotRequired, TypedDict

import numpy as np
from scipy.optimize import linear_sum_assignment

from armvision.camera.frames import Intrinsics, project
from armvision.config import Config
from armvision.geometry import inv_T, transform_points
from armvision.perception.detection import Detection, FrameContext
from armvision.perception.factory import object_detector
from armvision.perception.geometric import GeometricDetector

Array = np.ndarray

#: Fraction of the radius a bottle's neck and cap have (sim.world builds them 0.42 r and
#: 0.47 r wide); 0.45 is close enough to sample them.
_NECK_RADIUS_FRACTION = 0.45


def surface_samples_obj(
    label: str, radius: float, height: float, body_height: float, n_around: int = 48
) -> tuple[Array, Array]:
    """Points on an object's side wall and their outward normals, object frame (z up), (N, 3).

    Bottles: the body cylinder to ``body_height`` and the neck and cap above it at ~0.45 x
    the radius. Everything else (cups, distractors): one cylinder of ``radius`` from 0 to
    ``height``, the object's bounding cylinder.
    """
    angles = np.linspace(0.0, 2.0 * math.pi, n_around, endpoint=False)
    rings: list[tuple[float, Array]] = []
    if label == "bottle":
        rings += [(radius, z) for z in np.linspace(0.005, body_height - 0.005, 16)]
        rings += [
            (_NECK_RADIUS_FRACTION * radius, z)
            for z in np.linspace(body_height + 0.005, height - 0.003, 6)
        ]
    else:
        rings += [(radius, z) for z in np.linspace(0.005, height - 0.003, 16)]
    points, normals = [], []
    for r, z in rings:
        ring_n = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
        points.append(ring_n * r + [0.0, 0.0, z])
        normals.append(ring_n)
    return np.concatenate(points), np.concatenate(normals)


def visible_fraction(
    intr: Intrinsics,
    T_cam_obj: Array,
    points_obj: Array,
    normals_obj: Array,
    true_depth: Array,
    tolerance_m: float = 0.005,
) -> float:
    """Fraction of the camera-facing samples that are in the image and not behind a surface.

    ``true_depth`` is the exact z-depth render of the whole scene (H, W); a sample is hidden
    when the render is nearer than the sample by more than ``tolerance_m``.
    """
    p_cam = transform_points(T_cam_obj, points_obj)
    n_cam = normals_obj @ T_cam_obj[:3, :3].T
    facing = np.einsum("ij,ij->i", n_cam, -p_cam) > 0.0
    if not facing.any():
        return 0.0
    p_cam = p_cam[facing]
    uv = np.rint(project(intr, p_cam))
    ok = np.asarray(np.isfinite(uv).all(axis=1))
    ok[ok] &= (
        (uv[ok, 0] >= 0) & (uv[ok, 0] < intr.width) & (uv[ok, 1] >= 0) & (uv[ok, 1] < intr.height)
    )
    seen = np.zeros(len(p_cam), dtype=bool)
    cols, rows = uv[ok, 0].astype(int), uv[ok, 1].astype(int)
    seen[ok] = true_depth[rows, cols] >= p_cam[ok, 2] - tolerance_m
    return float(seen.mean())


class _ObjectRecord(TypedDict):
    """One true object of a scene, as reported in ``per_scene``."""

    name: str
    kind: str
    truth: str
    radius: float
    height: float
    center_cam: Array
    visible_fraction: float
    visible: bool
    detection: NotRequired[int | None]
    center_error_mm: NotRequired[float | None]
    label: NotRequired[str | None]


def match_detections(
    centers_true: Array, centers_detected: Array, gate_m: float
) -> list[tuple[int, int, float]]:
    """Hungarian matching on 3-D distance: (true index, detection index, distance) within gate.

    Pairs beyond the gate cost the same large amount, so that a far detection (a phantom)
    cannot pull the assignment of the near ones off their objects."""
    if len(centers_true) == 0 or len(centers_detected) == 0:
        return []
    cost = np.linalg.norm(centers_true[:, None, :] - centers_detected[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.where(cost < gate_m, cost, 1e6))
    return [(int(i), int(j), float(cost[i, j])) for i, j in zip(rows, cols) if cost[i, j] < gate_m]


def _render(config: Config, seed: int, arm_pose: str) -> tuple[Any, Array, Any, Array]:
    """One scene's frame, its exact depth render, the ground truth and the encoder readings."""
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    with SimWorld(config, seed) as world, SimCamera(world) as camera:
        arm = SimArm(world)
        # The world starts with the arm asleep, as the real arm powers up.
        if arm_pose == "home" and not arm.go_to_home_pose():
            raise RuntimeError(f"seed {seed}: the arm could not reach home: {arm.last_error}")
        world.advance(0.1)  # let the objects settle on the table
        frame = camera.read()
        true_depth = camera.render_true_depth()
        truth = world.ground_truth()
        q_encoders = arm.get_joint_positions()
    return frame, true_depth, truth, q_encoders


def _true_objects(
    frame: Any, true_depth: Array, truth: Any, min_visible_fraction: float
) -> list[_ObjectRecord]:
    """The scene's true objects: centre in the camera frame and how visible each is."""
    T_cam_base = inv_T(truth.T_base_cam)
    objects: list[_ObjectRecord] = []
    for state in truth.objects:
        spec = state.spec
        T_cam_obj = T_cam_base @ state.T_base_obj
        points, normals = surface_samples_obj(
            spec.label, spec.radius, spec.height, spec.body_height
        )
        fraction = visible_fraction(frame.intrinsics, T_cam_obj, points, normals, true_depth)
        objects.append(
            {
                "name": spec.name,
                "kind": spec.kind,
                "truth": spec.label,
                "radius": spec.radius,
                "height": spec.height,
                "center_cam": transform_points(T_cam_obj, [0.0, 0.0, spec.height / 2.0]),
                "visible_fraction": fraction,
                "visible": fraction >= min_visible_fraction,
            }
        )
    return objects


#: The labels a detector reports; every other true object is a distractor (truth "other").
CONTAINERS = ("bottle", "cup")


@dataclasses.dataclass
class _LabelCounts:
    """One label's tallies: visible true objects, those found with this label, detections
    reported with this label (those matched to an object out of view excepted), and how many
    of them were right."""

    visible: int = 0
    found: int = 0
    reported: int = 0
    correct: int = 0


@dataclasses.dataclass
class _Counts:
    """The tallies over the scenes. Bottles and cups count for recall and the centre error;
    a distractor matched by a bottle or cup detection is its false positive and a call."""

    errors_mm: list[float] = dataclasses.field(default_factory=list)
    visible: int = 0
    hits: int = 0
    false_positives: int = 0
    label_ok: int = 0
    matched: int = 0
    objects: int = 0
    labels: dict[str, _LabelCounts] = dataclasses.field(
        default_factory=lambda: {label: _LabelCounts() for label in CONTAINERS}
    )
    #: per object kind (family or distractor): [visible, matched by any detection, matched by
    #: a bottle or cup detection]
    kinds: dict[str, list[int]] = dataclasses.field(default_factory=dict)
    distractors_visible: int = 0
    distractors_called: int = 0


def _score_scene(
    objects: list[_ObjectRecord], detections: list[Detection], gate_m: float, counts: _Counts
) -> list[int]:
    """Match the detections to the objects (filling in each object's match) and count; the
    indices of the false positives (bottle or cup detections unmatched, or matched to a
    distractor)."""
    centers_true = np.array([o["center_cam"] for o in objects]).reshape(-1, 3)
    centers_det = np.array([d.center_cam for d in detections]).reshape(-1, 3)
    matches = match_detections(centers_true, centers_det, gate_m)
    matched_obj = {i: (j, dist) for i, j, dist in matches}
    owner = {j: i for i, j, _ in matches}
    for i, obj in enumerate(objects):
        match = matched_obj.get(i)
        obj["detection"] = None if match is None else match[0]
        obj["center_error_mm"] = None if match is None else 1e3 * match[1]
        obj["label"] = None if match is None else detections[match[0]].label
        _count_object(obj, match, detections, counts)
    scene_fp = []
    for j, det in enumerate(detections):
        k = owner.get(j)
        truth = None if k is None else objects[k]
        if det.label in CONTAINERS and (truth is None or truth["truth"] not in CONTAINERS):
            scene_fp.append(j)
        if truth is not None and truth["truth"] in CONTAINERS and not truth["visible"]:
            continue  # an object out of view: neither right nor wrong
        if det.label in counts.labels:
            tally = counts.labels[det.label]
            tally.reported += 1
            tally.correct += int(truth is not None and truth["truth"] == det.label)
    counts.false_positives += len(scene_fp)
    counts.objects += len(objects)
    return scene_fp


def _count_object(
    obj: _ObjectRecord, match: tuple[int, float] | None, detections: list[Detection], c: _Counts
) -> None:
    """One true object's part of the tallies."""
    called = match is not None and detections[match[0]].label in CONTAINERS
    kind = c.kinds.setdefault(obj["kind"], [0, 0, 0])
    if obj["visible"]:
        kind[0] += 1
        kind[1] += int(match is not None)
        kind[2] += int(called)
    if obj["truth"] not in CONTAINERS:
        if obj["visible"]:
            c.distractors_visible += 1
            c.distractors_called += int(called)
        return
    tally = c.labels[obj["truth"]]
    if obj["visible"]:
        c.visible += 1
        tally.visible += 1
        if match is not None and called:
            c.hits += 1
            tally.found += int(detections[match[0]].label == obj["truth"])
    if match is not None:
        j, dist = match
        c.matched += 1
        c.errors_mm.append(1e3 * dist)
        c.label_ok += int(detections[j].label == obj["truth"])


def _ratio(num: int, den: int) -> float:
    return num / den if den else float("nan")


def _summary(counts: _Counts, scenes: int) -> dict[str, Any]:
    errors_mm = counts.errors_mm
    summary: dict[str, Any] = {
        "object_recall": _ratio(counts.hits, counts.visible),
        "object_false_positives": counts.false_positives,
        "object_label_accuracy": _ratio(counts.label_ok, counts.matched),
        "object_center_error_mm_median": (
            float(np.median(errors_mm)) if errors_mm else float("nan")
        ),
        "object_center_error_mm_p90": (
            float(np.percentile(errors_mm, 90)) if errors_mm else float("nan")
        ),
        "scenes": scenes,
        "objects": counts.objects,
        "objects_visible": counts.visible,
        "objects_matched": counts.matched,
    }
    for label, tally in counts.labels.items():
        summary[f"object_recall_{label}"] = _ratio(tally.found, tally.visible)
        summary[f"object_precision_{label}"] = _ratio(tally.correct, tally.reported)
    summary["distractor_rate"] = _ratio(counts.distractors_called, counts.distractors_visible)
    summary["distractors_visible"] = counts.distractors_visible
    summary["found_by_kind"] = {
        kind: {"visible": seen, "found": found, "called": called, "rate": _ratio(found, seen)}
        for kind, (seen, found, called) in sorted(counts.kinds.items())
    }
    return summary


def evaluate_objects(
    config: Config,
    seeds: list[int],
    *,
    randomize_camera: bool = True,
    arm_pose: Literal["sleep", "home"] = "sleep",
    match_gate_m: float = 0.05,
    min_visible_fraction: float = 0.3,
    detector_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Detection figures over one frame per seed; see the module docstring for the rules.

    Returns {"summary": {object_recall, object_false_positives, object_label_accuracy,
    object_center_error_mm_median, object_recall_bottle, object_recall_cup,
    object_precision_bottle, object_precision_cup, distractor_rate, found_by_kind, scenes,
    objects, ...}, "per_scene": [...]}.
    """
    config = dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, randomize_camera=randomize_camera)
    )
    # The configured detector (a user's network, alone or in the hybrid), loaded once; the
    # geometric one is made per scene with its seed, as the figures in the README were.
    configured = (
        None if config.perception.detector == "geometric" else object_detector(config.perception)
    )
    per_scene: list[dict[str, Any]] = []
    counts = _Counts()
    for seed in seeds:
        frame, true_depth, truth, q_encoders = _render(config, seed, arm_pose)
        detector = configured or GeometricDetector(seed=seed, **(detector_kwargs or {}))
        context = FrameContext(T_base_cam=truth.T_base_cam, joint_positions=q_encoders)
        detections: list[Detection] = detector.detect(frame, context)
        objects = _true_objects(frame, true_depth, truth, min_visible_fraction)
        scene_fp = _score_scene(objects, detections, match_gate_m, counts)
        per_scene.append(
            {
                "seed": int(seed),
                "objects": [
                    {**o, "center_cam": [float(v) for v in o["center_cam"]]} for o in objects
                ],
                "detections": [d.to_dict() for d in detections],
                "false_positives": scene_fp,
            }
        )
    summary = {**_summary(counts, len(seeds)), "detector": config.perception.detector}
    return {"summary": summary, "per_scene": per_scene}
