"""Objects standing against each other: how often the geometric detector finds each one.

Random pairs on the synthetic bench of the detector tests (exact depth of vertical cylinders
and boxes on a table, known by construction; camera 35-60 cm over the table, pitched 25-50
degrees down): a container (radius 25-45 mm, 7-25 cm tall, open or lidded) and, touching it
on a random side (up to 4 mm apart), either another cylinder (radius 25-70 mm) or a box
(5-20 cm wide, 6 cm deep, turned up to 0.5 rad). A cylinder counts as found when a detection's
foot lies within 5 mm of its own with the radius within 4 mm; a box when a detection's foot
lies within the box's half-diagonal of its centre. "Both": each found by a detection of its
own. "Extra": detections whose foot lies on neither object (within its radius or
half-diagonal, and 1 cm). The same pairs with the split of touching objects turned off
(``split_draws=0``) show what it adds.

    python benchmarks/bench_touching.py [--pairs 150] [--seed 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.perception.helpers import TiltedBench

from armvision.perception.detection import Detection
from armvision.perception.geometric import GeometricDetector


def _foot_off(bench: TiltedBench, det: Detection, foot: np.ndarray) -> float:
    """How far (m, along the table) ``det``'s foot is from ``foot``."""
    off = det.center_cam - foot
    return float(np.linalg.norm(off - (off @ bench.up) * bench.up))


def _pair(rng: np.random.Generator) -> tuple[TiltedBench, np.ndarray, dict, dict]:
    """A random bench, its depth image of two touching objects, and the two objects."""
    bench = TiltedBench(pitch_deg=float(rng.uniform(25, 50)), height=float(rng.uniform(0.35, 0.6)))
    foot = bench.table_point(float(rng.uniform(150, 490)), float(rng.uniform(250, 420)))
    toward = -(foot - (foot @ bench.up) * bench.up)
    toward /= np.linalg.norm(toward)
    side = np.cross(bench.up, toward)
    turn = rng.uniform(-1.2, 1.2)
    away = np.cos(turn) * side + np.sin(turn) * toward
    a = {"foot": foot, "radius": float(rng.uniform(0.025, 0.045))}
    depth_a = bench.vessel(foot, a["radius"], float(rng.uniform(0.07, 0.25)), bool(rng.integers(2)))
    gap = float(rng.uniform(0.0, 0.004))
    if rng.integers(3) == 0:
        radius = float(rng.uniform(0.025, 0.07))
        b = {
            "kind": "cylinder",
            "radius": radius,
            "foot": foot + away * (a["radius"] + radius + gap),
        }
        height = float(rng.uniform(0.05, 0.25))
        depth_b = bench.vessel(b["foot"], radius, height, bool(rng.integers(2)))
    else:
        width, height = float(rng.uniform(0.05, 0.2)), float(rng.uniform(0.04, 0.2))
        b = {"kind": "box", "reach": float(np.hypot(width, 0.06)) / 2.0}
        b["foot"] = foot + away * (a["radius"] + 0.03 + gap)
        depth_b = bench.capped_box(
            b["foot"], (width, 0.06, height), (0.0, height), turn=float(rng.uniform(-0.5, 0.5))
        )
    near = np.minimum(
        np.where(depth_a > 0, depth_a, np.inf), np.where(depth_b > 0, depth_b, np.inf)
    )
    return bench, np.where(np.isfinite(near), near, 0.0), a, b


def _found(bench: TiltedBench, found: list[Detection], obj: dict) -> int | None:
    """Index of the detection that finds ``obj`` (see the module docstring), or None."""
    for k, det in enumerate(found):
        off = _foot_off(bench, det, obj["foot"])
        if "reach" in obj:
            if off < obj["reach"]:
                return k
        elif off < 0.005 and abs(det.radius - obj["radius"]) < 0.004:
            return k
    return None


def _near(bench: TiltedBench, det: Detection, obj: dict) -> bool:
    """Whether ``det``'s foot lies on ``obj`` (within its radius or half-diagonal, and 1 cm)."""
    return _foot_off(bench, det, obj["foot"]) < obj.get("reach", obj.get("radius", 0.0)) + 0.01


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=150)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    detectors = {
        "split (default)": GeometricDetector(),
        "no split": GeometricDetector(split_draws=0),
    }
    rows: dict[tuple[str, str], list[int]] = {}
    rng = np.random.default_rng(args.seed)
    for _ in range(args.pairs):
        bench, depth, a, b = _pair(rng)
        frame = bench.frame(depth)
        for name, detector in detectors.items():
            found = detector.detect(frame)
            hit_a, hit_b = _found(bench, found, a), _found(bench, found, b)
            row = rows.setdefault((b["kind"], name), [0, 0, 0, 0, 0])
            row[0] += 1
            row[1] += hit_a is not None
            row[2] += hit_b is not None and hit_b != hit_a
            row[3] += hit_a is not None and hit_b is not None and hit_b != hit_a
            row[4] += sum(not (_near(bench, det, a) or _near(bench, det, b)) for det in found)
    print(f"Touching pairs on the synthetic bench, {args.pairs} pairs, seed {args.seed}\n")
    print(
        "| against | detector | pairs | container found | other found | both | extra detections |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for (kind, name), (n, found_a, found_b, both, extra) in sorted(rows.items()):
        print(f"| {kind} | {name} | {n} | {found_a} | {found_b} | {both} | {extra} |")


if __name__ == "__main__":
    main()
