"""The running system: stages in lockstep against the simulator's truth, task bookkeeping,
Stop, detector switches, failing stages, and 30 s of every thread in realtime."""

from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np
import pytest

from armvision.bench.system import sim_system
from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.runtime.context import TaskError
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.tasks.grab import grab

BOTTLE = ObjectSpec(
    "bottle", "bottle", radius=0.032, height=0.2, fill=0.6, liquid="juice", x=0.40, y=0.08
)
CUP = ObjectSpec(
    "cup",
    "cup",
    radius=0.034,
    height=0.1,
    fill=0.3,
    liquid="water",
    x=0.33,
    y=-0.15,
    colour=(0.8, 0.2, 0.2, 1.0),
)


def _scene() -> SceneSpec:
    return SceneSpec(random_camera_pose(Config().sim, None), (BOTTLE, CUP))


def _centre(world, name: str) -> np.ndarray:
    T = world.T_base_object(name)
    return T[:3, 3] + T[:3, 2] * world.object_spec(name).height / 2


@pytest.fixture(scope="module")
def running():
    """A lockstep system that has run 2.5 s of simulation time."""
    system = sim_system(Config(), seed=4, scene=_scene())
    system.start()
    system.pump(2.5)
    yield system
    system.close()


def test_lockstep_stages_run_at_their_rates(running) -> None:
    health = running.snapshot().health
    assert health["fusion"].rate_hz == pytest.approx(100.0, rel=0.02)
    assert health["fusion"].outputs == pytest.approx(251, abs=2)
    assert health["camera"].rate_hz == pytest.approx(30.0, rel=0.05)  # tags want every frame
    assert health["objects"].rate_hz == pytest.approx(10.0, rel=0.1)
    assert health["liquid"].rate_hz == pytest.approx(2.0, rel=0.25)
    for h in health.values():
        assert h.alive and h.last_error is None and h.errors == 0


def test_tracks_match_the_true_objects(running) -> None:
    state = running.snapshot()
    world = running.world
    by_label = {t.label: t for t in state.tracks}
    assert set(by_label) == {"bottle", "cup"} and len(state.tracks) == 2
    for name, label in (("bottle", "bottle"), ("cup", "cup")):
        track = by_label[label]
        assert np.linalg.norm(track.p_base - _centre(world, name)) < 0.01
        assert track.height == pytest.approx(world.object_spec(name).height, abs=0.015)
        assert track.radius == pytest.approx(world.object_spec(name).radius, abs=0.006)
    liquid = state.liquid[by_label["bottle"].id]
    assert liquid.samples >= 3
    assert liquid.fill == pytest.approx(BOTTLE.fill, abs=0.08)
    assert by_label["cup"].id not in state.liquid  # cups are not measured


def test_snapshots_are_immutable(running) -> None:
    state = running.snapshot()
    with pytest.raises(dataclasses.FrozenInstanceError):
        state.time = 0.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        state.frame.color[0, 0, 0] = 1
    with pytest.raises(ValueError):
        state.tracks[0].p_base[0] = 1.0
    with pytest.raises(TypeError):
        state.liquid[99] = None  # type: ignore[index]
    before = state.fusion.cycles
    running.pump(running.clock() + 0.1)
    assert state.fusion.cycles == before  # the old snapshot did not change


def test_switching_a_detector_off_and_on(running) -> None:
    running.set_detector("objects", False)
    outputs = running.snapshot().health["objects"].outputs
    running.pump(running.clock() + 0.5)
    off = running.snapshot()
    assert off.health["objects"].outputs == outputs
    assert not off.health["objects"].enabled and off.health["objects"].ok
    assert off.detections == ()
    running.set_detector("objects", True)
    running.pump(running.clock() + 0.5)
    assert running.snapshot().health["objects"].outputs >= outputs + 4
    with pytest.raises(ArmvisionError, match="no detector 'faces'"):
        running.set_detector("faces", True)


