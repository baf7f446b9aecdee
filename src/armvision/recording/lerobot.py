"""Recordings exported as a LeRobot dataset (``armvision export-lerobot``), without LeRobot.

The on-disk layout is LeRobot's ``v2.1`` (``codebase_version`` in ``meta/info.json``), which
LeRobot's loader reads and converts to its newer layout with its own script:

- ``meta/info.json``: fps, totals, path templates and the features below;
- ``meta/episodes.jsonl`` (``episode_index``, ``tasks``, ``length``), ``meta/tasks.jsonl``
  (``task_index``, ``task``), ``meta/episodes_stats.jsonl`` (per episode and feature: min,
  max, mean, std, count; images per channel, in 0..1, shaped [C, 1, 1]);
- ``data/chunk-000/episode_000000.parquet``: a row per frame: ``observation.state`` (the six
  joint readings, rad, float32), ``action`` (the joint target the arm was last commanded, rad;
  the reading itself before the first command), ``observation.images.depth`` (16-bit PNG of
  millimetres, LeRobot's image struct ``{bytes, path}``), ``timestamp`` (s from the episode's
  start), ``frame_index``, ``episode_index``, ``index``, ``task_index``;
- ``videos/chunk-000/observation.images.color/episode_000000.mp4``: the colour frames.

An episode is one task run of a recording (from its start to its end as the recorded task
status has them); a recording with no task is one episode, ``observe the bench``. Frames are
taken at ``fps`` (default the recording's camera rate): the newest recorded frame at each
tick, so the timestamps are exactly ``frame_index / fps`` as LeRobot requires.
"""

from __future__ import annotations

import bisect
import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from armvision.errors import ArmvisionError
from armvision.recording import ros
from armvision.recording.reader import Recording
from armvision.recording.sources import recorded_frames

