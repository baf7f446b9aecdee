"""Read an ``armvision export-lerobot`` dataset back with LeRobot's own loader and check it
against the recording it came from.

Run it with a Python that has LeRobot (0.4.x, with torch) and the ``mcap`` and
``mcap-ros2-support`` readers; armvision itself is not imported, so the recording is read
independently of the exporter::

    .venv/bin/armvision export-lerobot out/grab.mcap --out out/dataset
    /path/to/lerobot-venv/bin/python benchmarks/check_lerobot.py out/grab.mcap --dataset out/dataset

(several recordings, in the order given to ``export-lerobot``, for a dataset of several).

For the first, middle and last frame of every episode it loads ``LeRobotDataset(repo_id,
root=DIR)[i]`` (the parquet row and the decoded video frame) and checks: episode and frame
index, timestamp (``frame_index / fps``), task text, joint state and action (the newest recorded
joint reading and joint command at that tick, exactly in float32), depth (the very millimetres
of the newest recorded frame) and colour (the video frame within 4/255 of that recorded frame,
and where the arm moved, nearer to it than to the frames beside it). It also checks the totals
and ``meta/stats.json`` against the loaded columns. It prints what it checked and exits 1 on a
mismatch.
"""

from __future__ import annotations

import argparse
import bisect
import io
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

TASK_TOPIC = "/armvision/task"
DEPTH_TOPIC = "/camera/aligned_depth_to_color/image_raw"
COLOR_TOPIC = "/camera/color/image_raw/compressed"
FRAME_CLOCK_TOPIC = "/armvision/frame_clock"
JOINT_TOPICS = ("/vx300s/joint_states", "/armvision/frame_joint_states")
COMMANDS_TOPIC = "/armvision/joint_commands"
TASK_TEXT = {  # the exporter's task texts (armvision.recording.lerobot.TASK_TEXT)
    "grab": "grab a bottle and lift it",
    "analyze": "measure a bottle's liquid level",
    "follow": "follow the target with the gripper",
    "follow_tag": "follow the tag with the gripper",
    "follow_bottle": "follow the bottle with the gripper",
    "home": "move the arm to its home pose",
    "sleep": "fold the arm to its sleep pose",
    "gripper_open": "open the gripper",
    "gripper_close": "close the gripper",
    "calibrate": "calibrate the camera with the gripper tag",
}


def stamp(msg: Any) -> float:
    return (int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)) / 1e9


