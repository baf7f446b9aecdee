"""A realtime simulated system (the fixed bench: a bottle, a cup, tag 0) with the operator UI
served by uvicorn in a thread."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import httpx

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.runtime.system import System
from armvision.sim.scene import bench_scene
from armvision.ui.server import OperatorUI, Server, listen


@dataclass
class RunningUI:
    system: System
    server: Server
    url: str  # http://127.0.0.1:PORT (no trailing slash)

    def state(self, client: httpx.Client) -> dict:
        r = client.get(f"{self.url}/api/state")
        r.raise_for_status()
        return r.json()

    def wait_state(
        self, client: httpx.Client, condition: Callable[[dict], bool], timeout_s: float
    ) -> dict:
        """Poll /api/state until ``condition`` holds; the last state (AssertionError if never)."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state(client)
            if condition(state):
                return state
            assert time.monotonic() < deadline, f"timed out; task: {state['task']}"
            time.sleep(0.1)


@contextmanager
def serve(
    system: System, config: Config, host: str = "127.0.0.1", token: str | None = None
) -> Iterator[Server]:
    server = Server(OperatorUI(system, config, "sim", token), listen(host, 0)).start()
    try:
        yield server
    finally:
        server.stop()


@contextmanager
def running_ui(seed: int = 3) -> Iterator[RunningUI]:
    """The system (simulator truth as calibration) and its UI on 127.0.0.1, any free port."""
    config = Config()
    system = sim_system(config, seed, mode="realtime", scene=bench_scene(config))
    system.start()
    try:
        with serve(system, config) as server:
            ui = RunningUI(system, server, f"http://127.0.0.1:{server.port}")
            with httpx.Client(timeout=10.0) as client:  # tracks confirmed, tags seen
                ui.wait_state(
                    client,
                    lambda s: any(t["label"] == "bottle" for t in s["tracks"]) and s["tags"],
                    timeout_s=30.0,
                )
            yield ui
    finally:
        system.close()


class LogRecords(logging.Handler):
    """Every record logged while it is installed (:func:`captured_logs`)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def tracebacks(self) -> list[logging.LogRecord]:
        return [r for r in self.records if r.exc_info or "Traceback" in r.getMessage()]

    def lines(self) -> int:
        """How many lines these records make in a log (a traceback is many)."""
        formatter = logging.Formatter()
        return sum(formatter.format(r).count("\n") + 1 for r in self.records)


@contextmanager
def captured_logs() -> Iterator[LogRecords]:
    """The records of armvision's loggers and uvicorn's (which do not reach the root logger)."""
    handler = LogRecords()
    loggers = [logging.getLogger(), logging.getLogger("uvicorn")]
    for logger in loggers:
        logger.addHandler(handler)
    try:
        yield handler
    finally:
        for logger in loggers:
            logger.removeHandler(handler)