def test_task_outcomes_are_reported_readably(running) -> None:
    def fails(ctx):
        ctx.progress(0.5, "half way")
        raise TaskError("the bottle is out of reach: move it closer")

    def crashes(ctx):
        return 1 / 0

    @dataclasses.dataclass
    class Report:
        ok: bool
        reason: str

        def to_dict(self):
            return {"ok": self.ok, "reason": self.reason}

    def succeeds(ctx):
        start = ctx.now()
        ctx.sleep(0.2)
        return Report(True, f"slept {ctx.now() - start:.2f} s")

    status = running.run_task("fails", fails)
    assert status.phase == "failed" and status.error == "the bottle is out of reach: move it closer"
    assert status.progress == 0.5 and status.message == "half way"
    status = running.run_task("crashes", crashes)
    assert status.phase == "failed" and status.error.startswith("internal error (ZeroDivision")
    status = running.run_task("refused", lambda ctx: Report(False, "no bottle"))
    assert status.phase == "failed" and status.error == "no bottle"
    status = running.run_task("succeeds", succeeds)
    assert status.phase == "succeeded" and status.result == {"ok": True, "reason": "slept 0.20 s"}


def test_a_failing_stage_reports_and_carries_on() -> None:
    class Broken:
        calls = 0

        def detect(self, frame, context=None):
            Broken.calls += 1
            raise RuntimeError("model file missing")

    with sim_system(Config(), seed=4, scene=_scene(), object_detector=Broken()) as system:
        system.pump(1.0)
        health = system.snapshot().health
    assert Broken.calls >= 9
    assert health["objects"].last_error == "RuntimeError: model file missing"
    assert health["objects"].errors == Broken.calls and not health["objects"].ok
    assert health["fusion"].outputs >= 100 and health["fusion"].last_error is None
    assert health["tags"].ok


def test_all_threads_in_realtime_for_30_s_with_tasks_and_stop() -> None:
    """The acceptance test: realtime simulation, every thread, tasks, Stop, clean shutdown."""
    system = sim_system(Config(), seed=4, scene=_scene(), mode="realtime")
    start = time.monotonic()
    system.start()
    wall0, cycles0 = time.monotonic(), system.fusion.snapshot().cycles
    threads_before = {t.name for t in threading.enumerate()}
    assert {
        f"armvision-{n}" for n in ("camera", "tags", "objects", "liquid", "fusion", "motion")
    } <= (threads_before)

    # A grab while everything runs.
    status = system.run_task("grab", grab, timeout_s=60.0)
    assert status.phase == "succeeded", status.error
    assert system.world.held_object() == "bottle"

    # A long move, stopped half way: the arm halts where it is, the task ends "stopped".
    def wave(ctx):
        ctx.move_joints([0.8, -0.6, 0.4, 0.0, 0.6, 0.0], moving_time=4.0)
        return None

    task_id = system.submit("wave", wave)
    time.sleep(1.5)
    system.stop_task()
    stopped = system.wait_task(task_id, timeout_s=2.0)
    assert stopped.phase == "stopped"
    q_stop = system.world.joint_positions()
    time.sleep(0.5)
    assert np.max(np.abs(system.world.joint_positions() - q_stop)) < 0.02  # holding still
    assert abs(q_stop[0] - 0.8) > 0.2  # not at the goal: it really stopped early

    # Keep going until 30 s have passed, every stage working.
    while time.monotonic() - start < 30.0:
        time.sleep(0.5)
        assert all(h.alive for h in system.snapshot().health.values())
    state = system.snapshot()
    cycles = state.fusion.cycles - cycles0
    rate = cycles / (time.monotonic() - wall0)
    print(
        f"realtime 30 s: fusion {rate:.1f} Hz, camera {state.health['camera'].rate_hz:.1f} Hz,"
        f" tags {state.health['tags'].rate_hz:.1f} Hz,"
        f" objects {state.health['objects'].rate_hz:.1f} Hz, stalls {system.fusion_stalls}"
    )
    assert rate == pytest.approx(100.0, rel=0.05)
    for name, h in state.health.items():
        assert h.alive, name
        assert h.errors == 0, (name, h.last_error)
    assert state.health["camera"].rate_hz > 5.0
    assert state.health["objects"].outputs > 30
    assert state.tracks, "objects are still tracked"

    t0 = time.monotonic()
    system.close()
    assert time.monotonic() - t0 < 5.0
    alive = [t.name for t in threading.enumerate() if t.name.startswith(("armvision-", "sim-"))]
    assert alive == []
    assert not any(h.alive for h in system.snapshot().health.values())
    assert math.isfinite(rate)


