"""The ``armvision`` command.

Every subcommand loads the configuration the same way (``--config``, ``--set``); an
:class:`ArmvisionError` is printed as one line that says what to do, with exit status 2, never
a traceback (``--debug`` shows it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import os
import platform
import shutil
import subprocess
import sys
import typing
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from armvision import __version__
from armvision.cli_tasks import MAX_SEED, millimetres, out_dir, seed, seeds, writable_dir
from armvision.cli_tasks import add_parsers as add_task_parsers
from armvision.cli_tasks import int_in as _int_in
from armvision.config import (
    CalibrationConfig,
    Config,
    config_to_toml,
    find_config_file,
    load_config,
)
from armvision.errors import ArmvisionError

log = logging.getLogger("armvision")
CALIBRATION_METHODS = typing.get_args(typing.get_type_hints(CalibrationConfig)["method"])


# --------------------------------------------------------------------------- armvision info


@dataclass(frozen=True)
class BackendStatus:
    """Whether one backend can be used on this machine, and why (not)."""

    name: str
    usable: bool
    detail: str


# Rendering is probed in a child process: a broken GL stack can abort the interpreter, and
# MUJOCO_GL is read once, at import.
_MUJOCO_PROBE = """
import mujoco
model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size="0.1"/></worldbody></mujoco>')
renderer = mujoco.Renderer(model, 48, 64)
data = mujoco.MjData(model)
mujoco.mj_forward(model, data)
renderer.update_scene(data)
image = renderer.render()
renderer.close()
print(mujoco.__version__, image.shape[1], image.shape[0])
"""


def check_mujoco(timeout_s: float = 60.0) -> BackendStatus:
    """Can MuJoCo render offscreen here (the simulated camera needs it)?"""
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    try:
        result = subprocess.run(
            [sys.executable, "-c", _MUJOCO_PROBE],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return BackendStatus("mujoco", False, f"rendering test hung for {timeout_s:.0f} s")
    if result.returncode != 0:
        lines = (result.stderr or result.stdout).strip().splitlines()
        why = lines[-1] if lines else f"exit status {result.returncode}"
        if "No module named 'mujoco'" in why:
            return BackendStatus("mujoco", False, "not installed: pip install mujoco")
        return BackendStatus(
            "mujoco",
            False,
            f"cannot render with MUJOCO_GL={env['MUJOCO_GL']} ({why}); install libegl1 "
            "libgl1-mesa-dri (make setup does) or try MUJOCO_GL=osmesa",
        )
    version = result.stdout.split()[0]
    return BackendStatus(
        "mujoco",
        True,
        f"MuJoCo {version}, offscreen rendering with MUJOCO_GL={env['MUJOCO_GL']} works",
    )


def check_realsense() -> BackendStatus:
    """Is pyrealsense2 installed, and which cameras are connected?"""
    try:
        import pyrealsense2 as rs
    except ImportError:
        return BackendStatus(
            "realsense", False, "pyrealsense2 not installed: pip install 'armvision[realsense]'"
        )
    version = getattr(rs, "__version__", "?")
    try:
        devices = list(rs.context().query_devices())
    except RuntimeError as exc:
        return BackendStatus(
            "realsense", False, f"pyrealsense2 {version}: cannot list devices ({exc})"
        )
    if not devices:
        return BackendStatus(
            "realsense",
            False,
            f"pyrealsense2 {version} installed; no RealSense camera connected"
            " (plug it into a USB 3 port)",
        )
    found = []
    for dev in devices:
        info = {
            key: dev.get_info(getattr(rs.camera_info, key))
            if dev.supports(getattr(rs.camera_info, key))
            else "?"
            for key in ("name", "serial_number", "usb_type_descriptor")
        }
        found.append(
            f"{info['name']} serial {info['serial_number']} on USB {info['usb_type_descriptor']}"
        )
    return BackendStatus("realsense", True, f"pyrealsense2 {version}: " + "; ".join(found))


def check_interbotix() -> BackendStatus:
    """Are the Interbotix ROS 2 Python modules importable (needed for the real arm)?"""
    from armvision.robot.interbotix import interbotix_available

    usable, detail = interbotix_available()
    return BackendStatus("interbotix", usable, detail)


def cmd_info(args: argparse.Namespace, config: Config) -> int:
    statuses = [check_mujoco(), check_realsense(), check_interbotix()]
    config_file = find_config_file(args.config)
    report = {
        "version": __version__,
        "python": platform.python_version(),
        "platform": f"{platform.system()} {platform.machine()}",
        "config": str(config_file) if config_file else "defaults",
        "backends": [asdict(s) for s in statuses],
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"armvision {__version__} (Python {report['python']}, {report['platform']})")
    print(f"config: {report['config']}")
    width = max(len(s.name) for s in statuses)
    for s in statuses:
        print(f"  {s.name:<{width}}  {'yes' if s.usable else 'no ':<3}  {s.detail}")
    return 0


# --------------------------------------------------------------------------- armvision config


def cmd_config(args: argparse.Namespace, config: Config) -> int:
    print(config_to_toml(config), end="")
    return 0


# --------------------------------------------------------------------------- armvision sim


def cmd_sim_snapshot(args: argparse.Namespace, config: Config) -> int:
    from armvision.sim.snapshot import write_snapshot

    writable_dir(args.out)  # before the scene is built and rendered
    record = write_snapshot(config, args.seed, args.out, pose=args.pose)
    print(f"scene seed {args.seed}, arm at {args.pose}; wrote:")
    for name, path in record["files"].items():
        print(f"  {name:<13} {path}")
    objects = record.get("objects", [])
    if objects:
        print("objects (true, base frame):")
        for obj in objects:
            x, y, z = obj["position_base"]
            print(
                f"  {obj['name']:<10} {obj['kind']:<6} x={x:+.3f} y={y:+.3f} z={z:+.3f} m"
                f"  fill {100 * obj['fill']:.0f} %"
            )
    return 0


# --------------------------------------------------------------------------- armvision perceive


def _perceive_frame(config: Config, frame, T_base_cam=None, joint_positions=None) -> dict:
    """Tags, containers and liquid levels in one frame, and the annotated image."""
    from armvision.perception.annotate import annotate
    from armvision.perception.liquid import ContainerGeometry, LiquidLevelMeter
    from armvision.perception.objects import GeometricDetector
    from armvision.perception.tags import TagDetector

    tags = TagDetector.from_config(config.tag).detect(frame)
    detections = GeometricDetector(T_base_cam).detect(frame, joint_positions)
    meter = LiquidLevelMeter()
    levels = [
        meter.measure(frame, d.box, ContainerGeometry(tuple(d.center_cam), d.radius, d.height))
        if d.label == "bottle"
        else None
        for d in detections
    ]
    image = annotate(frame.color, frame.intrinsics, tags, detections, levels, config.tag.size)
    records = []
    for det, level in zip(detections, levels):
        record = det.to_dict()
        if level is not None:
            record["fill"] = level.fill
            record["fill_confidence"] = level.confidence
            record["liquid_colour"] = None if level.colour is None else list(level.colour)
        records.append(record)
    return {
        "tags": [
            {
                "id": t.id,
                "T_cam_tag": t.T_cam_tag.tolist(),
                "decision_margin": t.decision_margin,
                "pose_error_px": t.pose_error,
                "depth_refined": t.depth_refined,
            }
            for t in tags
        ],
        "detections": records,
        "image": image,
    }


def cmd_perceive(args: argparse.Namespace, config: Config) -> int:
    from armvision.sim.snapshot import _write_png

    out = writable_dir(args.out)  # before the camera or the scene starts
    if args.real:
        from armvision.camera.realsense import RealSenseCamera

        with RealSenseCamera.from_config(config.camera) as camera:
            frame = camera.read(timeout_s=5.0)
        result = _perceive_frame(config, frame)
    else:
        from armvision.camera.sim import SimCamera
        from armvision.geometry import inv_T
        from armvision.robot.sim import SimArm
        from armvision.sim.world import SimWorld

        with SimWorld(config, args.seed) as world, SimCamera(world) as camera:
            arm = SimArm(world)
            arm.go_to_sleep_pose()  # folded, with the gripper tag toward the camera
            world.advance(0.3)
            frame = camera.read()
            # No calibration yet: the self-filter uses the simulator's camera pose.
            result = _perceive_frame(config, frame, world.T_base_cam(), arm.get_joint_positions())
            T_cam_base = inv_T(world.T_base_cam())
            result["ground_truth"] = {
                "T_cam_tag": (T_cam_base @ world.T_base_tag()).tolist(),
                "objects": [
                    {
                        "name": o.spec.name,
                        "kind": o.spec.kind,
                        "fill": o.spec.fill,
                        "center_cam": (
                            T_cam_base[:3, :3] @ o.T_base_obj[:3, 3]
                            + T_cam_base[:3, 3]
                            + T_cam_base[:3, :3] @ o.T_base_obj[:3, 2] * o.spec.height / 2
                        ).tolist(),
                    }
                    for o in world.objects()
                ],
            }
    image = result.pop("image")
    _write_png(out / "annotated.png", image)
    with open(out / "detections.json", "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"{len(result['tags'])} tag(s), {len(result['detections'])} container(s):")
    for det in result["detections"]:
        x, y, z = det["center_cam"]
        fill = f"  fill {100 * det['fill']:.0f} %" if "fill" in det else ""
        print(f"  {det['label']:<6} at x={x:+.3f} y={y:+.3f} z={z:.3f} m (camera){fill}")
    print(f"wrote {out / 'annotated.png'} and {out / 'detections.json'}")
    return 0


# --------------------------------------------------------------------------- armvision calibrate


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


def _sim_calibration_path(path: str) -> Path:
    """``calibration.json`` -> ``calibration-sim.json``: a simulated run never overwrites
    the real arm's calibration."""
    p = Path(path)
    return p.with_name(f"{p.stem}-sim{p.suffix or '.json'}")


