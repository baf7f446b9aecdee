"""PoseCNN's YCB demo frames: armvision's detections against a published network's boxes.

The reference is PoseCNN's output (``posecnn_results/NNNNNN-color.png.mat``: ``rois`` rows
[batch, class, x1, y1, x2, y2, score]), not human truth; frames without a results file are
run but not scored. Network class i is YCB class ``TEST.CLASSES[i]`` of PoseCNN-PyTorch's
``ycb_object`` list, :data:`YCB_CLASSES` here. What armvision should call them
(:data:`EXPECTED`): the mustard and bleach bottles are bottles, the mug a cup; everything else
is a distractor, including the pitcher (a wide jug with a handle: neither a bottle to pour
from by its neck nor a cup) and the bowl. A detection matches the reference box it overlaps
best when that IoU is at least 0.3, or else the box its centre lies in. Per label, recall is
the share of reference objects of that label matched by a detection of that label, precision
the share of detections of that label matched to a reference object of that label.
``objects_reported`` counts the reference objects (every class) that some detection, of any
label, matched: what is reported at all, if only as an obstacle. Many YCB objects lie flat
(scissors, clamp, marker, banana), which the detector, looking for things standing on the
table, does not report.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from armvision.camera.frames import Intrinsics
from armvision.eval.real_scenes import box_centre, detect, read_depth, read_rgb
from armvision.perception.detection import Detection

SUBDIR = "posecnn_ycb_demo"
INTRINSICS = Intrinsics(640, 480, 618.0172729492188, 618.0033569335938, 312.376953125, 232.3753)
#: PoseCNN-PyTorch's network classes 0..20 (cfg TEST.CLASSES [0..18, 20, 21] of the YCB list).
YCB_CLASSES = (
    "__background__",
    "002_master_chef_can",
    "003_cracker_box",
    "004_sugar_box",
    "005_tomato_soup_can",
    "006_mustard_bottle",
    "007_tuna_fish_can",
    "008_pudding_box",
    "009_gelatin_box",
    "010_potted_meat_can",
    "011_banana",
    "019_pitcher_base",
    "021_bleach_cleanser",
    "024_bowl",
    "025_mug",
    "035_power_drill",
    "036_wood_block",
    "037_scissors",
    "040_large_marker",
    "052_extra_large_clamp",
    "061_foam_brick",
)
EXPECTED = {"006_mustard_bottle": "bottle", "021_bleach_cleanser": "bottle", "025_mug": "cup"}
MIN_IOU = 0.3


def iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes."""
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def read_rois(path: Path) -> list[tuple[str, tuple[float, float, float, float]]]:
    """(YCB class, box) per row of a PoseCNN results file's ``rois``."""
    from scipy.io import loadmat

    rois = np.atleast_2d(np.asarray(loadmat(str(path))["rois"], dtype=float))
    out = []
    for row in rois:
        k = int(row[1])
        name = YCB_CLASSES[k] if 0 <= k < len(YCB_CLASSES) else f"class_{k}"
        out.append((name, (float(row[2]), float(row[3]), float(row[4]), float(row[5]))))
    return out


def match(
    detections: list[Detection], refs: list[tuple[str, tuple[float, float, float, float]]]
) -> list[int]:
    """Per detection, the index of its reference box (see the module docstring), or -1."""
    out = []
    for d in detections:
        overlaps = [iou(d.box, box) for _, box in refs]
        u, v = box_centre(d.box)
        best = int(np.argmax(overlaps)) if refs else -1
        if best >= 0 and overlaps[best] < MIN_IOU:
            inside = [i for i, (_, b) in enumerate(refs) if b[0] <= u < b[2] and b[1] <= v < b[3]]
            best = max(inside, key=lambda i: overlaps[i]) if inside else -1
        out.append(best)
    return out


def _score(frames: list[dict[str, Any]]) -> dict[str, Any]:
    """Recall and precision per label, and what each distractor was called."""
    summary: dict[str, Any] = {}
    for label in ("bottle", "cup"):
        refs = [(f["frame"], i) for f in frames for i, r in enumerate(f["refs"]) if r[1] == label]
        hits = {(f["frame"], m) for f in frames for m, lab in f["pairs"] if lab == label}
        called = [lab for f in frames for _, lab in f["pairs"] if lab == label]
        right = sum(
            1
            for f in frames
            for m, lab in f["pairs"]
            if lab == label and m >= 0 and f["refs"][m][1] == label
        )
        summary[f"{label}_recall"] = f"{sum(r in hits for r in refs)}/{len(refs)}"
        summary[f"{label}_precision"] = f"{right}/{len(called)}"
    calls: dict[str, dict[str, int]] = {}
    for f in frames:
        for m, lab in f["pairs"]:
            if lab not in ("bottle", "cup"):
                continue  # reported as "other": no call
            name = f["refs"][m][0] if m >= 0 else "(no reference box)"
            if m < 0 or f["refs"][m][1] == "other":
                calls.setdefault(name, {"bottle": 0, "cup": 0})[lab] += 1
    summary["distractor_calls"] = calls
    # Every reference object a detection of any label matched: "other" is an obstacle the
    # tasks keep clear of, so an object reported as nothing is the one a grasp may hit.
    covered = {(f["frame"], m) for f in frames for m, _ in f["pairs"] if m >= 0}
    summary["objects_reported"] = f"{len(covered)}/{sum(len(f['refs']) for f in frames)}"
    return summary


def evaluate_posecnn(root: Path) -> dict[str, Any]:
    """The geometric detector on each frame, scored against PoseCNN's boxes where present."""
    folder = root / SUBDIR
    if not folder.is_dir():
        raise FileNotFoundError(f"no {SUBDIR}/ in {root}")
    frames: list[dict[str, Any]] = []
    unscored: list[dict[str, Any]] = []
    for color_path in sorted(folder.glob("*-color.png")):
        stem = color_path.name[: -len("-color.png")]
        found = detect(
            read_rgb(color_path), read_depth(folder / f"{stem}-depth.png", 0.001), INTRINSICS
        )
        results = folder / "posecnn_results" / f"{color_path.name}.mat"
        if not results.exists():
            unscored.append({"frame": stem, "detections": [d.label for d in found]})
            continue
        refs = [(name, EXPECTED.get(name, "other"), box) for name, box in read_rois(results)]
        matched = match(found, [(n, b) for n, _, b in refs])
        frames.append(
            {
                "frame": stem,
                "refs": [(n, lab) for n, lab, _ in refs],
                "pairs": [(m, d.label) for m, d in zip(matched, found)],
            }
        )
    if not frames:
        raise FileNotFoundError(f"no frame with a PoseCNN results file in {folder}")
    summary = _score(frames)
    summary["frames_scored"] = len(frames)
    summary["note"] = "reference = PoseCNN's output, not human truth; pitcher and bowl = other"
    return {
        "frames": [
            {
                "frame": f["frame"],
                "reference": [n for n, _ in f["refs"]],
                "detections": [
                    {"label": lab, "matched": f["refs"][m][0] if m >= 0 else None}
                    for m, lab in f["pairs"]
                ],
            }
            for f in frames
        ],
        "unscored": unscored,
        "label_map": {**EXPECTED, "every other class": "other (distractor)"},
        "summary": summary,
    }
