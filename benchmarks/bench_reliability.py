"""The operator UI and the calibration file under abuse: load, dropped clients, hostile
requests, racing actions, and hostile saves.

    python benchmarks/bench_reliability.py [--ws 30] [--mjpeg 40] [--seconds 20]
        [--requests 600] [--rounds 10] [--saves 300] [--seed 5]

A realtime simulation of the fixed bench with its UI served by uvicorn in a thread; every
client is in this process and talks to 127.0.0.1 only. Five parts:

1. Load held: ``--ws`` WebSocket clients on ``/ws/state`` and ``--mjpeg`` MJPEG clients on
   ``/stream.mjpg?view=color`` for ``--seconds``: state messages per second per client (min,
   median; target >= 10), video frames per second per client (median), five Stops during the
   load (max POST-to-answer latency), client errors, Python threads before and after.
2. Abrupt disconnects: 150 WebSockets dropped without a close handshake (FIN or RST) and 50
   POSTs that announce 1000 bytes of body and send 10: the server must still answer
   ``/api/state`` within 1 s, threads back to baseline (+-2), no traceback; the WARNING+ lines
   of the "armvision" and "uvicorn" loggers are counted.
3. Hostile requests: ``--requests`` random requests (fixed seed) of random method, endpoint,
   body (bad JSON, huge numbers, deep nesting, invalid UTF-8, up to ~200 KB), Content-Type,
   Origin and Host. No 5xx, no 2xx for a foreign Host or for a state-changing request with a
   foreign Origin, no traceback in the log. Stop after every action request.
4. Concurrency: 20 threads POST ``/api/actions/home`` at once, ``--rounds`` times: exactly
   one 202 each round.
5. Nothing saved is lost: ``--saves`` hostile operations on a calibration file in a temporary
   directory (NaN saves, the .bak a directory / a symlink / read-only / random bytes, stray
   temporary files, good saves); after each one ``load`` must give the newest good one.

Exit status 0 when every "must" holds, else 1 (the failures are listed).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import dataclasses
import json
import logging
import os
import random
import shutil
import socket
import statistics
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
from scipy.spatial.transform import Rotation
from websockets.sync.client import connect

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.sim.scene import bench_scene
from armvision.ui.server import ACTIONS, OperatorUI, Server, listen

HOST = "127.0.0.1"
SAFE = {"GET", "HEAD", "OPTIONS"}
FOREIGN_HOSTS = ("evil.example", "evil.example:80", "127.0.0.1.evil.example", "attacker.test:8080")
FOREIGN_ORIGINS = ("http://evil.example", "null", "https://127.0.0.1.evil.example")


# --------------------------------------------------------------------------- helpers


class Records(logging.Handler):
    """Every WARNING+ record of the loggers it is attached to (deduplicated by identity)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []
        self._seen: set[int] = set()
        self._lock2 = threading.Lock()

    def emit(self, record: logging.LogRecord) -> None:
        with self._lock2:
            if id(record) not in self._seen:
                self._seen.add(id(record))
                self.records.append(record)

    def mark(self) -> int:
        with self._lock2:
            return len(self.records)

    def since(self, mark: int) -> tuple[int, int]:
        """(lines, tracebacks) since ``mark``."""
        with self._lock2:
            recs = self.records[mark:]
        tracebacks = sum(
            1 for r in recs if r.exc_info or "Traceback" in r.getMessage() or r.exc_text
        )
        return len(recs), tracebacks


POOL = "AnyIO worker thread"


def _threads() -> int:
    """Python threads of this process, less the server's anyio worker pool (bounded, at most
    40 by default, reused; an idle worker only goes when a later call prunes it)."""
    return sum(1 for t in threading.enumerate() if t.name != POOL)


def _pool() -> int:
    return sum(1 for t in threading.enumerate() if t.name == POOL)


def _settle(target: int, timeout_s: float) -> int:
    """Thread count once it is at most ``target`` (or when ``timeout_s`` runs out)."""
    deadline = time.monotonic() + timeout_s
    while _threads() > target and time.monotonic() < deadline:
        time.sleep(0.25)
    return _threads()


def _wait_idle(client: httpx.Client, url: str, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError, ValueError, KeyError):
            if client.get(url + "/api/state").json()["task"]["phase"] not in ("queued", "running"):
                return
        time.sleep(0.05)


def _raw(port: int, timeout: float = 5.0) -> socket.socket:
    sock = socket.create_connection((HOST, port), timeout=timeout)
    return sock


def _read_head(sock: socket.socket, limit: int = 65536) -> bytes:
    data = b""
    while b"\r\n\r\n" not in data and len(data) < limit:
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data


