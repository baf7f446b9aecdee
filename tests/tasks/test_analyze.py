"""tasks.analyze on the lockstep simulation, judged by the simulator's truth.

Fill is compared with ``ObjectSpec.fill`` (liquid height over the body's inner height, the
meter's definition). Bounds, from runs of the task on the simulator: in place the fill is off
by up to ~7.5 points (3.2 MAE over 16 bottles; the object detector's radius of a clear bottle
is short, which moves the meter's shoulder), presented by at most ~1.7 points (18 bottles;
the gripper measures the radius). The tag stage is off and the object stage runs at 5 Hz: the
tests spend their time rendering, and neither matters to the analysis.
"""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest

from armvision.bench.system import sim_system
from armvision.camera.frames import Intrinsics
from armvision.config import Config
from armvision.eval.liquid import true_box_and_mask
from armvision.geometry import inv_T, make_T, rpy_to_R
from armvision.perception.liquid import LiquidLevelMeter
from armvision.robot.kinematics import VX300S, ik_solutions
from armvision.runtime.context import TaskContext, TaskStopped
from armvision.runtime.system import System
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.tasks.analyze import analyze
from armvision.tasks.colour import COLOUR_PALETTE, colour_name
from armvision.tasks.spots import (
    IMAGE_MARGIN_PX,
    SPOT_CLEARANCE_M,
    Obstacle,
    bottle_box,
    presentation_spot,
    presentation_spots,
)

IN_PLACE_TOL = 0.09
PRESENTED_TOL = 0.035

NEAR = ObjectSpec("near", "bottle", 0.030, 0.20, 0.74, "water", x=0.33, y=-0.11, yaw=0.4)
FAR = ObjectSpec("far", "bottle", 0.032, 0.21, 0.35, "wine", x=0.45, y=0.10, yaw=-1.0)
# A bottle behind a taller one, a cup beside: the presentation spot must be clear of both.
TARGET = ObjectSpec("target", "bottle", 0.030, 0.18, 0.45, "wine", x=0.33, y=0.0)
FRONT = ObjectSpec("front", "bottle", 0.035, 0.24, 0.70, "milk", x=0.50, y=0.02)
SIDE = ObjectSpec("side", "cup", 0.035, 0.10, 0.50, "cola", x=0.45, y=-0.20)


def _config(**analyze: object) -> Config:
    config = Config()
    runtime = dataclasses.replace(
        config.runtime, tag_detection=False, liquid_detection=False, object_hz=5.0
    )
    grab = dataclasses.replace(config.grab, track_wait_s=3.0)
    return dataclasses.replace(
        config,
        runtime=runtime,
        grab=grab,
        analyze=dataclasses.replace(config.analyze, **analyze),
    )


def _scene(*objects: ObjectSpec) -> SceneSpec:
    return SceneSpec(random_camera_pose(Config().sim, None), objects)


class _RecordingMeter(LiquidLevelMeter):
    """The default meter, noting the time of every frame it measures; ``on_measure`` (if
    set) is called first."""

    def __init__(self) -> None:
        super().__init__()
        self.frame_times: list[float] = []
        self.on_measure = None

    def measure(self, frame, box, geometry=None):
        if self.on_measure is not None:
            self.on_measure()
        self.frame_times.append(frame.timestamp)
        return super().measure(frame, box, geometry)


def _truth(system: System, position) -> ObjectSpec:
    """The simulated object nearest the position (base frame) an analysis reports."""
    assert position is not None
    p = np.array(position[:2])
    state = min(
        system.world.objects(), key=lambda o: float(np.linalg.norm(o.T_base_obj[:2, 3] - p))
    )
    return state.spec


def _context(system: System, config: Config, stop: threading.Event | None = None) -> TaskContext:
    """A TaskContext on ``system`` running with ``config`` (as the motion worker would)."""
    ctx = TaskContext(system, 99, stop or threading.Event())
    ctx.config = config
    return ctx


@pytest.fixture(scope="module")
def two_bottles():
    meter = _RecordingMeter()
    system = sim_system(_config(), 3, scene=_scene(NEAR, FAR), liquid_meter=meter)
    system.start()
    yield system, meter
    system.close()


# --------------------------------------------------------------------------- in place


def test_in_place_the_nearest_bottle_is_measured_over_distinct_new_frames(two_bottles) -> None:
    system, meter = two_bottles
    meter.frame_times.clear()
    start = system.clock()
    status = system.run_task("analyze", analyze)  # as the motion worker runs it
    assert status.phase == "succeeded", status.error
    report = status.result
    assert report["ok"] and not report["picked"] and report["view"] == "in place"
    assert _truth(system, report["position"]).name == "near"
    assert report["fill"] == pytest.approx(NEAR.fill, abs=IN_PLACE_TOL)
    assert 0.0 <= report["fill_std"] < 0.05
    # One measurement per frame, every frame new and taken after the task started.
    assert report["frames"] == system.config.analyze.frames == len(meter.frame_times)
    assert len(set(meter.frame_times)) == len(meter.frame_times)
    assert min(meter.frame_times) >= start
    assert report["colour_name"] in COLOUR_PALETTE
    assert report["box_height_px"] > system.config.analyze.min_box_height_px


