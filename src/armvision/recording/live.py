"""The recording's channels served live to Foxglove (``ui.foxglove = true``).

:class:`LiveServer` runs the Foxglove SDK's WebSocket server (the ``foxglove-sdk`` package,
imported only when this is used) and publishes each message the recorder encodes, on the same
topic, schema and encoding as in the MCAP file: so Foxglove shows a live run exactly as it
shows its recording, with the same layout (``docs/foxglove-layout.json``). Foxglove connects
with "Open connection" -> "Foxglove WebSocket" -> ``ws://HOST:PORT``.
"""

from __future__ import annotations

import json
from typing import Any

from armvision.errors import ArmvisionError
from armvision.recording import ros
from armvision.recording.writer import json_schema_name


class LiveServer:
    """The Foxglove WebSocket server on ``host``:``port`` (0: any free port)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765) -> None:
        try:
            import foxglove
        except ImportError:
            raise ArmvisionError(
                "ui.foxglove needs the Foxglove SDK: pip install 'armvision[foxglove]'"
            ) from None
        self._foxglove = foxglove
        self._context = foxglove.Context()  # its own channels, not the process-wide ones
        try:
            self._server = foxglove.start_server(
                name="armvision", host=host, port=port, context=self._context
            )
        except Exception as exc:  # the SDK's own error type for a busy port
            raise ArmvisionError(
                f"cannot serve Foxglove on {host}:{port} ({exc}): set ui.foxglove_port to a "
                "free port"
            ) from None
        self.host = host
        self.port = int(self._server.port)
        self._channels: dict[str, Any] = {}

    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def _channel(self, topic: str) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            fg = self._foxglove
            msgtype = ros.TOPICS[topic]
            if msgtype == "json":
                schema = fg.Schema(
                    name=json_schema_name(topic),
                    encoding="jsonschema",
                    data=json.dumps({"type": "object"}).encode(),
                )
                channel = fg.Channel(
                    topic, schema=schema, message_encoding="json", context=self._context
                )
            else:
                schema = fg.Schema(
                    name=msgtype, encoding="ros2msg", data=ros.msgdef(msgtype).encode()
                )
                channel = fg.Channel(
                    topic, schema=schema, message_encoding="cdr", context=self._context
                )
            self._channels[topic] = channel
        return channel

    def publish(self, topic: str, t: float, data: bytes) -> None:
        """One encoded message (:func:`~armvision.recording.writer.encode`) at clock ``t``."""
        self._channel(topic).log(data, log_time=max(ros.to_ns(t), 0))

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self._server.stop()
