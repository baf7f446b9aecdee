"""``armvision eval real``: perception and calibration on public real RealSense data sets.

The data (see its INDEX.md) stays where it is: the licences allow evaluation only, so nothing
is copied into the project; the folder is given with ``--data``, ``$ARMVISION_REALDATA``, or
found at ``../shared/realdata``. Each part runs on its own: a missing or unreadable sub-folder
becomes ``{"skipped": why}`` and the other parts still run. Parts: ``visp``
(:mod:`~armvision.eval.real_visp`), ``apriltag`` (:mod:`~armvision.eval.real_apriltag`),
``cleargrasp`` and ``graspnet`` (:mod:`~armvision.eval.real_scenes`), ``posecnn``
(:mod:`~armvision.eval.real_posecnn`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armvision.config import Config
from armvision.errors import ArmvisionError, ConfigError
from armvision.eval.real_apriltag import evaluate_apriltag
from armvision.eval.real_posecnn import evaluate_posecnn
from armvision.eval.real_scenes import evaluate_cleargrasp, evaluate_graspnet
from armvision.eval.real_visp import evaluate_visp

DEFAULT_DIR = Path("..") / "shared" / "realdata"
ENV = "ARMVISION_REALDATA"
PARTS = ("visp", "apriltag", "cleargrasp", "posecnn", "graspnet")


def data_dir(given: str | None) -> Path:
    """The real-data folder: ``given``, else ``$ARMVISION_REALDATA``, else ../shared/realdata."""
    candidate = given or os.environ.get(ENV) or None
    path = Path(candidate) if candidate else DEFAULT_DIR
    if not path.is_dir():
        where = f"{path} is not a folder" if candidate else f"no {DEFAULT_DIR} here"
        raise ConfigError(f"real data: {where}; pass --data DIR (or set {ENV})")
    return path


def evaluate_real(root: Path, config: Config) -> dict[str, Any]:
    """Every part on the folder; a part that cannot run is ``{"skipped": why, "summary": ...}``."""
    runs: dict[str, Callable[[], dict[str, Any]]] = {
        "visp": lambda: evaluate_visp(root, config),
        "apriltag": lambda: evaluate_apriltag(root),
        "cleargrasp": lambda: evaluate_cleargrasp(root),
        "posecnn": lambda: evaluate_posecnn(root),
        "graspnet": lambda: evaluate_graspnet(root),
    }
    result: dict[str, Any] = {}
    for name in PARTS:
        try:
            result[name] = runs[name]()
        except (OSError, ArmvisionError, KeyError, ValueError, IndexError) as exc:
            why = str(exc) or type(exc).__name__
            result[name] = {"skipped": why, "summary": {"skipped": why}}
    return result


def _fmt(value: Any, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _visp_lines(part: dict[str, Any]) -> list[str]:
    lines = [
        f"ViSP eye-to-hand (Franka + RealSense): tag found in {part['summary']['images_with_tag']}"
        " images; camera pose vs ViSP's published rMc",
        f"  tag offset: {part['tag_offset_handling']}",
        f"  {'method':<16}{'tag offset':<26}{'cam mm':>8}{'cam deg':>8}{'rms mm':>8}"
        f"  offset used/estimated (mm)",
    ]
    for r in part["methods"]:
        if "error" in r:
            lines.append(f"  {r['method']:<16}{r['prior']:<26}  not run: {r['error']}")
            continue
        lines.append(
            f"  {r['method']:<16}{r['prior']:<26}{r['camera_error_mm']:8.1f}"
            f"{r['camera_error_deg']:8.2f}{r['residual_rms_mm']:8.1f}  {r['tag_offset_mm']}"
        )
    lines.append(f"  ViSP's own mean residual: {part['summary']['published_residual']}")
    return lines


def _apriltag_lines(part: dict[str, Any]) -> list[str]:
    lines = [
        "AprilTag regression photos (expected = the library's own corners)",
        f"  {'image':<28}{'expected':>9}{'found':>7}{'matched':>9}{'median px':>11}{'max px':>8}",
    ]
    for r in part["images"]:
        lines.append(
            f"  {r['image']:<28}{r['expected']:>9}{r['found']:>7}{r['matched']:>9}"
            f"{_fmt(r['corner_median_px'], '11.4f')}{_fmt(r['corner_max_px'], '8.3f')}"
        )
    s = part["summary"]
    lines.append(
        f"  all: {s['tags_matched']} tags, corners median {s['corner_median_px']} px,"
        f" max {s['corner_max_px']} px"
    )
    return lines


def _cleargrasp_lines(part: dict[str, Any]) -> list[str]:
    lines = [
        "ClearGrasp (clear bottles/cups, raw D435 depth): detections on/off the object mask",
        f"  {'frame':<12}{'mask comps':>11}{'detections':>11}{'on mask':>9}{'off mask':>9}  labels",
    ]
    for r in part["frames"]:
        lines.append(
            f"  {r['frame']:<12}{r['mask_components']:>11}{r['detections']:>11}"
            f"{r['on_mask']:>9}{r['off_mask']:>9}  {', '.join(r['labels']) or '-'}"
        )
    lines.append(f"  {part['summary']['note']}")
    depth = part["clear_depth"]
    if isinstance(depth, dict):
        depth = ", ".join(
            f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in depth.items()
        )
    lines.append(f"  clear-wall depth on the mask (eval.clear_depth): {depth}")
    return lines


def _posecnn_lines(part: dict[str, Any]) -> list[str]:
    s = part["summary"]
    lines = [
        "PoseCNN YCB frames (reference = PoseCNN's boxes; bottle = mustard, bleach; cup = mug;"
        " pitcher, bowl, rest = other)",
        f"  bottle recall {s['bottle_recall']}, precision {s['bottle_precision']};"
        f" cup recall {s['cup_recall']}, precision {s['cup_precision']}"
        f" ({s['frames_scored']} frames scored)",
        f"  reference objects reported with any label (other: an obstacle):"
        f" {s['objects_reported']}",
        "  distractors called bottle / cup:",
    ]
    for name, calls in s["distractor_calls"].items():
        lines.append(f"    {name:<24}{calls['bottle']:>3} bottle {calls['cup']:>3} cup")
    for u in part["unscored"]:
        lines.append(f"  frame {u['frame']}: no PoseCNN results, detections {u['detections']}")
    return lines


def _graspnet_lines(part: dict[str, Any]) -> list[str]:
    s = part["summary"]
    lines = [
        f"GraspNet top-down clutter: {s['detections']} detections, {s['true_objects']} true"
        f" objects ({s['note']})"
    ]
    for r in part["detections"]:
        lines.append(
            f"  {r['label']:<7} at {r['center_cam_m']} m: {r['distance_mm']:.0f} mm from"
            f" object {r['nearest_object_id']}"
        )
    return lines


def format_real(result: dict[str, Any]) -> list[str]:
    """The readable tables, one block per part."""
    formatters = {
        "visp": _visp_lines,
        "apriltag": _apriltag_lines,
        "cleargrasp": _cleargrasp_lines,
        "posecnn": _posecnn_lines,
        "graspnet": _graspnet_lines,
    }
    lines: list[str] = []
    for name in PARTS:
        part = result[name]
        if "skipped" in part:
            lines.append(f"{name}: skipped: {part['skipped']}")
        else:
            lines.extend(formatters[name](part))
        lines.append("")
    return lines[:-1]
