"""Clear plastic: the real D435 (ClearGrasp's real-val frames) beside SimCamera's model.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_clear_depth.py /path/to/cleargrasp_real_d435

Without a folder (or if it is missing) only the simulated side is printed. The tolerance:
each share of the simulated frames within 10 points of the pooled real value.
"""

from __future__ import annotations

import sys
from pathlib import Path

from armvision.eval.clear_depth import CATEGORIES, measure_real, measure_sim

TOLERANCE = 0.10  # each share within 10 points of the pooled real value


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else None
    real = measure_real(folder)["pooled"] if folder is not None and folder.is_dir() else None
    sim = measure_sim(seeds=range(4))["pooled"]
    print(f"{'':24}" + "".join(f"{c:>9}" for c in CATEGORIES) + f"{'median err':>12}")
    rows = [("simulated (4 scenes)", sim)]
    if real is not None:
        rows.insert(0, ("real D435 (4 frames)", real))
    for name, stats in rows:
        shares = "".join(f"{100 * stats[c]:8.1f}%" for c in CATEGORIES)
        print(f"{name:24}{shares}{100 * stats['median_error_m']:10.1f} cm")
    if real is None:
        print("(no real folder given: simulated side only)")
        return 0
    worst = max(abs(sim[c] - real[c]) for c in CATEGORIES)
    ok = worst <= TOLERANCE
    print(
        f"largest share difference {100 * worst:.1f} points, tolerance {100 * TOLERANCE:.0f}:"
        f" {'PASS' if ok else 'FAIL'}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
