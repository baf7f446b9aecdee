"""The MuJoCo workspace: robot model vs our kinematics, scene generation, clock, ground truth."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from tests.sim.helpers import config_with

from armvision.camera.placement import camera_pose_from_placement
from armvision.config import Config
from armvision.errors import SimulationError
from armvision.geometry import pose_error
from armvision.robot.kinematics import VX300S, fk
from armvision.sim import world as world_module
from armvision.sim._mujoco import mujoco
from armvision.sim.scene import generate_scene
from armvision.sim.world import SimWorld


def _set_joints(world: SimWorld, q: np.ndarray) -> None:
    with world.lock:
        world.data.qpos[world._qadr] = q
        mujoco.mj_kinematics(world.model, world.data)


def test_mjcf_ee_site_equals_our_forward_kinematics() -> None:
    """The link chain is the URDF's: the ee_gripper_link site is fk(q) for random q."""
    world = SimWorld(config_with(min_objects=0, max_objects=0), seed=0)
    rng = np.random.default_rng(1)
    for q in rng.uniform(VX300S.lower, VX300S.upper, size=(50, 6)):
        _set_joints(world, q)
        dp, dr = pose_error(world.T_base_ee(), fk(q))
        assert dp < 1e-9 and dr < 1e-6


def test_joint_limits_and_actuators_match_the_arm_model(empty_world: SimWorld) -> None:
    m = empty_world.model
    for i, name in enumerate(VX300S.joint_names):
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert m.jnt_range[j] == pytest.approx([VX300S.lower[i], VX300S.upper[i]])
    left = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "left_finger")
    assert m.jnt_range[left] == pytest.approx(VX300S.finger_limits)
    assert m.nu == 7  # six joint servos and one gripper servo
    # Menagerie's grasping settings: elliptic cones, impratio 10, condim 4 on the pads.
    assert m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC and m.opt.impratio == 10
    pad = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "left_pad")
    assert m.geom_condim[pad] == 4


def test_world_starts_in_the_sleep_pose_with_the_gripper_open(empty_world: SimWorld) -> None:
    world = SimWorld(config_with(min_objects=0, max_objects=0), seed=0)
    assert world.joint_positions() == pytest.approx(VX300S.sleep)
    assert world.finger_position() == pytest.approx(0.057)
    world.advance(1.0)  # gravity on, servos holding
    assert world.joint_positions() == pytest.approx(VX300S.sleep, abs=1e-3)


@pytest.mark.parametrize("seed", range(12))
def test_scene_generator_places_1_to_4_graspable_objects_without_overlap(seed: int) -> None:
    scene = generate_scene(Config(), seed)
    assert 1 <= len(scene.objects) <= 4
    for obj in scene.objects:
        assert obj.radius <= 0.038  # the open pads are 89 mm apart
        assert 0.0 <= obj.fill <= 1.0
        assert 0.25 <= math.hypot(obj.x, obj.y) <= 0.55
    for i, a in enumerate(scene.objects):
        for b in scene.objects[i + 1 :]:
            assert math.hypot(a.x - b.x, a.y - b.y) >= a.radius + b.radius + 0.05


def test_same_seed_same_scene_other_seed_other_scene() -> None:
    a, b = generate_scene(Config(), 3), generate_scene(Config(), 3)
    assert a.objects == b.objects and np.array_equal(a.T_base_cam, b.T_base_cam)
    assert generate_scene(Config(), 3).objects != generate_scene(Config(), 4).objects


def test_objects_rest_upright_where_they_were_placed() -> None:
    world = SimWorld(config_with(min_objects=4, max_objects=4), seed=2)
    world.advance(1.0)
    for state in world.objects():
        spec = state.spec
        assert state.upright
        assert state.T_base_obj[:3, 3] == pytest.approx([spec.x, spec.y, 0.0], abs=2e-3)
        assert not state.held


def test_camera_is_placed_as_configured(empty_world: SimWorld) -> None:
    sim = Config().sim
    expected = camera_pose_from_placement(
        sim.camera_distance, 0.0, sim.camera_height, math.radians(sim.camera_pitch_deg)
    )
    world = SimWorld(config_with(min_objects=0, max_objects=0), seed=0)
    T_base_cam = world.T_base_cam()
    dp, dr = pose_error(T_base_cam, expected)
    assert dp < 1e-9 and dr < 1e-6
    # OpenCV optical frame: looking at the robot (towards -x), 30 degrees down, x to the right.
    z_cam = T_base_cam[:3, 2]
    assert math.degrees(math.asin(-z_cam[2])) == pytest.approx(30.0)
    assert z_cam[0] < 0 and T_base_cam[:3, 0] == pytest.approx([0.0, 1.0, 0.0])
    assert T_base_cam[2, 1] < 0  # image y points down


