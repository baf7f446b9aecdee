"""Recordings made once per module: a lockstep simulated run, and reading files back with the
independent readers (the ``mcap`` library's and mcap-ros2-support's decoder)."""

from __future__ import annotations

import collections
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from armvision.bench.system import sim_system, sim_world
from armvision.config import Config
from armvision.runtime.recorder import Recorder

ROS_TYPES = {
    "/camera/color/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/camera/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
    "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
    "/vx300s/joint_states": "sensor_msgs/msg/JointState",
    "/armvision/frame_joint_states": "sensor_msgs/msg/JointState",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/armvision/markers": "visualization_msgs/msg/MarkerArray",
    "/armvision/planning_scene": "visualization_msgs/msg/MarkerArray",
}


@dataclass
class Recorded:
    """A lockstep run recorded to ``path``, with the simulator's truth at its end."""

    path: Path
    config: Config
    cycles: int
    truth: dict[str, Any] = field(default_factory=dict)
    last_depth: Any = None
    tracks: list[Any] = field(default_factory=list)


def record_lockstep(
    path: Path, seconds: float, *, task: Any = None, config: Config | None = None, seed: int = 0
) -> Recorded:
    """Record a lockstep run of ``seconds`` on scene ``seed`` (then ``task``, if given)."""
    config = config or Config()
    system = sim_system(config, seed, mode="lockstep")
    recorder = Recorder(path, config, wait=True).open()
    system.attach_recorder(recorder)
    with system:
        system.pump(system.clock() + seconds)
        if task is not None:
            system.run_task(task.__name__, task)
            system.pump(system.clock() + 0.3)
        world = sim_world(system)
        state = system.snapshot()
        truth = {
            "T_base_cam": world.T_base_cam(),
            "T_base_ee": world.T_base_ee(),
            "objects": [o.T_base_obj[:3, 3].copy() for o in world.objects()],
            "heights": [o.spec.height for o in world.objects()],
        }
        cycles = system.fusion.snapshot().cycles
    assert recorder.error is None, recorder.error
    return Recorded(path, config, cycles, truth, state.frame.depth, list(state.tracks))


def with_record(config: Config, **settings: Any) -> Config:
    return replace(config, record=replace(config.record, **settings))


def read_independently(path: Path) -> dict[str, list[tuple[Any, Any, Any, Any]]]:
    """Every message by topic as (schema, channel, message, decoded): ROS 2 ones decoded by
    mcap-ros2-support from the schema in the file, JSON ones by json."""
    import json

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list[tuple[Any, Any, Any, Any]]] = collections.defaultdict(list)
    factory = DecoderFactory()
    decoders: dict[int, Any] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None  # a finished file: summary and footer
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                if schema.id not in decoders:
                    decoders[schema.id] = factory.decoder_for(channel.message_encoding, schema)
                decoded = decoders[schema.id](message.data)
            out[channel.topic].append((schema, channel, message, decoded))
    return out
