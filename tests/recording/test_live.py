"""The live view: the Foxglove SDK's WebSocket server publishing the recording's channels.

A plain WebSocket client speaks the Foxglove WebSocket protocol (``foxglove.sdk.v1``, the
the server advertises its channels, the client subscribes, messages come as binary frames of
opcode 1, subscription id, log time and payload), and each payload is decoded by
mcap-ros2-support from the schema the server advertised: what a Foxglove app would see.
"""

from __future__ import annotations

import json
import struct
import threading
import time

import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from armvision.bench.system import sim_system
from armvision.config import Config

pytest.importorskip("foxglove")


def test_a_lockstep_run_is_served_live_and_a_file_starts_and_stops_mid_run(tmp_path) -> None:
    from armvision.recording.live import LiveServer
    from armvision.recording.reader import Recording
    from armvision.runtime.recorder import Recorder

    config = Config()
    live = LiveServer("127.0.0.1", 0)
    recorder = Recorder(None, config, wait=True, live=live).open()
    system = sim_system(config, 0, mode="lockstep")
    system.attach_recorder(recorder)
    received: dict[str, list] = {}
    channels: dict[int, dict] = {}
    subscribed = threading.Event()
    done = threading.Event()

    def client() -> None:
        with connect(live.url(), subprotocols=["foxglove.sdk.v1"]) as ws:
            subscriptions: dict[int, dict] = {}
            # A subscription sent right after the advertisement can reach the server before
            # it knows the channel ("unknown channel", seen on a loaded machine), as a viewer
            # clicking a topic would not: subscribe a quarter second after, and again for a
            # channel the server says it does not know.
            pending: list[tuple[float, dict]] = []

            def subscribe_due() -> None:
                due = [ch for t, ch in pending if time.monotonic() - t >= 0.25]
                if not due:
                    return
                pending[:] = [(t, ch) for t, ch in pending if time.monotonic() - t < 0.25]
                new = []
                for ch in due:
                    sub_id = len(subscriptions) + 1
                    subscriptions[sub_id] = ch
                    new.append({"id": sub_id, "channelId": ch["id"]})
                ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                subscribed.set()

            while not done.is_set():
                subscribe_due()
                try:
                    message = ws.recv(timeout=0.05)
                except TimeoutError:
                    continue
                except ConnectionClosed:  # the server stopped with the run
                    return
                if isinstance(message, str):
                    data = json.loads(message)
                    if data.get("op") == "advertise":
                        for ch in data["channels"]:
                            channels[ch["id"]] = ch
                            pending.append((time.monotonic(), ch))
                    elif data.get("op") == "status" and "unknown channel" in data.get(
                        "message", ""
                    ):
                        tail = data["message"].rsplit(":", 1)[-1].strip()
                        if tail.isdigit() and int(tail) in channels:
                            pending.append((time.monotonic(), channels[int(tail)]))
                    continue
                opcode, sub_id, log_ns = struct.unpack_from("<BIQ", message)
                if opcode == 1:
                    ch = subscriptions[sub_id]
                    received.setdefault(ch["topic"], []).append((log_ns, message[13:]))

    thread = threading.Thread(target=client, daemon=True)
    thread.start()
    wanted = {
        "/camera/color/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/camera/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
        "/vx300s/joint_states": "sensor_msgs/msg/JointState",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/armvision/markers": "visualization_msgs/msg/MarkerArray",
        "/armvision/task": "json",
    }
    with system:
        system.pump(system.clock() + 0.5)  # channels are advertised as they first appear
        assert subscribed.wait(10.0)
        deadline = time.monotonic() + 60.0  # a loaded machine: the client may lag behind
        while not all(len(received.get(topic, ())) >= 3 for topic in wanted):
            assert time.monotonic() < deadline, {t: len(received.get(t, ())) for t in wanted}
            time.sleep(0.2)
            system.pump(system.clock() + 0.1)
        recorder.start_file(tmp_path / "mid.mcap")
        system.pump(system.clock() + 0.5)
        recorder.stop_file()
        system.pump(system.clock() + 0.3)
        time.sleep(0.5)
    done.set()
    thread.join(5.0)

    factory = DecoderFactory()
    del wanted["/armvision/task"]
    by_topic = {ch["topic"]: ch for ch in channels.values()}
    for topic, msgtype in wanted.items():
        ch = by_topic[topic]
        assert (ch["schemaName"], ch["encoding"], ch["schemaEncoding"]) == (
            msgtype,
            "cdr",
            "ros2msg",
        )
        schema = Schema(id=ch["id"], name=msgtype, encoding="ros2msg", data=ch["schema"].encode())
        decode = factory.decoder_for("cdr", schema)
        messages = received.get(topic, [])
        assert messages, topic
        times = [t for t, _ in messages]
        assert times == sorted(times)
        for t, payload in messages[-3:]:
            decoded = decode(payload)
            header = getattr(decoded, "header", None)
            if header is not None:
                assert header.stamp.sec * 10**9 + header.stamp.nanosec == t
    task = [json.loads(p) for _, p in received["/armvision/task"]]
    assert task[-1]["phase"] == "idle"
    # The file started mid-run begins with the configuration, calibration and tf_static.
    recording = Recording(tmp_path / "mid.mcap")
    topics = [m.topic for m in recording.messages()]
    assert {"/armvision/config", "/armvision/calibration", "/tf_static"} <= set(topics[:6])
    frames = topics.count("/camera/aligned_depth_to_color/image_raw")
    assert 10 <= frames <= 20  # 0.5 s of a 30 Hz lockstep run
