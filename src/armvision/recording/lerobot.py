"""Recordings exported as a LeRobot dataset (``armvision export-lerobot``), without LeRobot.

The on-disk layout is LeRobot's ``v3.0`` (``codebase_version`` in ``meta/info.json``), the one
LeRobot 0.4's ``LeRobotDataset`` reads (it refuses ``v2.1``). Episodes share files, found
through the episodes metadata:

- ``meta/info.json``: fps (a whole number), totals, ``chunks_size``, ``data_files_size_in_mb``,
  ``video_files_size_in_mb``, the ``data_path`` and ``video_path`` templates and the features;
- ``meta/tasks.parquet``: ``task_index`` with the task text as its (pandas) index;
- ``meta/episodes/chunk-000/file-000.parquet``: a row per episode: ``episode_index``,
  ``tasks``, ``length``, ``data/chunk_index``, ``data/file_index``, ``dataset_from_index``,
  ``dataset_to_index``, ``videos/KEY/{chunk_index,file_index,from_timestamp,to_timestamp}``,
  ``meta/episodes/{chunk_index,file_index}`` and the episode's statistics as
  ``stats/FEATURE/{min,max,mean,std,count,q01,q10,q50,q90,q99}``;
- ``meta/stats.json``: the same statistics over the whole dataset;
- ``data/chunk-000/file-000.parquet``: a row per frame: ``observation.images.depth`` (16-bit PNG
  of millimetres in Hugging Face's image struct ``{bytes, path}``), ``observation.state`` (the
  six joint readings, rad, float32), ``action`` (the joint target the arm was last commanded,
  rad; the reading itself before the first command), ``timestamp`` (s from the episode's start),
  ``frame_index``, ``episode_index``, ``index``, ``task_index``; a new file (``file-001``...)
  when one would pass ``data_files_size_in_mb``, an episode never split;
- ``videos/observation.images.color/chunk-000/file-000.mp4``: the colour frames of the
  episodes one after the other (MPEG-4 Part 2, the codec OpenCV's wheels write), an episode's
  frames from its ``from_timestamp``; a new file past ``video_files_size_in_mb``.

Statistics are exact (over every frame and pixel, quantiles the smallest value reaching the
fraction): vectors per dimension; colour per RGB channel in 0..1, shaped [3, 1, 1]; depth in
millimetres, shaped [1, 1, 1], the units LeRobot's loader gives it in (a 16-bit PNG becomes an
int16 tensor, so depth is clipped to 32767 mm). ``count`` is the frames.

An episode is one task run of a recording (from its start to its end as the recorded task
status has them); a recording with no task is one episode, ``observe the bench``. Frames are
taken at ``fps`` (default the recording's camera rate): the newest recorded frame at each
tick, so the timestamps are exactly ``frame_index / fps`` as LeRobot requires.
"""

from __future__ import annotations

import bisect
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

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
TASKS_PATH = "meta/tasks.parquet"
STATS_PATH = "meta/stats.json"
COLOR_KEY = "observation.images.color"
DEPTH_KEY = "observation.images.depth"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
DEPTH_MAX_MM = 32767  # LeRobot reads a 16-bit PNG as int16
ROWS_PER_GROUP = 256  # frames buffered before a parquet row group is written
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
_INDEX_KEYS = ("frame_index", "episode_index", "index", "task_index")


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


def depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """A depth image in metres as the exported uint16 millimetres (0 = none, at most 32767)."""
    mm = np.rint(np.nan_to_num(depth_m, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float64) * 1e3)
    return np.clip(mm, 0, DEPTH_MAX_MM).astype(np.uint16)


