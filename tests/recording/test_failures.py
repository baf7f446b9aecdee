"""A recording killed mid-run, a full disk, a file-size limit, a target that cannot be made:
what is on disk is readable, the message is one line, the run goes on.

Each case runs in a subprocess: SIGKILL, ``/dev/full`` and RLIMIT_FSIZE are the operating
system's own failures, not simulated ones.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from tests.recording.helpers import ROS_TYPES

from armvision.recording.reader import Recording

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path("src").resolve()), "."])}

#: Records synthetic frames and joint states forever (small chunks, so several are complete
#: quickly); prints "recording" once it has written some.
WRITER = """
import sys, time
from dataclasses import replace
import numpy as np
from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.config import Config
from armvision.runtime.recorder import Recorder

config = Config()
config = replace(config, record=replace(config.record, chunk_kib=64))
recorder = Recorder(sys.argv[1], config, wait=True).open()
recorder.begin(0.0, ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate"))
intr = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
v, u = np.mgrid[0:480, 0:640]
rng = np.random.default_rng(0)
i = 0
while True:
    t = i / 30
    colour = np.dstack([(u + i) % 256, (v + 2 * i) % 256, np.full_like(u, 128)]).astype(np.uint8)
    depth = (0.8 + 0.0005 * v + rng.normal(0, 0.002, v.shape)).astype(np.float32)
    recorder.frame(RGBDFrame(colour, depth, intr, t, i))
    recorder.frame_joints(t, np.full(6, 0.01 * i))
    i += 1
    if i == 15:
        print("recording", flush=True)
    time.sleep(0.005)
"""


def _messages_in_complete_chunks(path: Path) -> int:
    """Messages in the chunks that were written whole, counted by the mcap library's own
    record reader (it stops at the cut-off record)."""
    from mcap.records import Chunk
    from mcap.records import Message as McapMessage
    from mcap.stream_reader import StreamReader, breakup_chunk

    count = 0
    with open(path, "rb") as f:
        records = StreamReader(f, emit_chunks=True, validate_crcs=True).records
        try:
            for record in records:
                if isinstance(record, Chunk):
                    count += sum(isinstance(r, McapMessage) for r in breakup_chunk(record, True))
        except Exception:  # the record the kill cut short
            pass
    return count


def test_a_recording_killed_with_sigkill_reads_up_to_its_last_complete_chunk(
    tmp_path: Path,
) -> None:
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, env=ENV, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "recording"
        deadline = time.monotonic() + 30
        while path.stat().st_size < 400_000:  # several 64 KiB chunks
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    with open(path, "rb") as f, pytest.raises(McapError):  # no summary, no footer
        make_reader(f).get_summary()
    expected = _messages_in_complete_chunks(path)
    assert expected > 30
    recording = Recording(path)
    messages = list(recording.messages())
    assert recording.truncated and len(messages) == expected
    # Every recovered ROS message decodes with the independent decoder, frames are whole.
    factory = DecoderFactory()
    with open(path, "rb") as f:
        from mcap.reader import NonSeekingReader

        decoded = 0
        try:
            for schema, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                if channel.message_encoding == "cdr":
                    assert schema.name == ROS_TYPES[channel.topic]
                    factory.decoder_for("cdr", schema)(message.data)
                    decoded += 1
        except Exception:
            pass
    assert decoded == sum(m.topic in ROS_TYPES for m in messages) > 0
    depths = [m.value for m in messages if m.topic.endswith("image_raw")]
    assert depths and all(len(d.data) == 640 * 480 * 2 for d in depths)
    # ... and armvision's own replay reads the frames it holds.
    from armvision.recording.sources import RecordedCamera

    camera = RecordedCamera(path)
    frame = camera.read()
    assert frame.depth.shape == (480, 640) and abs(float(np.median(frame.depth)) - 0.92) < 0.01


PERCEIVE = [sys.executable, "-m", "armvision.cli", "perceive", "--sim", "--seed", "3"]


def _run(args: list[str], tmp_path: Path, preexec=None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*args, "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        env={**ENV, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
        preexec_fn=preexec,
        timeout=300,
    )


def test_a_full_disk_is_one_line_and_the_run_goes_on(tmp_path: Path) -> None:
    done = _run([*PERCEIVE, "--record", "/dev/full"], tmp_path)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if "/dev/full" in line]
    assert len(lines) == 1
    assert "No space left on device" in lines[0] and "goes on" in lines[0]
    assert (tmp_path / "out" / "detections.json").is_file()  # perception did its work


def test_a_target_that_cannot_be_made_is_one_line_and_the_run_goes_on(tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("not a folder")
    target = tmp_path / "a-file" / "run.mcap"
    done = _run([*PERCEIVE, "--record", str(target)], tmp_path)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if str(target) in line]
    assert len(lines) == 1 and "cannot record to" in lines[0] and "Not a directory" in lines[0]
    assert (tmp_path / "out" / "detections.json").is_file()


RUN = """
import sys
from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.runtime.recorder import Recorder

config = Config()
system = sim_system(config, 0, mode="lockstep")
say = lambda message: print(message, file=sys.stderr)
recorder = Recorder(sys.argv[1], config, wait=True, notify=say).open()
system.attach_recorder(recorder)
with system:
    system.pump(system.clock() + 1.5)
    state = system.snapshot()
    print(system.fusion.snapshot().cycles, len(state.tracks), recorder.counts.frames)
"""


def test_a_file_size_limit_mid_run_stops_the_recording_and_the_run_goes_on(
    tmp_path: Path,
) -> None:
    path = tmp_path / "limited.mcap"
    limit = 1_500_000  # a few frames' worth

    def limited() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    done = subprocess.run(
        [sys.executable, "-c", RUN, str(path)],
        capture_output=True,
        text=True,
        env={**ENV, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
        preexec_fn=limited,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    cycles, tracks, frames = (int(v) for v in done.stdout.split())
    assert cycles >= 150 and tracks >= 1  # fusion and tracking ran the whole 1.5 s
    assert 0 < frames < 45  # the recording stopped early
    lines = [line for line in done.stderr.splitlines() if str(path) in line]
    assert len(lines) == 1
    assert lines[0].startswith("recording stopped: cannot write") and "File too large" in lines[0]
    assert path.stat().st_size <= limit
    assert len(list(Recording(path).messages())) > 0  # what was written reads back
