"""The UI's HTTP and WebSocket API against a real uvicorn server on a realtime simulation.

Ground truth is the simulator's (joint angles, end effector, object positions); the server is
the same code `armvision ui` runs, in a thread, on a free port.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator

import cv2
import httpx
import numpy as np
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.runtime.build import uncalibrated
from armvision.sim.scene import bench_scene
from armvision.ui.server import ACTIONS, TOKEN_ENV, action_states, resolve_token

from .conftest import RunningUI, captured_logs, running_ui, serve


@pytest.fixture(scope="module")
def ui() -> Iterator[RunningUI]:
    with running_ui() as running:
        yield running


@pytest.fixture
def client() -> Iterator[httpx.Client]:
    with httpx.Client(timeout=10.0) as c:
        yield c


def _error(response: httpx.Response, status: int) -> str:
    """The readable message of an error response (JSON, no traceback)."""
    assert response.status_code == status, response.text
    message = response.json()["error"]
    assert isinstance(message, str) and message and "Traceback" not in message
    return message


def test_the_page_and_its_assets_are_served(ui: RunningUI, client: httpx.Client) -> None:
    page = client.get(ui.url + "/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "armvision" in page.text and 'id="btn-stop"' in page.text
    for asset, kind in (("app.js", "javascript"), ("style.css", "text/css")):
        r = client.get(f"{ui.url}/static/{asset}")
        assert r.status_code == 200 and kind in r.headers["content-type"]


def test_state_matches_the_simulator(ui: RunningUI, client: httpx.Client) -> None:
    state = ui.state(client)
    world = ui.system.world
    arm = state["arm"]
    assert arm["joint_names"][0] == "waist" and len(arm["joints_deg"]) == 6
    # Encoder reading (0.1 deg noise, a per-seed zero bias of at most 0.3 deg) vs the truth.
    assert np.allclose(arm["joints_deg"], np.degrees(world.joint_positions()), atol=0.6)
    assert np.allclose(arm["ee"]["xyz_m"], world.T_base_ee()[:3, 3], atol=0.005)
    assert arm["finger_m"] == pytest.approx(ui.system.arm.gripper.get_finger_position(), abs=1e-3)
    assert state["calibration"]["source"] == "simulator truth"
    assert set(state["health"]) == {"camera", "tags", "objects", "liquid", "fusion", "motion"}
    assert all(h["alive"] and h["last_error"] is None for h in state["health"].values())
    # The rate is counted over 2 s: just after start it still holds the start-up stall.
    settled = ui.wait_state(client, lambda s: s["health"]["fusion"]["rate_hz"] > 80, 10.0)
    assert settled["health"]["fusion"]["rate_hz"] > 80
    assert state["detectors"] == {"tags": True, "objects": True, "liquid": True}
    assert {t["id"] for t in state["tags"]} >= {0}  # the tag on the table
    by_label = {t["label"]: t for t in state["tracks"]}
    for name in ("bottle", "cup"):
        true_centre = world.T_base_object(name)[:3, 3]
        track = by_label[name]
        # Tracks sit at the container's centre; the truth's origin is its base.
        assert np.linalg.norm(np.array(track["position_m"][:2]) - true_centre[:2]) < 0.02
        assert track["sigma_mm"] > 0
    assert list(state["actions"]) == list(ACTIONS)
    assert state["task"]["phase"] == "idle" and state["busy"] is False
    assert all(a["enabled"] for a in state["actions"].values())


def test_liquid_level_of_the_bottle_is_in_the_state(ui: RunningUI, client: httpx.Client) -> None:
    state = ui.wait_state(
        client,
        lambda s: any(t["liquid"] for t in s["tracks"] if t["label"] == "bottle"),
        timeout_s=20.0,
    )
    bottle = next(t for t in state["tracks"] if t["label"] == "bottle")
    assert bottle["liquid"]["fill"] == pytest.approx(0.6, abs=0.12)  # the scene's fill


def test_state_is_pushed_over_the_websocket_at_10_hz_or_more(ui: RunningUI) -> None:
    ws_url = ui.url.replace("http://", "ws://") + "/ws/state"
    with connect(ws_url, open_timeout=5) as ws:
        start, messages = time.monotonic(), []
        while time.monotonic() - start < 3.0:
            messages.append(json.loads(ws.recv(timeout=2)))
        elapsed = time.monotonic() - start
    rate = len(messages) / elapsed
    assert rate >= 10.0, rate
    assert messages[-1]["frame"]["index"] > messages[0]["frame"]["index"]  # live
    assert messages[-1]["time"] > messages[0]["time"]


def _mjpeg_frames(client: httpx.Client, url: str, n: int) -> list[np.ndarray]:
    frames, buffer = [], b""
    with client.stream("GET", url) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("multipart/x-mixed-replace")
        for chunk in r.iter_bytes():
            buffer += chunk
            while (start := buffer.find(b"\xff\xd8")) >= 0 and (
                end := buffer.find(b"\xff\xd9", start)
            ) >= 0:
                jpeg, buffer = buffer[start : end + 2], buffer[end + 2 :]
                frames.append(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR))
                if len(frames) == n:
                    return frames
    raise AssertionError("the stream ended early")


def test_colour_and_depth_streams_are_live_jpeg(ui: RunningUI, client: httpx.Client) -> None:
    for view in ("color", "depth"):
        frames = _mjpeg_frames(client, f"{ui.url}/stream.mjpg?view={view}", 3)
        assert all(f is not None and f.shape == (480, 640, 3) for f in frames)
        assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).sum() > 0  # new frames
    one = client.get(f"{ui.url}/api/frame.jpg")
    assert one.status_code == 200 and one.headers["content-type"] == "image/jpeg"


def test_home_runs_in_the_background_and_reaches_home(ui: RunningUI, client: httpx.Client):
    started = time.monotonic()
    r = client.post(f"{ui.url}/api/actions/home", json={})
    assert r.status_code == 202 and time.monotonic() - started < 1.0  # did not wait for it
    task_id = r.json()["task_id"]
    busy = ui.state(client)
    assert busy["busy"] and busy["task"]["id"] == task_id
    assert not busy["actions"]["grab"]["enabled"] and "running" in busy["actions"]["grab"]["reason"]
    done = ui.wait_state(client, lambda s: s["task"]["phase"] == "succeeded", timeout_s=20.0)
    assert done["task"]["id"] == task_id and not done["busy"]
    assert np.max(np.abs(np.degrees(ui.system.world.joint_positions()))) < 1.0  # truth


def test_a_conflicting_action_is_refused_and_stop_halts_the_task(
    ui: RunningUI, client: httpx.Client
) -> None:
    r = client.post(f"{ui.url}/api/actions/sleep", json={})
    assert r.status_code == 202
    time.sleep(0.4)
    assert "sleep is running" in _error(client.post(f"{ui.url}/api/actions/grab", json={}), 409)
    assert client.post(f"{ui.url}/api/stop").json() == {"stopped": True}
    state = ui.wait_state(client, lambda s: s["task"]["phase"] == "stopped", timeout_s=5.0)
    assert state["task"]["error"] == "stopped by the operator"
    world = ui.system.world
    q_stop = world.joint_positions()
    time.sleep(0.5)
    assert np.max(np.abs(world.joint_positions() - q_stop)) < 0.02  # holds still
    assert abs(q_stop[1] - (-1.85)) > 0.2  # short of the sleep pose: it stopped early
    assert client.post(f"{ui.url}/api/stop").status_code == 200  # always accepted, even idle


def _saved_calibration(state: dict) -> dict:
    """The calibration part of the state without the live estimates made while running (the
    camera pose as fusion refines it, the drift check)."""
    return {k: v for k, v in state["calibration"].items() if k not in ("camera", "drift")}


def test_calibrate_reports_progress_and_stops(ui: RunningUI, client: httpx.Client) -> None:
    before = _saved_calibration(ui.state(client))
    assert client.post(f"{ui.url}/api/actions/calibrate", json={}).status_code == 202
    state = ui.wait_state(
        client,
        lambda s: s["task"]["name"] == "calibrate" and s["task"]["progress"] > 0,
        timeout_s=30.0,
    )
    assert "azimuth" in state["task"]["message"]  # a pose of the sampling plan
    client.post(f"{ui.url}/api/stop")
    ui.wait_state(client, lambda s: s["task"]["phase"] == "stopped", timeout_s=5.0)
    # A stopped calibration changes nothing.
    assert _saved_calibration(ui.state(client)) == before


def test_detectors_switch_off_and_on(ui: RunningUI, client: httpx.Client) -> None:
    r = client.post(f"{ui.url}/api/detectors/objects", json={"enabled": False})
    assert r.json()["detectors"] == {"tags": True, "objects": False, "liquid": True}
    time.sleep(1.5)
    off = ui.state(client)
    assert off["detectors"]["objects"] is False and not off["health"]["objects"]["enabled"]
    outputs = off["health"]["objects"]["outputs"]
    time.sleep(1.0)
    assert ui.state(client)["health"]["objects"]["outputs"] == outputs  # not working
    client.post(f"{ui.url}/api/detectors/objects", json={"enabled": True})
    on = ui.wait_state(
        client, lambda s: s["health"]["objects"]["outputs"] > outputs + 3, timeout_s=10.0
    )
    assert on["detectors"]["objects"] and on["health"]["objects"]["ok"]


def test_bad_requests_get_readable_errors(ui: RunningUI, client: httpx.Client) -> None:
    u = ui.url
    assert "grab" in _error(client.post(f"{u}/api/actions/fly", json={}), 404)
    grab_tag = client.post(f"{u}/api/actions/grab", json={"tag_id": 1})
    assert "takes no tag_id" in _error(grab_tag, 400)
    assert "unknown parameter" in _error(client.post(f"{u}/api/actions/home", json={"x": 1}), 400)
    assert "duration_s" in _error(
        client.post(f"{u}/api/actions/follow_tag", json={"duration_s": -3}), 400
    )
    json_type = {"Content-Type": "application/json"}
    not_json = client.post(f"{u}/api/actions/home", content=b"{nope", headers=json_type)
    assert "not valid JSON" in _error(not_json, 400)
    assert "Content-Type: application/json" in _error(
        client.post(f"{u}/api/actions/home", content=b"{}"), 415
    )
    assert "no bottle track #999" in _error(
        client.post(f"{u}/api/actions/grab", json={"track_id": 999}), 400
    )
    assert "detectors are" in _error(client.post(f"{u}/api/detectors/x", json={"enabled": 1}), 404)
    assert "enabled" in _error(client.post(f"{u}/api/detectors/tags", json={}), 400)
    assert "view" in _error(client.get(f"{u}/api/frame.jpg?view=infrared"), 400)
    assert "nothing at" in _error(client.get(f"{u}/api/nothing"), 404)
    assert ui.state(client)["task"]["phase"] != "running"  # none of them started anything


def test_analyze_bottle_measures_the_fill(ui: RunningUI, client: httpx.Client) -> None:
    track_id = next(t["id"] for t in ui.state(client)["tracks"] if t["label"] == "bottle")
    r = client.post(f"{ui.url}/api/actions/analyze", json={"track_id": track_id})
    assert r.status_code == 202
    task_id = r.json()["task_id"]
    done = ui.wait_state(
        client,
        lambda s: s["task"]["id"] == task_id and s["task"]["phase"] not in ("queued", "running"),
        60,
    )
    assert done["task"]["phase"] == "succeeded", done["task"]["error"]
    assert done["task"]["result"]["fill"] == pytest.approx(0.6, abs=0.1)  # the scene's 60 %


def test_follow_bottle_starts_and_stops(ui: RunningUI, client: httpx.Client) -> None:
    assert client.post(f"{ui.url}/api/actions/follow_bottle", json={}).status_code == 202
    ui.wait_state(client, lambda s: "following bottle" in s["task"]["message"], timeout_s=15.0)
    client.post(f"{ui.url}/api/stop")
    stopped = ui.wait_state(client, lambda s: s["task"]["phase"] == "stopped", timeout_s=3.0)
    assert stopped["task"]["name"] == "follow_bottle"


def test_follow_tag_runs_until_stopped(ui: RunningUI, client: httpx.Client) -> None:
    r = client.post(f"{ui.url}/api/actions/follow_tag", json={"duration_s": 120})
    assert r.status_code == 202
    state = ui.wait_state(
        client,
        lambda s: s["task"]["phase"] == "running" and "following" in s["task"]["message"],
        timeout_s=15.0,
    )
    assert state["task"]["name"] == "follow_tag"
    time.sleep(1.0)
    client.post(f"{ui.url}/api/stop")
    stopped = ui.wait_state(client, lambda s: s["task"]["phase"] == "stopped", timeout_s=3.0)
    assert stopped["task"]["finished"] - stopped["task"]["started"] < 60  # not its 120 s


# --------------------------------------------------------------------------- access


def test_without_the_token_a_server_off_the_loopback_refuses_everything(
    ui: RunningUI, client: httpx.Client
) -> None:
    token = "s3cret-t0ken-0f-sixteen"
    with serve(ui.system, ui.server.ui.config, host="0.0.0.0", token=token) as server:
        base = f"http://127.0.0.1:{server.port}"
        for method, path in (
            ("GET", "/"),
            ("GET", "/api/state"),
            ("GET", "/static/app.js"),
            ("GET", "/stream.mjpg"),
            ("POST", "/api/actions/home"),
            ("POST", "/api/stop"),
            ("POST", "/api/detectors/tags"),
        ):
            r = client.request(method, base + path)
            assert "token" in _error(r, 401), path
            wrong = client.request(method, f"{base}{path}?token=guess")
            assert wrong.status_code == 401, path
        assert client.get(base + "/api/state", headers={"Authorization": "Bearer x"}).is_error
        with pytest.raises(InvalidStatus):
            connect(f"ws://127.0.0.1:{server.port}/ws/state", open_timeout=5).close()
        assert ui.state(client)["task"]["phase"] != "running"  # the refused Home did nothing

        # With the token: query, header, or the cookie the page gets when opened with it.
        assert client.get(f"{base}/api/state?token={token}").status_code == 200
        bearer = {"Authorization": f"Bearer {token}"}
        assert client.get(base + "/api/state", headers=bearer).status_code == 200
        with httpx.Client(timeout=10.0) as browser:
            assert browser.get(f"{base}/?token={token}").status_code == 200
            assert browser.get(base + "/static/app.js").status_code == 200  # by cookie
            assert browser.get(base + "/api/state").status_code == 200
        with connect(f"ws://127.0.0.1:{server.port}/ws/state?token={token}") as ws:
            assert json.loads(ws.recv(timeout=5))["mode"] == "sim"

        # A script (the README's curl): the token and a JSON body; Stop needs no body.
        script = {**bearer, "Content-Type": "application/json"}
        home = client.post(f"{base}/api/actions/home", content=b"{}", headers=script)
        assert home.status_code == 202, home.text
        assert client.post(f"{base}/api/stop", headers=bearer).json() == {"stopped": True}
        ui.wait_state(
            client, lambda s: s["task"]["id"] == home.json()["task_id"] and not s["busy"], 5
        )

        # Off the loopback it answers to addresses and this machine's names, not other names.
        for host in (f"127.0.0.1:{server.port}", f"10.1.2.3:{server.port}", socket.gethostname()):
            assert client.get(base + "/api/state", headers={**bearer, "Host": host}).is_success
        rebound = client.get(base + "/api/state", headers={**bearer, "Host": "evil.example"})
        assert "ui.allowed_hosts" in _error(rebound, 403)
    # The loopback server of the fixture needs none.
    assert client.get(ui.url + "/api/state").status_code == 200


def test_token_rules(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    assert resolve_token("127.0.0.1") is None and resolve_token("localhost") is None
    assert resolve_token("::1") is None
    made = resolve_token("0.0.0.0")
    assert made is not None and len(made) >= 20 and made != resolve_token("0.0.0.0")
    configured = "from-config-0123456789"
    assert resolve_token("192.168.1.20", configured) == configured
    assert resolve_token("127.0.0.1", configured) == configured  # asked for: kept
    monkeypatch.setenv(TOKEN_ENV, "from-env-0123456789")
    assert resolve_token("0.0.0.0", configured) == "from-env-0123456789"


# --------------------------------------------------------------------------- not calibrated


def test_uncalibrated_nothing_moves_to_what_the_camera_sees() -> None:
    """Without a calibration (a first start on the real arm) the page offers Home, Sleep, the
    gripper and Calibrate, and refuses grab, analyze and the follows, saying to calibrate."""
    config = Config()
    with sim_system(config, 3, scene=bench_scene(config), calibration=uncalibrated(config)) as sim:
        sim.pump(2.0)
        state = sim.snapshot()
    assert state.bottles()  # the camera sees the bottle ...
    actions = action_states(state)
    for name in ("grab", "analyze", "follow_tag", "follow_bottle"):
        assert not actions[name]["enabled"] and "Calibrate" in actions[name]["reason"]
    for name in ("home", "sleep", "gripper_open", "gripper_close", "calibrate"):
        assert actions[name]["enabled"], name


def test_the_server_refuses_what_the_page_disables(ui: RunningUI, client: httpx.Client) -> None:
    """A request for a disabled control (e.g. from a stale page) gets the same reason."""
    calibrated = ui.system.calibration
    ui.system.set_calibration(uncalibrated(Config()))
    try:
        message = _error(client.post(f"{ui.url}/api/actions/grab", json={}), 409)
        assert "not calibrated" in message
        assert ui.state(client)["calibration"]["calibrated"] is False
    finally:
        ui.system.set_calibration(calibrated)


# --------------------------------------------------------------------------- bad clients


def test_a_socket_from_another_site_is_refused(ui: RunningUI) -> None:
    ws_url = ui.url.replace("http://", "ws://") + "/ws/state"
    for origin in ("http://evil.example", "http://127.0.0.1:1", "null"):
        with pytest.raises(InvalidStatus) as refused:
            connect(ws_url, origin=origin, open_timeout=5).close()
        assert refused.value.response.status_code == 403
    with connect(ws_url, origin=ui.url, open_timeout=5) as ws:  # the page's own
        assert json.loads(ws.recv(timeout=5))["mode"] == "sim"


def _half_sent_post(port: int, path: str) -> None:
    """A POST whose client leaves after a few bytes of the body it announced."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(
            f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
            "Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n{".encode()
        )
        time.sleep(0.02)  # the server is reading the body