def _png16(mm: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", mm)
    if not ok:
        raise ArmvisionError("PNG encoding of a depth frame failed")
    return buf.tobytes()


def _next_file(chunk: int, file: int) -> tuple[int, int]:
    """LeRobot's next (chunk, file) index: ``chunks_size`` files a chunk."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


def _quantile_keys() -> list[str]:
    return [f"q{round(q * 100):02d}" for q in QUANTILES]


def vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's statistics of a feature over its frames (the first axis): min, max, mean, std,
    count and quantiles, each shaped like one frame's value ([1] for a scalar)."""
    v = np.asarray(values)
    v = v.reshape(len(v), -1)
    out = {"min": v.min(axis=0), "max": v.max(axis=0),
           "mean": v.mean(axis=0, dtype=np.float64), "std": v.std(axis=0, dtype=np.float64),
           "count": np.array([len(v)])}  # fmt: skip
    for key, q in zip(_quantile_keys(), QUANTILES, strict=True):
        out[key] = np.quantile(v.astype(np.float64), q, axis=0, method="inverted_cdf")
    return out


def histogram_stats(hist: np.ndarray, frames: int, scale: float) -> dict[str, np.ndarray]:
    """Per-channel statistics of an image feature from its histograms ([C, levels] counts of
    the integer pixel values), times ``scale``, shaped [C, 1, 1] as LeRobot's."""
    hist = np.asarray(hist, dtype=np.float64)
    levels = np.arange(hist.shape[1], dtype=np.float64)
    n = hist.sum(axis=1)
    mean = (hist * levels).sum(axis=1) / n
    var = (hist * (levels - mean[:, None]) ** 2).sum(axis=1) / n
    cdf = np.cumsum(hist, axis=1)
    seen = hist > 0
    out = {
        "min": np.argmax(seen, axis=1).astype(np.float64),
        "max": (hist.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)).astype(np.float64),
        "mean": mean,
        "std": np.sqrt(var),
    }
    for key, q in zip(_quantile_keys(), QUANTILES, strict=True):
        # the smallest value whose cumulative count reaches q of the pixels (inverted CDF)
        out[key] = np.array([np.searchsorted(c, q * t) for c, t in zip(cdf, n, strict=True)],
                            dtype=np.float64)  # fmt: skip
    shaped = {k: (v * scale).reshape(-1, 1, 1) for k, v in out.items()}
    return {**shaped, "count": np.array([frames])}


def _listed(stats: dict[str, np.ndarray]) -> dict[str, Any]:
    return {k: v.tolist() for k, v in stats.items()}


class _Files:
    """Files of one kind filled one after another, a new one (LeRobot's next chunk/file index)
    when the next episode would take the current one past ``limit_mb``, reckoned as LeRobot
    does from the size so far and its frames (an open mp4's size is what the encoder has
    flushed, a little behind)."""

    def __init__(self, limit_mb: float) -> None:
        self.limit = limit_mb * 1024 * 1024
        self.chunk = self.file = 0
        self.frames = 0  # in the current file

    def start_episode(self, size_now: float, frames: int) -> bool:
        """Place an episode of about ``frames`` frames; whether it starts a new file."""
        if self.frames and size_now + size_now / self.frames * frames >= self.limit:
            self.chunk, self.file = _next_file(self.chunk, self.file)
            self.frames = 0
            return True
        return False


class _Video:
    """The colour frames of consecutive episodes in mp4 files (``VIDEO_PATH``)."""

    def __init__(self, out: Path, fps: int, size: tuple[int, int]) -> None:
        self.out, self.fps, self.size = out, fps, size
        self.files = _Files(VIDEO_FILES_SIZE_IN_MB)
        self.writer: cv2.VideoWriter | None = None
        self.path: Path | None = None

    def start_episode(self, frames: int) -> dict[str, Any]:
        size_now = self.path.stat().st_size if self.path and self.path.exists() else 0
        if self.files.start_episode(size_now, frames) or self.writer is None:
            self.close()
            self.path = self.out / VIDEO_PATH.format(
                video_key=COLOR_KEY, chunk_index=self.files.chunk, file_index=self.files.file
            )
            self.path.parent.mkdir(parents=True, exist_ok=True)
            h, w = self.size
            self.writer = cv2.VideoWriter(
                str(self.path), cv2.VideoWriter.fourcc(*"mp4v"), float(self.fps), (w, h)
            )
            if not self.writer.isOpened():
                raise ArmvisionError(f"cannot write the video {self.path}")
        prefix = f"videos/{COLOR_KEY}/"
        return {prefix + "chunk_index": self.files.chunk, prefix + "file_index": self.files.file,
                prefix + "from_timestamp": self.files.frames / self.fps}  # fmt: skip

    def write(self, rgb: np.ndarray) -> None:
        assert self.writer is not None
        self.writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        self.files.frames += 1

    def end_episode(self) -> dict[str, Any]:
        return {f"videos/{COLOR_KEY}/to_timestamp": self.files.frames / self.fps}

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()
            self.writer = None