def messages(path: Path, topics: list[str]) -> Any:
    """(topic, log ns, decoded) in file order, decoded by mcap-ros2-support or json."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    factory, decoders = DecoderFactory(), {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(
            topics=topics, log_time_order=False
        ):
            if channel.message_encoding == "json":
                value = json.loads(message.data)
            else:
                if schema.id not in decoders:
                    decoders[schema.id] = factory.decoder_for(channel.message_encoding, schema)
                value = decoders[schema.id](message.data)
            yield channel.topic, message.log_time, value


class Recorded:
    """What the recording holds: task runs, joint readings and commands, frame times."""

    def __init__(self, path: Path) -> None:
        self.path = path
        runs: dict[int, dict[str, Any]] = {}
        first = last = None
        readings, commands = [], []
        self.frame_times: list[float] = []  # seconds of each complete (colour + depth) frame
        self.frame_ns: list[int] = []
        color_ns = clock = None
        topics = [
            TASK_TOPIC,
            DEPTH_TOPIC,
            COLOR_TOPIC,
            FRAME_CLOCK_TOPIC,
            *JOINT_TOPICS,
            COMMANDS_TOPIC,
        ]
        for topic, ns, value in messages(path, topics):
            if topic in (TASK_TOPIC, DEPTH_TOPIC):
                first = ns / 1e9 if first is None else first
                last = ns / 1e9
            if topic == TASK_TOPIC and value.get("id") and value.get("started") is not None:
                runs.setdefault(int(value["id"]), {}).update(value)
            elif topic in JOINT_TOPICS:
                readings.append((stamp(value), np.asarray(value.position, dtype=float)))
            elif topic == COMMANDS_TOPIC:
                commands.append((stamp(value), np.asarray(value.position, dtype=float)))
            elif topic == FRAME_CLOCK_TOPIC:
                clock = (ns, float(value["t"]))
            elif topic == COLOR_TOPIC:
                color_ns = ns
            elif topic == DEPTH_TOPIC and color_ns == ns:
                t = clock[1] if clock is not None and clock[0] == ns else stamp(value)
                self.frame_times.append(t)
                self.frame_ns.append(ns)
        assert first is not None and last is not None, f"{path} holds no frames"
        self.episodes = sorted(
            (
                float(r["started"]),
                float(r.get("finished") or last),
                TASK_TEXT.get(str(r["name"]), str(r["name"])),
            )
            for r in runs.values()
        ) or [(first, last, "observe the bench")]
        readings.sort(key=lambda p: p[0])
        commands.sort(key=lambda p: p[0])
        self.readings, self.commands = readings, commands

    @staticmethod
    def newest(series: list[tuple[float, np.ndarray]], t: float) -> np.ndarray | None:
        k = bisect.bisect_right([s for s, _ in series], t) - 1
        return None if k < 0 else series[k][1]

    def state(self, t: float) -> np.ndarray:
        q = self.newest(self.readings, t)
        return self.readings[0][1] if q is None else q

    def action(self, t: float) -> np.ndarray:
        target = self.newest(self.commands, t)
        return self.state(t) if target is None else target

    def frame(self, t: float) -> int:
        """The index of the newest frame at or before ``t`` (the first if none is)."""
        k = bisect.bisect_right(self.frame_times, t + 1e-9) - 1
        return max(k, 0)

    def images(self, wanted: set[int]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """(RGB uint8, depth mm uint16) of the frames at ``wanted`` indices."""
        from PIL import Image

        by_ns = {self.frame_ns[i]: i for i in wanted}
        colors: dict[int, np.ndarray] = {}
        out = {}
        for topic, ns, value in messages(self.path, [COLOR_TOPIC, DEPTH_TOPIC]):
            if ns not in by_ns:
                continue
            if topic == COLOR_TOPIC:
                colors[ns] = np.asarray(Image.open(io.BytesIO(bytes(value.data))).convert("RGB"))
            elif ns in colors:
                assert value.encoding == "16UC1", value.encoding
                h, w = int(value.height), int(value.width)
                raw = np.frombuffer(bytes(value.data), dtype=">u2" if value.is_bigendian else "<u2")
                depth = raw.reshape(h, int(value.step) // 2)[:, :w]
                out[by_ns[ns]] = (colors.pop(ns), np.minimum(depth, 32767))
        return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", type=Path, nargs="+", metavar="RECORDING.mcap")
    parser.add_argument("--dataset", type=Path, required=True, metavar="DIR")
    parser.add_argument("--repo-id", default="local/armvision")
    parser.add_argument(
        "--video-backend", default=None, help="torchcodec (LeRobot's default) or pyav"
    )
    args = parser.parse_args()

    import lerobot
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    failures: list[str] = []

    def check(ok: bool, what: str) -> None:
        print(("ok   " if ok else "FAIL ") + what)
        if not ok:
            failures.append(what)

    ds = LeRobotDataset(args.repo_id, root=args.dataset, video_backend=args.video_backend)
    meta = ds.meta
    print(
        f"LeRobot {lerobot.__version__}: LeRobotDataset({args.repo_id!r}, "
        f"root={str(args.dataset)!r}) read codebase {meta.info['codebase_version']}, "
        f"{ds.num_episodes} episode(s), "
        f"{len(ds)} frames at {ds.fps} FPS, video backend {ds.video_backend}"
    )
    recordings = [Recorded(path) for path in args.recordings]
    runs = [(rec, *span) for rec in recordings for span in rec.episodes]
    fps = ds.fps
    check(
        ds.num_episodes == len(runs),
        f"{ds.num_episodes} episode(s), the recordings' task runs: {len(runs)}",
    )
    lengths = [int(meta.episodes[e]["length"]) for e in range(ds.num_episodes)]
    check(
        sum(lengths) == len(ds) == meta.total_frames, f"episode lengths {lengths} sum to {len(ds)}"
    )
    picks: list[tuple[int, int, float]] = []  # (dataset index, episode, recording seconds)
    for e, (_, start, end, task) in enumerate(runs[: ds.num_episodes]):
        ep = meta.episodes[e]
        expected = int(np.floor((end - start) * fps + 1e-9)) + 1
        check(
            ep["tasks"] == [task] and abs(ep["length"] - expected) <= 1,
            f"episode {e}: task {ep['tasks']}, {ep['length']} frames ({end - start:.3f} s), "
            f"video from {ep['videos/observation.images.color/from_timestamp']:.3f} s of "
            f"file {ep['videos/observation.images.color/file_index']}",
        )
        n = int(ep["length"])
        for k in sorted({0, n // 2, n - 1}):
            picks.append((int(ep["dataset_from_index"]) + k, e, start + k / fps))
    frames = {i: runs[e][0].frame(t) for i, e, t in picks}
    images: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for rec in recordings:
        wanted = {frames[i] for i, e, _ in picks if runs[e][0] is rec}
        wanted |= {j for i in wanted for j in (i - 1, i + 1) if 0 <= j < len(rec.frame_times)}
        images[id(rec)] = rec.images(wanted)
    for i, e, t in picks:
        item = ds[i]
        rec, start, _, task = runs[e]
        shots = images[id(rec)]
        k = round((t - start) * fps)
        where = f"frame {i} (episode {e}, frame {k})"
        check(
            int(item["episode_index"]) == e
            and int(item["frame_index"]) == k
            and int(item["index"]) == i,
            f"{where}: episode_index, frame_index, index",
        )
        check(
            abs(float(item["timestamp"]) - k / fps) < 1e-6,
            f"{where}: timestamp {float(item['timestamp']):.6f} s = {k}/{fps}",
        )
        check(item["task"] == task, f"{where}: task {item['task']!r}")
        state = item["observation.state"].numpy()
        want = rec.state(t).astype(np.float32)
        check(np.array_equal(state, want), f"{where}: observation.state {np.round(state, 4)}")
        action = item["action"].numpy()
        want = rec.action(t).astype(np.float32)
        check(np.array_equal(action, want), f"{where}: action {np.round(action, 4)}")
        j = frames[i]
        _, depth = shots[j]
        got_depth = item["observation.images.depth"]
        check(
            got_depth.dtype == torch.int16
            and tuple(got_depth.shape) == (1, *depth.shape)
            and np.array_equal(got_depth[0].numpy().astype(np.uint16), depth),
            f"{where}: depth {tuple(got_depth.shape)} {got_depth.dtype} = recorded frame {j}'s "
            f"millimetres (median {int(np.median(depth))} mm)",
        )
        video = item["observation.images.color"]
        rgb = (video.permute(1, 2, 0).numpy() * 255.0).astype(np.float64)
        own = float(np.abs(rgb - shots[j][0]).mean())
        # Where the frames beside it differ from it (the arm moving), the video frame must be
        # nearest to its own; a still arm's frames beside it are all but the same.
        beside = [m for m in (j - 1, j + 1) if m in shots]
        moved = np.zeros(depth.shape, dtype=bool)
        for m in beside:
            moved |= np.abs(shots[m][0].astype(float) - shots[j][0]).sum(axis=2) > 30
        near = {m: float(np.abs(rgb[moved] - shots[m][0][moved]).mean()) for m in (j, *beside)}
        nearest = moved.sum() < 500 or all(near[j] < near[m] for m in beside)
        there = (
            "the arm still beside it"
            if moved.sum() < 500
            else f"{near[j]:.1f} where {int(moved.sum())} pixels moved, "
            + ", ".join(f"{near[m]:.1f}" for m in beside)
            + " to the frames beside it"
        )
        check(
            tuple(video.shape) == (3, *depth.shape) and own < 4.0 and nearest,
            f"{where}: video frame {tuple(video.shape)} is recorded frame {j}'s colour (mean "
            f"|diff| {own:.2f}/255; {there})",
        )
    columns = ds.hf_dataset.with_format("numpy")
    for key in ("observation.state", "action"):
        values = np.stack(columns[key])
        s = meta.stats[key]
        check(
            np.allclose(s["min"], values.min(0))
            and np.allclose(s["max"], values.max(0))
            and np.allclose(s["mean"], values.mean(0), atol=1e-6)
            and int(s["count"][0]) == len(values),
            f"stats.json {key}: min, max, mean and count of the {len(values)} loaded rows",
        )
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    names = ", ".join(str(p) for p in args.recordings)
    print(f"all {len(picks)} frames checked and the totals match the recording(s) {names}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
