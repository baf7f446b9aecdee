"""``armvision eval ...``: each capability measured against the simulator's truth."""

from __future__ import annotations

import argparse
import json
from typing import Any

from armvision.cli.args import ProgressBar, _print_summary, _say
from armvision.config import (
    Config,
)


def cmd_eval_perception(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval import parse_seeds
    from armvision.eval.objects import evaluate_objects
    from armvision.eval.tags import evaluate_tags

    seeds = parse_seeds(args.seeds)
    tags = evaluate_tags(config, seeds)
    objects = evaluate_objects(config, seeds)
    result = {
        "seeds": seeds,
        "summary": {**tags["summary"], **objects["summary"]},
        "tags": tags["views"],
        "objects": objects["per_scene"],
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_summary(
            f"perception on seeds {args.seeds} (simulation ground truth)", result["summary"]
        )
    return 0


def cmd_eval_liquid(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.liquid import evaluate_liquid

    result = evaluate_liquid(config, args.n, args.seed, boxes=args.boxes)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        title = f"liquid level, {args.n} bottles from seed {args.seed}, {args.boxes} boxes"
        _print_summary(title, result["summary"])
    return 0


def cmd_eval_fusion(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.fusion import evaluate_fusion

    result = evaluate_fusion(config, args.seed, waypoints=args.waypoints, objects=not args.ee_only)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    summary = result["summary"]
    _print_summary(f"fusion and tracking, seed {args.seed} (simulation ground truth)", summary)
    calibration = result["calibration"]
    print(
        f"end effector, {result['ee']['seconds']:.1f} s of motion, camera pose off by "
        f"{calibration['camera_position_error_mm']:.1f} mm / "
        f"{calibration['camera_rotation_error_deg']:.2f} deg ({calibration['source']}):"
    )
    for name in ("fused", "camera", "encoders", "paper"):
        print(f"  {name:<9} RMSE {summary[f'ee_rmse_mm_{name}']:6.2f} mm")
    velocities = "fused" if result["ee"]["joint_velocities_fused"] else "not fused"
    print(
        f"  fused velocity RMSE {summary['ee_velocity_rmse_mm_s_fused']:6.1f} mm/s "
        f"(arm {result['ee']['arm']}, measured joint velocities {velocities})"
    )
    return 0


def cmd_eval_calibration(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval import parse_seeds
    from armvision.eval.calibration import evaluate_calibration

    seeds = parse_seeds(args.seeds)
    progress = None if args.json else ProgressBar("calibrating")
    result = evaluate_calibration(config, seeds, args.offset_error_mm, progress=progress)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    _print_summary(
        f"calibration on seeds {args.seeds} (simulation ground truth)", result["summary"]
    )
    print(f"{'method':<16} {'translation mm':>19} {'rotation deg':>17}")
    print(f"{'':<16} {'median':>9} {'max':>9} {'median':>8} {'max':>8}")
    for name, row in result["methods"].items():
        print(
            f"{name:<16} {row['translation_error_mm_median']:>9.2f}"
            f" {row['translation_error_mm_max']:>9.2f} {row['rotation_error_deg_median']:>8.3f}"
            f" {row['rotation_error_deg_max']:>8.3f}"
        )
    return 0


def cmd_eval_grab(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.grab import evaluate_grab

    def progress(done: int, total: int, row: dict[str, Any]) -> None:
        verdict = "ok" if row["success"] else f"FAILED ({row['task_error'] or row['held']})"
        if row["collateral"]:
            verdict += f", disturbed {', '.join(c['name'] for c in row['collateral'])}"
        _say(f"trial {done}/{total}, scene {row['seed']}: {verdict}")

    result = evaluate_grab(
        config,
        args.trials,
        args.seed,
        args.calibration,
        None if args.json else progress,
        args.jobs,
    )
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    _print_summary(f"grab, {args.trials} random scenes from seed {args.seed}", result["summary"])
    for row in result["failures"]:
        print(f"  scene {row['seed']}: {row['task_phase']} {row['task_error'] or ''}")
    for row in result["collateral"]:
        hit = ", ".join(
            f"{c['name']} ({c['kind']}) {'tipped' if c['tipped'] else 'moved'} "
            f"{100 * c['moved_m']:.1f} cm"
            for c in row["collateral"]
        )
        print(f"  scene {row['seed']}: disturbed {hit}")
    return 0


def cmd_eval_sort(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.sort import evaluate_sort

    def progress(done: int, total: int, row: dict[str, Any]) -> None:
        right = sum(b["right"] for b in row["bottles"])
        verdict = f"{right}/{len(row['bottles'])} bottles in the right zone"
        if row["collateral"]:
            verdict += f", disturbed {', '.join(c['name'] for c in row['collateral'])}"
        _say(f"trial {done}/{total}, scene {row['seed']}: {verdict}")

    result = evaluate_sort(
        config,
        args.trials,
        args.seed,
        args.calibration,
        args.jobs,
        None if args.json else progress,
    )
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    _print_summary(f"sort, {args.trials} sort scenes from seed {args.seed}", result["summary"])
    for b in result["wrong"]:
        print(
            f"  scene {b['seed']} {b['name']} ({b['kind']}, fill {100 * b['true_fill']:.0f} %, "
            f"wants {b['want_zone']}): {b['action']}: {b['reason']}"
        )
    return 0


def cmd_eval_follow(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.follow import evaluate_follow

    kwargs = {} if args.duration is None else {"duration_s": args.duration}
    result = evaluate_follow(config, seed=args.seed, **kwargs)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    _print_summary(f"follow a tag on a circle, seed {args.seed}", result["summary"])
    return 0


def cmd_eval_real(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.real import data_dir, evaluate_real, format_real

    result = evaluate_real(data_dir(args.data), config)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print("\n".join(format_real(result)))
    return 0
