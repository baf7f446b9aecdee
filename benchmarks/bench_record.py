"""What recording costs: per frame, on the stage that hands it over and on the recorder
thread, at 30 FPS 640x480, and the file size per minute.

Simulated frames of the default scene (rendered once, then cycled, each with a fresh time)
are handed to a :class:`~armvision.runtime.recorder.Recorder` at 30 FPS in real time, with a
joint state at the fusion rate (100 Hz) and a state sample (tracks, markers, health) at
``record.state_hz``, as a running system hands them over. Printed: the time a stage spends
handing a frame over (the only cost recording adds to a stage), the recorder thread's time
per frame (JPEG, 16UC1, CDR, zstd, write), the share of one core it takes, what it dropped,
and the size of the file per minute of recording.

    python benchmarks/bench_record.py [--seconds 60] [--frames 30]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from armvision.bench.system import sim_system
from armvision.camera.frames import RGBDFrame
from armvision.config import Config
from armvision.runtime.recorder import Recorder


def _rendered(config: Config, n: int) -> tuple[list[RGBDFrame], object, tuple[str, ...]]:
    """``n`` frames of a lockstep run of the default scene, and a state sample of it."""
    frames = []
    system = sim_system(config, 0, mode="lockstep")
    with system:
        system.pump(system.clock() + 1.5)  # tracks confirmed, liquid measured
        for _ in range(n):
            frames.append(system.read_frame())
            system.pump(system.clock() + 1.0 / 30)
        state = system.snapshot()
        names = tuple(system.arm.model.joint_names)
    return frames, state, names


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--frames", type=int, default=30, help="distinct frames cycled")
    args = parser.parse_args()
    config = Config()
    frames, state, names = _rendered(config, args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        recorder = Recorder(path, config, wait=False).open()
        recorder.begin(0.0, names)
        hand_over = []
        start = time.monotonic()
        cpu0 = time.thread_time(), resource.getrusage(resource.RUSAGE_SELF)
        i = j = k = 0
        q = np.zeros(6)
        while (now := time.monotonic() - start) < args.seconds:
            due = min((i / 30.0), (j / 100.0), (k / config.record.state_hz))
            if due > now:
                time.sleep(due - now)
                continue
            if due == i / 30.0:
                f = frames[i % len(frames)]
                frame = RGBDFrame(f.color, f.depth, f.intrinsics, i / 30.0, i)
                t0 = time.perf_counter()
                recorder.frame(frame)
                recorder.frame_joints(frame.timestamp, q)
                hand_over.append(time.perf_counter() - t0)
                i += 1
            elif due == j / 100.0:
                recorder.joints(j / 100.0, q)
                j += 1
            else:
                recorder.state_sample(dataclasses.replace(state, time=k / config.record.state_hz))
                k += 1
        elapsed = time.monotonic() - start
        recorder.stop()
        size = path.stat().st_size
        counts = recorder.counts
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (usage.ru_utime + usage.ru_stime) - (cpu0[1].ru_utime + cpu0[1].ru_stime)
    main_cpu = time.thread_time() - cpu0[0]
    per_frame = counts.encode_s / max(counts.frames, 1)
    print(f"recording {args.seconds:.0f} s at 30 FPS 640x480 (+100 Hz joints, "
          f"{config.record.state_hz:.0f} Hz state), {os.cpu_count()} cores")  # fmt: skip
    print("| measure | value |")
    print("|---|---:|")
    print(f"| hand-over per frame, on the stage (median / max) | "
          f"{1e6 * np.median(hand_over):.0f} µs / {1e6 * np.max(hand_over):.0f} µs |")  # fmt: skip
    print(f"| recorder thread per frame (encode + write) | {1000 * per_frame:.1f} ms |")
    print(f"| recorder thread, share of one core | {100 * (cpu - main_cpu) / elapsed:.0f} % |")
    print(f"| frames written / dropped | {counts.frames} / {counts.dropped} |")
    print(f"| file size per minute | {size / 1e6 / elapsed * 60:.0f} MB |")


if __name__ == "__main__":
    main()
