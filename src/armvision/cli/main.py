"""The ``armvision`` command: its parser and the dispatch to each sub-command's module."""

from __future__ import annotations

import argparse
import logging
import sys
import typing
from collections.abc import Callable, Sequence
from typing import Any

from armvision import __version__
from armvision.cli.args import MAX_SEED, arm_option, int_in, millimetres, out_dir, seed, seeds
from armvision.cli.calibrate import CALIBRATION_METHODS, cmd_calibrate
from armvision.cli.evaluate import (
    cmd_eval_calibration,
    cmd_eval_fusion,
    cmd_eval_liquid,
    cmd_eval_perception,
    cmd_eval_real,
)
from armvision.cli.info import cmd_config, cmd_info
from armvision.cli.perceive import cmd_perceive, cmd_sim_snapshot
from armvision.cli.record import add_export_parser, add_record_option, add_replay_parser
from armvision.cli.tasks import add_parsers
from armvision.config import (
    Config,
    load_config,
)
from armvision.errors import ArmvisionError

log = logging.getLogger("armvision")


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (no usage block), exit status 2 as before."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="armvision",
        description="Vision-guided manipulation with an Interbotix ViperX-300s and a RealSense "
        "D435i, or their MuJoCo simulation.",
    )
    parser.add_argument("--version", action="version", version=f"armvision {__version__}")
    parser.add_argument(
        "--config",
        metavar="PATH",
        help="TOML configuration (default: $ARMVISION_CONFIG, ./armvision.toml)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        help="override one setting, e.g. --set robot.moving_time=1.5 (repeatable)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    _add_info_parsers(sub)
    _add_perception_parsers(sub)
    _add_calibrate_parser(sub)
    evaluate = sub.add_parser("eval", help="measure a capability against the simulator's truth")
    eval_sub = evaluate.add_subparsers(dest="eval_command", metavar="WHAT", required=True)
    _add_eval_parsers(eval_sub)
    add_parsers(sub, eval_sub)
    add_replay_parser(sub)
    add_export_parser(sub)
    _add_profile_options(eval_sub)
    return parser


#: The evaluations that run on simulated scenes, and so take ``--profile``.
PROFILED_EVALS = ("perception", "liquid", "grab", "follow", "fusion")


def overrides(args: argparse.Namespace) -> list[str]:
    """The ``--set`` overrides, with ``--profile`` as ``sim.profile`` (given last, it wins)."""
    out = list(args.overrides)
    if getattr(args, "profile", None) is not None:
        out.append(f"sim.profile={args.profile}")
    if getattr(args, "arm", None) is not None:
        out.append(f"sim.arm={args.arm}")
    return out


def _add_profile_options(eval_sub: Any) -> None:
    """``--profile`` on every evaluation that builds simulated scenes (``sim.profile``)."""
    for name in PROFILED_EVALS:
        eval_sub.choices[name].add_argument(
            "--profile",
            choices=("default", "cluttered"),
            help="the simulated scenes: default, or cluttered with distractors "
            "(the same as --set sim.profile=...)",
        )


def _add_info_parsers(sub: Any) -> None:
    """``armvision info`` and ``armvision config``."""
    info = sub.add_parser("info", help="version and which backends work on this machine")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    info.set_defaults(func=cmd_info)

    show = sub.add_parser("config", help="print the effective configuration as TOML")
    show.set_defaults(func=cmd_config)


def _add_perception_parsers(sub: Any) -> None:
    """``armvision sim snapshot`` and ``armvision perceive``."""
    sim = sub.add_parser("sim", help="the simulated workspace (MuJoCo)")
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)
    snapshot = sim_sub.add_parser(
        "snapshot", help="write the colour image, false-colour depth and ground truth of a scene"
    )
    snapshot.add_argument("--seed", type=seed, default=0, help="scene seed (default 0)")
    snapshot.add_argument(
        "--out", type=out_dir, default="snapshot", metavar="DIR", help="output directory"
    )
    snapshot.add_argument("--pose", choices=("home", "sleep"), default="home", help="arm pose")
    snapshot.set_defaults(func=cmd_sim_snapshot)

    perceive = sub.add_parser(
        "perceive", help="detect tags, bottles, cups and liquid levels in one frame"
    )
    source = perceive.add_mutually_exclusive_group()
    source.add_argument("--sim", action="store_true", help="a simulated scene (default)")
    source.add_argument("--real", action="store_true", help="the RealSense camera")
    source.add_argument(
        "--color", metavar="IMG", help="a saved colour image (PNG, JPG), with --depth"
    )
    source.add_argument(
        "--replay", metavar="FILE.mcap", help="a frame of a recording (--frame; default the last)"
    )
    perceive.add_argument(
        "--frame",
        type=int_in(0, 10**9, "a frame number"),
        help="with --replay: which recorded frame, counted from 0",
    )
    perceive.add_argument(
        "--depth",
        metavar="IMG",
        help="its depth, aligned to the colour: 16-bit PNG or .npy (x --depth-scale), "
        "float EXR or .npy (metres)",
    )
    perceive.add_argument(
        "--depth-scale",
        type=float,
        default=0.001,
        metavar="S",
        help="metres per unit of integer depth (default 0.001: millimetres)",
    )
    perceive.add_argument(
        "--intrinsics",
        metavar="FX,FY,CX,CY",
        help="pixels at the image's size, or a JSON file holding them (a snapshot's "
        "ground_truth.json); default: those in --calibration",
    )
    perceive.add_argument(
        "--calibration",
        metavar="FILE",
        help="a calibration from `armvision calibrate`: the camera pose for the table prior "
        "(--color, --real)",
    )
    perceive.add_argument(
        "--joints",
        metavar="Q1,...,Q6",
        help="with --color and --calibration: the six joint readings (rad) at capture, for the "
        "arm's self-mask, or a JSON file with joint_positions (a snapshot's ground_truth.json)",
    )
    perceive.add_argument("--seed", type=seed, default=0, help="scene seed (simulation)")
    perceive.add_argument(
        "--out", type=out_dir, default="perceive", metavar="DIR", help="output directory"
    )
    perceive.add_argument("--json", action="store_true", help="one JSON object on stdout")
    add_record_option(perceive)
    perceive.set_defaults(func=cmd_perceive)


