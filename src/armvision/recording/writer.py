"""One MCAP file being written: ROS 2 (CDR) and JSON channels, chunked and compressed.

:class:`McapLog` registers each topic's schema and channel on first use and writes messages
in the order given; chunks reach the operating system as each one closes (the file is flushed
after every message), so a process killed mid-run leaves every complete chunk readable. A
write that fails (disk full, file too large, a removed drive) raises :class:`RecordingError`
with a one-line message; the caller stops recording there.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import IO, Any

from armvision.errors import ArmvisionError
from armvision.recording import ros

#: Profile and library strings written into the file's header.
PROFILE = "ros2"
LIBRARY = "armvision"


class RecordingError(ArmvisionError):
    """The recording cannot go on (its file cannot be opened or written)."""


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc) or type(exc).__name__


def encode(topic: str, message: Any) -> bytes:
    """A message's bytes on ``topic``: CDR for a ROS 2 type, compact JSON for armvision's."""
    msgtype = ros.TOPICS[topic]
    if msgtype == "json":
        return json.dumps(message, separators=(",", ":"), allow_nan=False).encode()
    return ros.serialize(message, msgtype)


def json_schema_name(topic: str) -> str:
    """The schema name of one of armvision's JSON topics (``/armvision/task`` ->
    ``armvision.task``)."""
    return topic.strip("/").replace("/", ".")


class McapLog:
    """An MCAP file being written at ``path`` (``compression``: zstd, lz4 or none;
    ``chunk_size`` in bytes). :meth:`close` writes the summary that makes it seekable."""

    def __init__(self, path: str | os.PathLike[str], compression: str = "zstd",
                 chunk_size: int = 1 << 20) -> None:  # fmt: skip
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        try:
            self._file: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 - kept open
        except OSError as exc:
            raise RecordingError(
                f"cannot record to {self.path} ({_why(exc)}): choose a file in a directory "
                "you can write to"
            ) from None
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                 "none": CompressionType.NONE}  # fmt: skip
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=kinds[compression])
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self.messages = 0
        self.closed = False
        self._size = 0
        self._guard(lambda: self._writer.start(profile=PROFILE, library=LIBRARY))

    @property
    def bytes_written(self) -> int:
        try:
            if self._file is not None:
                self._size = int(self._file.tell())
        except (OSError, ValueError):
            pass
        return self._size

    def _guard(self, work: Any) -> None:
        try:
            work()
            if self._file is not None:
                self._file.flush()
        except OSError as exc:
            self.abandon()
            raise RecordingError(
                f"recording stopped: cannot write {self.path} ({_why(exc)}); the run goes on "
                "without it (free some space, or record to another disk)"
            ) from None

    def _channel(self, topic: str, msgtype: str) -> int:
        channel = self._channels.get(topic)
        if channel is not None:
            return channel
        schema = self._schemas.get(msgtype)
        if schema is None:
            if msgtype == "json":
                schema = self._writer.register_schema(
                    json_schema_name(topic), "jsonschema",
                    json.dumps({"type": "object"}).encode(),
                )  # fmt: skip
            else:
                schema = self._writer.register_schema(
                    msgtype, "ros2msg", ros.msgdef(msgtype).encode()
                )
                self._schemas[msgtype] = schema
        encoding = "json" if msgtype == "json" else "cdr"
        channel = self._writer.register_channel(topic, encoding, schema)
        self._channels[topic] = channel
        return channel

    def write(self, topic: str, t: float, message: Any) -> None:
        """Write ``message`` on ``topic`` (a key of :data:`~armvision.recording.ros.TOPICS`) at
        clock seconds ``t``: a ROS message object, or a JSON-able dict for a JSON topic."""
        self.write_encoded(topic, t, encode(topic, message))

    def write_encoded(self, topic: str, t: float, data: bytes) -> None:
        """Write a message :func:`encode` made."""
        if self.closed:
            raise RecordingError(f"the recording {self.path} is closed")
        msgtype = ros.TOPICS[topic]
        ns = max(ros.to_ns(t), 0)
        seq = self._sequence.get(topic, 0)
        self._sequence[topic] = seq + 1

        def add() -> None:
            channel = self._channel(topic, msgtype)
            self._writer.add_message(channel, log_time=ns, data=data, publish_time=ns, sequence=seq)

        self._guard(add)
        self.messages += 1

    def close(self) -> None:
        """Finish the file (summary, footer) and close it."""
        if self.closed:
            return
        self._guard(self._writer.finish)
        self.abandon()

    def abandon(self) -> None:
        """Close the file as it is (after a failed write: what reached the disk stays)."""
        self.closed = True
        if self._file is not None:
            _ = self.bytes_written  # the size it reached
            with contextlib.suppress(OSError):  # what could not be written is gone anyway
                self._file.close()
            self._file = None