class _Data:
    """The frame rows of consecutive episodes in parquet files (``DATA_PATH``), written a row
    group at a time with Hugging Face's features in the schema metadata, as LeRobot writes."""

    def __init__(self, out: Path, schema: Any) -> None:
        self.out, self.schema = out, schema
        self.files = _Files(DATA_FILES_SIZE_IN_MB)
        self.writer: Any = None
        self.bytes = 0

    def start_episode(self, frames: int) -> dict[str, Any]:
        import pyarrow.parquet as pq

        if self.files.start_episode(self.bytes, frames) or self.writer is None:
            self.close()
            path = self.out / DATA_PATH.format(
                chunk_index=self.files.chunk, file_index=self.files.file
            )
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(path, self.schema, compression="snappy")
            self.bytes = 0
        return {"data/chunk_index": self.files.chunk, "data/file_index": self.files.file}

    def write(self, rows: dict[str, list[Any]]) -> None:
        import pyarrow as pa

        if not rows["index"]:
            return
        table = pa.Table.from_pydict(rows, schema=self.schema)
        self.writer.write_table(table)
        self.bytes += table.nbytes
        self.files.frames += table.num_rows
        for values in rows.values():
            values.clear()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def _frame_schema(n_joints: int) -> Any:
    import pyarrow as pa

    vector = pa.list_(pa.float32(), n_joints)
    fields = [
        (DEPTH_KEY, pa.struct([("bytes", pa.binary()), ("path", pa.string())])),
        ("observation.state", vector),
        ("action", vector),
        ("timestamp", pa.float32()),
        *((key, pa.int64()) for key in _INDEX_KEYS),
    ]
    sequence = {"feature": {"dtype": "float32", "_type": "Value"}, "length": n_joints,
                "_type": "List"}  # fmt: skip
    features = {DEPTH_KEY: {"_type": "Image"}, "observation.state": sequence, "action": sequence,
                "timestamp": {"dtype": "float32", "_type": "Value"},
                **{key: {"dtype": "int64", "_type": "Value"} for key in _INDEX_KEYS}}  # fmt: skip
    meta = {"huggingface": json.dumps({"info": {"features": features}})}
    return pa.schema(fields, metadata=meta)


