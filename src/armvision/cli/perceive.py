"""``armvision sim snapshot`` and ``armvision perceive``: one frame from the simulation or the
camera, rendered and run through perception."""

from __future__ import annotations

import argparse
import json

from armvision.cli.args import writable_dir
from armvision.config import (
    Config,
)


def cmd_sim_snapshot(args: argparse.Namespace, config: Config) -> int:
    from armvision.bench.snapshot import write_snapshot

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


def _perceive_frame(config: Config, frame, T_base_cam=None, joint_positions=None) -> dict:
    """Tags, containers and liquid levels in one frame, and the annotated image.

    Every tag record has the same keys, and so has every detection record (``fill``,
    ``fill_confidence`` and ``liquid_colour`` are None for a cup or an unmeasured bottle;
    ``fill`` is None and ``fill_unknown`` says why when the liquid cannot be seen);
    the keys are documented in the README ("Perception on a saved frame").
    """
    import numpy as np

    from armvision.perception.annotate import annotate
    from armvision.perception.detection import FrameContext
    from armvision.perception.factory import object_detector
    from armvision.perception.liquid import ContainerGeometry, LiquidLevelMeter
    from armvision.perception.tags import TagDetector

    tags = TagDetector.from_config(config.tag).detect(frame)
    detections = object_detector(config.perception).detect(
        frame, FrameContext(T_base_cam, joint_positions)
    )
    meter = LiquidLevelMeter()
    levels = [
        meter.measure(frame, d.box, ContainerGeometry.of(d)) if d.label == "bottle" else None
        for d in detections
    ]
    image = annotate(frame.color, frame.intrinsics, tags, detections, levels, config.tag.size)
    records = []
    for det, level in zip(detections, levels):
        record = det.to_dict()
        record["fill"] = None if level is None or level.fill is None else float(level.fill)
        record["fill_confidence"] = None if level is None else float(level.confidence)
        record["fill_unknown"] = None if level is None else level.unknown
        record["liquid_colour"] = (
            None if level is None or level.colour is None else [int(c) for c in level.colour]
        )
        records.append(record)
    return {
        "tags": [
            {
                "id": int(t.id),
                "center": [float(v) for v in t.center],
                "corners": np.asarray(t.corners, dtype=float).tolist(),
                "T_cam_tag": t.T_cam_tag.tolist(),
                "distance_m": float(np.linalg.norm(t.T_cam_tag[:3, 3])),
                "decision_margin": float(t.decision_margin),
                "pose_error_px": float(t.pose_error),
                "depth_refined": bool(t.depth_refined),
            }
            for t in tags
        ],
        "detections": records,
        "image": image,
    }


def _frame_source(frame, kind: str, **more) -> dict:
    """The ``source`` record: where the frame came from, its size and intrinsics."""
    h, w = frame.depth.shape
    return {
        "kind": kind,
        **more,
        "size": [int(w), int(h)],
        "intrinsics": frame.intrinsics.to_dict(),
    }


def _calibration_pose(path: str | None):
    """T_base_cam of a calibration file, its intrinsics and its joint offsets (None if it has
    none)."""
    if path is None:
        return None, None, None
    import numpy as np

    from armvision.calibration.store import load
    from armvision.camera.frames import Intrinsics
    from armvision.runtime.build import load_calibration

    status = load_calibration(path)  # the runtime's checks and messages
    stored = load(path)
    intr = stored.camera.get("intrinsics")
    intrinsics = None if intr is None else Intrinsics(**{**intr, "coeffs": tuple(intr["coeffs"])})
    return np.asarray(status.T_base_cam, dtype=float), intrinsics, status.joint_offsets_rad


