"""What the UI does with requests that are not the page's: other sites, other host names, bad
bodies. The app itself (``OperatorUI(...).app``, every middleware and route) is driven through
Starlette's TestClient, in process, on a started realtime simulation; a task that a request
does start is stopped at once (``POST /api/stop``), so the arm barely moves.

The property tests throw generated bodies (any JSON value, nested, wrong types, huge or odd
numbers, random bytes, invalid UTF-8) with generated content types at every action and
detector: the only outcomes are 2xx, or 4xx with a one-line JSON error, and never a traceback
in the log.
"""

from __future__ import annotations

import json
import socket
import time
import warnings
from collections.abc import Iterator
from dataclasses import replace

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

with warnings.catch_warnings():  # Starlette would rather have httpx2; httpx is what we have
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.runtime.system import DETECTORS, System
from armvision.sim.scene import bench_scene
from armvision.ui.server import ACTIONS, TOKEN_ENV, OperatorUI, resolve_token

from .conftest import LogRecords, captured_logs

BASE = "http://127.0.0.1:8000"  # what the TestClient sends as Host; the app is bound there
WS = "ws://127.0.0.1:8000/ws/state"
JSON = {"Content-Type": "application/json"}
MAX_MESSAGE = 300  # characters of an error message, at most


@pytest.fixture(scope="module")
def system() -> Iterator[System]:
    config = Config()
    system = sim_system(config, 3, mode="realtime", scene=bench_scene(config))
    system.start()
    try:
        deadline = time.monotonic() + 30.0
        while not (system.snapshot().bottles() and system.snapshot().tags):
            assert time.monotonic() < deadline, "no bottle tracked and no tag seen in 30 s"
            time.sleep(0.1)
        yield system
    finally:
        system.close()


@pytest.fixture(scope="module")
def client(system: System) -> Iterator[TestClient]:
    ui = OperatorUI(system, system.config, "sim")
    with TestClient(ui.app, base_url=BASE) as c:
        yield c
        c.post("/api/stop")
        for name in DETECTORS:
            system.set_detector(name, True)


@pytest.fixture(autouse=True)
def _idle(client: TestClient, system: System) -> Iterator[None]:
    """Each test starts and ends with no task running."""
    yield
    _stop(client, system)


def _stop(client: TestClient, system: System) -> None:
    """Stop whatever runs and wait for it to end (the next request finds the system idle)."""
    assert client.post("/api/stop").status_code == 200
    deadline = time.monotonic() + 5.0
    while system.snapshot().task.active:
        assert time.monotonic() < deadline, "a stopped task did not end"
        time.sleep(0.01)


def _error(response, status: int) -> str:
    """The readable message of an error response: JSON, one line, short, no traceback."""
    assert response.status_code == status, response.text[:500]
    message = response.json()["error"]
    assert isinstance(message, str) and message
    assert "\n" not in message and len(message) <= MAX_MESSAGE, message[:1000]
    assert "Traceback" not in message
    return message


def _no_tracebacks(logs: LogRecords) -> None:
    bad = logs.tracebacks() + [r for r in logs.records if r.levelname in ("ERROR", "CRITICAL")]
    assert not bad, [r.getMessage()[:300] for r in bad]


# --------------------------------------------------------------------------- other sites


def test_a_request_from_another_site_is_refused(client: TestClient, system: System) -> None:
    evil = {"Origin": "http://evil.example"}
    before = system.snapshot().task.task_id
    for path, body in (("/api/actions/home", {}), ("/api/detectors/tags", {"enabled": False})):
        r = client.post(path, json=body, headers=evil)
        assert "another site" in _error(r, 403)
        other_port = client.post(path, json=body, headers={"Origin": "http://127.0.0.1:9999"})
        assert other_port.status_code == 403  # another port is another site
        assert client.post(path, json=body, headers={"Origin": "null"}).status_code == 403
    assert "another site" in _error(client.post("/api/stop", headers=evil), 403)
    assert system.snapshot().task.task_id == before and system.enabled["tags"]  # nothing done
    # The page's own origin (by any of the names the server answers to) and scripts (no Origin).
    for origin in (BASE, "http://127.0.0.1:8000", "http://LOCALHOST:8000"):
        host = origin.removeprefix("http://").lower()
        r = client.post("/api/actions/home", json={}, headers={"Origin": origin, "Host": host})
        assert r.status_code == 202, r.text
        _stop(client, system)
    assert client.post("/api/stop", headers={"Origin": BASE}).status_code == 200


