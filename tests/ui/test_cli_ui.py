"""`armvision ui` as a user starts it: the printed address, the token off the loopback, Ctrl-C,
and a busy port."""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import httpx

from armvision.ui.server import TOKEN_ENV, listen

ARMVISION = [sys.executable, "-m", "armvision.cli"]


def _sigint_default() -> None:
    """In the child: Ctrl-C as in a terminal, even when this test runs as a background job
    (a shell without job control starts those with SIGINT ignored, which Python keeps)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("ARMVISION_CONFIG", TOKEN_ENV)}


def test_off_the_loopback_it_prints_a_token_address_and_refuses_requests_without_it(tmp_path):
    proc = subprocess.Popen(
        [*ARMVISION, "ui", "--sim", "--calibration", "truth", "--host", "0.0.0.0", "--port", "0"],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        cwd=tmp_path,
        env=_env(),
        preexec_fn=_sigint_default,
    )
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stderr], daemon=True).start()
    try:
        deadline, url = time.monotonic() + 120, None
        while url is None:
            assert time.monotonic() < deadline and proc.poll() is None, "no address printed"
            try:
                line = lines.get(timeout=1.0)
            except queue.Empty:
                continue
            url = re.search(r"operator UI at (http://\S+)", line)
        match = re.fullmatch(r"http://[^:/]+:(\d+)/\?token=(\S+)", url.group(1))
        assert match, url.group(1)
        port, token = match.groups()
        base = f"http://127.0.0.1:{port}"
        assert httpx.get(f"{base}/api/state").status_code == 401
        assert httpx.get(f"{base}/api/state?token=wrong").status_code == 401
        state = httpx.get(f"{base}/api/state?token={token}")
        assert state.status_code == 200 and state.json()["mode"] == "sim"
        proc.send_signal(signal.SIGINT)  # Ctrl-C: a clean shutdown, the usual status 130
        assert proc.wait(timeout=30) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    rest = []
    while not lines.empty():
        rest.append(lines.get())
    assert any("UI closing" in line for line in rest)


def test_a_busy_port_is_a_one_line_error_before_anything_starts(tmp_path) -> None:
    taken = listen("127.0.0.1", 0)
    taken.listen()
    port = taken.getsockname()[1]
    try:
        started = time.monotonic()
        result = subprocess.run(
            [*ARMVISION, "ui", "--sim", "--port", str(port)],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            env=_env(),
            timeout=60,
        )
    finally:
        taken.close()
    assert result.returncode != 0
    assert f"cannot listen on 127.0.0.1:{port}" in result.stderr
    assert "--port" in result.stderr and "Traceback" not in result.stderr
    assert time.monotonic() - started < 20  # did not calibrate or build a simulation first


def test_a_short_token_is_a_one_line_error_before_anything_starts(tmp_path) -> None:
    started = time.monotonic()
    result = subprocess.run(
        [*ARMVISION, "ui", "--sim", "--host", "0.0.0.0", "--port", "0"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**_env(), TOKEN_ENV: "hunter2"},
        timeout=60,
    )
    assert result.returncode != 0
    assert f"${TOKEN_ENV} must be at least 16 characters" in result.stderr
    assert "secrets.token_urlsafe" in result.stderr and "Traceback" not in result.stderr
    assert time.monotonic() - started < 20  # did not build a simulation first