def _drop(sock: socket.socket, reset: bool) -> None:
    if reset:  # RST: no FIN, no close frame
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


# --------------------------------------------------------------------------- 1. load


def part_load(url: str, port: int, n_ws: int, n_mjpeg: int, seconds: float) -> dict:
    errors: list[str] = []
    lock = threading.Lock()
    ws_rates: list[float] = []
    mjpeg_rates: list[float] = []
    stop_at = time.monotonic() + seconds + 5.0  # hard end for every client

    def ws_client() -> None:
        try:
            with connect(url.replace("http://", "ws://") + "/ws/state", open_timeout=10) as ws:
                ws.recv(timeout=5)
                n, start = 0, time.monotonic()
                end = min(start + seconds, stop_at)
                while time.monotonic() < end:
                    ws.recv(timeout=3)
                    n += 1
                rate = n / (time.monotonic() - start)
            with lock:
                ws_rates.append(rate)
        except Exception as exc:
            with lock:
                errors.append(f"ws: {type(exc).__name__}: {exc}")

    def mjpeg_client() -> None:
        try:
            sock = _raw(port, 10.0)
            try:
                sock.sendall(
                    f"GET /stream.mjpg?view=color HTTP/1.1\r\nHost: {HOST}:{port}\r\n\r\n".encode()
                )
                head = _read_head(sock)
                status = head.split(b"\r\n", 1)[0]
                if b" 200 " not in status + b" ":
                    raise RuntimeError(f"status {status!r}")
                tail, frames, start = head, 0, time.monotonic()
                end = min(start + seconds, stop_at)
                while time.monotonic() < end:
                    chunk = sock.recv(262144)
                    if not chunk:
                        raise RuntimeError("stream ended")
                    data = tail[-8:] + chunk
                    frames += data.count(b"--frame")
                    tail = chunk
                rate = frames / (time.monotonic() - start)
            finally:
                sock.close()
            with lock:
                mjpeg_rates.append(rate)
        except Exception as exc:
            with lock:
                errors.append(f"mjpeg: {type(exc).__name__}: {exc}")

    before, pool_before = _threads(), _pool()
    clients = [threading.Thread(target=ws_client, daemon=True) for _ in range(n_ws)]
    clients += [threading.Thread(target=mjpeg_client, daemon=True) for _ in range(n_mjpeg)]
    for t in clients:
        t.start()
    stops: list[float] = []
    with httpx.Client(timeout=10.0) as client:
        t_start = time.monotonic()
        for i in range(5):
            time.sleep(max(0.0, t_start + (i + 1) * seconds / 6 - time.monotonic()))
            try:
                client.post(url + "/api/actions/home", json={})  # something to stop
                time.sleep(0.2)
                t0 = time.perf_counter()
                r = client.post(url + "/api/stop")
                stops.append(time.perf_counter() - t0)
                if not 200 <= r.status_code < 300:
                    errors.append(f"stop: {r.status_code}")
            except httpx.HTTPError as exc:
                errors.append(f"stop: {type(exc).__name__}: {exc}")
        for t in clients:
            t.join(timeout=max(0.1, stop_at + 5.0 - time.monotonic()))
        _wait_idle(client, url)
    hung = sum(t.is_alive() for t in clients)
    if hung:
        errors.append(f"{hung} clients still running")
    during = _threads()
    after = _settle(before + 2, 12.0)
    return {
        "ws_min": min(ws_rates, default=float("nan")),
        "ws_median": statistics.median(ws_rates) if ws_rates else float("nan"),
        "ws_n": len(ws_rates),
        "video_median": statistics.median(mjpeg_rates) if mjpeg_rates else float("nan"),
        "video_n": len(mjpeg_rates),
        "stop_max_ms": 1000 * max(stops, default=float("nan")),
        "stops": len(stops),
        "errors": errors,
        "threads_before": before,
        "threads_end": during,
        "threads_after": after,
        "pool_before": pool_before,
        "pool_after": _pool(),
    }


# --------------------------------------------------------------------------- 2. disconnects


