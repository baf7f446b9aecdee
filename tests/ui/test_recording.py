"""Record / Stop recording from the UI's API on a realtime simulation: the file reads back
with the independent readers (the ``mcap`` library, mcap-ros2-support's decoder), and the
controls refuse what they do not take."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from tests.recording.helpers import ROS_TYPES, read_independently

from .conftest import RunningUI, running_ui


@pytest.fixture(scope="module")
def ui(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningUI]:
    with running_ui() as running:
        app = running.server.ui
        folder = tmp_path_factory.mktemp("recordings")
        app.config = dataclasses.replace(
            app.config, record=dataclasses.replace(app.config.record, dir=str(folder))
        )
        yield running


@pytest.fixture
def client() -> Iterator[httpx.Client]:
    with httpx.Client(timeout=10.0) as c:
        yield c


def _folder(ui: RunningUI) -> Path:
    return Path(ui.server.ui.config.record.dir)


def test_record_then_stop_writes_a_file_every_reader_opens(
    ui: RunningUI, client: httpx.Client
) -> None:
    camera_before = ui.state(client)["health"]["camera"]["outputs"]
    r = client.post(f"{ui.url}/api/recording/start", json={})
    assert r.status_code == 200, r.text
    path = Path(r.json()["recording"]["path"])
    assert path.parent == _folder(ui) and path.suffix == ".mcap"
    assert ui.state(client)["recording"]["active"]
    again = client.post(f"{ui.url}/api/recording/start", json={})
    assert again.status_code == 409 and "already recording" in again.json()["error"]
    started = time.monotonic()
    ui.wait_state(client, lambda s: s["recording"]["frames"] >= 45, timeout_s=30.0)
    r = client.post(f"{ui.url}/api/recording/stop", json={})
    seconds = time.monotonic() - started
    camera_after = ui.state(client)["health"]["camera"]["outputs"]
    assert r.status_code == 200, r.text
    status = r.json()["recording"]
    assert not status["active"] and status["error"] is None and status["bytes"] > 0
    assert client.post(f"{ui.url}/api/recording/stop", json={}).status_code == 409

    topics = read_independently(path)
    for topic, msgtype in ROS_TYPES.items():
        assert topics[topic], topic
        assert {s.name for s, *_ in topics[topic]} == {msgtype}
    for messages in topics.values():
        times = [m.log_time for _, _, m, _ in messages]
        assert times == sorted(times)
    frames = topics["/camera/aligned_depth_to_color/image_raw"]
    assert {d.header.frame_id for *_, d in frames} == {"camera_color_optical_frame"}
    # Realtime: every frame the camera delivered meanwhile, and a joint state per fusion
    # cycle (100 Hz), less what the recorder dropped (it counts them) on this shared machine.
    assert len(frames) == status["frames"]
    assert len(frames) + status["dropped"] >= 0.8 * (camera_after - camera_before) - 2
    assert len(frames) <= camera_after - camera_before
    joints = topics["/vx300s/joint_states"]
    assert len(joints) + status["dropped"] > 50 * seconds
    (static,) = [d for *_, d in topics["/tf_static"]]
    (camera,) = static.transforms
    truth = ui.system.world.T_base_cam()
    p = camera.transform.translation
    assert np.allclose([p.x, p.y, p.z], truth[:3, 3], atol=1e-9)
    assert ui.state(client)["recording"]["path"] == str(path)


def test_recording_controls_refuse_what_they_do_not_take(
    ui: RunningUI, client: httpx.Client
) -> None:
    before = set(_folder(ui).iterdir())
    r = client.post(f"{ui.url}/api/recording/start", json={"path": "/etc/passwd"})
    assert r.status_code == 400 and "takes no parameters" in r.json()["error"]
    r = client.post(f"{ui.url}/api/recording/start", json=[])
    assert r.status_code == 400
    r = client.post(
        f"{ui.url}/api/recording/start", content=b"{}", headers={"Content-Type": "text/plain"}
    )
    assert r.status_code == 415
    r = client.post(f"{ui.url}/api/recording/pause", json={})
    assert r.status_code == 404 and "start and stop" in r.json()["error"]
    r = client.post(f"{ui.url}/api/recording/start", content=b"{" * 70_000,
                    headers={"Content-Type": "application/json"})  # fmt: skip
    assert r.status_code == 413
    r = client.post(
        f"{ui.url}/api/recording/start", json={}, headers={"Origin": "http://evil.example"}
    )
    assert r.status_code == 403
    assert set(_folder(ui).iterdir()) == before  # nothing was made


def test_a_folder_that_cannot_be_written_is_a_one_line_error(
    ui: RunningUI, client: httpx.Client, tmp_path: Path
) -> None:
    app = ui.server.ui
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    kept = app.config
    app.config = dataclasses.replace(
        kept, record=dataclasses.replace(kept.record, dir=str(blocker / "recordings"))
    )
    try:
        r = client.post(f"{ui.url}/api/recording/start", json={})
    finally:
        app.config = kept
    assert r.status_code == 400
    message = r.json()["error"]
    assert "cannot record into" in message and "\n" not in message
    shown = ui.state(client)["recording"]
    assert shown is None or not shown["active"]