def _print_calibration(result) -> None:
    samples = result.samples
    print(f"{'#':>3} {'phase':>5} {'azimuth':>8} {'height':>6} {'seen':>5} {'residual':>9}")
    for i, (sample, residual) in enumerate(zip(samples, result.fit.residuals)):
        flag = "  dropped" if not result.fit.used[i] else ""
        print(
            f"{i:>3} {sample.phase:>5} {math.degrees(sample.azimuth):>7.0f}\u00b0"
            f" {sample.height:>5.2f}m {sample.detections:>2}/{sample.frames:<2}"
            f" {1000 * residual:>6.2f} mm{flag}"
        )
    fit = result.fit
    print(
        f"method {result.method}: {int(fit.used.sum())} of {len(samples)} samples,"
        f" residual RMS {1000 * fit.rms_m:.2f} mm, max {1000 * fit.max_m:.2f} mm"
    )
    for note in fit.notes:
        print(f"  {note}")
    t = result.T_base_cam[:3, 3]
    print(f"camera at x={t[0]:+.4f} y={t[1]:+.4f} z={t[2]:+.4f} m in the base frame")
    if result.truth is not None:
        print(f"{'method':<16} {'residual':>9} {'error vs truth':>22}")
        for name, fit_or_error in result.fits.items():
            if isinstance(fit_or_error, str):
                print(f"{name:<16} failed: {fit_or_error}")
                continue
            err = result.truth["methods"][name]
            mark = " <- chosen" if name == result.method else ""
            print(
                f"{name:<16} {1000 * fit_or_error.rms_m:>6.2f} mm"
                f" {err['translation_error_mm']:>7.2f} mm {err['rotation_error_deg']:>6.3f}\u00b0"
                f"{mark}"
            )
    for line in result.sampling.skipped:
        print(f"skipped: {line}")