def part_disconnects(url: str, port: int, logs: Records, n_ws: int, n_post: int) -> dict:
    base, pool_base = _threads(), _pool()
    mark = logs.mark()
    failures = 0
    rng = random.Random(2)
    # WebSockets: open in batches, read the 101 (and maybe a message), drop without a close.
    done = 0
    while done < n_ws:
        batch = []
        for _ in range(min(50, n_ws - done)):
            try:
                s = _raw(port)
                key = base64.b64encode(os.urandom(16)).decode()
                s.sendall(
                    (
                        f"GET /ws/state HTTP/1.1\r\nHost: {HOST}:{port}\r\nUpgrade: websocket\r\n"
                        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                        "Sec-WebSocket-Version: 13\r\n\r\n"
                    ).encode()
                )
                if b" 101 " not in _read_head(s).split(b"\r\n", 1)[0] + b" ":
                    failures += 1
                if rng.random() < 0.5:
                    with contextlib.suppress(OSError):
                        s.recv(1024)
                batch.append(s)
            except OSError:
                failures += 1
            done += 1
        for s in batch:
            _drop(s, reset=rng.random() < 0.5)
    # Half-sent POSTs: headers promise 1000 bytes, 10 arrive, then the socket goes.
    done = 0
    while done < n_post:
        batch = []
        for _ in range(min(25, n_post - done)):
            try:
                s = _raw(port)
                path = rng.choice(["/api/actions/home", "/api/detectors/tags", "/api/stop"])
                s.sendall(
                    (
                        f"POST {path} HTTP/1.1\r\nHost: {HOST}:{port}\r\n"
                        "Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n"
                        '{"track_id'
                    ).encode()
                )
                batch.append(s)
            except OSError:
                failures += 1
            done += 1
        time.sleep(0.1)
        for s in batch:
            _drop(s, reset=rng.random() < 0.5)
    time.sleep(0.5)
    answered = False
    t0 = time.perf_counter()
    try:
        with httpx.Client(timeout=1.0) as client:
            answered = client.get(url + "/api/state").status_code == 200
            answer_ms = 1000 * (time.perf_counter() - t0)
            client.post(url + "/api/stop")
            _wait_idle(client, url)
    except httpx.HTTPError:
        answer_ms = float("nan")
    after = _settle(base + 2, 15.0)
    lines, tracebacks = logs.since(mark)
    return {
        "answered": answered,
        "answer_ms": answer_ms,
        "threads_base": base,
        "threads_after": after,
        "pool_base": pool_base,
        "pool_after": _pool(),
        "lines": lines,
        "tracebacks": tracebacks,
        "connect_failures": failures,
    }


# --------------------------------------------------------------------------- 3. hostile


def _hostile_body(rng: random.Random) -> bytes:
    kind = rng.randrange(16)
    if kind == 0:
        return b""
    if kind == 1:
        return json.dumps(
            rng.choice(
                [
                    {},
                    {"track_id": rng.randrange(5)},
                    {"tag_id": rng.randrange(3), "duration_s": 0.5},
                    {"enabled": rng.choice([True, False])},
                    {"duration_s": 1.0},
                ]
            )
        ).encode()
    if kind == 2:
        return json.dumps(
            rng.choice([[1, 2, 3], [], [{"track_id": 1}], "x", 1, None, True])
        ).encode()
    if kind == 3:  # huge numbers
        return rng.choice(
            [
                b'{"track_id": 1' + b"0" * 400 + b"}",
                b'{"duration_s": 1e400}',
                b'{"duration_s": -1e400}',
                b'{"tag_id": -1}',
                b'{"duration_s": NaN}',
                b'{"duration_s": Infinity}',
                b'{"track_id": 1.5}',
                b'{"duration_s": 1e-400}',
                b'{"enabled": 1e999}',
            ]
        )
    if kind == 4:  # strings where numbers go
        return json.dumps(
            rng.choice(
                [
                    {"track_id": "1"},
                    {"duration_s": "5"},
                    {"tag_id": "0"},
                    {"enabled": "true"},
                    {"track_id": True},
                    {"duration_s": None},
                ]
            )
        ).encode()
    if kind == 5:  # deep nesting
        n = rng.choice([100, 1000, 10000, 60000])
        return rng.choice([b"[" * n + b"]" * n, b'{"a":' * n + b"1" + b"}" * n, b"[" * n])
    if kind == 6:  # random bytes
        return rng.randbytes(rng.choice([1, 10, 1000, 70000, 200000]))
    if kind == 7:  # invalid UTF-8 inside JSON
        return rng.choice(
            [
                b'{"track_id": "\xff\xfe"}',
                b'{"\xc3\x28": 1}',
                b"\xef\xbb\xbf{}",
                b'{"a": "\xed\xa0\x80"}',
            ]
        )
    if kind == 8:  # large but valid JSON (over and under the limit)
        return json.dumps({"x": "a" * rng.choice([1000, 60000, 70000, 200000])}).encode()
    if kind == 9:
        return rng.choice([b"null", b"true", b"1", b'"home"', b"{", b"}", b"{}{}", b"{} x"])
    if kind == 10:  # unknown and duplicate keys
        return rng.choice(
            [b'{"evil": 1}', b'{"track_id": 1, "track_id": "x"}', b'{"enabled": true, "x": 1}']
        )
    if kind == 11:
        return b"track_id=1&duration_s=2"  # a form
    if kind == 12:
        return b"\x00" * rng.choice([1, 100, 5000])
    if kind == 13:
        return json.dumps({"track_id": -(2**63), "tag_id": 2**64}).encode()
    if kind == 14:
        return json.dumps({"duration_s": rng.choice([0, -1, 3600.0001, 1e308, 5e-324])}).encode()
    return json.dumps({"enabled": rng.choice([0, 1, "yes", [], {}])}).encode()


