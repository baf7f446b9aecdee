"""Check a recording with the independent readers: the ``mcap`` library's reader and
mcap-ros2-support's decoder (neither is armvision's code).

Every ROS 2 message is decoded from the schema written in the file; its schema must be the
standard type of its topic, its header's frame id the driver's, its stamp its log time, and
every channel's times must not go backwards. Prints a line per topic and exits 1 on any
problem.

    python benchmarks/check_recording.py FILE.mcap
"""

from __future__ import annotations

import argparse
import collections
import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from armvision.recording import ros

FRAME_IDS = {
    ros.COLOR_TOPIC: ros.CAMERA_FRAME,
    ros.DEPTH_TOPIC: ros.CAMERA_FRAME,
    ros.INFO_TOPIC: ros.CAMERA_FRAME,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    args = parser.parse_args()
    problems: list[str] = []
    counts: collections.Counter[str] = collections.Counter()
    last: dict[str, int] = {}
    first_ns = last_ns = None
    factory = DecoderFactory()
    decoders = {}
    with open(args.file, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None:
            problems.append("no summary: the file was not finished")
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] += 1
            first_ns = message.log_time if first_ns is None else first_ns
            last_ns = message.log_time
            if message.log_time < last.get(topic, -1):
                problems.append(f"{topic}: time goes backwards at {message.log_time}")
            last[topic] = message.log_time
            want = ros.TOPICS.get(topic)
            if channel.message_encoding == "json":
                json.loads(message.data)
                continue
            if schema is None or schema.name != want or schema.encoding != "ros2msg":
                problems.append(f"{topic}: schema {schema and schema.name} is not {want}")
                continue
            if schema.id not in decoders:
                decoders[schema.id] = factory.decoder_for("cdr", schema)
            decoded = decoders[schema.id](message.data)
            header = getattr(decoded, "header", None)
            if header is not None:
                if header.stamp.sec * 10**9 + header.stamp.nanosec != message.log_time:
                    problems.append(f"{topic}: header stamp is not the log time")
                if topic in FRAME_IDS and header.frame_id != FRAME_IDS[topic]:
                    problems.append(f"{topic}: frame id {header.frame_id!r}")
            for t in getattr(decoded, "transforms", ()):
                if t.header.frame_id != ros.BASE_FRAME:
                    problems.append(f"{topic}: parent {t.header.frame_id!r}")
    span = 0.0 if first_ns is None or last_ns is None else (last_ns - first_ns) / 1e9
    print(f"{args.file}: {sum(counts.values())} messages over {span:.1f} s")
    for topic, n in sorted(counts.items()):
        print(f"  {topic:<42} {n:>7}  {n / span if span else 0:>6.1f} Hz  {ros.TOPICS.get(topic)}")
    for problem in dict.fromkeys(problems):
        print(f"problem: {problem}")
    print("OK: every ROS 2 message decodes with its standard schema" if not problems else "FAILED")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