def test_randomised_camera_stays_within_the_configured_ranges() -> None:
    config = config_with(randomize_camera=True)
    sim = config.sim
    poses = [generate_scene(config, seed).T_base_cam for seed in range(20)]
    distances = [math.hypot(*T[:2, 3]) for T in poses]
    heights = [T[2, 3] for T in poses]
    pitches = [math.degrees(math.asin(-T[2, 2])) for T in poses]
    assert max(abs(d - sim.camera_distance) for d in distances) <= sim.camera_distance_jitter
    assert max(abs(h - sim.camera_height) for h in heights) <= sim.camera_height_jitter + 1e-9
    assert max(abs(p - sim.camera_pitch_deg) for p in pitches) <= sim.camera_pitch_jitter_deg
    assert np.std(distances) > 0.01  # it does vary


def test_set_camera_pose_moves_the_true_camera(empty_world: SimWorld) -> None:
    T_base_cam = camera_pose_from_placement(0.8, math.radians(20), 0.6, math.radians(40))
    empty_world.set_camera_pose(T_base_cam)
    dp, dr = pose_error(empty_world.T_base_cam(), T_base_cam)
    assert dp < 1e-9 and dr < 1e-6


def test_tag_pose_is_the_configured_offset_from_the_ee(empty_world: SimWorld) -> None:
    rng = np.random.default_rng(3)
    for q in rng.uniform(VX300S.lower * 0.5, VX300S.upper * 0.5, size=(5, 6)):
        _set_joints(empty_world, q)
        T_base_tag = empty_world.T_base_tag()
        dp, dr = pose_error(T_base_tag, fk(q) @ empty_world.T_ee_tag)
        assert dp < 1e-9 and dr < 1e-6
    assert empty_world.T_ee_tag[:3, 3] == pytest.approx(Config().tag.offset_ee)
    # The tag faces out of the top of the gripper: its z (into the tag) is -z_ee.
    assert empty_world.T_ee_tag[:3, 2] == pytest.approx([0.0, 0.0, -1.0])


def test_loose_tags_lie_face_up_on_the_table() -> None:
    world = SimWorld(config_with(loose_tags=2, max_objects=2), seed=4)
    tags = world.T_base_loose_tags()
    assert len(tags) == 2 and 96 not in tags
    for T_base_tag in tags.values():
        assert T_base_tag[2, 3] == pytest.approx(0.001)
        assert T_base_tag[:3, 2] == pytest.approx([0.0, 0.0, -1.0])


def test_ground_truth_is_json_serialisable_and_consistent() -> None:
    world = SimWorld(Config(), seed=6)
    truth = world.ground_truth()
    record = json.loads(json.dumps(truth.to_dict()))
    assert np.array(record["T_base_ee"]) == pytest.approx(fk(truth.joint_positions), abs=1e-9)
    assert len(record["objects"]) == len(world.scene.objects)
    assert record["held_object"] is None
    first = record["objects"][0]
    spec = world.scene.objects[0]
    assert first["fill"] == spec.fill
    assert first["liquid_top_above_bottom"] == pytest.approx(
        spec.inner_bottom + spec.fill * (spec.body_height - spec.inner_bottom)
    )


def test_lockstep_time_moves_only_when_asked() -> None:
    world = SimWorld(config_with(min_objects=0, max_objects=0), seed=0)
    assert world.time == 0.0
    time.sleep(0.05)
    assert world.time == 0.0
    world.run_until(0.1)
    assert world.time == pytest.approx(0.1, abs=world.timestep)
    world.advance(0.25)
    assert world.time == pytest.approx(0.35, abs=world.timestep)


def test_realtime_mode_follows_the_wall_clock() -> None:
    with SimWorld(config_with(min_objects=0, max_objects=0), seed=0, mode="realtime") as world:
        start_wall, start_sim = time.monotonic(), world.time
        time.sleep(0.4)
        elapsed_sim = world.time - start_sim
        elapsed_wall = time.monotonic() - start_wall
        assert elapsed_sim == pytest.approx(elapsed_wall, abs=0.08)
        world.run_until(world.time + 0.1)  # waits rather than steps
    stopped = world.time
    time.sleep(0.05)
    assert world.time == stopped


def test_unknown_mode_is_refused() -> None:
    with pytest.raises(SimulationError, match="lockstep"):
        SimWorld(Config(), seed=0, mode="fast")  # type: ignore[arg-type]


def test_broken_opengl_backend_is_an_error_naming_mujoco_gl() -> None:
    code = (
        "from armvision.errors import SimulationError\n"
        "try:\n    import armvision.sim.world\n"
        "except SimulationError as e:\n    print('SimulationError:', e)\n"
    )
    env = {**os.environ, "MUJOCO_GL": "no-such-backend"}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert "SimulationError:" in out.stdout, out.stderr
    assert "MUJOCO_GL=egl" in out.stdout


def test_marker_radius(empty_world: SimWorld) -> None:
    assert empty_world.marker_radius == pytest.approx(0.01)
    assert world_module.MARKER_PARKED[2] < -1.0