def part_hostile(url: str, port: int, logs: Records, n: int, seed: int) -> dict:
    rng = random.Random(seed)
    mark = logs.mark()
    endpoints = [f"/api/actions/{a}" for a in ACTIONS]
    endpoints += ["/api/actions/x", "/api/actions/HOME", "/api/actions/" + "a" * 300]
    endpoints += ["/api/actions/%00", "/api/actions/%ff%fe", "/api/actions/"]
    endpoints += [f"/api/detectors/{d}" for d in ("tags", "objects", "liquid", "x")]
    endpoints += ["/api/stop", "/api/state", "/api/frame.jpg", "/", "/ws/state", "/static/x"]
    views = ["color", "depth", "", "x", "%ff", "color&view=depth", "COLOR", "a" * 500, "%00"]
    methods = ["POST"] * 6 + ["GET"] * 3 + ["PUT", "DELETE", "PATCH", "OPTIONS", "HEAD"]
    ctypes = [
        None,
        "application/json",
        "application/json",
        "application/json; charset=utf-8",
        "APPLICATION/JSON",
        "text/plain",
        "application/x-www-form-urlencoded",
        "multipart/form-data; boundary=x",
        "application/jsonx",
        "application/json; charset=latin-1",
        b"application/\xff\xfe",
        "",
    ]
    own_origin = f"http://{HOST}:{port}"
    codes: dict[str, int] = {}
    server_errors: list[str] = []
    foreign_ok: list[str] = []
    foreign_get_ok = 0
    client_errors: list[str] = []
    with httpx.Client(timeout=10.0) as client, httpx.Client(timeout=10.0) as stopper:
        t_end = time.monotonic() + 300.0  # bound
        for i in range(n):
            if time.monotonic() > t_end:
                break
            path = rng.choice(endpoints + ["/stream.mjpg", "/api/frame.jpg?view="] * 2)
            if path.endswith(("mjpg", "view=")):
                path = path.split("?")[0] + "?view=" + rng.choice(views)
            method = rng.choice(methods)
            body = _hostile_body(rng) if rng.random() < 0.9 else b""
            headers: dict[str, str | bytes] = {}
            ct = rng.choice(ctypes)
            if ct is not None:
                headers["Content-Type"] = ct
            o = rng.random()
            foreign_origin = o < 0.2
            if foreign_origin:
                headers["Origin"] = rng.choice([*FOREIGN_ORIGINS, f"http://{HOST}:1"])
            elif o < 0.35:
                headers["Origin"] = own_origin
            foreign_host = rng.random() < 0.15
            headers["Host"] = (
                rng.choice(FOREIGN_HOSTS)
                if foreign_host
                else rng.choice([f"{HOST}:{port}", f"localhost:{port}", HOST])
            )
            what = (
                f"#{i} {method} {path[:60]} ct={ct!r} origin={headers.get('Origin')!r}"
                f" host={headers['Host']!r} body={body[:40]!r}..{len(body)}B"
            )
            try:
                with client.stream(
                    method,
                    url + path,
                    content=body if method not in ("GET", "HEAD") else None,
                    headers=headers,
                ) as r:
                    status = r.status_code
                    if not path.startswith("/stream.mjpg") or status != 200:
                        r.read()
            except httpx.HTTPError as exc:
                client_errors.append(f"{what}: {type(exc).__name__}: {exc}")
                status = None
            key = str(status) if status is not None else "no answer"
            codes[key] = codes.get(key, 0) + 1
            if status is not None and status >= 500:
                server_errors.append(f"{what} -> {status}")
            if status is not None and 200 <= status < 300:
                if foreign_host or (foreign_origin and method not in SAFE):
                    foreign_ok.append(f"{what} -> {status}")
                elif foreign_origin:
                    foreign_get_ok += 1
            if path.startswith("/api/actions/"):
                with contextlib.suppress(httpx.HTTPError):
                    stopper.post(url + "/api/stop")
        with contextlib.suppress(httpx.HTTPError):
            stopper.post(url + "/api/stop")
            for d in ("tags", "objects", "liquid"):  # back as they were by default
                stopper.post(url + f"/api/detectors/{d}", json={"enabled": True})
        _wait_idle(stopper, url)
    lines, tracebacks = logs.since(mark)
    return {
        "tried": i + 1,
        "codes": dict(sorted(codes.items())),
        "server_errors": server_errors,
        "foreign_ok": foreign_ok,
        "foreign_get_ok": foreign_get_ok,
        "client_errors": client_errors,
        "lines": lines,
        "tracebacks": tracebacks,
    }


