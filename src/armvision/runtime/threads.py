"""The realtime schedule: each stage of a :class:`~armvision.runtime.system.System` on a thread.

Real hardware, or a realtime simulation. The camera thread publishes every frame; the tag
and object threads take the newest frame at most at their configured rates; the liquid
thread measures the tracked bottles; the fusion thread cycles at ``fusion.rate_hz``; the
motion thread runs the queued tasks one by one. Every unit of work goes through
:meth:`System.guard <armvision.runtime.system.System.guard>`, so a failing stage reports and
carries on.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from armvision.camera.frames import RGBDFrame
from armvision.realtime import share_interpreter_finely

if TYPE_CHECKING:
    from armvision.runtime.system import System

log = logging.getLogger("armvision.runtime")

#: The fusion thread makes up for at most this much lost time by running cycles back to back.
FUSION_CATCH_UP_S = 0.1


class StageThreads:
    """The threads of one system: :meth:`start` them, :meth:`join` them at close."""

    def __init__(self, system: System) -> None:
        self.system = system
        self.threads: dict[str, threading.Thread] = {}

    def start(self) -> None:
        """Start every stage; returns once the camera delivered a first frame (or gave up)."""
        system = self.system
        share_interpreter_finely()
        ready = threading.Event()
        spawn: list[tuple[str, Callable[[], None]]] = [
            ("camera", lambda: self._camera(ready)),
            ("tags", lambda: self._detector("tags", system.tags_once)),
            ("objects", lambda: self._detector("objects", system.objects_once)),
            ("liquid", self._liquid),
            ("fusion", self._fusion),
            ("motion", self._motion),
        ]
        for name, target in spawn:
            thread = threading.Thread(target=target, name=f"armvision-{name}", daemon=True)
            self.threads[name] = thread
            thread.start()
        if not ready.wait(system.config.runtime.join_timeout_s + 5.0):
            log.warning("the camera did not deliver a first frame in time; carrying on")

    def alive(self, name: str) -> bool:
        thread = self.threads.get(name)
        return thread is not None and thread.is_alive()

    def join(self, timeout_s: float | None) -> tuple[str, ...]:
        """Wait up to ``timeout_s`` (None: as long as it takes) for each thread; the names of
        those still running."""
        for thread in self.threads.values():
            thread.join(timeout=timeout_s)
        return tuple(name for name, t in self.threads.items() if t.is_alive())

    def _camera(self, ready: threading.Event) -> None:
        system = self.system
        try:  # the renderer's GL context belongs to the thread that made it
            system.camera.start()
        except Exception as exc:
            system.meters["camera"].error(f"{type(exc).__name__}: {exc}")
            log.error("camera could not start: %s", exc)
            ready.set()
            return

        def once() -> None:
            system.publish_frame(system.camera.read(timeout_s=2.0))
            ready.set()

        try:
            while not system.stopping.is_set():
                system.guard("camera", once)
        finally:
            try:
                system.camera.stop()
            except Exception:
                log.exception("stopping the camera failed")

    def _detector(self, name: str, work: Callable[[RGBDFrame], None]) -> None:
        system = self.system
        rate = system.rates[name]
        seq = 0
        next_time = time.monotonic()
        while not system.stopping.is_set():
            if not system.enabled[name]:
                system.stopping.wait(0.05)
                continue
            new_seq, frame = system.store.wait_frame(seq, 0.5)
            if frame is None or new_seq == seq:
                continue
            seq = new_seq
            system.guard(name, functools.partial(work, frame))
            next_time = max(next_time + 1.0 / rate, time.monotonic() - 1.0)
            delay = next_time - time.monotonic()
            if delay > 0:
                system.stopping.wait(delay)

    def _liquid(self) -> None:
        system = self.system
        period = 1.0 / system.rates["liquid"]
        while not system.stopping.is_set():
            if system.enabled["liquid"]:
                system.guard("liquid", system.liquid_once)
            system.stopping.wait(period)

    def _fusion(self) -> None:
        """Cycles on a fixed grid of 1/rate_hz. A cycle that starts late (another thread held
        the interpreter) is followed by the missed ones at once, up to FUSION_CATCH_UP_S of
        them, so the rate holds on average; a longer stall is skipped and counted."""
        system = self.system
        period = 1.0 / system.config.fusion.rate_hz
        next_time = time.monotonic()
        while not system.stopping.is_set():
            system.guard("fusion", system.fusion_step)
            next_time += period
            delay = next_time - time.monotonic()
            if delay < -FUSION_CATCH_UP_S:
                system.fusion_stalls += 1
                next_time = time.monotonic()
            elif delay > 0:
                system.stopping.wait(delay)

    def _motion(self) -> None:
        jobs = self.system.jobs
        while not self.system.stopping.is_set():
            job = jobs.next()
            if job is None:
                break
            try:
                jobs.run(job)
            except Exception as exc:  # the worker outlives any task: the next one must run
                jobs.fail(job, exc)