def _add_calibrate_parser(sub: Any) -> None:
    """``armvision calibrate``."""
    calibrate = sub.add_parser(
        "calibrate", help="find the camera's pose in the robot base frame with the gripper tag"
    )
    where = calibrate.add_mutually_exclusive_group()
    where.add_argument("--sim", action="store_true", help="a simulated workspace (default)")
    where.add_argument("--real", action="store_true", help="the real arm and RealSense camera")
    calibrate.add_argument("--seed", type=seed, default=0, help="scene seed (simulation)")
    calibrate.add_argument(
        "--out",
        metavar="PATH",
        help="where to save (default: calibration.file; -sim added to the name in simulation)",
    )
    calibrate.add_argument(
        "--method", choices=CALIBRATION_METHODS, help="solver, overriding calibration.method"
    )
    calibrate.add_argument("--json", action="store_true", help="print the saved JSON")
    calibrate.add_argument(
        "--force",
        action="store_true",
        help="keep a calibration that fails the plausibility check (residual, spread, tag mount)",
    )
    add_record_option(calibrate)
    calibrate.set_defaults(func=cmd_calibrate)


def _add_eval_parsers(eval_sub: Any) -> None:
    """``armvision eval perception|liquid|fusion|calibration|real``."""
    perception = eval_sub.add_parser("perception", help="tag poses and object detection")
    perception.add_argument(
        "--seeds", type=seeds, default="0-19", help="scene seeds: 7, 0-19 or 1,4,9"
    )
    perception.add_argument("--json", action="store_true", help="one JSON object on stdout")
    perception.set_defaults(func=cmd_eval_perception)
    liquid = eval_sub.add_parser("liquid", help="liquid level in bottles")
    liquid.add_argument(
        "--n", type=int_in(1, 10_000, "a count"), default=50, help="bottles (default 50)"
    )
    liquid.add_argument("--seed", type=seed, default=0)
    liquid.add_argument(
        "--boxes",
        choices=("truth", "detector"),
        default="truth",
        help="what the meter is given: the true bottle's box (the meter alone, the default), "
        "or the geometric detector's box and geometry (the system end to end)",
    )
    liquid.add_argument("--json", action="store_true", help="one JSON object on stdout")
    liquid.set_defaults(func=cmd_eval_liquid)
    fusion = eval_sub.add_parser(
        "fusion", help="Kalman fusion of camera and encoders, and object tracking"
    )
    fusion.add_argument("--seed", type=seed, default=0)
    fusion.add_argument(
        "--waypoints",
        type=int_in(2, 1000, "a count of poses"),
        default=10,
        help="poses of the scripted motion (default 10)",
    )
    fusion.add_argument(
        "--ee-only",
        action="store_true",
        help="the end-effector fusion only, without the object tracking (half the time)",
    )
    fusion.add_argument("--json", action="store_true", help="one JSON object on stdout")
    arm_option(fusion)
    fusion.set_defaults(func=cmd_eval_fusion)
    calib = eval_sub.add_parser("calibration", help="camera-to-robot calibration, every solver")
    calib.add_argument(
        "--seeds", type=seeds, default="0-9", help="seeds: 7, 0-9 or 1,4,9 (default 0-9)"
    )
    calib.add_argument(
        "--offset-error-mm",
        type=millimetres,
        default=0.0,
        help="tell the calibration a tag offset wrong by this much (default 0)",
    )
    calib.add_argument("--json", action="store_true", help="one JSON object on stdout")
    calib.set_defaults(func=cmd_eval_calibration)
    real = eval_sub.add_parser(
        "real", help="perception and calibration on public real RealSense data (not simulation)"
    )
    real.add_argument(
        "--data",
        metavar="DIR",
        help="the real-data folder (default: $ARMVISION_REALDATA, else ../shared/realdata)",
    )
    real.add_argument("--json", action="store_true", help="one JSON object on stdout")
    real.set_defaults(func=cmd_eval_real)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error already printed
        return exc.code if isinstance(exc.code, int) else 2
    seed_given = getattr(args, "seed", None)
    if isinstance(seed_given, int) and not 0 <= seed_given <= MAX_SEED:
        # A sub-parser that takes --seed as a plain int (calibrate) gets the same check.
        print(
            f"armvision: error: argument --seed: must be a seed, a whole number from 0 to "
            f"{MAX_SEED}, not {seed_given} (see armvision --help)",
            file=sys.stderr,
        )
        return 2
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    func: Callable[[argparse.Namespace, Config], int] | None = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 0
    try:
        config = load_config(args.config, overrides(args))
        return func(args, config)
    except ArmvisionError as exc:
        if args.debug:
            raise
        print(f"armvision: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("armvision: interrupted", file=sys.stderr)
        return 130
