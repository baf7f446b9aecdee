"""The AprilTag library's regression photos: ids and corners against the library's own output.

Each ``NAME.txt`` holds one line per tag, ``ID, (x1 y1), (x2 y2), (x3 y3), (x4 y4)``: the corner
pixels the AprilTag library's test found (decimation 1, no edge refinement), in its corner
order, which pupil-apriltags (and so armvision's ``TagDetector``) reports too. They are the
library's answer, not independent truth: this checks armvision's detector set-up, not accuracy.
A found tag is matched to the expected tag of the same id with the nearest centre (within half
the tag's size); its corner error is the distance of each corner to the expected one.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics
from armvision.errors import ArmvisionError
from armvision.perception.tags import TagDetector

Array = NDArray[np.float64]
SUBDIR = "apriltag_test_images"
#: Corrected bits accepted: armvision's default (``TagDetector``).
MAX_HAMMING = 1
_LINE = re.compile(r"^\s*(\d+)\s*," + r"\s*\(\s*([-+0-9.eE]+)\s+([-+0-9.eE]+)\s*\)\s*,?" * 4)


def read_corner_file(path: Path) -> list[tuple[int, Array]]:
    """(id, (4, 2) corners) per line of an AprilTag regression ``.txt`` file."""
    tags = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        m = _LINE.match(line)
        if m is None:
            raise ArmvisionError(f"{path}:{number}: not 'ID, (x y), (x y), (x y), (x y)'")
        values = [float(v) for v in m.groups()[1:]]
        tags.append((int(m.group(1)), np.array(values).reshape(4, 2)))
    return tags


def match_corners(
    expected: list[tuple[int, Array]], found: list[tuple[int, Array]]
) -> tuple[int, list[float]]:
    """(expected tags matched, corner distances of the matches, px)."""
    taken: set[int] = set()
    errors: list[float] = []
    for tag_id, corners in found:
        centre = corners.mean(axis=0)
        best, best_d = -1, np.inf
        for i, (eid, ec) in enumerate(expected):
            d = float(np.linalg.norm(ec.mean(axis=0) - centre))
            size = float(np.linalg.norm(ec[0] - ec[2]))
            if eid == tag_id and i not in taken and d < best_d and d < 0.5 * size:
                best, best_d = i, d
        if best >= 0:
            taken.add(best)
            errors.extend(np.linalg.norm(expected[best][1] - corners, axis=1).tolist())
    return len(taken), errors


def evaluate_apriltag(root: Path) -> dict[str, Any]:
    """armvision's TagDetector (decimation 1, no edge refinement, like the test) per photo."""
    folder = root / SUBDIR
    if not folder.is_dir():
        raise FileNotFoundError(f"no {SUBDIR}/ in {root}")
    detector = TagDetector(refine_edges=False, refine_with_depth=False, max_hamming=MAX_HAMMING)
    rows: list[dict[str, Any]] = []
    all_errors: list[float] = []
    for txt in sorted(folder.glob("*.txt")):
        jpg = txt.with_suffix(".jpg")
        image = cv2.imread(str(jpg), cv2.IMREAD_GRAYSCALE) if jpg.exists() else None
        if image is None:
            continue
        expected = read_corner_file(txt)
        h, w = image.shape
        intr = Intrinsics(w, h, float(w), float(w), w / 2.0, h / 2.0)  # poses are not used
        found = [(d.id, d.corners) for d in detector.detect_image(image, intr)]
        matched, errors = match_corners(expected, found)
        all_errors += errors
        rows.append(
            {
                "image": txt.stem,
                "expected": len(expected),
                "found": len(found),
                "matched": matched,
                "ids_expected": sorted({e[0] for e in expected}),
                "corner_median_px": float(np.median(errors)) if errors else None,
                "corner_max_px": float(np.max(errors)) if errors else None,
            }
        )
    if not rows:
        raise FileNotFoundError(f"no image/.txt pairs in {folder}")
    return {
        "images": rows,
        "summary": {
            "tags_matched": f"{sum(r['matched'] for r in rows)}/{sum(r['expected'] for r in rows)}",
            "detections": sum(r["found"] for r in rows),
            "corner_median_px": round(float(np.median(all_errors)), 4) if all_errors else None,
            "corner_max_px": round(float(np.max(all_errors)), 3) if all_errors else None,
            "truth": "the AprilTag library's own regression corners, not independent truth",
        },
    }