def test_only_json_bodies_change_anything(client: TestClient, system: System) -> None:
    """An HTML form (urlencoded, multipart, text/plain) or a no-cors fetch cannot send JSON."""
    before = system.snapshot().task.task_id
    for content_type in (
        "text/plain",
        "application/x-www-form-urlencoded",
        "multipart/form-data; boundary=x",
        None,
    ):
        headers = {} if content_type is None else {"Content-Type": content_type}
        r = client.post("/api/actions/home", content=b"{}", headers=headers)
        assert "Content-Type: application/json" in _error(r, 415)
        r = client.post("/api/detectors/tags", content=b'{"enabled": false}', headers=headers)
        assert _error(r, 415)
        # Stop is a safety control: whatever it carries, it stops.
        assert client.post("/api/stop", content=b"x", headers=headers).json() == {"stopped": True}
    assert system.snapshot().task.task_id == before and system.enabled["tags"]
    r = client.post(
        "/api/actions/home",
        content=b"{}",
        headers={"Content-Type": "application/json; charset=utf-8"},
    )
    assert r.status_code == 202
    _stop(client, system)


def test_other_host_names_are_refused(client: TestClient, system: System) -> None:
    """DNS rebinding: a foreign name that resolves to this machine gets nothing."""
    for name in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example", "", "a b"):
        r = client.get("/api/state", headers={"Host": name})
        assert "ui.allowed_hosts" in _error(r, 403), name
        assert client.get("/", headers={"Host": name}).status_code == 403
        assert client.post("/api/stop", headers={"Host": name}).status_code == 403
    evil = {"Host": "evil.example"}
    with pytest.raises(WebSocketDisconnect), client.websocket_connect(WS, headers=evil):
        pass
    for name in ("127.0.0.1:8000", "localhost:8000", "localhost", "127.1.2.3", "[::1]:8000"):
        assert client.get("/api/state", headers={"Host": name}).status_code == 200, name
    with client.websocket_connect(WS, headers={"Host": "localhost:8000"}) as ws:
        assert json.loads(ws.receive_text())["mode"] == "sim"

    # Configured names; bound off the loopback, addresses and this machine's names too.
    config = replace(system.config, ui=replace(system.config.ui, allowed_hosts=("bench.lab",)))
    lab = OperatorUI(system, config, "sim")
    with TestClient(lab.app, base_url=BASE) as c:
        assert c.get("/api/state", headers={"Host": "bench.lab:8000"}).status_code == 200
        assert c.get("/api/state", headers={"Host": "192.168.1.20:8000"}).status_code == 403
        lab.bind("0.0.0.0")
        for name in ("192.168.1.20:8000", "[fe80::1]:8000", socket.gethostname(), "bench.lab"):
            assert c.get("/api/state", headers={"Host": name}).status_code == 200, name
        assert c.get("/api/state", headers={"Host": f"{socket.gethostname()}.local"}).is_success
        assert c.get("/api/state", headers={"Host": "evil.example"}).status_code == 403


def test_a_socket_from_another_site_is_refused(client: TestClient) -> None:
    evil = {"Origin": "http://evil.example"}
    with pytest.raises(WebSocketDisconnect), client.websocket_connect(WS, headers=evil):
        pass
    with client.websocket_connect(WS, headers={"Origin": BASE}) as ws:
        assert json.loads(ws.receive_text())["mode"] == "sim"


def test_responses_forbid_framing_and_sniffing(client: TestClient) -> None:
    for r in (
        client.get("/"),
        client.get("/api/state"),
        client.get("/static/app.js"),
        client.get("/api/nothing"),
        client.post("/api/actions/home", content=b"{}", headers={"Content-Type": "text/plain"}),
        client.post("/api/stop", headers={"Origin": "http://evil.example"}),
        client.get("/api/state", headers={"Host": "evil.example"}),
    ):
        assert r.headers["x-frame-options"] == "DENY"
        assert r.headers["x-content-type-options"] == "nosniff"
        csp = r.headers["content-security-policy"]
        assert "frame-ancestors 'none'" in csp
        assert "unsafe-inline" not in csp and "unsafe-eval" not in csp
        if r.status_code == 403:  # a refusal: nothing at all may load from it
            assert "default-src 'none'" in csp and "evil" not in csp
        else:  # the page's policy: its own script, style, pictures and socket
            assert "default-src 'self'" in csp and "connect-src 'self'" in csp