def cmd_calibrate(args: argparse.Namespace, config: Config) -> int:
    import time

    from armvision.calibration import store
    from armvision.calibration.procedure import calibrate, calibrate_sim
    from armvision.calibration.quality import check_quality

    if args.method:
        config = dataclasses.replace(
            config, calibration=dataclasses.replace(config.calibration, method=args.method)
        )
    out = Path(
        args.out
        or (
            config.calibration.file if args.real else _sim_calibration_path(config.calibration.file)
        )
    )
    writable_dir(
        out.parent if str(out.parent) else ".", "the calibration's folder"
    )  # before moving
    progress = ProgressBar("calibrating")
    if args.real:
        from armvision.camera.realsense import RealSenseCamera
        from armvision.robot.interbotix import InterbotixArm

        arm = InterbotixArm.from_config(config.robot)
        with RealSenseCamera.from_config(config.camera) as camera:
            arm.go_to_home_pose()
            try:
                result = calibrate(arm, camera, config, wait=time.sleep, progress=progress)
            finally:
                arm.go_to_home_pose()
                arm.go_to_sleep_pose()
            stored = store.record(result, source="real")
    else:
        result = calibrate_sim(config, args.seed, progress=progress)
        stored = store.record(result, source=f"simulation, seed {args.seed}")
    quality = check_quality(
        result, config.calibration, "rerun, or pass --force to keep it", force=args.force
    )
    warnings = []
    if quality.problems:
        warnings.append(f"calibration kept with --force although {'; '.join(quality.problems)}")
        print(f"armvision: warning: {warnings[-1]}", file=sys.stderr)
    saved = store.save(stored, out)  # a backup that cannot be made is logged as a warning
    if saved.backup_error:
        warnings.append(saved.backup_error)
    if args.json:
        extra = {"path": str(out), "backup": saved.backup and str(saved.backup)}
        print(json.dumps({**stored.to_dict(), **extra, "warnings": warnings}, indent=2))
    else:
        _print_calibration(result)
        kept = f" (previous kept as {saved.backup})" if saved.backup else ""
        print(f"saved {out}{kept}" + (f", but {saved.backup_error}" if saved.backup_error else ""))
    return 0