def _joints(text: str, offsets) -> list[float]:
    """Six joint angles (rad) from "q1,...,q6" or a JSON file's ``joint_positions``, less the
    calibration's joint offsets (as the runtime corrects its encoders)."""
    import math
    from pathlib import Path

    import numpy as np

    from armvision.camera.files import FrameFileError

    help_ = "give --joints as six angles in radians, q1,...,q6, or a JSON file with joint_positions"
    values: object = None
    if "," in text:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = None
    else:
        path = Path(text)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise FrameFileError(f"--joints file {path} does not exist: {help_}") from None
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise FrameFileError(f"--joints file {path} is unreadable ({exc}): {help_}") from None
        values = data.get("joint_positions") if isinstance(data, dict) else None
    ok = (
        isinstance(values, list)
        and len(values) == 6
        and all(isinstance(v, int | float) and math.isfinite(v) for v in values)
    )
    if not ok:
        raise FrameFileError(f"--joints {text!r} is not six finite numbers: {help_}")
    q = np.asarray(values, dtype=float)
    if offsets is not None:
        q = q - np.asarray(offsets, dtype=float)
    return [float(v) for v in q]


def _file_frame(args: argparse.Namespace):
    """The frame of --color/--depth, the camera pose of --calibration, and the source record."""
    from armvision.camera.files import FrameFileError, check_depth_scale, load_rgbd_with_unit

    if args.depth is None:
        raise FrameFileError(
            "--color needs --depth: give the depth image aligned to it (16-bit PNG, EXR or .npy)"
        )
    check_depth_scale(args.depth_scale)
    T_base_cam, calib_intrinsics, offsets = _calibration_pose(args.calibration)
    joints = None
    if args.joints is not None:
        if T_base_cam is None:
            raise FrameFileError(
                "--joints needs --calibration: the arm is masked out in the base frame, so the "
                "camera's pose is needed"
            )
        joints = _joints(args.joints, offsets)
    intrinsics = args.intrinsics
    if intrinsics is None:
        if calib_intrinsics is None:
            raise FrameFileError(
                "--color needs --intrinsics fx,fy,cx,cy (pixels, at the image's size), or a "
                "--calibration file that holds the camera's intrinsics"
            )
        intrinsics = calib_intrinsics
    frame, scale = load_rgbd_with_unit(args.color, args.depth, args.depth_scale, intrinsics)
    source = _frame_source(
        frame,
        "files",
        color=str(args.color),
        depth=str(args.depth),
        depth_scale=scale,
        calibration=None if args.calibration is None else str(args.calibration),
        joint_positions=joints,
    )
    return frame, T_base_cam, joints, source


