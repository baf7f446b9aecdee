"""Evaluations against the simulator's ground truth: the figures armvision publishes.

Each ``evaluate_*`` function builds simulated scenes, runs one capability on them and returns a
JSON-ready dict whose ``"summary"`` holds the headline figures (``armvision eval ...``).
"""

from __future__ import annotations

from armvision.errors import ConfigError


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"7"``, ``"0-9"`` (inclusive) or ``"1,4,9"``."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            first, sep, last = part.strip().partition("-")
            if sep:
                lo, hi = int(first), int(last)
                if hi < lo:
                    raise ValueError
                seeds.extend(range(lo, hi + 1))
            else:
                seeds.append(int(first))
    except ValueError:
        raise ConfigError(
            f"seeds {text!r}: write one seed (7), a range (0-9) or a list (1,4,9)"
        ) from None
    return seeds
