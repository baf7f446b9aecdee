"""The grab: its geometry by hand, its safety rules, and grasps judged by the simulator."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from armvision.bench.system import sim_system
from armvision.config import Config, GrabConfig
from armvision.fusion.kalman import FilterStats
from armvision.fusion.loop import FusionSnapshot
from armvision.fusion.tracker import TrackState
from armvision.geometry import make_T
from armvision.robot.base import GripperBase
from armvision.robot.kinematics import VX300S, fk, ik
from armvision.runtime.build import uncalibrated
from armvision.runtime.context import TaskContext
from armvision.runtime.state import SystemState, TaskStatus
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.tasks.grab import (
    GRASP_MARGIN_M,
    choose_bottle,
    corridor_clear,
    grab,
    holding,
    plan_grasp,
    safe_start_pose,
    tracked_bottle,
)


def _track(track_id: int, p, height: float = 0.2, radius: float = 0.03) -> TrackState:
    z = np.zeros(3)
    return TrackState(
        track_id,
        "bottle",
        True,
        0.0,
        np.array(p, float),
        z,
        np.eye(6) * 1e-6,
        5,
        0.0,
        (("bottle", 5.0),),
        radius,
        height,
    )


def test_plan_follows_the_papers_rule() -> None:
    # A bottle 0.5 m out at 30 deg, centre 0.1 m up (height 0.2): waypoint 0.35 m out on the
    # same bearing, grasp at 45 % of the height, both facing the bottle.
    p = [0.5 * math.cos(math.radians(30)), 0.5 * math.sin(math.radians(30)), 0.1]
    plan = plan_grasp(_track(1, p), GrabConfig())
    assert plan.yaw == pytest.approx(math.radians(30))
    assert plan.grasp_z == pytest.approx(0.09)
    assert plan.waypoint[:3, 3] == pytest.approx(
        [0.35 * math.cos(plan.yaw), 0.35 * math.sin(plan.yaw), 0.09]
    )
    assert plan.grasp[:3, 3] == pytest.approx([p[0], p[1], 0.09])
    assert plan.grasp[:3, 0] == pytest.approx([math.cos(plan.yaw), math.sin(plan.yaw), 0.0])
    # Nearer than the stand-off: the waypoint is the bottle's distance itself.
    near = plan_grasp(_track(2, [0.1, 0.0, 0.1]), GrabConfig())
    assert near.waypoint[:3, 3] == pytest.approx([0.1, 0.0, 0.09])


def _state(*tracks: TrackState) -> SystemState:
    """What the system knows when the fusion loop holds ``tracks`` (nothing else seen)."""
    fusion = FusionSnapshot(0.0, None, None, tracks, None, 0, 0, True, None, FilterStats())
    return SystemState(
        0.0,
        None,
        (),
        None,
        (),
        None,
        {},
        fusion,
        {},
        {},
        TaskStatus(),
        uncalibrated(Config()),
        None,
    )


def test_a_chosen_bottle_is_kept_while_bottle_is_among_its_votes() -> None:
    """A bottle's label may lose the vote while the gripper hides part of it on the way in;
    the grab that chose it keeps it. A track never seen as a bottle, or one whose height is
    unknown, is not kept; a first choice takes only a track labelled bottle."""
    p = [0.45, 0.0, 0.1]
    outvoted = dataclasses.replace(
        _track(3, p), label="other", votes=(("bottle", 35.8), ("other", 37.8))
    )
    can = dataclasses.replace(_track(4, p), label="other", votes=(("other", 40.0),))
    no_height = dataclasses.replace(_track(5, p), height=None)
    state = _state(outvoted, can, no_height)
    assert state.bottles() == [no_height]  # the bottles the tasks start from
    assert tracked_bottle(state, 3) is outvoted
    assert tracked_bottle(state, 4) is None
    assert tracked_bottle(state, 5) is None
    assert tracked_bottle(state, 6) is None  # no such track
    assert choose_bottle(state, 0.15, 3) is None  # not a bottle now: not a first choice


def test_safe_start_pose_is_the_papers_when_reachable_else_the_nearest() -> None:
    T = safe_start_pose((0.1, 0.0, 0.65))
    assert T[:3, 3] == pytest.approx([0.1, 0.0, 0.65]) and T[:3, :3] == pytest.approx(np.eye(3))
    far = safe_start_pose((0.1, 0.0, 0.95))  # above the arm's reach
    _, ok = ik(far, np.zeros(6), VX300S)
    assert ok and far[2, 3] < 0.95
    assert fk(ik(far, np.zeros(6), VX300S)[0])[:3, 3] == pytest.approx(far[:3, 3], abs=1e-6)


def test_corridor_sees_what_stands_in_the_way() -> None:
    target = _track(1, [0.45, 0.0, 0.1])
    assert not corridor_clear(target, [_track(2, [0.33, 0.02, 0.1])], 0.15)  # right in front
    assert corridor_clear(target, [_track(3, [0.33, 0.15, 0.1])], 0.15)  # well to the side
    assert corridor_clear(target, [_track(4, [0.1, 0.0, 0.1])], 0.15)  # behind the waypoint


def _scene(*objects: ObjectSpec) -> SceneSpec:
    return SceneSpec(random_camera_pose(Config().sim, None), objects)


def _config(**grab) -> Config:
    config = Config()
    runtime = dataclasses.replace(config.runtime, tag_detection=False, liquid_detection=False)
    return dataclasses.replace(
        config, runtime=runtime, grab=dataclasses.replace(config.grab, **grab)
    )


BOTTLE = ObjectSpec("bottle", "bottle", 0.03, 0.21, 0.5, "juice", x=0.42, y=-0.1)
BLOCKER = ObjectSpec("front", "bottle", 0.03, 0.18, 0.5, "cola", x=0.27, y=-0.064)


def test_grab_takes_the_bottle_with_a_clear_way_and_lifts_it() -> None:
    # "front" is the nearest bottle and nothing stands in its way, so it is the one taken;
    # the simulator judges the lift.
    with sim_system(_config(), seed=2, scene=_scene(BOTTLE, BLOCKER)) as system:
        z0 = system.world.T_base_object("front")[2, 3]
        status = system.run_task("grab", grab)
        assert status.phase == "succeeded", status.error
        system.pump(system.clock() + 2.0)
        assert system.world.held_object() == "front"
        assert system.world.T_base_object("front")[2, 3] - z0 == pytest.approx(0.10, abs=0.01)
        assert status.result["finger"] > VX300S.finger_limits[0] + GRASP_MARGIN_M
        assert status.result["stages"][-1] == "checked"
        # The other bottle was not touched.
        assert system.world.T_base_object("bottle")[:3, 3] == pytest.approx(
            [0.42, -0.1, 0], abs=2e-3
        )


@pytest.mark.parametrize(("planner", "stages"), [("collision", []), ("paper", ["safe_start"])])
def test_grab_refuses_a_bottle_too_close_to_the_base(planner: str, stages: list[str]) -> None:
    # The rule is tested with the limit raised above the bottle's distance (a bottle within
    # 5 cm of the base axis cannot stand there: the base is in the way). The collision-aware
    # grab plans before it moves, the paper's after going to its safe start pose.
    cfg = _config(min_base_distance=0.5, planner=planner)
    with sim_system(cfg, seed=2, scene=_scene(BOTTLE)) as system:
        status = system.run_task("grab", grab)
        assert status.phase == "failed" and "not safe to grasp" in status.error
        assert system.world.held_object() is None
        assert status.result["stages"] == stages


def test_grab_without_a_bottle_says_so() -> None:
    cup = ObjectSpec(
        "cup", "cup", 0.034, 0.1, 0.3, "water", x=0.4, y=0.0, colour=(0.8, 0.2, 0.2, 1.0)
    )
    with sim_system(_config(track_wait_s=2.0), seed=2, scene=_scene(cup)) as system:
        status = system.run_task("grab", grab)
    assert status.phase == "failed" and "no confirmed track of any bottle" in status.error


def _ring(n: int, centre: tuple[float, float], reach: float) -> list[ObjectSpec]:
    return [
        ObjectSpec(
            f"ring{k}",
            "bottle",
            0.03,
            0.21,
            0.5,
            "cola",
            x=centre[0] + reach * math.cos(a),
            y=centre[1] + reach * math.sin(a),
        )
        for k, a in enumerate(np.linspace(0.0, 2 * math.pi, n, endpoint=False) + 0.3)
    ]


def test_a_bottle_blocked_all_round_is_refused_and_nothing_moves() -> None:
    # Six bottles in a ring 1.5 cm from the middle one: no way in for the open fingers.
    middle = ObjectSpec("middle", "bottle", 0.03, 0.21, 0.5, "juice", x=0.40, y=0.0)
    scene = _scene(middle, *_ring(6, (0.40, 0.0), 0.075))
    with sim_system(_config(), seed=2, scene=scene) as system:
        system.pump(system.clock() + 3.0)
        state = system.snapshot()
        # The planning scene holds every object (true position within 2 cm, and the body's
        # radius covering the true one), the table at the base's height.
        scene_now = state.planning_scene
        assert scene_now.table_z == pytest.approx(0.0, abs=0.005)
        for obj in scene.objects:
            near = min(scene_now.bodies, key=lambda b: math.hypot(b.xy[0] - obj.x, b.xy[1] - obj.y))
            assert math.hypot(near.xy[0] - obj.x, near.xy[1] - obj.y) < 0.02
            assert near.radius >= obj.radius - 0.005 and near.top >= obj.height - 0.005
        track = min(state.bottles(), key=lambda t: float(np.hypot(*(t.p_base[:2] - [0.4, 0.0]))))
        assert np.hypot(*(track.p_base[:2] - [0.4, 0.0])) < 0.02
        q0 = system.world.joint_positions()
        finger0 = system.world.finger_position()
        start = {o.spec.name: o.T_base_obj[:3, 3].copy() for o in system.world.objects()}
        status = system.run_task("grab", grab, track_id=track.id)
        assert status.phase == "failed"
        assert status.error.startswith(f"every approach to bottle {track.id} at ("), status.error
        assert "is blocked: by the bottle (track" in status.error
        assert status.error.endswith("(nothing moved)")
        assert status.result["stages"] == [] and status.result["untouched"] is True
        system.pump(system.clock() + 1.0)
        assert np.max(np.abs(system.world.joint_positions() - q0)) < 1e-3
        assert system.world.finger_position() == pytest.approx(finger0, abs=1e-3)
        for o in system.world.objects():
            assert np.linalg.norm(o.T_base_obj[:3, 3] - start[o.spec.name]) < 1e-3


def test_a_bottle_in_a_tight_cluster_is_taken_from_above_and_nothing_else_moves() -> None:
    # Two bottles 1.5 cm from it behind, a can 1.5 cm in front: no room beside it for the
    # fingers, so it is grasped by the cap from above and lifted.
    target = ObjectSpec("target", "bottle", 0.03, 0.20, 0.5, "juice", x=0.42, y=0.0)
    behind = [
        ObjectSpec(
            f"behind{k}",
            "bottle",
            0.03,
            0.20,
            0.5,
            "cola",
            x=0.42 + 0.075 * math.cos(a),
            y=0.075 * math.sin(a),
        )
        for k, a in enumerate(np.radians([60.0, -60.0]))
    ]
    can = ObjectSpec("can", "can", 0.033, 0.12, 0.0, "water", x=0.342, y=0.0)
    with sim_system(_config(), seed=3, scene=_scene(target, *behind, can)) as system:
        start = {o.spec.name: o.T_base_obj[:3, 3].copy() for o in system.world.objects()}
        system.pump(system.clock() + 1.5)
        state = system.snapshot()
        track = min(state.bottles(), key=lambda t: float(np.hypot(*(t.p_base[:2] - [0.42, 0.0]))))
        status = system.run_task("grab", grab, track_id=track.id)
        assert status.phase == "succeeded", status.error
        assert status.result["from_above"]
        system.pump(system.clock() + 2.0)
        assert system.world.held_object() == "target"
        lifted = system.world.T_base_object("target")[:3, 3] - start["target"]
        assert lifted[2] == pytest.approx(0.10, abs=0.015)  # a cap grasp may slip a little
        assert np.hypot(*lifted[:2]) < 0.01
        for o in system.world.objects():
            if o.spec.name != "target":
                assert np.linalg.norm(o.T_base_obj[:3, 3] - start[o.spec.name]) < 0.003
                assert o.upright


# --------------------------------------------------------------------------- the grasp check


class _Gripper(GripperBase):
    def __init__(self, finger: float, confirmed: bool | None) -> None:
        self.finger, self.confirmed = finger, confirmed

    def open(self, delay: float | None = None) -> None: ...
    def close(self, delay: float | None = None) -> None: ...

    def get_finger_position(self) -> float:
        return self.finger

    def grasp_confirmed(self) -> bool | None:
        return self.confirmed


class _Arm:
    model = VX300S

    def __init__(self, gripper: GripperBase) -> None:
        self.gripper = gripper


def test_holding_is_the_grippers_own_confirmation_else_the_finger_gap() -> None:
    empty = VX300S.finger_limits[0]
    wide, shut = empty + GRASP_MARGIN_M + 0.005, empty + 0.001
    # A gripper that senses no more than its fingers (the base class): the gap decides.
    assert GripperBase.grasp_confirmed(_Gripper(wide, None)) is None
    assert holding(_Arm(_Gripper(wide, None)))
    assert not holding(_Arm(_Gripper(shut, None)))
    # One that senses a grasp decides itself, whatever the gap says.
    assert not holding(_Arm(_Gripper(wide, False)))
    assert holding(_Arm(_Gripper(shut, True)))


def _emulated(**grab) -> Config:
    config = _config(**grab)
    return dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, arm="dynamixel-emulated")
    )


def _spy_confirmations(gripper, monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Every answer the gripper's grasp_confirmed() gives from now on."""
    answers: list[bool] = []
    real = gripper.grasp_confirmed

    def spy() -> bool:
        answers.append(real())
        return answers[-1]

    monkeypatch.setattr(gripper, "grasp_confirmed", spy)
    return answers