def cmd_perceive(args: argparse.Namespace, config: Config) -> int:
    from armvision.bench.snapshot import _write_png
    from armvision.errors import ArmvisionError

    color = getattr(args, "color", None)
    if color is None and getattr(args, "depth", None) is not None:
        raise ArmvisionError("--depth goes with --color: give the colour image too")
    for given in ("intrinsics", "joints"):
        if color is None and getattr(args, given, None) is not None:
            raise ArmvisionError(f"--{given} goes with --color (a saved frame)")
    calibration = getattr(args, "calibration", None)
    replayed = getattr(args, "replay", None)
    if getattr(args, "frame", None) is not None and replayed is None:
        raise ArmvisionError("--frame goes with --replay (a recording's frame number)")
    if calibration is not None and color is None and not args.real and replayed is None:
        raise ArmvisionError(
            "--calibration goes with --color or --real; in simulation the simulator's camera "
            "pose is used"
        )
    out = writable_dir(args.out)  # before the camera or the scene starts
    frame = None
    if replayed is not None:
        from armvision.cli.record import recorded_frame

        frame, T_base_cam, joints, source = recorded_frame(replayed, args.frame)
        if calibration is not None:
            T_base_cam, _, _ = _calibration_pose(calibration)
        result = {"source": source, **_perceive_frame(config, frame, T_base_cam, joints)}
    elif color is not None:
        frame, T_base_cam, joints, source = _file_frame(args)
        result = {"source": source, **_perceive_frame(config, frame, T_base_cam, joints)}
    elif args.real:
        from armvision.camera.realsense import RealSenseCamera

        T_base_cam, _, _ = _calibration_pose(calibration)
        with RealSenseCamera.from_config(config.camera) as camera:
            frame = camera.read(timeout_s=5.0)
        source = _frame_source(frame, "real", calibration=calibration)
        result = {"source": source, **_perceive_frame(config, frame, T_base_cam)}
    else:
        from armvision.geometry import inv_T
        from armvision.sim.arm import SimArm
        from armvision.sim.camera import SimCamera
        from armvision.sim.world import SimWorld

        with SimWorld(config, args.seed) as world, SimCamera(world) as camera:
            arm = SimArm(world)
            arm.go_to_sleep_pose()  # folded, with the gripper tag toward the camera
            world.advance(0.3)
            frame = camera.read()
            # No calibration yet: the self-filter uses the simulator's camera pose.
            source = _frame_source(frame, "sim", seed=int(args.seed))
            result = {
                "source": source,
                **_perceive_frame(config, frame, world.T_base_cam(), arm.get_joint_positions()),
            }
            T_cam_base = inv_T(world.T_base_cam())
            result["ground_truth"] = {
                "T_cam_tag": (T_cam_base @ world.T_base_tag()).tolist(),
                "objects": [
                    {
                        "name": o.spec.name,
                        "kind": o.spec.kind,
                        "label": o.spec.label,
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
    _record_result(getattr(args, "record", None), config, frame, result)
    image = result.pop("image")
    _write_png(out / "annotated.png", image)
    result["image"] = str(out / "annotated.png")
    with open(out / "detections.json", "w") as fh:
        json.dump(result, fh, indent=2)
    if getattr(args, "json", False):
        print(json.dumps(result))
        return 0
    _print_result(result)
    print(f"wrote {out / 'annotated.png'} and {out / 'detections.json'}")
    return 0


def _record_result(path: str | None, config: Config, frame, result: dict) -> None:
    """``--record``: the frame, and its tags and detections as found, in an MCAP file."""
    from armvision.cli.record import finish_recording, open_recorder

    recorder = open_recorder(path, config, wait=True)
    if recorder is None or frame is None:
        finish_recording(recorder)
        return
    t = float(frame.timestamp)
    recorder.begin(t)
    recorder.frame(frame)
    joints = result["source"].get("joint_positions")
    if joints is not None:
        recorder.frame_joints(t, joints)
    recorder.json("/armvision/tags", t, result["tags"])
    recorder.json("/armvision/detections", t, result["detections"])
    finish_recording(recorder)


def _print_result(result: dict) -> None:
    source = result["source"]
    if source["kind"] == "files":
        w, h = source["size"]
        k = source["intrinsics"]
        scale = source["depth_scale"]
        unit = "float metres" if scale is None else f"x {scale:g} m"
        print(
            f"{source['color']} + {source['depth']} ({unit}): {w}x{h}, fx={k['fx']:.1f} "
            f"fy={k['fy']:.1f} cx={k['ppx']:.1f} cy={k['ppy']:.1f}; camera pose: "
            f"{source['calibration'] or 'none (no table prior)'}"
        )
    print(f"{len(result['tags'])} tag(s), {len(result['detections'])} container(s):")
    for tag in result["tags"]:
        x, y, z = (row[3] for row in tag["T_cam_tag"][:3])
        print(
            f"  tag {tag['id']:<3} at x={x:+.3f} y={y:+.3f} z={z:.3f} m (camera), "
            f"{tag['distance_m']:.3f} m away"
        )
    for det in result["detections"]:
        x, y, z = det["center_cam"]
        fill = "" if det["fill"] is None else f"  fill {100 * det['fill']:.0f} %"
        print(
            f"  {det['label']:<6} at x={x:+.3f} y={y:+.3f} z={z:.3f} m (camera), score "
            f"{det['score']:.2f}, {1000 * 2 * det['radius']:.0f} mm wide "
            f"{1000 * det['height']:.0f} mm tall{fill}"
        )
