"""Gripper-tag pose accuracy in simulation, with and without depth refinement (issue 4).

The same views for both: random camera placements, the tag 0.5-1.2 m away, its face turned up
to 40 degrees from the camera. Truth from the simulator (see armvision.eval.tags).

    python benchmarks/bench_tags.py [--seeds 0-9]
"""

from __future__ import annotations

import argparse

from armvision.config import Config
from armvision.eval import parse_seeds
from armvision.eval.tags import evaluate_tags


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-9")
    args = parser.parse_args(argv)
    result = evaluate_tags(Config(), parse_seeds(args.seeds))
    s = result["summary"]
    print(
        f"\nGripper tag pose, {s['tag_views']} simulated views, seeds {args.seeds}, "
        f"detected in {100 * s['tag_detection_rate']:.1f} %\n"
    )
    print("| pose | position error median mm | rotation error median deg | rotation p95 deg |")
    print("|---|---:|---:|---:|")
    print(
        f"| PnP + depth refinement (default) | {s['tag_position_error_mm_median']:.2f} "
        f"| {s['tag_rotation_error_deg_median']:.2f} | {s['tag_rotation_error_deg_p95']:.2f} |"
    )
    print(
        f"| PnP only (IPPE, no depth) | {s['tag_position_error_mm_median_no_depth']:.2f} "
        f"| {s['tag_rotation_error_deg_median_no_depth']:.2f} "
        f"| {s['tag_rotation_error_deg_p95_no_depth']:.2f} |"
    )
    return s


if __name__ == "__main__":
    main()