def test_a_given_track_is_the_bottle_measured(two_bottles) -> None:
    system, _ = two_bottles
    system.pump(system.clock() + 0.5)
    far_track = max(system.snapshot().bottles(), key=lambda t: float(np.hypot(*t.p_base[:2])))
    result = analyze(_context(system, system.config), track_id=far_track.id)
    assert result.ok, result.reason
    assert _truth(system, result.position).name == "far"
    assert result.fill == pytest.approx(FAR.fill, abs=IN_PLACE_TOL)
    assert result.colour_name is not None


def test_a_poor_view_without_picking_reports_why_and_what_it_saw(two_bottles) -> None:
    system, _ = two_bottles
    q_before = system.world.joint_positions()
    config = _config(min_box_height_px=2000.0, allow_pick=False)
    result = analyze(_context(system, config))
    assert not result.ok and not result.picked
    assert "px tall < 2000 px" in result.reason and "allow_pick" in result.reason
    assert result.fill is not None and result.frames == config.analyze.frames
    assert np.allclose(system.world.joint_positions(), q_before, atol=1e-3)


def test_the_timeout_ends_the_measurement_and_keeps_the_bottle_in_place(two_bottles) -> None:
    system, _ = two_bottles
    q_before = system.world.joint_positions()
    config = _config(timeout_s=0.7)  # room for ~3 of the 8 frames at 5 Hz
    start = system.clock()
    result = analyze(_context(system, config))
    assert not result.ok and not result.picked
    assert "of 8 frames measured" in result.reason and "no time is left" in result.reason
    assert 0 < result.frames < 8
    assert system.clock() - start == pytest.approx(0.7, abs=0.06)
    assert np.allclose(system.world.joint_positions(), q_before, atol=1e-3)


def test_an_unknown_track_is_a_clear_failure(two_bottles) -> None:
    system, _ = two_bottles
    result = analyze(_context(system, system.config), track_id=4242)
    assert not result.ok and result.fill is None
    assert "no confirmed track of bottle track 4242" in result.reason


def test_stop_during_the_measurement_stops_the_task(two_bottles) -> None:
    system, meter = two_bottles
    meter.on_measure = system.stop_task  # the Stop button, pressed while measuring
    try:
        status = system.run_task("analyze", analyze)
    finally:
        meter.on_measure = None
    assert status.phase == "stopped"


def test_a_set_stop_raises_task_stopped(two_bottles) -> None:
    system, _ = two_bottles
    stop = threading.Event()
    stop.set()
    with pytest.raises(TaskStopped):
        analyze(_context(system, system.config, stop))


def test_no_bottle_is_a_clear_failure() -> None:
    with sim_system(_config(), 5, scene=_scene()) as system:
        result = analyze(_context(system, system.config))
    assert not result.ok and result.track_id is None and result.frames == 0
    assert "no confirmed track of any bottle" in result.reason


# --------------------------------------------------------------------------- presented


def test_a_poor_view_presents_the_bottle_measures_it_and_puts_it_back() -> None:
    # Every bottle looks too small: the view is poor, so the bottle is picked and presented.
    config = _config(min_box_height_px=2000.0)
    with sim_system(config, 7, scene=_scene(TARGET, FRONT, SIDE)) as system:
        start = {o.spec.name: o.T_base_obj[:2, 3].copy() for o in system.world.objects()}
        result = analyze(_context(system, config))
        assert result.ok, result.reason
        assert result.picked and result.view == "presented"
        assert _truth(system, result.position).name == "target"
        assert result.frames == config.analyze.frames
        assert result.fill == pytest.approx(TARGET.fill, abs=PRESENTED_TOL)
        assert result.colour_name == "dark red"
        # Put back where it stood, upright; nothing else moved; the gripper is empty.
        for state in system.world.objects():
            moved = np.linalg.norm(state.T_base_obj[:2, 3] - start[state.spec.name])
            assert moved < (0.015 if state.spec.name == "target" else 0.002)
            assert state.upright and not state.held
        assert system.world.held_object() is None


def test_a_carry_out_of_reach_stands_the_bottle_back_where_it_was_taken(monkeypatch) -> None:
    # The view is poor, so the bottle is picked; the presentation spot is then one the arm
    # cannot reach holding the bottle level (1 m out), so the carry fails after the lift.
    from armvision.tasks import analyze as analyze_module
    from armvision.tasks.spots import Spot

    def far_spot(*args: object, **kwargs: object) -> Spot:
        return Spot((1.0, 0.0), 0.0, 1.0, (0.0, 0.0, 10.0, 10.0))

    monkeypatch.setattr(analyze_module, "presentation_spot", far_spot)
    config = _config(min_box_height_px=2000.0)
    with sim_system(config, 7, scene=_scene(TARGET, FRONT, SIDE)) as system:
        start = {o.spec.name: o.T_base_obj[:2, 3].copy() for o in system.world.objects()}
        result = analyze(_context(system, config))
        assert not result.ok and result.picked
        assert "cannot reach" in result.reason
        assert result.reason.endswith("the bottle is back in its place"), result.reason
        for state in system.world.objects():
            moved = np.linalg.norm(state.T_base_obj[:2, 3] - start[state.spec.name])
            assert moved < (0.015 if state.spec.name == "target" else 0.002)
            assert state.upright and not state.held
        assert system.world.held_object() is None


