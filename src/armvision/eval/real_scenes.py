"""armvision's geometric detector on real RealSense frames: ClearGrasp and GraspNet.

Both run ``GeometricDetector().detect(frame, FrameContext())``: no calibration, so the
detector finds the table plane on its own. ClearGrasp (4 frames of clear bottles and cups, a
mask of the transparent objects, no per-object truth) counts the detections whose box centre
lies on the mask against those off it; the mask's connected components (over
:data:`MIN_COMPONENT_PX` pixels) stand in for the number of objects, which is rough (touching
objects merge, a lying bottle split by a highlight counts twice). GraspNet (one top-down frame,
true 6-D poses of 9 objects lying flat) gives each detection's distance to the nearest true
object centre; the detector expects upright containers, so little is expected there.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.errors import ArmvisionError
from armvision.perception.detection import Detection, FrameContext
from armvision.perception.geometric import GeometricDetector

CLEARGRASP = "cleargrasp_real_d435"
GRASPNET = "graspnet_example_realsense"
CLEARGRASP_INTRINSICS = Intrinsics(1280, 720, 921.0, 921.0, 642.0, 359.0)
MIN_COMPONENT_PX = 500


def _cv2() -> Any:
    """cv2 with EXR reading on (the flag must be set before OpenCV is first imported)."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    return cv2


def read_rgb(path: Path) -> NDArray[np.uint8]:
    """An 8-bit colour image as RGB."""
    cv2 = _cv2()
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ArmvisionError(f"cannot read {path}")
    return np.ascontiguousarray(image[:, :, ::-1])


def read_depth(path: Path, scale: float = 1.0) -> NDArray[np.float32]:
    """Depth in metres from an EXR (metres, first channel) or 16-bit PNG (times ``scale``).

    NaN and inf become 0, armvision's "no measurement".
    """
    cv2 = _cv2()
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ArmvisionError(f"cannot read {path} (EXR needs OPENCV_IO_ENABLE_OPENEXR=1)")
    depth = (raw[:, :, 0] if raw.ndim == 3 else raw).astype(np.float32) * np.float32(scale)
    depth[~np.isfinite(depth)] = 0.0
    return depth


def detect(
    color: NDArray[np.uint8], depth: NDArray[np.float32], intr: Intrinsics
) -> list[Detection]:
    """The geometric detector on one frame, nothing known about the camera."""
    frame = RGBDFrame(color, depth, intr, 0.0, 0)
    return GeometricDetector().detect(frame, FrameContext())


def box_centre(box: tuple[float, float, float, float]) -> tuple[int, int]:
    """The centre pixel (column, row) of an (x0, y0, x1, y1) box."""
    return int((box[0] + box[2]) / 2), int((box[1] + box[3]) / 2)


def mask_components(mask: NDArray[np.bool_], min_px: int = MIN_COMPONENT_PX) -> int:
    """Connected components (8-connected) of a mask with at least ``min_px`` pixels."""
    cv2 = _cv2()
    _, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return int(np.sum(stats[1:, cv2.CC_STAT_AREA] >= min_px))


def on_mask(mask: NDArray[np.bool_], detections: list[Detection]) -> tuple[int, int]:
    """(detections whose box centre lies on the mask, those off it)."""
    inside = 0
    for d in detections:
        u, v = box_centre(d.box)
        if 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1] and mask[v, u]:
            inside += 1
    return inside, len(detections) - inside


def _clear_depth_row(folder: Path) -> Any:
    """The pooled scalars of ``armvision.eval.clear_depth.measure_real``, when it exists."""
    try:
        from armvision.eval.clear_depth import measure_real
    except ImportError:
        return "not available"
    try:
        pooled = measure_real(folder)["pooled"]
    except (ArmvisionError, OSError, KeyError, ValueError) as exc:
        return f"failed: {exc}"
    return {k: v for k, v in pooled.items() if isinstance(v, (int, float)) or v is None}


def evaluate_cleargrasp(root: Path) -> dict[str, Any]:
    """Bottle/cup detections on and off the transparent-object mask, per frame."""
    folder = root / CLEARGRASP
    if not folder.is_dir():
        raise FileNotFoundError(f"no {CLEARGRASP}/ in {root}")
    rows = []
    for mask_path in sorted(folder.glob("*-mask.png")):
        stem = mask_path.name[: -len("-mask.png")]
        color = read_rgb(folder / f"{stem}-transparent-rgb-img.jpg")
        depth = read_depth(folder / f"{stem}-transparent-depth-img.exr")
        mask = _cv2().imread(str(mask_path), 0) > 127
        found = detect(color, depth, CLEARGRASP_INTRINSICS)
        inside, outside = on_mask(mask, found)
        rows.append(
            {
                "frame": stem,
                "mask_components": mask_components(mask),
                "detections": len(found),
                "on_mask": inside,
                "off_mask": outside,
                "labels": [d.label for d in found],
            }
        )
    if not rows:
        raise FileNotFoundError(f"no *-mask.png frames in {folder}")
    return {
        "frames": rows,
        "clear_depth": _clear_depth_row(folder),
        "summary": {
            "frames": len(rows),
            "mask_components": sum(r["mask_components"] for r in rows),
            "detections": sum(r["detections"] for r in rows),
            "on_mask": sum(r["on_mask"] for r in rows),
            "off_mask": sum(r["off_mask"] for r in rows),
            "note": "no per-object truth: mask components are a rough object count",
        },
    }


def evaluate_graspnet(root: Path) -> dict[str, Any]:
    """Each detection's distance to the nearest true object centre (GraspNet's meta.mat)."""
    from scipy.io import loadmat

    folder = root / GRASPNET
    if not folder.is_dir():
        raise FileNotFoundError(f"no {GRASPNET}/ in {root}")
    meta = loadmat(str(folder / "meta.mat"))
    K = np.asarray(meta["intrinsic_matrix"], dtype=float)
    factor = float(np.ravel(meta["factor_depth"])[0])
    poses = np.asarray(meta["poses"], dtype=float)  # (3, 4, N), camera frame
    ids = [int(i) for i in np.ravel(meta["cls_indexes"])]
    centres = poses[:, 3, :].T  # (N, 3) object origins
    color = read_rgb(folder / "color.png")
    depth = read_depth(folder / "depth.png", 1.0 / factor)
    h, w = depth.shape
    found = detect(color, depth, Intrinsics(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    rows = []
    for d in found:
        gaps = np.linalg.norm(centres - d.center_cam, axis=1)
        k = int(np.argmin(gaps))
        rows.append(
            {
                "label": d.label,
                "center_cam_m": np.round(d.center_cam, 3).tolist(),
                "nearest_object_id": ids[k],
                "distance_mm": round(1000 * float(gaps[k]), 1),
            }
        )
    return {
        "objects": [
            {"id": i, "center_cam_m": np.round(c, 3).tolist()} for i, c in zip(ids, centres)
        ],
        "detections": rows,
        "summary": {
            "true_objects": len(ids),
            "detections": len(rows),
            "within_30mm": sum(r["distance_mm"] <= 30 for r in rows),
            "median_distance_mm": float(np.median([r["distance_mm"] for r in rows]))
            if rows
            else None,
            "note": "objects lie flat; the detector looks for upright containers",
        },
    }