CODEBASE_VERSION = "v2.1"
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
VIDEO_PATH = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
COLOR_KEY = "observation.images.color"
DEPTH_KEY = "observation.images.depth"
TASK_TEXT = {
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
NO_TASK = "observe the bench"


@dataclass(frozen=True)
class Episode:
    """A span of a recording: ``start``..``end`` clock seconds, and what was done."""

    path: Path
    start: float
    end: float
    task: str


def episodes_of(recording: Recording) -> list[Episode]:
    """The task runs of a recording (from the recorded task status), or all of it."""
    runs: dict[int, dict[str, Any]] = {}
    first = last = None
    for msg in recording.messages(["/armvision/task", ros.DEPTH_TOPIC]):
        first = msg.t if first is None else first
        last = msg.t
        if msg.topic != "/armvision/task":
            continue
        status = msg.value
        if status.get("id") and status.get("started") is not None:
            runs.setdefault(int(status["id"]), {}).update(status)
    if first is None or last is None:
        raise ArmvisionError(f"{recording.path} holds no frames to export")
    out = []
    for status in runs.values():
        end = status.get("finished") or last
        name = str(status.get("name"))
        out.append(Episode(recording.path, float(status["started"]), float(end),
                           TASK_TEXT.get(name, name)))  # fmt: skip
    return sorted(out, key=lambda e: e.start) or [Episode(recording.path, first, last, NO_TASK)]


class _Series:
    """Joint vectors by time: the newest at or before a time."""

    def __init__(self, recording: Recording, topics: Sequence[str]) -> None:
        pairs = [(ros.seconds(m.value.header.stamp), np.asarray(m.value.position, dtype=float))
                 for m in recording.messages(topics)]  # fmt: skip
        pairs.sort(key=lambda p: p[0])
        self.times = [t for t, _ in pairs]
        self.values = [q for _, q in pairs]

    def at(self, t: float) -> np.ndarray | None:
        k = bisect.bisect_right(self.times, t) - 1
        return None if k < 0 else self.values[k]


def _png16(depth_m: np.ndarray) -> bytes:
    mm = np.rint(np.clip(np.nan_to_num(depth_m), 0.0, 65.535) * 1000.0).astype(np.uint16)
    ok, buf = cv2.imencode(".png", mm)
    if not ok:
        raise ArmvisionError("PNG encoding of a depth frame failed")
    return buf.tobytes()


def _stats(values: np.ndarray) -> dict[str, list[Any]]:
    """min, max, mean, std over the first axis; count."""
    v = np.asarray(values, dtype=np.float64)
    return {
        "min": np.min(v, axis=0).tolist(),
        "max": np.max(v, axis=0).tolist(),
        "mean": np.mean(v, axis=0).tolist(),
        "std": np.std(v, axis=0).tolist(),
        "count": [int(v.shape[0])],
    }


def _image_stats(sums: np.ndarray, squares: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 n: int) -> dict[str, list[Any]]:  # fmt: skip
    """Per-channel image statistics (values in 0..1) shaped [C, 1, 1], as LeRobot's."""
    mean = sums / n
    std = np.sqrt(np.maximum(squares / n - mean**2, 0.0))

    def shaped(a: np.ndarray) -> list[Any]:
        return np.asarray(a, dtype=float).reshape(-1, 1, 1).tolist()

    return {"min": shaped(lo), "max": shaped(hi), "mean": shaped(mean), "std": shaped(std),
            "count": [n]}  # fmt: skip


def export_lerobot(
    paths: Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str],
    fps: float | None = None, robot_type: str = "vx300s",
) -> dict[str, Any]:  # fmt: skip
    """Write the episodes of the recordings at ``paths`` as a LeRobot dataset in ``out_dir``
    (which must not hold one yet); the ``meta/info.json`` written."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(out_dir)
    if (out / "meta" / "info.json").exists():
        raise ArmvisionError(f"{out} already holds a dataset: choose an empty --out")
    recordings = [Recording(p) for p in paths]
    episodes = [e for r in recordings for e in episodes_of(r)]
    names: tuple[str, ...] = ()
    size: tuple[int, int] | None = None
    tasks: dict[str, int] = {}
    total = 0
    stats_lines, episode_lines = [], []
    rate = fps
    for index, episode in enumerate(episodes):
        recording = Recording(episode.path)
        if rate is None:
            config = recording.first("/armvision/config")
            rate = float(config.value["camera"]["fps"]) if config else 30.0
        readings = _Series(recording, [ros.JOINTS_TOPIC, ros.FRAME_JOINTS_TOPIC])
        commands = _Series(recording, [ros.COMMANDS_TOPIC])
        if not names:
            joint_msg = recording.first(ros.JOINTS_TOPIC) or recording.first(ros.FRAME_JOINTS_TOPIC)
            names = (
                tuple(joint_msg.value.name) if joint_msg else tuple(f"joint{i}" for i in range(6))
            )
        task_index = tasks.setdefault(episode.task, len(tasks))
        chunk = index // CHUNKS_SIZE
        video = out / VIDEO_PATH.format(
            episode_chunk=chunk, video_key=COLOR_KEY, episode_index=index
        )
        video.parent.mkdir(parents=True, exist_ok=True)
        writer = None
        rows: dict[str, list[Any]] = {k: [] for k in (
            "observation.state", "action", DEPTH_KEY, "timestamp", "frame_index",
            "episode_index", "index", "task_index")}  # fmt: skip
        sums = squares = lo = hi = None
        dsum = dsq = 0.0
        dlo, dhi = np.inf, -np.inf
        frames = recorded_frames(recording)
        current = None
        pending = next(frames, None)
        k = 0
        while True:
            t = episode.start + k / rate
            if t > episode.end + 1e-9:
                break
            while pending is not None and pending[0].timestamp <= t + 1e-9:
                current, pending = pending[0], next(frames, None)
            if current is None:  # no frame yet: the first one stands in
                if pending is None:
                    break
                current = pending[0]
            q = readings.at(t)
            if q is None:
                q = readings.values[0] if readings.values else np.zeros(len(names))
            target = commands.at(t)
            action = q if target is None else target
            h, w = current.depth.shape
            size = size or (h, w)
            if writer is None:
                fourcc = cv2.VideoWriter.fourcc(*"mp4v")
                writer = cv2.VideoWriter(str(video), fourcc, float(rate), (w, h))
                if not writer.isOpened():
                    raise ArmvisionError(f"cannot write the video {video}")
            writer.write(cv2.cvtColor(current.color, cv2.COLOR_RGB2BGR))
            rgb = current.color.reshape(-1, 3).astype(np.float64) / 255.0
            s, s2 = rgb.sum(axis=0), (rgb**2).sum(axis=0)
            sums = s if sums is None else sums + s
            squares = s2 if squares is None else squares + s2
            lo = rgb.min(axis=0) if lo is None else np.minimum(lo, rgb.min(axis=0))
            hi = rgb.max(axis=0) if hi is None else np.maximum(hi, rgb.max(axis=0))
            depth_u = np.clip(current.depth.astype(np.float64) * 1000.0, 0, 65535) / 65535.0
            dsum, dsq = dsum + depth_u.sum(), dsq + (depth_u**2).sum()
            dlo, dhi = min(dlo, float(depth_u.min())), max(dhi, float(depth_u.max()))
            rows["observation.state"].append(np.asarray(q, dtype=np.float32).tolist())
            rows["action"].append(np.asarray(action, dtype=np.float32).tolist())
            rows[DEPTH_KEY].append({"bytes": _png16(current.depth), "path": None})
            rows["timestamp"].append(np.float32(k / rate))
            rows["frame_index"].append(k)
            rows["episode_index"].append(index)
            rows["index"].append(total + k)
            rows["task_index"].append(task_index)
            k += 1
        if writer is not None:
            writer.release()
        if k == 0:
            raise ArmvisionError(f"{episode.path}: the episode '{episode.task}' holds no frames")
        vector = pa.list_(pa.float32())
        table = pa.table({
            "observation.state": pa.array(rows["observation.state"], vector),
            "action": pa.array(rows["action"], vector),
            DEPTH_KEY: pa.array(rows[DEPTH_KEY], pa.struct([("bytes", pa.binary()),
                                                              ("path", pa.string())])),
            "timestamp": pa.array(rows["timestamp"], pa.float32()),
            "frame_index": pa.array(rows["frame_index"], pa.int64()),
            "episode_index": pa.array(rows["episode_index"], pa.int64()),
            "index": pa.array(rows["index"], pa.int64()),
            "task_index": pa.array(rows["task_index"], pa.int64()),
        })  # fmt: skip
        data = out / DATA_PATH.format(episode_chunk=chunk, episode_index=index)
        data.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, data)
        assert sums is not None and squares is not None and lo is not None and hi is not None
        assert size is not None
        n_pixels = k * size[0] * size[1]
        stats = {
            key: _stats(np.asarray(rows[key]).reshape(k, -1))
            for key in ("observation.state", "action", "timestamp", "frame_index",
                        "episode_index", "index", "task_index")
        }  # fmt: skip
        stats[COLOR_KEY] = _image_stats(sums, squares, lo, hi, n_pixels)
        stats[DEPTH_KEY] = _image_stats(
            np.array([dsum]), np.array([dsq]), np.array([dlo]), np.array([dhi]), n_pixels
        )
        stats_lines.append({"episode_index": index, "stats": stats})
        episode_lines.append({"episode_index": index, "tasks": [episode.task], "length": k})
        total += k
    assert size is not None and rate is not None
    h, w = size
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": len(episodes),
        "total_frames": total,
        "total_tasks": len(tasks),
        "total_videos": len(episodes),
        "total_chunks": (len(episodes) - 1) // CHUNKS_SIZE + 1,
        "chunks_size": CHUNKS_SIZE,
        "fps": rate,
        "splits": {"train": f"0:{len(episodes)}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH,
        "features": {
            COLOR_KEY: {
                "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channel"],
                "info": {"video.fps": rate, "video.height": h, "video.width": w,
                         "video.channels": 3, "video.codec": "mpeg4", "video.pix_fmt": "yuv420p",
                         "video.is_depth_map": False, "has_audio": False},
            },
            DEPTH_KEY: {"dtype": "image", "shape": [h, w, 1],
                        "names": ["height", "width", "channel"]},
            "observation.state": {"dtype": "float32", "shape": [len(names)], "names": list(names)},
            "action": {"dtype": "float32", "shape": [len(names)], "names": list(names)},
            "timestamp": {"dtype": "float32", "shape": [1], "names": None},
            "frame_index": {"dtype": "int64", "shape": [1], "names": None},
            "episode_index": {"dtype": "int64", "shape": [1], "names": None},
            "index": {"dtype": "int64", "shape": [1], "names": None},
            "task_index": {"dtype": "int64", "shape": [1], "names": None},
        },
    }  # fmt: skip
    meta = out / "meta"
    meta.mkdir(parents=True, exist_ok=True)
    (meta / "info.json").write_text(json.dumps(info, indent=4))
    _jsonl(meta / "episodes.jsonl", episode_lines)
    _jsonl(meta / "tasks.jsonl", [{"task_index": i, "task": t} for t, i in tasks.items()])
    _jsonl(meta / "episodes_stats.jsonl", stats_lines)
    return info


def _jsonl(path: Path, lines: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    for line in lines:
        buf.write(json.dumps(line) + "\n")
    path.write_text(buf.getvalue())
