"""Recording a lockstep simulated run, read back with the independent readers, and replayed.

Ground truth: the simulator's camera pose, end effector and objects; the ``mcap`` library's
reader and mcap-ros2-support's decoder (which parse the file and the schemas written into it,
not armvision's code); the run's own last depth frame and fusion cycle count.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from tests.recording.helpers import (
    ROS_TYPES,
    Recorded,
    read_independently,
    record_lockstep,
    with_record,
)

from armvision.cli.main import main
from armvision.config import Config
from armvision.robot.kinematics import VX300S
from armvision.runtime.recorder import plain

CAMERA_FRAME = "camera_color_optical_frame"


@pytest.fixture(scope="module")
def still(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """2 s of the default scene, the arm at home: JPEG colour (the default)."""
    return record_lockstep(tmp_path_factory.mktemp("recording") / "still.mcap", 2.0)


@pytest.fixture(scope="module")
def topics(still: Recorded) -> dict:
    return read_independently(still.path)


def _matrix(transform) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    r, p = transform.rotation, transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    T[:3, 3] = [p.x, p.y, p.z]
    return T


def test_every_ros_message_decodes_with_its_standard_schema(topics: dict) -> None:
    for topic, msgtype in ROS_TYPES.items():
        assert topics[topic], f"nothing on {topic}"
        for schema, channel, _, decoded in topics[topic]:
            assert (schema.name, schema.encoding, channel.message_encoding) == (
                msgtype,
                "ros2msg",
                "cdr",
            )
            assert type(decoded).__name__ == msgtype.rsplit("/", 1)[-1]


def test_timestamps_are_monotonic_and_headers_match_log_times(topics: dict) -> None:
    for topic, messages in topics.items():
        times = [m.log_time for _, _, m, _ in messages]
        assert times == sorted(times), topic
        for _, _, message, decoded in messages:
            header = getattr(decoded, "header", None)
            if header is not None:
                assert header.stamp.sec * 10**9 + header.stamp.nanosec == message.log_time
    # Frames come at the tag stage's 30 Hz, fusion cycles at 100 Hz: simulated seconds.
    frames = [m.log_time for _, _, m, _ in topics["/camera/aligned_depth_to_color/image_raw"]]
    assert np.median(np.diff(frames)) == pytest.approx(1e9 / 30, rel=0.1)


def test_images_and_camera_info_are_the_drivers_messages(still: Recorded, topics: dict) -> None:
    for topic in (
        "/camera/color/image_raw/compressed",
        "/camera/aligned_depth_to_color/image_raw",
        "/camera/color/camera_info",
    ):
        assert {d.header.frame_id for *_, d in topics[topic]} == {CAMERA_FRAME}
    depth = topics["/camera/aligned_depth_to_color/image_raw"][-1][3]
    assert (depth.encoding, depth.height, depth.width, depth.step) == ("16UC1", 480, 640, 1280)
    mm = np.frombuffer(bytes(depth.data), dtype="<u2").reshape(480, 640)
    # The run's own last frame, in millimetres (the simulated D435 rounds to 1 mm units).
    assert np.abs(mm * 0.001 - still.last_depth).max() < 0.0005 + 1e-6
    assert np.count_nonzero(mm) == np.count_nonzero(still.last_depth)
    colour = topics["/camera/color/image_raw/compressed"][-1][3]
    assert "jpeg" in colour.format
    image = cv2.imdecode(np.frombuffer(bytes(colour.data), np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (480, 640, 3)
    info = topics["/camera/color/camera_info"][-1][3]
    k, p = np.asarray(info.k).reshape(3, 3), np.asarray(info.p).reshape(3, 4)
    assert (info.width, info.height, info.distortion_model, len(info.d)) == (
        640,
        480,
        "plumb_bob",
        5,
    )
    assert np.allclose(p[:, :3], k) and k[2, 2] == 1.0 and k[0, 0] > 0


def test_transforms_are_where_the_simulator_has_things(still: Recorded, topics: dict) -> None:
    (static,) = [d for *_, d in topics["/tf_static"]]
    (camera,) = static.transforms
    assert (camera.header.frame_id, camera.child_frame_id) == ("vx300s/base_link", CAMERA_FRAME)
    assert np.allclose(_matrix(camera.transform), still.truth["T_base_cam"], atol=1e-9)
    last = {t.child_frame_id: t for t in topics["/tf"][-1][3].transforms}
    assert {t.header.frame_id for t in last.values()} == {"vx300s/base_link"}
    ee = _matrix(last["vx300s/ee_gripper_link"].transform)
    assert np.linalg.norm(ee[:3, 3] - still.truth["T_base_ee"][:3, 3]) < 0.005
    # Each true object has a track frame at its centre (half-way up), within 2 cm.
    centres = [
        p + np.array([0, 0, h / 2]) for p, h in zip(still.truth["objects"], still.truth["heights"])
    ]
    tracks = [t for name, t in last.items() if name.startswith("armvision/track_")]
    assert len(tracks) == len(centres)
    for centre in centres:
        d = min(np.linalg.norm(_matrix(t.transform)[:3, 3] - centre) for t in tracks)
        assert d < 0.02


def test_joint_states_and_markers(still: Recorded, topics: dict) -> None:
    joints = topics["/vx300s/joint_states"]
    assert len(joints) == still.cycles  # every fusion cycle's encoder reading
    assert {tuple(d.name) for *_, d in joints} == {VX300S.joint_names}
    markers = topics["/armvision/markers"][-1][3].markers
    assert markers[0].action == 3  # DELETEALL: tracks that ended disappear
    cylinders = [m for m in markers[1:] if m.ns == "tracks"]
    texts = [m.text for m in markers if m.type == 9]
    tracks = topics["/armvision/tracks"][-1][3]["tracks"]
    assert len(cylinders) == len(tracks) == len(texts)
    for track, cylinder in zip(tracks, cylinders):
        assert cylinder.type == 3 and cylinder.header.frame_id == "vx300s/base_link"
        assert cylinder.scale.x == pytest.approx(2 * track["radius_m"])
        assert cylinder.scale.z == pytest.approx(track["height_m"])
    assert any(t.startswith("bottle #") and t.endswith("%") for t in texts)  # with the fill
    assert any(m.ns == "liquid" for m in markers)


def test_json_channels(still: Recorded, topics: dict) -> None:
    ((*_, config),) = topics["/armvision/config"]
    assert config == json.loads(json.dumps(plain(dataclasses.asdict(still.config))))
    calibration = topics["/armvision/calibration"][0][3]
    assert np.allclose(calibration["T_base_cam"], still.truth["T_base_cam"])
    health = topics["/armvision/health"][-1][3]
    assert set(health["threads"]) == {"camera", "tags", "objects", "liquid", "fusion", "motion"}
    assert health["recorder"]["dropped"] == 0
    assert topics["/armvision/task"][-1][3]["phase"] == "idle"
    assert topics["/armvision/liquid"] and topics["/armvision/detections"]


def test_replay_of_a_jpeg_recording_keeps_the_tracks_within_a_millimetre(
    still: Recorded, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", str(still.path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["same_tracks"] and report["samples"] >= 15
    assert {t["id"] for t in report["tracks"]} == {t.id for t in still.tracks}
    assert report["max_diff_mm"] < 1.0
    assert report["detections_replayed"] == report["detections_recorded"] > 0


@pytest.fixture(scope="module")
def moving(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """1 s of the default scene, then Home (the arm moves): PNG colour."""
    from armvision.tasks.basic import home

    config = with_record(Config(), color_format="png")
    path = tmp_path_factory.mktemp("recording") / "moving.mcap"
    return record_lockstep(path, 1.0, task=home, config=config)


def test_a_realtime_replay_keeps_the_recordings_pace(
    still: Recorded, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", str(still.path), "--json", "--realtime"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["recorded_s"] == pytest.approx(2.0, abs=0.1)
    assert report["wall_s"] >= report["recorded_s"] - 0.05  # never ahead of the recording
    assert report["same_tracks"] and report["max_diff_mm"] < 1.0


def test_a_lossless_recording_replays_exactly_while_the_arm_moves(
    moving: Recorded, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recorded = moving
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(recorded.path), "--json", "--record", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["same_tracks"] and report["samples"] >= 20
    assert {t["id"] for t in report["tracks"]} == {t.id for t in recorded.tracks}
    assert report["max_diff_mm"] < 1e-6  # the same numbers: a replay is deterministic
    joints = [d.position for *_, d in read_independently(recorded.path)["/vx300s/joint_states"]]
    assert np.ptp(np.asarray(joints), axis=0).max() > 0.5  # the arm went home meanwhile
    replayed = read_independently(out)
    assert len(replayed["/camera/color/image_raw/compressed"]) == report["frames"]


def test_a_jpeg_recording_of_a_grab_replays_within_a_millimetre(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The acceptance case: a lockstep run that grabs and lifts a bottle, with the default
    JPEG colour, the gripper tag coming into view at a slant as the arm reaches. Before, one
    such sighting seen in the recording but not in the replay (JPEG moves the tag's edge)
    turned the refined camera pose and every track by 1.2 mm in the demo, 6.8 mm here."""
    from armvision.tasks.grab import grab

    recorded = record_lockstep(tmp_path / "grab.mcap", 1.0, task=grab)
    assert recorded.truth["objects"]  # the scene's objects, where the simulator has them
    assert main(["replay", str(recorded.path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["same_tracks"] and report["samples"] >= 50  # same ids, sample by sample
    assert {t.id for t in recorded.tracks} <= {t["id"] for t in report["tracks"]}
    assert report["max_diff_mm"] < 1.0, report["tracks"]
    tags = read_independently(recorded.path)["/armvision/tags"]
    assert any(decoded for *_, decoded in tags)  # the gripper tag was seen during the grab
    heights = [o[2] for o in recorded.truth["objects"]]
    assert max(heights) > 0.05  # a bottle was carried up (simulator truth)


def test_perceive_replays_one_recorded_frame(
    still: Recorded, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["perceive", "--replay", str(still.path), "--frame", "30", "--json"]
    assert main([*args, "--out", str(tmp_path)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["source"]["kind"] == "replay" and result["source"]["frame"] == 30
    T_base_cam = still.truth["T_base_cam"]
    centres = [
        p + np.array([0, 0, h / 2]) for p, h in zip(still.truth["objects"], still.truth["heights"])
    ]
    found = [
        T_base_cam[:3, :3] @ np.asarray(d["center_cam"]) + T_base_cam[:3, 3]
        for d in result["detections"]
    ]
    for centre in centres:
        assert min(np.linalg.norm(f - centre) for f in found) < 0.02
    args = ["perceive", "--replay", str(still.path), "--frame", "100000"]
    assert main([*args, "--out", str(tmp_path)]) == 2
    assert "no frame 100000" in capsys.readouterr().err


def test_export_lerobot_writes_the_documented_dataset(
    moving: Recorded, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import pyarrow.parquet as pq

    out = tmp_path / "dataset"
    assert main(["export-lerobot", str(moving.path), "--out", str(out)]) == 0
    assert "1 episode(s)" in capsys.readouterr().out
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v2.1" and info["fps"] == 30
    assert info["total_episodes"] == 1 and info["splits"] == {"train": "0:1"}
    (episode,) = [
        json.loads(line) for line in (out / "meta/episodes.jsonl").read_text().splitlines()
    ]
    (task,) = [json.loads(line) for line in (out / "meta/tasks.jsonl").read_text().splitlines()]
    assert task == {"task_index": 0, "task": "move the arm to its home pose"}
    assert episode["tasks"] == [task["task"]] and episode["length"] == info["total_frames"]
    data = out / info["data_path"].format(episode_chunk=0, episode_index=0)
    table = pq.read_table(data)
    import pyarrow as pa

    types = {f.name: f.type for f in table.schema}
    assert set(types) == {
        "observation.state", "action", "observation.images.depth", "timestamp",
        "frame_index", "episode_index", "index", "task_index",
    }  # fmt: skip
    for key in ("observation.state", "action"):  # float32 vectors
        assert pa.types.is_list(types[key]) and types[key].value_type == pa.float32()
    assert types["observation.images.depth"] == pa.struct(
        [("bytes", pa.binary()), ("path", pa.string())]
    )  # LeRobot's (Hugging Face datasets') image
    assert types["timestamp"] == pa.float32()
    for key in ("frame_index", "episode_index", "index", "task_index"):
        assert types[key] == pa.int64()
    rows = table.to_pydict()
    n = table.num_rows
    # The Home task's span at 30 FPS (its moving time, 2 s by default, and its settling).
    assert n == episode["length"] and 55 <= n <= 120
    assert rows["frame_index"] == list(range(n)) == rows["index"]
    assert np.allclose(rows["timestamp"], np.arange(n) / 30.0, atol=1e-6)
    for key in ("observation.state", "action"):
        assert info["features"][key]["shape"] == [6]
        assert info["features"][key]["names"] == list(VX300S.joint_names)
    # The action ends at the commanded home pose; the readings get there (encoder noise).
    home = np.asarray(rows["action"][-1])
    assert np.allclose(home, VX300S.home, atol=1e-6)
    assert np.abs(np.asarray(rows["observation.state"][-1]) - home).max() < np.radians(1.5)
    assert np.abs(np.asarray(rows["observation.state"][0]) - home).max() > 0.5  # from sleep
    # Depth is 16-bit PNG of millimetres; colour an mp4 of the same frames.
    depth = cv2.imdecode(np.frombuffer(rows["observation.images.depth"][-1]["bytes"], np.uint8), -1)
    assert depth.dtype == np.uint16 and depth.shape == (480, 640)
    recorded = read_independently(moving.path)["/camera/aligned_depth_to_color/image_raw"]
    assert any(  # the very millimetres of one of the recorded frames
        np.array_equal(np.frombuffer(bytes(d.data), "<u2").reshape(480, 640), depth)
        for *_, d in recorded
    )
    video = out / info["video_path"].format(
        episode_chunk=0, video_key="observation.images.color", episode_index=0
    )
    capture = cv2.VideoCapture(str(video))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == n
    ok, image = capture.read()
    assert ok and image.shape == (480, 640, 3)
    (stats,) = [
        json.loads(line) for line in (out / "meta/episodes_stats.jsonl").read_text().splitlines()
    ]
    assert stats["stats"]["observation.state"]["count"] == [n]
    assert np.asarray(stats["stats"]["observation.images.color"]["mean"]).shape == (3, 1, 1)
    assert main(["export-lerobot", str(moving.path), "--out", str(out)]) == 2  # not over it


def test_replay_of_a_missing_or_foreign_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    foreign = tmp_path / "notes.mcap"
    foreign.write_text("not a recording")
    for path, says in ((tmp_path / "none.mcap", "no recording at"), (foreign, "not an MCAP")):
        for command in (["replay", str(path)], ["export-lerobot", str(path), "--out", "x"]):
            assert main(command) == 2
            err = capsys.readouterr().err
            assert says in err and err.count("\n") == 1