# --------------------------------------------------------------------------- 4. concurrency


def part_race(url: str, n_threads: int, rounds: int) -> dict:
    accepted: list[int] = []
    other: dict[str, int] = {}
    clients = [httpx.Client(timeout=10.0) for _ in range(n_threads)]
    try:
        for c in clients:
            c.get(url + "/api/state")  # connections open before the race
        for _ in range(rounds):
            clients[0].post(url + "/api/stop")
            _wait_idle(clients[0], url)
            barrier = threading.Barrier(n_threads, timeout=10)
            statuses: list[int | str] = []
            lock = threading.Lock()

            def go(
                c: httpx.Client,
                barrier: threading.Barrier = barrier,
                lock: threading.Lock = lock,
                statuses: list[int | str] = statuses,
            ) -> None:
                try:
                    barrier.wait()
                    s: int | str = c.post(url + "/api/actions/home", json={}).status_code
                except Exception as exc:
                    s = type(exc).__name__
                with lock:
                    statuses.append(s)

            threads = [threading.Thread(target=go, args=(c,), daemon=True) for c in clients]
            for t in threads:
                t.start()
            for t in threads:
                t.join(timeout=15)
            accepted.append(sum(1 for s in statuses if s == 202))
            for s in statuses:
                if s != 202:
                    other[str(s)] = other.get(str(s), 0) + 1
        clients[0].post(url + "/api/stop")
        _wait_idle(clients[0], url)
    finally:
        for c in clients:
            c.close()
    return {"accepted": accepted, "other": other}


# --------------------------------------------------------------------------- 5. saves


