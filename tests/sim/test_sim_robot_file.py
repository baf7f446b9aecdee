"""The static ViperX-300s MJCF against the arm's kinematic facts, and what the builder sets."""

from __future__ import annotations

import dataclasses
from importlib import resources

import numpy as np
import pytest

from armvision.config import Config
from armvision.geometry import pose_error
from armvision.robot.kinematics import VX300S, fk
from armvision.robot.tag_mount import R_EE_TAG
from armvision.robot.vx300s import EE_ARM_X, EE_GRIPPER_X, FINGER_LINK_X, FINGER_PAD_INSET
from armvision.sim import names
from armvision.sim._mujoco import mujoco
from armvision.sim.model import GRIPPER_MAX_FORCE_N, T_WORLD_BASE, build_model
from armvision.sim.scene import bench_scene

OBJ = mujoco.mjtObj


@pytest.fixture(scope="module")
def robot() -> mujoco.MjModel:
    """The robot file on its own, as installed (package data), base at the world origin."""
    text = resources.files("armvision.sim").joinpath("data", names.ROBOT_FILE).read_text()
    return mujoco.MjModel.from_xml_string(text)


def _id(m: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    i = mujoco.mj_name2id(m, kind, name)
    assert i >= 0, f"no {name}"
    return i


def test_joint_ranges_and_servo_ranges_are_the_arm_model_limits(robot: mujoco.MjModel) -> None:
    for i, name in enumerate(VX300S.joint_names):
        j = _id(robot, OBJ.mjOBJ_JOINT, name)
        np.testing.assert_allclose(
            robot.jnt_range[j], [VX300S.lower[i], VX300S.upper[i]], atol=1e-9
        )
        a = _id(robot, OBJ.mjOBJ_ACTUATOR, name)
        assert robot.actuator_trnid[a, 0] == j
        np.testing.assert_allclose(robot.actuator_ctrlrange[a], robot.jnt_range[j], atol=1e-12)
    left, right = (_id(robot, OBJ.mjOBJ_JOINT, n) for n in VX300S.finger_names)
    np.testing.assert_allclose(robot.jnt_range[left], VX300S.finger_limits, atol=1e-12)
    np.testing.assert_allclose(
        robot.jnt_range[right], [-VX300S.finger_limits[1], -VX300S.finger_limits[0]]
    )
    gripper = _id(robot, OBJ.mjOBJ_ACTUATOR, names.GRIPPER_ACTUATOR)
    np.testing.assert_allclose(robot.actuator_ctrlrange[gripper], VX300S.finger_limits)


def test_ee_site_forward_kinematics_is_ours(robot: mujoco.MjModel) -> None:
    data = mujoco.MjData(robot)
    ee = _id(robot, OBJ.mjOBJ_SITE, names.EE_SITE)
    qadr = [robot.jnt_qposadr[_id(robot, OBJ.mjOBJ_JOINT, n)] for n in VX300S.joint_names]
    rng = np.random.default_rng(3)
    for q in [VX300S.home, VX300S.sleep, *rng.uniform(VX300S.lower, VX300S.upper, (5, 6))]:
        data.qpos[qadr] = q
        mujoco.mj_kinematics(robot, data)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = data.site_xmat[ee].reshape(3, 3), data.site_xpos[ee]
        dp, dr = pose_error(T, fk(q))
        assert dp < 1e-6 and dr < 1e-6


def test_gripper_geometry_is_the_robot_facts(robot: mujoco.MjModel) -> None:
    gripper = _id(robot, OBJ.mjOBJ_BODY, names.GRIPPER_BODY)
    for site, x in ((names.EE_SITE, EE_GRIPPER_X), ("ee_arm_link", EE_ARM_X)):
        s = _id(robot, OBJ.mjOBJ_SITE, site)
        assert robot.site_bodyid[s] == gripper
        np.testing.assert_allclose(robot.site_pos[s], [x, 0.0, 0.0], atol=1e-12)
    for pad, side in ((names.LEFT_PAD, 1.0), (names.RIGHT_PAD, -1.0)):
        g = _id(robot, OBJ.mjOBJ_GEOM, pad)
        body = robot.geom_bodyid[g]
        assert robot.body_parentid[body] == gripper
        np.testing.assert_allclose(robot.body_pos[body], [FINGER_LINK_X, 0.0, 0.0], atol=1e-12)
        # The gripping face (the pad's inner side) lies FINGER_PAD_INSET inboard of the joint.
        inner_face = robot.geom_pos[g][1] - side * robot.geom_size[g][1]
        assert inner_face == pytest.approx(-side * FINGER_PAD_INSET, abs=1e-12)


def test_builder_sets_the_configured_tag_mount_and_gripper_force() -> None:
    base = Config()
    config = dataclasses.replace(
        base,
        tag=dataclasses.replace(base.tag, offset_ee=(0.01, -0.02, 0.03)),
        robot=dataclasses.replace(base.robot, gripper_pressure=0.8),
    )
    m = build_model(config, bench_scene(config))
    site = _id(m, OBJ.mjOBJ_SITE, names.ARM_TAG_SITE)
    np.testing.assert_allclose(m.site_pos[site], [EE_GRIPPER_X + 0.01, -0.02, 0.03], atol=1e-12)
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)
    R_world_ee = data.site_xmat[_id(m, OBJ.mjOBJ_SITE, names.EE_SITE)].reshape(3, 3)
    np.testing.assert_allclose(
        R_world_ee.T @ data.site_xmat[site].reshape(3, 3), R_EE_TAG, atol=1e-9
    )
    plate = _id(m, OBJ.mjOBJ_GEOM, names.ARM_TAG_PLATE)
    assert m.geom_bodyid[plate] == m.site_bodyid[site]
    gripper = _id(m, OBJ.mjOBJ_ACTUATOR, names.GRIPPER_ACTUATOR)
    force = GRIPPER_MAX_FORCE_N * 0.8
    np.testing.assert_allclose(m.actuator_forcerange[gripper], [-force, force])
    base_body = _id(m, OBJ.mjOBJ_BODY, names.BASE_BODY)
    np.testing.assert_array_equal(m.body_pos[base_body], T_WORLD_BASE[:3, 3])


def test_the_names_the_world_and_evaluations_use_exist() -> None:
    config = Config()
    scene = bench_scene(config)
    m = build_model(config, scene)
    assert _id(m, OBJ.mjOBJ_CAMERA, names.CAMERA_NAME) >= 0
    for body in (names.CAMERA_BODY, names.CAMERA_MOUNT_BODY, names.MARKER_BODY):
        assert m.body_mocapid[_id(m, OBJ.mjOBJ_BODY, body)] >= 0
    bottle, cup = scene.objects
    for part in names.BOTTLE_PARTS:
        _id(m, OBJ.mjOBJ_GEOM, names.object_geom(bottle.name, part))
    for part in (names.SHELL, names.WALL, names.LIQUID):
        _id(m, OBJ.mjOBJ_GEOM, names.object_geom(cup.name, part))
    _id(m, OBJ.mjOBJ_SITE, names.loose_tag(0))
