"""SimWorld.set_object_pose: a hand puts an object somewhere; physics carries on from there."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armvision.errors import SimulationError
from armvision.geometry import make_T, pose_error, rot_x, rot_z
from armvision.sim.world import SimWorld


@pytest.fixture(scope="module")
def world() -> SimWorld:
    return SimWorld(seed=0)  # the default scene has 1-4 objects; seed 0 has some


def test_object_is_placed_at_rest_and_stays_there(world: SimWorld) -> None:
    name = world.scene.objects[0].name
    target = make_T(rot_z(0.7), [0.42, 0.05, 0.0])
    world.set_object_pose(name, target)
    dp, dr = pose_error(world.T_base_object(name), target)
    assert dp < 1e-9 and dr < 1e-9
    body = world._object_bodies[name]
    joint = world.model.body_jntadr[body]
    dof = world.model.jnt_dofadr[joint]
    assert np.all(world.data.qvel[dof : dof + 6] == 0.0)
    world.advance(0.5)  # standing on the table: it stays (settling by under a millimetre)
    dp, dr = pose_error(world.T_base_object(name), target)
    assert dp < 1e-3 and dr < math.radians(0.5)
    assert world.ground_truth().objects[0].upright


def test_small_steps_drive_an_object_along_a_path(world: SimWorld) -> None:
    name = world.scene.objects[0].name
    start = np.array([0.40, -0.05])
    for k in range(50):  # 10 cm along y in 0.5 s, a step every 10 ms
        xy = start + np.array([0.0, 0.002 * k])
        world.set_object_pose(name, make_T(rot_z(0.0), [xy[0], xy[1], 0.0]))
        world.advance(0.01)
        p = world.T_base_object(name)[:3, 3]
        assert np.linalg.norm(p[:2] - xy) < 1e-3 and abs(p[2]) < 1e-3


def test_a_tilted_pose_is_taken_as_given(world: SimWorld) -> None:
    name = world.scene.objects[0].name
    target = make_T(rot_x(math.radians(90.0)), [0.4, 0.0, 0.2])  # lying, in the air
    world.set_object_pose(name, target)
    assert not world.ground_truth().objects[0].upright
    dp, _ = pose_error(world.T_base_object(name), target)
    assert dp < 1e-9


def test_bad_requests_raise_simulation_errors_that_say_what_to_do(world: SimWorld) -> None:
    with pytest.raises(SimulationError, match="no object 'nope'"):
        world.set_object_pose("nope", np.eye(4))
    name = world.scene.objects[0].name
    with pytest.raises(SimulationError, match="4x4"):
        world.set_object_pose(name, np.eye(3))
    with pytest.raises(SimulationError, match="4x4"):
        world.set_object_pose(name, np.full((4, 4), np.nan))
    with pytest.raises(SimulationError, match="orthonormal"):
        world.set_object_pose(name, np.diag([2.0, 1.0, 1.0, 1.0]))