def test_through_the_dynamixel_driver_the_grab_takes_the_grippers_confirmation(
    monkeypatch,
) -> None:
    # The driver over the servo-bus emulator: the task asks the gripper (current and finger
    # gap) after the close and after the lift; the simulator says the bottle is held up.
    pytest.importorskip("dynamixel_sdk")
    with sim_system(_emulated(), seed=2, scene=_scene(BOTTLE)) as system:
        answers = _spy_confirmations(system.arm.gripper, monkeypatch)
        z0 = system.world.T_base_object("bottle")[2, 3]
        status = system.run_task("grab", grab)
        assert status.phase == "succeeded", status.error
        assert answers == [True, True]
        assert system.world.held_object() == "bottle"
        assert system.world.T_base_object("bottle")[2, 3] - z0 == pytest.approx(0.10, abs=0.01)


def _taken_away_at_close(world, monkeypatch: pytest.MonkeyPatch, spots: list) -> None:
    """The bottle is taken away (by the simulator, as a hand would) just before the gripper
    closes, to the next of ``spots`` (as long as there is one)."""
    close = TaskContext.close_gripper

    def close_on_nothing(ctx: TaskContext) -> None:
        if spots:
            world.set_object_pose("bottle", make_T(np.eye(3), spots.pop(0)))
        close(ctx)

    monkeypatch.setattr(TaskContext, "close_gripper", close_on_nothing)


