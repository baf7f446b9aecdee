"""A camera and an arm that play a recording back (``armvision replay``, ``perceive --replay``).

:class:`RecordedCamera` is a :class:`~armvision.camera.base.Camera` whose :meth:`read` gives
the recorded frames in order: colour decoded from its JPEG (or PNG), depth from 16UC1
millimetres back to metres, the recorded intrinsics. :class:`RecordedArm` is an
:class:`~armvision.robot.base.ArmBase` whose encoders read, at the time its ``clock`` says,
the newest recorded joint state (of a fusion cycle or taken with a frame); it refuses every
motion, saying it is a recording.
"""

from __future__ import annotations

import bisect
import os
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, RGBDFrame
from armvision.errors import ArmvisionError
from armvision.recording import ros
from armvision.recording.reader import Recording
from armvision.robot.base import ArmBase, GripperBase, TrapezoidalTrajectory

Array = NDArray[np.float64]

_FRAME_TOPICS = (
    ros.INFO_TOPIC, ros.COLOR_TOPIC, ros.DEPTH_TOPIC, "/armvision/camera", ros.FRAME_CLOCK_TOPIC,
)  # fmt: skip


def recorded_frames(recording: Recording) -> Iterator[tuple[RGBDFrame, int]]:
    """(frame, depth message's log ns) for every complete recorded frame, in order."""
    intr: Intrinsics | None = None
    recorded: Intrinsics | None = None
    color: tuple[int, Any] | None = None
    exact_t: tuple[int, float] | None = None  # the clock's seconds of the frame coming
    index = 0
    for msg in recording.messages(_FRAME_TOPICS):
        if msg.topic == ros.FRAME_CLOCK_TOPIC:
            exact_t = (msg.log_ns, float(msg.value["t"]))
        elif msg.topic == "/armvision/camera":
            recorded = Intrinsics(**{**msg.value["intrinsics"]})
        elif msg.topic == ros.INFO_TOPIC:
            intr = recorded or ros.intrinsics_of(msg.value)
        elif msg.topic == ros.COLOR_TOPIC:
            color = (msg.log_ns, msg.value)
        elif msg.topic == ros.DEPTH_TOPIC and color is not None and color[0] == msg.log_ns:
            depth = ros.decode_depth(msg.value)
            rgb = ros.decode_color(color[1])
            h, w = depth.shape
            if intr is None or (intr.width, intr.height) != (w, h):
                raise ArmvisionError(
                    f"{recording.path}: a frame at {msg.t:.3f} s has no camera info of its size"
                )
            for a in (rgb, depth):
                a.flags.writeable = False
            t = ros.seconds(msg.value.header.stamp)
            if exact_t is not None and exact_t[0] == msg.log_ns:
                t = exact_t[1]
            yield RGBDFrame(rgb, depth, intr, t, index), msg.log_ns
            index += 1
            color = None


class RecordedCamera:
    """The frames of a recording, one per :meth:`read` (see the module docstring)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.recording = Recording(path)
        self._frames: Iterator[tuple[RGBDFrame, int]] | None = None
        self._intrinsics: Intrinsics | None = None
        self.last: RGBDFrame | None = None

    @property
    def serial(self) -> str | None:
        return None

    @property
    def intrinsics(self) -> Intrinsics:
        if self._intrinsics is None:
            info = self.recording.first(ros.INFO_TOPIC)
            if info is None:
                raise ArmvisionError(f"{self.recording.path} holds no camera frames")
            exact = self.recording.first("/armvision/camera")
            self._intrinsics = (
                Intrinsics(**exact.value["intrinsics"]) if exact else ros.intrinsics_of(info.value)
            )
        return self._intrinsics

    def start(self) -> None:
        if self._frames is None:
            self._frames = recorded_frames(self.recording)

    def stop(self) -> None:
        self._frames = None

    def read(self, timeout_s: float = 1.0) -> RGBDFrame:
        """The next recorded frame; ArmvisionError once they are all read."""
        self.start()
        assert self._frames is not None
        got = next(self._frames, None)
        if got is None:
            raise ArmvisionError(f"the recording {self.recording.path} has no more frames")
        self.last = got[0]
        return got[0]

    def __enter__(self) -> RecordedCamera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class _RecordedGripper(GripperBase):
    def open(self, delay: float | None = None) -> None:
        raise ArmvisionError("a recorded arm's gripper does not move")

    def close(self, delay: float | None = None) -> None:
        raise ArmvisionError("a recorded arm's gripper does not move")

    def get_finger_position(self) -> float:
        raise ArmvisionError("a recording holds no finger position")


class RecordedArm(ArmBase):
    """An arm whose encoders play back a recording's joint states (see the module docstring).

    ``clock``: the replay's time; the reading is the newest sample at or before it (the
    first sample before the first), unless a replay :meth:`hold` s the very reading a stage
    was given when it was recorded.
    """

    def __init__(self, path: str | os.PathLike[str], clock: Callable[[], float]) -> None:
        super().__init__()
        self.clock = clock
        self.gripper = _RecordedGripper()
        times: list[float] = []
        positions: list[Array] = []
        recording = Recording(path)
        exact: dict[int, float] = {}
        clocks = (ros.CLOCK_TOPIC, ros.FRAME_CLOCK_TOPIC)
        for msg in recording.messages([ros.JOINTS_TOPIC, ros.FRAME_JOINTS_TOPIC, *clocks]):
            if msg.topic in clocks:
                exact[msg.log_ns] = float(msg.value["t"])
                continue
            times.append(exact.get(msg.log_ns, ros.seconds(msg.value.header.stamp)))
            positions.append(np.asarray(msg.value.position, dtype=float))
        if not times:
            raise ArmvisionError(f"{recording.path} holds no joint states")
        order = np.argsort(np.asarray(times), kind="stable")
        self.times = [times[i] for i in order]
        self.positions = [positions[i] for i in order]
        self.held: Array | None = None

    def hold(self, q: Array | None) -> None:
        """Read ``q`` until the next hold (None: the recording at the clock's time again)."""
        self.held = None if q is None else np.array(q, dtype=float)

    def _read_joint_positions(self) -> Array:
        if self.held is not None:
            return self.held.copy()
        k = bisect.bisect_right(self.times, self.clock()) - 1
        return self.positions[max(k, 0)].copy()

    def _halt(self) -> None:
        """Nothing to hold: a recording's arm goes where it went."""

    def _execute(self, trajectory: TrapezoidalTrajectory, blocking: bool) -> None:
        raise ArmvisionError("a recorded arm cannot move: this is a replay")

    def _stream(self, q: Array) -> None:
        raise ArmvisionError("a recorded arm cannot move: this is a replay")