def test_a_camera_that_knows_its_intrinsics_only_once_started() -> None:
    """A RealSense has no intrinsics before start(); the system still builds (real_system)."""
    from armvision.bench.system import sim_truth_calibration
    from armvision.errors import HardwareError
    from armvision.fusion.kalman import DEFAULT_FOCAL_PX
    from armvision.runtime.system import System
    from armvision.sim.arm import SimArm
    from armvision.sim.world import SimWorld

    class Unstarted:
        serial = "123"

        @property
        def intrinsics(self):
            raise HardwareError("RealSenseCamera is not started")

    world = SimWorld(Config(), seed=4, scene=_scene())
    system = System(Config(), SimArm(world), Unstarted(), sim_truth_calibration(world.T_base_cam()))
    assert system.fusion.focal_px == DEFAULT_FOCAL_PX
    system.close()


def test_one_camera_pose_the_refined_one_is_in_the_state_and_given_to_the_detector() -> None:
    """A calibration 4 mm / 0.3 deg off, the gripper tag shown at several places: fusion
    refines the camera pose; the state's pose is that refined one (nearer the truth than the
    calibration, which stays unchanged as the prior) and the object detector is given it."""
    from armvision.calibration.sampling import facing_pose
    from armvision.eval.fusion import perturbed_calibration
    from armvision.geometry import pose_error
    from armvision.perception.detection import NO_CONTEXT, FrameContext
    from armvision.perception.geometric import GeometricDetector
    from armvision.runtime.state import CalibrationStatus

    config = Config()
    scene = _scene()
    T_true = scene.T_base_cam
    T_off, _ = perturbed_calibration(T_true, seed=1, translation=0.004, rotation_deg=0.3)
    given: list[np.ndarray] = []

    class Recording(GeometricDetector):
        def detect(self, frame, context: FrameContext = NO_CONTEXT):
            given.append(np.array(context.T_base_cam))
            return super().detect(frame, context)

    calibration = CalibrationStatus("4 mm off", "none", None, T_off)
    with sim_system(config, 4, scene=scene, calibration=calibration, object_detector=Recording()):
        pass  # built and closed: the constructor alone must not change the prior
    system = sim_system(
        config, 4, scene=scene, calibration=calibration, object_detector=Recording()
    )
    with system:
        offset = np.array(config.tag.offset_ee)
        for p in ([0.32, 0.05, 0.25], [0.38, -0.10, 0.32], [0.28, 0.12, 0.20], [0.35, 0.0, 0.38]):
            T = facing_pose(np.array(p), T_true[:3, 3], offset)

            def show(ctx, T=T):
                if not ctx.move_pose(T, moving_time=2.0):
                    raise TaskError(f"the arm refused: {ctx.arm.last_error}")

            status = system.run_task("show", show)
            assert status.phase == "succeeded", status.error
            system.pump(system.clock() + 2.0)
        state = system.snapshot()
    assert np.array_equal(state.calibration.T_base_cam, T_off)  # the prior is kept as given
    assert np.array_equal(state.T_base_cam, state.fusion.T_base_cam)
    assert np.array_equal(system.T_base_cam, state.T_base_cam)
    refined_mm = 1000.0 * float(pose_error(state.T_base_cam, T_true)[0])
    prior_mm = 1000.0 * float(pose_error(T_off, T_true)[0])
    assert refined_mm < prior_mm - 0.2, (refined_mm, prior_mm)
    # The detector was told the pose fusion held at each frame, not the calibration's.
    assert len(given) > 10
    assert float(pose_error(given[-1], T_off)[0]) > 1e-4
    assert float(pose_error(given[-1], state.T_base_cam)[0]) < 1e-3
