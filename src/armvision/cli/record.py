"""``--record PATH.mcap`` on the commands that run something, and ``armvision replay``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from armvision.cli.args import _say
from armvision.config import Config

if TYPE_CHECKING:
    from armvision.runtime.recorder import Recorder
    from armvision.runtime.system import System


def add_record_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--record",
        metavar="PATH.mcap",
        help="record the run to this MCAP file (ROS 2 messages: open it in Foxglove, play it "
        "with ros2 bag play, replay it with armvision replay)",
    )


def open_recorder(path: str | None, config: Config, *, wait: bool) -> Recorder | None:
    """A started recorder on ``path`` (None if no path); if the file cannot be made, a
    one-line message and None: the run goes on without recording."""
    if not path:
        return None
    from armvision.runtime.recorder import Recorder, RecordingError

    try:
        recorder = Recorder(path, config, wait=wait, notify=_say).open()
    except RecordingError as exc:
        _say(f"{exc}; the run goes on without recording")
        return None
    _say(f"recording to {path}")
    return recorder


def record_system(path: str | None, config: Config, system: System) -> Recorder | None:
    """Record ``system``'s run from its start (call before starting it)."""
    recorder = open_recorder(path, config, wait=system.lockstep)
    if recorder is not None:
        system.attach_recorder(recorder)
    return recorder


def finish_recording(recorder: Recorder | None) -> None:
    """Stop ``recorder`` (if not yet) and say what it wrote."""
    if recorder is None:
        return
    recorder.stop()
    if recorder.error is not None:
        return  # said when it happened
    s = recorder.status()
    dropped = f", {s['dropped']} items dropped (the recorder fell behind)" if s["dropped"] else ""
    _say(
        f"recorded {s['frames']} frames, {s['joint_states']} joint states, "
        f"{s['bytes'] / 1e6:.1f} MB to {s['path']}{dropped}"
    )


def cmd_replay(args: argparse.Namespace, config: Config) -> int:
    from armvision.recording.reader import Recording
    from armvision.runtime.build import load_calibration
    from armvision.runtime.replay import replay

    Recording(args.file)  # a missing or wrong file: one line, before anything else
    own_config = args.config is None and not args.overrides
    calibration = load_calibration(args.calibration) if args.calibration else None
    report = replay(
        args.file,
        None if own_config else config,
        calibration=calibration,
        record_to=args.record,
        realtime=args.realtime,
        notify=_say,
    )
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print(report.table())
    return 0


def add_replay_parser(sub: Any) -> None:
    replay = sub.add_parser(
        "replay",
        help="re-run perception, fusion and tracking on a recording and say what changed",
    )
    replay.add_argument("file", metavar="FILE.mcap", help="a recording armvision made")
    replay.add_argument(
        "--calibration",
        metavar="PATH",
        help="run with this calibration file instead of the recorded calibration",
    )
    replay.add_argument(
        "--realtime", action="store_true", help="at the recording's pace (default: full speed)"
    )
    replay.add_argument("--json", action="store_true", help="the comparison as JSON")
    add_record_option(replay)
    replay.set_defaults(func=cmd_replay)


def recorded_frame(path: str, index: int | None) -> tuple[Any, Any, Any, dict[str, Any]]:
    """Frame ``index`` of a recording (default: the last), the recorded camera pose and raw
    encoder reading with it, minus the joint offsets, and the ``source`` record."""
    import numpy as np

    from armvision.errors import ArmvisionError
    from armvision.recording import ros
    from armvision.recording.reader import Recording
    from armvision.recording.sources import recorded_frames

    recording = Recording(path)
    chosen = None
    count = 0
    for frame, log_ns in recorded_frames(recording):
        if index is None or count == index:
            chosen = (frame, log_ns)
        count += 1
        if index is not None and count > index:
            break
    if chosen is None:
        have = f"it has {count} (0 to {count - 1})" if count else "it has none"
        raise ArmvisionError(f"{path}: no frame {index}; {have}")
    frame, frame_ns = chosen
    calibration = None
    joints = None
    for msg in recording.messages([ros.FRAME_JOINTS_TOPIC, "/armvision/calibration"]):
        if msg.log_ns > frame_ns:
            break
        if msg.topic == "/armvision/calibration":
            calibration = msg.value
        elif msg.log_ns == frame_ns:
            joints = np.asarray(msg.value.position, dtype=float)
    T_base_cam = None if calibration is None else np.asarray(calibration["T_base_cam"])
    if joints is not None and calibration is not None and calibration["joint_offsets_rad"]:
        joints = joints - np.asarray(calibration["joint_offsets_rad"], dtype=float)
    source = {
        "kind": "replay",
        "file": str(Path(path)),
        "frame": frame.index,
        "timestamp": frame.timestamp,
        "size": [int(frame.depth.shape[1]), int(frame.depth.shape[0])],
        "intrinsics": frame.intrinsics.to_dict(),
        "calibration": calibration is not None,
        "joint_positions": None if joints is None else [float(v) for v in joints],
    }
    return frame, T_base_cam, joints, source


def cmd_export_lerobot(args: argparse.Namespace, config: Config) -> int:
    from armvision.cli.args import writable_dir
    from armvision.recording.lerobot import export_lerobot
    from armvision.recording.reader import Recording

    for path in args.files:
        Recording(path)  # a missing or wrong file: one line, before anything is written
    out = writable_dir(args.out)
    info = export_lerobot(args.files, out, fps=args.fps)
    print(
        f"wrote a LeRobot {info['codebase_version']} dataset to {out}: "
        f"{info['total_episodes']} episode(s), {info['total_frames']} frames at "
        f"{info['fps']:g} FPS, {info['total_tasks']} task(s)"
    )
    return 0


def add_export_parser(sub: Any) -> None:
    from armvision.cli.args import int_in, out_dir

    export = sub.add_parser(
        "export-lerobot",
        help="write recordings' task episodes as a LeRobot v3.0 dataset (parquet, mp4, meta)",
    )
    export.add_argument("files", nargs="+", metavar="FILE.mcap", help="recordings armvision made")
    export.add_argument("--out", type=out_dir, required=True, metavar="DIR", help="a new folder")
    export.add_argument(
        "--fps",
        type=int_in(1, 120, "frames a second"),
        help="frames a second, a whole number as LeRobot's (default: the recording's camera rate)",
    )
    export.set_defaults(func=cmd_export_lerobot)
