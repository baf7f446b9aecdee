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
    """Tags, containers and liquid levels in one frame, and the annotated image."""
    from armvision.perception.annotate import annotate
    from armvision.perception.detection import FrameContext
    from armvision.perception.geometric import GeometricDetector
    from armvision.perception.liquid import ContainerGeometry, LiquidLevelMeter
    from armvision.perception.tags import TagDetector

    tags = TagDetector.from_config(config.tag).detect(frame)
    detections = GeometricDetector().detect(frame, FrameContext(T_base_cam, joint_positions))
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
    from armvision.bench.snapshot import _write_png

    out = writable_dir(args.out)  # before the camera or the scene starts
    if args.real:
        from armvision.camera.realsense import RealSenseCamera

        with RealSenseCamera.from_config(config.camera) as camera:
            frame = camera.read(timeout_s=5.0)
        result = _perceive_frame(config, frame)
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