def part_saves(n: int, seed: int) -> dict:
    root = Path(__file__).resolve().parents[1]
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    from tests.calibration.helpers import make_result

    from armvision.calibration import store
    from armvision.errors import CalibrationError

    base = store.record(make_result(), "bench_reliability")
    rng = random.Random(seed)
    nrng = np.random.default_rng(seed)
    counts = {"ops": 0, "refused": 0, "nan_accepted": 0, "good_refused": 0, "losses": 0}
    kinds: dict[str, int] = {}
    problems: list[str] = []

    def fresh() -> store.StoredCalibration:
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=int(nrng.integers(2**31))).as_matrix()
        T[:3, 3] = nrng.uniform(-1, 1, 3)
        return dataclasses.replace(base, T_base_cam=T)

    def poisoned() -> store.StoredCalibration:
        bad = rng.choice([float("nan"), float("inf"), -float("inf")])
        field = rng.randrange(6)
        if field == 0:
            T = fresh().T_base_cam.copy()
            T[rng.randrange(3), rng.randrange(4)] = bad
            return dataclasses.replace(base, T_base_cam=T)
        if field == 1:
            return dataclasses.replace(base, residual_rms_mm=bad)
        if field == 2:
            return dataclasses.replace(base, residual_max_mm=bad)
        if field == 3:
            r = list(base.residuals_mm)
            r[rng.randrange(len(r))] = bad
            return dataclasses.replace(base, residuals_mm=tuple(r))
        if field == 4:
            return dataclasses.replace(base, joint_offsets=(0.0, 0.0, bad, 0.0, 0.0, 0.0))
        tag = dict(base.tag)
        tag["offset_ee_estimated"] = [0.0, bad, 0.0]
        return dataclasses.replace(base, tag=tag)

    with tempfile.TemporaryDirectory(prefix="armvision-bench-") as tmp:
        d = Path(tmp)
        path = d / "calibration.json"
        bak = d / "calibration.json.bak"
        victim = d / "victim.txt"
        victim.write_bytes(b"not a calibration")
        newest = fresh()
        store.save(newest, path)

        def clear_bak() -> None:
            if bak.is_symlink() or bak.is_file():
                with contextlib.suppress(OSError):
                    os.chmod(bak, 0o600, follow_symlinks=False)
                bak.unlink()
            elif bak.is_dir():
                os.chmod(bak, 0o700)
                shutil.rmtree(bak)

        t_end = time.monotonic() + 120.0
        for i in range(n):
            if time.monotonic() > t_end:
                break
            kind = rng.choice(
                ["nan", "good", "bak_dir", "bak_symlink", "bak_readonly", "bak_bytes", "stray"]
            )
            kinds[kind] = kinds.get(kind, 0) + 1
            counts["ops"] += 1
            try:
                if kind == "nan":
                    try:
                        store.save(poisoned(), path)
                        counts["nan_accepted"] += 1
                        problems.append(f"op {i}: a non-finite calibration was saved")
                    except CalibrationError:
                        counts["refused"] += 1
                else:
                    if kind == "bak_dir":
                        clear_bak()
                        bak.mkdir()
                        if rng.random() < 0.5:
                            (bak / "inside").write_bytes(rng.randbytes(100))
                    elif kind == "bak_symlink":
                        clear_bak()
                        bak.symlink_to(rng.choice([victim, d / "missing", path, d]))
                    elif kind == "bak_readonly":
                        clear_bak()
                        bak.write_bytes(rng.randbytes(50))
                        os.chmod(bak, rng.choice([0o000, 0o400, 0o444]))
                    elif kind == "bak_bytes":
                        clear_bak()
                        bak.write_bytes(rng.randbytes(rng.choice([0, 1, 1000, 100000])))
                    elif kind == "stray":
                        for _ in range(rng.randrange(1, 4)):
                            name = rng.choice(
                                [
                                    f".calibration.json.{rng.randbytes(4).hex()}.tmp",
                                    f".calibration.json.bak.{rng.randbytes(4).hex()}.tmp",
                                    "calibration.json.tmp",
                                ]
                            )
                            stray = d / name
                            if not stray.exists() and not stray.is_symlink():
                                if rng.random() < 0.3:
                                    stray.symlink_to(victim)
                                else:
                                    stray.write_bytes(rng.randbytes(rng.randrange(1, 5000)))
                    # every kind but "nan" then saves a good calibration through it
                    candidate = fresh()
                    try:
                        store.save(candidate, path)
                        newest = candidate
                    except CalibrationError as exc:
                        counts["refused"] += 1
                        counts["good_refused"] += 1
                        problems.append(f"op {i} ({kind}): a good save refused: {exc}")
            except Exception as exc:
                problems.append(f"op {i} ({kind}): {type(exc).__name__}: {exc}")
            try:
                got = store.load(path)
                if not np.allclose(got.T_base_cam, newest.T_base_cam, rtol=0, atol=1e-12):
                    counts["losses"] += 1
                    problems.append(f"op {i} ({kind}): load gave another calibration")
            except CalibrationError as exc:
                counts["losses"] += 1
                problems.append(f"op {i} ({kind}): load failed: {exc}")
            if victim.read_bytes() != b"not a calibration":
                counts["losses"] += 1
                problems.append(f"op {i} ({kind}): a file behind a symlink was overwritten")
                victim.write_bytes(b"not a calibration")
        with contextlib.suppress(OSError):
            clear_bak()
    return {**counts, "kinds": kinds, "problems": problems, "root": os.geteuid() == 0}


# --------------------------------------------------------------------------- main


