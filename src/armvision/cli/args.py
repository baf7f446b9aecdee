"""Argument types shared by the commands: each turns a bad value into a one-line argparse
error that says what to give instead; and the small printing helpers they share."""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from armvision.config import (
    TAG_FAMILY_SIZES,
)
from armvision.errors import ArmvisionError, ConfigError

#: Scene seeds: numpy's SeedSequence takes any non-negative int; 32 bits are plenty and print.
MAX_SEED = 2**32 - 1


#: At most this many scenes, trials or seeds in one evaluation.
MAX_RUNS = 10_000


def int_in(low: int, high: int, what: str) -> Callable[[str], int]:
    """An int argument in ``low``..``high``; ``what`` says what it counts in the error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be {what}, a whole number from {low} to {high}, not {text!r}"
            )
        return value

    parse.__name__ = what  # argparse's fallback messages name the type
    return parse


def float_in(low: float, high: float, what: str, above_low: bool = False) -> Callable[[str], float]:
    """A finite number argument in ``low``..``high`` (above ``low`` with ``above_low``);
    ``what`` says what it is, with its range, in the error."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = low < value if above_low else low <= value
        if not (math.isfinite(value) and inside and value <= high):
            raise argparse.ArgumentTypeError(f"must be {what}, not {text!r}")
        return value

    parse.__name__ = what
    return parse


#: A distance: millimetres from 0 to 1000.
millimetres = float_in(0.0, 1000.0, "millimetres from 0 to 1000")


seed = int_in(0, MAX_SEED, "a seed")


def seeds(text: str) -> str:
    """``--seeds``: one seed (7), a range (0-9) or a list (1,4,9), each 0..MAX_SEED, at most
    MAX_RUNS in all; returned as given (armvision.eval.parse_seeds expands it)."""
    from armvision.eval import parse_seeds

    count = 0
    for part in text.split(","):
        first, sep, last = part.strip().partition("-")
        try:
            low = int(first)
            high = int(last) if sep else low
        except ValueError:
            continue  # parse_seeds says what is wrong with it
        if not 0 <= low <= high <= MAX_SEED:
            raise argparse.ArgumentTypeError(
                f"{text!r}: seeds run from 0 to {MAX_SEED}, a range low-high with low <= high"
            )
        count += high - low + 1
        if count > MAX_RUNS:
            raise argparse.ArgumentTypeError(
                f"{text!r}: at most {MAX_RUNS} seeds; give a shorter range"
            )
    try:
        parse_seeds(text)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


port = int_in(0, 65535, "a TCP port (0: any free one)")


runs = int_in(1, MAX_RUNS, "a count")


def out_dir(text: str) -> str:
    """An output directory argument: not empty (checked for writing by :func:`writable_dir`)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("give a directory, not an empty path")
    return text


def writable_dir(path: str | Path, argument: str = "--out") -> Path:
    """``path`` created if need be and checked writable, before anything slow starts; an
    ArmvisionError naming ``argument`` otherwise."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise ArmvisionError(
            f"{argument} {path}: cannot write there ({exc.strerror or exc}); choose a directory "
            "you can write to"
        ) from None
    return out


#: A duration: seconds above 0, at most a day.
seconds = float_in(0.0, 86400.0, "a duration in seconds above 0 and at most 86400", True)


track_id = int_in(0, 2**31 - 1, "a track id")


tag_id = int_in(0, max(TAG_FAMILY_SIZES.values()) - 1, "a tag id")


class ProgressBar:
    """A one-line progress bar on stderr (a line per step when stderr is not a terminal)."""

    def __init__(self, title: str, width: int = 30, stream=None) -> None:
        self.title = title
        self.width = width
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()

    def __call__(self, done: int, total: int, message: str) -> None:
        filled = int(self.width * done / max(total, 1))
        bar = "#" * filled + "." * (self.width - filled)
        line = f"{self.title} [{bar}] {done}/{total} {message}"
        if self.tty:
            self.stream.write("\r\033[K" + line[: shutil.get_terminal_size().columns - 1])
            if done >= total:
                self.stream.write("\n")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def _say(message: str) -> None:
    print(f"armvision: {message}", file=sys.stderr, flush=True)


def _print_summary(title: str, summary: dict) -> None:
    """The summary's figures a line each; a nested table (per kind, per family) after them."""
    print(title)
    flat = {k: v for k, v in summary.items() if not isinstance(v, dict)}
    width = max((len(k) for k in flat), default=0)
    for key, value in flat.items():
        shown = f"{value:.3f}" if isinstance(value, float) else str(value)
        print(f"  {key:<{width}}  {shown}")
    for key, table in summary.items():
        if isinstance(table, dict) and table:
            _print_table(key, table)


def _print_table(title: str, rows: dict) -> None:
    """``{row: {column: value}}`` as an aligned table."""
    columns = list(dict.fromkeys(c for row in rows.values() for c in row))
    width = max(len(str(r)) for r in rows)

    def cell(value: object) -> str:
        return f"{value:.3f}" if isinstance(value, float) else str(value)

    print(f"  {title}:")
    print("    " + f"{'':<{width}}" + "".join(f"  {c:>10}" for c in columns))
    for name, row in rows.items():
        print(
            "    " + f"{name:<{width}}" + "".join(f"  {cell(row.get(c, '')):>10}" for c in columns)
        )


def _sim_calibration_path(path: str) -> Path:
    """``calibration.json`` -> ``calibration-sim.json``: a simulated run never overwrites
    the real arm's calibration."""
    p = Path(path)
    return p.with_name(f"{p.stem}-sim{p.suffix or '.json'}")


def arm_option(parser: argparse.ArgumentParser) -> None:
    """``--arm``: which simulated arm (``sim.arm``)."""
    parser.add_argument(
        "--arm",
        choices=("sim", "dynamixel-emulated"),
        help="simulation: SimArm (default) or the Dynamixel driver over the servo-bus emulator "
        "(the same as --set sim.arm=...)",
    )


def _where(
    parser: argparse.ArgumentParser,
    task: bool = True,
    calibration_help: str = "calibration file (real default: calibration.file); in simulation "
    "the default is to calibrate now, and 'truth' uses the simulator's camera pose",
) -> None:
    """--sim | --real, --seed, --calibration; a one-task command also gets --realtime, --json."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--sim", action="store_true", help="the simulated workspace (default)")
    where.add_argument("--real", action="store_true", help="the real arm and RealSense camera")
    parser.add_argument("--seed", type=seed, default=0, help="scene seed (simulation)")
    parser.add_argument("--calibration", metavar="PATH", help=calibration_help)
    if not task:
        return
    arm_option(parser)
    parser.add_argument(
        "--realtime",
        action="store_true",
        help="simulation on the wall clock, threads as on the real arm",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