# --------------------------------------------------------------------------- bad bodies


def test_bodies_that_used_to_crash_get_400(client: TestClient, system: System) -> None:
    before = system.snapshot().task.task_id
    with captured_logs() as logs:
        not_utf8 = client.post("/api/actions/home", content=b'{"\xff": 1}', headers=JSON)
        assert "UTF-8" in _error(not_utf8, 400)
        for deep in (b"[" * 50_000, b'{"a":' * 12_000):
            for path in ("/api/actions/follow_tag", "/api/detectors/tags"):
                assert "nested" in _error(client.post(path, content=deep, headers=JSON), 400)
        digits = b'{"track_id": ' + b"9" * 5000 + b"}"
        assert _error(client.post("/api/actions/grab", content=digits, headers=JSON), 400)
        nan = client.post("/api/actions/follow_tag", content=b'{"duration_s": NaN}', headers=JSON)
        assert "NaN is not a JSON number" in _error(nan, 400)
    _no_tracebacks(logs)
    assert system.snapshot().task.task_id == before


def test_a_big_body_is_413_and_a_big_value_is_not_echoed(client: TestClient) -> None:
    huge = json.dumps({"duration_s": "9" * 20_000_000}).encode()
    assert "64 KiB" in _error(
        client.post("/api/actions/follow_tag", content=huge, headers=JSON), 413
    )
    just_over = b'{"x": "' + b"a" * (64 * 1024) + b'"}'
    assert _error(client.post("/api/detectors/tags", content=just_over, headers=JSON), 413)
    # Under the limit, a bad value (or key) is quoted by a short prefix only.
    long_value = client.post("/api/actions/follow_tag", json={"duration_s": "7" * 60_000})
    assert "777" in _error(long_value, 400)
    long_key = client.post("/api/actions/home", json={"k" * 60_000: 1, "j" * 50: 2, "i": 3})
    assert "kkk" in _error(long_key, 400)


def test_numbers_must_be_json_numbers(client: TestClient, system: System) -> None:
    for bad in ("10", True, [10], {"s": 10}):
        r = client.post("/api/actions/follow_tag", json={"duration_s": bad})
        assert "duration_s must be a number" in _error(r, 400), bad
    track = system.snapshot().bottles()[0].id
    for bad in (str(track), float(track), True, -1):
        r = client.post("/api/actions/grab", json={"track_id": bad})
        assert "track_id must be" in _error(r, 400), bad
    for bad in ("0", 0.0, False):
        assert "tag_id must be" in _error(
            client.post("/api/actions/follow_tag", json={"tag_id": bad}), 400
        )
    for bad in ("true", 1, None):
        r = client.post("/api/detectors/tags", json={"enabled": bad})
        assert "enabled must be true or false" in _error(r, 400), bad
    assert client.post("/api/actions/follow_tag", json={"duration_s": 10}).status_code == 202
    _stop(client, system)


def test_unknown_ids_are_refused_first(client: TestClient, system: System) -> None:
    """A track id that is no bottle, or the gripper's own tag: 400 naming what exists, even
    while a task runs (before the 409 that would say to wait)."""
    bottles = [t.id for t in system.snapshot().bottles()]
    cup = next(t.id for t in system.snapshot().tracks if t.label == "cup")
    gripper_tag = system.config.tag.id
    assert client.post("/api/actions/sleep", json={}).status_code == 202
    try:
        for name in ("grab", "analyze", "follow_bottle"):
            for track in (999, cup):
                message = _error(client.post(f"/api/actions/{name}", json={"track_id": track}), 400)
                assert f"no bottle track #{track}" in message and f"#{bottles[0]}" in message
        message = _error(client.post("/api/actions/follow_tag", json={"tag_id": gripper_tag}), 400)
        assert f"tag {gripper_tag} is the gripper's own tag" in message
        assert "in view now: 0" in message  # the tag on the table
        busy = client.post("/api/actions/grab", json={"track_id": bottles[0]})
        assert "sleep is running" in _error(busy, 409)
    finally:
        _stop(client, system)