# --------------------------------------------------------------------------- armvision eval


def _print_summary(title: str, summary: dict) -> None:
    print(title)
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        shown = f"{value:.3f}" if isinstance(value, float) else str(value)
        print(f"  {key:<{width}}  {shown}")


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

    result = evaluate_liquid(config, args.n, args.seed)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_summary(f"liquid level, {args.n} bottles from seed {args.seed}", result["summary"])
    return 0


def cmd_eval_fusion(args: argparse.Namespace, config: Config) -> int:
    from armvision.eval.fusion import evaluate_fusion

    result = evaluate_fusion(config, args.seed, waypoints=args.waypoints)
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


# --------------------------------------------------------------------------- entry point


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

    info = sub.add_parser("info", help="version and which backends work on this machine")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    info.set_defaults(func=cmd_info)

    show = sub.add_parser("config", help="print the effective configuration as TOML")
    show.set_defaults(func=cmd_config)

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
    perceive.add_argument("--seed", type=seed, default=0, help="scene seed (simulation)")
    perceive.add_argument(
        "--out", type=out_dir, default="perceive", metavar="DIR", help="output directory"
    )
    perceive.set_defaults(func=cmd_perceive)

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
    calibrate.set_defaults(func=cmd_calibrate)

    evaluate = sub.add_parser("eval", help="measure a capability against the simulator's truth")
    eval_sub = evaluate.add_subparsers(dest="eval_command", metavar="WHAT", required=True)
    perception = eval_sub.add_parser("perception", help="tag poses and object detection")
    perception.add_argument(
        "--seeds", type=seeds, default="0-19", help="scene seeds: 7, 0-19 or 1,4,9"
    )
    perception.add_argument("--json", action="store_true", help="one JSON object on stdout")
    perception.set_defaults(func=cmd_eval_perception)
    liquid = eval_sub.add_parser("liquid", help="liquid level in bottles")
    liquid.add_argument(
        "--n", type=_int_in(1, 10_000, "a count"), default=50, help="bottles (default 50)"
    )
    liquid.add_argument("--seed", type=seed, default=0)
    liquid.add_argument("--json", action="store_true", help="one JSON object on stdout")
    liquid.set_defaults(func=cmd_eval_liquid)
    fusion = eval_sub.add_parser(
        "fusion", help="Kalman fusion of camera and encoders, and object tracking"
    )
    fusion.add_argument("--seed", type=seed, default=0)
    fusion.add_argument(
        "--waypoints",
        type=_int_in(2, 1000, "a count of poses"),
        default=10,
        help="poses of the scripted motion (default 10)",
    )
    fusion.add_argument("--json", action="store_true", help="one JSON object on stdout")
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
    add_task_parsers(sub, eval_sub)
    return parser


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
        config = load_config(args.config, args.overrides)
        return func(args, config)
    except ArmvisionError as exc:
        if args.debug:
            raise
        print(f"armvision: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("armvision: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