def test_through_the_dynamixel_driver_a_close_on_nothing_is_looked_at_again_and_retaken(
    monkeypatch,
) -> None:
    # The bottle is taken away as the gripper closes: the gripper does not confirm, the task
    # opens, backs off to the safe start pose, looks again and takes the bottle where it now
    # stands.
    pytest.importorskip("dynamixel_sdk")
    with sim_system(_emulated(), seed=2, scene=_scene(BOTTLE)) as system:
        world = system.world
        answers = _spy_confirmations(system.arm.gripper, monkeypatch)
        _taken_away_at_close(world, monkeypatch, [[0.30, 0.30, 0.0]])
        status = system.run_task("grab", grab)
        assert status.phase == "succeeded", status.error
        assert answers == [False, True, True]
        stages = status.result["stages"]
        assert stages.index("missed") < stages.index("closed")
        assert world.held_object() == "bottle"
        held_xy = world.T_base_object("bottle")[:2, 3]
        assert held_xy == pytest.approx([0.30, 0.30], abs=0.02)


def test_a_bottle_that_slips_out_during_the_lift_is_looked_at_again_and_retaken(
    monkeypatch,
) -> None:
    # As the first lift starts, the bottle slips out and stands on the table again, 10 cm
    # further along the approach (the simulator moves it, as a hand would: ahead of the
    # fingertips, clear of the gripper whichever side it came from). The gripper finds itself
    # empty after the lift, opens, goes down the way it went up and out the way it came in,
    # looks again and takes the bottle where it now stands. The simulator judges the second
    # lift.
    from armvision.tasks.grab import _PlannedGrab

    with sim_system(_config(), seed=2, scene=_scene(BOTTLE)) as system:
        world = system.world
        start = world.T_base_object("bottle").copy()
        steps = _PlannedGrab.steps
        moved: list[np.ndarray] = []

        def slip_at_first_lift(self, what, qs):
            if what == "lift" and not moved:
                yaw = self.candidate.yaw
                ahead = start[:3, 3] + 0.10 * np.array([math.cos(yaw), math.sin(yaw), 0.0])
                moved.append(ahead)
                world.set_object_pose("bottle", make_T(np.eye(3), ahead))
            steps(self, what, qs)

        monkeypatch.setattr(_PlannedGrab, "steps", slip_at_first_lift)
        status = system.run_task("grab", grab)
        assert status.phase == "succeeded", status.error
        assert moved  # it did slip
        stages = status.result["stages"]
        assert stages.count("lifted") == 2 and stages.index("missed") > stages.index("lifted")
        system.pump(system.clock() + 1.0)
        assert world.held_object() == "bottle"
        held = world.T_base_object("bottle")[:3, 3]
        assert held[:2] == pytest.approx(moved[0][:2], abs=0.02)
        assert held[2] - start[2, 3] == pytest.approx(0.10, abs=0.01)


def test_through_the_dynamixel_driver_two_closes_on_nothing_end_the_grab_open(
    monkeypatch,
) -> None:
    # Taken away at both closes: the task says so, opens and does not lift.
    pytest.importorskip("dynamixel_sdk")
    with sim_system(_emulated(), seed=2, scene=_scene(BOTTLE)) as system:
        world = system.world
        answers = _spy_confirmations(system.arm.gripper, monkeypatch)
        _taken_away_at_close(world, monkeypatch, [[0.30, 0.30, 0.0], [0.30, -0.30, 0.0]])
        status = system.run_task("grab", grab)
        assert status.phase == "failed"
        assert "the gripper closed on nothing" in status.error and "twice" in status.error
        assert answers == [False, False]
        assert status.result["stages"][-1] == "approach"
        system.pump(system.clock() + 1.0)
        assert world.held_object() is None
        assert world.finger_position() > VX300S.finger_limits[1] - 0.005  # opened again
        assert world.T_base_object("bottle")[:3, 3] == pytest.approx([0.30, -0.30, 0.0], abs=0.01)
