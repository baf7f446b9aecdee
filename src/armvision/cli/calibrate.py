"""``armvision calibrate``: the two-phase gripper-tag calibration, on the simulation or the
real arm, checked for plausibility and saved."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import typing
from pathlib import Path
from typing import Any

from armvision.cli.args import ProgressBar, _sim_calibration_path, writable_dir
from armvision.cli.record import finish_recording, open_recorder
from armvision.config import (
    CalibrationConfig,
    Config,
)

CALIBRATION_METHODS = typing.get_args(typing.get_type_hints(CalibrationConfig)["method"])


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

    from armvision.bench.system import calibrate_sim
    from armvision.calibration import store
    from armvision.calibration.procedure import calibrate
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
    recorder = open_recorder(args.record, config, wait=not args.real)
    if recorder is not None:
        from armvision.robot.kinematics import VX300S

        recorder.begin(0.0, tuple(VX300S.joint_names))
    if args.real:
        from armvision.camera.realsense import RealSenseCamera
        from armvision.robot.interbotix import InterbotixArm

        arm = InterbotixArm.from_config(config.robot)
        with RealSenseCamera.from_config(config.camera) as rs_camera:
            from armvision.runtime.recorder import RecordingArm, RecordingCamera

            camera: Any = rs_camera
            moved: Any = arm
            if recorder is not None:
                camera = RecordingCamera(rs_camera, recorder)
                moved = RecordingArm(arm, recorder)
            arm.go_to_home_pose()
            try:
                result = calibrate(moved, camera, config, wait=time.sleep, progress=progress)
            finally:
                arm.go_to_home_pose()
                arm.go_to_sleep_pose()
            stored = store.record(result, source="real")
    else:
        result = calibrate_sim(config, args.seed, progress=progress, recorder=recorder)
        stored = store.record(result, source=f"simulation, seed {args.seed}")
    if recorder is not None:
        from armvision.runtime.build import result_status

        recorder.calibration(recorder.last_t, result_status(result))
        finish_recording(recorder)
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
