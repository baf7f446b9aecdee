"""The operator UI's speed: what one page gets, and how fast Stop acts.

    python benchmarks/bench_ui.py [--seconds 6] [--seed 3]

A realtime simulation of the fixed bench (simulator-truth calibration, a bottle, a cup and a tag)
with its UI served by uvicorn in a thread, one client on the loopback:

- state over the WebSocket: messages per second and their size (target >= 10 Hz, issue 8);
- the annotated colour MJPEG: frames per second delivered and their size, and the time to
  draw and encode one (annotation + JPEG, in the server);
- an action: time from POST to the 202 answer (the task runs in the background);
- Stop during a 4 s move: time from the POST to the answer, to the task's "stopped" in the
  state, and how far the end effector went after the click (simulator truth).

The camera renders in software here, so the video rate is the camera stage's, not the UI's.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import httpx
import numpy as np
from websockets.sync.client import connect

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.sim.scene import bench_scene
from armvision.ui.server import OperatorUI, Server, listen


def _websocket(url: str, seconds: float) -> tuple[float, float]:
    sizes = []
    with connect(url.replace("http://", "ws://") + "/ws/state") as ws:
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            sizes.append(len(ws.recv(timeout=2)))
        elapsed = time.monotonic() - start
    return len(sizes) / elapsed, float(np.mean(sizes))


def _mjpeg(client: httpx.Client, url: str, seconds: float) -> tuple[float, float]:
    frames, sizes, buffer = 0, [], b""
    with client.stream("GET", url + "/stream.mjpg?view=color") as r:
        start = time.monotonic()
        for chunk in r.iter_bytes():
            buffer += chunk
            while (end := buffer.find(b"\xff\xd9")) >= 0:
                sizes.append(end + 2 - max(buffer.find(b"\xff\xd8"), 0))
                buffer = buffer[end + 2 :]
                frames += 1
            if time.monotonic() - start > seconds:
                break
        elapsed = time.monotonic() - start
    return frames / elapsed, float(np.mean(sizes)) if sizes else float("nan")


def _wait(client: httpx.Client, url: str, condition, timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while True:
        state = client.get(url + "/api/state").json()
        if condition(state) or time.monotonic() > deadline:
            return state
        time.sleep(0.02)


def measure(seconds: float, seed: int) -> dict[str, float]:
    config = Config()
    system = sim_system(config, seed, mode="realtime", scene=bench_scene(config))
    system.start()
    ui = OperatorUI(system, config, "sim")
    server = Server(ui, listen("127.0.0.1", 0)).start()
    url = f"http://127.0.0.1:{server.port}"
    out: dict[str, float] = {}
    try:
        with httpx.Client(timeout=10.0) as client:
            _wait(client, url, lambda s: s["tracks"], 30.0)
            out["state_hz"], out["state_bytes"] = _websocket(url, seconds)
            out["video_fps"], out["video_bytes"] = _mjpeg(client, url, seconds)
            draw = []
            for _ in range(20):
                ui._jpeg.clear()
                t0 = time.perf_counter()
                ui.jpeg("color")
                draw.append(time.perf_counter() - t0)
            out["draw_encode_ms"] = 1000 * float(np.median(draw))
            out["camera_fps"] = system.snapshot().health["camera"].rate_hz

            t0 = time.perf_counter()
            client.post(url + "/api/actions/home", json={})
            out["action_answer_ms"] = 1000 * (time.perf_counter() - t0)
            _wait(client, url, lambda s: s["task"]["phase"] == "succeeded", 30.0)

            def wave(ctx):
                ctx.move_joints([0.8, -0.6, 0.4, 0.0, 0.6, 0.0], moving_time=4.0)

            world = system.world
            system.submit("wave", wave)
            time.sleep(1.5)
            p_click = world.T_base_ee()[:3, 3].copy()
            t0 = time.perf_counter()
            client.post(url + "/api/stop")
            out["stop_answer_ms"] = 1000 * (time.perf_counter() - t0)
            _wait(client, url, lambda s: s["task"]["phase"] == "stopped", 5.0)
            out["stop_to_stopped_ms"] = 1000 * (time.perf_counter() - t0)
            time.sleep(0.5)
            out["stop_travel_mm"] = 1000 * float(np.linalg.norm(world.T_base_ee()[:3, 3] - p_click))
    finally:
        server.stop()
        system.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="per streaming measure")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    out = measure(args.seconds, args.seed)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    rows = [
        ("state over WebSocket", f"{out['state_hz']:.1f} Hz", ">= 10 Hz"),
        ("state message size", f"{out['state_bytes'] / 1024:.1f} KiB", ""),
        ("colour MJPEG delivered", f"{out['video_fps']:.1f} FPS", "camera stage's rate"),
        ("camera stage", f"{out['camera_fps']:.1f} FPS", ""),
        ("JPEG frame size", f"{out['video_bytes'] / 1024:.1f} KiB", ""),
        ("draw + encode one frame", f"{out['draw_encode_ms']:.1f} ms", ""),
        ("action: POST to 202", f"{out['action_answer_ms']:.1f} ms", ""),
        ("Stop: POST to answer", f"{out['stop_answer_ms']:.1f} ms", ""),
        ("Stop: POST to task stopped", f"{out['stop_to_stopped_ms']:.0f} ms", ""),
        ("Stop: ee travel after click", f"{out['stop_travel_mm']:.1f} mm", ""),
    ]
    print(f"Operator UI, one client on the loopback ({os.cpu_count()} cores, realtime sim)")
    width = max(len(r[0]) for r in rows)
    print(f"{'measure':<{width}}  {'value':>10}  target")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:>10}  {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
