"""Run every benchmark and print its table (``make bench``). Figures go into the README."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main() -> int:
    for name in sorted(path.stem for path in HERE.glob("bench_*.py")):
        print(f"\n=== {name} ===", flush=True)
        importlib.import_module(name).main([])
    return 0


if __name__ == "__main__":
    sys.exit(main())
