"""Faults the runtime must survive: an arm whose halt fails during Stop, a detector that returns
NaN, a camera read that hangs at shutdown."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from armvision.bench.system import sim_system, sim_truth_calibration
from armvision.config import Config
from armvision.errors import ArmvisionError, HardwareError
from armvision.perception.detection import NO_CONTEXT, Detection
from armvision.perception.geometric import GeometricDetector
from armvision.runtime.system import System
from armvision.sim.arm import SimArm
from armvision.sim.scene import bench_scene
from armvision.sim.world import SimWorld
from armvision.tasks.basic import home


def _halt_fails(system: System) -> list[int]:
    """Make the arm's halt raise as a real arm's hardware error would; counts the calls."""
    calls = []

    def halt() -> None:
        calls.append(1)
        raise HardwareError("[xs_sdk] failed to write Goal_Position on ID 1 (no status packet)")

    system.arm.halt = halt  # type: ignore[method-assign]
    return calls


def test_stop_ends_the_task_even_when_halting_the_arm_fails() -> None:
    """The motion worker survives: the task reads stopped with the halt failure, the next task
    runs, and the motion stage reports the error."""
    config = Config()
    system = sim_system(config, seed=3, mode="realtime", scene=bench_scene(config))
    system.start()
    try:

        def wave(ctx):
            ctx.move_joints([0.8, -0.6, 0.4, 0.0, 0.6, 0.0], moving_time=4.0)

        task_id = system.submit("wave", wave)
        time.sleep(1.0)
        real_halt = system.arm.halt
        calls = _halt_fails(system)
        system.stop_task()
        status = system.wait_task(task_id, timeout_s=5.0)
        assert calls, "Stop tried to halt the arm"
        assert status.phase == "stopped"
        assert "halting the arm failed" in status.error and "no status packet" in status.error
        assert "\n" not in status.error
        health = system.snapshot().health["motion"]
        assert health.alive and "halting the arm failed" in (health.last_error or "")

        system.arm.halt = real_halt  # type: ignore[method-assign]
        after = system.wait_task(system.submit("home", home), timeout_s=20.0)
        assert after.phase == "succeeded", after.error
        assert np.max(np.abs(system.world.joint_positions())) < 0.02
    finally:
        system.close()


def test_stop_in_lockstep_with_a_failing_halt_reports_instead_of_raising() -> None:
    system = sim_system(Config(), seed=3, scene=bench_scene(Config()))
    system.start()
    try:
        _halt_fails(system)

        def stops_itself(ctx):
            ctx.system.stop_task()  # Stop pressed while the task runs
            ctx.sleep(0.1)

        status = system.run_task("stops_itself", stops_itself)
        assert status.phase == "stopped" and "halting the arm failed" in status.error
        assert system.run_task("noop", lambda ctx: None).phase == "succeeded"
    finally:
        system.close()


class _NaNDetector(GeometricDetector):
    """The real geometric detector, plus one bottle with NaN in its centre (a detector bug)."""

    def detect(self, frame, context=NO_CONTEXT):
        found = super().detect(frame, context)
        bad = Detection(
            "bottle",
            0.9,
            (10.0, 10.0, 40.0, 90.0),
            np.array([np.nan, 0.0, 0.8]),
            np.array([0.06, 0.2, 0.06]),
            0.03,
            0.2,
        )
        return [*found, bad]


def test_a_nan_detection_is_blamed_on_the_object_stage_and_fusion_goes_on() -> None:
    config = Config()
    system = sim_system(config, seed=3, scene=bench_scene(config))
    system.object_detector = _NaNDetector()
    system.start()
    try:
        system.pump(2.0)
        state = system.snapshot()
        objects, fusion = state.health["objects"], state.health["fusion"]
        assert objects.errors > 0 and "non-finite" in (objects.last_error or "")
        assert fusion.errors == 0 and fusion.last_error is None
        assert all(np.all(np.isfinite(d.center_cam)) for d in state.detections)
        assert {t.label for t in state.tracks} == {"bottle", "cup"}  # the good ones went on
    finally:
        system.close()


class _HangingCamera:
    """A camera whose read() blocks, ignoring its timeout, until released (a hung driver)."""

    serial = "hang"

    def __init__(self) -> None:
        self.release = threading.Event()
        self.reading = threading.Event()

    @property
    def intrinsics(self):
        raise HardwareError("not started")

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def read(self, timeout_s: float = 1.0):
        self.reading.set()
        self.release.wait()
        raise HardwareError("the camera went away")


class _Owned:
    """Something the system owns; records whether the camera thread still ran at close()."""

    def __init__(self, system_ref: list[System]) -> None:
        self.system_ref = system_ref
        self.closed_while_camera_ran: bool | None = None

    def close(self) -> None:
        thread = self.system_ref[0]._threads.threads["camera"]
        self.closed_while_camera_ran = thread.is_alive()


def test_close_with_a_hung_camera_read_releases_nothing_under_it() -> None:
    config = Config()
    config = dataclasses.replace(
        config, runtime=dataclasses.replace(config.runtime, join_timeout_s=0.5)
    )
    world = SimWorld(config, seed=3, scene=bench_scene(config))
    camera = _HangingCamera()
    ref: list[System] = []
    owned = _Owned(ref)
    system = System(
        config,
        SimArm(world),
        camera,
        sim_truth_calibration(world.T_base_cam()),
        owns=(owned,),
    )
    ref.append(system)
    system.start()
    assert camera.reading.wait(10.0)
    t0 = time.monotonic()
    system.close()
    assert time.monotonic() - t0 < 5.0  # close() itself does not hang
    assert system.stuck == ("camera",)
    assert owned.closed_while_camera_ran is None  # not released under the running read
    camera.release.set()
    deadline = time.monotonic() + 5.0
    while owned.closed_while_camera_ran is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert owned.closed_while_camera_ran is False  # released once the read had ended


def test_a_system_refuses_work_after_close() -> None:
    system = sim_system(Config(), seed=3, scene=bench_scene(Config()))
    system.start()
    system.close()
    with pytest.raises(ArmvisionError, match="shut down"):
        system.submit("home", home)