# --------------------------------------------------------------------------- pure helpers


def test_colour_names() -> None:
    for name, rgb in COLOUR_PALETTE.items():
        assert colour_name(rgb) == name
    assert colour_name(None) is None
    # Liquids as the simulated camera sees them through a clear bottle (default lighting).
    assert colour_name((126, 153, 180)) == "light blue"  # water
    assert colour_name((121, 79, 97)) == "dark red"  # wine
    assert colour_name((206, 211, 213)) == "white"  # milk


INTR = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)


def test_bottle_box_bounds_the_true_bottle() -> None:
    T_base_cam = random_camera_pose(Config().sim, None)
    T_cam_base = inv_T(T_base_cam)
    spec = ObjectSpec("b", "bottle", 0.03, 0.2, 0.5, "water", x=0.4, y=0.1)
    box = bottle_box(INTR, T_cam_base, [spec.x, spec.y, 0.0], spec.radius, spec.height)
    truth, _ = true_box_and_mask(INTR, spec, T_cam_base @ make_T(p=[spec.x, spec.y, 0.0]))
    assert np.allclose(box, truth, atol=3.0)


def _spot_args() -> dict:
    """A 20 cm bottle of radius 32 mm grasped 9 cm up, carried at 35 cm, seen from the
    default camera placement."""
    return dict(
        T_base_cam=random_camera_pose(Config().sim, None),
        intr=INTR,
        radius=0.032,
        height=0.2,
        table_z=0.0,
        grasp_offset=0.09,
        present_distance=0.45,
        standoff=0.15,
        carry_z=0.35,
    )


def test_presentation_spot_is_in_view_reachable_and_clear() -> None:
    args = {**_spot_args(), "model": VX300S}
    spot = presentation_spot(obstacles=[], **args)
    assert spot is not None
    x0, y0, x1, y1 = spot.box
    assert x0 >= IMAGE_MARGIN_PX and y0 >= IMAGE_MARGIN_PX
    assert x1 <= INTR.width - IMAGE_MARGIN_PX and y1 <= INTR.height - IMAGE_MARGIN_PX
    assert spot.distance >= 0.45  # the whole bottle does not fit in view any nearer
    assert spot.yaw == pytest.approx(math.atan2(spot.xy[1], spot.xy[0]))
    # Something standing on that spot moves it elsewhere, clear of the obstacle.
    blocker = Obstacle(spot.xy, 0.035, 0.12)
    other = presentation_spot(obstacles=[blocker], **args)
    assert other is not None
    gap = np.linalg.norm(np.subtract(other.xy, blocker.xy)) - 0.032 - blocker.radius
    assert gap >= SPOT_CLEARANCE_M - 1e-9
    # Nothing reachable in view: no spot.
    grid = np.arange(-0.75, 0.76, 0.15)
    crowd = [Obstacle((x, y), 0.08, 0.2) for x in grid for y in grid]
    assert presentation_spot(obstacles=crowd, **args) is None


def test_presentation_spots_are_ranked_and_reached_on_the_grasps_wrist_branch() -> None:
    args = {**_spot_args(), "obstacles": []}
    ranked = presentation_spots(model=VX300S, **args)
    assert ranked and ranked[0] == presentation_spot(model=VX300S, **args)
    # Without an arm to check, every spot in view and clear counts (a planner decides):
    # those the arm reaches are among them.
    unchecked = presentation_spots(model=None, **args)
    assert {s.xy for s in ranked} < {s.xy for s in unchecked}
    # From a grasp that left the forearm rolled half a turn, a spot counts only if the arm
    # reaches it on that branch. Facing a spot from the base, that branch has the forearm
    # rolled to its +-180 degree limit: the closed-form IK finds no such solution within the
    # limits for the unflipped branch's spots, so there is none.
    seed = np.array([0.83, -0.34, 1.14, -1.92, 1.25, 2.44])
    assert presentation_spots(model=VX300S, seed=seed, **args) == []
    for spot in ranked[:10]:
        T = make_T(rpy_to_R(0.0, 0.0, spot.yaw), [spot.xy[0], spot.xy[1], 0.09])
        solutions = ik_solutions(T, VX300S.home, VX300S)
        assert solutions
        assert not any(abs(q[3]) >= math.pi / 2 or abs(q[5]) >= math.pi / 2 for q in solutions)