def _table(title: str, rows: list[tuple[str, ...]], header: tuple[str, ...]) -> None:
    print(f"\n### {title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for row in rows:
        print("| " + " | ".join(str(c) for c in row) + " |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ws", type=int, default=30, help="WebSocket clients in part 1")
    parser.add_argument("--mjpeg", type=int, default=40, help="MJPEG clients in part 1")
    parser.add_argument("--seconds", type=float, default=20.0, help="part 1's duration")
    parser.add_argument("--requests", type=int, default=600, help="hostile requests (part 3)")
    parser.add_argument("--rounds", type=int, default=10, help="racing rounds (part 4)")
    parser.add_argument("--saves", type=int, default=300, help="hostile saves (part 5)")
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args(argv)

    started = time.monotonic()
    config = Config()
    system = sim_system(config, args.seed, mode="realtime", scene=bench_scene(config))
    system.start()
    ui = OperatorUI(system, config, "sim", None)
    server = Server(ui, listen(HOST, 0)).start()
    port = server.port
    url = f"http://{HOST}:{port}"
    logs = Records()
    for name in ("armvision", "uvicorn"):
        logging.getLogger(name).addHandler(logs)
    failures: list[str] = []
    try:
        with httpx.Client(timeout=10.0) as client:
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline:
                if client.get(url + "/api/frame.jpg").status_code == 200:
                    break
                time.sleep(0.2)
        print(f"Reliability of the operator UI ({os.cpu_count()} cores, realtime sim, {url})")

        m0 = logs.mark()
        load = part_load(url, port, args.ws, args.mjpeg, args.seconds)
        load_lines, load_tb = logs.since(m0)
        _table(
            f"1. Load: {args.ws} WebSocket + {args.mjpeg} MJPEG clients, {args.seconds:g} s",
            [
                ("state msg/s per client, min", f"{load['ws_min']:.1f}", ">= 10"),
                ("state msg/s per client, median", f"{load['ws_median']:.1f}", ">= 10"),
                ("WebSocket clients finished", f"{load['ws_n']}/{args.ws}", ""),
                ("video FPS per client, median", f"{load['video_median']:.1f}", ""),
                ("MJPEG clients finished", f"{load['video_n']}/{args.mjpeg}", ""),
                (f"Stop latency, max of {load['stops']}", f"{load['stop_max_ms']:.0f} ms", ""),
                ("client errors", len(load["errors"]), "0"),
                (
                    "Python threads before / at end / settled",
                    f"{load['threads_before']} / {load['threads_end']} / {load['threads_after']}",
                    "",
                ),
                (
                    "server's anyio worker pool before / after",
                    f"{load['pool_before']} / {load['pool_after']}",
                    "<= 40",
                ),
                ("log lines WARNING+ / tracebacks", f"{load_lines} / {load_tb}", "- / 0"),
            ],
            ("measure", "value", "target"),
        )
        for e in load["errors"][:10]:
            print(f"- {e}")
        if not load["ws_min"] >= 10:
            failures.append(f"load: a WebSocket client got {load['ws_min']:.1f} msg/s (< 10)")
        if load["errors"]:
            failures.append(f"load: {len(load['errors'])} client errors")
        if load["threads_after"] > load["threads_before"] + 2:
            failures.append(
                f"load: threads {load['threads_before']} -> {load['threads_after']} (leak?)"
            )
        if load["pool_after"] > 40:
            failures.append(f"load: {load['pool_after']} anyio workers (> 40)")
        if load_tb:
            failures.append(f"load: {load_tb} tracebacks in the log")

        disc = part_disconnects(url, port, logs, 150, 50)
        delta = disc["threads_after"] - disc["threads_base"]
        _table(
            "2. Abrupt disconnects: 150 dropped WebSockets, 50 half-sent POSTs",
            [
                (
                    "/api/state answered within 1 s",
                    f"{disc['answered']} ({disc['answer_ms']:.0f} ms)",
                    "yes",
                ),
                (
                    "threads baseline / after",
                    f"{disc['threads_base']} / {disc['threads_after']} ({delta:+d})",
                    "+-2",
                ),
                (
                    "server's anyio worker pool before / after",
                    f"{disc['pool_base']} / {disc['pool_after']}",
                    "<= 40",
                ),
                ("log lines WARNING+", disc["lines"], ""),
                ("tracebacks", disc["tracebacks"], "0"),
                ("connections that failed to open", disc["connect_failures"], "0"),
            ],
            ("measure", "value", "target"),
        )
        if not disc["answered"]:
            failures.append("disconnects: /api/state not answered within 1 s")
        if disc["pool_after"] > 40:
            failures.append(f"disconnects: {disc['pool_after']} anyio workers (> 40)")
        if abs(delta) > 2:
            failures.append(f"disconnects: threads {delta:+d} after (more than 2)")
        if disc["tracebacks"]:
            failures.append(f"disconnects: {disc['tracebacks']} tracebacks in the log")

        hostile = part_hostile(url, port, logs, args.requests, args.seed)
        _table(
            f"3. Hostile requests: {hostile['tried']} (seed {args.seed})",
            [
                (
                    "answers by status",
                    ", ".join(f"{k} x {v}" for k, v in hostile["codes"].items()),
                    "",
                ),
                ("5xx", len(hostile["server_errors"]), "0"),
                (
                    "foreign Host, or foreign Origin on a POST/PUT/..., answered 2xx",
                    len(hostile["foreign_ok"]),
                    "0",
                ),
                (
                    "foreign Origin on GET/HEAD/OPTIONS answered 2xx (allowed)",
                    hostile["foreign_get_ok"],
                    "",
                ),
                ("no answer (client error)", len(hostile["client_errors"]), ""),
                (
                    "log lines WARNING+ / tracebacks",
                    f"{hostile['lines']} / {hostile['tracebacks']}",
                    "- / 0",
                ),
            ],
            ("measure", "value", "target"),
        )
        for e in (hostile["server_errors"] + hostile["foreign_ok"] + hostile["client_errors"])[:10]:
            print(f"- {e}")
        if hostile["server_errors"]:
            failures.append(f"hostile: {len(hostile['server_errors'])} answers 5xx")
        if hostile["foreign_ok"]:
            failures.append(f"hostile: {len(hostile['foreign_ok'])} foreign requests got 2xx")
        if hostile["tracebacks"]:
            failures.append(f"hostile: {hostile['tracebacks']} tracebacks in the log")

        race = part_race(url, 20, args.rounds)
        _table(
            f"4. Concurrency: 20 simultaneous POST /api/actions/home x {args.rounds}",
            [
                ("202 per round", " ".join(map(str, race["accepted"])), "1 each"),
                ("other answers", ", ".join(f"{k} x {v}" for k, v in race["other"].items()), "409"),
            ],
            ("measure", "value", "target"),
        )
        if any(a != 1 for a in race["accepted"]):
            failures.append(f"concurrency: 202s per round {race['accepted']} (not all 1)")

        saves = part_saves(args.saves, args.seed)
        _table(
            f"5. Hostile saves/loads: {saves['ops']} operations",
            [
                (
                    "operations by kind",
                    ", ".join(f"{k} x {v}" for k, v in sorted(saves["kinds"].items())),
                    "",
                ),
                ("refusals (CalibrationError)", saves["refused"], ""),
                ("non-finite calibrations saved", saves["nan_accepted"], "0"),
                ("good saves refused", saves["good_refused"], ""),
                ("calibrations lost", saves["losses"], "0"),
                ("running as root (read-only .bak does not bind)", saves["root"], ""),
            ],
            ("measure", "value", "target"),
        )
        for p in saves["problems"][:10]:
            print(f"- {p}")
        if saves["nan_accepted"]:
            failures.append(f"saves: {saves['nan_accepted']} non-finite calibrations saved")
        if saves["losses"]:
            failures.append(f"saves: {saves['losses']} calibrations lost")
        other_problems = len(saves["problems"]) - saves["nan_accepted"] - saves["losses"]
        if other_problems - saves["good_refused"] > 0:
            failures.append(
                f"saves: {other_problems - saves['good_refused']} unexpected exceptions"
            )
    finally:
        for name in ("armvision", "uvicorn"):
            logging.getLogger(name).removeHandler(logs)
        server.stop()
        system.close()

    codes = ", ".join(f"{k} x {v}" for k, v in hostile["codes"].items())
    _table(
        "Summary",
        [
            (
                "load held",
                f"{args.ws} WebSocket + {args.mjpeg} video clients, {args.seconds:g} s",
                f"state {load['ws_median']:.1f} msg/s per client (min {load['ws_min']:.1f}), "
                f"video {load['video_median']:.1f} FPS, Stop max {load['stop_max_ms']:.0f} ms, "
                f"{len(load['errors'])} errors, threads {load['threads_before']} -> "
                f"{load['threads_after']} (+ anyio pool {load['pool_after']})",
            ),
            (
                "abrupt disconnects",
                "150 dropped sockets, 50 half-sent POSTs",
                f"server {'answering' if disc['answered'] else 'NOT answering'}, threads "
                f"{delta:+d} (anyio pool {disc['pool_base']} -> {disc['pool_after']}), "
                f"{disc['tracebacks']} tracebacks, {disc['lines']} log lines",
            ),
            (
                "hostile requests",
                f"{hostile['tried']} hostile requests",
                f"{len(hostile['server_errors'])} x 5xx, {len(hostile['foreign_ok'])} foreign "
                f"accepted, {hostile['tracebacks']} tracebacks, codes: {codes}",
            ),
            (
                "racing actions",
                f"20 simultaneous actions x {args.rounds}",
                "exactly one task each time"
                if all(a == 1 for a in race["accepted"])
                else f"202s per round: {race['accepted']}",
            ),
            (
                "nothing saved is lost",
                f"{saves['ops']} hostile saves/loads",
                f"{saves['losses']} calibrations lost, {saves['refused']} refusals, "
                f"{saves['nan_accepted']} non-finite saved",
            ),
        ],
        ("what", "tried", "result"),
    )
    print(f"\nwall time {time.monotonic() - started:.0f} s")
    if failures:
        print("\nFAILED:")
        for f in failures:
            print(f"- {f}")
        return 1
    print("\nevery must holds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