def _write_tasks(path: Path, tasks: dict[str, int]) -> None:
    """``meta/tasks.parquet`` as pandas writes a frame of ``task_index`` indexed by the task
    text (LeRobot reads it with ``pandas.read_parquet``), without pandas."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    index = "__index_level_0__"
    pandas_meta = {
        "index_columns": [index],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": None, "field_name": index, "pandas_type": "unicode", "numpy_type": "object",
             "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
    }  # fmt: skip
    ordered = sorted(tasks.items(), key=lambda item: item[1])
    table = pa.table(
        {
            "task_index": pa.array([i for _, i in ordered], pa.int64()),
            index: pa.array([t for t, _ in ordered], pa.string()),
        }
    ).replace_schema_metadata({"pandas": json.dumps(pandas_meta)})
    pq.write_table(table, path)


def _frame_rate(recording: Recording, fps: float | None) -> int:
    if fps is None:
        config = recording.first("/armvision/config")
        fps = float(config.value["camera"]["fps"]) if config else 30.0
    if not (fps > 0 and abs(fps - round(fps)) < 1e-9):
        raise ArmvisionError(
            f"LeRobot datasets take a whole number of frames a second, not {fps:g}: give --fps N"
        )
    return round(fps)


def export_lerobot(
    paths: Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str],
    fps: float | None = None, robot_type: str = "vx300s",
) -> dict[str, Any]:  # fmt: skip
    """Write the episodes of the recordings at ``paths`` as a LeRobot ``v3.0`` dataset in
    ``out_dir`` (which must be empty or new); the ``meta/info.json`` written."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise ArmvisionError(f"{out} is not empty: choose a new or empty --out")
    recordings = [Recording(p) for p in paths]
    episodes = [e for r in recordings for e in episodes_of(r)]
    rate = _frame_rate(recordings[0], fps)
    names: tuple[str, ...] = ()
    size: tuple[int, int] | None = None
    tasks: dict[str, int] = {}
    video: _Video | None = None
    data: _Data | None = None
    episode_rows: list[dict[str, Any]] = []
    all_vectors: dict[str, list[np.ndarray]] = {}
    all_color = np.zeros((3, 256), dtype=np.int64)
    all_depth = np.zeros((1, DEPTH_MAX_MM + 1), dtype=np.int64)
    total = 0
    try:
        for index, episode in enumerate(episodes):
            recording = Recording(episode.path)
            readings = _Series(recording, [ros.JOINTS_TOPIC, ros.FRAME_JOINTS_TOPIC])
            commands = _Series(recording, [ros.COMMANDS_TOPIC])
            if not names:
                msg = recording.first(ros.JOINTS_TOPIC) or recording.first(ros.FRAME_JOINTS_TOPIC)
                names = tuple(msg.value.name) if msg else tuple(f"joint{i}" for i in range(6))
            if data is None:
                data = _Data(out, _frame_schema(len(names)))
            task_index = tasks.setdefault(episode.task, len(tasks))
            expected = int((episode.end - episode.start) * rate + 1e-6) + 1
            meta: dict[str, Any] = {"episode_index": index, "tasks": [episode.task]}
            rows: dict[str, list[Any]] = {name: [] for name in data.schema.names}
            keys = ("observation.state", "action", "timestamp", *_INDEX_KEYS)
            vectors: dict[str, list[Any]] = {key: [] for key in keys}
            color_hist = np.zeros((3, 256), dtype=np.int64)
            depth_hist = np.zeros((1, DEPTH_MAX_MM + 1), dtype=np.int64)
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
                if k == 0:
                    h, w = current.depth.shape
                    if size is not None and size != (h, w):
                        raise ArmvisionError(
                            f"{episode.path}: frames of {w}x{h}, not the {size[1]}x{size[0]} "
                            "of the dataset's first recording; export them apart"
                        )
                    size = (h, w)
                    video = video or _Video(out, rate, size)
                    meta.update(data.start_episode(expected))
                    meta.update(video.start_episode(expected))
                assert video is not None
                q = readings.at(t)
                if q is None:
                    q = readings.values[0] if readings.values else np.zeros(len(names))
                target = commands.at(t)
                action = q if target is None else target
                video.write(current.color)
                for c in range(3):
                    color_hist[c] += np.bincount(current.color[..., c].ravel(), minlength=256)
                mm = depth_mm(current.depth)
                depth_hist[0] += np.bincount(mm.ravel(), minlength=DEPTH_MAX_MM + 1)
                values = {"observation.state": np.asarray(q, dtype=np.float32),
                          "action": np.asarray(action, dtype=np.float32),
                          "timestamp": np.float32(k / rate), "frame_index": k,
                          "episode_index": index, "index": total + k,
                          "task_index": task_index}  # fmt: skip
                for key, value in values.items():
                    vectors[key].append(value)
                    rows[key].append(np.asarray(value).tolist())
                rows[DEPTH_KEY].append({"bytes": _png16(mm), "path": None})
                k += 1
                if k % ROWS_PER_GROUP == 0:
                    data.write(rows)
            if k == 0:
                raise ArmvisionError(
                    f"{episode.path}: the episode '{episode.task}' holds no frames"
                )
            assert video is not None
            data.write(rows)
            meta.update(video.end_episode())
            stats: dict[str, dict[str, np.ndarray]] = {
                COLOR_KEY: histogram_stats(color_hist, k, 1 / 255),
                DEPTH_KEY: histogram_stats(depth_hist, k, 1.0),
            }
            for key, series in vectors.items():
                column = np.asarray(series)
                stats[key] = vector_stats(column)
                all_vectors.setdefault(key, []).append(column)
            all_color += color_hist
            all_depth += depth_hist
            meta.update(length=k, dataset_from_index=total, dataset_to_index=total + k)
            meta.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
            for key, feature in stats.items():
                for stat, value in _listed(feature).items():
                    meta[f"stats/{key}/{stat}"] = value
            episode_rows.append(meta)
            total += k
    finally:
        if video is not None:
            video.close()
        if data is not None:
            data.close()
    assert size is not None
    h, w = size
    episodes_path = out / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), episodes_path)
    _write_tasks(out / TASKS_PATH, tasks)
    stats_all = {
        COLOR_KEY: histogram_stats(all_color, total, 1 / 255),
        DEPTH_KEY: histogram_stats(all_depth, total, 1.0),
        **{key: vector_stats(np.concatenate(parts)) for key, parts in all_vectors.items()},
    }
    (out / STATS_PATH).write_text(
        json.dumps({k: _listed(v) for k, v in stats_all.items()}, indent=4)
    )
    scalar = {"shape": [1], "names": None}
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": len(episodes),
        "total_frames": total,
        "total_tasks": len(tasks),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": rate,
        "splits": {"train": f"0:{len(episodes)}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH,
        "features": {
            COLOR_KEY: {
                "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channel"],
                "info": {"video.height": h, "video.width": w, "video.codec": "mpeg4",
                         "video.pix_fmt": "yuv420p", "video.is_depth_map": False,
                         "video.fps": rate, "video.channels": 3, "has_audio": False},
            },
            DEPTH_KEY: {"dtype": "image", "shape": [h, w, 1],
                        "names": ["height", "width", "channel"]},
            "observation.state": {"dtype": "float32", "shape": [len(names)], "names": list(names)},
            "action": {"dtype": "float32", "shape": [len(names)], "names": list(names)},
            "timestamp": {"dtype": "float32", **scalar},
            **{key: {"dtype": "int64", **scalar} for key in _INDEX_KEYS},
        },
    }  # fmt: skip
    (out / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    return info
