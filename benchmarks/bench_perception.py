"""Per-frame perception cost at 640x480 on simulated frames: tags, objects, liquid, and all three.

Frames are rendered once per scene (arm asleep so its tag faces the camera, 1-4 objects);
each stage is then timed on the same frames. Raw pupil-apriltags detection on the same grey
image is the reference for the tag stage. The liquid stage measures every detected bottle
with the detection's box and geometry, as the runtime does. The whole pipeline is timed in
sequence and as the runtime runs it, the tag stage in a thread beside objects and liquid.

    python benchmarks/bench_perception.py [--scenes 8] [--repeats 5] [--profile cluttered]

``--profile cluttered`` renders the cluttered scenes (3-8 objects, distractors, clear-plastic
depth). The last line is the whole pipeline over raw tag detection, the same frames and run.
"""

from __future__ import annotations

import argparse
import threading
import time

import cv2
import numpy as np

from armvision.config import load_config
from armvision.perception.detection import FrameContext
from armvision.perception.geometric import GeometricDetector
from armvision.perception.liquid import ContainerGeometry, LiquidLevelMeter
from armvision.perception.tags import TagDetector, pupil_detector
from armvision.sim.arm import SimArm
from armvision.sim.camera import SimCamera
from armvision.sim.world import SimWorld


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _time_stages(
    frame, context, objects, tags, tags_no_depth, raw, liquid, repeats: int
) -> list[float]:
    """Median ms of each stage on one frame, in the order of the table's rows."""
    gray = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY)
    bottles = [d for d in objects.detect(frame, context) if d.label == "bottle"]

    def measure_bottles() -> None:
        for det in bottles:  # as the runtime does: the detection's box and geometry
            liquid.measure(frame, det.box, ContainerGeometry.of(det))

    def objects_and_liquid() -> None:
        for det in objects.detect(frame, context):
            if det.label == "bottle":
                liquid.measure(frame, det.box, ContainerGeometry.of(det))

    def pipeline() -> None:
        tags.detect(frame)
        objects_and_liquid()

    def pipeline_threads() -> None:
        # The runtime's stages are threads of their own: tags beside objects and liquid
        # (pupil-apriltags releases the GIL while it detects).
        worker = threading.Thread(target=tags.detect, args=(frame,))
        worker.start()
        objects_and_liquid()
        worker.join()

    stages = [
        lambda: tags.detect(frame),
        lambda: tags_no_depth.detect(frame),
        lambda: raw.detect(gray),
        lambda: objects.detect(frame, context),
        measure_bottles,
        pipeline,
        pipeline_threads,
    ]
    return [_median_ms(fn, repeats) for fn in stages]


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--profile", choices=("default", "cluttered"), default="default")
    args = parser.parse_args(argv)
    config = load_config(None, [f"sim.profile={args.profile}"])
    tags = TagDetector.from_config(config.tag, ids=[config.tag.id])
    tags_no_depth = TagDetector.from_config(
        config.tag, ids=[config.tag.id], refine_with_depth=False
    )
    raw = pupil_detector(families=config.tag.family, quad_decimate=1.0)
    liquid = LiquidLevelMeter()
    rows: dict[str, list[float]] = {
        "tags (TagDetector, depth refinement)": [],
        "tags without depth refinement": [],
        "raw pupil-apriltags detect (reference)": [],
        "objects (GeometricDetector)": [],
        "liquid (all bottles in the frame)": [],
        "whole pipeline (tags + objects + liquid)": [],
        "whole pipeline, tags in a thread beside objects + liquid": [],
    }
    # Every frame first, then the timing, with no renderer open: MuJoCo's GL context
    # left alive beside the timed code slowed the threaded pipeline by a fifth here.
    scenes = []
    for seed in range(args.scenes):
        with SimWorld(config, seed) as world, SimCamera(world) as camera:
            arm = SimArm(world)
            arm.go_to_sleep_pose()
            world.advance(0.3)
            frame = camera.read()
            q = arm.get_joint_positions()
            scenes.append((frame, FrameContext(T_base_cam=world.T_base_cam(), joint_positions=q)))
    bottles: list[int] = []
    for frame, context in scenes:
        objects = GeometricDetector()
        found = objects.detect(frame, context)  # also builds its per-intrinsics ray cache
        bottles.append(sum(d.label == "bottle" for d in found))
        times = _time_stages(
            frame, context, objects, tags, tags_no_depth, raw, liquid, args.repeats
        )
        for name, ms in zip(rows, times):
            rows[name].append(ms)

    print(
        f"\nPerception per 640x480 frame, median over {args.scenes} simulated {args.profile} "
        f"scenes, {np.mean(bottles):.1f} bottles per frame (2 cores, no GPU)\n"
    )
    print("| stage | median ms | worst scene ms |")
    print("|---|---:|---:|")
    summary = {}
    for name, values in rows.items():
        summary[name] = float(np.median(values))
        print(f"| {name} | {np.median(values):.1f} | {np.max(values):.1f} |")
    ratio = (
        summary["whole pipeline (tags + objects + liquid)"]
        / (summary["raw pupil-apriltags detect (reference)"])
    )
    threaded = (
        summary["whole pipeline, tags in a thread beside objects + liquid"]
        / summary["raw pupil-apriltags detect (reference)"]
    )
    print(f"\nwhole pipeline / raw pupil-apriltags: {ratio:.1f}x ({threaded:.1f}x threaded)")
    summary["pipeline_over_raw_tags"] = ratio
    summary["pipeline_threaded_over_raw_tags"] = threaded
    return summary


if __name__ == "__main__":
    main()