def test_clients_that_leave_mid_body_are_answered_quietly(
    ui: RunningUI, client: httpx.Client
) -> None:
    """50 half-sent POSTs used to write 5,300 log lines (two tracebacks each)."""
    port = ui.server.port
    with captured_logs() as logs:
        for i in range(50):
            _half_sent_post(port, ("/api/actions/home", "/api/detectors/tags")[i % 2])
        time.sleep(0.5)  # the server notices the last ones leaving
        assert client.get(ui.url + "/api/state").status_code == 200  # and serves on
    assert not logs.tracebacks(), [r.getMessage() for r in logs.tracebacks()][:3]
    assert logs.lines() <= 50, [r.getMessage() for r in logs.records][:5]
    assert ui.state(client)["task"]["phase"] != "running" and ui.system.enabled["tags"]


def test_a_bug_is_one_traceback_in_the_log_and_one_line_to_the_client(
    ui: RunningUI, client: httpx.Client, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(fresh: bool = False) -> str:
        raise ZeroDivisionError("a bug\nover two lines")

    monkeypatch.setattr(ui.server.ui, "payload", broken)
    with captured_logs() as logs:
        r = client.get(ui.url + "/api/state")
        time.sleep(0.3)  # what the server logs after answering
    assert len(logs.tracebacks()) == 1, [r.getMessage() for r in logs.records]
    assert _error(r, 500) == "internal error (ZeroDivisionError); see the server log"