def test_a_token_must_be_long(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    for short in ("x", "s3cret-t0ken", "fifteen-chars!!"):
        with pytest.raises(ArmvisionError, match="at least 16 characters") as err:
            resolve_token("0.0.0.0", short)
        assert "secrets.token_urlsafe" in str(err.value) and "\n" not in str(err.value)
    assert resolve_token("0.0.0.0", "sixteen-chars-ok") == "sixteen-chars-ok"
    monkeypatch.setenv(TOKEN_ENV, "short")
    with pytest.raises(ArmvisionError, match=TOKEN_ENV):
        resolve_token("127.0.0.1")


# --------------------------------------------------------------------------- properties

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.integers(min_value=-(2**80), max_value=2**80),
    st.floats(),  # with NaN and the infinities, sent as JSON's non-standard NaN / Infinity
    st.text(max_size=20),
)
json_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=10,
)
keys = st.sampled_from(["track_id", "tag_id", "duration_s", "enabled"]) | st.text(max_size=10)
objects = st.dictionaries(keys, json_values, max_size=3)
raw_bodies = st.one_of(
    st.binary(max_size=64),
    st.binary(max_size=16).map(lambda b: b'{"duration_s": "' + b + b'\xff"}'),  # not UTF-8
    st.integers(2, 3000).map(lambda n: b"[" * n + b"]" * n),
    st.integers(1, 2000).map(lambda n: b'{"enabled": ' * n + b"1" + b"}" * n),
    st.integers(1, 400).map(lambda n: b'{"track_id": 1' + b"0" * n + b"}"),
    st.sampled_from([b"", b" ", b"{}", b"null", b"[]", b'"x"', b"1e999", b"-0", b"\xef\xbb\xbf{}"]),
)
near_values = st.one_of(
    st.none(), st.booleans(), st.integers(-2, 5), st.floats(0, 4000), st.text(max_size=3)
)
near_valid = st.fixed_dictionaries(  # the parameters by name, with values of many kinds
    {}, optional=dict.fromkeys(["track_id", "tag_id", "duration_s", "enabled"], near_values)
)
bodies = st.one_of(
    near_valid.map(lambda v: json.dumps(v).encode()),
    objects.map(lambda v: json.dumps(v).encode()),
    json_values.map(lambda v: json.dumps(v).encode()),
    raw_bodies,
)
content_types = st.one_of(
    st.just("application/json"),  # twice: most bodies should get as far as being read
    st.just("application/json"),
    st.sampled_from(
        [
            "application/json; charset=utf-8",
            "APPLICATION/JSON",
            "text/plain",
            "application/x-www-form-urlencoded",
            "multipart/form-data; boundary=x",
            "application/jsonp",
            "",
        ]
    ),
    st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=30),
)


def _check(response) -> None:
    event(f"status {response.status_code}")  # the spread shows with --hypothesis-show-statistics
    assert 200 <= response.status_code < 300 or 400 <= response.status_code < 500, (
        response.status_code,
        response.text[:300],
    )
    data = response.json()
    if response.status_code >= 400:
        _error(response, response.status_code)
    else:
        assert isinstance(data, dict)


def _post(client: TestClient, path: str, body: bytes | str, content_type: str):
    headers = {"Content-Type": content_type} if content_type else {}
    return client.post(path, content=body, headers=headers)


PROPERTY = settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@PROPERTY
@given(
    name=st.sampled_from([*ACTIONS, "fly", "home/../stop"]),
    body=bodies,
    content_type=content_types,
)
def test_any_action_body_is_answered_without_a_crash(
    client: TestClient, system: System, name: str, body: bytes, content_type: str
) -> None:
    with captured_logs() as logs:
        r = _post(client, f"/api/actions/{name}", body, content_type)
        if r.status_code == 202:
            _stop(client, system)  # a body that starts a task: stop it at once
    _check(r)
    _no_tracebacks(logs)


@PROPERTY
@given(
    name=st.sampled_from([*DETECTORS, "x"]),
    body=st.one_of(st.fixed_dictionaries({"enabled": near_values}).map(json.dumps), bodies),
    content_type=content_types,
)
def test_any_detector_body_is_answered_without_a_crash(
    client: TestClient, system: System, name: str, body: bytes | str, content_type: str
) -> None:
    with captured_logs() as logs:
        r = _post(client, f"/api/detectors/{name}", body, content_type)
        stop = _post(client, "/api/stop", body, content_type)
    _check(r)
    assert stop.status_code == 200  # Stop, whatever it carries
    _no_tracebacks(logs)
    for detector in DETECTORS:
        system.set_detector(detector, True)
