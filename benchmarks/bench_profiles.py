"""Perception and liquid level on both scene profiles, side by side: the default bench and the
cluttered one (distractors, bottle and cup families, objects close together and behind one
another, the real D435's habits on clear plastic).

    python benchmarks/bench_profiles.py [--seeds 0-19] [--n 50]

The same figures as ``armvision eval perception --profile P --seeds ...`` and ``armvision eval
liquid --profile P --n ...``; the cluttered column is today's detector in the harder world.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

from armvision.config import Config
from armvision.eval import parse_seeds
from armvision.eval.liquid import evaluate_liquid
from armvision.eval.objects import evaluate_objects

PROFILES = ("default", "cluttered")
ROWS = (
    ("bottle and cup recall", "object_recall", "{:.0%}"),
    ("bottle recall", "object_recall_bottle", "{:.0%}"),
    ("bottle precision", "object_precision_bottle", "{:.0%}"),
    ("cup recall", "object_recall_cup", "{:.0%}"),
    ("cup precision", "object_precision_cup", "{:.0%}"),
    ("distractors called bottle or cup", "distractor_rate", "{:.0%}"),
    ("false positives", "object_false_positives", "{}"),
    ("centre error median (mm)", "object_center_error_mm_median", "{:.1f}"),
    ("centre error p90 (mm)", "object_center_error_mm_p90", "{:.1f}"),
    ("objects visible / distractors visible", None, None),
    ("liquid MAE, all bottles (points)", "mae_pct", "{:.1f}"),
    ("liquid MAE, see-through bottles", "mae_pct_fill_visible", "{:.1f}"),
    ("opaque bottles reported unknown", "opaque_unknown_rate", "{:.0%}"),
    ("bottles measured", "bottles", "{}"),
)


def _show(fmt: str | None, value: object) -> str:
    if fmt is None or value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return fmt.format(value)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-19")
    parser.add_argument("--n", type=int, default=50)
    args = parser.parse_args(argv)
    columns = {}
    for profile in PROFILES:
        config = Config()
        config = dataclasses.replace(config, sim=dataclasses.replace(config.sim, profile=profile))
        objects = evaluate_objects(config, parse_seeds(args.seeds))["summary"]
        liquid = evaluate_liquid(config, args.n, 0)["summary"]
        columns[profile] = {**objects, **liquid}
    print(
        f"{'seeds ' + args.seeds + ', ' + str(args.n) + ' bottles':38}"
        + "".join(f"{p:>12}" for p in PROFILES)
    )
    for title, key, fmt in ROWS:
        if key is None:
            cells = [
                f"{c['objects_visible']} / {c['distractors_visible']}" for c in columns.values()
            ]
        else:
            cells = [_show(fmt, c.get(key)) for c in columns.values()]
        print(f"{title:38}" + "".join(f"{cell:>12}" for cell in cells))
    kinds = columns["cluttered"]["found_by_kind"]
    print("\ncluttered: visible objects of each kind matched by any detection, by a bottle/cup")
    for kind, row in kinds.items():
        rate = _show("{:.0%}", row["rate"])
        print(f"  {kind:16} {row['found']:>3} / {row['visible']:<3} {rate:>5}  {row['called']:>3}")
    families = columns["cluttered"]["by_family"]
    print("\ncluttered: liquid MAE per bottle family (points)")
    for kind, row in families.items():
        print(f"  {kind:16} {row['bottles']:>3} bottles  {row['mae_pct']:6.1f}")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
