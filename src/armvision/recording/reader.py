"""Reading a recording back: its messages in the order they were written, decoded.

The file is read front to back with the ``mcap`` library's streaming reader, which needs no
summary: a file whose writer was killed (no summary, a last chunk cut short) yields every
message of its complete chunks, then :attr:`Recording.truncated` is set. ROS 2 messages are
decoded with rosbags' CDR reader (the schemas are the standard ones), JSON ones with
:mod:`json`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armvision.errors import ArmvisionError
from armvision.recording import ros


@dataclass(frozen=True)
class Message:
    """One recorded message: its ``topic``, log time ``t`` (clock seconds) and ``log_ns``,
    and ``value``: the decoded ROS message, or the JSON value."""

    topic: str
    t: float
    log_ns: int
    value: Any


class Recording:
    """The recording at ``path`` (an ArmvisionError naming it if it is none)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise ArmvisionError(f"no recording at {self.path}: give an .mcap file armvision wrote")
        with open(self.path, "rb") as f:
            magic = f.read(8)
        if magic != b"\x89MCAP0\r\n":
            raise ArmvisionError(f"{self.path} is not an MCAP file (it does not start like one)")
        self.truncated = False

    def messages(self, topics: Collection[str] | None = None) -> Iterator[Message]:
        """The messages on ``topics`` (default all), in the order they were written."""
        from mcap.exceptions import McapError
        from mcap.reader import NonSeekingReader

        wanted = None if topics is None else set(topics)
        with open(self.path, "rb") as f:
            reader = NonSeekingReader(f, validate_crcs=True)
            it = reader.iter_messages(
                topics=None if wanted is None else list(wanted), log_time_order=False
            )
            while True:
                try:
                    schema, channel, message = next(it)
                except StopIteration:
                    return
                except (McapError, EOFError, ValueError, OSError):
                    self.truncated = True  # a killed writer's last chunk: the rest is gone
                    return
                yield Message(
                    channel.topic,
                    message.log_time / 1e9,
                    message.log_time,
                    _decode(channel.message_encoding, schema, channel.topic, message.data),
                )

    def first(self, topic: str) -> Message | None:
        """The first message on ``topic``, or None."""
        return next(self.messages([topic]), None)


def _decode(encoding: str, schema: Any, topic: str, data: bytes) -> Any:
    if encoding == "json":
        return json.loads(data)
    if encoding == "cdr" and schema is not None:
        return ros.deserialize(data, schema.name)
    raise ArmvisionError(f"{topic}: messages encoded as {encoding!r} are not ones armvision reads")
